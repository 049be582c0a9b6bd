"""Writing a trajectory sequence: objects table first, then every frame with its instance mask.

The objects table is settled in this process from the seed (:func:`~.trajectory_frames.
setup_trajectory`), the frames are rendered here or in worker processes that settle the same
paths and objects from the same seed, so the output is the same whatever ``jobs`` is.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from allo_mrad_ros.ephemeris import StationEphemeris
from allo_mrad_ros.sequence import GroundTruthObject
from allo_mrad_ros.staging import hold_point
from allo_mrad_ros.synth.config import SynthConfig
from allo_mrad_ros.synth.frames import camera_intrinsics
from allo_mrad_ros.synth.occupancy import StationOccupancy
from allo_mrad_ros.synth.planning import STREAM_POSES, stream
from allo_mrad_ros.synth.poses import make_base_poses
from allo_mrad_ros.synth.trajectory_frames import (
    TrajectoryFrameOutput,
    TrajectorySetup,
    TrajectorySynthesizer,
    plan_trajectories,
    setup_trajectory,
)
from allo_mrad_ros.synth.workers import SequenceJob, write_output


def settle(config: SynthConfig, seed: int, mesh: Path, start_ns: int) -> list[TrajectorySetup]:
    """Every trajectory's path and objects, as the renderers will find them (no renderer)."""
    occupancy = StationOccupancy.from_model(mesh)
    base_poses = make_base_poses(
        occupancy,
        {split: spec.cameras for split, spec in config.splits.items()},
        stream(seed, STREAM_POSES),
        config.camera_distance_m,
        config.min_camera_clearance_m,
    )
    ephemeris = StationEphemeris()
    intrinsics = camera_intrinsics(config)
    trajectories, _ = plan_trajectories(config, seed, start_ns)
    return [
        setup_trajectory(
            plan,
            config,
            occupancy,
            base_poses[plan.split][plan.number],
            ephemeris.sky_on_day(plan.day),
            intrinsics,
        )
        for plan in trajectories
    ]


def _in_view(item: GroundTruthObject, output: TrajectoryFrameOutput, config: SynthConfig) -> bool:
    """Whether the object's centre projects into the image in front of the camera."""
    camera = camera_intrinsics(config)
    T = output.T_true
    point = T[:3, :3].T @ (item.position_at(output.plan.stamp_ns) - T[:3, 3])
    if point[2] <= 0.1:
        return False
    u = camera.fx * point[0] / point[2] + camera.cx
    v = camera.fy * point[1] / point[2] + camera.cy
    return 0 <= u < camera.width and 0 <= v < camera.height


def generate_trajectories(job: SequenceJob) -> tuple[int, dict]:
    """Render and write a trajectory sequence (see :func:`~.generator.generate`).

    Returns
    -------
    tuple
        Frames written, and the composition per split (trajectories, scenes, frames, objects
        per type, placement and state, frames in view, shown and hidden).
    """
    config, seed, mesh = job.config, job.seed, job.mesh
    trajectories, plans = plan_trajectories(config, seed, job.start_ns)
    setups = settle(config, seed, mesh, job.start_ns)
    objects = [item for setup in setups for item in setup.objects]
    outputs = job.rendered(
        TrajectorySynthesizer,
        TrajectorySynthesizer.synthesize_trajectory_frame,
        plans,
        # Runs of frames per task, so a worker mostly settles each trajectory once.
        chunksize=max(1, min(16, config.trajectory.frames // job.jobs)),
    )
    by_trajectory = {plan.ordinal: [] for plan in trajectories}
    for item in objects:
        by_trajectory[int(item.extra["trajectory"])].append(item)
    seen: dict[int, list[int]] = {item.id: [] for item in objects}
    in_view: dict[int, list[int]] = {item.id: [] for item in objects}
    frame_rows: list[tuple[str, bool]] = []
    with job.writer(objects) as writer:
        for output in outputs:
            write_output(
                writer,
                output,
                camera=output.plan.trajectory.number,
                anomaly=output.anomaly,
                instances=output.instances,
                stamp_ns=output.plan.stamp_ns,
            )
            frame_rows.append((output.plan.split, bool(output.shown)))
            for item in by_trajectory[output.plan.trajectory.ordinal]:
                if item.id in output.shown:
                    seen[item.id].append(output.plan.step)
                if _in_view(item, output, config):
                    in_view[item.id].append(output.plan.step)
            hold_point("generate-frame")
    composition = _composition(config, trajectories, setups, objects, frame_rows, seen, in_view)
    return len(plans), composition


def _composition(
    config: SynthConfig,
    trajectories: list,
    setups: list[TrajectorySetup],
    objects: list[GroundTruthObject],
    frame_rows: list[tuple[str, bool]],
    seen: dict[int, list[int]],
    in_view: dict[int, list[int]],
) -> dict:
    frames = config.trajectory.frames
    result: dict[str, dict] = {}
    for split in config.splits:
        plans = [p for p in trajectories if p.split == split]
        ordinals = {p.ordinal for p in plans}
        items = [o for o in objects if int(o.extra["trajectory"]) in ordinals]
        rows = [shown for s, shown in frame_rows if s == split]
        split_setups = [s for s in setups if s.plan.ordinal in ordinals]
        hidden = [o for o in items if set(in_view[o.id]) - set(seen[o.id])]
        result[split] = {
            "trajectories": len(plans),
            "frames_per_trajectory": frames,
            "per_scene": dict(sorted(Counter(p.scene for p in plans).items())),
            "frames": len(rows),
            "normal": rows.count(False),
            "anomalous": rows.count(True),
            "objects": len(items),
            "objects_planned": sum(len(p.types) for p in plans),
            "per_type": dict(sorted(Counter(o.type for o in items).items())),
            "per_placement": dict(sorted(Counter(o.extra["placement"] for o in items).items())),
            "drifting": sum(o.extra["drifting"] == "1" for o in items),
            "in_shadow": sum(o.extra["in_shadow"] == "1" for o in items),
            "never_shown": sum(not seen[o.id] for o in items),
            "enter_or_leave_view": sum(
                bool(seen[o.id]) and (seen[o.id][0] > 0 or seen[o.id][-1] < frames - 1)
                for o in items
            ),
            "hidden_while_in_view": len(hidden),
            "median_frames_shown": float(np.median([len(seen[o.id]) for o in items]))
            if items
            else 0.0,
            "peak_speed_m_s": round(max((s.peak_speed_m_s for s in split_setups), default=0), 4),
            "peak_turn_deg_s": round(max((s.peak_turn_deg_s for s in split_setups), default=0), 3),
        }
    return result
