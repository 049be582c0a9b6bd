"""Generator settings: :class:`SynthConfig`, its parts, the presets and :class:`SynthError`.

Every number that shapes a generated sequence lives here, validated once, so the generator
itself can trust its inputs. Defaults follow ALLO's pipeline where it states a value (see the
project's ALLO notes): 1 m / 0.2 rad pose perturbation, a 1.2 m half-width placement box 4 m
in front of the camera, depths 0, +-1, +-2 m, up to 10 retries, relative Sun strengths 0.1,
0.5 and 1 (ALLO's 1, 5 and 10).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType

from allo_mrad_ros.errors import lookup
from allo_mrad_ros.sequence import SPLITS
from allo_mrad_ros.synth.cycles_light import CyclesLightConfig
from allo_mrad_ros.synth.realism_config import RealismConfig
from allo_mrad_ros.synth.trajectory_config import TrajectoryConfig
from allo_mrad_ros.synth.validation import SynthError, finite_number, integer_at_least, number_pair

__all__ = [
    "PRESETS",
    "QUERY_RENDERERS",
    "CyclesLightConfig",
    "RealismConfig",
    "SplitSpec",
    "SynthConfig",
    "SynthError",
    "TrajectoryConfig",
    "preset",
]


@dataclass(frozen=True)
class SplitSpec:
    """Frames and camera base poses of one split.

    Parameters
    ----------
    normal, anomalous : int
        Number of normal and anomalous frames (ALLO's train split is normal only).
    cameras : int
        Number of camera base poses (``Camera<N>`` folders); at least one.
    """

    normal: int
    anomalous: int
    cameras: int

    def __post_init__(self) -> None:
        integer_at_least(self.normal, "normal")
        integer_at_least(self.anomalous, "anomalous")
        integer_at_least(self.cameras, "cameras", 1)
        if self.normal + self.anomalous == 0:
            raise SynthError("a split needs at least one frame")

    @property
    def frames(self) -> int:
        """Total number of frames."""
        return self.normal + self.anomalous


DEFAULT_DEPTHS_M = (0.0, -1.0, 1.0, -2.0, 2.0)
DEFAULT_SUN_STRENGTHS = (0.1, 0.5, 1.0)
DEFAULT_SUN_WEIGHTS = (0.2, 0.3, 0.5)
QUERY_RENDERERS = ("pyrender", "cycles")
VIEW_TRANSFORMS = ("AgX", "Filmic", "Standard", "Khronos PBR Neutral")
"""Blender view transforms a Cycles query may be developed with."""
"""Renderers of the query: the rasteriser the references use, or Blender Cycles (optional)."""


@dataclass(frozen=True)
class SynthConfig:
    """Everything that defines a generated sequence, apart from the seed and the mesh.

    Parameters
    ----------
    name : str
        Sequence name (``sequence.yaml``) and preset name.
    splits : Mapping[str, SplitSpec]
        Frames per split (``train``, ``val``, ``test``); written in that order.
    width, height : int
        Image size. The camera keeps ALLO's field of view (25 mm lens, 36 mm sensor).
    position_sigma_m, rotation_sigma_rad : float
        Per-frame Gaussian perturbation of the base pose (position per axis, and each of
        ALLO's Blender XYZ Euler angles).
    pose_error_m, pose_error_rad : float
        Standard deviation of the error of the pose written to ``frames.csv`` (the pose the
        robot reports) against the pose the query was rendered from (kept in the ``true_*``
        columns); per axis. 0 writes exact poses.
    object_distance_m, box_half_width_m : float
        ALLO's placement box: half-width around a point this far in front of the camera.
    depths_m : tuple of float
        Offsets along the viewing axis; anomalous frames cycle through them.
    max_retries : int
        Placement tries per camera pose before the camera pose is drawn again.
    camera_attempts : int
        Camera poses drawn per depth before falling back to the next nearer depth.
    min_anomaly_fraction : float
        Smallest visible anomaly, as a fraction of the image (ALLO: 0.1 %).
    max_occluded_fraction : float
        Largest fraction of the anomaly's surface samples hidden by the station.
    sun_strengths, sun_weights : tuple of float
        Relative Sun strengths and their probabilities.
    colour_probability : float
        Probability that an anomalous frame recolours its object (ALLO's colour variant).
    scale_probability : float
        Probability that an anomalous frame scales its object (ALLO's scale variant).
    scales : tuple of float
        The scale factors of that variant (ALLO: 0.3, 0.5, 0.7). A scaled object that
        cannot be placed visibly is placed at the next larger scale, finally at 1.
    anomaly_types : tuple of str or None
        Object types to use; None for the default set (:data:`~.objects.ANOMALY_TYPES`;
        opt-in types such as ``dark_visor`` are drawn only when named).
    dark_background_types : tuple of str
        Object types placed only against a dark part of the station: a placement is kept
        when the ring of pixels around the object's silhouette is mostly station and its
        mean luminance is at most ``dark_background_level``; when no try meets that, the
        darkest valid placement is kept. Empty (the default) leaves placement as ALLO's.
    dark_background_level : float
        Largest mean luminance (0..1, display values of the rendered query before the
        camera model) of that ring.
    camera_distance_m : tuple of float
        Range of base-pose distances from the point of the station looked at.
    min_camera_clearance_m : float
        Smallest distance of a base pose from the station's surface.
    days : tuple of int
        First and last day of 2030 to draw from.
    references : bool
        Also write pre-rendered references (nominal model, reported pose, nominal light).
    reference_scale : float
        Render scale of the references; they are resized to the image size to be written.
    shadows : bool
        Directional shadows from the Sun in the query.
    realism : RealismConfig
        The query's departures from the model.
    query_renderer : str
        ``"pyrender"`` (the rasteriser the references are made with) or ``"cycles"``
        (Blender's path tracer, :mod:`~.cycles`; needs the optional ``bpy``). Masks,
        placement and references are rasterised either way.
    camera_effects : bool
        Apply :func:`~.realism.apply_camera` to the query (when realism is enabled). False
        writes the renderer's own output, e.g. Cycles' view transform without our camera
        model on top; the per-frame draws are made either way, so poses and objects match.
    cycles_samples : int
        Path-tracing samples per pixel of the Cycles query (denoised).
    cycles_view_transforms : tuple of str
        Blender view transforms the Cycles query draws one of per frame (e.g. ``AgX``,
        ``Filmic``, ``Standard``); empty keeps Blender's default.
    cycles_exposure_ev : tuple of float
        Range of the Cycles view's exposure, stops, drawn uniformly per frame.
    jpeg_quality : int
        0 keeps the query lossless; 1-100 passes it through a JPEG encoder of that quality
        before it is written (a camera that streams JPEG).
    rate_hz : float
        Nominal frame rate for the stamps.
    png_compression : int
        zlib level of the written PNGs.
    cycles_light : CyclesLightConfig or None
        Materials and lamps of the Cycles query that depart from the reference's
        (:mod:`~.cycles_light`); None keeps the reference's.
    hard_kinds : bool
        Place the hard object kinds as their kind needs (thin cables 1-4 px wide, small
        objects at most 100 px, station-coloured ones against the station) and write each
        anomalous frame's ``kind`` and visibility columns (:mod:`~.hard_kinds`).
    trajectory : TrajectoryConfig or None
        None: ALLO's frames, each from its own perturbed base pose. Set: arm trajectories
        (:mod:`~.trajectories`), each split's ``anomalous`` count being its number of
        trajectories past objects and ``normal`` its anomaly-free ones; written in format
        version 2 (objects table and instance masks).
    """

    name: str
    splits: Mapping[str, SplitSpec]
    width: int = 1920
    height: int = 1080
    position_sigma_m: float = 1.0
    rotation_sigma_rad: float = 0.2
    pose_error_m: float = 0.02
    pose_error_rad: float = math.radians(0.2)
    object_distance_m: float = 4.0
    box_half_width_m: float = 1.2
    depths_m: tuple[float, ...] = DEFAULT_DEPTHS_M
    max_retries: int = 10
    camera_attempts: int = 5
    min_anomaly_fraction: float = 0.001
    max_occluded_fraction: float = 0.5
    sun_strengths: tuple[float, ...] = DEFAULT_SUN_STRENGTHS
    sun_weights: tuple[float, ...] = DEFAULT_SUN_WEIGHTS
    colour_probability: float = 0.2
    scale_probability: float = 0.2
    scales: tuple[float, ...] = (0.3, 0.5, 0.7)
    anomaly_types: tuple[str, ...] | None = None
    dark_background_types: tuple[str, ...] = ()
    dark_background_level: float = 0.12
    camera_distance_m: tuple[float, float] = (12.0, 30.0)
    min_camera_clearance_m: float = 7.0
    days: tuple[int, int] = (1, 365)
    references: bool = False
    reference_scale: float = 0.25
    shadows: bool = True
    realism: RealismConfig = field(default_factory=RealismConfig)
    query_renderer: str = "pyrender"
    camera_effects: bool = True
    cycles_samples: int = 32
    cycles_view_transforms: tuple[str, ...] = ()
    cycles_exposure_ev: tuple[float, float] = (0.0, 0.0)
    jpeg_quality: int = 0
    rate_hz: float = 10.0
    png_compression: int = 3
    cycles_light: CyclesLightConfig | None = None
    hard_kinds: bool = False
    trajectory: TrajectoryConfig | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SynthError(f"name must be non-empty text, got {self.name!r}")
        if not isinstance(self.splits, Mapping) or not self.splits:
            raise SynthError("splits must map at least one split name to a SplitSpec")
        for split, spec in self.splits.items():
            if split not in SPLITS:
                raise SynthError(f"unknown split {split!r}; use {', '.join(SPLITS)}")
            if not isinstance(spec, SplitSpec):
                raise SynthError(f"split {split!r} must be a SplitSpec, got {spec!r}")
        # A plain dict (in split order) keeps the settings picklable for worker processes.
        ordered = {s: self.splits[s] for s in SPLITS if s in self.splits}
        object.__setattr__(self, "splits", ordered)
        integer_at_least(self.width, "width", 16)
        integer_at_least(self.height, "height", 16)
        if self.width > 8192 or self.height > 8192:
            raise SynthError(f"image size {self.width}x{self.height} is above 8192")
        finite_number(self.position_sigma_m, "position_sigma_m", 0.0, 10.0)
        finite_number(self.rotation_sigma_rad, "rotation_sigma_rad", 0.0, math.pi)
        finite_number(self.pose_error_m, "pose_error_m", 0.0, 1.0)
        finite_number(self.pose_error_rad, "pose_error_rad", 0.0, 0.2)
        finite_number(self.object_distance_m, "object_distance_m", 0.5, 100.0)
        finite_number(self.box_half_width_m, "box_half_width_m", 0.0, 10.0)
        if not isinstance(self.depths_m, tuple) or not self.depths_m:
            raise SynthError(f"depths_m must be a non-empty tuple, got {self.depths_m!r}")
        for depth in self.depths_m:
            finite_number(depth, "depths_m", -self.object_distance_m + 0.5)
        integer_at_least(self.max_retries, "max_retries", 1)
        integer_at_least(self.camera_attempts, "camera_attempts", 1)
        finite_number(self.min_anomaly_fraction, "min_anomaly_fraction", 0.0, 0.5)
        finite_number(self.max_occluded_fraction, "max_occluded_fraction", 0.0, 1.0)
        self._check_sun()
        finite_number(self.colour_probability, "colour_probability", 0.0, 1.0)
        finite_number(self.scale_probability, "scale_probability", 0.0, 1.0)
        if not isinstance(self.scales, tuple) or not self.scales:
            raise SynthError(f"scales must be a non-empty tuple, got {self.scales!r}")
        for scale in self.scales:
            finite_number(scale, "scales", 0.05, 1.0)
        if self.anomaly_types is not None:
            from allo_mrad_ros.synth.objects import KNOWN_TYPES

            if not isinstance(self.anomaly_types, tuple) or not self.anomaly_types:
                raise SynthError("anomaly_types must be a non-empty tuple or None")
            unknown = [t for t in self.anomaly_types if t not in KNOWN_TYPES]
            if unknown:
                raise SynthError(
                    f"unknown anomaly types {unknown}; known: {', '.join(KNOWN_TYPES)}"
                )
        self._check_dark_background()
        object.__setattr__(
            self, "camera_distance_m", number_pair(self.camera_distance_m, "camera_distance_m", 1.0)
        )
        finite_number(self.min_camera_clearance_m, "min_camera_clearance_m", 0.5, 100.0)
        if (
            not isinstance(self.days, tuple)
            or len(self.days) != 2
            or not all(isinstance(d, int) and not isinstance(d, bool) for d in self.days)
            or not 1 <= self.days[0] <= self.days[1] <= 365
        ):
            raise SynthError(f"days must be (first, last) within 1..365, got {self.days!r}")
        if not isinstance(self.references, bool) or not isinstance(self.shadows, bool):
            raise SynthError("references and shadows must be bools")
        finite_number(self.reference_scale, "reference_scale", 0.05, 1.0)
        if not isinstance(self.realism, RealismConfig):
            raise SynthError(f"realism must be a RealismConfig, got {self.realism!r}")
        if self.query_renderer not in QUERY_RENDERERS:
            raise SynthError(
                f"query_renderer must be one of {', '.join(QUERY_RENDERERS)}, "
                f"got {self.query_renderer!r}"
            )
        if not isinstance(self.camera_effects, bool):
            raise SynthError(f"camera_effects must be a bool, got {self.camera_effects!r}")
        integer_at_least(self.cycles_samples, "cycles_samples", 1)
        if not isinstance(self.cycles_view_transforms, tuple) or not all(
            isinstance(name, str) and name in VIEW_TRANSFORMS
            for name in self.cycles_view_transforms
        ):
            raise SynthError(
                f"cycles_view_transforms must be a tuple of {', '.join(VIEW_TRANSFORMS)}, "
                f"got {self.cycles_view_transforms!r}"
            )
        low_ev, high_ev = number_pair(self.cycles_exposure_ev, "cycles_exposure_ev", -10.0)
        if high_ev > 10.0:
            raise SynthError(f"cycles_exposure_ev must lie in [-10, 10], got {(low_ev, high_ev)}")
        if isinstance(self.jpeg_quality, bool) or self.jpeg_quality not in range(101):
            raise SynthError(f"jpeg_quality must be 0-100, got {self.jpeg_quality!r}")
        finite_number(self.rate_hz, "rate_hz", 1e-3, 1e4)
        if isinstance(self.png_compression, bool) or self.png_compression not in range(10):
            raise SynthError(f"png_compression must be 0-9, got {self.png_compression!r}")
        if self.cycles_light is not None and not isinstance(self.cycles_light, CyclesLightConfig):
            raise SynthError(f"cycles_light must be a CyclesLightConfig, got {self.cycles_light!r}")
        if not isinstance(self.hard_kinds, bool):
            raise SynthError(f"hard_kinds must be a bool, got {self.hard_kinds!r}")
        if self.trajectory is not None:
            if not isinstance(self.trajectory, TrajectoryConfig):
                raise SynthError(f"trajectory must be a TrajectoryConfig, got {self.trajectory!r}")
            for split, spec in self.splits.items():
                if spec.cameras != spec.frames:
                    raise SynthError(
                        f"split {split!r}: a trajectory sequence has one camera (start pose) "
                        f"per trajectory: cameras must be {spec.frames}, got {spec.cameras}"
                    )

    def _check_dark_background(self) -> None:
        from allo_mrad_ros.synth.objects import KNOWN_TYPES

        types = self.dark_background_types
        if not isinstance(types, tuple) or not all(isinstance(t, str) for t in types):
            raise SynthError(f"dark_background_types must be a tuple of names, got {types!r}")
        unknown = [t for t in types if t not in KNOWN_TYPES]
        if unknown:
            raise SynthError(
                f"unknown dark_background_types {unknown}; known: {', '.join(KNOWN_TYPES)}"
            )
        finite_number(self.dark_background_level, "dark_background_level", 0.0, 1.0)

    def _check_sun(self) -> None:
        strengths, weights = self.sun_strengths, self.sun_weights
        if not isinstance(strengths, tuple) or not strengths:
            raise SynthError("sun_strengths must be a non-empty tuple")
        if not isinstance(weights, tuple) or len(weights) != len(strengths):
            raise SynthError("sun_weights must be a tuple as long as sun_strengths")
        for value in strengths:
            finite_number(value, "sun_strengths", 0.0, 100.0)
        for value in weights:
            finite_number(value, "sun_weights", 0.0)
        if sum(weights) <= 0:
            raise SynthError("sun_weights must not all be zero")

    @property
    def frames(self) -> int:
        """Total number of frames over all splits."""
        count = sum(spec.frames for spec in self.splits.values())
        return count * self.trajectory.frames if self.trajectory is not None else count

    def with_overrides(self, **changes: object) -> SynthConfig:
        """Return a copy with some fields replaced (validated again); None values are ignored."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise SynthError(f"unknown settings {unknown}")
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def with_frames(self, frames: int) -> SynthConfig:
        """Return a copy whose splits are scaled to about ``frames`` frames in total.

        Every split keeps its share and its normal/anomalous ratio, with at least one frame.
        A trajectory configuration keeps its trajectories and scales their length instead
        (at least two frames each).
        """
        integer_at_least(frames, "frames", 1)
        if self.trajectory is not None:
            count = sum(spec.frames for spec in self.splits.values())
            length = max(2, round(frames / count))
            return replace(self, trajectory=replace(self.trajectory, frames=length))
        total = self.frames
        splits = {}
        for split, spec in self.splits.items():
            share = max(1, round(frames * spec.frames / total))
            anomalous = round(share * spec.anomalous / spec.frames)
            splits[split] = SplitSpec(share - anomalous, anomalous, spec.cameras)
        return replace(self, splits=splits)


def _smoke() -> SynthConfig:
    return SynthConfig(
        name="smoke",
        splits={"train": SplitSpec(2, 0, 2), "test": SplitSpec(2, 4, 2)},
        width=240,
        height=135,
        references=True,
        reference_scale=0.5,
        shadows=False,
    )


def _demo() -> SynthConfig:
    return SynthConfig(name="demo", splits={"test": SplitSpec(14, 26, 4)})


def _bench() -> SynthConfig:
    # ALLO's ratio: about two anomalous test frames per normal one; train is normal only.
    return SynthConfig(
        name="bench",
        splits={
            "train": SplitSpec(120, 0, 40),
            "val": SplitSpec(20, 40, 10),
            "test": SplitSpec(110, 220, 10),
        },
    )


def _bench_val() -> SynthConfig:
    # A validation split as large as bench's test, for choosing defaults: generate it with a
    # seed other than the bench sequence's, so it shares no frame plan with that test split.
    return SynthConfig(name="bench-val", splits={"val": SplitSpec(110, 220, 10)})


def _bench_cycles() -> SynthConfig:
    # A path-traced test split: every object type twice, ALLO's 2:1 anomalous ratio, small
    # frames (Cycles on 2 CPU cores), the renderer's own view transform as the only camera.
    return SynthConfig(
        name="bench-cycles",
        splits={"test": SplitSpec(16, 32, 8)},
        width=640,
        height=360,
        query_renderer="cycles",
        camera_effects=False,
    )


def _bench_stations() -> SynthConfig:
    # One station's share of the multi-station path-traced bench (``make bench-stations``
    # generates it once per station model): bench-cycles' frames with more variation, Cycles
    # queries developed under several view transforms and exposures from -1 to +1.5 stops
    # (bright parts clip: glare), JPEG as a camera streams it, 4:3 frames, a larger pose
    # error than the rasterised bench; anomalies recoloured and scaled as ALLO does.
    return _bench_cycles().with_overrides(
        name="bench-stations",
        splits={"test": SplitSpec(8, 16, 4)},
        width=512,
        height=384,
        cycles_samples=16,
        cycles_view_transforms=("AgX", "Filmic", "Standard"),
        cycles_exposure_ev=(-1.0, 1.5),
        jpeg_quality=85,
        pose_error_m=0.03,
        pose_error_rad=math.radians(0.3),
        colour_probability=0.3,
        scale_probability=0.3,
    )


PT_TYPES = (
    "thin_cable",
    "black_foil",
    "dark_visor",
    "small_debris",
    "station_patch",
    "blanket_curved",
)
"""Object types of the path-traced bench: the hard kinds and one ordinary type."""


def _bench_pt() -> SynthConfig:
    # One station's share of the extended path-traced bench (``make bench-pt``): the
    # bench-stations frames with queries that share neither the reference's materials
    # (roughness and specular strength moved per material) nor its lamps (Earth-shine, an
    # area light for the spot lamp; the Sun a 0.53 degree disc), developed by a view
    # transform and then by a camera response of our own (tone curve, white balance error,
    # vignetting, noise); the hard object kinds placed as their kind needs, unscaled and
    # in their own colours, down to 30 px.
    return _bench_stations().with_overrides(
        name="bench-pt",
        anomaly_types=PT_TYPES,
        colour_probability=0.0,
        scale_probability=0.0,
        min_anomaly_fraction=0.00015,
        camera_effects=True,
        realism=RealismConfig(
            white_balance_sigma=0.06,
            vignetting=0.25,
            tone_contrast=(1.2, 1.6),
            noise_gain=(1.0, 2.0),
        ),
        cycles_light=CyclesLightConfig(),
        hard_kinds=True,
    )


def _bench_dark() -> SynthConfig:
    # Dark glossy objects against dark station parts: the dark visor alone, kept dark (no
    # colour variant), placed where the station around it is dark, under a Sun weighted to
    # its weaker strengths; a validation split to choose on and a test split to report.
    return SynthConfig(
        name="bench-dark",
        splits={"val": SplitSpec(8, 24, 6), "test": SplitSpec(8, 24, 6)},
        anomaly_types=("dark_visor",),
        dark_background_types=("dark_visor",),
        colour_probability=0.0,
        sun_weights=(0.4, 0.3, 0.3),
    )


def _objects() -> SynthConfig:
    # Arm trajectories at 10 Hz past objects, with anomaly-free ones (glare, Earth or Moon,
    # moving shadows) between: a validation split to choose parameters on and a test split.
    # Cameras start 8-20 m from the station (an arm's reach around a module, not ALLO's
    # 12-30 m survey), closer to the hull than ALLO's base poses allow.
    return SynthConfig(
        name="objects",
        splits={"val": SplitSpec(3, 6, 9), "test": SplitSpec(3, 6, 9)},
        width=960,
        height=540,
        camera_distance_m=(8.0, 20.0),
        min_camera_clearance_m=4.0,
        trajectory=TrajectoryConfig(frames=80),
    )


def _objects_pt() -> SynthConfig:
    # The objects trajectories with the extended path-traced bench's queries (Cycles; the
    # query's own roughness, specular strength, Earth-shine, area lamp and a Sun disc; a view
    # transform and a camera response of our own), for another station model (``--mesh``): a
    # test split only, with the trajectories of ``objects`` (80 frames at 10 Hz) at 640x360,
    # so that it renders in under an hour on two cores. Nothing is chosen on it.
    pt = _bench_pt()
    return _objects().with_overrides(
        name="objects-pt",
        splits={"test": SplitSpec(2, 4, 6)},
        width=640,
        height=360,
        query_renderer="cycles",
        cycles_samples=pt.cycles_samples,
        cycles_view_transforms=pt.cycles_view_transforms,
        cycles_exposure_ev=pt.cycles_exposure_ev,
        jpeg_quality=pt.jpeg_quality,
        camera_effects=True,
        realism=pt.realism,
        cycles_light=pt.cycles_light,
    )


def _objects_normal() -> SynthConfig:
    # Anomaly-free trajectories only: false objects per minute, glare, bodies and shadows.
    return _objects().with_overrides(
        name="objects-normal",
        splits={"val": SplitSpec(6, 0, 6), "test": SplitSpec(6, 0, 6)},
    )


PRESETS = MappingProxyType(
    {
        "smoke": _smoke,
        "demo": _demo,
        "bench": _bench,
        "bench-val": _bench_val,
        "bench-cycles": _bench_cycles,
        "bench-stations": _bench_stations,
        "bench-pt": _bench_pt,
        "bench-dark": _bench_dark,
        "objects": _objects,
        "objects-normal": _objects_normal,
        "objects-pt": _objects_pt,
    }
)
"""Preset name to a function returning its :class:`SynthConfig`."""


def preset(name: str) -> SynthConfig:
    """Return the configuration of a preset.

    Parameters
    ----------
    name : str
        ``smoke`` (tiny images, 10 frames: for tests), ``demo`` (40 frames at 1920x1080,
        test split), ``bench`` (train 120, val 60, test 330 at 1920x1080) or ``bench-val``
        (val 330 at 1920x1080: the selection split of ``make bench``, generated with seed 1)
        or ``bench-cycles`` (test 48 at 640x360, queries path-traced by Blender Cycles
        without our camera model; needs the optional bpy, ``make bench-cycles``) or
        ``bench-pt`` (test 24 at 512x384, one station's share of ``make bench-pt``: Cycles
        queries with their own materials, lamps and camera response, the hard object
        kinds) or
        ``bench-dark`` (val 32 and test 32 at 1920x1080: the opt-in dark visor against
        dark station parts) or ``objects`` (arm trajectories at 960x540 and 10 Hz, 80
        frames each: per split 6 past objects and 3 anomaly-free) or ``objects-normal``
        (6 anomaly-free trajectories per split) or ``objects-pt`` (test: 4 past objects and
        2 anomaly-free, 640x360, with ``bench-pt``'s Cycles queries; for another station
        model, ``--mesh``; needs the optional bpy).

    Returns
    -------
    SynthConfig
        A fresh configuration.

    Raises
    ------
    SynthError
        For an unknown name.
    """
    return lookup(PRESETS, name, what="preset", error=SynthError)()
