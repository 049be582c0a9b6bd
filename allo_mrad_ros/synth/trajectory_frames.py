"""Rendering arm trajectories: the plan of every trajectory, its path and objects, its frames.

:func:`plan_trajectories` decides, from the seed alone, the trajectories of every split (scene,
day, Sun strength, object types, stamps). :func:`setup_trajectory` settles what needs the
station model (the path clear of the station, where each object goes), again from the seed
alone, so a worker process that renders some of a trajectory's frames finds the same path and
objects as the process that writes the objects table. :class:`TrajectorySynthesizer` renders
one frame: the query with every object of its trajectory at its place at the frame's time, the
class mask and the instance mask.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.ephemeris import Sky
from allo_mrad_ros.render import LABEL_ANOMALY, ExtraObject
from allo_mrad_ros.sequence import GroundTruthObject
from allo_mrad_ros.synth.config import SynthConfig, SynthError
from allo_mrad_ros.synth.frames import FrameSynthesizer
from allo_mrad_ros.synth.lighting import query_light
from allo_mrad_ros.synth.objects import ANOMALY_TYPES, DEFAULT_COLOUR, build_anomaly
from allo_mrad_ros.synth.occupancy import StationOccupancy
from allo_mrad_ros.synth.planning import (
    STREAM_FRAME,
    STREAM_LIGHT,
    STREAM_PLAN,
    STREAM_WEAR,
    balanced,
    stream,
)
from allo_mrad_ros.synth.poses import MIN_FRAME_CLEARANCE_M, BasePose
from allo_mrad_ros.synth.surfaces import worn_object
from allo_mrad_ros.synth.trajectories import (
    OBJECT_SCENE,
    STREAM_TRAJECTORY,
    TRAJECTORY_LIGHT_OFFSET,
    exit_after,
    first_hit,
    make_sweep,
    path_clear,
    plan_scenes,
    speeds,
    turned_towards,
)

# Draws of a path (then of an object's place) before a trajectory is given up on.
_PATH_ATTEMPTS = 30
_PLACE_ATTEMPTS = 40
# How far an object keeps from the station's hull and from the camera's path.
_HULL_MARGIN_M = 0.15
_CAMERA_MARGIN_M = 1.5
# The farthest a ray is followed into the station, metres.
_RAY_RANGE_M = 120.0
OBJECT_NAME = "object"
"""Prefix of an object's name in the renderer's instance names (``object<id>``)."""


@dataclass(frozen=True)
class TrajectoryPlan:
    """What one trajectory shows, decided from the seed.

    Attributes
    ----------
    ordinal : int
        Position among all trajectories of the sequence.
    split : str
        Its split.
    number : int
        Its index within the split: the ``Camera<N>`` folder and the base pose it starts at.
    scene : str
        ``objects``, ``glare``, ``bodies`` or ``shadows``.
    day : int
        Day of 2030 (Sun, Earth, Moon).
    sun_strength : float
        Relative Sun strength.
    types : tuple of str
        Object types (``objects`` trajectories), one per object.
    first_id : int
        Id of its first object; the others follow.
    start_ns : int
        Stamp of its first frame.
    seed : int
        Sequence seed.
    """

    ordinal: int
    split: str
    number: int
    scene: str
    day: int
    sun_strength: float
    types: tuple[str, ...]
    first_id: int
    start_ns: int
    seed: int


@dataclass(frozen=True)
class TrajectoryFramePlan:
    """One frame of a trajectory: ``index`` in the sequence, ``step`` in the trajectory."""

    index: int
    step: int
    stamp_ns: int
    trajectory: TrajectoryPlan

    @property
    def seed(self) -> int:
        """Sequence seed."""
        return self.trajectory.seed

    @property
    def sun_strength(self) -> float:
        """Relative Sun strength of the trajectory."""
        return self.trajectory.sun_strength

    @property
    def split(self) -> str:
        """The trajectory's split."""
        return self.trajectory.split

    @property
    def name(self) -> str:
        """Image file stem: frame index, trajectory and step."""
        return f"{self.index:06d}_t{self.trajectory.ordinal:03d}_{self.step:04d}"


