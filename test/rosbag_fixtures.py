"""Tiny ALLO sequences for the rosbag_tools tests, rendered with the project's renderer.

Frames show the package's station model from a few poses; anomalous frames add a coloured
box or plate (an :class:`ExtraObject`) in front of the camera, and the masks come from the
renderer's label pass, so ground truth and pixels agree exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.geometry import look_at, pose_components
from allo_mrad_ros.render import ExtraObject, ReferenceRenderer
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.sequence import SequenceMeta, SequenceWriter

# ALLO's camera at 1/12 scale: 160x90 keeps the tests fast and the field of view real.
CAMERA = ALLO_INTRINSICS.scaled(1.0 / 12.0)
SUN = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
EYES = (
    (-30.0, -12.0, 6.0),
    (-26.0, 14.0, 9.0),
    (24.0, -18.0, 5.0),
    (28.0, 10.0, -7.0),
)


def _anomaly(kind: str, pose: np.ndarray, offset: float) -> ExtraObject:
    if kind == "box":
        mesh = trimesh.creation.box((1.2, 1.2, 1.2))
        mesh.visual.face_colors = (230, 180, 40, 255)
    else:
        mesh = trimesh.creation.box((1.8, 1.4, 0.1))
        mesh.visual.face_colors = (40, 120, 230, 255)
    placed = pose.copy()
    # In front of the camera, off-centre, so it covers sky and station.
    placed[:3, 3] = pose[:3, 3] + 8.0 * pose[:3, 2] + offset * pose[:3, 0] - 1.5 * pose[:3, 1]
    return ExtraObject(mesh, placed)


def write_tiny_sequence(root: Path, *, train: int = 2, with_bodies: bool = True) -> Path:
    """Write a rendered sequence: ``train`` normal train frames, then 6 test frames.

    Test frames: normal, box, plate, normal, box, plate (poses cycle through ``EYES``).
    The mesh is copied into the sequence. Returns ``root``.
    """
    mesh = share_path("meshes", "station.glb")
    meta = SequenceMeta(name="tiny rendered", camera=CAMERA, rate_hz=10.0, mesh=mesh)
    kinds = ["", "box", "plate", "", "box", "plate"]
    renderer = ReferenceRenderer(mesh, CAMERA, scale=1.0, shadows=True)
    try:
        with SequenceWriter(root, meta, start_ns=1_000_000_000) as writer:
            plan = [("train", "")] * train + [("test", kind) for kind in kinds]
            for i, (split, kind) in enumerate(plan):
                pose = look_at(EYES[i % len(EYES)], (0.0, 0.0, 0.0))
                extras = [_anomaly(kind, pose, 1.0 + 0.3 * i)] if kind else []
                earth = [1500.0, -800.0, 400.0, 35.0] if with_bodies else None
                moon = [-200.0, 300.0, 150.0, 20.0] if with_bodies and i % 3 else None
                bodies = [
                    (name, value[:3], value[3])
                    for name, value in (("earth", earth), ("moon", moon))
                    if value is not None
                ]
                render = renderer.render(pose, SUN, 1.0, bodies, extra_objects=extras, labels=True)
                position, quaternion = pose_components(pose)
                writer.add_frame(
                    split=split,
                    camera=i % 2,
                    image=render.rgb,
                    mask=render.labels,
                    anomaly=kind,
                    position=position,
                    quaternion=quaternion,
                    sun_direction=SUN,
                    sun_strength=1.0,
                    earth=earth,
                    moon=moon,
                )
    finally:
        renderer.close()
    return root
