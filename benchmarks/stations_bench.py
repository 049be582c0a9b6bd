"""The multi-station path-traced bench (``make bench-stations``): colour gap, per station.

Each station of :data:`~benchmarks.stations.BENCH_SPLITS` has its own
sequence (``allo-synth generate --preset bench-stations --mesh <station>``): queries
path-traced by Blender Cycles under several view transforms and exposures, JPEG, references
rasterised here from the reported pose at the evaluator's default scale. Every reference is
rendered once per frame; each named setting (an MRAD parameter set, or a baseline) then runs
on the same frames, so settings are compared on identical inputs.

Per split it prints, per setting, the pooled P.AP, P.AUROC, P.FPR95 and I.AUROC and the
P.AP of each station, then (``--compare A,B``) a paired frame bootstrap of the P.AP
difference of B over A with its 95 % interval, and the pixel recall per anomaly type at the
threshold where the setting's false-positive rate is 5 %. With ``--bench pt`` it reads the
extended path-traced bench (:data:`~benchmarks.stations.PT_SPLITS`) and ``--kinds`` adds,
per object kind (the sequences' ``kind`` column; objects marked invisible apart, as
``invisible``), P.AP against every negative pixel of the split, the pixel recall at that 5 %
threshold and the anomalous frames found (the method's decision says anomalous and its mask
touches the object), and per station the normal frames flagged and anomalous ones found.
Writes a JSON report.

Usage::

    python -m benchmarks.stations_bench data/bench_stations --split val \\
        --settings default,no_transfer,PAD,RXD --out reports/bench_stations_val.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from allo_mrad_ros.detector import METHODS, MradParams, profile
from allo_mrad_ros.errors import lookup
from allo_mrad_ros.metrics import (
    MetricsAccumulator,
    PooledScoreCounts,
    ScoreCounts,
    bootstrap_ap_difference,
    frame_counts,
    pixel_metrics,
)
from allo_mrad_ros.render import ReferenceProvider, RenderSettings
from allo_mrad_ros.sequence import read_sequence
from allo_mrad_ros.view import View
from benchmarks import machine_facts
from benchmarks.stations import BENCH_SPLITS, BENCHES

MASK_ANOMALY = 2


@dataclass(frozen=True)
class BenchFrame:
    """One frame with its rendered reference."""

    station: str
    anomaly: str
    image: np.ndarray
    truth: np.ndarray
    reference: np.ndarray
    kind: str = ""
    """The object's kind (``invisible`` for an object marked invisible); "" when normal."""
    sun_pixel: tuple[float, float] | None = None
    """Where the Sun's centre falls in the image (None: behind the camera), for
    ``sun_glare``."""
    body_discs: tuple[tuple[float, float, float], ...] = ()
    """The Earth's and the Moon's discs in the image, for ``body_margin``."""


@dataclass(frozen=True)
class NamedSetting:
    """A method and its parameters under a name."""

    name: str
    method: str
    params: MradParams


@dataclass
class SettingResult:
    """Pooled and per-station metrics of one setting."""

    setting: NamedSetting
    pooled: MetricsAccumulator = field(default_factory=MetricsAccumulator)
    stations: dict[str, MetricsAccumulator] = field(default_factory=dict)
    counts: list[np.ndarray] = field(default_factory=list)
    scores: list[np.ndarray] = field(default_factory=list)
    detect_ms: list[float] = field(default_factory=list)
    found: list[bool] = field(default_factory=list)
    """Per frame: the decision says anomalous (and, on an anomalous frame, its mask touches
    the object)."""


SETTINGS: dict[str, tuple[str, dict[str, object]]] = {
    "default": ("MRAD", {}),
    "no_transfer": ("MRAD", {"colour_transfer": "none"}),
    "transfer_reference": ("MRAD", {"colour_transfer": "reference"}),
    "no_transfer_affine_map": (
        "MRAD",
        {"colour_transfer": "none", "map_photometric": "cell_affine"},
    ),
    "PAD": ("PAD", {}),
    "RXD": ("RXD", {}),
}
"""Named settings; ``KEY=VALUE`` pairs after a name (``default:transfer_bin=8``) override."""


