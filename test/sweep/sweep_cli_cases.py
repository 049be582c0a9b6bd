"""The command-line cases of the sweep: ``allo-bag`` and ``allo-synth`` with bad input.

Fixtures (built once by :mod:`sweep`): ``{seq}`` a tiny rendered sequence, ``{bag}`` its bag
(MCAP folder), ``{mcap}`` that bag's storage file, ``{allo}`` a tiny ALLO split, ``{bigseq}`` a longer sequence (a write that a signal
can interrupt), ``{mesh}`` the
package's station model, ``{baseline}`` the intact bag's MRAD metrics.
"""

from __future__ import annotations

import json
import shutil
import signal
from pathlib import Path

from sweep_run import CliCase

WRITE = ("write", "{seq}")
EVAL = ("evaluate", "--methods", "MRAD", "--overlays", "0", "--quiet")
SMOKE = ("generate", "--preset", "smoke", "--frames", "2", "--no-references", "--quiet")
IMPORT = ("import-allo", "{allo}", "--quiet")


# --- preparations -------------------------------------------------------------------------


def a_file(ws: Path, fx: dict) -> None:
    (ws / "file").write_text("not a folder\n")


def empty_folder(ws: Path, fx: dict) -> None:
    (ws / "empty").mkdir()


def copy_sequence(ws: Path, fx: dict) -> Path:
    return Path(shutil.copytree(fx["seq"], ws / "seq"))


def sequence_with(edit):
    def prepare(ws: Path, fx: dict) -> None:
        edit(copy_sequence(ws, fx))

    return prepare


def garbage_frames(seq: Path) -> None:
    (seq / "frames.csv").write_text("this,is\nnot,frames\n\x00\x01")


def nan_position(seq: Path) -> None:
    lines = (seq / "frames.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[2].split(",")
    row[header.index("tx")] = "nan"
    lines[2] = ",".join(row)
    (seq / "frames.csv").write_text("\n".join(lines) + "\n")


def set_cell(column: str, value: str, row: int = 2):
    """An edit of ``frames.csv``: ``column`` of data row ``row`` becomes ``value``."""

    def edit(seq: Path) -> None:
        lines = (seq / "frames.csv").read_text().splitlines()
        header = lines[0].split(",")
        cells = lines[row].split(",")
        cells[header.index(column)] = value
        lines[row] = ",".join(cells)
        (seq / "frames.csv").write_text("\n".join(lines) + "\n")

    return edit


def first_png(seq: Path, kind: str) -> Path:
    return sorted((seq / "test").glob(f"Camera*/{kind}/*.png"))[0]


def truncate_image(seq: Path) -> None:
    image = first_png(seq, "images")
    image.write_bytes(image.read_bytes()[:200])


def remove_image(seq: Path) -> None:
    first_png(seq, "images").unlink()


def bad_mask(seq: Path) -> None:
    import cv2
    import numpy as np

    mask = first_png(seq, "masks")
    image = cv2.imread(str(mask), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(mask), np.full_like(image, 7))


def garbage_meta(seq: Path) -> None:
    (seq / "sequence.yaml").write_text("{[: not yaml\n")


def existing_out(ws: Path, fx: dict) -> None:
    (ws / "out").mkdir()
    (ws / "out" / "keep.txt").write_text("mine")


def stale_partial(ws: Path, fx: dict) -> None:
    stale = ws / ".out.partial-4194000"  # no such process (above the usual pid range)
    stale.mkdir()
    (stale / "junk").write_bytes(b"x" * 1000)


def copy_bag(ws: Path, fx: dict) -> Path:
    return Path(shutil.copytree(fx["bag"], ws / "bag"))


def corrupt_middle(path: Path, count: int = 4000) -> None:
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + count] = bytes((i * 37 + 11) % 256 for i in range(count))
    path.write_bytes(bytes(data))


def corrupted_bag(ws: Path, fx: dict) -> None:
    bag = copy_bag(ws, fx)
    corrupt_middle(next(bag.glob("*.mcap")))


def truncated_bag(ws: Path, fx: dict) -> None:
    bag = copy_bag(ws, fx)
    storage = next(bag.glob("*.mcap"))
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])


def garbage_metadata(ws: Path, fx: dict) -> None:
    bag = copy_bag(ws, fx)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")


