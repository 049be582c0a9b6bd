"""Turn a split of a real ALLO download into an ALLO sequence (``allo-synth import-allo``).

ALLO ships images and masks only; the sequence adds what MRAD needs from ALLO's own tables,
which the package carries (``data/camera_base_poses.csv``, ``data/ephemeris_2030.csv``):

* the camera pose of ``Camera<N>`` is the base pose ``N`` of the split's table, converted
  from Blender Euler angles to a ROS optical-frame quaternion. ALLO perturbed every render
  by N(0, 1 m) per axis and N(0, 0.2 rad) per angle and did not save the result, so the pose
  is only the base pose;
* Sun, Earth and Moon come from ALLO's ephemeris row of the image's day;
* ``sun_strength`` is ALLO's sun lamp strength divided by its default, 10;
* intrinsics are ALLO's camera (:data:`~allo_mrad_ros.camera.ALLO_INTRINSICS`);
* frames are ordered by (day, camera, name) and stamped at a nominal rate from
  2030-01-01T00:00Z.

Images are referenced in place by default: ``frames.csv`` holds their paths relative to the
output folder (``../ALLO/test/Camera0/images/...``), so nothing is copied and the ALLO tree
stays untouched; the pair of folders can be moved together. With ``copy=True`` the PNGs are
copied into the sequence's own ``<split>/Camera<N>/`` layout, which makes it self-contained.
Pointing the output at the folder that holds the split (``ALLO/`` for ``ALLO/test``) with the
split named after its folder gives the format's own layout without copying: the import then
only adds ``sequence.yaml`` and ``frames.csv``.
"""

from __future__ import annotations

import argparse
import re
import shutil
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from allo_mrad_ros.allo_format import (
    ALLO_SPLITS,
    AlloImportError,
    AlloName,
    allo_base_poses,
    parse_allo_name,
)

from .allo_ephemeris import allo_sky
from .camera import ALLO_INTRINSICS, CameraIntrinsics
from .ephemeris import EPOCH_2030, EphemerisError
from .errors import AlloError
from .options import keyword_options
from .sequence import Sequence as AlloSequence
from .sequence import (
    SequenceError,
    SequenceMeta,
    SequenceWriter,
    read_sequence,
    validate_sequence,
)
from .staging import hold_point, signals_as_interrupt, staged_folder, staging_path
from .targets import SEQUENCE, OutputArgumentParser, TargetError, check_target, output_path

ALLO_DEFAULT_SUN_STRENGTH = 10.0
"""ALLO's default sun lamp strength, which maps to ``sun_strength`` 1.0."""

EPOCH_2030_NS = int(EPOCH_2030.timestamp()) * 10**9
"""Default stamp of the first imported frame: 2030-01-01T00:00:00Z in nanoseconds."""

_CAMERA_DIR = re.compile(r"^Camera(\d+)$")


@dataclass(frozen=True)
class _Item:
    day: int
    camera: int
    image: Path
    mask: Path | None
    name: AlloName


def _scan(split_dir: Path, poses: Mapping[int, object], split: str) -> list[_Item]:
    items: list[_Item] = []
    camera_dirs = []
    for entry in sorted(split_dir.iterdir()):
        match = _CAMERA_DIR.match(entry.name)
        if match and entry.is_dir():
            camera_dirs.append((int(match.group(1)), entry))
    if not camera_dirs:
        raise AlloImportError(f"{split_dir}: no Camera<N> folders")
    for camera, folder in camera_dirs:
        if camera not in poses:
            raise AlloImportError(
                f"{folder}: no base pose {camera} for split {split!r} "
                f"(the table has {min(poses)}-{max(poses)})"
                if poses
                else f"{folder}: no base poses for split {split!r}"
            )
        images = folder / "images"
        if not images.is_dir():
            raise AlloImportError(f"{folder}: no images/ folder")
        for image in sorted(images.glob("*.png")):
            name = parse_allo_name(image.name, source=str(image))
            mask = folder / "masks" / image.name
            items.append(_Item(name.day, camera, image, mask if mask.is_file() else None, name))
    if not items:
        raise AlloImportError(f"{split_dir}: no images found under Camera<N>/images/")
    items.sort(key=lambda item: (item.day, item.camera, item.image.name))
    return items


