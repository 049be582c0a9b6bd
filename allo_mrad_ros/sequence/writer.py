"""Writing a sequence: :class:`SequenceWriter`.

Write order makes an interrupted run obvious: images first, then ``sequence.yaml``, then
``frames.csv`` under a temporary name renamed into place. A folder without ``frames.csv``
is not a sequence, so a crash never leaves a valid-looking partial one.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import replace
from os import PathLike
from pathlib import Path
from types import TracebackType

import numpy as np

from .checks import (
    checked_body,
    checked_unit_vector,
    checked_vector,
    extra_columns,
    frame_label,
)
from .csv_table import format_float
from .metafile import relative_posix, write_meta
from .model import (
    FORMAT_V2,
    FRAMES_FILE,
    INSTANCES_COLUMN,
    MASK_ANOMALY,
    MAX_STAMP_NS,
    META_FILE,
    POSE_COLUMNS,
    SPLITS,
    SUN_COLUMNS,
    Frame,
    SequenceError,
    SequenceMeta,
    columns_of,
)
from .objects import OBJECTS_FILE, GroundTruthObject, checked_objects, write_objects_text
from .png import bad_mask_values, encode_png, read_png_header, write_atomic
from .table import frame_from_record, leaves_root, write_frames_text

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")


class SequenceWriter:
    """Write a sequence folder frame by frame.

    Use it as a context manager: leaving the block normally calls :meth:`close`, leaving it
    with an exception calls :meth:`abort`, so no ``frames.csv`` is written.

    Parameters
    ----------
    root : path-like
        Output folder, created if needed.
    meta : SequenceMeta
        Metadata; ``meta.mesh`` (if set) is the station model file to record.
    copy_mesh : bool
        Copy ``meta.mesh`` into ``root/meshes/`` (default). Otherwise record its path
        relative to ``root``. Only single-file models (.glb, .ply, .stl, .obj without
        material files) survive a copy intact.
    overwrite : bool
        Allow ``root`` to hold a sequence already. Its ``frames.csv`` and ``sequence.yaml``
        are deleted at once, so an interrupted overwrite leaves no stale valid sequence.
    start_ns : int
        Stamp of the first frame when stamps are not given.
    png_compression : int
        zlib level 0-9 for written PNGs: output is lossless at any level, 3 balances speed
        and size.
    images_in_place : bool
        The images are another dataset's own files in ``root`` (an ALLO download imported
        where it lies): ``sequence.yaml`` says so, so that no command replaces the folder.
    objects : iterable of GroundTruthObject, optional
        The objects table. Given (even empty), the sequence is written in format version 2
        (``objects.csv``, and frames may carry instance masks); None writes version 1, as
        does a ``meta`` of version 1 without objects. A ``meta`` of version 2 without
        objects gets an empty table.

    Raises
    ------
    SequenceError
        If ``root`` already holds a sequence and ``overwrite`` is False, or a parameter is
        invalid.

    Examples
    --------
    >>> with SequenceWriter(out, meta) as writer:  # doctest: +SKIP
    ...     writer.add_frame(split="test", camera=0, image=rgb, position=p, quaternion=q,
    ...                      sun_direction=s, mask=mask, anomaly="drill")
    """

    def __init__(
        self,
        root: str | PathLike[str],
        meta: SequenceMeta,
        *,
        copy_mesh: bool = True,
        overwrite: bool = False,
        start_ns: int = 0,
        png_compression: int = 3,
        images_in_place: bool = False,
        objects: Iterable[GroundTruthObject] | None = None,
    ) -> None:
        if not isinstance(meta, SequenceMeta):
            raise SequenceError(f"meta must be SequenceMeta, got {type(meta).__name__}")
        if objects is None and meta.format == FORMAT_V2:
            objects = ()
        self._objects: tuple[GroundTruthObject, ...] | None = None
        if objects is not None:
            self._objects = checked_objects(objects)
            meta = replace(meta, format=FORMAT_V2)
        ids = [o.id for o in self._objects or ()]
        self._object_ids = np.zeros(max(ids, default=0) + 1, dtype=bool)
        self._object_ids[ids] = True
        if (
            isinstance(start_ns, bool)
            or not isinstance(start_ns, int)
            or not (0 <= start_ns < MAX_STAMP_NS)
        ):
            raise SequenceError(f"start_ns must be an integer in [0, 2**31 s), got {start_ns!r}")
        if isinstance(png_compression, bool) or png_compression not in range(10):
            raise SequenceError(f"png_compression must be 0-9, got {png_compression!r}")
        if meta.mesh is not None and not meta.mesh.is_file():
            raise SequenceError("mesh file not found", file=meta.mesh, column="mesh")
        self.root = Path(root)
        self.meta = meta
        self._copy_mesh = copy_mesh
        self._compression = png_compression
        self._images_in_place = images_in_place
        self._period_ns = max(1, round(1e9 / meta.rate_hz))
        self._next_stamp = start_ns
        self._last_stamp = -1
        self._records: list[dict[str, str]] = []
        self._frames: list[Frame] = []
        self._extra_columns: list[str] = []
        self._written: set[str] = set()
        self._state = "open"
        existing = [n for n in (FRAMES_FILE, META_FILE) if (self.root / n).exists()]
        if existing and not overwrite:
            raise SequenceError(
                "folder already holds a sequence; use --overwrite (overwrite=True) to replace it",
                file=self.root / existing[0],
            )
        self.root.mkdir(parents=True, exist_ok=True)
        for name in (FRAMES_FILE, META_FILE, OBJECTS_FILE):
            (self.root / name).unlink(missing_ok=True)

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    @property
    def frames(self) -> tuple[Frame, ...]:
        """The frames added so far, as a reader would return them.

        Their ``extra`` holds only the columns given for that frame; once read back, every
        frame has every extra column (empty where not given).
        """
        return tuple(self._frames)

    def _require_open(self) -> None:
        if self._state != "open":
            raise SequenceError(f"writer is {self._state}")

    @property
    def objects(self) -> tuple[GroundTruthObject, ...] | None:
        """The objects table (None for a version-1 sequence)."""
        return self._objects

    def _check_array(
        self, array: object, what: str, channels: int, dtype: type = np.uint8
    ) -> np.ndarray:
        array = np.asarray(array)
        camera = self.meta.camera
        shape = (camera.height, camera.width) + ((channels,) if channels > 1 else ())
        if array.dtype != dtype or array.shape != shape:
            kind = np.dtype(dtype).name
            raise SequenceError(
                f"{what} must be {kind} of shape {shape}, got {array.dtype} {array.shape}"
            )
        return array

    def _check_instances(self, instances: np.ndarray, mask: object) -> None:
        """Instance ids must be in the objects table and mark exactly the mask's class 2."""
        present = np.flatnonzero(np.bincount(instances.ravel()))
        known = self._object_ids
        unknown = [int(v) for v in present if v and (v >= len(known) or not known[v])]
        if unknown:
            raise SequenceError(f"instance ids {unknown[:10]} are not in the objects table")
        if mask is None or isinstance(mask, (str, PathLike)):
            if mask is None and present.max(initial=0) > 0:
                raise SequenceError("an instance mask with objects needs a class mask")
            return
        differ = np.count_nonzero((instances > 0) != (np.asarray(mask) == MASK_ANOMALY))
        if differ:
            raise SequenceError(
                f"instance mask: {differ} pixels differ from the mask's class-2 pixels"
            )

    def _prepare(self, data: object, split: str, camera: int, name: str, kind: str) -> tuple:
        """Validate one image input without touching the disk.

        Returns ``(relative path, what to put there)``: an array to write as PNG, the path of
        a file outside the sequence folder to link to, or None for a file already inside.
        """
        if isinstance(data, (str, PathLike)):
            path = Path(data)
            header = read_png_header(path)
            camera_size = (self.meta.camera.width, self.meta.camera.height)
            if (header.width, header.height) != camera_size:
                raise SequenceError(
                    f"size {header.width}x{header.height} differs from camera "
                    f"{camera_size[0]}x{camera_size[1]}",
                    file=path,
                )
            if kind == "instances":
                ok = header.is_grey16
            else:
                ok = header.is_grey8 if kind == "masks" else header.is_rgb8
            if not ok:
                raise SequenceError(f"unexpected pixel layout {header.describe()}", file=path)
            relative = relative_posix(path, self.root)
            if not leaves_root(relative):
                return relative, None
            # Paths in frames.csv stay inside the folder: a file outside is linked in.
            relative = f"{split}/Camera{camera}/{kind}/{path.name}"
            if relative in self._written:
                raise SequenceError(f"duplicate file {relative}: file names must be unique")
            return relative, path
        if kind == "instances":
            array = self._check_array(data, "instance mask", 1, np.uint16)
            relative = f"{split}/Camera{camera}/{kind}/{name}.png"
            if relative in self._written:
                raise SequenceError(f"duplicate file {relative}: frame names must be unique")
            return relative, array
        channels = 1 if kind == "masks" else 3
        array = self._check_array(data, kind[:-1], channels)
        if kind == "masks":
            bad = bad_mask_values(array)
            if bad:
                raise SequenceError(f"mask values must be 0, 1 or 2; found {bad[:10]}")
        relative = f"{split}/Camera{camera}/{kind}/{name}.png"
        if relative in self._written:
            raise SequenceError(f"duplicate file {relative}: frame names must be unique")
        return relative, array

    def add_frame(
        self,
        *,
        split: str,
        camera: int,
        image: np.ndarray | PathLike[str],
        position: object,
        quaternion: object,
        sun_direction: object,
        sun_strength: float = 1.0,
        mask: np.ndarray | PathLike[str] | None = None,
        reference: np.ndarray | PathLike[str] | None = None,
        instances: np.ndarray | PathLike[str] | None = None,
        label: str | None = None,
        anomaly: str = "",
        earth: object = None,
        moon: object = None,
        name: str | None = None,
        stamp_ns: int | None = None,
        extra: Mapping[str, object] | None = None,
    ) -> Frame:
        """Add one frame: write its PNGs now and keep its row for :meth:`close`.

        Parameters
        ----------
        split : str
            ``train``, ``val`` or ``test``.
        camera : int
            Camera index ``N`` (folder ``Camera<N>``), non-negative.
        image : numpy.ndarray or path-like
            RGB uint8 (height, width, 3) array, written to
            ``<split>/Camera<N>/images/<name>.png``; or an existing PNG, recorded by its path
            relative to the root (nothing is copied).
        position : array_like, shape (3,)
            Camera optical frame origin in the station frame, metres.
        quaternion : array_like, shape (4,)
            ``(x, y, z, w)`` orientation of the optical frame in the station frame, unit norm
            within 1e-3; written as given (see :func:`~allo_mrad_ros.geometry.pose_components`
            to split a 4x4 pose).
        sun_direction : array_like, shape (3,)
            Unit vector towards the Sun in the station frame.
        sun_strength : float
            Relative sun intensity, non-negative.
        mask : numpy.ndarray or path-like, optional
            uint8 (height, width) array of classes 0, 1, 2, written to ``masks/``; or an
            existing 8-bit single-channel PNG, referenced.
        reference : numpy.ndarray or path-like, optional
            Pre-rendered reference, like ``image``, written to ``references/``.
        instances : numpy.ndarray or path-like, optional
            Format version 2 only (the writer was given ``objects``): uint16 (height, width)
            array of object ids of the objects table, 0 where no object is, nonzero exactly
            on the mask's class-2 pixels; written to ``instances/`` as a 16-bit PNG. Or an
            existing 16-bit single-channel PNG, referenced.
        label : str, optional
            ``normal`` or ``anomalous``. By default taken from a mask array (class-2 pixels
            present) or else from ``anomaly`` (non-empty means anomalous). A label that
            contradicts a mask array is an error.
        anomaly : str
            Object type name; required for anomalous frames, empty for normal ones.
        earth, moon : array_like, shape (4,), optional
            ``(x, y, z, r)`` of the scaled-down body in the station frame, metres.
        name : str, optional
            File name stem, unique per split and camera; defaults to the frame index as six
            digits. Letters, digits and ``._+-`` only.
        stamp_ns : int, optional
            Frame time; defaults to the previous stamp plus one period of ``meta.rate_hz``
            (the first frame gets ``start_ns``). Must increase strictly.
        extra : Mapping[str, object], optional
            Values of extra columns (names of letters, digits and ``_``), written with
            ``str`` (floats with ``repr``); rows without a value get an empty cell.

        Returns
        -------
        Frame
            The frame as :func:`read_sequence` will return it.

        Raises
        ------
        SequenceError
            If a value is invalid; nothing is recorded for the frame then.
        """
        self._require_open()
        index = len(self._records)
        if split not in SPLITS:
            raise SequenceError(f"split must be one of {', '.join(SPLITS)}; got {split!r}")
        if isinstance(camera, bool) or not isinstance(camera, (int, np.integer)) or camera < 0:
            raise SequenceError(f"camera must be a non-negative integer, got {camera!r}")
        camera = int(camera)
        name = f"{index:06d}" if name is None else name
        if not isinstance(name, str) or not _NAME.match(name) or name.lower().endswith(".png"):
            raise SequenceError(
                f"name must be a file stem of letters, digits and ._+- without .png, got {name!r}"
            )
        if stamp_ns is None:
            stamp_ns = max(self._next_stamp, self._last_stamp + 1)
        if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, (int, np.integer)):
            raise SequenceError(f"stamp_ns must be an integer, got {stamp_ns!r}")
        stamp_ns = int(stamp_ns)
        if stamp_ns <= self._last_stamp or stamp_ns >= MAX_STAMP_NS:
            raise SequenceError(
                f"stamp_ns must increase strictly and stay below 2**31 s: {stamp_ns} after "
                f"{self._last_stamp}"
            )
        position = checked_vector(position, 3, "position")
        quaternion = checked_unit_vector(quaternion, 4, "quaternion")
        sun_direction = checked_unit_vector(sun_direction, 3, "sun_direction")
        if not math.isfinite(sun_strength) or sun_strength < 0:
            raise SequenceError(f"sun_strength must be finite and >= 0, got {sun_strength!r}")
        earth = checked_body(earth, "earth")
        moon = checked_body(moon, "moon")
        label = frame_label(label, anomaly, mask)
        if instances is not None:
            if self._objects is None:
                raise SequenceError(
                    "instance masks need format version 2: give the writer an objects table"
                )
            if not isinstance(instances, (str, PathLike)):
                instances = self._check_array(instances, "instance mask", 1, np.uint16)
                self._check_instances(instances, mask)
        extra_text = extra_columns(extra or {})
        # Validate every input before writing any file, so a rejected frame leaves nothing.
        files = {
            column: self._prepare(
                data, split, camera, name, column if column == INSTANCES_COLUMN else f"{column}s"
            )
            for column, data in (
                ("image", image),
                ("mask", mask),
                ("reference", reference),
                (INSTANCES_COLUMN, instances),
            )
            if data is not None
        }
        record = {
            "stamp_ns": str(stamp_ns),
            "split": split,
            "camera": str(camera),
            "image": files["image"][0],
            "mask": files["mask"][0] if "mask" in files else "",
            "reference": files["reference"][0] if "reference" in files else "",
            "label": label,
            "anomaly": anomaly,
        }
        values = [*position, *quaternion, *sun_direction, sun_strength]
        numeric = (*POSE_COLUMNS, *SUN_COLUMNS, "sun_strength")
        record.update({c: format_float(v) for c, v in zip(numeric, values, strict=True)})
        for body, value in (("earth", earth), ("moon", moon)):
            for axis, component in zip(("x", "y", "z", "r"), range(4), strict=True):
                record[f"{body}_{axis}"] = "" if value is None else format_float(value[component])
        version = self.meta.format
        if version == FORMAT_V2:
            record[INSTANCES_COLUMN] = files[INSTANCES_COLUMN][0] if instances is not None else ""
        record.update(extra_text)
        frame = frame_from_record(
            {c: record.get(c, "") for c in (*columns_of(version), *extra_text)},
            index,
            self.root,
            extra_text,
            version,
        )
        for relative, payload in files.values():
            if isinstance(payload, np.ndarray):
                write_atomic(self.root / relative, encode_png(payload, self._compression))
            elif payload is not None:
                _link(self.root / relative, payload)
            else:
                continue
            self._written.add(relative)
        for key in extra_text:
            if key not in self._extra_columns:
                self._extra_columns.append(key)
        self._records.append(record)
        self._frames.append(frame)
        self._last_stamp = stamp_ns
        self._next_stamp = stamp_ns + self._period_ns
        return frame

    def close(self) -> None:
        """Write ``objects.csv`` (version 2), ``sequence.yaml`` and then ``frames.csv``; copy
        the mesh if asked.

        Calling it again does nothing.

        Raises
        ------
        SequenceError
            If no frame was added or the writer was aborted.
        """
        if self._state == "closed":
            return
        self._require_open()
        if not self._records:
            raise SequenceError("no frames were added")
        mesh = None
        if self.meta.mesh is not None:
            if self._copy_mesh:
                target = self.root / "meshes" / self.meta.mesh.name
                target.parent.mkdir(parents=True, exist_ok=True)
                if self.meta.mesh.absolute() != target.absolute():
                    write_atomic(target, self.meta.mesh.read_bytes())
                mesh = f"meshes/{self.meta.mesh.name}"
            else:
                mesh = relative_posix(self.meta.mesh, self.root)
        if self._objects is not None:
            objects_text = write_objects_text(self._objects)
            write_atomic(self.root / OBJECTS_FILE, objects_text.encode("utf-8"))
        write_meta(self.root / META_FILE, self.meta, mesh, images_in_place=self._images_in_place)
        text = write_frames_text(self._records, self._extra_columns, self.meta.format)
        write_atomic(self.root / FRAMES_FILE, text.encode("utf-8"))
        self._state = "closed"

    def abort(self) -> None:
        """Stop without writing the metadata; images written so far stay on disk."""
        if self._state == "open":
            self._state = "aborted"


def _link(link: Path, source: Path) -> None:
    """A relative symbolic link at ``link`` to ``source`` (replacing an older link)."""
    link.parent.mkdir(parents=True, exist_ok=True)
    if link.is_symlink():
        link.unlink()
    link.symlink_to(os.path.relpath(source.absolute(), link.parent.absolute()))
