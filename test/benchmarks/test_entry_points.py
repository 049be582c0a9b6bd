"""Every benchmark command imports and answers --help (they run outside the test suite), and
the Makefile and the documents name only benchmarks that exist, the way they run them:
``python -m benchmarks.<name>`` from the repository root."""

import importlib
import importlib.util
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

import benchmarks

REPO = Path(__file__).resolve().parents[2]
MODULES = sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__))
NEEDS_RCLPY = ("node", "node_outputs", "node_profile", "node_session", "flood")
COMMAND = re.compile(r"-m ((?:allo_mrad_ros\.)?benchmarks)\.(\w+)")


def _commands(path: Path) -> list[tuple[str, str]]:
    return COMMAND.findall(path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", MODULES)
def test_benchmark_module_imports_and_prints_help(name, capsys):
    if name in NEEDS_RCLPY and importlib.util.find_spec("rclpy") is None:
        pytest.skip("the node benchmarks need rclpy")
    module = importlib.import_module(f"benchmarks.{name}")
    if not hasattr(module, "main"):
        return  # a helper module of the benchmarks, imported above
    with pytest.raises(SystemExit) as stop:
        module.main(["--help"])
    assert stop.value.code == 0
    assert "usage" in capsys.readouterr().out


@pytest.mark.parametrize(
    "document",
    ["Makefile", "README.md", *sorted(p.name for p in (REPO / "docs").glob("*.md"))],
)
def test_commands_name_benchmarks_that_exist_outside_the_package(document):
    path = REPO / document if (REPO / document).exists() else REPO / "docs" / document
    commands = _commands(path)
    assert all(package == "benchmarks" for package, _ in commands), (
        f"{document}: the benchmarks are not in the package: {commands}"
    )
    unknown = sorted({name for _, name in commands} - set(MODULES))
    assert not unknown, f"{document} runs benchmarks that do not exist: {unknown}"


def test_the_makefile_runs_the_benchmarks_as_modules_from_the_repository_root():
    names = {name for _, name in _commands(REPO / "Makefile")}
    assert {"detector", "render", "node", "flood", "tradeoff", "param_study"} <= names
    run = subprocess.run(
        [sys.executable, "-m", "benchmarks.detector", "--help"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0 and "usage" in run.stdout, run.stderr
