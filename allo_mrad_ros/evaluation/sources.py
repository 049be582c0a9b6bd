"""Frames for evaluation: the :class:`FrameSource` interface and the sequence-folder source.

Every source yields the same :class:`EvalFrame`: the camera image, its ground-truth mask and
the :class:`~allo_mrad_ros.view.View` (pose, lighting, celestial bodies), i.e. everything
:meth:`allo_mrad_ros.pipeline.Pipeline.process` and the metrics need. Bags are a source too
(:mod:`rosbag_tools.bag_source`); this package knows nothing of them.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.sequence import (
    MASK_ANOMALY,
    META_FILE,
    SPLITS,
    GroundTruthObject,
    Sequence,
    SequenceError,
    read_sequence,
)
from allo_mrad_ros.view import View


class FrameSourceError(InvalidInput):
    """An input cannot be evaluated: unreadable, incomplete frames, missing mesh or mask."""


@dataclass(frozen=True)
class EvalFrame:
    """One frame to evaluate (plain arrays, so it pickles to worker processes).

    ``index`` is the frame's position in the input (0-based, all splits counted), ``name``
    the sequence's image name (``frame<index>`` for bags), ``stamp_ns`` its time, ``split``
    and ``anomaly`` (empty for normal frames) its labels; ``image`` is RGB uint8 (H, W, 3),
    ``mask`` the ground truth uint8 (H, W) with classes 0, 1, 2, ``view`` the camera pose,
    lighting and bodies (Earth, Moon), ``reference`` a pre-rendered reference when asked for,
    ``instances`` the instance mask uint16 (H, W) of inputs with ground-truth objects (the
    ``id`` of an object of :attr:`FrameSource.objects` per anomaly pixel, 0 elsewhere), else
    None.
    """

    index: int
    name: str
    stamp_ns: int
    split: str
    anomaly: str
    image: np.ndarray
    mask: np.ndarray
    view: View
    reference: np.ndarray | None = None
    instances: np.ndarray | None = None

    @property
    def is_anomalous(self) -> bool:
        """True when the mask has anomaly pixels."""
        return bool(np.any(self.mask == MASK_ANOMALY))


@dataclass(frozen=True)
class FrameHeader:
    """What is known of a frame before its pixels are read: index, split."""

    index: int
    split: str


@dataclass(eq=False)
class FrameSource:
    """Frames of a sequence or a bag, with the camera and the station model.

    Build it with :func:`open_source`.

    Attributes
    ----------
    path : pathlib.Path
        The input.
    kind : str
        ``"sequence"`` or ``"bag"``.
    name : str
        Sequence name (from the bag's custom data for bags).
    camera : CameraIntrinsics
        Full-resolution intrinsics.
    mesh : pathlib.Path or None
        The station model to render references with (None: the package's model).
    headers : tuple of FrameHeader
        Index and split of every frame, in order.
    objects : tuple of GroundTruthObject
        The ground-truth objects table (sequences of format version 2 and their bags);
        empty otherwise.
    """

    path: Path
    kind: str
    name: str
    camera: CameraIntrinsics
    mesh: Path | None
    headers: tuple[FrameHeader, ...]
    objects: tuple[GroundTruthObject, ...] = ()

    @property
    def splits(self) -> tuple[str, ...]:
        """Splits present, in order of first appearance."""
        return tuple(dict.fromkeys(h.split for h in self.headers))

    def default_split(self) -> str | None:
        """``test`` if present, else None (all frames)."""
        return "test" if "test" in self.splits else None

    def select(self, split: str | None, limit: int | None = None) -> list[int]:
        """Indices of the frames of ``split`` (None: all), at most ``limit`` of them.

        A limit keeps frames evenly spread over the split (see :func:`spread`), so a quick
        run still sees every part of a sequence whatever its order (cameras, anomaly types).

        Raises
        ------
        FrameSourceError
            For an unknown or absent split, or a limit below 1.
        """
        if split is not None and split not in SPLITS:
            raise FrameSourceError(f"unknown split {split!r}; choose from {list(SPLITS)}")
        if limit is not None and limit < 1:
            raise FrameSourceError(f"limit must be at least 1, got {limit}")
        indices = [h.index for h in self.headers if split is None or h.split == split]
        if not indices:
            raise FrameSourceError(
                f"{self.path}: no frames in split {split!r} (splits present: {list(self.splits)})"
            )
        return spread(indices, limit) if limit is not None else indices

    def frames(self, indices: list[int]) -> Iterator[EvalFrame]:
        """Yield the frames of ``indices`` (ascending) in order."""
        raise NotImplementedError


@dataclass
class RunFacts:
    """What every run reports about its input: path, kind, name, split and frame count."""

    input: str
    kind: str
    name: str
    split: str | None
    frames: int

    @classmethod
    def of(cls, source: FrameSource, split: str | None, indices: list[int]) -> RunFacts:
        """The facts of running ``indices`` of ``split`` of ``source``."""
        return cls(str(source.path), source.kind, source.name, split, len(indices))


def spread(indices: list[int], limit: int) -> list[int]:
    """At most ``limit`` items of ``indices``, evenly spaced, first and last included."""
    if limit >= len(indices):
        return list(indices)
    if limit == 1:
        return [indices[0]]
    positions = np.floor(np.linspace(0, len(indices) - 1, limit) + 0.5).astype(int)
    return [indices[i] for i in positions]


class SequenceSource(FrameSource):
    """Frames of a sequence folder (see :func:`open_source`)."""

    def __init__(self, sequence: Sequence, use_references: bool, mesh: Path | None) -> None:
        headers = tuple(FrameHeader(f.index, f.split) for f in sequence.frames)
        super().__init__(
            sequence.root,
            "sequence",
            sequence.meta.name,
            sequence.meta.camera,
            mesh if mesh is not None else sequence.meta.mesh,
            headers,
            sequence.objects,
        )
        self.sequence = sequence
        self.use_references = use_references

    def frames(self, indices: list[int]) -> Iterator[EvalFrame]:
        """Yield the frames of ``indices`` in order, decoding their PNGs."""
        sequence = self.sequence
        for index in indices:
            frame = sequence.frames[index]
            try:
                image = sequence.load_image(frame)
                mask = sequence.load_mask(frame)
                instances = sequence.load_instances(frame, mask)
                reference = sequence.load_reference(frame) if self.use_references else None
            except SequenceError as error:
                raise FrameSourceError(str(error)) from None
            if mask is None:
                raise FrameSourceError(
                    f"{sequence.root}: frame {frame.name} (row {index + 1}) has no mask; "
                    "evaluation needs ground truth"
                )
            if self.use_references and reference is None:
                raise FrameSourceError(
                    f"{sequence.root}: frame {frame.name} (row {index + 1}) has no reference; "
                    "drop --use-sequence-references to render one"
                )
            view = View.of_frame(frame)
            header = (index, frame.name, frame.stamp_ns, frame.split, frame.anomaly)
            yield EvalFrame(*header, image, mask, view, reference, instances)


def open_sequence(
    path: str | PathLike[str],
    *,
    mesh: str | PathLike[str] | None = None,
    use_references: bool = False,
) -> SequenceSource:
    """Open a sequence folder for evaluation.

    Parameters
    ----------
    path : path-like
        Sequence folder (with ``sequence.yaml``).
    mesh : path-like, optional
        Station model to render references with, instead of the sequence's.
    use_references : bool
        Use the sequence's pre-rendered references.

    Raises
    ------
    FrameSourceError
        If the folder is not a readable sequence, or the mesh is missing.
    """
    path = Path(path)
    mesh_path = Path(mesh) if mesh is not None else None
    if mesh_path is not None and not mesh_path.is_file():
        raise FrameSourceError(f"{mesh_path}: station mesh not found")
    if not (path.is_dir() and (path / META_FILE).is_file()):
        raise FrameSourceError(f"{path}: not a sequence folder ({META_FILE} missing)")
    try:
        sequence = read_sequence(path, check_images=True)
    except SequenceError as error:
        raise FrameSourceError(str(error)) from None
    return SequenceSource(sequence, use_references, mesh_path)
