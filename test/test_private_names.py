"""No module imports another module's private (``_``) name: a helper two modules share is
public where its concept lives."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# The benchmarks are leaving the package for a top-level folder, their own private imports
# with them; they are checked once they have moved.
NOT_YET = REPO / "allo_mrad_ros" / "benchmarks"


def private_imports(text: str) -> list[str]:
    """``module:name`` for every ``from module import _name`` in ``text``."""
    return [
        f"{node.module or '.'}:{alias.name}"
        for node in ast.walk(ast.parse(text))
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
        if alias.name.startswith("_") and not alias.name.startswith("__")
    ]


def _sources() -> list[Path]:
    paths = [*REPO.glob("allo_mrad_ros/**/*.py"), *REPO.glob("rosbag_tools/**/*.py")]
    return sorted(p for p in paths if NOT_YET not in p.parents)


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(REPO)))
def test_no_module_imports_a_private_name(path):
    assert private_imports(path.read_text(encoding="utf-8")) == []


def test_the_check_sees_private_names_and_leaves_dunders():
    text = "from .checks import _body, frame_label\nfrom __future__ import annotations\n"
    assert private_imports(text) == ["checks:_body"]
    assert private_imports("from a import __version__\n") == []
