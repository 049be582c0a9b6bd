"""Do the masks of a path-traced sequence fit its Cycles images? Silhouette IoU per frame.

A sequence generated with ``--query-renderer cycles`` keeps the rasteriser's label image as
its mask. For each anomalous frame this rebuilds the object and its pose from
``frames.csv`` (``object_seed``, ``colour``, ``scale``, ``obj_*``, ``true_*``), renders the
object's silhouette with Cycles from the true camera pose (the station hiding what is behind
it) and compares it with the mask's class-2 pixels. Needs the optional bpy.

Usage: ``python -m allo_mrad_ros.benchmarks.cycles_silhouettes data/bench_cycles``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.benchmarks import finish
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


def main(argv: list[str] | None = None) -> int:
    """Print the IoU per frame and their summary; write the JSON report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequence", type=Path, help="a sequence made with --query-renderer cycles")
    parser.add_argument("--frames", type=int, default=8, help="anomalous frames to check")
    parser.add_argument("--out", type=Path, default=Path("reports/cycles_silhouettes.json"))
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be >= 1")
    rows = silhouette_iou(args.sequence, args.frames)
    for row in rows:
        print(f"{row['name']}: {row['anomaly']}, {row['mask_pixels']} px, IoU {row['iou']:.3f}")
    ious = [row["iou"] for row in rows]
    summary = {"frames": len(rows), "median_iou": float(np.median(ious)), "min_iou": min(ious)}
    print(
        f"{summary['frames']} frames: median IoU {summary['median_iou']:.3f}, "
        f"lowest {summary['min_iou']:.3f}"
    )
    return finish(args.out, {"summary": summary, "frames": rows})


if __name__ == "__main__":
    raise SystemExit(main())