def parse_setting(text: str) -> NamedSetting:
    """``name[:key=value[:key=value...]]`` -> a :class:`NamedSetting` over the defaults."""
    name, *overrides = text.split(":")
    method, changes = lookup(SETTINGS, name, what="setting", error=ValueError)
    changes = dict(changes)
    for item in overrides:
        key, _, value = item.partition("=")
        if not key or not value:
            raise ValueError(f"setting {text!r}: override {item!r} is not key=value")
        default = getattr(MradParams(), key, None)
        if default is None:
            raise ValueError(f"setting {text!r}: unknown MRAD parameter {key!r}")
        changes[key] = _typed(default, value)
    return NamedSetting(text, method, profile("default", **changes))


def _typed(default: object, text: str) -> object:
    if isinstance(default, bool):
        if text not in ("True", "False", "true", "false"):
            raise ValueError(f"expected true or false, got {text!r}")
        return text in ("True", "true")
    return text if isinstance(default, str) else type(default)(text)


def load_frames(
    root: Path,
    split: str,
    render: RenderSettings,
    splits: Mapping[str, Sequence[str]] = BENCH_SPLITS,
) -> list[BenchFrame]:
    """Read every station sequence of ``split`` and render each frame's reference once."""
    frames = []
    for station in splits[split]:
        folder = root / split / station
        if not (folder / "frames.csv").is_file():
            raise FileNotFoundError(f"{folder}: station sequence missing (make bench-stations)")
        frames += sequence_frames(folder, station, None, render)
    return frames


def sequence_frames(
    folder: Path, station: str, split: str | None, render: RenderSettings
) -> list[BenchFrame]:
    """The frames of one sequence (one split of it, or all) with their references."""
    frames = []
    sequence = read_sequence(folder)
    provider = ReferenceProvider(sequence.meta.mesh, sequence.meta.camera, render)
    try:
        for frame in sequence.frames:
            if split is not None and frame.split != split:
                continue
            image = sequence.load_image(frame)
            truth = sequence.load_mask(frame)
            view = View.of_frame(frame)
            reference = provider.render(view)
            frames.append(
                BenchFrame(
                    station,
                    frame.anomaly,
                    image,
                    truth,
                    reference,
                    frame_kind(frame),
                    view.sun_pixel(sequence.meta.camera),
                    tuple(view.body_discs(sequence.meta.camera)),
                )
            )
    finally:
        provider.close()
    return frames


def frame_kind(frame: object) -> str:
    """A frame's object kind: its ``kind`` column (``other`` without one), ``invisible``
    when its ``visible`` column is 0, "" for a normal frame."""
    if not frame.anomaly:
        return ""
    extra = frame.extra
    if extra.get("visible", "1") in ("0", "0.0"):
        return "invisible"
    return extra.get("kind") or "other"


def run_settings(
    frames: Sequence[BenchFrame], settings: Sequence[NamedSetting]
) -> list[SettingResult]:
    """Run every setting on every frame (interleaved, so all see the same machine load)."""
    results = [SettingResult(s) for s in settings]
    for frame in frames:
        for result in results:
            s = result.setting
            start = time.perf_counter()
            detection = METHODS[s.method](
                frame.image,
                frame.reference,
                s.params,
                sun_pixel=frame.sun_pixel,
                body_discs=frame.body_discs,
            )
            result.detect_ms.append(1e3 * (time.perf_counter() - start))
            result.pooled.update(detection.score, detection.image_score, frame.truth)
            station = result.stations.setdefault(frame.station, MetricsAccumulator())
            station.update(detection.score, detection.image_score, frame.truth)
            result.counts.append(frame_counts(detection.score, frame.truth))
            result.scores.append(detection.score)
            result.found.append(frame_found(detection, frame.truth))
    return results


def recall_per_type(frames: Sequence[BenchFrame], result: SettingResult, fpr: float = 0.05) -> dict:
    """Share of each anomaly type's pixels above the threshold where the pooled FPR is ``fpr``."""
    negatives = np.concatenate(
        [s[f.truth != MASK_ANOMALY] for f, s in zip(frames, result.scores, strict=True)]
    )
    threshold = float(np.quantile(negatives, 1.0 - fpr))
    found: dict[str, list[int]] = {}
    for frame, score in zip(frames, result.scores, strict=True):
        positive = frame.truth == MASK_ANOMALY
        if not positive.any():
            continue
        hits = found.setdefault(frame.anomaly or "?", [0, 0])
        hits[0] += int(np.count_nonzero(score[positive] > threshold))
        hits[1] += int(np.count_nonzero(positive))
    return {kind: round(100.0 * a / b, 1) for kind, (a, b) in sorted(found.items())}


