"""Rendering one planned frame: camera pose, anomaly placement, query, mask and reference.

One :class:`FrameSynthesizer` per process holds the renderers (built once: the OpenGL
context and the station upload are reused across frames), the station's voxel model, the
base poses and the ephemeris.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from os import PathLike
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.ephemeris import Sky, StationEphemeris
from allo_mrad_ros.geometry import pose_components
from allo_mrad_ros.render import (
    LABEL_ANOMALY,
    LABEL_STATION,
    ExtraObject,
    ReferenceRenderer,
    RenderResult,
)
from allo_mrad_ros.synth import placement
from allo_mrad_ros.synth.config import SynthConfig, SynthError
from allo_mrad_ros.synth.cycles_light import draw_earthshine
from allo_mrad_ros.synth.hard_kinds import (
    STATION_COLOURED_TYPES,
    kind_columns,
    paint_like_station,
    placement_penalty,
    station_palette,
)
from allo_mrad_ros.synth.lighting import QueryLight, query_lamps, query_light
from allo_mrad_ros.synth.objects import AnomalyObject, build_anomaly
from allo_mrad_ros.synth.occupancy import StationOccupancy
from allo_mrad_ros.synth.planning import (
    STREAM_CAMERA,
    STREAM_DEVELOP,
    STREAM_FRAME,
    STREAM_LIGHT,
    STREAM_MATERIALS,
    STREAM_POSES,
    STREAM_PT_KIND,
    STREAM_PT_LIGHT,
    STREAM_PT_MATERIALS,
    STREAM_WEAR,
    FramePlan,
    stream,
)
from allo_mrad_ros.synth.poses import BasePose, clear_camera, make_base_poses, perturb, pose_error
from allo_mrad_ros.synth.realism import (
    CameraLook,
    apply_camera,
    find_sun,
    jpeg_round_trip,
    resize_to,
)
from allo_mrad_ros.synth.surfaces import as_built_station, worn_object

# The low-resolution pre-check of an object's visible area accepts down to this share of
# the threshold; the full-resolution render decides.
_CHECK_MARGIN = 0.7
_CHECK_SCALE = 0.25
# Perturbed camera poses tried per draw before giving up on a frame (cameras in the hull).
_CLEAR_ATTEMPTS = 50
# The background of a dark-background type: a ring this wide (share of the image width)
# around its silhouette, which must be at least this much station (not space).
_RING_FRACTION = 0.015
_RING_STATION_SHARE = 0.5


def background_level(rgb: np.ndarray, labels: np.ndarray) -> float:
    """Mean luminance (0..1) of the ring of pixels around the anomaly's silhouette.

    Parameters
    ----------
    rgb : numpy.ndarray
        (h, w, 3) uint8 render with the object.
    labels : numpy.ndarray
        (h, w) uint8 classes of the same render.

    Returns
    -------
    float
        The ring's mean luminance, or ``inf`` when less than half of the ring is station
        (the object is seen against space, not against the station).
    """
    anomaly = (labels == LABEL_ANOMALY).astype(np.uint8)
    width = max(3, 2 * round(_RING_FRACTION * labels.shape[1] / 2) + 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (width, width))
    ring = (cv2.dilate(anomaly, kernel) > 0) & (anomaly == 0)
    if not ring.any() or np.mean(labels[ring] == LABEL_STATION) < _RING_STATION_SHARE:
        return math.inf
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return float(grey[ring].mean()) / 255.0


def camera_intrinsics(config: SynthConfig) -> CameraIntrinsics:
    """ALLO's camera (25 mm lens on a 36 mm sensor) at the configured image size."""
    return CameraIntrinsics.from_fov(
        config.width, config.height, focal_mm=25.0, sensor_width_mm=36.0
    )


