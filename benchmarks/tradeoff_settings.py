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
    """One point of the sweep: how the reference is rendered and how MRAD runs.

    ``binary`` ranks pixels by the method's 0/255 mask instead of its score map (how the
    paper evaluated its thresholded PAD and RXD maps).
    """

    name: str
    render: RenderSettings = field(default_factory=lambda: render_settings(0.25))
    params: MradParams = field(default_factory=MradParams)
    method: str = "MRAD"
    binary: bool = False

    @property
    def config(self) -> PipelineConfig:
        """The pipeline configuration this setting runs."""
        return PipelineConfig(self.render, self.params, (self.method,))

    @property
    def conforms(self) -> bool:
        """Whether docs/method.md ("How defaults are chosen") admits the outputs as a default."""
        return self.params.pixel_score in ("continuous", "regions") and not self.binary


# Parameters that change the pixel score map (and so P.AP); the others shape only the mask.
# The photometric model behind the map is ``map_photometric`` for the continuous map and
# ``photometric`` (the mask's) for the others: see :func:`map_key`.
MAP_KNOBS = (
    "grid",
    "max_gain",
    "score_sigma",
    "process_scale",
    "score_scaling",
    "score_ref",
    "abs_floor",
    "rel_floor",
    "pixel_score",
)

# The mask's photometric model is not a bench choice: the photometric tests require it (a
# normal frame stays normal under a camera's exposure, tone curve, white balance, ...).
MASK_PHOTOMETRIC = "cell_affine"


def map_key(row: dict) -> tuple:
    """What decides a report row's pixel map: reference rendering and map knobs."""
    params = row["params"]
    model = params["map_photometric" if params["pixel_score"] == "continuous" else "photometric"]
    knobs = (params[k] for k in MAP_KNOBS)
    return (row["reference_scale"], row["shadows"], row["cull_bodies"], model, *knobs)


# The `previous` profile: a simpler configuration the sweep compares against (docs/evaluation.md).
PREVIOUS_DEFAULT = profile("previous")


def sweep_settings(base: MradParams) -> list[Setting]:
    """The swept settings around ``base`` (the default profile).

    Map knobs (grid, photometric model, smoothing, query scale, reference scale) decide P.AP;
    mask knobs (growth rule, thresholds, blur, noise rule) decide only the mask and the
    image score, so they are swept at the base's map settings and chosen by I.AUROC.
    """
    eighth, eighth_flat = render_settings(0.125), render_settings(0.125, False)
    settings = [
        Setting("previous default (sparse map)", eighth, PREVIOUS_DEFAULT),
        Setting(
            "previous default, continuous map",
            eighth,
            PREVIOUS_DEFAULT.replace(pixel_score="continuous"),
        ),
        Setting("paper-faithful", render_settings(1.0), profile("paper")),
    ]
    for photometric in ("none", "cell_affine"):
        for grid in (1, 3, 4, 6, 8):
            settings.append(
                Setting(
                    f"grid {grid}, {photometric}",
                    eighth,
                    base.replace(grid=grid, photometric=photometric),
                )
            )
    affine = base.replace(photometric="cell_affine")
    settings += [
        Setting("cell_affine, score_sigma 0", eighth, affine.replace(score_sigma=0.0)),
        Setting("cell_affine, score_sigma 2", eighth, affine.replace(score_sigma=2.0)),
        Setting("cell_affine, query 1", eighth, affine.replace(process_scale=1.0)),
        Setting("cell_affine, query 1/2", eighth, affine.replace(process_scale=0.5)),
        Setting("cell_affine, query 1/4", eighth, affine.replace(process_scale=0.25)),
        Setting("cell_affine, ref 1/4", render_settings(0.25), affine),
        Setting("cell_affine, ref 1/8 no shadows", eighth_flat, affine),
        Setting(
            "cell_affine, mask: tolerance growth",
            eighth,
            affine.replace(growth="tolerance", noise_removal="cell_spread"),
        ),
        Setting("cell_affine, mask: seed 50", eighth, affine.replace(seed_score=50.0)),
        Setting(
            "cell_affine, mask: min 15, seed 30",
            eighth,
            affine.replace(min_score=15.0, seed_score=30.0),
        ),
        Setting(
            "cell_affine, mask: min 40, seed 80",
            eighth,
            affine.replace(min_score=40.0, seed_score=80.0),
        ),
        Setting("cell_affine, mask: blur 2", eighth, affine.replace(blur_sigma=2.0)),
        Setting(
            "cell_affine, mask: no noise rule",
            eighth,
            affine.replace(noise_removal="none"),
        ),
    ]
    unique = {}
    for setting in settings:  # base may coincide with a grid row: keep the first name
        key = (setting.render, setting.params, setting.method, setting.binary)
        unique.setdefault(key, setting)
    return list(unique.values())


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
    # (the frame's anomalous flag, whether its ground truth holds an anomaly) per frame
    flags: list[tuple[bool, bool]] = field(default_factory=list)

    def flag_balanced_accuracy(self) -> float:
        """Mean of the flag's recall on anomalous and on normal frames (nan if one is absent)."""
        flags = np.array(self.flags, dtype=bool).reshape(-1, 2)
        anomalous, normal = flags[flags[:, 1], 0], flags[~flags[:, 1], 0]
        if anomalous.size == 0 or normal.size == 0:
            return float("nan")
        return 0.5 * (float(anomalous.mean()) + float(1.0 - normal.mean()))

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
            "binary": s.binary,
            "frames": len(self.latency_ms),
            "latency_ms_median": float(np.median(self.latency_ms)),
            "latency_ms_p95": float(np.percentile(self.latency_ms, 95)),
            "render_ms_median": float(np.median(self.render_ms)),
            "detect_ms_median": float(np.median(self.detect_ms)),
            "flag_balanced_accuracy": self.flag_balanced_accuracy(),
            **m,
        }
