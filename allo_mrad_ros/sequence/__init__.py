"""Reader and writer of the ALLO sequence format, versions 1 and 2.

A sequence is a folder with ``sequence.yaml`` (intrinsics, frames, rate, station mesh),
``frames.csv`` (one row per frame: stamp, split, camera, image/mask/reference paths, label,
camera pose, sun, Earth and Moon) and the PNGs under ``<split>/Camera<N>/``. It extends the
processed ALLO layout, so a real ALLO split becomes a sequence by adding the two files.
Version 2 adds ``objects.csv`` (ground-truth objects in the station frame:
:class:`GroundTruthObject`, :attr:`Sequence.objects`) and a 16-bit instance mask per frame
(``instances`` column, :meth:`Sequence.load_instances`); version 1 is still read.

Read with :func:`read_sequence` (or :func:`validate_sequence` for a full pass that decodes
every mask), write with :class:`SequenceWriter`. Every problem raises :class:`SequenceError`
naming the file, the row and the column.
"""

from .model import (
    ANOMALOUS,
    COLUMNS,
    COLUMNS_V2,
    FORMAT_V1,
    FORMAT_V2,
    FORMATS,
    FRAMES_FILE,
    INSTANCES_COLUMN,
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
from .objects import (
    MAX_OBJECT_ID,
    OBJECT_COLUMNS,
    OBJECTS_FILE,
    GroundTruthObject,
    parse_objects,
    read_objects,
    write_objects_text,
)
from .png import read_png_header
from .reader import Sequence, read_sequence, validate_sequence
from .writer import SequenceWriter

__all__ = [
    "ANOMALOUS",
    "COLUMNS",
    "COLUMNS_V2",
    "FORMATS",
    "FORMAT_V1",
    "FORMAT_V2",
    "FRAMES_FILE",
    "INSTANCES_COLUMN",
    "LABELS",
    "MASK_ANOMALY",
    "MASK_BACKGROUND",
    "MASK_STATION",
    "MAX_OBJECT_ID",
    "META_FILE",
    "NORMAL",
    "OBJECTS_FILE",
    "OBJECT_COLUMNS",
    "SPLITS",
    "Frame",
    "GroundTruthObject",
    "Sequence",
    "SequenceError",
    "SequenceMeta",
    "SequenceWriter",
    "parse_objects",
    "read_objects",
    "read_png_header",
    "read_sequence",
    "validate_sequence",
    "write_objects_text",
]