@dataclass(frozen=True, eq=False)
class FrameOutput:
    """Everything the writer needs for one frame.

    Attributes
    ----------
    plan : FramePlan
        What was asked for.
    image, mask : numpy.ndarray
        Query (h, w, 3) and classes (h, w), uint8.
    reference : numpy.ndarray or None
        Pre-rendered reference at full size, if configured.
    T_true, T_reported : numpy.ndarray
        (4, 4) pose the query was rendered from, and the pose written as the frame's pose.
    sky : Sky
        Sun, Earth and Moon of the frame's day.
    extra : dict
        Extra ``frames.csv`` columns.
    """

    plan: FramePlan
    image: np.ndarray
    mask: np.ndarray
    reference: np.ndarray | None
    T_true: np.ndarray
    T_reported: np.ndarray
    sky: Sky
    extra: dict = field(default_factory=dict)


def _pose_columns(prefix: str, T: np.ndarray) -> dict[str, float]:
    position, quaternion = pose_components(T)
    names = ("tx", "ty", "tz", "qx", "qy", "qz", "qw")
    return {f"{prefix}_{n}": float(v) for n, v in zip(names, (*position, *quaternion), strict=True)}


class FrameSynthesizer:
    """Renders planned frames of one sequence.

    Parameters
    ----------
    config : SynthConfig
        Sequence settings.
    seed : int
        Sequence seed (base poses and the as-built station's materials derive from it).
    mesh : path-like
        The station model file.
    backend : str or None
        OpenGL backend for the renderers (None chooses).
    """

    def __init__(
        self,
        config: SynthConfig,
        seed: int,
        mesh: str | PathLike[str],
        backend: str | None = None,
    ) -> None:
        self.config = config
        self.seed = seed
        self.mesh = Path(mesh)
        self.intrinsics = camera_intrinsics(config)
        self.occupancy = StationOccupancy.from_model(self.mesh)
        self.base_poses: dict[str, list[BasePose]] = make_base_poses(
            self.occupancy,
            {split: spec.cameras for split, spec in config.splits.items()},
            stream(seed, STREAM_POSES),
            config.camera_distance_m,
            config.min_camera_clearance_m,
        )
        self.ephemeris = StationEphemeris()
        realism = config.realism
        station = as_built_station(self.mesh, stream(seed, STREAM_MATERIALS), realism)
        camera_rng = stream(seed, STREAM_CAMERA)
        self.look = CameraLook.draw(camera_rng, realism)
        self.ambient, self.spot_intensity = query_lamps(camera_rng, realism)
        self._query = ReferenceRenderer(
            station,
            self.intrinsics,
            scale=1.0,
            backend=backend,
            shadows=config.shadows,
            ambient=self.ambient,
            spot_intensity=self.spot_intensity,
        )
        self._low: ReferenceRenderer | None = None
        pixels = config.width * config.height
        low_scale = config.reference_scale if config.references else _CHECK_SCALE
        if config.references or pixels * low_scale**2 >= 256 * 144:
            # One reduced-scale renderer of the nominal model serves both the references
            # and the quick visibility pre-check (labels do not depend on materials).
            self._low = ReferenceRenderer(
                self.mesh, self.intrinsics, scale=low_scale, backend=backend
            )
        self._check = self._low is not None and low_scale <= 0.5
        self._sky = lru_cache(maxsize=512)(self.ephemeris.sky_on_day)
        self._cycles = None
        if config.query_renderer == "cycles":
            from allo_mrad_ros.synth.cycles import CyclesRenderer

            # The same surfaces and lamps as the rasterised query (the file itself when
            # realism is off, so nothing is re-exported).
            self._cycles = CyclesRenderer(
                station if realism.enabled else self.mesh,
                self.intrinsics,
                samples=config.cycles_samples,
                ambient=self.ambient,
                spot_intensity=self.spot_intensity,
                light=config.cycles_light,
                light_rng=stream(seed, STREAM_PT_MATERIALS),
            )
        # The station's own materials, for objects painted like it (the nominal model's:
        # what a designer choosing a colour would have had).
        self._palette = station_palette(self.mesh) if config.hard_kinds else []

    def close(self) -> None:
        """Free the renderers."""
        self._query.close()
        if self._cycles is not None:
            self._cycles.close()
        if self._low is not None:
            self._low.close()

    # ------------------------------------------------------------------ one frame
    def synthesize(self, plan: FramePlan) -> FrameOutput:
        """Render one planned frame.

        Raises
        ------
        SynthError
            If no placement meets the rules after all retries and depth fallbacks.
        """
        rng = stream(plan.seed, STREAM_FRAME, plan.index)
        base = self.base_poses[plan.split][plan.camera]
        sky = self._sky(plan.day)
        bodies = sky.bodies()
        realism = self.config.realism
        light = query_light(
            stream(plan.seed, STREAM_LIGHT, plan.index),
            realism,
            sky.sun_direction,
            plan.sun_strength,
        )
        extra: dict[str, object] = {"day": plan.day, "pose_id": base.pose_id}
        extras: list[ExtraObject] = []
        if plan.is_anomalous:
            T_true, result, anomaly_extra, extras = self._place(plan, base, sky, light, rng)
            extra.update(anomaly_extra)
        else:
            T_true = self._camera(base, rng)
            result = self._query.render(
                T_true, light.sun_direction, light.sun_strength, bodies, labels=True
            )
        image, reference, T_reported = self._develop(
            plan, rng, result, T_true, sky, light, extras, extra
        )
        return FrameOutput(plan, image, result.labels, reference, T_true, T_reported, sky, extra)

    def _develop(
        self,
        plan: FramePlan,
        rng: np.random.Generator,
        result: RenderResult,
        T_true: np.ndarray,
        sky: Sky,
        light: QueryLight,
        extras: list[ExtraObject],
        extra: dict[str, object],
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """The query as a camera gives it, the reference and the reported pose of a rendered
        frame (``extra`` gains the frame's draws). ``plan`` needs ``seed``, ``index`` and
        ``sun_strength``."""
        bodies = sky.bodies()
        realism = self.config.realism
        query = result.rgb
        if self._cycles is not None:
            # Path-traced from the same pose, light and objects; the mask stays the
            # rasteriser's label image of the same geometry.
            view_transform, exposure_ev = self._development(plan)
            earthshine = None
            if self.config.cycles_light is not None:
                # Sunlight the Earth sends back, so it scales with the Sun's strength.
                level = draw_earthshine(
                    stream(plan.seed, STREAM_PT_LIGHT, plan.index), self.config.cycles_light
                )
                towards = np.asarray(sky.earth[:3], dtype=np.float64)
                earthshine = (towards, level * light.sun_strength)
            query = self._cycles.render(
                T_true,
                light.sun_direction,
                light.sun_strength,
                bodies,
                extras,
                view_transform=view_transform,
                exposure_ev=exposure_ev,
                earthshine=earthshine,
            )
            if view_transform is not None:
                extra["view_transform"] = view_transform
            extra["exposure_ev"] = round(exposure_ev, 4)
            if earthshine is not None:
                extra["earthshine"] = round(earthshine[1], 5)
        if self.config.hard_kinds and extras:
            # Measured on the clean query: the camera's noise would make space "visible".
            background = self._query.render(
                T_true, light.sun_direction, light.sun_strength, bodies, labels=True
            ).labels
            extra.update(kind_columns(plan.anomaly, result.labels, background, query))
        sun = find_sun(result, sky.sun[:3], T_true, float(sky.sun[3]))
        # Drawn even when not applied: the pose error below comes from the same stream.
        image, effects = apply_camera(query, rng, realism, sun, light.sun_strength, self.look)
        if not self.config.camera_effects:
            image = query
        if self.config.jpeg_quality:
            image = jpeg_round_trip(image, self.config.jpeg_quality)
        T_reported = pose_error(T_true, rng, self.config.pose_error_m, self.config.pose_error_rad)
        reference = None
        if self.config.references:
            low = self._low.render(T_reported, sky.sun_direction, plan.sun_strength, bodies)
            reference = resize_to(low.rgb, self.intrinsics)
        extra.update(_pose_columns("true", T_true))
        if self.config.camera_effects:
            extra.update(
                {
                    "exposure": round(effects.exposure, 6),
                    "noise_gain": round(effects.noise_gain, 6),
                    "white_balance_r": round(effects.white_balance[0], 6),
                    "white_balance_b": round(effects.white_balance[1], 6),
                }
            )
        extra.update(
            {
                "query_sun_strength": round(light.sun_strength, 6),
                "query_sun_angle_deg": round(light.angle_deg, 4),
            }
        )
        if self.config.camera_effects:
            extra.update(
                {
                    "tone_contrast": round(self.look.tone_contrast, 4),
                    "saturation": round(self.look.saturation, 4),
                }
            )
        extra["sun_in_view"] = 0.0 if sun is None else round(sun.visible, 4)
        if self._cycles is not None:
            extra["query_renderer"] = "cycles"
        return image, reference, T_reported

    def _development(self, plan: FramePlan) -> tuple[str | None, float]:
        # Its own stream, so adding it leaves every other draw of a sequence unchanged.
        rng = stream(plan.seed, STREAM_DEVELOP, plan.index)
        transforms = self.config.cycles_view_transforms
        view_transform = transforms[int(rng.integers(len(transforms)))] if transforms else None
        low, high = self.config.cycles_exposure_ev
        return view_transform, float(rng.uniform(low, high)) if high > low else low

    def _camera(self, base: BasePose, rng: np.random.Generator) -> np.ndarray:
        """A perturbed camera pose that is clear of the station."""
        for _ in range(_CLEAR_ATTEMPTS):
            T = perturb(
                base.T_station_camera,
                rng,
                self.config.position_sigma_m,
                self.config.rotation_sigma_rad,
            )
            if clear_camera(self.occupancy, T):
                return T
        raise SynthError(f"base pose {base.pose_id}: every perturbed camera is in the station")

    def _depth_order(self, requested: float) -> list[float]:
        # The requested depth first, then the others by distance from it, nearer first:
        # a small object too small at +2 m is re-placed at +1 m, not at -2 m.
        return sorted(self.config.depths_m, key=lambda d: (abs(d - requested), d))

    def _place(
        self,
        plan: FramePlan,
        base: BasePose,
        sky: Sky,
        light: QueryLight,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, RenderResult, dict[str, object], list[ExtraObject]]:
        config = self.config
        need = math.ceil(config.min_anomaly_fraction * config.width * config.height)
        bodies = sky.bodies()
        tries = 0
        reasons: dict[str, int] = {}
        # A scale variant too small to be seen is placed at the next larger scale, finally 1.
        scales = [plan.scale, *sorted(s for s in {*config.scales, 1.0} if s > plan.scale)]
        dark = plan.anomaly in config.dark_background_types
        # The darkest valid placement of a dark-background type, kept if none is dark enough;
        # for a hard kind, the placement nearest what its kind needs.
        darkest: tuple[float, tuple] | None = None
        for scale in scales:
            obj = build_anomaly(plan.anomaly, plan.object_seed, plan.colour, scale)
            if self._area_bound(obj) < need:
                reasons["scale"] = reasons.get("scale", 0) + 1
                continue
            wear = stream(plan.seed, STREAM_WEAR, plan.index)
            scene = obj.scene
            if config.hard_kinds and plan.anomaly in STATION_COLOURED_TYPES:
                paint = stream(plan.seed, STREAM_PT_KIND, plan.index)
                scene = paint_like_station(scene, self._palette, paint)
            worn = worn_object(scene, wear, config.realism)
            for depth in self._depth_order(plan.depth_m):
                for _ in range(config.camera_attempts):
                    T = self._camera(base, rng)
                    for _ in range(config.max_retries):
                        tries += 1
                        pose = placement.propose(
                            T, rng, config.object_distance_m, config.box_half_width_m, depth
                        )
                        candidate = placement.check(
                            obj,
                            pose,
                            T,
                            self.intrinsics,
                            self.occupancy,
                            config.max_occluded_fraction,
                            depth,
                        )
                        reason = candidate.rejected or self._too_small(obj, pose, T, sky, need)
                        if not reason:
                            extras = [ExtraObject(worn, pose, LABEL_ANOMALY, plan.anomaly)]
                            result = self._query.render(
                                T,
                                light.sun_direction,
                                light.sun_strength,
                                bodies,
                                extras,
                                labels=True,
                            )
                            pixels = int(np.count_nonzero(result.labels == LABEL_ANOMALY))
                            if pixels >= need:
                                extra = self._anomaly_extra(plan, obj, candidate, pixels, tries)
                                chosen = (T, result, extra, extras)
                                rank, reason = self._judge(plan.anomaly, chosen, dark, light)
                                if not reason:
                                    return chosen
                                if darkest is None or rank < darkest[0]:
                                    darkest = (rank, chosen)
                            else:
                                reason = "small"
                        reasons[reason] = reasons.get(reason, 0) + 1
            if darkest is not None:
                return darkest[1]
        raise SynthError(
            f"frame {plan.index} ({plan.anomaly}, camera {plan.split}/{plan.camera}): no "
            f"placement met the rules in {tries} tries ({reasons})"
        )

    def _judge(
        self, anomaly: str, chosen: tuple, dark: bool, light: QueryLight
    ) -> tuple[float, str]:
        """Rank (lower is better) of a visible placement and why it is not kept ('' keeps
        it): a dark-background type wants a dark ring, a hard kind what its kind needs."""
        T, result, extra, _ = chosen
        if self.config.hard_kinds:
            background = self._query.render(
                T, light.sun_direction, light.sun_strength, (), labels=True
            ).labels
            mask = result.labels == LABEL_ANOMALY
            penalty = placement_penalty(anomaly, mask, background)
            return penalty, "" if penalty <= 0 else "kind"
        if not dark:
            return 0.0, ""
        level = background_level(result.rgb, result.labels)
        if math.isfinite(level):
            extra["background_level"] = round(level, 4)
        return level, "" if level <= self.config.dark_background_level else "bright"

    def _area_bound(self, obj: AnomalyObject) -> float:
        """Upper bound of the object's image area (pixels) at the nearest placement."""
        config = self.config
        nearest = config.object_distance_m + min(config.depths_m)
        nearest = max(0.5, nearest - math.sqrt(3.0) * config.box_half_width_m)
        largest = np.sort(obj.extents)[::-1]
        return float(largest[0] * largest[1] * (self.intrinsics.fx / nearest) ** 2)

    def _too_small(
        self, obj: AnomalyObject, pose: np.ndarray, T: np.ndarray, sky: Sky, need: int
    ) -> str:
        """Quick low-resolution estimate of the visible area; '' if it may be enough."""
        if not self._check:
            return ""
        low = self._low
        result = low.render(
            T, sky.sun_direction, 1.0, (), [ExtraObject(obj.scene, pose)], labels=True
        )
        scale2 = (low.output_intrinsics.width * low.output_intrinsics.height) / (
            self.intrinsics.width * self.intrinsics.height
        )
        pixels = np.count_nonzero(result.labels == LABEL_ANOMALY)
        return "" if pixels >= _CHECK_MARGIN * need * scale2 else "small"

    @staticmethod
    def _anomaly_extra(
        plan: FramePlan,
        obj: AnomalyObject,
        candidate: placement.Candidate,
        pixels: int,
        tries: int,
    ) -> dict[str, object]:
        extra: dict[str, object] = {
            "object_seed": obj.seed,
            "colour": obj.colour,
            "scale": obj.scale,
            "requested_scale": plan.scale,
            "depth_m": candidate.depth_m,
            "requested_depth_m": plan.depth_m,
            "anomaly_pixels": pixels,
            "occluded_fraction": round(candidate.occluded_fraction, 4),
            "placement_tries": tries,
        }
        extra.update(_pose_columns("obj", candidate.pose))
        return extra