def frame_found(detection: object, truth: np.ndarray) -> bool:
    """Whether a method's decision flags the frame; on a frame with an object, its mask must
    also touch the object (a false alarm elsewhere does not find it)."""
    if not bool(getattr(detection, "anomalous", False)):
        return False
    positive = truth == MASK_ANOMALY
    if not positive.any():
        return True
    mask = getattr(detection, "mask", None)
    return mask is not None and bool(np.any(np.asarray(mask, dtype=bool) & positive))


def per_kind(frames: Sequence[BenchFrame], result: SettingResult, fpr: float = 0.05) -> dict:
    """Per object kind: P.AP against every negative pixel of the split, pixel recall at the
    threshold where the pooled false-positive rate is ``fpr``, and frames found.

    Returns
    -------
    dict
        Kind to ``{"frames", "p_ap", "recall", "found"}`` (percent; ``found`` a count).
    """
    negatives_only = []
    for frame, score in zip(frames, result.scores, strict=True):
        keep = frame.truth != MASK_ANOMALY
        negatives_only.append(ScoreCounts.of_frame(score[keep], frame.truth[keep]))
    negatives = np.concatenate(
        [s[f.truth != MASK_ANOMALY] for f, s in zip(frames, result.scores, strict=True)]
    )
    threshold = float(np.quantile(negatives, 1.0 - fpr))
    kinds = sorted({f.kind for f in frames if f.kind})
    report = {}
    for kind in kinds:
        pool = PooledScoreCounts()
        hits = total = found = count = 0
        for i, (frame, score) in enumerate(zip(frames, result.scores, strict=True)):
            if frame.kind != kind:
                pool.add(negatives_only[i])
                continue
            pool.update(score, frame.truth)
            positive = frame.truth == MASK_ANOMALY
            hits += int(np.count_nonzero(score[positive] > threshold))
            total += int(np.count_nonzero(positive))
            found += int(result.found[i])
            count += 1
        table = pool.table()
        p_ap = pixel_metrics(table)[0]["p_ap"] if total else float("nan")
        report[kind] = {
            "frames": count,
            "p_ap": round(100 * p_ap, 1),
            "recall": round(100.0 * hits / max(total, 1), 1),
            "found": found,
        }
    return report


def per_station_decisions(frames: Sequence[BenchFrame], result: SettingResult) -> dict:
    """Per station: normal frames flagged and anomalous frames found, as counts of totals."""
    report: dict[str, dict[str, list[int]]] = {}
    for frame, found in zip(frames, result.found, strict=True):
        row = report.setdefault(frame.station, {"flagged": [0, 0], "found": [0, 0]})
        key = "found" if frame.anomaly else "flagged"
        row[key][0] += int(found)
        row[key][1] += 1
    return report


def format_kinds(name: str, kinds: Mapping[str, dict]) -> str:
    """A plain-text table of :func:`per_kind` for one setting."""
    lines = [
        f"per kind, {name}: {'kind':<20} {'frames':>6} {'P.AP':>6} {'recall5':>8} {'found':>6}"
    ]
    for kind, row in kinds.items():
        lines.append(
            f"{'':<{len(name) + 11}}{kind:<20} {row['frames']:>6} {row['p_ap']:>6.1f} "
            f"{row['recall']:>8.1f} {row['found']:>6}"
        )
    return "\n".join(lines)


def summarise(result: SettingResult) -> dict:
    """Metrics of one setting in percent: pooled, then P.AP per station."""
    pooled = result.pooled.compute()
    return {
        "p_ap": round(100 * pooled.p_ap, 1),
        "p_auroc": round(100 * pooled.p_auroc, 1),
        "p_fpr95": round(100 * pooled.p_fpr95, 1),
        "p_fpr95_interp": round(100 * pooled.p_fpr95_interp, 1),
        "i_auroc": round(100 * pooled.i_auroc, 1),
        "stations": {
            name: round(100 * acc.compute().p_ap, 1) for name, acc in result.stations.items()
        },
        "detect_ms_median": round(float(np.median(result.detect_ms)), 2),
    }


def compare(a: SettingResult, b: SettingResult, resamples: int = 1000) -> dict:
    """Paired frame bootstrap of P.AP(b) - P.AP(a), percentage points, with a 95 % interval."""
    diffs = 100 * bootstrap_ap_difference(np.stack(a.counts), np.stack(b.counts), resamples)
    point = 100 * (b.pooled.compute().p_ap - a.pooled.compute().p_ap)
    low, high = (float(v) for v in np.percentile(diffs, [2.5, 97.5]))
    return {"difference": round(point, 1), "ci95": [round(low, 1), round(high, 1)]}


