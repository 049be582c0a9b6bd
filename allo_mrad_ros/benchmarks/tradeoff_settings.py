"""The settings the trade-off benchmark sweeps, their outcomes, and the pose perturbations."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from allo_mrad_ros.detector import MradParams, profile
from allo_mrad_ros.geometry import pose_matrix
from allo_mrad_ros.metrics import MetricsAccumulator
from allo_mrad_ros.pipeline import PipelineConfig, RenderSettings
from allo_mrad_ros.sequence import Frame


def render_settings(
    reference_scale: float, shadows: bool = True, cull_bodies: bool = True
) -> RenderSettings:
    """The render settings of a sweep point (the sweep's baseline: shadows, bodies culled)."""
    return RenderSettings(reference_scale, shadows, cull_bodies)


@dataclass(frozen=True)
class Setting:
    """One point of the sweep: how the reference is rendered and how MRAD runs."""

    name: str
    render: RenderSettings
    params: MradParams = field(default_factory=MradParams)
    method: str = "MRAD"

    @property
    def config(self) -> PipelineConfig:
        """The pipeline configuration this setting runs."""
        return PipelineConfig(self.render, self.params, (self.method,))

    @property
    def conforms(self) -> bool:
        """Whether the outputs follow mrad.md (only those may become the default)."""
        return self.params.pixel_score == "regions"


def sweep_settings(base: MradParams) -> list[Setting]:
    """The swept settings: each knob alone around ``base``, then the speed knobs combined
    with each accuracy knob (grid 6, cell_spread), so fast and accurate can meet."""
    full, eighth = render_settings(0.25), render_settings(0.125)
    eighth_flat = render_settings(0.125, False)
    half = base.replace(process_scale=0.5)
    settings = [
        Setting("baseline", full, base),
        Setting("ref scale 1", render_settings(1.0), base),
        Setting("ref scale 1/2", render_settings(0.5), base),
        Setting("ref scale 1/8", eighth, base),
        Setting("process scale 1/2", full, half),
        Setting("process scale 1/4", full, base.replace(process_scale=0.25)),
        Setting("no shadows", render_settings(0.25, False), base),
        Setting("bodies always", render_settings(0.25, True, False), base),
        Setting("grid 6", full, base.replace(grid=6)),
        Setting("cell_spread", full, base.replace(noise_removal="cell_spread")),
        Setting("per_image scaling", full, base.replace(score_scaling="per_image")),
        Setting("ref 1/8, no shadows", eighth_flat, base),
        Setting("ref 1/8, process 1/2, no shadows", eighth_flat, half),
        Setting("paper-faithful", render_settings(1.0), profile("paper")),
    ]
    for label, accurate in (
        ("grid 6", base.replace(grid=6)),
        ("grid 6, cell_spread", base.replace(grid=6, noise_removal="cell_spread")),
    ):
        fast = accurate.replace(process_scale=0.5)
        fastest = accurate.replace(process_scale=0.25)
        if label != "grid 6":
            settings.append(Setting(label, full, accurate))
        settings += [
            Setting(f"{label}, ref 1/8", eighth, accurate),
            Setting(f"{label}, process 1/2", full, fast),
            Setting(f"{label}, ref 1/8, process 1/2", eighth, fast),
            Setting(f"{label}, ref 1/8, process 1/2, no shadows", eighth_flat, fast),
            Setting(f"{label}, ref 1/8, process 1/4", eighth, fastest),
            Setting(f"{label}, ref 1/8, process 1/4, no shadows", eighth_flat, fastest),
        ]
    # Not mrad.md's output (score kept outside the regions): shown, never chosen.
    blurred = base.replace(grid=6, pixel_score="blurred")
    settings += [
        Setting("grid 6, pixel score blurred (not mrad.md)", full, blurred),
        Setting(
            "grid 6, pixel score blurred, ref 1/8, process 1/2 (not mrad.md)",
            eighth,
            blurred.replace(process_scale=0.5),
        ),
    ]
    return settings


def true_pose(frame: Frame) -> np.ndarray:
    """The pose the image was rendered from (``true_*`` columns), else the reported one."""
    keys = ("true_tx", "true_ty", "true_tz", "true_qx", "true_qy", "true_qz", "true_qw")
    if all(frame.extra.get(k) for k in keys):
        values = [float(frame.extra[k]) for k in keys]
        return pose_matrix(values[:3], values[3:])
    return frame.T_station_camera


def perturbed(pose: np.ndarray, rotation_deg: float, translation_m: float, seed: int) -> np.ndarray:
    """``pose`` turned by exactly ``rotation_deg`` and moved by exactly ``translation_m``,
    about and along directions drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    out = pose.copy()
    turn = Rotation.from_rotvec(math.radians(rotation_deg) * axis / np.linalg.norm(axis))
    out[:3, :3] = pose[:3, :3] @ turn.as_matrix()
    out[:3, 3] = pose[:3, 3] + translation_m * direction / np.linalg.norm(direction)
    return out


@dataclass
class Outcome:
    """Latencies and metrics of one setting over a split."""

    setting: Setting
    latency_ms: list[float] = field(default_factory=list)
    render_ms: list[float] = field(default_factory=list)
    detect_ms: list[float] = field(default_factory=list)
    metrics: MetricsAccumulator = field(default_factory=MetricsAccumulator)
    counts: list[np.ndarray] = field(default_factory=list)

    def row(self) -> dict:
        """The report row."""
        m = self.metrics.compute().as_dict()
        s = self.setting
        return {
            "setting": s.name,
            "method": s.method,
            "reference_scale": s.render.reference_scale,
            "shadows": s.render.shadows,
            "cull_bodies": s.render.cull_bodies,
            "params": s.params.to_dict(),
            "conforms_to_mrad_md": s.conforms,
            "frames": len(self.latency_ms),
            "latency_ms_median": float(np.median(self.latency_ms)),
            "latency_ms_p95": float(np.percentile(self.latency_ms, 95)),
            "render_ms_median": float(np.median(self.render_ms)),
            "detect_ms_median": float(np.median(self.detect_ms)),
            **m,
        }
