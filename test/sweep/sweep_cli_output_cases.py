"""Command-line cases of the sweep for output folders, sequence paths and bag folders.

Every command that writes follows one rule: an existing output is replaced only with
``--overwrite`` and only when it is what that command writes; a folder of other files, a
file, the working folder, the home folder, a parent of the input and an empty name are
refused in one line naming the path, and nothing there is lost. Then ``frames.csv`` as a
spreadsheet saves it (byte-order mark), paths that leave the sequence, a camera that is not
the image's folder, and a bag folder without ``metadata.yaml``.

Fixtures as in :mod:`sweep_cli_cases`.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from sweep_cli_cases import EVAL, IMPORT, SMOKE, WRITE, copy_bag, copy_sequence, existing_out
from sweep_run import CliCase

ABLATE = ("ablate", "--quiet", "--limit", "1")
# HOME inside the case's folder; caches that libraries keep under it go outside that folder.
HOME = (
    ("HOME", "{ws}/home"),
    ("XDG_CACHE_HOME", "{ws}/../xdg-cache"),
    ("XDG_CONFIG_HOME", "{ws}/../xdg-config"),
    ("MPLCONFIGDIR", "{ws}/../mpl-config"),
)


# --- preparations -------------------------------------------------------------------------


def a_file_out(ws: Path, fx: dict) -> None:
    (ws / "out").write_text("mine\n")


def a_report(ws: Path, fx: dict) -> None:
    (ws / "out").mkdir()
    (ws / "out" / "metrics.json").write_text("{}\n")
    (ws / "out" / "metrics.md").write_text("# old\n")


def allo_imported_in_place(ws: Path, fx: dict) -> None:
    """An ALLO download (test and train splits) with its test split imported in place."""
    from allo_mrad_ros.allo_import import import_allo

    shutil.copytree(fx["allo"], ws / "ALLO" / "test")
    shutil.copytree(fx["allo"], ws / "ALLO" / "train")
    import_allo(ws / "ALLO" / "test", ws / "ALLO")


def allo_test_split_imported_in_place(ws: Path, fx: dict) -> None:
    """The same with the test split alone: every file is the sequence's, none its own."""
    from allo_mrad_ros.allo_import import import_allo

    shutil.copytree(fx["allo"], ws / "ALLO" / "test")
    import_allo(ws / "ALLO" / "test", ws / "ALLO")


def not_bag_metadata(ws: Path, fx: dict) -> None:
    (ws / "out").mkdir()
    (ws / "out" / "metadata.yaml").write_text("hello: 1\n")


def a_home(ws: Path, fx: dict) -> None:
    (ws / "home").mkdir()
    (ws / "home" / "keep.txt").write_text("mine")


def nested_bag(ws: Path, fx: dict) -> None:
    (ws / "d").mkdir()
    shutil.copytree(fx["bag"], ws / "d" / "bag")


def bag_without_metadata(ws: Path, fx: dict) -> None:
    (copy_bag(ws, fx) / "metadata.yaml").unlink()


