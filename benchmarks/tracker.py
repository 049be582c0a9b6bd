"""The object tracker's cost per frame: ``python -m benchmarks.tracker``.

Fifty objects spread 5-30 m in front of a 1080p camera sweeping past at 0.2 m/s, twenty of
them detected each frame (a region each), at 10 Hz; the reference depth is a 240x135 image
(the default reference of a 1080p camera) with station surface behind half of it. The
tracker runs ``--warm-up`` frames first (so every object exists), then
``ObjectTracker.update`` is timed over ``--frames`` frames; the median milliseconds per frame
is printed (target <= 1 ms). ``--param name=value`` sets a tracker parameter.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.detector.regions import Region
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.objects import ObjectParams, ObjectsError, ObjectTracker
from allo_mrad_ros.objects.params import params_from


def region_at(u: float, v: float, extent: int) -> Region:
    """A square region of side ``extent`` centred on ``(u, v)``."""
    box = (round(u - extent / 2), round(v - extent / 2), extent, extent)
    return Region(box, extent * extent, (u, v), box, extent * extent, 200.0, 150.0, 0.9)


def run(
    objects: int,
    regions: int,
    frames: int,
    warm_up: int,
    seed: int,
    params: ObjectParams | None = None,
) -> tuple[list[float], int]:
    """Milliseconds per timed frame, and the objects live at the end (``params``: the
    tracker's, with no object ended by misses or time)."""
    rng = np.random.default_rng(seed)
    camera = ALLO_INTRINSICS
    points = np.c_[
        rng.uniform(-6, 6, objects), rng.uniform(-5, 20, objects), rng.uniform(-3, 3, objects)
    ]
    depth = np.zeros((135, 240), np.float32)
    depth[:, 120:] = 40.0  # a module far behind the right half
    params = (params or ObjectParams()).replace(end_misses=1000, tentative_timeout_s=1000.0)
    tracker = ObjectTracker(params, camera)
    timings = []
    live = 0
    for k in range(warm_up + frames):
        t = k / 10.0
        eye = np.array([-1.0 + 0.02 * k, -10.0, 0.0])
        pose = look_at(eye, eye + np.array([0.0, 1.0, 0.0]))
        local = (points - pose[:3, 3]) @ pose[:3, :3]
        u = camera.fx * local[:, 0] / local[:, 2] + camera.cx
        v = camera.fy * local[:, 1] / local[:, 2] + camera.cy
        # Every object in the first frames (so all exist), then a rotating subset of them.
        chosen = range(objects) if k < 3 else (np.arange(regions) + 7 * k) % objects
        frame_regions = [region_at(float(u[i]), float(v[i]), 12) for i in chosen]
        start = time.perf_counter()
        result = tracker.update(frame_regions, pose, depth, t)
        if k >= warm_up:
            timings.append(1e3 * (time.perf_counter() - start))
        live = sum(o.state != "ended" for o in result)
    return timings, live


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="The object tracker's cost per frame.")
    parser.add_argument("--objects", type=int, default=50)
    parser.add_argument("--regions", type=int, default=20)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--warm-up", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--param", action="append", default=[], help="a tracker parameter, name=value (repeated)"
    )
    args = parser.parse_args(argv)
    try:
        params = params_from(args.param)
    except ObjectsError as error:
        raise SystemExit(str(error)) from None
    timings, live = run(args.objects, args.regions, args.frames, args.warm_up, args.seed, params)
    print(
        f"tracker: {args.regions} regions, {live} objects: median "
        f"{statistics.median(timings):.3f} ms per frame (p90 "
        f"{float(np.percentile(timings, 90)):.3f} ms, {len(timings)} frames)"
    )


if __name__ == "__main__":
    main()
