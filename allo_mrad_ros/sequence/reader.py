"""Reading a sequence: :func:`read_sequence`, :class:`Sequence` and :func:`validate_sequence`."""

from __future__ import annotations

from collections.abc import Iterator
from os import PathLike
from pathlib import Path

import numpy as np

from .metafile import read_meta
from .model import (
    ANOMALOUS,
    FORMAT_V2,
    FRAMES_FILE,
    INSTANCES_COLUMN,
    MASK_ANOMALY,
    META_FILE,
    SPLITS,
    Frame,
    SequenceError,
    SequenceMeta,
)
from .objects import OBJECTS_FILE, GroundTruthObject, read_objects
from .png import PngHeader, bad_mask_values, load_grey, load_grey16, load_rgb, read_png_header
from .table import read_frames


class Sequence:
    """A validated sequence: metadata, frames in playback order and image access.

    Build it with :func:`read_sequence`.

    Attributes
    ----------
    root : pathlib.Path
        The sequence folder.
    meta : SequenceMeta
        Contents of ``sequence.yaml``.
    frames : tuple of Frame
        All frames in playback order.
    objects : tuple of GroundTruthObject
        The objects table (format version 2; empty for version 1 and for sequences without
        objects).
    """

    def __init__(
        self,
        root: Path,
        meta: SequenceMeta,
        frames: tuple[Frame, ...],
        objects: tuple[GroundTruthObject, ...] = (),
    ) -> None:
        self.root = root
        self.meta = meta
        self.frames = frames
        self.objects = objects
        self._object_ids = np.zeros(0, dtype=bool)
        if objects:
            self._object_ids = np.zeros(max(o.id for o in objects) + 1, dtype=bool)
            self._object_ids[[o.id for o in objects]] = True

    @property
    def has_objects(self) -> bool:
        """Whether the sequence is of format version 2 (objects table and instance masks),
        even with an empty table."""
        return self.meta.format == FORMAT_V2

    def object(self, object_id: int) -> GroundTruthObject:
        """The object of the table with this id (KeyError if none)."""
        for item in self.objects:
            if item.id == object_id:
                return item
        raise KeyError(object_id)

    def __len__(self) -> int:
        return len(self.frames)

    def __iter__(self) -> Iterator[Frame]:
        return iter(self.frames)

    def __getitem__(self, index: int) -> Frame:
        return self.frames[index]

    def __repr__(self) -> str:
        return f"Sequence({str(self.root)!r}, {len(self.frames)} frames)"

    @property
    def splits(self) -> tuple[str, ...]:
        """The splits present, in order of first appearance."""
        return tuple(dict.fromkeys(f.split for f in self.frames))

    def split(self, name: str) -> tuple[Frame, ...]:
        """Return the frames of one split (``train``, ``val`` or ``test``), possibly none."""
        if name not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}; got {name!r}")
        return tuple(f for f in self.frames if f.split == name)

    def _located(self, error: SequenceError, frame: Frame, column: str) -> SequenceError:
        return error.located(row=frame.index + 1, column=column)

    def _check_shape(self, array: np.ndarray, path: Path, frame: Frame, column: str) -> None:
        height, width = array.shape[:2]
        _check_size(width, height, self.meta, path, frame, column)

    def load_image(self, frame: Frame) -> np.ndarray:
        """Decode the frame's image.

        Returns
        -------
        numpy.ndarray
            RGB uint8, shape (height, width, 3).

        Raises
        ------
        SequenceError
            If the file cannot be read or its size differs from ``sequence.yaml``.
        """
        return self._load_rgb(frame, frame.image, "image")

    def load_reference(self, frame: Frame) -> np.ndarray | None:
        """Decode the frame's pre-rendered reference (RGB uint8) or return None if it has none."""
        if frame.reference is None:
            return None
        return self._load_rgb(frame, frame.reference, "reference")

    def _load_rgb(self, frame: Frame, path: Path, what: str) -> np.ndarray:
        try:
            image = load_rgb(path)
        except SequenceError as error:
            raise self._located(error, frame, what) from None
        self._check_shape(image, path, frame, what)
        return image

    def load_mask(self, frame: Frame) -> np.ndarray | None:
        """Decode the frame's ground-truth mask, or return None if it has none.

        Returns
        -------
        numpy.ndarray or None
            uint8, shape (height, width), values in {0, 1, 2}.

        Raises
        ------
        SequenceError
            If the mask cannot be read, has the wrong size, holds values other than 0, 1, 2
            or contradicts the frame's label (anomalous iff it has class-2 pixels).
        """
        if frame.mask is None:
            return None
        try:
            mask = load_grey(frame.mask)
        except SequenceError as error:
            raise self._located(error, frame, "mask") from None
        self._check_shape(mask, frame.mask, frame, "mask")
        bad = bad_mask_values(mask)
        if bad:
            raise SequenceError(
                f"mask values must be 0, 1 or 2; found {bad[:10]}",
                file=frame.mask,
                row=frame.index + 1,
                column="mask",
            )
        has_anomaly = bool(np.any(mask == MASK_ANOMALY))
        if has_anomaly != (frame.label == ANOMALOUS):
            found = "has" if has_anomaly else "has no"
            raise SequenceError(
                f"label {frame.label!r} contradicts the mask, which {found} class-2 pixels "
                f"({frame.mask})",
                file=self.root / FRAMES_FILE,
                row=frame.index + 1,
                column="label",
            )
        return mask

    def load_instances(self, frame: Frame, mask: np.ndarray | None = None) -> np.ndarray | None:
        """Decode the frame's instance mask (format version 2), or return None if it has none.

        Parameters
        ----------
        frame : Frame
            The frame.
        mask : numpy.ndarray, optional
            The frame's class mask (:meth:`load_mask`): when given, the instance mask must
            mark exactly its class-2 pixels.

        Returns
        -------
        numpy.ndarray or None
            uint16, shape (height, width): the ``id`` of the object of :attr:`objects`
            each pixel shows, 0 where none.

        Raises
        ------
        SequenceError
            If the file cannot be read, has the wrong size or pixel layout, holds an id that
            is not in the objects table, or disagrees with ``mask``.
        """
        if frame.instances is None:
            return None
        path = frame.instances
        try:
            instances = load_grey16(path)
        except SequenceError as error:
            raise self._located(error, frame, INSTANCES_COLUMN) from None
        self._check_shape(instances, path, frame, INSTANCES_COLUMN)
        present = np.flatnonzero(np.bincount(instances.ravel()))
        known = self._object_ids
        unknown = [int(v) for v in present if v and (v >= len(known) or not known[v])]
        if unknown:
            raise SequenceError(
                f"ids {unknown[:10]} are not in {OBJECTS_FILE}",
                file=path,
                row=frame.index + 1,
                column=INSTANCES_COLUMN,
            )
        if mask is not None:
            differ = np.count_nonzero((instances > 0) != (mask == MASK_ANOMALY))
            if differ:
                raise SequenceError(
                    f"{differ} pixels differ from the mask's class-2 pixels ({frame.mask}); "
                    "every anomaly pixel, and only those, belongs to an object",
                    file=path,
                    row=frame.index + 1,
                    column=INSTANCES_COLUMN,
                )
        return instances