def _edit_first_row(seq: Path, column: str, value: str) -> None:
    lines = (seq / "frames.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[1].split(",")
    row[header.index(column)] = value
    lines[1] = ",".join(row)
    (seq / "frames.csv").write_text("\n".join(lines) + "\n")


def frames_with_bom(ws: Path, fx: dict) -> None:
    seq = copy_sequence(ws, fx)
    text = (seq / "frames.csv").read_text()
    (seq / "frames.csv").write_text(text, encoding="utf-8-sig")


def image_path_leaving(ws: Path, fx: dict) -> None:
    _edit_first_row(copy_sequence(ws, fx), "image", "../../x.png")


def camera_not_its_folder(ws: Path, fx: dict) -> None:
    _edit_first_row(copy_sequence(ws, fx), "camera", "7")


# --- checks ------------------------------------------------------------------------------


def allo_kept(*splits: str):
    """Exit 0 over an ALLO download: every PNG of ``splits`` must still be there, unchanged."""

    def check(ws: Path, fx: dict) -> str | None:
        for image in sorted(Path(fx["allo"]).rglob("*.png")):
            relative = image.relative_to(fx["allo"])
            for split in splits:
                kept = ws / "ALLO" / split / relative
                if not kept.is_file() or kept.read_bytes() != image.read_bytes():
                    return f"data loss: ALLO/{split}/{relative} deleted or changed"
        return None

    return check


def others_kept(ws: Path, fx: dict) -> str | None:
    """Exit 0 on a refused output: what the user had there must still be there."""
    for path in (ws / "out" / "keep.txt", ws / "home" / "keep.txt"):
        if path.parent.is_dir() and not path.is_file():
            return f"data loss: {path.relative_to(ws)} deleted"
    return None


# --- the cases ---------------------------------------------------------------------------


def _refusals(group: str, head: tuple[str, ...], out_option: tuple[str, ...]) -> list[CliCase]:
    """The output cases every writing command shares; ``out_option`` precedes the path
    (``("--out",)``, or ``()`` for ``allo-bag write``'s positional output)."""

    def argv(path: str, *extra: str) -> tuple[str, ...]:
        return (*head, *out_option, path, *extra)

    return [
        CliCase(
            group,
            "output holds other files, --overwrite",
            argv("{ws}/out", "--overwrite"),
            "not a (report|bag|sequence)",
            prepare=existing_out,
            check=others_kept,
        ),
        CliCase(
            group,
            "output is a file, --overwrite",
            argv("{ws}/out", "--overwrite"),
            "not a folder",
            prepare=a_file_out,
        ),
        CliCase(
            group,
            "empty output name",
            argv("", "--overwrite"),
            "empty name",
            one_line=True,  # no usage block before the error
        ),
        CliCase(group, "output is the working folder", argv(".", "--overwrite"), "working folder"),
        CliCase(
            group,
            "output is the home folder",
            argv("{ws}/home", "--overwrite"),
            "home folder",
            prepare=a_home,
            check=others_kept,
            env=HOME,
        ),
    ]


def output_cases() -> list[CliCase]:
    """The output-folder, sequence-path and bag-folder cases."""
    e, a, w = "allo-bag evaluate", "allo-bag ablate", "allo-bag write"
    cases = _refusals(e, (*EVAL, "{bag}"), ("--out",))
    cases += _refusals(a, (*ABLATE, "{bag}"), ("--out",))
    cases += _refusals(w, WRITE, ())
    cases += _refusals("allo-synth generate", SMOKE, ("--out",))
    cases += _refusals("allo-synth import-allo", IMPORT, ("--out",))
    cases += [
        CliCase(
            e,
            "output holds other files",
            (*EVAL, "{bag}", "--out", "{ws}/out"),
            "not a report",
            prepare=existing_out,
            check=others_kept,
            quick=True,
        ),
        CliCase(
            e,
            "output holds a report",
            (*EVAL, "{bag}", "--out", "{ws}/out"),
            "--overwrite",
            prepare=a_report,
        ),
        CliCase(
            e,
            "output is a parent of the input",
            (*EVAL, "{ws}/d/bag", "--out", "{ws}/d", "--overwrite"),
            "input",
            prepare=nested_bag,
        ),
        CliCase(
            a,
            "output holds an evaluation report",
            (*ABLATE, "{bag}", "--out", "{ws}/out", "--overwrite"),
            "not a report",
            prepare=a_report,
        ),
        CliCase(
            w,
            "frames.csv with a byte-order mark",
            ("write", "{ws}/seq", "{ws}/out"),
            expect_error=False,
            prepare=frames_with_bom,
            outputs=("out", "seq"),
        ),
        CliCase(
            w,
            "image path leaving the sequence",
            ("write", "{ws}/seq", "{ws}/out"),
            r"leaves the sequence.*\.\./\.\./x\.png",
            prepare=image_path_leaving,
        ),
        CliCase(
            w,
            "camera not the image's folder",
            ("write", "{ws}/seq", "{ws}/out"),
            "camera 7",
            prepare=camera_not_its_folder,
        ),
        CliCase(
            w,
            "output holds a metadata.yaml that is not a bag's, --overwrite",
            (*WRITE, "{ws}/out", "--overwrite"),
            r"not a bag \(metadata\.yaml",
            prepare=not_bag_metadata,
            quick=True,
        ),
        CliCase(
            "allo-synth generate",
            "output is an ALLO download with a split imported in place, --overwrite",
            (*SMOKE, "--out", "{ws}/ALLO", "--overwrite"),
            r"not a sequence \(train/\)",
            prepare=allo_imported_in_place,
            check=allo_kept("test", "train"),
            quick=True,
        ),
        CliCase(
            "allo-synth generate",
            "output is an ALLO split imported in place, --overwrite",
            (*SMOKE, "--out", "{ws}/ALLO", "--overwrite"),
            "imported in place",
            prepare=allo_test_split_imported_in_place,
            check=allo_kept("test"),
        ),
        CliCase(
            "allo-synth import-allo",
            "output is an ALLO download imported in place, another split, --overwrite",
            (*IMPORT, "--out", "{ws}/ALLO", "--overwrite"),
            r"not a sequence \(train/\)",
            prepare=allo_imported_in_place,
            check=allo_kept("test", "train"),
        ),
        CliCase(
            "allo-bag info",
            "bag folder without metadata.yaml",
            ("info", "{ws}/bag"),
            r"metadata\.yaml: not found",
            prepare=bag_without_metadata,
        ),
        CliCase(
            e,
            "bag folder without metadata.yaml",
            (*EVAL, "{ws}/bag", "--out", "{ws}/report"),
            r"metadata\.yaml: not found",
            prepare=bag_without_metadata,
        ),
    ]
    return cases
