"""The trade-off benchmark's selection rule (Pareto front, default choice), its tables and plots."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from allo_mrad_ros.metrics import bootstrap_ap_difference
from benchmarks.tradeoff_settings import MASK_PHOTOMETRIC, Outcome, map_key


def pareto_front(rows: Iterable[dict]) -> list[dict]:
    """Rows that no other row beats on both median latency and P.AP."""
    rows = list(rows)
    return [
        r
        for r in rows
        if not any(
            o["latency_ms_median"] <= r["latency_ms_median"]
            and o["p_ap"] >= r["p_ap"]
            and (o["latency_ms_median"] < r["latency_ms_median"] or o["p_ap"] > r["p_ap"])
            for o in rows
        )
    ]


def _candidates(rows: Iterable[dict]) -> list[dict]:
    """The rows that may become the default: MRAD with outputs that docs/method.md ("How
    defaults are chosen") admits."""
    return [r for r in rows if r["conforms_to_mrad_md"] and r["method"] == "MRAD"]


def most_accurate(rows: Sequence[dict]) -> dict:
    """The candidate row with the highest P.AP."""
    return max(_candidates(rows), key=lambda r: r["p_ap"])


def most_accurate_with_speedup(rows: Sequence[dict], speedup: float) -> dict | None:
    """The most accurate candidate row at least ``speedup`` times faster than the most
    accurate candidate of all (None if no row is that fast)."""
    best = most_accurate(rows)
    fast = [
        r
        for r in _candidates(rows)
        if r["latency_ms_median"] * speedup <= best["latency_ms_median"]
    ]
    return max(fast, key=lambda r: r["p_ap"]) if fast else None


def describe_speedup_tier(rows: Sequence[dict], speedup: float) -> str:
    """One line naming :func:`most_accurate_with_speedup` and its P.AP gap."""
    best, fast = most_accurate(rows), most_accurate_with_speedup(rows, speedup)
    if fast is None:
        return f"no setting is {speedup:g}x faster than the most accurate ({best['setting']})"
    return (
        f"most accurate setting at least {speedup:g}x faster than the most accurate: "
        f"{fast['setting']} ({fast['latency_ms_median']:.1f} ms, "
        f"{best['latency_ms_median'] / fast['latency_ms_median']:.1f}x), "
        f"{100 * (best['p_ap'] - fast['p_ap']):.1f} P.AP points below it"
    )


def reprint(report: dict, speedup: float) -> None:
    """Print the tables and the summary lines of a saved ``speed_vs_error.json``."""
    default = report["default_setting"]
    print(f"validation ({report.get('validation_sequence', report['sequence'])}, val split)")
    print(format_table(report["rows"], default))
    print(f"* chosen default ({report['choice_rule']}): {default}\n")
    print(f"test ({report['sequence']}, test split)")
    print(format_table(report["test_rows"], default))
    print(describe_default_on_test(report["test_summary"]))
    mrad_test = [r for r in report["test_rows"] if r["method"] == "MRAD"]
    print(describe_speedup_tier(mrad_test, speedup))


def choose_default(rows: Sequence[dict], ap_margin: float) -> dict:
    """The fastest Pareto-front row within ``ap_margin`` P.AP points of the best, among the
    rows whose outputs docs/method.md admits."""
    rows = _candidates(rows)
    best = max(r["p_ap"] for r in rows)
    eligible = [r for r in pareto_front(rows) if r["p_ap"] >= best - ap_margin / 100.0]
    return min(eligible, key=lambda r: r["latency_ms_median"])


def choose_mask(rows: Sequence[dict], chosen: dict, margin: float = 0.01) -> dict:
    """The mask for ``chosen``'s map.

    The eligible rows have ``chosen``'s map (:func:`map_key`, so the same P.AP) and the
    photometric model the robustness tests require (:data:`MASK_PHOTOMETRIC`); ``chosen``
    itself when none does. The incumbent is ``chosen`` if eligible, else the first eligible
    row (the sweep lists the base's mask first); another row replaces it only when its
    anomalous flag's balanced accuracy (reports without it: I.AUROC) is more than ``margin``
    higher, so a difference of a few frames does not move the default.
    """
    eligible = [
        r
        for r in _candidates(rows)
        if map_key(r) == map_key(chosen) and r["params"]["photometric"] == MASK_PHOTOMETRIC
    ]
    if not eligible:
        return chosen

    def merit(r: dict) -> float:
        value = r.get("flag_balanced_accuracy", r["i_auroc"])
        return -math.inf if value is None or math.isnan(value) else value

    incumbent = chosen if chosen in eligible else eligible[0]
    best = max(eligible, key=merit)
    return best if merit(best) > merit(incumbent) + margin else incumbent


def format_table(rows: Sequence[dict], default: str | None = None) -> str:
    """The printed table (metrics in percent)."""
    lines = [
        f"{'setting':<62}{'ms p50':>8}{'ms p95':>8}{'render':>8}{'detect':>8}"
        f"{'P.AP':>7}{'AUPR':>7}{'I.AUROC':>9}{'FPR95':>7}{'interp':>7}{'P.AUROC':>9}"
    ]
    for r in rows:
        mark = " *" if r["setting"] == default else ""
        method = r["method"] + (" binary" if r.get("binary") else "")
        name = r["setting"] if r["method"] == "MRAD" else f"{method} ({r['setting']})"
        lines.append(
            f"{name + mark:<62}{r['latency_ms_median']:>8.1f}{r['latency_ms_p95']:>8.1f}"
            f"{r['render_ms_median']:>8.1f}{r['detect_ms_median']:>8.1f}"
            f"{100 * r['p_ap']:>7.1f}{100 * r.get('p_aupr', math.nan):>7.1f}"
            f"{100 * r['i_auroc']:>9.1f}{100 * r['p_fpr95']:>7.1f}"
            f"{100 * r.get('p_fpr95_interp', math.nan):>7.1f}{100 * r['p_auroc']:>9.1f}"
        )
    return "\n".join(lines)


def plot_pareto(rows: Sequence[dict], default: str, path: Path, title: str) -> None:
    """Scatter of median latency against P.AP with the Pareto front and the default."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    conforming = [r for r in rows if r.get("conforms_to_mrad_md", True)]
    front = {r["setting"] for r in pareto_front(conforming)}
    fig, ax = plt.subplots(figsize=(9, 6))
    for r in rows:
        chosen = r["setting"] == default
        ax.scatter(
            r["latency_ms_median"],
            100 * r["p_ap"],
            s=80 if chosen else 40,
            c="tab:red" if chosen else ("tab:blue" if r["setting"] in front else "tab:gray"),
            zorder=3,
        )
        ax.annotate(
            r["setting"],
            (r["latency_ms_median"], 100 * r["p_ap"]),
            fontsize=7,
            xytext=(4, 3),
            textcoords="offset points",
        )
    ordered = sorted(
        (r for r in rows if r["setting"] in front), key=lambda r: r["latency_ms_median"]
    )
    ax.plot(
        [r["latency_ms_median"] for r in ordered],
        [100 * r["p_ap"] for r in ordered],
        "--",
        c="tab:blue",
        lw=1,
        label="Pareto front",
    )
    ax.set_xscale("log")
    ax.set_xlabel("median latency per frame, render + detect (ms, log scale)")
    ax.set_ylabel("P.AP (%)")
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_robustness(rows: Sequence[dict], path: Path) -> None:
    """P.AP against rotation error and against translation error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    rot = [r for r in rows if r["translation_cm"] == 0]
    trans = [r for r in rows if r["rotation_deg"] == 0]
    left.plot([r["rotation_deg"] for r in rot], [100 * r["p_ap"] for r in rot], "o-")
    right.plot([r["translation_cm"] for r in trans], [100 * r["p_ap"] for r in trans], "o-")
    left.set_xlabel("reference rotation error (deg)")
    right.set_xlabel("reference translation error (cm)")
    left.set_ylabel("P.AP (%)")
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.suptitle("MRAD default: P.AP against reference pose error (test split)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def gap_with_interval(outcomes: Sequence[Outcome], setting: str, reference: str) -> dict:
    """P.AP points by which ``setting`` trails ``reference``, with a paired bootstrap 95 %
    interval over frames (coarse bins of 1/2: the interval, not the point, uses them)."""
    by_name = {o.setting.name: o for o in outcomes if o.setting.method == "MRAD"}
    ours, theirs = by_name[setting], by_name[reference]
    points = 100.0 * (theirs.metrics.compute().p_ap - ours.metrics.compute().p_ap)
    draws = 100.0 * bootstrap_ap_difference(np.stack(ours.counts), np.stack(theirs.counts))
    low, high = np.percentile(draws, [2.5, 97.5]) if draws.size else (math.nan, math.nan)
    return {"points": points, "interval_95": [float(low), float(high)]}


def gap_to_baseline(outcomes: Sequence[Outcome], setting: str, method: str) -> dict:
    """P.AP points by which MRAD's ``setting`` leads ``method`` (continuous map) on the same
    references, with a paired bootstrap 95 % interval over frames."""
    ours = next(o for o in outcomes if o.setting.name == setting and o.setting.method == "MRAD")
    theirs = next(
        o
        for o in outcomes
        if o.setting.name == setting and o.setting.method == method and not o.setting.binary
    )
    points = 100.0 * (ours.metrics.compute().p_ap - theirs.metrics.compute().p_ap)
    draws = 100.0 * bootstrap_ap_difference(np.stack(theirs.counts), np.stack(ours.counts))
    low, high = np.percentile(draws, [2.5, 97.5]) if draws.size else (math.nan, math.nan)
    return {"points": points, "interval_95": [float(low), float(high)]}


def describe_gap(points: float, interval_95: Sequence[float], reference: str) -> str:
    """A P.AP gap to the most accurate setting and its interval, as one phrase."""
    low, high = interval_95
    return (
        f"{points:.1f} P.AP points below the most accurate setting ({reference}; "
        f"95 % paired-bootstrap interval {low:.1f} to {high:.1f})"
    )


def describe_default_on_test(summary: dict) -> str:
    """The summary line of the default on test, from the report's ``test_summary``."""
    gap = describe_gap(
        summary["ap_gap_points"], summary["ap_gap_interval_95"], summary["best_setting"]
    )
    return (
        f"default on test: P.AP {100 * summary['default_p_ap']:.1f}, {gap}, "
        f"{summary['speedup_vs_best']:.1f}x faster than it"
    )