def plan_trajectories(
    config: SynthConfig, seed: int, start_ns: int
) -> tuple[list[TrajectoryPlan], list[TrajectoryFramePlan]]:
    """Plan every trajectory and frame of a trajectory sequence.

    A split's ``anomalous`` count is its number of ``objects`` trajectories, ``normal`` its
    number of anomaly-free ones. Object types are balanced over the split's objects.

    Returns
    -------
    tuple
        The trajectories and the frames, in playback order.
    """
    settings = config.trajectory
    rng = stream(seed, STREAM_PLAN)
    types = config.anomaly_types or tuple(ANOMALY_TYPES)
    weights = np.asarray(config.sun_weights, dtype=np.float64)
    weights = weights / weights.sum()
    period_ns = max(1, round(1e9 / config.rate_hz))
    gap_ns = round(settings.gap_s * 1e9)
    trajectories: list[TrajectoryPlan] = []
    frames: list[TrajectoryFramePlan] = []
    next_id = 1
    stamp = start_ns
    for split, spec in config.splits.items():
        scenes = plan_scenes(spec.anomalous, spec.normal, settings.normal_scenes)
        low, high = settings.objects
        counts = [int(rng.integers(low, high + 1)) if s == OBJECT_SCENE else 0 for s in scenes]
        kinds = balanced(types, sum(counts), rng)
        days = rng.integers(config.days[0], config.days[1] + 1, len(scenes))
        strengths = rng.choice(len(weights), size=len(scenes), p=weights)
        used = 0
        for number, scene in enumerate(scenes):
            plan = TrajectoryPlan(
                ordinal=len(trajectories),
                split=split,
                number=number,
                scene=scene,
                day=int(days[number]),
                sun_strength=float(config.sun_strengths[strengths[number]]),
                types=tuple(kinds[used : used + counts[number]]),
                first_id=next_id,
                start_ns=stamp,
                seed=seed,
            )
            used += counts[number]
            next_id += counts[number]
            trajectories.append(plan)
            for step in range(settings.frames):
                frames.append(TrajectoryFramePlan(len(frames), step, stamp, plan))
                stamp += period_ns
            stamp += gap_ns
    return trajectories, frames


@dataclass(eq=False)
class TrajectorySetup:
    """A trajectory's path, Sun and objects, settled against the station model.

    Attributes
    ----------
    plan : TrajectoryPlan
        The plan.
    poses : list of numpy.ndarray
        (4, 4) camera pose of every frame.
    skies : list of Sky
        Sun, Earth and Moon of every frame (the Sun turns in ``shadows`` trajectories).
    objects : list of GroundTruthObject
        Its objects (``extra``: trajectory, placement, drifting, in_shadow).
    builds : list
        The built :class:`~.objects.AnomalyObject` of each object.
    peak_speed_m_s, peak_turn_deg_s : float
        The path's largest speeds between two frames.
    """

    plan: TrajectoryPlan
    poses: list[np.ndarray]
    skies: list[Sky]
    objects: list[GroundTruthObject]
    builds: list = field(default_factory=list)
    peak_speed_m_s: float = 0.0
    peak_turn_deg_s: float = 0.0


def _turned_sky(sky: Sky, rotation: np.ndarray) -> Sky:
    sun = np.concatenate([rotation @ sky.sun[:3], sky.sun[3:]])
    return Sky(rotation @ sky.sun_direction, sun, sky.earth, sky.moon)


