"""Flood of the running ``mrad_detector`` node: full-HD frames at 30 Hz for minutes.

The node runs as its own process with its default parameters; a camera feed in this process
publishes rendered 1920x1080 frames, poses and the Sun at ``--rate`` Hz for ``--minutes``,
then stops. Reports whether the node stayed alive, its resident memory after the first minute
and at the end (growth target <= 5 %), and how honest ``/diagnostics`` was: the level of every
status received while frames flowed (OK expected), and how long after the last image the
status said "no image" (ERROR; STALE is the aggregator's call; target <= 3 s). The machine's
load average is printed with the figures: on a shared machine the node processes fewer
frames, not different ones.

Usage: ``python -m benchmarks.flood --minutes 10 --out reports/flood.json``
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus

from allo_mrad_ros.ros.messages import stamp_to_ns
from benchmarks import finish, machine_facts
from benchmarks.node_session import SUN, node_session, still_frames

LEVELS = {
    DiagnosticStatus.OK: "OK",
    DiagnosticStatus.WARN: "WARN",
    DiagnosticStatus.ERROR: "ERROR",
    DiagnosticStatus.STALE: "STALE",
}
# Statuses in the first seconds describe the start (no frame processed yet), not the flood.
WARM_UP_S = 10.0
# Resident memory is sampled this often. It is a sawtooth (the frames in flight, tens of MB,
# come and go), so one sample says little; growth is judged on the peak of each minute.
RSS_SAMPLE_S = 1.0


def peak_growth(samples: list[tuple[float, float]], duration_s: float) -> dict:
    """Resident memory of the second minute against the last minute, by peak and median.

    Parameters
    ----------
    samples : list of (float, float)
        Seconds since the flood started and resident MB.
    duration_s : float
        Length of the flood; the last minute is ``[duration_s - 60, duration_s]``.

    Returns
    -------
    dict
        ``second_minute`` and ``last_minute`` as ``{"peak", "median"}`` in MB, and
        ``growth_percent`` of the peak (None when either minute has no sample).
    """
    windows = {"second_minute": (60.0, 120.0), "last_minute": (duration_s - 60.0, duration_s)}
    figures: dict = {}
    for name, (start, end) in windows.items():
        values = sorted(mb for t, mb in samples if start <= t <= end)
        figures[name] = {"peak": values[-1], "median": values[len(values) // 2]} if values else None
    first, last = figures["second_minute"], figures["last_minute"]
    figures["growth_percent"] = (
        100.0 * (last["peak"] / first["peak"] - 1) if first and last else None
    )
    return figures


def flood(minutes: float, rate_hz: float, log_path: Path) -> dict:
    """Drive the node for ``minutes`` at ``rate_hz``, then stop and watch it say "no image"."""
    pose, images = still_frames()
    duration = 60.0 * minutes
    with node_session(log_path, {}) as (feed, node):
        warm = time.monotonic()
        while not feed.arrival["mask"] and time.monotonic() - warm < 120.0:
            feed.publish_frame(time.time_ns(), images[0], pose, SUN)
            feed.spin(0.5)
        feed.arrival["mask"].clear()
        feed.diagnostics.clear()
        published = 0
        rss: list[tuple[float, float]] = []
        load_start = os.getloadavg()
        wall_start = time.time()
        start = time.monotonic()
        next_frame = start
        next_sample = start
        while time.monotonic() - start < duration:
            now = time.monotonic()
            if now >= next_frame:
                feed.publish_frame(time.time_ns(), images[published % 2], pose, SUN)
                published += 1
                next_frame += 1.0 / rate_hz
                if next_frame < now - 1.0:  # a stall of this process: do not burst after it
                    next_frame = now
            if now >= next_sample:
                rss.append((now - start, node.memory_info().rss / 2**20))
                next_sample += RSS_SAMPLE_S
            rclpy.spin_once(feed.node, timeout_sec=0.002)
        last_image = time.monotonic()
        load_end = os.getloadavg()
        settled = wall_start + WARM_UP_S
        during = [
            (msg.status[0].level, msg.status[0].message)
            for msg in feed.diagnostics
            if len(msg.status) and stamp_to_ns(msg.header.stamp) / 1e9 >= settled
        ]
        statuses_at_stop = len(feed.diagnostics)
        stale_after = None
        while time.monotonic() - last_image < 15.0:
            feed.spin(0.05)
            fresh = feed.diagnostics[statuses_at_stop:]
            if any(
                m.status[0].level == DiagnosticStatus.ERROR and "no image" in m.status[0].message
                for m in fresh
            ):
                stale_after = time.monotonic() - last_image
                break
        alive = node.is_running()
        rss_end = node.memory_info().rss / 2**20
    times = sorted(feed.arrival["mask"].values())
    levels = Counter(LEVELS.get(level, str(level)) for level, _ in during)
    not_ok = Counter(message for level, message in during if level != DiagnosticStatus.OK)
    after_first_minute = next((mb for t, mb in rss if t >= 60.0), rss[-1][1] if rss else None)
    return {
        "image": f"{images[0].shape[1]}x{images[0].shape[0]}",
        "input_rate_hz": rate_hz,
        "minutes": minutes,
        "frames_published": published,
        "frames_processed": len(times),
        "output_rate_hz": (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0,
        "node_alive_at_end": alive,
        "rss_mb_after_first_minute": after_first_minute,
        "rss_mb_end": rss_end,
        "rss_growth_percent": 100.0 * (rss_end / after_first_minute - 1)
        if after_first_minute
        else None,
        "rss_mb_samples": rss,
        "rss_peak_by_minute": peak_growth(rss, duration),
        "diagnostics_levels_while_flooding": dict(levels),
        "diagnostics_not_ok_messages": dict(not_ok.most_common(5)),
        "stale_seconds_after_last_image": stale_after,
        "load_average_start": load_start,
        "load_average_end": load_end,
        **machine_facts(),
    }


def _peak_line(figures: dict) -> str:
    first, last = figures["second_minute"], figures["last_minute"]
    if first is None or last is None:
        return "resident memory by minute: the flood is shorter than two minutes"
    return (
        f"resident memory by minute (samples every {RSS_SAMPLE_S:g} s): second minute peak "
        f"{first['peak']:.0f} MB (median {first['median']:.0f}), last minute peak "
        f"{last['peak']:.0f} MB (median {last['median']:.0f}): {figures['growth_percent']:+.1f} %"
    )


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="flood duration")
    parser.add_argument("--rate", type=float, default=30.0, help="input frame rate, Hz")
    parser.add_argument("--out", type=Path, default=Path("reports/flood.json"))
    args = parser.parse_args(argv)
    log = Path(tempfile.mkdtemp(prefix="flood_")) / "node.log"
    report = flood(args.minutes, args.rate, log)
    growth = report["rss_growth_percent"]
    stale = report["stale_seconds_after_last_image"]
    print(
        f"mrad_detector at {report['image']}, input {args.rate:g} Hz for {args.minutes:g} min, "
        f"default parameters; load average {report['load_average_start'][0]:.1f} at start, "
        f"{report['load_average_end'][0]:.1f} at end ({report['cpu_count']} CPUs)\n"
        f"frames published {report['frames_published']}, processed "
        f"{report['frames_processed']} ({report['output_rate_hz']:.2f} frames/s)\n"
        f"node alive at the end: {report['node_alive_at_end']}\n"
        f"resident memory: {report['rss_mb_after_first_minute']:.0f} MB after the first "
        f"minute, {report['rss_mb_end']:.0f} MB at the end ({growth:+.1f} %; single samples)\n"
        f"{_peak_line(report['rss_peak_by_minute'])}\n"
        f"/diagnostics while flooding (after {WARM_UP_S:g} s): "
        f"{report['diagnostics_levels_while_flooding']}; not OK: "
        f"{report['diagnostics_not_ok_messages'] or 'none'}\n"
        f"'no image' {'never' if stale is None else f'{stale:.1f} s'} after the last image\n"
        f"node log: {log}"
    )
    return finish(args.out, report)


if __name__ == "__main__":
    sys.exit(main())
