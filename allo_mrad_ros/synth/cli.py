"""The ``allo-synth`` command: ``generate`` an ALLO-like sequence, or ``import-allo`` one.

Examples
--------
::

    allo-synth generate --preset demo --seed 0 --out data/demo
    allo-synth generate --preset bench --seed 0 --out data/bench --jobs 2
    allo-synth generate --preset smoke --frames 20 --width 480 --height 270 --out /tmp/s
    allo-synth generate --preset cycles --seed 0 --out data/bench_cycles
    allo-synth generate --preset objects --seed 0 --out data/objects --trajectory-frames 100
    allo-synth import-allo ALLO/test --out data/allo_test
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from allo_mrad_ros.allo_import import add_import_parser
from allo_mrad_ros.errors import AlloError
from allo_mrad_ros.resources import package_version
from allo_mrad_ros.staging import signals_as_interrupt, staged_folder, staging_path
from allo_mrad_ros.synth.config import PRESETS, QUERY_RENDERERS, SynthError, preset
from allo_mrad_ros.synth.objects import KNOWN_TYPES
from allo_mrad_ros.targets import (
    SEQUENCE,
    OutputArgumentParser,
    TargetError,
    check_target,
    output_path,
)

# The options of `generate` that set the SynthConfig field of their name (their dest).
_CONFIG_OPTIONS = (
    "width",
    "height",
    "references",
    "anomaly_types",
    "position_sigma_m",
    "rotation_sigma_rad",
    "pose_error_m",
    "query_renderer",
    "cycles_samples",
    "camera_effects",
    "rate_hz",
)


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _rate(text: str) -> float:
    value = float(text)
    if not math.isfinite(value) or not 0 < value <= 1000:
        raise argparse.ArgumentTypeError(f"must be a frame rate in (0, 1000] Hz, got {text}")
    return value


def _non_negative(text: str) -> float:
    value = float(text)
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def _types(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in KNOWN_TYPES]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown object types {unknown}; choose from {', '.join(KNOWN_TYPES)}"
        )
    return names


def add_generate_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``generate`` sub-command; its ``func`` default runs it and returns a status."""
    parser = subparsers.add_parser(
        "generate",
        help="generate an ALLO-like sequence",
        description="Render an ALLO-like sequence of the station: camera base poses around "
        "it (disjoint per split), ALLO's per-frame perturbation, Sun, Earth and Moon of 2030, "
        "procedural anomaly objects placed by ALLO's rules, 3-class masks and camera "
        "realism. The same seed gives identical files.",
    )
    parser.add_argument("--preset", choices=tuple(PRESETS), default="demo", help="(default demo)")
    parser.add_argument("--seed", type=int, default=0, help="sequence seed (default 0)")
    parser.add_argument("--out", type=output_path, help="output folder (default data/<preset>)")
    parser.add_argument("--mesh", type=Path, help="station model (default the package's)")
    parser.add_argument(
        "--frames",
        type=_positive_int,
        help="scale the preset to about this many frames",
    )
    # Options that override a field of the preset's SynthConfig parse into that field's
    # name (dest); one not given is None and keeps the preset's value.
    parser.add_argument("--width", type=_positive_int, help="image width")
    parser.add_argument("--height", type=_positive_int, help="image height")
    parser.add_argument(
        "--jobs", type=_positive_int, default=1, help="worker processes (default 1)"
    )
    parser.add_argument(
        "--references",
        action=argparse.BooleanOptionalAction,
        help="also write pre-rendered references (reported pose, nominal model and light)",
    )
    parser.add_argument(
        "--types",
        dest="anomaly_types",
        metavar="TYPES",
        type=_types,
        help="comma-separated object types",
    )
    for flag, dest, what in (
        ("--position-sigma", "position_sigma_m", "base-pose perturbation, m (1)"),
        ("--rotation-sigma", "rotation_sigma_rad", "base-pose perturbation, rad (0.2)"),
        ("--pose-error-m", "pose_error_m", "reported pose error, m (0.02)"),
        # Degrees on the command line; the config holds radians (see _run_generate).
        ("--pose-error-deg", "pose_error_deg", "reported pose error, deg (0.2)"),
    ):
        metavar = flag[2:].upper().replace("-", "_")
        parser.add_argument(flag, dest=dest, metavar=metavar, type=_non_negative, help=what)
    parser.add_argument(
        "--query-renderer",
        choices=QUERY_RENDERERS,
        help="renderer of the query: pyrender (default, as the references) or cycles "
        "(Blender's path tracer; needs the optional bpy: make bench-cycles)",
    )
    parser.add_argument("--cycles-samples", type=_positive_int, help="Cycles samples (32)")
    parser.add_argument(
        "--camera-effects",
        action=argparse.BooleanOptionalAction,
        help="apply the camera model (exposure, tone curve, noise, ...) to the query (default on)",
    )
    parser.add_argument(
        "--rate-hz", type=_rate, help="frame rate of the stamps (10; trajectories move with it)"
    )
    parser.add_argument(
        "--trajectory-frames",
        type=_positive_int,
        metavar="N",
        help="frames per arm trajectory (presets objects, objects-normal and objects-pt only)",
    )
    parser.add_argument(
        "--clean", action="store_true", help="no camera effects or material variation (debugging)"
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing sequence")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=_run_generate)
    return parser


def _run_generate(args: argparse.Namespace) -> int:
    from allo_mrad_ros.synth.generator import generate

    try:
        config = preset(args.preset)
        if args.frames is not None:
            config = config.with_frames(args.frames)
        pose_error_rad = None if args.pose_error_deg is None else math.radians(args.pose_error_deg)
        config = config.with_overrides(
            **{name: getattr(args, name) for name in _CONFIG_OPTIONS},
            pose_error_rad=pose_error_rad,
        )
        if args.trajectory_frames is not None:
            if config.trajectory is None:
                raise SynthError(
                    "--trajectory-frames needs a trajectory preset (objects, objects-normal, "
                    f"objects-pt), not {args.preset}"
                )
            trajectory = replace(config.trajectory, frames=args.trajectory_frames)
            config = config.with_overrides(trajectory=trajectory)
        if args.clean:
            config = config.with_overrides(realism=replace(config.realism, enabled=False))
        out = args.out if args.out is not None else Path("data") / args.preset
        check_target(out, SEQUENCE, overwrite=args.overwrite, inputs=(args.mesh,))
        # Generated beside the target and renamed at the end: never a half-written folder.
        with staged_folder(out) as staging:
            report = generate(
                config,
                staging,
                args.seed,
                mesh=args.mesh,
                jobs=args.jobs,
                overwrite=True,
                progress=not args.quiet,
            )
        report = replace(report, root=out)
    except TargetError as error:
        print(f"allo-synth generate: error: {error}", file=sys.stderr)
        return 2
    except (AlloError, SynthError) as error:
        # Name the folder asked for, not the hidden one it was built in.
        message = str(error)
        if args.out is not None:
            message = message.replace(str(staging_path(args.out)), str(args.out))
        print(f"allo-synth generate: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("allo-synth generate: interrupted; nothing written", file=sys.stderr)
        return 130
    print(
        f"wrote {report.root}: {report.frames} frames in {report.seconds:.1f} s "
        f"({report.frames_per_minute:.1f} frames/min at {config.width}x{config.height})"
    )
    for split, row in report.composition.items():
        types = ", ".join(f"{k} {v}" for k, v in row["per_type"].items())
        if "trajectories" in row:
            print(
                f"  {split}: {row['trajectories']} trajectories, {row['frames']} frames "
                f"({row['normal']} without an object shown), {row['objects']} objects"
                + (f"; {types}" if types else "")
            )
            continue
        print(
            f"  {split}: {row['frames']} frames ({row['normal']} normal, {row['anomalous']} "
            f"anomalous, {row['cameras']} cameras)" + (f"; {types}" if types else "")
        )
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``allo-synth`` argument parser with its sub-commands."""
    parser = OutputArgumentParser(
        prog="allo-synth", description="ALLO-like sequences: generate them, or import ALLO."
    )
    parser.add_argument("--version", action="version", version=f"allo-synth {package_version()}")
    subparsers = parser.add_subparsers(dest="command", required=True)
    add_generate_parser(subparsers)
    add_import_parser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``allo-synth``; returns the exit status."""
    args = build_parser().parse_args(argv)
    with signals_as_interrupt():
        return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