def import_allo(
    allo_split_dir: str | PathLike[str],
    out_dir: str | PathLike[str],
    split: str | None = None,
    *,
    copy: bool = False,
    rate_hz: float = 10.0,
    start_ns: int = EPOCH_2030_NS,
    intrinsics: CameraIntrinsics = ALLO_INTRINSICS,
    name: str | None = None,
    overwrite: bool = False,
    validate: bool = False,
    progress: bool = False,
) -> AlloSequence:
    """Import one ALLO split as a sequence.

    Parameters
    ----------
    allo_split_dir : path-like
        An ALLO split folder holding ``Camera<N>/images/*.png`` (and ``masks/``).
    out_dir : path-like
        Output sequence folder; may be the folder that contains ``allo_split_dir``.
    split : str, optional
        ``train`` or ``test``: picks the base-pose table and is the frames' split. By default
        the folder's name, which must then be one of the two.
    copy : bool
        Copy images and masks into ``out_dir`` instead of referencing them in place.
    rate_hz : float
        Nominal frame rate for the stamps.
    start_ns : int
        Stamp of the first frame (default 2030-01-01T00:00:00Z).
    intrinsics : CameraIntrinsics
        Camera intrinsics; every image must have its size.
    name : str, optional
        Sequence name; default ``ALLO <split>``.
    overwrite : bool
        Replace a sequence already in ``out_dir``.
    validate : bool
        Finish with :func:`~allo_mrad_ros.sequence.validate_sequence`, which decodes every
        mask (values 0/1/2, agreement with the label); otherwise only headers are checked.
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    Sequence
        The imported sequence, read back from ``out_dir``.

    Raises
    ------
    AlloImportError
        For a bad tree, file name or day, naming the file.
    SequenceError
        If an image or mask does not fit the format (wrong size or pixel layout).
    """
    split_dir = Path(allo_split_dir)
    if not split_dir.is_dir():
        raise AlloImportError(f"{split_dir}: ALLO split folder not found")
    if split is None:
        split = split_dir.resolve().name
        if split not in ALLO_SPLITS:
            raise AlloImportError(
                f"{split_dir}: cannot tell the split from the folder name; give it "
                "(--split train or --split test; split= in Python)"
            )
    poses = allo_base_poses(split)
    items = _scan(split_dir, poses, split)
    out = Path(out_dir)
    meta = SequenceMeta(
        name=name if name is not None else f"ALLO {split}", camera=intrinsics, rate_hz=rate_hz
    )
    iterator = items
    if progress:
        from tqdm import tqdm

        iterator = tqdm(items, desc=f"import-allo {split}", unit="frame", file=sys.stderr)
    # Into the folder that holds the split: its images are the download's own files, which
    # sequence.yaml records so that no command ever replaces that folder.
    in_place = split_dir.resolve().is_relative_to(out.resolve())
    with SequenceWriter(
        out, meta, overwrite=overwrite, start_ns=start_ns, images_in_place=in_place
    ) as writer:
        for item in iterator:
            try:
                sky = allo_sky(item.day)
            except EphemerisError as error:
                raise AlloImportError(f"{item.image}: {error}") from None
            image, mask = item.image, item.mask
            if copy:
                image = _copy(image, out / split / f"Camera{item.camera}" / "images")
                mask = _copy(mask, out / split / f"Camera{item.camera}" / "masks")
            position, quaternion = poses[item.camera]
            allo = item.name
            extra = {
                "allo_day": allo.day,
                "allo_sun_strength": allo.sun_strength,
                "allo_scale": "" if allo.scale is None else allo.scale,
                "allo_depth": "" if allo.depth is None else allo.depth,
                "allo_colour": allo.colour or "",
            }
            try:
                writer.add_frame(
                    split=split,
                    camera=item.camera,
                    image=image,
                    mask=mask,
                    anomaly=allo.anomaly,
                    position=position,
                    quaternion=quaternion,
                    sun_direction=sky.sun_direction,
                    sun_strength=allo.sun_strength / ALLO_DEFAULT_SUN_STRENGTH,
                    earth=sky.earth,
                    moon=sky.moon,
                    extra=extra,
                )
            except SequenceError as error:
                raise error.located(file=item.image) from None
            hold_point("import-frame")
    return validate_sequence(out, decode_images=True) if validate else read_sequence(out)


