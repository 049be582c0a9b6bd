"""Every benchmark command imports and answers --help (they run outside the test suite)."""

import importlib
import importlib.util
import pkgutil

import pytest

import allo_mrad_ros.benchmarks as benchmarks

MODULES = sorted(m.name for m in pkgutil.iter_modules(benchmarks.__path__))


@pytest.mark.parametrize("name", MODULES)
def test_benchmark_module_imports_and_prints_help(name, capsys):
    needs_rclpy = ("node", "node_outputs", "node_profile", "flood")
    if name in needs_rclpy and importlib.util.find_spec("rclpy") is None:
        pytest.skip("the node benchmarks need rclpy")
    module = importlib.import_module(f"allo_mrad_ros.benchmarks.{name}")
    if not hasattr(module, "main"):
        return  # a helper module of the benchmarks, imported above
    with pytest.raises(SystemExit) as stop:
        module.main(["--help"])
    assert stop.value.code == 0
    assert "usage" in capsys.readouterr().out
