"""Report files of ``evaluate`` and ``ablate``: Markdown, JSON and PNG figures.

JSON holds fractions in 0..1 (``null`` where a metric is undefined, e.g. I.AUROC without
normal frames); Markdown shows percentages like the paper's tables. Figures are drawn with
matplotlib's Agg canvas through :class:`matplotlib.figure.Figure`, without pyplot, so no
display and no global state are involved.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from matplotlib.figure import Figure

from allo_mrad_ros.detector import MradParams
from allo_mrad_ros.errors import BackendError
from allo_mrad_ros.metrics import AlloMetrics

if TYPE_CHECKING:
    from allo_mrad_ros.evaluation.ablate import AblationResult
    from allo_mrad_ros.evaluation.evaluate import EvaluationResult

# Which computation each is: the docstring of the allo_mrad_ros.metrics package.
METRIC_KEYS = ("i_auroc", "p_auroc", "p_ap", "p_aupr", "p_fpr95", "p_fpr95_interp")
METRIC_TITLES = (
    "I.AUROC",
    "P.AUROC",
    "P.AP (step)",
    "P.AUPR (trapezoid)",
    "P.FPR95 (first)",
    "P.FPR95 (interp.)",
)
_TRUTH_COLOUR = (60, 220, 60)
_DETECTION_COLOUR = np.array([230, 40, 40], dtype=np.float32)


class ReportError(BackendError):
    """A report cannot be written (the message names the file)."""


def _clean(value: Any) -> Any:
    """JSON-safe copy: NaN and infinities become null, NumPy scalars plain numbers."""
    if isinstance(value, Mapping):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        number = float(value)
        return number if math.isfinite(number) else None
    return value


def _percent(value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{100.0 * value:.1f}"


def _metrics_row(label: str, metrics: Mapping[str, float]) -> str:
    cells = " | ".join(_percent(metrics.get(key)) for key in METRIC_KEYS)
    return f"| {label} | {cells} |"


def _params_text(params: MradParams) -> str:
    return ", ".join(f"{k}={v}" for k, v in params.to_dict().items())


def _write_text(path: Path, text: str) -> None:
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        temporary.write_text(text, encoding="utf-8")
        temporary.replace(path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        raise ReportError(f"{path}: cannot write: {error.strerror}") from None


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    _write_text(path, json.dumps(_clean(data), indent=2, allow_nan=False) + "\n")


def _write_tables(out: Path, stem: str, data: Mapping[str, Any], text: str) -> list[Path]:
    """Write ``<stem>.json`` and ``<stem>.md`` into ``out``; return both paths."""
    _write_json(out / f"{stem}.json", data)
    _write_text(out / f"{stem}.md", text)
    return [out / f"{stem}.json", out / f"{stem}.md"]


def _save(figure: Figure, path: Path) -> None:
    try:
        figure.savefig(path, dpi=110, format="png")
    except OSError as error:
        raise ReportError(f"{path}: cannot write: {error.strerror}") from None


def _prepare(out: str | PathLike[str]) -> Path:
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ReportError(f"{out}: cannot create the report folder: {error.strerror}") from None
    return out


# ---------------------------------------------------------------------- evaluation
def evaluation_json(result: EvaluationResult) -> dict[str, Any]:
    """The content of ``metrics.json``."""
    config = result.config
    return {
        "frames": result.frames,
        "methods": {name: m.as_dict() for name, m in result.metrics.items()},
        "pixel_error_bounds": {name: m.error_bounds for name, m in result.metrics.items()},
        "split": result.split,
        "input": {"path": result.input, "kind": result.kind, "name": result.name},
        "per_anomaly_type": result.per_type,
        "detection": result.detection,
        "latency_ms": result.latency_ms,
        "throughput": {
            "frames_per_second": result.frames_per_second,
            "wall_s": result.wall_s,
            "jobs": config.jobs,
        },
        "params": config.pipeline.params.to_dict(),
        "reference_scale": config.pipeline.render.reference_scale,
        "shadows": config.pipeline.render.shadows,
    }


def _latency_rows(
    latency: Mapping[str, Mapping[str, float]], methods: tuple[str, ...]
) -> list[str]:
    rows = ["| stage | median | p95 | mean |", "|---|---:|---:|---:|"]
    # The pipeline in processing order, then each method's inner stages.
    first = [s for s in ("render", *methods, "total") if s in latency]
    order = first + sorted(s for s in latency if s not in first)
    for stage in order:
        s = latency[stage]
        rows.append(f"| {stage} | {s['median']:.1f} | {s['p95']:.1f} | {s['mean']:.1f} |")
    return rows


def _exactness(metrics: Mapping[str, AlloMetrics]) -> str:
    """Whether the pixel metrics are exact, or the largest bound on their error."""
    largest = {
        name: max((b for b in m.error_bounds.values() if math.isfinite(b)), default=0.0)
        for name, m in metrics.items()
    }
    inexact = {name: bound for name, bound in largest.items() if bound > 0}
    if not inexact:
        return "Pixel metrics are exact (pixels counted per distinct score)."
    bounds = ", ".join(f"{name} {100 * bound:.2g}" for name, bound in inexact.items())
    return (
        "Pixel metrics are exact up to a bound where a run holds more distinct scores than "
        f"are kept apart; the largest bound, in percentage points: {bounds} (each metric's "
        "bound: `pixel_error_bounds` in metrics.json)."
    )


def evaluation_markdown(result: EvaluationResult) -> str:
    """The content of ``metrics.md``."""
    config = result.config
    header = "| method | " + " | ".join(METRIC_TITLES) + " |"
    rule = "|---|" + "---:|" * len(METRIC_TITLES)
    split = result.split or "all frames"
    lines = [
        f"# ALLO metrics: {result.name}",
        "",
        f"Input: {result.kind} `{Path(result.input).name}`, split {split}, "
        f"{result.frames} frames. Values in percent (P.FPR95: lower is better).",
        "",
        header,
        rule,
        *(_metrics_row(name, m.as_dict()) for name, m in result.metrics.items()),
        "",
        _exactness(result.metrics),
        "",
        "Image-level decisions (anomalous when the detected area exceeds the threshold):",
        "",
        "| method | TP | FP | TN | FN |",
        "|---|---:|---:|---:|---:|",
        *(
            f"| {name} | {c['tp']} | {c['fp']} | {c['tn']} | {c['fn']} |"
            for name, c in result.detection.items()
        ),
        "",
    ]
    if result.per_type:
        lines += [
            "## Per anomaly type",
            "",
            "Each type's anomalous frames together with all normal frames of the split.",
            "",
            "| type | frames | method | " + " | ".join(METRIC_TITLES) + " |",
            "|---|---:|---|" + "---:|" * len(METRIC_TITLES),
        ]
        for anomaly, entry in result.per_type.items():
            for name, metrics in entry["methods"].items():
                cells = " | ".join(_percent(metrics.get(k)) for k in METRIC_KEYS)
                lines.append(f"| {anomaly} | {entry['frames']} | {name} | {cells} |")
        lines += [
            "",
            "Localisation per type (anomalous frames only): found = some object pixel detected; "
            "recall = fraction of the object's pixels in the mask; IoU = mask against object.",
            "",
            "| type | method | found | recall | IoU |",
            "|---|---|---:|---:|---:|",
        ]
        for anomaly, entry in result.per_type.items():
            for name, loc in entry.get("localisation", {}).items():
                cells = " | ".join(_percent(loc[k]) for k in ("found", "recall", "iou"))
                lines.append(f"| {anomaly} | {name} | {cells} |")
        lines.append("")
    lines += [
        "## Latency",
        "",
        "Milliseconds per frame in one worker process: `render` is the reference, each "
        "method's row its detection, `total` all methods together; `METHOD/stage` rows are "
        "the detector's inner stages.",
        "",
        *_latency_rows(result.latency_ms, config.pipeline.methods),
        "",
        f"Throughput: {result.frames_per_second:.2f} frames/s with {config.jobs} job(s) "
        f"({result.frames} frames in {result.wall_s:.1f} s, all methods).",
        "",
        "## Settings",
        "",
        f"- reference scale {config.pipeline.render.reference_scale}, "
        f"shadows {'on' if config.pipeline.render.shadows else 'off'}",
        "- MRAD parameters: " + _params_text(config.pipeline.params),
        "",
        "Figures: `roc.png`, `pr.png`, `overlays.png` (green: ground-truth anomaly outline, "
        "red: detected pixels).",
        "",
    ]
    return "\n".join(lines)


def plot_curves(result: EvaluationResult, out: Path) -> list[Path]:
    """Write the pooled-pixel ROC and PR curves of every method; return the files."""
    written = []
    for kind in ("roc", "pr"):
        figure = Figure(figsize=(5.0, 4.2))
        axes = figure.add_subplot()
        for name, curve in result.curves.items():
            if curve is None:
                continue
            metrics = result.metrics[name]
            if kind == "roc":
                axes.plot(curve.fpr, curve.tpr, label=f"{name} (AUROC {_percent(metrics.p_auroc)})")
            else:
                axes.plot(curve.tpr, curve.precision, label=f"{name} (AP {_percent(metrics.p_ap)})")
        if kind == "roc":
            axes.plot([0, 1], [0, 1], color="0.7", linestyle=":", linewidth=1)
            axes.set_xlabel("false-positive rate")
            axes.set_ylabel("true-positive rate")
            axes.set_title("Pixel ROC")
        else:
            axes.set_xlabel("recall")
            axes.set_ylabel("precision")
            axes.set_title("Pixel precision-recall")
        axes.set_xlim(0, 1)
        axes.set_ylim(0, 1.02)
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(loc="lower right" if kind == "roc" else "upper right", fontsize=8)
        figure.tight_layout()
        path = out / f"{kind}.png"
        _save(figure, path)
        written.append(path)
    return written


def _outlined(image: np.ndarray, truth: np.ndarray) -> np.ndarray:
    canvas = np.ascontiguousarray(image.copy())
    contours, _ = cv2.findContours(truth.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(canvas, contours, -1, _TRUTH_COLOUR, 1)
    return canvas


def _tinted(image: np.ndarray, mask: np.ndarray) -> np.ndarray:
    canvas = image.astype(np.float32)
    hit = mask > 0
    canvas[hit] = 0.45 * canvas[hit] + 0.55 * _DETECTION_COLOUR
    return canvas.astype(np.uint8)


def plot_overlays(result: EvaluationResult, out: Path) -> Path | None:
    """Write the overlay grid (one row per example frame); None if there are no examples."""
    rows = result.overlays
    if not rows:
        return None
    methods = list(result.config.pipeline.methods)
    height, width = rows[0].overlay.image.shape[:2]
    columns = 1 + len(methods)
    scale = 2.4 / max(width, 1)
    figure = Figure(figsize=(columns * width * scale, len(rows) * height * scale + 0.4))
    for r, outcome in enumerate(rows):
        overlay = outcome.overlay
        base = overlay.image
        panels = [("image", _outlined(base, overlay.truth))]
        for name in methods:
            verdict = "anomalous" if outcome.methods[name].anomalous else "normal"
            tinted = _tinted(base, overlay.masks[name])
            panels.append((f"{name}: {verdict}", _outlined(tinted, overlay.truth)))
        for c, (title, picture) in enumerate(panels):
            axes = figure.add_subplot(len(rows), columns, r * columns + c + 1)
            axes.imshow(picture)
            axes.set_xticks([])
            axes.set_yticks([])
            label = f"{outcome.name} [{outcome.group}]" if c == 0 else title
            axes.set_title(label, fontsize=7)
    figure.tight_layout()
    path = out / "overlays.png"
    _save(figure, path)
    return path


def write_evaluation_report(result: EvaluationResult, out: str | PathLike[str]) -> list[Path]:
    """Write ``metrics.md``, ``metrics.json``, ``roc.png``, ``pr.png`` and ``overlays.png``.

    Returns
    -------
    list of pathlib.Path
        The files written.

    Raises
    ------
    ReportError
        If a file cannot be written.
    """
    out = _prepare(out)
    written = _write_tables(out, "metrics", evaluation_json(result), evaluation_markdown(result))
    written += plot_curves(result, out)
    overlays = plot_overlays(result, out)
    if overlays is not None:
        written.append(overlays)
    return written


# ---------------------------------------------------------------------- ablation
def ablation_json(result: AblationResult) -> dict[str, Any]:
    """The content of ``ablation.json``."""
    return {
        "frames": result.frames,
        "split": result.split,
        "input": {"path": result.input, "kind": result.kind, "name": result.name},
        "baseline": result.baseline.to_dict(),
        "reference_scale": result.reference_scale,
        "rows": [
            {
                "sweep": row.sweep,
                "setting": row.label,
                "value": row.value,
                "baseline": row.is_baseline,
                **row.metrics.as_dict(),
                "mrad_ms_median": row.mrad_ms_median,
            }
            for row in result.rows
        ],
        "render_ms_median": result.render_ms_median,
        "wall_s": result.wall_s,
        "jobs": result.jobs,
    }


def ablation_markdown(result: AblationResult) -> str:
    """The content of ``ablation.md``: one table, one block of rows per sweep."""
    split = result.split or "all frames"
    lines = [
        f"# MRAD ablation (paper Table II sweeps): {result.name}",
        "",
        f"Input: {result.kind} `{Path(result.input).name}`, split {split}, {result.frames} "
        "frames. One parameter varies per block, the others stay at the baseline (marked *). "
        "Values in percent.",
        "",
        "| sweep | setting | " + " | ".join(METRIC_TITLES) + " | MRAD ms (median) |",
        "|---|---|" + "---:|" * (len(METRIC_TITLES) + 1),
    ]
    for row in result.rows:
        mark = " *" if row.is_baseline else ""
        cells = " | ".join(_percent(v) for v in _metric_values(row.metrics))
        lines.append(f"| {row.sweep} | {row.label}{mark} | {cells} | {row.mrad_ms_median:.1f} |")
    lines += [
        "",
        f"Reference rendered once per frame (median {result.render_ms_median:.1f} ms, "
        f"scale {result.reference_scale}) and reused by all {result.configs} parameter sets; "
        f"{result.wall_s:.1f} s with {result.jobs} job(s).",
        "",
        "Baseline: " + _params_text(result.baseline),
        "",
    ]
    return "\n".join(lines)


def _metric_values(metrics: AlloMetrics) -> list[float]:
    return [getattr(metrics, key) for key in METRIC_KEYS]


def write_ablation_report(result: AblationResult, out: str | PathLike[str]) -> list[Path]:
    """Write ``ablation.md`` and ``ablation.json``; return the files (ReportError if not)."""
    return _write_tables(
        _prepare(out), "ablation", ablation_json(result), ablation_markdown(result)
    )
