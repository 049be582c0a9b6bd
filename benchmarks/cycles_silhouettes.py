"""Do the masks of a path-traced sequence fit its Cycles images? Silhouette IoU per frame.

A sequence generated with ``--query-renderer cycles`` keeps the rasteriser's label image as
its mask. For each anomalous frame this rebuilds the object and its pose from
``frames.csv`` (``object_seed``, ``colour``, ``scale``, ``obj_*``, ``true_*``), renders the
object's silhouette with Cycles from the true camera pose (the station hiding what is behind
it) and compares it with the mask's class-2 pixels. Needs the optional bpy.

Usage: ``python -m benchmarks.cycles_silhouettes data/bench_cycles``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from benchmarks import finish
from harness.silhouettes import silhouette_iou


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