def _view_axis(
    plan: TrajectoryPlan,
    base: BasePose,
    sky: Sky,
    intrinsics: CameraIntrinsics,
    rng: np.random.Generator,
) -> np.ndarray:
    """Where the path starts looking: at the station, or turned towards the Sun or a body."""
    eye = base.T_station_camera[:3, 3]
    axis = base.target - eye
    half_fov = math.atan(0.5 * intrinsics.width / intrinsics.fx)
    half_vertical = math.atan(0.5 * intrinsics.height / intrinsics.fy)
    if plan.scene == "glare":
        # The Sun just inside or just outside the view: glare and a bright disc at the edge.
        return turned_towards(sky.sun_direction, axis, rng.uniform(0.6, 1.1) * half_fov)
    if plan.scene == "bodies":
        body = sky.earth if rng.random() < 0.5 else sky.moon
        return turned_towards(body[:3] - eye, axis, rng.uniform(0.2, 0.7) * half_vertical)
    return axis


def _place(
    kind: str,
    build: object,
    placement: str,
    poses: list[np.ndarray],
    occupancy: StationOccupancy,
    intrinsics: CameraIntrinsics,
    rng: np.random.Generator,
) -> tuple[np.ndarray, int] | None:
    """An object's centre on a ray seen by one frame of the path, and that frame; or None."""
    radius = float(build.radius)
    frames = len(poses)
    low, high = max(0, int(0.15 * frames)), max(1, int(0.85 * frames))
    step = int(rng.integers(low, high)) if high > low else 0
    pose = poses[step]
    u = rng.uniform(0.15, 0.85) * intrinsics.width
    v = rng.uniform(0.15, 0.85) * intrinsics.height
    ray = np.array([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, 1.0])
    direction = pose[:3, :3] @ (ray / np.linalg.norm(ray))
    eye = pose[:3, 3]
    hit = first_hit(occupancy, eye, direction, _RAY_RANGE_M)
    if placement == "front":
        if hit is None:
            return None
        distance = hit - rng.uniform(0.5, 3.0) - radius
    elif placement == "space":
        if hit is not None:
            return None
        distance = rng.uniform(3.0, 15.0)
    else:
        if hit is None:
            return None
        leave = exit_after(occupancy, eye, direction, hit, _RAY_RANGE_M)
        if leave is None:
            return None
        distance = leave + radius + rng.uniform(0.3, 2.0)
    if distance < 2.0 + radius:
        return None
    return eye + distance * direction, step


def _clear(
    centres: np.ndarray,
    radius: float,
    occupancy: StationOccupancy,
    eyes: np.ndarray,
    placed: list[tuple[np.ndarray, float]],
) -> bool:
    """Whether an object at each of ``centres`` keeps clear of the hull, the camera and the
    objects placed before it (at the same times)."""
    for centre in centres:
        if occupancy.clearance(centre) < radius + _HULL_MARGIN_M:
            return False
    if np.min(np.linalg.norm(eyes[:, None, :] - centres[None], axis=2)) < radius + _CAMERA_MARGIN_M:
        return False
    for other, other_radius in placed:
        if np.min(np.linalg.norm(other - centres, axis=1)) < radius + other_radius + 0.2:
            return False
    return True