def lone_corrupted_mcap(ws: Path, fx: dict) -> None:
    target = ws / "lone.mcap"
    shutil.copy(fx["mcap"], target)
    corrupt_middle(target)


def ros1_bag(ws: Path, fx: dict) -> None:
    (ws / "old.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(100))


def random_mcap(ws: Path, fx: dict) -> None:
    (ws / "random.mcap").write_bytes(bytes(range(256)) * 40)


def garbage_mesh(ws: Path, fx: dict) -> None:
    (ws / "garbage.glb").write_bytes(b"glTF\x02\x00\x00\x00 definitely not a model" * 10)


def copy_allo(ws: Path, fx: dict) -> Path:
    """A copy of the ALLO split as ``{ws}/allo/ALLO/test`` (the folder names the split)."""
    return Path(shutil.copytree(fx["allo"], ws / "allo" / "ALLO" / "test"))


def renamed_allo(ws: Path, fx: dict) -> None:
    copy_allo(ws, fx).rename(ws / "allo" / "ALLO" / "camera_dump")


def truncated_allo_png(ws: Path, fx: dict) -> None:
    image = sorted(copy_allo(ws, fx).rglob("images/*.png"))[-1]
    image.write_bytes(image.read_bytes()[: image.stat().st_size // 2])


def small_allo_mask(ws: Path, fx: dict) -> None:
    import cv2
    import numpy as np

    mask = sorted(copy_allo(ws, fx).rglob("masks/*.png"))[0]
    cv2.imwrite(str(mask), np.ones((4, 4), np.uint8))


def badly_named_allo(ws: Path, fx: dict) -> None:
    image = sorted(copy_allo(ws, fx).rglob("images/*.png"))[0]
    image.rename(image.with_name("what_is_this.png"))


def same_metrics(ws: Path, fx: dict) -> str | None:
    """A report that claims success must hold the intact bag's figures."""
    found = json.loads((ws / "report" / "metrics.json").read_text())
    if found.get("methods") != fx["baseline"].get("methods"):
        return "metrics differ from the intact bag's"
    return None


def existing_bag(ws: Path, fx: dict) -> None:
    shutil.copytree(fx["bag"], ws / "out")


def existing_bag_with_an_immutable_file(ws: Path, fx: dict) -> None:
    """An old bag whose storage file is immutable (``chattr +i``): root cannot remove it
    either. Where the file system has no such attribute, ``no-chattr`` says so."""
    import subprocess

    existing_bag(ws, fx)
    storage = next((ws / "out").glob("*.mcap"))
    if subprocess.run(["chattr", "+i", str(storage)], capture_output=True).returncode != 0:
        (ws / "no-chattr").touch()


def mutable_again(ws: Path) -> None:
    import subprocess

    for storage in ws.rglob("*.mcap"):
        subprocess.run(["chattr", "-i", str(storage)], capture_output=True)


def new_bag_in_place(ws: Path, fx: dict) -> str | None:
    """The path holds a complete bag whose files match the digests recorded at writing."""
    from rosbag_tools.info import bag_info

    try:
        bag_info(ws / "out")
    except Exception as error:  # any failure to read it back is the finding
        return f"no complete bag at out: {error}"
    return None


def old_bag_left_whole(ws: Path, fx: dict) -> str | None:
    """The new bag in place and the old one, whole, at the one ``.out.old-<pid>`` named."""
    if (ws / "no-chattr").exists():
        return None
    found = new_bag_in_place(ws, fx)
    if found:
        return found
    old = list(ws.glob(".out.old-*"))
    storage = next(Path(fx["bag"]).glob("*.mcap"))
    if len(old) != 1 or (old[0] / storage.name).read_bytes() != storage.read_bytes():
        return f"the old bag is not left whole at one .out.old-<pid>: {old}"
    return None


def no_stale_left(ws: Path, fx: dict) -> str | None:
    return "stale partial kept" if any(ws.glob(".out.partial-*")) else None


# --- the cases ---------------------------------------------------------------------------


def cli_cases() -> list[CliCase]:
    """Every command-line case of the sweep."""
    b, s = "allo-bag write", "allo-synth generate"
    cases = [
        CliCase(b, "missing sequence", ("write", "{ws}/nope", "{ws}/out"), "nope", quick=True),
        CliCase(
            b, "sequence is a file", ("write", "{ws}/file", "{ws}/out"), "file", prepare=a_file
        ),
        CliCase(
            b,
            "empty sequence folder",
            ("write", "{ws}/empty", "{ws}/out"),
            "empty",
            prepare=empty_folder,
        ),
        CliCase(
            b,
            "garbage frames.csv",
            ("write", "{ws}/seq", "{ws}/out"),
            "frames.csv",
            prepare=sequence_with(garbage_frames),
        ),
        CliCase(
            b,
            "NaN pose in a row",
            ("write", "{ws}/seq", "{ws}/out"),
            "row",
            prepare=sequence_with(nan_position),
        ),
        CliCase(
            b,
            "translation of 1e300 in a row",
            ("write", "{ws}/seq", "{ws}/out"),
            r"row 2 .*'tx'.*not physical",
            prepare=sequence_with(set_cell("tx", "1e300")),
        ),
        CliCase(
            b,
            "Moon radius of 1e300 in a row",
            ("write", "{ws}/seq", "{ws}/out"),
            r"row 2 .*'moon_r'.*not physical",
            prepare=sequence_with(set_cell("moon_r", "1e300")),
        ),
        CliCase(
            b,
            "Sun strength of 1e300 in a row",
            ("write", "{ws}/seq", "{ws}/out"),
            r"row 2 .*'sun_strength'.*not physical",
            prepare=sequence_with(set_cell("sun_strength", "1e300")),
        ),
        CliCase(
            b,
            "truncated PNG",
            ("write", "{ws}/seq", "{ws}/out"),
            r"\.png",
            prepare=sequence_with(truncate_image),
        ),
        CliCase(
            b,
            "missing image",
            ("write", "{ws}/seq", "{ws}/out"),
            r"\.png",
            prepare=sequence_with(remove_image),
        ),
        CliCase(
            b,
            "mask value 7",
            ("write", "{ws}/seq", "{ws}/out"),
            "mask",
            prepare=sequence_with(bad_mask),
        ),
        CliCase(
            b,
            "garbage sequence.yaml",
            ("write", "{ws}/seq", "{ws}/out"),
            "sequence.yaml",
            prepare=sequence_with(garbage_meta),
        ),
        CliCase(
            b,
            "output exists",
            (*WRITE, "{ws}/out"),
            "not a bag",
            prepare=existing_out,
            quick=True,
        ),
        CliCase(
            b,
            "output under a file",
            (*WRITE, "{ws}/file/out"),
            "cannot create",
            prepare=a_file,
            quick=True,
        ),
        CliCase(
            b, "read-only folder", (*WRITE, "{locked}/out"), "Read-only", mount="ro", quick=True
        ),
        CliCase(
            b,
            "full disk",
            (*WRITE, "{disk}/out"),
            "No space left",
            mount="full",
            disk_kb=256,
            quick=True,
        ),
        CliCase(
            b,
            "SIGTERM mid-write",
            ("write", "{bigseq}", "{ws}/out"),
            "interrupted",
            signal=signal.SIGTERM,
            hold="bag-frame",
            quick=True,
        ),
        CliCase(
            b,
            "SIGTERM while starting",
            ("write", "{bigseq}", "{ws}/out"),
            "interrupted",
            signal=signal.SIGTERM,
            signal_after_s=1.0,
            hold="bag-frame",  # after 1 s it is starting or held: never finished
        ),
        CliCase(
            b,
            "SIGINT mid-write",
            ("write", "{bigseq}", "{ws}/out"),
            "interrupted",
            signal=signal.SIGINT,
            hold="bag-frame",
        ),
        CliCase(
            b,
            "SIGTERM during the final swap",
            (*WRITE, "{ws}/out", "--overwrite"),
            expect_error=False,
            prepare=existing_bag,
            signal=signal.SIGTERM,
            hold="swap",
            outputs=("out",),
            check=new_bag_in_place,
            quick=True,
        ),
        CliCase(
            b,
            "SIGINT during the final swap",
            (*WRITE, "{ws}/out", "--overwrite"),
            expect_error=False,
            prepare=existing_bag,
            signal=signal.SIGINT,
            hold="swap",
            outputs=("out",),
            check=new_bag_in_place,
        ),
        CliCase(
            b,
            "old bag with an immutable file, --overwrite",
            (*WRITE, "{ws}/out", "--overwrite"),
            expect_error=False,
            prepare=existing_bag_with_an_immutable_file,
            outputs=("out", ".out.old-*", "no-chattr"),
            check=old_bag_left_whole,
            cleanup=mutable_again,
        ),
        CliCase(
            b,
            "stale partial of a dead process",
            (*WRITE, "{ws}/out"),
            expect_error=False,
            prepare=stale_partial,
            outputs=("out",),
            check=no_stale_left,
        ),
        CliCase(b, "bad --storage", (*WRITE, "{ws}/out", "--storage", "zip"), "storage"),
        CliCase(b, "unknown topic role", (*WRITE, "{ws}/out", "--topic", "lens=/x"), "lens"),
        CliCase(
            b, "invalid topic name", (*WRITE, "{ws}/out", "--topic", "image=bad name!"), "bad name"
        ),
        CliCase(b, "bad --distro", (*WRITE, "{ws}/out", "--distro", "rolling"), "distro"),
        CliCase(b, "split with no frames", (*WRITE, "{ws}/out", "--split", "val"), "val"),
        CliCase(
            b, "empty tf-static parent", (*WRITE, "{ws}/out", "--tf-static-parent", ""), "frame"
        ),
        CliCase(
            b,
            "bag over its own sequence",
            ("write", "{ws}/seq", "{ws}/seq", "--overwrite"),
            "seq",
            prepare=copy_sequence,
        ),
    ]
    b = "allo-bag info"
    cases += [
        CliCase(b, "missing bag", ("info", "{ws}/nope"), "not found", quick=True),
        CliCase(b, "a plain file", ("info", "{ws}/file"), "file", prepare=a_file),
        CliCase(b, "empty folder", ("info", "{ws}/empty"), "empty", prepare=empty_folder),
        CliCase(
            b,
            "4000 bytes corrupted",
            ("info", "{ws}/bag"),
            r"topic /\S+ .*stamp",
            prepare=corrupted_bag,
            quick=True,
        ),
        CliCase(b, "truncated storage file", ("info", "{ws}/bag"), "bag", prepare=truncated_bag),
        CliCase(
            b,
            "garbage metadata.yaml",
            ("info", "{ws}/bag"),
            "metadata.yaml",
            prepare=garbage_metadata,
        ),
        CliCase(
            b,
            "lone corrupted .mcap",
            ("info", "{ws}/lone.mcap"),
            "lone.mcap",
            prepare=lone_corrupted_mcap,
        ),
        CliCase(b, "ROS 1 bag", ("info", "{ws}/old.bag"), "ROS 1", prepare=ros1_bag),
        CliCase(
            b,
            "random bytes .mcap",
            ("info", "{ws}/random.mcap"),
            "random.mcap",
            prepare=random_mcap,
        ),
        CliCase(
            b,
            "corrupted, --json",
            ("info", "{ws}/bag", "--json"),
            r"topic /\S+ .*stamp",
            prepare=corrupted_bag,
        ),
    ]
    b = "allo-bag play"
    cases += [
        CliCase(b, "missing bag", ("play", "{ws}/nope"), "not found"),
        CliCase(
            b,
            "4000 bytes corrupted",
            ("play", "{ws}/bag", "--delay", "0"),
            r"topic /\S+ .*stamp",
            prepare=corrupted_bag,
        ),
        CliCase(b, "rate 0", ("play", "{bag}", "--rate", "0"), "rate"),
        CliCase(b, "rate -1", ("play", "{bag}", "--rate", "-1"), "rate"),
        CliCase(b, "rate nan", ("play", "{bag}", "--rate", "nan"), "rate"),
        CliCase(b, "delay -1", ("play", "{bag}", "--delay", "-1"), "delay"),
        CliCase(
            b,
            "unknown --topics",
            ("play", "{bag}", "--topics", "/nowhere", "--delay", "0"),
            "/nowhere",
        ),
        CliCase(
            b,
            "wait-for with no subscriber",
            ("play", "{bag}", "--wait-for", "/nobody", "--wait-timeout", "1"),
            "/nobody",
        ),
        CliCase(
            b,
            "wait-timeout -5",
            ("play", "{bag}", "--wait-for", "/x", "--wait-timeout", "-5"),
            "wait",
        ),
        CliCase(
            b,
            "SIGINT while playing",
            ("play", "{bag}", "--loop", "--delay", "0"),
            "interrupted",
            signal=signal.SIGINT,
            signal_after_s=6.0,
        ),
        CliCase(
            b,
            "SIGTERM while playing",
            ("play", "{bag}", "--loop", "--delay", "0"),
            "interrupted",
            signal=signal.SIGTERM,
            signal_after_s=6.0,
        ),
    ]
    b = "allo-bag evaluate"
    out = ("--out", "{ws}/report")
    cases += [
        CliCase(
            b,
            "4000 bytes corrupted",
            (*EVAL, "{ws}/bag", *out),
            r"topic /\S+ .*stamp",
            prepare=corrupted_bag,
            quick=True,
        ),
        CliCase(
            b,
            "lone corrupted .mcap",
            (*EVAL, "{ws}/lone.mcap", *out),
            "lone.mcap",
            prepare=lone_corrupted_mcap,
            outputs=("report",),
            check=same_metrics,
        ),
        CliCase(
            b,
            "garbage --mesh",
            (*EVAL, "{bag}", *out, "--mesh", "{ws}/garbage.glb"),
            "garbage.glb",
            prepare=garbage_mesh,
            quick=True,
        ),
        CliCase(b, "missing --mesh", (*EVAL, "{bag}", *out, "--mesh", "{ws}/none.glb"), "none.glb"),
        CliCase(
            b,
            "report under a file",
            (*EVAL, "{bag}", "--out", "{ws}/file/report"),
            "cannot create",
            prepare=a_file,
        ),
        CliCase(
            b,
            "read-only report folder",
            (*EVAL, "{bag}", "--out", "{locked}/report"),
            "Read-only",
            mount="ro",
        ),
        CliCase(
            b,
            "full disk",
            (*EVAL, "{bag}", "--out", "{disk}/report"),
            "No space left",
            mount="full",
            disk_kb=24,
            quick=True,
        ),
        CliCase(b, "limit 0", (*EVAL, "{bag}", *out, "--limit", "0"), "limit"),
        CliCase(b, "limit -3", (*EVAL, "{bag}", *out, "--limit", "-3"), "limit"),
        CliCase(b, "jobs 0", (*EVAL, "{bag}", *out, "--jobs", "0"), "jobs"),
        CliCase(b, "unknown profile", (*EVAL, "{bag}", *out, "--profile", "fastest"), "fastest"),
        CliCase(b, "grid=0", (*EVAL, "{bag}", *out, "--set", "grid=0"), "grid"),
        CliCase(b, "grid=abc", (*EVAL, "{bag}", *out, "--set", "grid=abc"), "grid"),
        CliCase(b, "unknown parameter", (*EVAL, "{bag}", *out, "--set", "gird=4"), "gird"),
        CliCase(b, "--set without =", (*EVAL, "{bag}", *out, "--set", "grid"), "grid"),
        CliCase(
            b, "unknown method", ("evaluate", "{bag}", *out, "--methods", "FOO", "--quiet"), "FOO"
        ),
        CliCase(
            b,
            "empty method list",
            ("evaluate", "{bag}", *out, "--methods", ",", "--quiet"),
            "method",
        ),
        CliCase(b, "reference scale 0", (*EVAL, "{bag}", *out, "--reference-scale", "0"), "scale"),
        CliCase(
            b, "reference scale nan", (*EVAL, "{bag}", *out, "--reference-scale", "nan"), "scale"
        ),
        CliCase(b, "split with no frames", (*EVAL, "{bag}", *out, "--split", "val"), "val"),
        CliCase(
            b, "overlays -1", ("evaluate", "{bag}", *out, "--overlays", "-1", "--quiet"), "overlays"
        ),
        CliCase(
            b,
            "input is an empty folder",
            (*EVAL, "{ws}/empty", *out),
            "empty",
            prepare=empty_folder,
        ),
        CliCase(
            b,
            "sequence with a translation of 1e300",
            (*EVAL, "{ws}/seq", *out),
            r"row 2 .*'tx'.*not physical",
            prepare=sequence_with(set_cell("tx", "1e300")),
        ),
        CliCase(
            b,
            "sequence with truncated PNG",
            (*EVAL, "{ws}/seq", *out),
            r"\.png",
            prepare=sequence_with(truncate_image),
        ),
        CliCase(
            b,
            "SIGTERM mid-evaluate",
            (*EVAL, "{bag}", *out),
            "interrupted",
            signal=signal.SIGTERM,
            hold="evaluate-frame",
        ),
        CliCase(
            "allo-bag ablate",
            "report under a file",
            ("ablate", "{bag}", "--out", "{ws}/file/r", "--quiet", "--limit", "2"),
            "cannot create",
            prepare=a_file,
        ),
        CliCase(
            "allo-bag ablate",
            "4000 bytes corrupted",
            ("ablate", "{ws}/bag", "--out", "{ws}/r", "--quiet"),
            r"topic /\S+ .*stamp",
            prepare=corrupted_bag,
        ),
        CliCase("allo-bag", "no command", (), "(?i)command"),
        CliCase("allo-bag", "unknown command", ("record",), "record"),
    ]
    o = ("--out", "{ws}/seq")
    cases += [
        CliCase(
            s,
            "output under a file",
            (*SMOKE, "--out", "{ws}/file/seq"),
            "cannot create",
            prepare=a_file,
        ),
        CliCase(
            s,
            "read-only folder",
            (*SMOKE, "--out", "{locked}/seq"),
            "Read-only",
            mount="ro",
            quick=True,
        ),
        CliCase(
            s,
            "full disk",
            (*SMOKE, "--out", "{disk}/seq"),
            "No space left",
            mount="full",
            disk_kb=48,
        ),
        CliCase(
            s,
            "garbage --mesh",
            (*SMOKE, *o, "--mesh", "{ws}/garbage.glb"),
            "garbage.glb",
            prepare=garbage_mesh,
        ),
        CliCase(s, "missing --mesh", (*SMOKE, *o, "--mesh", "{ws}/none.glb"), "none.glb"),
        CliCase(s, "width 0", (*SMOKE, *o, "--width", "0"), "width"),
        CliCase(
            s,
            "width beyond the renderer",
            (*SMOKE, *o, "--width", "40000", "--height", "40"),
            "width|40000",
        ),
        CliCase(s, "unknown preset", ("generate", "--preset", "huge", *o), "huge"),
        CliCase(s, "seed abc", (*SMOKE, *o, "--seed", "abc"), "seed"),
        CliCase(s, "frames 0", ("generate", "--preset", "smoke", "--frames", "0", *o), "frames"),
        CliCase(s, "frames -1", ("generate", "--preset", "smoke", "--frames", "-1", *o), "frames"),
        CliCase(s, "unknown object type", (*SMOKE, *o, "--types", "anvil"), "anvil"),
        CliCase(
            s,
            "output holds other files",
            (*SMOKE, "--out", "{ws}/out"),
            "not a sequence",
            prepare=existing_out,
        ),
        CliCase(
            s,
            "output holds a sequence",
            (*SMOKE, "--out", "{ws}/seq"),
            "--overwrite",
            prepare=copy_sequence,
        ),
        CliCase(
            s,
            "SIGINT mid-generate",
            (*SMOKE, *o),
            "interrupted",
            signal=signal.SIGINT,
            hold="generate-frame",
        ),
        CliCase(
            s,
            "SIGTERM mid-generate",
            (*SMOKE, *o),
            "interrupted",
            signal=signal.SIGTERM,
            hold="generate-frame",
            quick=True,
        ),
    ]
    i = "allo-synth import-allo"
    cases += [
        CliCase(i, "read-only folder", (*IMPORT, "--out", "{locked}/seq"), "Read-only", mount="ro"),
        CliCase(
            i,
            "output under a file",
            (*IMPORT, "--out", "{ws}/file/seq"),
            "cannot create",
            prepare=a_file,
        ),
        CliCase(
            i,
            "truncated PNG with --validate",
            ("import-allo", "{ws}/allo/ALLO/test", "--out", "{ws}/seq", "--validate", "--quiet"),
            r"\.png",
            prepare=truncated_allo_png,
            quick=True,
        ),
        CliCase(
            i,
            "mask of the wrong size",
            ("import-allo", "{ws}/allo/ALLO/test", "--out", "{ws}/seq", "--validate", "--quiet"),
            "mask",
            prepare=small_allo_mask,
        ),
        CliCase(
            i, "missing split folder", ("import-allo", "{ws}/nope", "--out", "{ws}/seq"), "nope"
        ),
        CliCase(
            i,
            "split folder is a file",
            ("import-allo", "{ws}/file", "--out", "{ws}/seq"),
            "file",
            prepare=a_file,
        ),
        CliCase(
            i,
            "empty split folder",
            ("import-allo", "{ws}/empty", "--out", "{ws}/seq"),
            "empty",
            prepare=empty_folder,
        ),
        CliCase(
            i,
            "unparsable image name",
            ("import-allo", "{ws}/allo/ALLO/test", "--out", "{ws}/seq", "--quiet"),
            "what_is_this",
            prepare=badly_named_allo,
        ),
        CliCase(i, "rate 0", (*IMPORT, "--out", "{ws}/seq", "--rate-hz", "0"), "rate"),
        CliCase(i, "rate nan", (*IMPORT, "--out", "{ws}/seq", "--rate-hz", "nan"), "rate"),
        CliCase(
            i,
            "output holds other files",
            (*IMPORT, "--out", "{ws}/out"),
            "not a sequence",
            prepare=existing_out,
        ),
        CliCase(
            i,
            "output holds a sequence",
            (*IMPORT, "--out", "{ws}/seq"),
            "--overwrite",
            prepare=copy_sequence,
        ),
        CliCase(
            i,
            "split not named by its folder",
            ("import-allo", "{ws}/allo/ALLO/camera_dump", "--out", "{ws}/seq"),
            "--split",
            prepare=renamed_allo,
        ),
        CliCase(
            i,
            "full disk with --copy",
            (*IMPORT, "--out", "{disk}/seq", "--copy"),
            "No space left",
            mount="full",
            disk_kb=48,
        ),
        CliCase(
            i,
            "SIGTERM mid-copy",
            (*IMPORT, "--out", "{ws}/seq", "--copy"),
            "interrupted",
            signal=signal.SIGTERM,
            hold="import-frame",
        ),
        CliCase("allo-synth", "no command", (), "(?i)command"),
    ]
    return cases


# --- station models in the formats meshes/README.md lists ---------------------------------
# A block of its own: cli_cases() above gains these cases at the end of its list.


def latin1_obj(ws: Path, fx: dict) -> None:
    """A valid OBJ whose exporter wrote a Latin-1 comment (not UTF-8)."""
    (ws / "m.obj").write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n# caf\xe9\n")


def garbage_model(suffix: str):
    def prepare(ws: Path, fx: dict) -> None:
        (ws / f"garbage.{suffix}").write_bytes(bytes(range(256)) * 8)

    return prepare


def has_metrics(ws: Path, fx: dict) -> str | None:
    found = json.loads((ws / "report" / "metrics.json").read_text())
    return None if found.get("methods") else "a report without metrics"


def mesh_format_cases() -> list[CliCase]:
    """A Latin-1 OBJ loads; a garbage file of each listed format is refused in one line that
    names the file and the format."""
    b = "allo-bag evaluate"
    out = ("--out", "{ws}/report")
    cases = [
        CliCase(
            b,
            "Latin-1 OBJ --mesh",
            (*EVAL, "{bag}", *out, "--mesh", "{ws}/m.obj"),
            expect_error=False,
            prepare=latin1_obj,
            outputs=("report",),
            check=has_metrics,
            quick=True,
        )
    ]
    formats = {"obj": "OBJ", "stl": "STL", "ply": "PLY", "off": "OFF", "3mf": "3MF"}
    formats |= {"gltf": "glTF", "glb": "GLB", "dae": "DAE"}
    for suffix, name in formats.items():
        cases.append(
            CliCase(
                b,
                f"garbage {suffix} --mesh",
                (*EVAL, "{bag}", *out, "--mesh", f"{{ws}}/garbage.{suffix}"),
                rf"garbage\.{suffix}.*{name}",
                prepare=garbage_model(suffix),
            )
        )
    return cases


_cli_cases_before_mesh_formats = cli_cases


def cli_cases() -> list[CliCase]:
    """Every command-line case of the sweep (the list above and the model formats')."""
    return [*_cli_cases_before_mesh_formats(), *mesh_format_cases()]
