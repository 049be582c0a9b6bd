"""Per-frame detector outputs that the frame decision reads, cached once per sequence split.

The decision (:mod:`allo_mrad_ros.detector.decision`) reads only what the pixel stages made:
the mask's raw score, the ranking map, the mask at the processing resolution and the
regions. None of these depend on the decision's parameters, so one detection of every frame
serves every decision rule and operating point that :mod:`benchmarks.decision` compares.
Each frame's arrays go to ``<cache>/<key>/<index>.npz`` (``key``: the sequence, split, frame
limit, the pixel parameters and the package's code), written as they are made, so a run that
is stopped goes on where it was.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from allo_mrad_ros.detector import DetectionResult, MradParams
from allo_mrad_ros.detector.decision import DECISION_FIELDS
from allo_mrad_ros.evaluation.sources import open_sequence
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.render import RenderSettings
from benchmarks.source_digest import package_digest
from harness.perturbations import PERTURBATIONS, agx_like, filmic

ANOMALY = 2


PERTURBED: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "agx": agx_like,
    "filmic": filmic,
    "s-curve": PERTURBATIONS["S tone curve"],
    "ramp": PERTURBATIONS["ramp x0.6-x1.4"],
    "vignetting": PERTURBATIONS["vignetting 50 %"],
    "bloom": PERTURBATIONS["bloom"],
    "exposure-0.6": PERTURBATIONS["exposure x0.6"],
    "exposure-1.6": PERTURBATIONS["exposure x1.6"],
}
"""Camera and renderer changes a sequence's queries can be put through (``PATH:SPLIT@NAME``):
the view transforms of a path tracer (AgX-like, filmic), a tone curve, light fall-off across
the frame, glow around clipped pixels, exposure (``harness/perturbations.py``)."""


@dataclass(frozen=True)
class SequenceSplit:
    """A sequence folder, one split of it (None: every frame) and a change of its queries
    (None: as they are), as named on a command line (``PATH``, ``PATH:SPLIT``,
    ``PATH:SPLIT@NAME`` with ``NAME`` one of :data:`PERTURBED`)."""

    path: Path
    split: str | None
    perturbation: str | None = None
    limit: int | None = None

    @classmethod
    def parse(cls, text: str) -> SequenceSplit:
        """``data/bench:test`` -> (data/bench, test); ``data/demo/sequence`` -> all frames;
        ``data/bench_val:val@agx`` -> the val split with AgX-like queries; a suffix ``#N``
        keeps N frames, evenly spread (``data/bench_val:val@agx#110``)."""
        text, hash_sign, count = text.partition("#")
        limit = None
        if hash_sign:
            if not count.isdigit() or int(count) < 1:
                raise argparse.ArgumentTypeError(f"#{count}: a frame count must be >= 1")
            limit = int(count)
        item = cls._parse(text)
        return cls(item.path, item.split, item.perturbation, limit)

    @classmethod
    def _parse(cls, text: str) -> SequenceSplit:
        text, at, perturbation = text.partition("@")
        if at and perturbation not in PERTURBED:
            raise argparse.ArgumentTypeError(
                f"unknown query change {perturbation!r}; choose from {', '.join(PERTURBED)}"
            )
        path, sep, split = text.rpartition(":")
        if not sep or "/" in split:
            return cls(Path(text), None, perturbation or None)
        return cls(Path(path), split or None, perturbation or None)

    @property
    def label(self) -> str:
        """A short name for tables: the folder's name, the split and the query change."""
        name = self.path.name if self.path.name != "sequence" else self.path.parent.name
        name = f"{name}:{self.split}" if self.split else name
        name = f"{name}@{self.perturbation}" if self.perturbation else name
        return f"{name}#{self.limit}" if self.limit is not None else name


@dataclass(frozen=True)
class CachedFrame:
    """What the decision reads of one detected frame, and its truth.

    ``raw``, ``score``, ``mask`` and ``query`` are at the processing resolution (``mask``
    boolean, ``query`` the query as the detector saw it before the colour transfer);
    ``pixels`` is the number of pixels of the query; ``anomalous`` whether the truth mask
    holds anomaly pixels; ``kind`` the anomaly type (empty for normal frames).
    """

    name: str
    kind: str
    anomalous: bool
    raw: np.ndarray
    score: np.ndarray
    mask: np.ndarray
    query: np.ndarray
    pixels: int


def pixel_params(params: MradParams) -> dict:
    """``params`` without the decision's fields: what the cached arrays depend on."""
    values = params.to_dict()
    for name in DECISION_FIELDS:
        values.pop(name, None)
    return values


def cache_dir(
    root: Path,
    item: SequenceSplit,
    limit: int | None,
    params: MradParams,
    supersampling: int = 1,
) -> Path:
    """The folder of ``item``'s cached frames under ``root``."""
    frames_csv = (item.path / "frames.csv").read_bytes()
    # The reference's supersampling joins the key only when it is on, so that the folders
    # of references rendered without it keep their names.
    key = json.dumps(
        [
            item.split,
            limit,
            pixel_params(params),
            hashlib.sha256(frames_csv).hexdigest(),
            package_digest(),
        ]
        + ([item.perturbation] if item.perturbation else [])
        + ([{"supersampling": supersampling}] if supersampling != 1 else []),
        sort_keys=True,
    )
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    stem = item.label.partition("#")[0].replace(":", "-").replace("@", "-")
    return root / f"{stem}-{digest}"


def save_frame(path: Path, name: str, kind: str, anomalous: bool, result: DetectionResult) -> None:
    """Write one frame's arrays (``path`` is written aside and renamed into place)."""
    partial = path.with_suffix(".partial.npz")
    np.savez_compressed(
        partial,
        raw=result.raw_score.astype(np.float32),
        score=result.work_score.astype(np.float32),
        mask=(result.work_mask > 0) if result.work_mask is not None else result.mask > 0,
        query=result.work_query,
        meta=np.array(json.dumps([name, kind, bool(anomalous), int(result.mask.size)])),
    )
    partial.rename(path)


def load_frame(path: Path) -> CachedFrame:
    """Read one cached frame."""
    with np.load(path) as data:
        name, kind, anomalous, pixels = json.loads(str(data["meta"]))
        return CachedFrame(
            name,
            kind,
            anomalous,
            data["raw"],
            data["score"],
            data["mask"],
            data["query"],
            int(pixels),
        )


def cached_frames(
    root: Path,
    item: SequenceSplit,
    *,
    limit: int | None,
    params: MradParams,
    supersampling: int = 1,
) -> list[CachedFrame]:
    """Every frame of ``item`` (at most its own limit, else ``limit``, evenly spread),
    detected once with ``params`` (the reference rendered from each frame's pose with the
    sequence's model, ``supersampling`` times larger and area-averaged down) and read back
    from the cache."""
    limit = item.limit if item.limit is not None else limit
    folder = cache_dir(root, item, limit, params, supersampling)
    folder.mkdir(parents=True, exist_ok=True)
    source = open_sequence(item.path)
    indices = source.select(item.split, limit)
    missing = [i for i in indices if not (folder / f"{i:06d}.npz").is_file()]
    if missing:
        render = RenderSettings(supersampling=supersampling)
        config = PipelineConfig(params=params, methods=("MRAD",), render=render)
        pipeline = Pipeline.open(source.camera, mesh=source.mesh, config=config)
        try:
            frames = source.frames(missing)
            for frame in tqdm(frames, total=len(missing), desc=item.label, leave=False):
                image = frame.image
                if item.perturbation:
                    image = PERTURBED[item.perturbation](image)
                result = pipeline.process(image, frame.view).primary
                kind = frame.anomaly if frame.is_anomalous else ""
                save_frame(
                    folder / f"{frame.index:06d}.npz",
                    frame.name,
                    kind,
                    frame.is_anomalous,
                    result,
                )
        finally:
            pipeline.close()
    return [load_frame(folder / f"{i:06d}.npz") for i in indices]
