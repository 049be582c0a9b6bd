"""Benchmark of :func:`allo_mrad_ros.detector.detect` at 1920x1080.

Prints median and p95 per stage and in total, the peak resident memory, the speed and
error of the float64 per-pixel oracle measured in the same run, and ``detect()`` on each
array backend (NumPy, and PyTorch where installed: on a GPU when one is visible), interleaved;
writes the same figures to a JSON report. The oracle lives in the tests
(``test/mrad_oracle.py`` of a source checkout) and is skipped when the package runs from an
install without its tests.

Usage: ``python -m benchmarks.detector --out reports/bench_detector.json``
"""

from __future__ import annotations

import argparse
import importlib.util
import platform
import resource
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.backends import ArrayBackendError, select_backend
from allo_mrad_ros.detector.params import add_params_options, params_from
from allo_mrad_ros.detector.score import cross_score
from allo_mrad_ros.example_scene import example_pair
from allo_mrad_ros.render import DEFAULT_SCALE
from benchmarks import finish

_ORACLE_PATH = Path(__file__).resolve().parents[2] / "test" / "mrad_oracle.py"


def _load_oracle() -> ModuleType | None:
    if not _ORACLE_PATH.is_file():
        return None
    spec = importlib.util.spec_from_file_location("mrad_oracle", _ORACLE_PATH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _summary(samples: list[float]) -> dict[str, float]:
    return {"median": float(np.median(samples)), "p95": float(np.percentile(samples, 95))}


def compare_backends(
    query: np.ndarray, reference: np.ndarray, params: MradParams, specs: list[str], frames: int
) -> dict[str, dict]:
    """``detect()`` on each array backend in ``specs``, interleaved frame by frame.

    Returns, per backend name, its median total and cross-score milliseconds, and how far its
    raw score and mask are from NumPy's; a backend that cannot run here gives its reason.
    """
    backends, figures = {}, {}
    for spec in specs:
        try:
            backend = select_backend(spec)
        except ArrayBackendError as error:
            figures[spec] = {"unavailable": str(error)}
            continue
        backends[backend.name] = backend
    baseline = detect(query, reference, params)
    totals: dict[str, list[float]] = {name: [] for name in backends}
    scores: dict[str, list[float]] = {name: [] for name in backends}
    for name, backend in backends.items():
        for _ in range(3):
            result = detect(query, reference, params, backend=backend)
        error = np.abs(result.raw_score.astype(np.float64) - baseline.raw_score)
        figures[name] = {
            "max_abs_raw_diff_vs_numpy": float(error.max()),
            "max_raw_score": float(np.abs(baseline.raw_score).max()),
            "mask_pixels_differing": int(np.count_nonzero(result.mask != baseline.mask)),
        }
    for _ in range(frames):
        for name, backend in backends.items():
            start = time.perf_counter()
            result = detect(query, reference, params, backend=backend)
            totals[name].append(1e3 * (time.perf_counter() - start))
            scores[name].append(result.timings_ms["cross_score"])
    for name in backends:
        figures[name]["detect_ms_median"] = float(np.median(totals[name]))
        figures[name]["cross_score_ms_median"] = float(np.median(scores[name]))
    return figures


def _default_backends() -> list[str]:
    return ["numpy", "torch"] if importlib.util.find_spec("torch") else ["numpy"]


def run(
    frames: int,
    warmup: int,
    oracle_frames: int,
    reference_scale: float,
    profile_name: str,
    backends: list[str] | None = None,
    changes: Sequence[str] = (),
) -> dict:
    """Time ``detect`` and the oracle on the built-in 1080p example; return the figures."""
    pair = example_pair(1080, 1920)
    ref_size = (round(1920 * reference_scale), round(1080 * reference_scale))
    reference = cv2.resize(pair.reference, ref_size, interpolation=cv2.INTER_AREA)
    params = params_from(profile_name, changes)
    # The same profile without the colour transfer: what the transfer costs per frame.
    bare = params.replace(colour_transfer="none")
    for _ in range(warmup):
        detect(pair.query, reference, params)
        detect(pair.query, reference, bare)
    totals: list[float] = []
    cpu: list[float] = []
    previous: list[float] = []
    one_thread: list[float] = []
    stages: dict[str, list[float]] = {}
    result = None
    threads = cv2.getNumThreads()
    for _ in range(frames):
        # Interleaved with the run without colour transfer and with a one-thread run, so all
        # three see the same machine load.
        start = time.perf_counter()
        detect(pair.query, reference, bare)
        previous.append(1e3 * (time.perf_counter() - start))
        cv2.setNumThreads(1)
        try:
            start = time.perf_counter()
            detect(pair.query, reference, params)
            one_thread.append(1e3 * (time.perf_counter() - start))
        finally:
            cv2.setNumThreads(threads)
        start, start_cpu = time.perf_counter(), time.process_time()
        result = detect(pair.query, reference, params)
        totals.append(1e3 * (time.perf_counter() - start))
        cpu.append(1e3 * (time.process_time() - start_cpu))
        for name, ms in result.timings_ms.items():
            if name != "total":
                stages.setdefault(name, []).append(ms)
    report: dict = {
        "image": "1920x1080",
        "reference": f"{ref_size[0]}x{ref_size[1]}",
        "frames": frames,
        "warmup": warmup,
        "profile": profile_name,
        "params": params.to_dict(),
        "stages_ms": {name: _summary(values) for name, values in stages.items()},
        "detect_ms_median": float(np.median(totals)),
        "detect_ms_p95": float(np.percentile(totals, 95)),
        "detect_cpu_ms_median": float(np.median(cpu)),
        "opencv_threads": threads,
        "one_thread_ms_median": float(np.median(one_thread)),
        "without_transfer_ms_median": float(np.median(previous)),
        "ratio_to_without_transfer": float(np.median(totals) / np.median(previous)),
        "load_average_1min": _load_average(),
        "anomalous": bool(result.anomalous),
        "area": int(result.area),
        "machine": {"cpus": _cpu_count(), "python": platform.python_version()},
    }
    oracle = _load_oracle()
    if oracle is None or oracle_frames == 0:
        report["oracle_ms_median"] = None
        report["speedup_vs_oracle"] = None
    else:
        # The oracle scores the query at the resolution detect() processes it at.
        scale = params.process_scale
        size = (round(1920 * scale), round(1080 * scale))
        query = (
            cv2.resize(pair.query, size, interpolation=cv2.INTER_AREA) if scale < 1 else pair.query
        )
        report["processed_image"] = f"{size[0]}x{size[1]}"
        fast = cross_score(query, reference, params.grid, params.abs_floor, params.rel_floor)
        oracle_times = []
        for _ in range(oracle_frames):
            start = time.perf_counter()
            exact = oracle.cross_score_vectorised(
                query, reference, params.grid, params.abs_floor, params.rel_floor
            )
            oracle_times.append(1e3 * (time.perf_counter() - start))
        error = np.abs(fast.astype(np.float64) - exact)
        report["oracle_frames"] = oracle_frames
        report["oracle_ms_median"] = float(np.median(oracle_times))
        report["speedup_vs_oracle"] = report["oracle_ms_median"] / report["detect_ms_median"]
        report["score_speedup_vs_oracle"] = (
            report["oracle_ms_median"] / report["stages_ms"]["cross_score"]["median"]
        )
        report["oracle_max_abs_error"] = float(error.max())
        report["oracle_max_rel_error"] = float(error.max() / max(np.abs(exact).max(), 1e-12))
    report["array_backends"] = compare_backends(
        pair.query, reference, params, backends or _default_backends(), frames
    )
    report["peak_rss_mb"] = _peak_rss_mb()
    return report


def _load_average() -> float | None:
    import os

    return os.getloadavg()[0] if hasattr(os, "getloadavg") else None


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def format_report(report: dict) -> str:
    """The report as the table the benchmark prints."""
    lines = [
        f"detect() on {report['image']} (reference {report['reference']}, profile "
        f"{report['profile']!r}, processed at {report.get('processed_image', report['image'])}), "
        f"{report['frames']} frames after {report['warmup']} warm-up, "
        f"{report['machine']['cpus']} CPUs",
        f"{'stage':<18}{'median ms':>12}{'p95 ms':>10}",
    ]
    for name, figures in report["stages_ms"].items():
        lines.append(f"{name:<18}{figures['median']:>12.2f}{figures['p95']:>10.2f}")
    lines.append(
        f"{'detect() total':<18}{report['detect_ms_median']:>12.2f}{report['detect_ms_p95']:>10.2f}"
    )
    lines.append(
        f"CPU time per detect(): {report['detect_cpu_ms_median']:.2f} ms median (all "
        f"threads; {report['opencv_threads']} OpenCV threads); with one thread, "
        f"interleaved: {report['one_thread_ms_median']:.2f} ms median"
    )
    lines.append(
        f"the same profile without the colour transfer, interleaved: "
        f"{report['without_transfer_ms_median']:.2f} ms median; "
        f"ratio {report['ratio_to_without_transfer']:.2f}; 1-min load average "
        f"{report['load_average_1min']:.1f} on {report['machine']['cpus']} CPUs"
    )
    if report.get("oracle_ms_median") is not None:
        lines.append(
            f"float64 per-pixel oracle (cross score only, same resolution): "
            f"{report['oracle_ms_median']:.1f} ms "
            f"median over {report['oracle_frames']} frames"
        )
        lines.append(
            f"speed-up of detect() over the oracle: {report['speedup_vs_oracle']:.1f}x "
            f"(cross-score stage alone: {report['score_speedup_vs_oracle']:.1f}x); "
            f"max |fast - oracle| = {report['oracle_max_abs_error']:.2e} "
            f"({report['oracle_max_rel_error']:.1e} of the largest score)"
        )
    else:
        lines.append("oracle: not measured (test/mrad_oracle.py not found)")
    lines.append("array backends, interleaved (detect() and its cross-score stage, median):")
    for name, figures in report.get("array_backends", {}).items():
        if "unavailable" in figures:
            lines.append(f"  {name}: not run ({figures['unavailable']})")
            continue
        lines.append(
            f"  {name:<14}{figures['detect_ms_median']:>8.2f} ms"
            f"{figures['cross_score_ms_median']:>8.2f} ms; max |raw - NumPy's| "
            f"{figures['max_abs_raw_diff_vs_numpy']:.2e} of "
            f"{figures['max_raw_score']:.3g}, {figures['mask_pixels_differing']} mask pixels differ"
        )
    lines.append(f"peak resident memory: {report['peak_rss_mb']:.0f} MB")
    lines.append(f"frame decision: anomalous={report['anomalous']} area={report['area']} px")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=30, help="timed frames (>= 20)")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--oracle-frames", type=int, default=5)
    parser.add_argument(
        "--reference-scale", type=float, default=DEFAULT_SCALE, help="reference scale"
    )
    add_params_options(parser)
    parser.add_argument(
        "--array-backends",
        help="comma-separated array backends to compare (default: numpy, and torch where "
        "PyTorch is installed)",
    )
    parser.add_argument("--out", type=Path, default=Path("reports/bench_detector.json"))
    args = parser.parse_args(argv)
    if args.frames < 20:
        parser.error("--frames must be at least 20")
    backends = [b.strip() for b in args.array_backends.split(",")] if args.array_backends else None
    report = run(
        args.frames,
        args.warmup,
        args.oracle_frames,
        args.reference_scale,
        args.profile,
        backends,
        args.set,
    )
    print(format_report(report))
    return finish(args.out, report)


if __name__ == "__main__":
    sys.exit(main())
