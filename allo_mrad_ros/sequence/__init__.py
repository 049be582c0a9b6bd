"""Reader and writer of the ALLO sequence format, version 1.

A sequence is a folder with ``sequence.yaml`` (intrinsics, frames, rate, station mesh),
``frames.csv`` (one row per frame: stamp, split, camera, image/mask/reference paths, label,
camera pose, sun, Earth and Moon) and the PNGs under ``<split>/Camera<N>/``. It extends the
processed ALLO layout, so a real ALLO split becomes a sequence by adding the two files.

Read with :func:`read_sequence` (or :func:`validate_sequence` for a full pass that decodes
every mask), write with :class:`SequenceWriter`. Every problem raises :class:`SequenceError`
naming the file, the row and the column.
"""

from .model import (
    ANOMALOUS,
    COLUMNS,
    FORMAT_V1,
    FRAMES_FILE,
    LABELS,
    MASK_ANOMALY,
    MASK_BACKGROUND,
    MASK_STATION,
    META_FILE,
    NORMAL,
    SPLITS,
    Frame,
    SequenceError,
    SequenceMeta,
)
from .png import read_png_header
from .reader import Sequence, read_sequence, validate_sequence
from .writer import SequenceWriter

__all__ = [
    "ANOMALOUS",
    "COLUMNS",
    "FORMAT_V1",
    "FRAMES_FILE",
    "LABELS",
    "MASK_ANOMALY",
    "MASK_BACKGROUND",
    "MASK_STATION",
    "META_FILE",
    "NORMAL",
    "SPLITS",
    "Frame",
    "Sequence",
    "SequenceError",
    "SequenceMeta",
    "SequenceWriter",
    "read_png_header",
    "read_sequence",
    "validate_sequence",
]
