"""`allo-bag --version`, `allo-synth --version` and ``allo_mrad_ros.__version__`` give the
version package.xml declares, and setup.py declares the same one (the two are bumped together;
CHANGELOG.md names it)."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

import allo_mrad_ros
from allo_mrad_ros import resources
from allo_mrad_ros.resources import package_version

ROOT = Path(__file__).resolve().parent.parent


def _manifest_version() -> str:
    text = (ROOT / "package.xml").read_text(encoding="utf-8")
    return re.search(r"<version>\s*([^<\s]+)\s*</version>", text).group(1)


def test_setup_py_and_package_xml_declare_the_same_version():
    found = re.search(r'version="([^"]+)"', (ROOT / "setup.py").read_text(encoding="utf-8"))
    assert found is not None and found.group(1) == _manifest_version()


def test_the_package_metadata_has_the_manifest_version():
    assert package_version() == _manifest_version()


def test_the_version_attribute_is_the_manifest_version():
    assert allo_mrad_ros.__version__ == _manifest_version()


def test_without_installed_metadata_the_version_attribute_is_package_xmls(monkeypatch):
    def not_installed(name):
        raise resources.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(resources.metadata, "version", not_installed)
    assert allo_mrad_ros.__version__ == _manifest_version()  # the source tree's package.xml


def test_setup_py_declares_no_tests_require():
    # setuptools dropped it and colcon ignores it: test dependencies are package.xml's
    # test_depend keys (and requirements-dev.txt).
    call = next(
        node
        for node in ast.walk(ast.parse((ROOT / "setup.py").read_text(encoding="utf-8")))
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "setup"
    )
    assert "tests_require" not in {keyword.arg for keyword in call.keywords}


def test_the_changelog_has_a_section_for_the_manifest_version():
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert "## [Unreleased]" in changelog
    heading = rf"^## \[{re.escape(_manifest_version())}\] - \d{{4}}-\d\d-\d\d$"
    assert re.search(heading, changelog, re.M)


@pytest.mark.parametrize(
    ("module", "prog"),
    [("rosbag_tools.cli", "allo-bag"), ("allo_mrad_ros.synth.cli", "allo-synth")],
)
def test_command_line_prints_the_manifest_version(module, prog, capsys):
    main = __import__(module, fromlist=["main"]).main
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"{prog} {_manifest_version()}"


@pytest.mark.parametrize(
    ("entry", "prog"),
    [("rosbag_tools.entry", "allo-bag"), ("allo_mrad_ros.synth.entry", "allo-synth")],
)
def test_entry_point_prints_the_manifest_version(entry, prog):
    code = f"import sys; from {entry} import main; sys.exit(main(['--version']))"
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"{prog} {_manifest_version()}"
