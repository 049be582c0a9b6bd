"""Objects in the station frame against ground truth: ``python -m benchmarks.objects``
(``make bench-objects``).

1. Generates the ``objects`` preset (val and test: 9 arm trajectories each, 6 past objects and
   3 without, 960x540) into ``--data`` unless it is there (``--width``, ``--height``: another
   size).
2. Runs MRAD with the reference's depth on every frame of both splits once
   (:func:`allo_mrad_ros.evaluation.objects.detect_frames`), cached under ``--cache`` (keyed
   by the sequence and the settings), so a second run only tracks.
3. Chooses the tracker's parameters on the val split only: a small grid over the parameters
   that matter (confirmation N of M, the region scores that start and continue an object,
   the association and size gates, parallax, the image edge, the residual and the
   steady-size tests), ranked
   by the issue's targets met, then by the F1 of recall and precision, then by the error.
4. Tracks the test split with the chosen parameters and the shipped defaults, times the
   tracker alone (``benchmarks.tracker``: 20 regions, 50 objects) and writes
   ``reports/bench_objects.json``.
5. Tracks, with the same two parameter sets, a second station whose queries are path-traced
   (``--path-traced``: the ``objects-pt`` preset, a test split only, on the outpost
   ``--path-traced-mesh``; generated unless it is there, which needs Blender's ``bpy``,
   ``make cycles-setup``): the queries share neither the reference's materials nor its
   lamps, and nothing is chosen on them. ``--path-traced ''`` leaves it out.

``--diagnose`` instead follows every ground-truth object of the val split through the
detection, association, confirmation and matching with the shipped defaults (or the
parameters given with ``--param name=value``) and prints where each was lost
(:func:`allo_mrad_ros.evaluation.objects.diagnose_objects`); ``--diagnose path-traced``
does the same on the path-traced station (to read, not to choose on).
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import pickle
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from allo_mrad_ros.detector.params import params_from
from allo_mrad_ros.evaluation.object_metrics import HEADLINE_METRICS
from allo_mrad_ros.evaluation.objects import (
    ObjectDiagnosis,
    ObjectRun,
    detect_frames,
    detection_coverage,
    diagnose_objects,
    score_run,
)
from allo_mrad_ros.objects import ObjectParams
from allo_mrad_ros.objects.params import params_from as object_params_from
from allo_mrad_ros.pipeline import PipelineConfig
from allo_mrad_ros.sequence import read_sequence
from benchmarks import tracker as tracker_bench
from benchmarks.source_digest import package_digest
from benchmarks.stations import OUTPOSTS, write_outpost

# The grid searched on val (the rest of ObjectParams stays at its defaults).
GRID: dict[str, tuple[Any, ...]] = {
    "confirm": ((3, 5), (5, 8)),
    # (min_region_score, hit_region_score): the score a region needs to start an object,
    # and to continue one.
    "scores": ((0.5, 0.5), (0.5, 0.2), (0.5, 0.0), (0.2, 0.2), (0.0, 0.0)),
    "gate_sigma": (3.0, 5.0),
    "size_ratio_max": (2.0, 4.0),
    "parallax_sigma": (3.0, 4.0),
    "edge_sigma_fraction": (0.5, 2.0),
    "residual_quantile": (0.999, 1.0),
    # 1e6: no steady-size test; no partial-region rule.
    "steady_size_ratio": (1.25, 1e6),
    "partial_size_ratio": (2.0, 1e6),
}
# The grid's fields (``confirm`` sets confirm_hits and confirm_window, ``scores``
# min_region_score and hit_region_score).
GRID_FIELDS = (
    "confirm_hits",
    "confirm_window",
    "min_region_score",
    "hit_region_score",
    "gate_sigma",
    "size_ratio_max",
    "parallax_sigma",
    "edge_sigma_fraction",
    "residual_quantile",
    "steady_size_ratio",
    "partial_size_ratio",
)
# The targets: name -> (key, bound, kind).
TARGETS = {
    "recall >= 0.95": ("recall", 0.95, "min"),
    "precision >= 0.95": ("precision", 0.95, "min"),
    "error median <= 0.25 m": ("error_m_median", 0.25, "max"),
    "error p90 <= 0.6 m": ("error_m_p90", 0.6, "max"),
    "confirmation <= 0.5 s": ("confirmation_s_median", 0.5, "max"),
    "false objects <= 0.1/min": ("false_objects_per_min", 0.1, "max"),
    "normal flagged ratio <= 0.2": ("normal_frames_flagged_ratio", 0.2, "max"),
}


def met(report: dict[str, Any]) -> dict[str, bool]:
    """Which targets ``report`` meets (the ratio also needs equal or better frame recall)."""
    out = {}
    for name, (key, bound, kind) in TARGETS.items():
        value = report.get(key)
        out[name] = value is not None and (value >= bound if kind == "min" else value <= bound)
    frame = report["frame_level"]
    recall_objects = frame["objects"]["recall"] or 0.0
    recall_frame = frame["frame"]["recall"] or 0.0
    out["normal flagged ratio <= 0.2"] &= recall_objects >= recall_frame
    return out


def rank_key(report: dict[str, Any]) -> tuple[float, ...]:
    """Higher is better: targets met, F1 of recall and precision, then a smaller error."""
    recall = report["recall"] or 0.0
    precision = report["precision"] or 0.0
    f1 = 2 * recall * precision / (recall + precision) if recall + precision else 0.0
    error = report["error_m_median"]
    return (sum(met(report).values()), f1, -(error if error is not None else 1e9))


def grid_params(base: ObjectParams) -> list[ObjectParams]:
    """Every combination of :data:`GRID` on ``base``."""
    combos = []
    for (hits, window), (start, hit), *rest in itertools.product(*GRID.values()):
        changes = dict(zip(list(GRID)[2:], rest, strict=True))
        combos.append(
            base.replace(
                confirm_hits=hits,
                confirm_window=window,
                min_region_score=start,
                hit_region_score=hit,
                **changes,
            )
        )
    return combos


def report_of(run: ObjectRun, params: ObjectParams) -> dict[str, Any]:
    """The metrics of tracking ``run`` with ``params``, as a dict, with the tracker's time."""
    metrics, timings = score_run(run, params)
    report = metrics.as_dict()
    report["tracker_ms_per_frame_data"] = statistics.median(timings) if timings else None
    return report


