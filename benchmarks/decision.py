"""The frame decision per sequence: normal frames flagged and anomalous frames found, before
(the mask's area, ``frame_rule: area``) and after (``frame_rule: contrast``).

Every frame of each named sequence split is detected once with the given parameters and its
ranking map, mask and query are cached (:mod:`benchmarks.decision_cache`); the decision is
then taken from the cache by the detector's own functions
(:func:`allo_mrad_ros.detector.decision.frame_decision`), which is exact because the decision
changes neither the mask nor the maps.

With ``--choose-on`` it also chooses the ``contrast`` rule's operating point on those
(validation) sequences: for every setting of a small grid (``frame_map``,
``frame_top_fraction``, ``frame_background``, ``frame_floor``), the threshold
``frame_contrast`` is the lowest that flags at most ``--target`` of the normal frames of
*each* of them (rounded up to 0.1), and the admissible setting (:data:`ADMISSIBLE`) that
finds the most anomalous frames on the worst of them wins (then the mean).

    python -m benchmarks.decision data/bench:test data/objects:test \\
        --choose-on data/bench_val:val data/bench:val data/objects:val

Sequences are ``PATH`` (every frame) or ``PATH:SPLIT``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.detector import DetectionResult, MradParams, detect
from allo_mrad_ros.detector.decision import (
    decision_map,
    frame_decision,
    frame_evidence,
    image_score,
)
from allo_mrad_ros.detector.images import nearest_upscale
from allo_mrad_ros.detector.params import add_params_options, params_from
from allo_mrad_ros.evaluation.sources import open_sequence
from allo_mrad_ros.metrics import roc_auc
from benchmarks import finish
from benchmarks.decision_cache import CachedFrame, SequenceSplit, cached_frames
from harness.perturbations import PERTURBATIONS

GRID = {
    "frame_map": ("mask", "ranking"),
    "frame_top_fraction": (1e-3, 3e-3, 1e-2),
    "frame_background": (0.9, 0.95, 0.99, 0.995),
    "frame_floor": (1.0, 2.0, 3.0, 5.0),
}
"""The settings ``--choose-on`` compares."""

PHOTOMETRIC_SIZE = (540, 960)
PHOTOMETRIC_PATCH = (slice(250, 280), slice(560, 590))


def photometric_results(params: MradParams) -> list[tuple[DetectionResult, DetectionResult]]:
    """The photometric robustness tests' frames (``test/test_photometric.py``: half black
    sky, half grey panel, a saturated glare patch, noise SD 2), without and with a 30 x 30
    patch 40 DN brighter, under each camera change of ``harness/perturbations.py``,
    detected against the scene's reference at a quarter of its size."""
    height, width = PHOTOMETRIC_SIZE
    scene = np.zeros((height, width, 3))
    scene[:] = (110, 110, 114)
    scene[:, : width // 3] = (4, 4, 6)
    scene[int(0.8 * height) :, int(0.7 * width) :] = 255.0
    reference = np.clip(scene, 0, 255).astype(np.uint8)
    noisy = scene + np.random.default_rng(0).normal(0, 2, scene.shape)
    clean = np.clip(noisy, 0, 255).astype(np.uint8)
    noisy[PHOTOMETRIC_PATCH] += 40.0
    query = np.clip(noisy, 0, 255).astype(np.uint8)
    small = cv2.resize(reference, (width // 4, height // 4), interpolation=cv2.INTER_AREA)
    return [
        (detect(change(clean), small, params), detect(change(query), small, params))
        for change in PERTURBATIONS.values()
    ]


def photometric_margin(results: list, setting: MradParams, threshold: float) -> float:
    """The photometric tests under ``setting`` at ``threshold``: the least ratio of a patch
    frame's contrast to the threshold, or 0 when a frame without the patch reaches it (above
    1: every patch found and every clean frame left normal)."""

    def contrast(result: DetectionResult) -> float:
        values = decision_map(result.work_score, result.raw_score, setting)
        evidence = frame_evidence(values, result.work_mask, result.work_query, setting)
        return evidence.contrast(setting.frame_floor)

    if any(contrast(clean) > threshold for clean, _ in results):
        return 0.0
    return min(contrast(patch) for _, patch in results) / threshold


def admissible(row: dict) -> bool:
    """Whether a grid row may be chosen: it reads the map of the mask's photometric model
    (the ranking map has none) and passes the photometric tests (margin above 1)."""
    return row["frame_map"] == "mask" and row["photometric_margin"] > 1.0


@dataclass(frozen=True)
class Outcome:
    """One sequence's frames under one rule: the flags and the rule's anomaly scores."""

    truth: np.ndarray
    flagged: np.ndarray
    scores: np.ndarray

    @property
    def false_alarms(self) -> float:
        """Normal frames flagged, as a fraction of the normal frames (NaN: none)."""
        normal = ~self.truth
        return float(self.flagged[normal].mean()) if normal.any() else math.nan

    @property
    def found(self) -> float:
        """Anomalous frames flagged, as a fraction of the anomalous frames (NaN: none)."""
        return float(self.flagged[self.truth].mean()) if self.truth.any() else math.nan

    @property
    def auroc(self) -> float:
        """I.AUROC of the anomaly scores (NaN without both classes)."""
        if self.truth.all() or not self.truth.any():
            return math.nan
        return roc_auc(self.scores, self.truth)


def decide_all(frames: list[CachedFrame], shape: tuple[int, int], params: MradParams) -> Outcome:
    """Every cached frame decided with ``params`` (the query's size is ``shape``)."""
    flags, scores = [], []
    for frame in frames:
        mask = frame.mask.astype(np.uint8) * 255
        full = mask if mask.shape == shape else nearest_upscale(mask, shape)
        decision = frame_decision(full, frame.score, frame.raw, mask, frame.query, params)
        flags.append(decision.anomalous)
        scores.append(decision.anomaly_score)
    truth = np.array([f.anomalous for f in frames], dtype=bool)
    return Outcome(truth, np.array(flags, dtype=bool), np.array(scores, dtype=np.float64))


def lowest_threshold(normal: list[np.ndarray], target: float) -> float:
    """The lowest threshold (rounded up to 0.1) that flags (``>``) at most ``target`` of the
    normal frames of each sequence; ``normal`` holds each sequence's normal statistics."""
    candidates = np.unique(np.concatenate([[0.0], *normal]))
    for value in candidates:
        threshold = math.ceil(value * 10.0 - 1e-9) / 10.0
        if all((stats > threshold).mean() <= target for stats in normal if stats.size):
            return max(threshold, 0.1)
    return float(math.ceil(candidates[-1] * 10.0) / 10.0 + 0.1)


def choose(
    chosen_on: dict[str, list[CachedFrame]], params: MradParams, target: float
) -> list[dict]:
    """Every grid setting with its threshold and recall on ``chosen_on``, best first."""
    rows = []
    photometric = photometric_results(params)
    for source, fraction, quantile in itertools.product(
        GRID["frame_map"], GRID["frame_top_fraction"], GRID["frame_background"]
    ):
        setting = params.replace(
            frame_map=source, frame_top_fraction=fraction, frame_background=quantile
        )
        evidence = {
            name: [
                frame_evidence(decision_map(f.score, f.raw, setting), f.mask, f.query, setting)
                for f in frames
            ]
            for name, frames in chosen_on.items()
        }
        for floor in GRID["frame_floor"]:
            stats = {
                name: np.array([e.contrast(floor) for e in values])
                for name, values in evidence.items()
            }
            truth = {
                name: np.array([f.anomalous for f in frames], dtype=bool)
                for name, frames in chosen_on.items()
            }
            threshold = lowest_threshold([stats[n][~truth[n]] for n in stats], target)
            found = {
                n: float((stats[n][truth[n]] > threshold).mean()) for n in stats if truth[n].any()
            }
            rows.append(
                {
                    "frame_map": source,
                    "frame_top_fraction": fraction,
                    "frame_background": quantile,
                    "frame_floor": floor,
                    "frame_contrast": threshold,
                    "found": found,
                    "photometric_margin": photometric_margin(
                        photometric, setting.replace(frame_floor=floor), threshold
                    ),
                    "worst": min(found.values()),
                    "mean": float(np.mean(list(found.values()))),
                }
            )
    rows.sort(key=lambda r: (not admissible(r), -r["worst"], -r["mean"]))
    return rows


def alternatives(frame: CachedFrame, params: MradParams) -> dict[str, float]:
    """Other frame statistics a threshold could be set on, from one cached frame: the mask's
    area, its largest region, the image score, the strongest region's raw peak (alone, and
    over the frame's 99.9th raw percentile outside the mask), and the contrast of ``params``."""
    mask = frame.mask.astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    background = frame.raw[mask == 0]
    level = float(np.quantile(background, 0.999)) if background.size else 0.0
    peaks = [float(frame.raw[labels == i].max()) for i in range(1, count)]
    largest = float(stats[1:, cv2.CC_STAT_AREA].max()) if count > 1 else 0.0
    contrast = frame_evidence(
        decision_map(frame.score, frame.raw, params), frame.mask, frame.query, params
    )
    return {
        "mask area": float(mask.mean()),
        "largest region": largest / mask.size,
        "image score (map top 0.1 %)": image_score(frame.score, int(mask.sum()), params),
        "region raw peak": max(peaks, default=0.0),
        "region raw peak / raw p99.9": max(peaks, default=0.0) / max(level, 1.0),
        "contrast (these settings)": contrast.contrast(params.frame_floor),
    }


def compare(
    frames: dict[str, list[CachedFrame]], chosen_on: list[str], params: MradParams, target: float
) -> dict:
    """Each alternative statistic with its threshold chosen on ``chosen_on`` as the contrast's
    is, and its normal frames flagged and anomalous frames found per sequence."""
    stats = {name: [alternatives(f, params) for f in group] for name, group in frames.items()}
    truth = {
        name: np.array([f.anomalous for f in group], dtype=bool) for name, group in frames.items()
    }
    table = {}
    for rule in next(iter(stats.values()))[0]:
        values = {name: np.array([row[rule] for row in rows]) for name, rows in stats.items()}
        normal = [values[n][~truth[n]] for n in chosen_on]
        threshold = _lowest(normal, target)
        table[rule] = {"threshold": threshold, "sequences": {}}
        for name in frames:
            outcome = Outcome(truth[name], values[name] > threshold, values[name])
            table[rule]["sequences"][name] = {
                "flagged": outcome.false_alarms,
                "found": outcome.found,
                "i_auroc": outcome.auroc,
            }
    return table


def _lowest(normal: list[np.ndarray], target: float) -> float:
    """The lowest threshold among the normal values that flags (``>``) at most ``target`` of
    each sequence's normal frames (not rounded: the statistics have their own units)."""
    for value in np.unique(np.concatenate([[0.0], *normal])):
        if all((stats > value).mean() <= target for stats in normal if stats.size):
            return float(value)
    return float(np.concatenate(normal).max())


def plot(sequences: dict[str, dict], path: Path, title: str) -> None:
    """Bars per sequence: normal frames flagged and anomalous frames found, before and after."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(sequences)
    x = np.arange(len(names))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharex=True)
    panels = (("flagged", "normal frames flagged (%)"), ("found", "anomalous frames found (%)"))
    for ax, (key, label) in zip(axes, panels, strict=True):
        for offset, when, colour in ((-0.2, "before", "tab:gray"), (0.2, "after", "tab:blue")):
            values = [100 * sequences[n][f"{key}_{when}"] for n in names]
            rule = "area" if when == "before" else "contrast"
            ax.bar(x + offset, values, 0.4, color=colour, label=f"{when} ({rule} rule)")
        if key == "flagged":
            ax.axhline(5.0, color="tab:red", lw=1, ls="--", label="5 %")
        else:
            ax.axhline(90.0, color="tab:red", lw=1, ls="--", label="90 %")
        ax.set_ylabel(label)
        ax.set_xticks(x, names, rotation=35, ha="right", fontsize=8)
        ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"written: {path}")


def percent(value: float) -> str:
    """A fraction as a percentage with one decimal (``-`` for NaN)."""
    return "-" if math.isnan(value) else f"{100 * value:.1f}"


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequences", nargs="*", type=SequenceSplit.parse, metavar="SEQ")
    parser.add_argument("--choose-on", nargs="*", default=[], type=SequenceSplit.parse)
    parser.add_argument("--target", type=float, default=0.05, help="normal frames flagged")
    parser.add_argument(
        "--alternatives",
        action="store_true",
        help="also other frame statistics, thresholds chosen on --choose-on",
    )
    parser.add_argument("--limit", type=int, default=None, help="frames per sequence")
    parser.add_argument("--cache", type=Path, default=Path("data/decision_cache"))
    parser.add_argument("--out", type=Path, default=Path("reports/decision.json"))
    parser.add_argument("--figure", type=Path, default=None, help="bar chart (PNG)")
    parser.add_argument(
        "--reference-supersampling",
        type=int,
        default=1,
        help="render each reference this many times larger and area-average it down",
    )
    add_params_options(parser)
    args = parser.parse_args(argv)
    params = params_from(args.profile, args.set)
    items = list(dict.fromkeys([*args.choose_on, *args.sequences]))
    if not items:
        parser.error("name at least one sequence")
    frames = {}
    shapes = {}
    for item in items:
        frames[item.label] = cached_frames(
            args.cache,
            item,
            limit=args.limit,
            params=params,
            supersampling=args.reference_supersampling,
        )
        camera = open_sequence(item.path).camera
        shapes[item.label] = (camera.height, camera.width)
    report: dict = {
        "params": params.to_dict(),
        "target": args.target,
        "reference_supersampling": args.reference_supersampling,
    }
    if args.choose_on:
        grid = choose({i.label: frames[i.label] for i in args.choose_on}, params, args.target)
        report["grid"] = grid
        names = [i.label for i in args.choose_on]
        print(
            f"operating points chosen on {', '.join(names)}: normal frames flagged <= "
            f"{100 * args.target:g} % on each; anomalous frames found in % (best first; "
            "the first row is chosen; photo.: the photometric tests' least patch contrast over "
            "the threshold, 0 when a clean frame is flagged; the last three may not be chosen)"
        )
        print(
            f"{'map':>8} {'top':>7} {'bg q':>6} {'floor':>6} {'contrast':>9} {'photo.':>7} "
            + "".join(f"{n[:18]:>20}" for n in names)
        )
        shown = [r for r in grid if admissible(r)][:6] + [r for r in grid if not admissible(r)][:3]
        for row in shown:
            print(
                f"{row['frame_map']:>8} {row['frame_top_fraction']:>7g} "
                f"{row['frame_background']:>6g} "
                f"{row['frame_floor']:>6g} {row['frame_contrast']:>9.1f} "
                f"{row['photometric_margin']:>7.2f} "
                + "".join(f"{percent(row['found'][n]):>20}" for n in names)
            )
        print()
    if args.alternatives and args.choose_on:
        table = compare(frames, [i.label for i in args.choose_on], params, args.target)
        report["alternatives"] = table
        names = list(frames)
        print(
            "other frame statistics, each threshold chosen as the contrast's is; normal frames "
            "flagged / anomalous frames found, in %"
        )
        print(f"{'statistic':<30}" + "".join(f"{n[:19]:>20}" for n in names))
        for rule, row in table.items():
            cells = [
                "{} / {}".format(*(percent(row["sequences"][n][k]) for k in ("flagged", "found")))
                for n in names
            ]
            print(f"{rule:<30}" + "".join(f"{c:>20}" for c in cells))
        print()
    before = params.replace(frame_rule="area")
    after = params.replace(frame_rule="contrast")
    print(
        f"frame decision per sequence at the operating point (frame_contrast "
        f"{after.frame_contrast:g}, frame_map {after.frame_map}, "
        f"frame_top_fraction {after.frame_top_fraction:g}, "
        f"frame_background {after.frame_background:g}, frame_floor {after.frame_floor:g}; "
        f"before: area_threshold {before.area_threshold:g}), in %"
    )
    print(
        f"{'sequence':<24}{'normal':>7}{'anom.':>6}"
        f"{'flagged before':>16}{'after':>7}{'found before':>14}{'after':>7}"
        f"{'I.AUROC image score':>21}{'anomaly score':>15}"
    )
    report["sequences"] = {}
    for item in items:
        name = item.label
        old = decide_all(frames[name], shapes[name], before)
        new = decide_all(frames[name], shapes[name], after)
        image_scores = np.array([_image_score(f, params) for f in frames[name]])
        image = Outcome(new.truth, new.flagged, image_scores)
        print(
            f"{name:<24}{int((~new.truth).sum()):>7}{int(new.truth.sum()):>6}"
            f"{percent(old.false_alarms):>16}{percent(new.false_alarms):>7}"
            f"{percent(old.found):>14}{percent(new.found):>7}"
            f"{percent(image.auroc):>21}{percent(new.auroc):>15}"
        )
        report["sequences"][name] = {
            "normal": int((~new.truth).sum()),
            "anomalous": int(new.truth.sum()),
            "flagged_before": old.false_alarms,
            "flagged_after": new.false_alarms,
            "found_before": old.found,
            "found_after": new.found,
            "i_auroc_image_score": image.auroc,
            "i_auroc_anomaly_score": new.auroc,
            "i_auroc_area_score": old.auroc,
        }
    if args.figure is not None:
        title = (
            f"frame decision per sequence: area rule (before) and contrast rule (after) at "
            f"frame_contrast {after.frame_contrast:g}"
        )
        plot(report["sequences"], args.figure, title)
    return finish(args.out, report)


def _image_score(frame: CachedFrame, params: MradParams) -> float:
    """The frame's image score (what ``detect`` reports) from the cached map."""
    area = int(frame.mask.sum())  # the area image score ranks alike at either resolution
    return image_score(frame.score, area, params)


if __name__ == "__main__":
    sys.exit(main())