def _copy(source: Path | None, folder: Path) -> Path | None:
    if source is None:
        return None
    target = folder / source.name
    if source.absolute() != target.absolute():
        folder.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
    return target


def add_import_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``import-allo`` sub-command to an ``argparse`` sub-parser collection.

    The sub-parser's ``func`` default runs the import and returns an exit status, so a
    front end calls ``args.func(args)``.
    """
    parser = subparsers.add_parser(
        "import-allo",
        help="turn a real ALLO split into a sequence",
        description="Turn a split of a real ALLO download (<split>/Camera<N>/images, masks) "
        "into an ALLO sequence, with ALLO's base poses and ephemeris. Images are referenced "
        "in place unless --copy is given.",
    )
    parser.add_argument("split_dir", type=Path, help="ALLO split folder, e.g. ALLO/test")
    parser.add_argument("--out", type=output_path, required=True, help="output sequence folder")
    parser.add_argument(
        "--split",
        choices=ALLO_SPLITS,
        default=None,
        help="which base-pose table (default: the split folder's name)",
    )
    parser.add_argument("--copy", action="store_true", help="copy images and masks")
    parser.add_argument(
        "--rate-hz", type=float, default=10.0, help="nominal frame rate (default 10)"
    )
    parser.add_argument("--name", default=None, help="sequence name (default 'ALLO <split>')")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing sequence")
    parser.add_argument(
        "--validate",
        action="store_true",
        help="decode every image and mask; check masks against labels",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=_run_import)
    return parser


def _run_import(args: argparse.Namespace) -> int:
    try:
        options = keyword_options(args, "copy", "rate_hz", "name", "validate")
        if args.split_dir.resolve().is_relative_to(args.out.resolve()):
            # Into the ALLO folder itself: only frames.csv and sequence.yaml are added there.
            sequence = import_allo(
                args.split_dir, args.out, args.split, overwrite=args.overwrite, **options
            )
        else:
            check_target(args.out, SEQUENCE, overwrite=args.overwrite)
            with staged_folder(args.out) as staging:
                import_allo(args.split_dir, staging, args.split, overwrite=True, **options)
            sequence = read_sequence(args.out)
    except TargetError as error:
        print(f"import-allo: error: {error}", file=sys.stderr)
        return 2
    except AlloError as error:
        # Name the folder asked for, not the hidden one it was built in.
        message = str(error).replace(str(staging_path(args.out)), str(args.out))
        print(f"import-allo: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("import-allo: interrupted; nothing written", file=sys.stderr)
        return 130
    anomalous = sum(frame.is_anomalous for frame in sequence.frames)
    print(
        f"wrote {sequence.root}: {len(sequence)} frames "
        f"({len(sequence) - anomalous} normal, {anomalous} anomalous)"
    )
    return 0


def main_import(argv: Sequence[str] | None = None) -> int:
    """Run ``import-allo`` as a stand-alone command; returns the exit status."""
    parser = OutputArgumentParser(prog="allo-synth")
    add_import_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["import-allo", *(sys.argv[1:] if argv is None else argv)])
    with signals_as_interrupt():
        return args.func(args)


if __name__ == "__main__":
    sys.exit(main_import())