def generate(path: Path, preset: str, seed: int, *options: str) -> None:
    """Generate ``preset`` into ``path`` unless a sequence is there (``options``: more
    ``allo-synth generate`` arguments)."""
    if (path / "sequence.yaml").is_file():
        return
    command = [sys.executable, "-m", "allo_mrad_ros.synth.entry", "generate"]
    command += ["--preset", preset, "--seed", str(seed), "--out", str(path), "--quiet", *options]
    print("generating:", " ".join(command[2:]), flush=True)
    subprocess.run(command, check=True)


def ensure_data(path: Path, width: int | None, height: int | None, seed: int) -> None:
    """Generate the objects preset into ``path`` unless a sequence is there."""
    options = [] if width is None else ["--width", str(width)]
    options += [] if height is None else ["--height", str(height)]
    generate(path, "objects", seed, *options)


PT_SPLIT = "test, path-traced"
"""How the path-traced station's test split is named in the printed tables."""


def station_of(sequence: Path) -> str | None:
    """The station model a generated sequence was rendered with (its ``generation.json``),
    or None where that does not say."""
    try:
        mesh = json.loads((sequence / "generation.json").read_text())["mesh"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return Path(str(mesh)).stem


def path_traced_result(
    path: Path | None, run: ObjectRun | None, reports: dict[str, dict[str, Any]]
) -> dict[str, Any]:
    """The report's entries of the path-traced station (none when it was left out)."""
    if path is None or run is None:
        return {}
    chosen, defaults = reports.values()
    return {
        "path_traced": {
            "data": str(path),
            "station": station_of(path),
            "frames": len(run.frames),
            "camera": {"width": run.camera.width, "height": run.camera.height},
        },
        "test_path_traced": chosen,
        "test_path_traced_defaults": defaults,
        "targets_met_test_path_traced": met(chosen),
    }


def ensure_path_traced(path: Path, mesh: Path, seed: int) -> None:
    """Generate the ``objects-pt`` preset on ``mesh`` into ``path`` unless a sequence is
    there (``mesh`` itself is written when it is missing and names one of the outposts)."""
    if (path / "sequence.yaml").is_file():
        return
    if not mesh.is_file():
        if mesh.stem not in OUTPOSTS:
            raise SystemExit(
                f"--path-traced-mesh {mesh}: no such file, and not one of the outposts "
                f"({', '.join(f'{name}.glb' for name in OUTPOSTS)})"
            )
        write_outpost(mesh)
    generate(path, "objects-pt", seed, "--mesh", str(mesh))


def detections(data: Path, cache: Path, split: str, config: PipelineConfig, jobs: int) -> ObjectRun:
    """The detected frames of ``split``, from the cache when its key (the sequence's rows,
    the split, the configuration and the package's code) matches."""
    frames_csv = (data / "frames.csv").read_bytes()
    key = repr((split, config, package_digest()))
    key = hashlib.sha256(frames_csv + key.encode()).hexdigest()[:16]
    path = cache / f"{split}-{key}.pkl"
    if path.is_file():
        with path.open("rb") as handle:
            name, camera, frames, wall_s = pickle.load(handle)
        return ObjectRun(name, camera, read_sequence(data).objects, frames, wall_s)
    run = detect_frames(data, pipeline=config, split=split, jobs=jobs, progress=True)
    cache.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial")
    with partial.open("wb") as handle:
        # The objects are read again from the sequence (they do not pickle).
        state = (run.name, run.camera, run.frames, run.wall_s)
        pickle.dump(state, handle, protocol=pickle.HIGHEST_PROTOCOL)
    partial.replace(path)
    return run


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def table(reports: dict[str, dict[str, Any]]) -> str:
    """The headline metrics of each report side by side, as Markdown."""
    names = list(reports)
    rows = [
        "| metric | " + " | ".join(names) + " |",
        "|---|" + "---:|" * len(names),
    ]
    for key in (*HEADLINE_METRICS, "tracker_ms_per_frame_data"):
        rows.append(f"| {key} | " + " | ".join(_fmt(reports[n].get(key)) for n in names) + " |")
    for decision in ("objects", "frame"):
        for what in ("recall", "false_alarm_rate", "normal_flagged"):
            cells = [_fmt(reports[n]["frame_level"][decision][what]) for n in names]
            rows.append(f"| frames, decision {decision}: {what} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def group_table(report: dict[str, Any], key: str) -> str:
    """Per type or per placement rows of one report, as Markdown."""
    rows = [
        f"| {key.removeprefix('per_')} | objects | recall | error median m | error p90 m | "
        "confirmation s | frame recall, objects | frame recall, frame |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, row in report[key].items():
        cells = (
            row["objects"],
            row["recall"],
            row["error_m_median"],
            row["error_m_p90"],
            row["confirmation_s_median"],
            row["frame_recall_objects"],
            row["frame_recall_frame"],
        )
        rows.append(f"| {label} | " + " | ".join(_fmt(c) for c in cells) + " |")
    return "\n".join(rows)


def coverage_of(data: Path, runs: dict[str, ObjectRun]) -> dict[str, dict[str, dict[str, int]]]:
    """Per split, how much of the showing objects the detection mask covers (per placement)."""
    sequence = read_sequence(data, check_images=False)

    def instances(index: int) -> Any:
        return sequence.load_instances(sequence.frames[index])

    return {split: detection_coverage(run, instances) for split, run in runs.items()}


def coverage_table(coverage: dict[str, dict[str, dict[str, int]]]) -> str:
    """Object-frames the detection mask touches (a pixel) and half covers, as Markdown."""
    rows = [
        "| split | placement | object-frames | touched by the mask | half covered |",
        "|---|---|---:|---:|---:|",
    ]
    for split, groups in coverage.items():
        for placement, row in groups.items():
            rows.append(
                f"| {split} | {placement} | {row['object_frames']} | {row['touched']} | "
                f"{row['half_covered']} |"
            )
    return "\n".join(rows)


def diagnosis_table(rows: list[ObjectDiagnosis]) -> str:
    """Per object, where it was lost (:class:`ObjectDiagnosis`), as Markdown, with the
    count of each cause among the objects in view long enough to count for recall."""
    lines = [
        "| object | type | placement | frames showing | with a region | taken | regions "
        "| tracks | main track | waiting / unresolved | confirmed tracks | distance m | match m "
        "| cause |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        cells = (
            f"{row.id}{'' if row.eligible else ' (< 1 s)'}",
            row.type,
            row.placement,
            row.frames_showing,
            row.frames_touched,
            row.frames_tracked,
            row.regions,
            row.tracks,
            row.main_track_regions,
            f"{row.main_track_waiting} / {row.main_track_unresolved}",
            row.confirmed_tracks,
            _fmt(row.distance_m),
            _fmt(row.tolerance_m),
            row.cause,
        )
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    causes: dict[str, int] = {}
    for row in rows:
        if row.eligible:
            causes[row.cause] = causes.get(row.cause, 0) + 1
    counted = ", ".join(f"{k} {v}" for k, v in causes.items())
    lines += ["", f"causes (objects in view >= 1 s): {counted}"]
    return "\n".join(lines)


def diagnose(
    data: Path,
    cache: Path,
    params: ObjectParams,
    config: PipelineConfig,
    jobs: int,
    *,
    split: str = "val",
) -> list[ObjectDiagnosis]:
    """:func:`diagnose_objects` on ``split`` of ``data``, with the detections of ``config``."""
    run = detections(data, cache, split, config, jobs)
    sequence = read_sequence(data, check_images=False)
    rows = diagnose_objects(run, params, lambda i: sequence.load_instances(sequence.frames[i]))
    print(diagnosis_table(rows))
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Objects in the station frame, val and test.")
    parser.add_argument("--data", type=Path, default=Path("data/objects"))
    parser.add_argument("--width", type=int, help="when generating (default the preset's 960)")
    parser.add_argument("--height", type=int, help="when generating (default the preset's 540)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cache", type=Path, default=Path("data/bench_objects_cache"))
    parser.add_argument("--jobs", type=int, default=1, help="detection worker processes")
    parser.add_argument("--out", type=Path, default=Path("reports/bench_objects.json"))
    parser.add_argument(
        "--path-traced",
        default="data/objects_pt",
        help="the path-traced second station's sequence (objects-pt preset); '' leaves it out",
    )
    parser.add_argument(
        "--path-traced-mesh",
        type=Path,
        default=Path("data/stations_pt/outpost_spine.glb"),
        help="when generating it: the station model (default the outpost spine)",
    )
    parser.add_argument(
        "--path-traced-seed", type=int, default=7, help="when generating it (default 7)"
    )
    parser.add_argument(
        "--diagnose",
        nargs="?",
        const="val",
        choices=("val", "path-traced"),
        help="follow each object of val (or of the path-traced station's test split) through "
        "detection, tracking and matching; no grid",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        help="with --diagnose: a tracker parameter, name=value (repeated)",
    )
    parser.add_argument(
        "--detector",
        action="append",
        default=[],
        help="a detector parameter (MradParams), name=value (repeated): the detections the "
        "tracker is fed (and its parameters chosen on)",
    )
    args = parser.parse_args(argv)

    ensure_data(args.data, args.width, args.height, args.seed)
    try:
        detector = params_from("default", args.detector)
        tracker_changes = object_params_from(args.param)
    except ValueError as error:  # ParamsError, ObjectsError
        raise SystemExit(str(error)) from None
    config = PipelineConfig(methods=("MRAD",), params=detector)
    if args.diagnose == "val":
        diagnose(args.data, args.cache, tracker_changes, config, args.jobs)
        return
    if args.diagnose == "path-traced":
        if not args.path_traced:
            raise SystemExit("--diagnose path-traced needs --path-traced")
        path_traced = Path(args.path_traced)
        ensure_path_traced(path_traced, args.path_traced_mesh, args.path_traced_seed)
        diagnose(path_traced, args.cache, tracker_changes, config, args.jobs, split="test")
        return
    runs = {s: detections(args.data, args.cache, s, config, args.jobs) for s in ("val", "test")}
    coverage = coverage_of(args.data, runs)
    path_traced = Path(args.path_traced) if args.path_traced else None
    pt_run = None
    if path_traced is not None:
        ensure_path_traced(path_traced, args.path_traced_mesh, args.path_traced_seed)
        pt_run = detections(path_traced, args.cache, "test", config, args.jobs)
        coverage[PT_SPLIT] = coverage_of(path_traced, {"test": pt_run})["test"]
    print(coverage_table(coverage))

    defaults = ObjectParams()
    candidates = grid_params(defaults)
    val_reports = []
    for params in candidates:
        val_reports.append((params, report_of(runs["val"], params)))
    best_params, best_val = max(val_reports, key=lambda item: rank_key(item[1]))
    test_chosen = report_of(runs["test"], best_params)
    test_defaults = report_of(runs["test"], defaults)
    val_defaults = report_of(runs["val"], defaults)
    timings, live = tracker_bench.run(50, 20, 300, 30, 0)
    tracker_ms = statistics.median(timings)
    for report in (best_val, test_chosen, val_defaults, test_defaults):
        report["tracker_ms_per_frame"] = tracker_ms

    chosen = {k: getattr(best_params, k) for k in GRID_FIELDS}
    print(f"chosen on val ({len(candidates)} parameter sets): {chosen}")
    reports = {
        "val (chosen)": best_val,
        "test (chosen)": test_chosen,
        "val (defaults)": val_defaults,
        "test (defaults)": test_defaults,
    }
    pt_reports: dict[str, dict[str, Any]] = {}
    if pt_run is not None:
        pt_reports = {
            f"{PT_SPLIT} (chosen)": report_of(pt_run, best_params),
            f"{PT_SPLIT} (defaults)": report_of(pt_run, defaults),
        }
        for report in pt_reports.values():
            report["tracker_ms_per_frame"] = tracker_ms
        reports.update(pt_reports)
    print(table(reports))
    groups = [("val", best_val), ("test", test_chosen)]
    if pt_reports:
        groups.append((PT_SPLIT, pt_reports[f"{PT_SPLIT} (chosen)"]))
    for split, report in groups:
        for key in ("per_type", "per_placement"):
            print(f"\n{split}, chosen parameters:\n{group_table(report, key)}")
    print(f"\ntargets met on test (chosen): {met(test_chosen)}")
    for name, report in pt_reports.items():
        print(f"targets met on {name}: {met(report)}")
    print(f"tracker: 20 regions, {live} objects: median {tracker_ms:.3f} ms per frame")

    args.out.parent.mkdir(parents=True, exist_ok=True)
    result = {
        "data": str(args.data),
        "frames": {s: len(r.frames) for s, r in runs.items()},
        "camera": {"width": runs["test"].camera.width, "height": runs["test"].camera.height},
        "detector_changes": list(args.detector),
        "chosen_params": dict(vars(best_params)),
        "defaults": dict(vars(defaults)),
        "grid": {k: [list(v) if isinstance(v, tuple) else v for v in vs] for k, vs in GRID.items()},
        "val": best_val,
        "test": test_chosen,
        "val_defaults": val_defaults,
        "test_defaults": test_defaults,
        "targets_met_test": met(test_chosen),
        **path_traced_result(path_traced, pt_run, pt_reports),
        "detection_coverage": coverage,
        "grid_results": [
            {
                "params": {k: getattr(p, k) for k in GRID_FIELDS},
                **{k: r[k] for k in ("recall", "precision", "error_m_median")},
                "false_objects_per_min": r["false_objects_per_min"],
                "normal_frames_flagged_ratio": r["normal_frames_flagged_ratio"],
            }
            for p, r in val_reports
        ],
    }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
