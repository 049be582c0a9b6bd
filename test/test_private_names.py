"""No module imports another module's private (``_``) name: a helper two modules share is
public where its concept lives."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# The installed packages and the trees beside them that tests and benchmarks share.
TREES = ("allo_mrad_ros", "rosbag_tools", "harness", "benchmarks")


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
    return sorted(path for tree in TREES for path in REPO.glob(f"{tree}/**/*.py"))


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(REPO)))
def test_no_module_imports_a_private_name(path):
    assert private_imports(path.read_text(encoding="utf-8")) == []


def test_the_check_sees_private_names_and_leaves_dunders():
    text = "from .checks import _body, frame_label\nfrom __future__ import annotations\n"
    assert private_imports(text) == ["checks:_body"]
    assert private_imports("from a import __version__\n") == []