def _check_size(
    width: int, height: int, meta: SequenceMeta, path: Path, frame: Frame, column: str
) -> None:
    camera = meta.camera
    if (width, height) != (camera.width, camera.height):
        raise SequenceError(
            f"size {width}x{height} differs from {META_FILE} camera {camera.width}x{camera.height}",
            file=path,
            row=frame.index + 1,
            column=column,
        )


def _check_header(
    header: PngHeader, path: Path, frame: Frame, column: str, meta: SequenceMeta
) -> None:
    _check_size(header.width, header.height, meta, path, frame, column)
    if column == INSTANCES_COLUMN:
        good, expected = header.is_grey16, "16-bit single channel"
    elif column == "mask":
        good, expected = header.is_grey8, "8-bit single channel"
    else:
        good, expected = header.is_rgb8, "8-bit RGB or RGBA"
    if not good:
        raise SequenceError(
            f"expected {expected}, got {header.describe()}",
            file=path,
            row=frame.index + 1,
            column=column,
        )


def _check_files(frames: tuple[Frame, ...], meta: SequenceMeta) -> None:
    for frame in frames:
        for column in ("image", "mask", "reference", INSTANCES_COLUMN):
            path = getattr(frame, column)
            if path is None:
                continue
            try:
                header = read_png_header(path)
            except SequenceError as error:
                raise error.located(row=frame.index + 1, column=column) from None
            _check_header(header, path, frame, column, meta)


def read_sequence(root: str | PathLike[str], check_images: bool = True) -> Sequence:
    """Read and validate a sequence folder.

    Parameters
    ----------
    root : path-like
        The folder holding ``sequence.yaml`` and ``frames.csv``.
    check_images : bool
        Also check that every image, mask and reference exists and that its PNG header
        gives the size of ``sequence.yaml`` and the expected pixel layout (8-bit RGB/RGBA
        images, 8-bit single-channel masks, 16-bit single-channel instance masks). Reads a
        few bytes per file, decodes nothing.

    Returns
    -------
    Sequence
        The sequence. Mask values are checked when masks are loaded, or by
        :func:`validate_sequence`.

    Raises
    ------
    SequenceError
        On the first problem, naming the file, the row and the column.
    """
    root = Path(root)
    if not root.is_dir():
        raise SequenceError("sequence folder not found", file=root)
    meta = read_meta(root / META_FILE)
    frames = tuple(read_frames(root / FRAMES_FILE, root, meta.format))
    objects: tuple[GroundTruthObject, ...] = ()
    if meta.format == FORMAT_V2:
        objects = read_objects(root / OBJECTS_FILE)
    if check_images:
        _check_files(frames, meta)
    return Sequence(root, meta, frames, objects)


def validate_sequence(root: str | PathLike[str], decode_images: bool = False) -> Sequence:
    """Fully validate a sequence, decoding every mask (and optionally every image).

    On top of :func:`read_sequence`, checks that every mask holds only 0, 1 and 2 and agrees
    with its frame's label, and that every instance mask holds ids of the objects table
    exactly on the mask's class-2 pixels.

    Parameters
    ----------
    root : path-like
        The sequence folder.
    decode_images : bool
        Also decode every image and reference, which catches corrupt PNG data (slow).

    Returns
    -------
    Sequence
        The validated sequence.

    Raises
    ------
    SequenceError
        On the first problem, naming the file, the row and the column.
    """
    sequence = read_sequence(root, check_images=True)
    for frame in sequence.frames:
        mask = sequence.load_mask(frame)
        sequence.load_instances(frame, mask)
        if decode_images:
            sequence.load_image(frame)
            sequence.load_reference(frame)
    return sequence