def setup_trajectory(
    plan: TrajectoryPlan,
    config: SynthConfig,
    occupancy: StationOccupancy,
    base: BasePose,
    sky: Sky,
    intrinsics: CameraIntrinsics,
) -> TrajectorySetup:
    """Settle a trajectory's path and objects against the station, from the seed alone.

    Raises
    ------
    SynthError
        If no path clear of the station is found from the trajectory's base pose.
    """
    settings = config.trajectory
    rng = stream(plan.seed, STREAM_TRAJECTORY, plan.ordinal)
    rate = config.rate_hz
    duration = (settings.frames - 1) / rate
    eye = base.T_station_camera[:3, 3]
    up = -base.T_station_camera[:3, 1]
    distance = float(np.linalg.norm(base.target - eye))
    poses = None
    for _ in range(_PATH_ATTEMPTS):
        axis = _view_axis(plan, base, sky, intrinsics, rng)
        sweep = make_sweep(
            eye, axis, distance, up, duration, rng, settings.speed_m_s, settings.turn_deg_s
        )
        candidate = sweep.poses(settings.frames, rate)
        if path_clear(occupancy, candidate, MIN_FRAME_CLEARANCE_M):
            poses = candidate
            break
    if poses is None:
        raise SynthError(
            f"trajectory {plan.ordinal} ({plan.split}/{plan.number}): no path clear of the "
            f"station in {_PATH_ATTEMPTS} draws"
        )
    skies = [sky] * settings.frames
    if plan.scene == "shadows" and settings.sun_turn_deg_s > 0:
        turn_axis = np.cross(sky.sun_direction, rng.normal(size=3))
        turn_axis /= np.linalg.norm(turn_axis)
        skies = [
            _turned_sky(
                sky,
                Rotation.from_rotvec(
                    turn_axis * math.radians(settings.sun_turn_deg_s) * step / rate
                ).as_matrix(),
            )
            for step in range(settings.frames)
        ]
    linear, angular = speeds(poses, rate)
    setup = TrajectorySetup(plan, poses, skies, [], [], float(linear.max()), float(angular.max()))
    eyes = np.array([pose[:3, 3] for pose in poses])
    placed: list[tuple[np.ndarray, float]] = []
    times = np.arange(settings.frames)[:, None] / rate
    placements = settings.placements
    for number, kind in enumerate(plan.types):
        object_id = plan.first_id + number
        build = build_anomaly(kind, int(rng.integers(0, 2**31 - 1)), DEFAULT_COLOUR, 1.0)
        radius = float(build.radius)
        drifting = bool(rng.random() < settings.drift_probability)
        velocity = np.zeros(3)
        if drifting:
            velocity = rng.normal(size=3)
            velocity *= rng.uniform(*settings.drift_m_s) / np.linalg.norm(velocity)
        quaternion = rng.normal(size=4)
        quaternion /= np.linalg.norm(quaternion)
        first = (plan.ordinal + number) % len(placements)
        order = [placements[(first + i) % len(placements)] for i in range(len(placements))]
        found = None
        for placement in order:
            for _ in range(_PLACE_ATTEMPTS):
                spot = _place(kind, build, placement, poses, occupancy, intrinsics, rng)
                if spot is None:
                    continue
                centre, step = spot
                start = centre - velocity * step / rate
                track = start + times * velocity
                if _clear(track[[0, len(track) // 2, -1]], radius, occupancy, eyes, placed):
                    found = (placement, start, track)
                    break
            if found is not None:
                break
        if found is None:
            continue  # honest: the trajectory has one object fewer (in generation.json)
        placement, start, track = found
        placed.append((track[[0, len(track) // 2, -1]], radius))
        in_shadow = first_hit(occupancy, start, sky.sun_direction, _RAY_RANGE_M) is not None
        # The box of the built object (centred on its bounding box) in its own frame.
        setup.objects.append(
            GroundTruthObject(
                id=object_id,
                type=kind,
                stamp_ns=plan.start_ns,
                position=start,
                velocity=velocity,
                quaternion=quaternion,
                size=build.extents,
                extra={
                    "trajectory": str(plan.ordinal),
                    "placement": placement,
                    "drifting": "1" if drifting else "0",
                    "in_shadow": "1" if in_shadow else "0",
                },
            )
        )
        setup.builds.append(build)
    return setup


class TrajectorySynthesizer(FrameSynthesizer):
    """Renders the frames of arm trajectories (see :class:`~.frames.FrameSynthesizer`)."""

    def setup(self, plan: TrajectoryPlan) -> TrajectorySetup:
        """The trajectory's path and objects (computed once per trajectory and process)."""
        return self._setups(plan)

    def _setup_uncached(self, plan: TrajectoryPlan) -> TrajectorySetup:
        base = self.base_poses[plan.split][plan.number]
        return setup_trajectory(
            plan, self.config, self.occupancy, base, self._sky(plan.day), self.intrinsics
        )

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self._setups: Callable[[TrajectoryPlan], TrajectorySetup] = lru_cache(maxsize=4)(
            self._setup_uncached
        )
        self._worn: dict[int, object] = {}

    def _worn_scene(self, plan: TrajectoryFramePlan, item: GroundTruthObject, build: object):
        scene = self._worn.get(item.id)
        if scene is None:
            wear = stream(plan.seed, STREAM_WEAR, TRAJECTORY_LIGHT_OFFSET + item.id)
            scene = worn_object(build.scene, wear, self.config.realism)
            if len(self._worn) > 256:
                self._worn.clear()
            self._worn[item.id] = scene
        return scene

    def synthesize_trajectory_frame(self, plan: TrajectoryFramePlan) -> TrajectoryFrameOutput:
        """Render one frame of a trajectory."""
        setup = self.setup(plan.trajectory)
        T_true = setup.poses[plan.step]
        sky = setup.skies[plan.step]
        realism = self.config.realism
        # One draw per trajectory: the query's Sun departs from the recorded one by the same
        # small rotation in every frame, as a real Sun would not jump between frames.
        light = query_light(
            stream(plan.seed, STREAM_LIGHT, TRAJECTORY_LIGHT_OFFSET + plan.trajectory.ordinal),
            realism,
            sky.sun_direction,
            plan.sun_strength,
        )
        rng = stream(plan.seed, STREAM_FRAME, plan.index)
        extras = [
            ExtraObject(
                self._worn_scene(plan, item, build),
                item.pose_at(plan.stamp_ns),
                LABEL_ANOMALY,
                f"{OBJECT_NAME}{item.id}",
            )
            for item, build in zip(setup.objects, setup.builds, strict=True)
        ]
        result = self._query.render(
            T_true, light.sun_direction, light.sun_strength, sky.bodies(), extras, labels=True
        )
        ids = np.zeros(len(result.instance_names), dtype=np.uint16)
        for index, name in enumerate(result.instance_names):
            if name.startswith(OBJECT_NAME) and name[len(OBJECT_NAME) :].isdigit():
                ids[index] = int(name[len(OBJECT_NAME) :])
        instances = ids[result.instances]
        counts = np.bincount(instances.ravel(), minlength=int(ids.max(initial=0)) + 1)
        shown = {item.id: int(counts[item.id]) for item in setup.objects if counts[item.id]}
        anomaly = ""
        if shown:
            largest = max(shown, key=lambda i: (shown[i], -i))
            anomaly = next(o.type for o in setup.objects if o.id == largest)
        trajectory = plan.trajectory
        extra: dict[str, object] = {
            "day": trajectory.day,
            "trajectory": trajectory.ordinal,
            "step": plan.step,
            "scene": trajectory.scene,
            "objects_shown": len(shown),
        }
        image, reference, T_reported = self._develop(
            plan, rng, result, T_true, sky, light, extras, extra
        )
        return TrajectoryFrameOutput(
            plan,
            image,
            result.labels,
            instances,
            reference,
            T_true,
            T_reported,
            sky,
            anomaly,
            shown,
            extra,
        )


@dataclass(frozen=True, eq=False)
class TrajectoryFrameOutput:
    """One rendered trajectory frame, as the writer needs it.

    ``shown`` maps the id of every object with pixels in the frame to its pixel count;
    ``anomaly`` is the type of the largest of them (empty when none shows).
    """

    plan: TrajectoryFramePlan
    image: np.ndarray
    mask: np.ndarray
    instances: np.ndarray
    reference: np.ndarray | None
    T_true: np.ndarray
    T_reported: np.ndarray
    sky: Sky
    anomaly: str
    shown: dict[int, int]
    extra: dict = field(default_factory=dict)