def format_rows(summaries: Mapping[str, dict], stations: Sequence[str]) -> str:
    """A plain-text table: setting, pooled metrics, P.AP per station."""
    head = f"{'setting':<44} {'P.AP':>6} {'P.AUROC':>8} {'FPR95':>6} {'I.AUROC':>8} {'ms':>6}"
    head += "".join(f" {name[:12]:>12}" for name in stations)
    lines = [head]
    for name, s in summaries.items():
        line = (
            f"{name[:44]:<44} {s['p_ap']:>6.1f} {s['p_auroc']:>8.1f} {s['p_fpr95']:>6.1f} "
            f"{s['i_auroc']:>8.1f} {s['detect_ms_median']:>6.1f}"
        )
        line += "".join(f" {s['stations'].get(st, float('nan')):>12.1f}" for st in stations)
        lines.append(line)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the bench on one split and print and save its tables."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, help="folder with <split>/<station> sequences")
    parser.add_argument(
        "--sequence",
        action="store_true",
        help="ROOT is one sequence (e.g. the rasterised data/bench): use its --split",
    )
    parser.add_argument("--split", choices=("train", "val", "test"), default="val")
    parser.add_argument(
        "--bench", choices=tuple(BENCHES), default="stations", help="which stations per split"
    )
    parser.add_argument(
        "--kinds", action="store_true", help="per object kind and per-station decisions"
    )
    parser.add_argument("--settings", default="default,no_transfer,PAD,RXD")
    parser.add_argument("--compare", default="PAD,default", help="A,B: bootstrap P.AP(B)-P.AP(A)")
    parser.add_argument("--reference-scale", type=float, default=RenderSettings().reference_scale)
    parser.add_argument(
        "--reference-supersampling", type=int, default=RenderSettings().supersampling
    )
    parser.add_argument("--recall", action="store_true", help="recall per anomaly type")
    parser.add_argument("--out", type=Path, help="JSON report")
    args = parser.parse_args(argv)
    splits = BENCHES[args.bench][1]
    if not args.sequence and args.split not in splits:
        parser.error(f"--split must be one of {', '.join(splits)} without --sequence")
    try:
        settings = [parse_setting(text) for text in args.settings.split(",")]
    except ValueError as error:
        print(f"stations_bench: {error}", file=sys.stderr)
        return 2
    render = RenderSettings(args.reference_scale, supersampling=args.reference_supersampling)
    if args.sequence:
        frames = sequence_frames(args.root, args.root.name, args.split, render)
        stations: tuple[str, ...] = (args.root.name,)
    else:
        try:
            frames = load_frames(args.root, args.split, render, splits)
        except FileNotFoundError as error:
            print(f"stations_bench: {error}", file=sys.stderr)
            return 2
        stations = tuple(splits[args.split])
    results = run_settings(frames, settings)
    summaries = {r.setting.name: summarise(r) for r in results}
    by_name = {r.setting.name: r for r in results}
    print(f"split {args.split}: {len(frames)} frames, stations {', '.join(stations)}")
    print(format_rows(summaries, stations))
    report: dict = {"split": args.split, "frames": len(frames), "settings": summaries}
    a_name, _, b_name = args.compare.partition(",")
    if a_name in by_name and b_name in by_name:
        report["compare"] = {"a": a_name, "b": b_name, **compare(by_name[a_name], by_name[b_name])}
        c = report["compare"]
        print(f"P.AP {b_name} - {a_name}: {c['difference']:+.1f} points, 95 % CI {c['ci95']}")
    if args.recall:
        report["recall_at_fpr5"] = {r.setting.name: recall_per_type(frames, r) for r in results}
        for name, recall in report["recall_at_fpr5"].items():
            print(f"recall at 5 % FPR, {name}: {recall}")
    if args.kinds:
        report["kinds"] = {r.setting.name: per_kind(frames, r) for r in results}
        report["decisions"] = {r.setting.name: per_station_decisions(frames, r) for r in results}
        for name, kinds in report["kinds"].items():
            print(format_kinds(name, kinds))
        for name, stations_row in report["decisions"].items():
            text = ", ".join(
                f"{st}: normal flagged {v['flagged'][0]}/{v['flagged'][1]}, "
                f"anomalous found {v['found'][0]}/{v['found'][1]}"
                for st, v in stations_row.items()
            )
            print(f"decisions, {name}: {text}")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        report["machine"] = machine_facts()
        args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
