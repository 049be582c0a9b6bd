"""What reusing the reference costs in accuracy, on frames along moving arm trajectories.

``make bench-reuse``: a few trajectory segments around the station, each at the camera's
frame rate, every other one with the arm at its top speeds (5 deg/s and 0.3 m/s, the worst
case for reuse) and the others at 40 % of them,
an anomaly fixed near the viewed surface, and queries rendered at full resolution with an
exposure change, sensor noise and JPEG compression. MRAD runs over each segment in frame
order, once rendering every frame and once per reuse setting (error bound, rotation bound),
and the report gives, per setting, renders per frame, pooled P.AP and its difference from
rendering every frame (paired frame bootstrap, 95 % interval) and the mean reference
difference from a fresh render.

Usage: ``python -m benchmarks.reuse --out reports/bench_reuse.json``
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.metrics import (
    MetricsAccumulator,
    bootstrap_ap_difference,
    frame_counts,
)
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.render import (
    LABEL_ANOMALY,
    ExtraObject,
    ReferenceProvider,
    ReferenceRenderer,
    RenderSettings,
)
from allo_mrad_ros.render.reuse import ReuseBounds
from allo_mrad_ros.synth.objects import ANOMALY_TYPES, build_anomaly
from allo_mrad_ros.view import View
from benchmarks import finish
from benchmarks.trajectory import (
    MAX_ANGULAR_DEG_S,
    MAX_LINEAR_M_S,
    top_speed_path,
)

SUN = np.array([0.3, -0.5, 0.8])
# Error bounds (camera pixels) and rotation bounds (degrees) measured by default.
ERROR_BOUNDS = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
ROTATION_BOUNDS = (2.0,)
# Speed of the slow segments, as a share of the arm's top speeds.
SLOW_PACE = 0.4


@dataclass(frozen=True)
class Segment:
    """Frames of one trajectory segment: poses, times, queries (JPEG) and anomaly masks."""

    poses: list[np.ndarray]
    times_s: list[float]
    queries: list[bytes]
    masks: list[bytes]  # PNG of the class image (2: anomaly)


def make_segments(
    camera: CameraIntrinsics, count: int, frames: int, rate_hz: float, seed: int
) -> list[Segment]:
    """``count`` segments of ``frames`` frames at ``rate_hz``, each with one anomaly."""
    rng = np.random.default_rng(seed)
    segments = []
    kinds = list(ANOMALY_TYPES)
    with ReferenceRenderer(None, camera, scale=1.0) as renderer:
        for index in range(count):
            distance = rng.uniform(10.0, 30.0)
            direction = rng.normal(size=3) * [1.0, 1.0, 0.5]
            direction /= np.linalg.norm(direction)
            start = look_at(direction * distance, rng.normal(scale=2.0, size=3))
            # The anomaly floats 1-2 m in front of the surface seen at the image centre.
            depth = renderer.render(start, SUN, depth=True).depth
            centre = depth[camera.height // 2, camera.width // 2]
            reach = float(centre) if centre > 0 else distance
            along = max(2.0, reach - rng.uniform(1.0, 2.0))
            spot = start[:3, :3] @ np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), 1.0])
            anomaly = np.eye(4)
            anomaly[:3, 3] = start[:3, 3] + spot * along
            obj = build_anomaly(kinds[index % len(kinds)], seed + index)
            extra = ExtraObject(obj.scene, anomaly, LABEL_ANOMALY)
            # Every other segment at the arm's top speeds, the others at 40 % of them.
            pace = 1.0 if index % 2 == 0 else SLOW_PACE
            poses = top_speed_path(
                start, frames, rate_hz, pace * MAX_ANGULAR_DEG_S, pace * MAX_LINEAR_M_S, rng
            )
            exposure = rng.uniform(0.8, 1.2)
            queries, masks = [], []
            for pose in poses:
                result = renderer.render(pose, SUN, extra_objects=[extra], labels=True)
                queries.append(_camera_like(result.rgb, exposure, rng))
                masks.append(_png(result.labels))
            times = [i / rate_hz for i in range(frames)]
            segments.append(Segment(poses, times, queries, masks))
    return segments


def _camera_like(rgb: np.ndarray, exposure: float, rng: np.random.Generator) -> bytes:
    """Exposure, sensor noise and JPEG compression: a query that is not the render."""
    noisy = rgb.astype(np.float32) * exposure + rng.normal(0.0, 2.0, rgb.shape)
    image = np.clip(noisy, 0, 255).astype(np.uint8)
    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return encoded.tobytes()


def _png(labels: np.ndarray) -> bytes:
    ok, encoded = cv2.imencode(".png", labels)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return encoded.tobytes()


def _decoded(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


def evaluate(segments: list[Segment], camera: CameraIntrinsics, reuse: ReuseBounds | None) -> dict:
    """MRAD over every segment in frame order with ``reuse`` (None: render every frame)."""
    provider = ReferenceProvider(None, camera, RenderSettings(reuse=reuse))
    fresh = ReferenceProvider(None, camera, RenderSettings()) if reuse is not None else None
    pipeline = Pipeline(provider, PipelineConfig(render=provider.settings))
    accumulator = MetricsAccumulator()
    counts, differences, render_ms = [], [], []
    renders = frames = 0
    try:
        for segment in segments:
            for pose, time_s, query, mask in zip(
                segment.poses, segment.times_s, segment.queries, segment.masks, strict=True
            ):
                view = View(pose, SUN)
                start = time.perf_counter()
                reference = provider.render(view, time_s)
                render_ms.append(1e3 * (time.perf_counter() - start))
                renders += provider.reuse is None or not provider.reuse.last_decision.reuse
                frames += 1
                if fresh is not None:
                    exact = fresh.render(view)
                    differences.append(float(np.abs(exact.astype(np.int16) - reference).mean()))
                result = pipeline.process(_decoded(query), view, reference=reference).primary
                mask = _decoded(mask)
                accumulator.update(result.score, result.image_score, mask)
                counts.append(frame_counts(result.score, mask))
    finally:
        provider.close()
        if fresh is not None:
            fresh.close()
    metrics = accumulator.compute()
    return {
        "renders_per_frame": renders / max(frames, 1),
        "p_ap": metrics.p_ap,
        "p_fpr95": metrics.p_fpr95,
        "i_auroc": metrics.i_auroc,
        "reference_ms_median": float(np.median(render_ms)),
        "reference_mean_abs_difference": float(np.mean(differences)) if differences else 0.0,
        "counts": np.stack(counts),
    }


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--segments", type=int, default=6, help="trajectory segments")
    parser.add_argument("--frames", type=int, default=60, help="frames per segment")
    parser.add_argument("--rate", type=float, default=30.0, help="frame rate, Hz")
    parser.add_argument("--width", type=int, default=1920, help="camera width (ALLO FOV)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--errors", default=",".join(f"{v:g}" for v in ERROR_BOUNDS), help="error bounds, px"
    )
    parser.add_argument(
        "--rotations",
        default=",".join(f"{v:g}" for v in ROTATION_BOUNDS),
        help="rotation bounds, degrees",
    )
    parser.add_argument("--out", type=Path, default=Path("reports/bench_reuse.json"))
    args = parser.parse_args(argv)
    camera = ALLO_INTRINSICS.scaled(args.width / ALLO_INTRINSICS.width)
    start = time.monotonic()
    segments = make_segments(camera, args.segments, args.frames, args.rate, args.seed)
    print(
        f"{args.segments} segments x {args.frames} frames at {args.rate:g} Hz, "
        f"{camera.width}x{camera.height}, 5 deg/s and 0.3 m/s (every other one at "
        f"{SLOW_PACE:.0%} of that) "
        f"(made in {time.monotonic() - start:.0f} s)"
    )
    baseline = evaluate(segments, camera, None)
    settings: dict[str, dict] = {"render every frame": baseline}
    for rotation in (float(v) for v in args.rotations.split(",")):
        for error in (float(v) for v in args.errors.split(",")):
            bounds = ReuseBounds(max_error_px=error, max_rotation_deg=rotation)
            settings[f"error {error:g} px, rotation {rotation:g} deg"] = evaluate(
                segments, camera, bounds
            )
    print(
        f"{'setting':32} {'renders/frame':>13} {'P.AP':>6} {'dP.AP':>7} {'95% CI':>16} "
        f"{'FPR95':>6} {'ref diff':>8} {'ref ms':>7}"
    )
    report = {"segments": args.segments, "frames": args.frames, "rate_hz": args.rate}
    rows = {}
    baseline_counts = baseline["counts"]
    for name, result in settings.items():
        counts = result.pop("counts")
        delta = 100 * (result["p_ap"] - baseline["p_ap"])
        spread = 100 * bootstrap_ap_difference(baseline_counts, counts)
        low, high = np.percentile(spread, [2.5, 97.5])
        result.update(delta_p_ap_points=delta, delta_ci95=[float(low), float(high)])
        rows[name] = result
        print(
            f"{name:32} {result['renders_per_frame']:13.3f} {100 * result['p_ap']:6.1f} "
            f"{delta:+7.2f} [{low:+6.2f}, {high:+6.2f}] {100 * result['p_fpr95']:6.1f} "
            f"{result['reference_mean_abs_difference']:8.2f} {result['reference_ms_median']:7.2f}"
        )
    report["settings"] = rows
    return finish(args.out, report)


if __name__ == "__main__":
    sys.exit(main())
