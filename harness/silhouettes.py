"""Do the masks of a path-traced sequence fit its Cycles images? Silhouette IoU per frame.

Shared by ``python -m benchmarks.cycles_silhouettes`` and the generator's Cycles tests: the
object of each anomalous frame is rebuilt from ``frames.csv`` and its silhouette rendered by
Cycles from the true camera pose. Needs the optional bpy.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.geometry import pose_matrix
from allo_mrad_ros.render import LABEL_ANOMALY, ExtraObject
from allo_mrad_ros.sequence import read_sequence
from allo_mrad_ros.synth.objects import build_anomaly


def _pose(extra: dict, prefix: str) -> np.ndarray:
    position = [float(extra[f"{prefix}_{axis}"]) for axis in ("tx", "ty", "tz")]
    quaternion = [float(extra[f"{prefix}_{axis}"]) for axis in ("qx", "qy", "qz", "qw")]
    return pose_matrix(position, quaternion)


def silhouette_iou(root: Path, frames: int) -> list[dict]:
    """IoU of the Cycles silhouette and the mask for up to ``frames`` anomalous frames."""
    from allo_mrad_ros.synth.cycles import CyclesRenderer

    sequence = read_sequence(root)
    anomalous = [f for f in sequence if f.is_anomalous][:frames]
    rows = []
    with CyclesRenderer(sequence.meta.mesh, sequence.meta.camera) as cycles:
        for frame in anomalous:
            e = frame.extra
            obj = build_anomaly(
                frame.anomaly, int(e["object_seed"]), e["colour"], float(e["scale"])
            )
            extra = ExtraObject(obj.scene, _pose(e, "obj"))
            traced = cycles.silhouette(_pose(e, "true"), [extra])
            mask = cv2.imread(str(frame.mask), cv2.IMREAD_UNCHANGED) == LABEL_ANOMALY
            union = np.count_nonzero(traced | mask)
            rows.append(
                {
                    "name": frame.name,
                    "anomaly": frame.anomaly,
                    "mask_pixels": int(np.count_nonzero(mask)),
                    "iou": float(np.count_nonzero(traced & mask) / max(union, 1)),
                }
            )
    return rows
