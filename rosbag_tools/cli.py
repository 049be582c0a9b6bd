"""The ``allo-bag`` command: write, info, play, evaluate, ablate.

Exit status 0 on success, 1 when the work fails (the message names the file, row, topic or
frame), 2 for a usage error or a refused output folder (:mod:`allo_mrad_ros.targets`), 130
when interrupted (SIGINT or SIGTERM: nothing is left half written). Reports and bags are
built in a hidden sibling folder and renamed into place at the end, so ``--out`` is either
complete or untouched.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from allo_mrad_ros.detector.params import add_params_options
from allo_mrad_ros.errors import AlloError, InvalidInput
from allo_mrad_ros.options import keyword_options
from allo_mrad_ros.render import DEFAULT_SCALE, DEFAULT_SHADOWS
from allo_mrad_ros.resources import package_version
from allo_mrad_ros.staging import (
    signals_as_interrupt,
    staged_folder,
    staging_path,
)
from allo_mrad_ros.targets import (
    ABLATION_REPORT,
    EVALUATION_REPORT,
    OBJECTS_REPORT,
    OutputArgumentParser,
    TargetError,
    check_target,
    output_path,
)
from rosbag_tools.topics import DEFAULT_DISTRO, DISTROS, TopicError, TopicNames
from rosbag_tools.writer import DEFAULT_STORAGE, STORAGES

PROG = "allo-bag"


class CliError(InvalidInput):
    """A command-line value is invalid (reported as a usage error)."""


def _parser() -> argparse.ArgumentParser:
    parser = OutputArgumentParser(
        prog=PROG,
        description="ALLO sequences as rosbag2 bags: write, inspect, replay, evaluate, ablate.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {package_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    write = commands.add_parser("write", help="write a sequence folder as a rosbag2 bag")
    write.add_argument("sequence", type=Path, help="sequence folder (sequence.yaml, frames.csv)")
    write.add_argument("out", type=output_path, help="bag folder to create")
    write.add_argument("--storage", choices=sorted(STORAGES), default=DEFAULT_STORAGE)
    write.add_argument(
        "--distro",
        choices=sorted(DISTROS),
        default=DEFAULT_DISTRO,
        help="ROS 2 distribution whose message definitions the bag embeds",
    )
    write.add_argument(
        "--split",
        dest="splits",
        action="append",
        choices=("train", "val", "test"),
        help="write only this split (repeatable; default: all frames)",
    )
    write.add_argument(
        "--topic",
        action="append",
        default=[],
        metavar="ROLE=NAME",
        help=f"rename a topic; roles: {', '.join(TopicNames.roles())}",
    )
    write.add_argument(
        "--tf-static-parent",
        dest="static_parent",
        metavar="FRAME",
        help="also write /tf_static: identity from FRAME (e.g. world) to the station frame",
    )
    write.add_argument("--overwrite", action="store_true", help="replace an existing bag")
    write.add_argument("--quiet", action="store_true", help="no progress bar")

    info = commands.add_parser("info", help="topics, types, counts, duration, image sizes")
    info.add_argument("bag", type=Path)
    info.add_argument("--json", action="store_true", help="print JSON instead of text")

    play = commands.add_parser("play", help="publish a bag with rclpy at its recorded rate")
    play.add_argument("bag", type=Path)
    play.add_argument("--rate", type=float, default=1.0, help="speed multiple (default 1)")
    play.add_argument("--loop", action="store_true", help="start over at the end")
    play.add_argument("--topics", nargs="+", metavar="TOPIC", help="publish only these topics")
    play.add_argument(
        "--delay",
        type=float,
        default=1.0,
        help="seconds between creating publishers and the first message (discovery)",
    )
    play.add_argument("--clock", action="store_true", help="publish the bag time on /clock")
    play.add_argument(
        "--wait-for",
        nargs="+",
        default=[],
        metavar="TOPIC",
        help="start only once these topics have a subscriber (e.g. the detector's image topic)",
    )
    play.add_argument(
        "--wait-timeout",
        type=float,
        default=30.0,
        help="seconds to wait for those subscribers (default 30)",
    )

    for name, text in (
        ("evaluate", "run MRAD, PAD and RXD on a split and write the metrics report"),
        ("ablate", "the paper's Table II sweeps of MRAD as one table"),
    ):
        sub = commands.add_parser(name, help=text)
        sub.add_argument("input", type=Path, help="sequence folder or bag")
        sub.add_argument("--out", type=output_path, required=True, help="report folder")
        sub.add_argument(
            "--overwrite", action="store_true", help=f"replace an existing {name} report"
        )
        sub.add_argument("--split", choices=("train", "val", "test"), help="default: test, or all")
        sub.add_argument(
            "--limit", type=int, help="at most this many frames, evenly spread over the split"
        )
        sub.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
        add_params_options(sub)
        sub.add_argument(
            "--reference-scale",
            type=float,
            default=DEFAULT_SCALE,
            help=f"linear scale of the rendered reference (default {DEFAULT_SCALE})",
        )
        sub.add_argument(
            "--use-sequence-references",
            action="store_true",
            help="use the sequence's pre-rendered references instead of rendering",
        )
        sub.add_argument("--mesh", type=Path, help="station model instead of the input's own")
        sub.add_argument(
            "--shadows",
            action=argparse.BooleanOptionalAction,
            default=DEFAULT_SHADOWS,
            help=f"render Sun shadows in the reference (default {DEFAULT_SHADOWS})",
        )
        sub.add_argument(
            "--reuse-reference",
            action="store_true",
            help="warp the last render to nearby frames within the node's default bounds, "
            "frames in time order, as the node does (docs/node.md, Reference reuse); "
            "default: render every frame",
        )
        sub.add_argument(
            "--array-backend",
            default="numpy",
            help="where the detectors' per-pixel work runs: numpy (default), torch, "
            "torch:cuda or torch:cpu (docs/detector.md)",
        )
        sub.add_argument("--quiet", action="store_true", help="no progress bar")
        if name == "evaluate":
            sub.add_argument(
                "--methods",
                default="MRAD,PAD,RXD",
                help="comma-separated methods (default MRAD,PAD,RXD)",
            )
            sub.add_argument("--overlays", type=int, default=8, help="example frames (default 8)")
            sub.add_argument(
                "--objects",
                action="store_true",
                help="track MRAD's regions as objects in the station frame and measure them "
                "against the input's ground-truth objects (docs/evaluation.md, Objects): "
                "writes objects.json and objects.md",
            )
            sub.add_argument(
                "--object-set",
                action="append",
                default=[],
                metavar="NAME=VALUE",
                help="an object tracker parameter (docs/objects.md), with --objects; repeatable",
            )
    return parser


def _write(args: argparse.Namespace) -> str:
    from rosbag_tools.writer import write_bag

    summary = write_bag(
        args.sequence,
        args.out,
        topics=TopicNames.from_assignments(args.topic),
        **keyword_options(args, "storage", "distro", "splits", "static_parent", "overwrite"),
    )
    return (
        f"wrote {summary.path}: {summary.frames} frames, {sum(summary.messages.values())} "
        f"messages on {len(summary.messages)} topics ({summary.storage}, {summary.distro} "
        "definitions)"
    )


def _info(args: argparse.Namespace) -> str:
    from rosbag_tools.info import bag_info, format_info

    info = bag_info(args.bag)
    return json.dumps(info.as_dict(), indent=2) if args.json else format_info(info)


def _play(args: argparse.Namespace) -> str:
    from rosbag_tools.play import play_bag

    options = ("rate", "loop", "topics", "delay", "clock", "wait_for", "wait_timeout")
    summary = play_bag(args.bag, **keyword_options(args, *options))
    return (
        f"published {sum(summary.published.values())} messages on {len(summary.published)} "
        f"topics in {summary.wall_s:.2f} s ({summary.passes} pass(es)); "
        f"skipped {len(summary.skipped)}"
    )


def _source(args: argparse.Namespace) -> object:
    from allo_mrad_ros.render.model import load_model
    from rosbag_tools.bag_source import open_source

    if args.mesh is not None:
        load_model(args.mesh)  # here, so a bad model is one clear error, not a dead worker

    return open_source(args.input, mesh=args.mesh, use_references=args.use_sequence_references)


def pipeline_config(args: argparse.Namespace, methods: Sequence[str] = ("MRAD",)) -> object:
    """The :class:`~allo_mrad_ros.pipeline.PipelineConfig` of ``evaluate``/``ablate`` options.

    Raises
    ------
    CliError
        For an unknown profile, method or parameter, or a value out of range.
    """
    from allo_mrad_ros.detector.params import params_from
    from allo_mrad_ros.pipeline import PipelineConfig, RenderSettings
    from allo_mrad_ros.render.reuse import ReuseBounds

    try:
        return PipelineConfig(
            RenderSettings(
                reference_scale=args.reference_scale,
                shadows=args.shadows,
                reuse=ReuseBounds() if getattr(args, "reuse_reference", False) else None,
            ),
            params_from(args.profile, args.set),
            tuple(methods),
            args.array_backend,
        )
    except ValueError as error:  # InvalidInput, or the detector's ParamsError
        raise CliError(str(error)) from None


def object_params(assignments: Sequence[str]) -> object:
    """The :class:`~allo_mrad_ros.objects.ObjectParams` of ``--object-set name=value``.

    Raises
    ------
    CliError
        For a malformed assignment, an unknown name or a value out of range.
    """
    from allo_mrad_ros.objects import ObjectsError
    from allo_mrad_ros.objects.params import params_from

    try:
        return params_from(assignments)
    except ObjectsError as error:
        raise CliError(f"--object-set: {error}") from None


def _evaluate_objects(args: argparse.Namespace) -> str:
    from allo_mrad_ros.evaluation.objects import (
        ObjectEvaluationConfig,
        evaluate_objects,
        objects_markdown,
    )

    config = ObjectEvaluationConfig(
        pipeline=pipeline_config(args, ("MRAD",)),
        params=object_params(args.object_set),
        split=args.split,
        jobs=args.jobs,
        progress=not args.quiet,
    )
    check_target(args.out, OBJECTS_REPORT, overwrite=args.overwrite, inputs=(args.input, args.mesh))
    result = evaluate_objects(_source(args), config)
    markdown = objects_markdown(result)
    with staged_folder(args.out) as staging:
        (staging / "objects.json").write_text(json.dumps(result.as_dict(), indent=2) + "\n")
        (staging / "objects.md").write_text(markdown)
    return f"{markdown.rstrip()}\n\nreport in {args.out}"


def _evaluate(args: argparse.Namespace) -> str:
    from allo_mrad_ros.evaluation.evaluate import EvaluationConfig, evaluate

    if args.objects:
        if args.limit is not None:
            raise CliError("--limit does not apply with --objects: the tracker needs every frame")
        if args.use_sequence_references:
            raise CliError(
                "--use-sequence-references does not apply with --objects: it needs "
                "the rendered reference's depth"
            )
        return _evaluate_objects(args)
    if args.object_set:
        raise CliError("--object-set needs --objects")
    from allo_mrad_ros.evaluation.report import evaluation_markdown, write_evaluation_report

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    config = EvaluationConfig(
        pipeline=pipeline_config(args, methods),
        split=args.split,
        limit=args.limit,
        jobs=args.jobs,
        overlays=args.overlays,
        progress=not args.quiet,
    )
    check_target(
        args.out, EVALUATION_REPORT, overwrite=args.overwrite, inputs=(args.input, args.mesh)
    )
    result = evaluate(_source(args), config)
    with staged_folder(args.out) as staging:
        write_evaluation_report(result, staging)
    table = evaluation_markdown(result).split("\n## ")[0]
    return (
        f"{table.rstrip()}\n\n{result.frames_per_second:.2f} frames/s with {config.jobs} "
        f"job(s); report in {args.out}"
    )


def _ablate(args: argparse.Namespace) -> str:
    from allo_mrad_ros.evaluation.ablate import ablate
    from allo_mrad_ros.evaluation.report import ablation_markdown, write_ablation_report

    check_target(
        args.out, ABLATION_REPORT, overwrite=args.overwrite, inputs=(args.input, args.mesh)
    )
    result = ablate(
        _source(args),
        config=pipeline_config(args),
        split=args.split,
        limit=args.limit,
        jobs=args.jobs,
        progress=not args.quiet,
    )
    with staged_folder(args.out) as staging:
        write_ablation_report(result, staging)
    return f"{ablation_markdown(result).rstrip()}\n\nreport in {args.out}"


_COMMANDS = {
    "write": _write,
    "info": _info,
    "play": _play,
    "evaluate": _evaluate,
    "ablate": _ablate,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``allo-bag`` with ``argv`` (default: the process arguments).

    Returns
    -------
    int
        Exit status.
    """
    parser = _parser()
    args = parser.parse_args(argv)
    # Our own warnings (skipped topics) at INFO and up; other libraries' chatter stays out.
    logging.basicConfig(level=logging.WARNING, format=f"{PROG} {args.command}: %(message)s")
    logging.getLogger("allo_bag").setLevel(logging.INFO)
    try:
        with signals_as_interrupt():
            print(_COMMANDS[args.command](args))
    except (CliError, TopicError) as error:
        parser.error(str(error))
    except TargetError as error:  # a refused output: a usage error, in one line
        print(f"{PROG} {args.command}: error: {error}", file=sys.stderr)
        return 2
    except AlloError as error:
        message = str(error)
        out = getattr(args, "out", None)
        if out is not None:  # name the folder asked for, not the hidden one it was built in
            message = message.replace(str(staging_path(out)), str(out))
        print(f"{PROG} {args.command}: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
