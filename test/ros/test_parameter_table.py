"""One table per parameter set: the docs' tables, config/mrad.yaml and NodeConfig agree with it.

Needs no rclpy, so the distro route (no ROS install) runs it too. The documents are checked
twice: against what the generator writes, and by reading them back independently (Markdown
cells and YAML values parsed here, compared with the tables' values).
"""

from __future__ import annotations

import re
import shutil
from dataclasses import fields
from pathlib import Path
from typing import Any, get_type_hints

import pytest
import yaml

from allo_mrad_ros.detector.colour_transfer import DIRECTIONS
from allo_mrad_ros.detector.params import PARAMETER_SPECS, MradParams, ParameterSpec
from allo_mrad_ros.ros import parameter_table
from allo_mrad_ros.ros.parameters import (
    NODE_TABLE,
    NodeConfig,
    NodeParameter,
    declared_parameters,
    default_config,
    default_values,
    node_parameters,
    object_parameters,
    pipeline_config_from,
)

REPO = Path(__file__).resolve().parents[2]


def table_rows(document: Path, table: str) -> list[dict[str, str]]:
    """The rows of ``table`` in ``document``, each a mapping of column name to cell text."""
    text = document.read_text(encoding="utf-8")
    block = text.split(parameter_table.begin_marker(table) + "\n", 1)[1]
    block = block.split(parameter_table.END_MARKER, 1)[0]
    lines = block.strip().splitlines()
    split = lambda line: [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]  # noqa: E731
    header = split(lines[0])
    return [dict(zip(header, split(line), strict=True)) for line in lines[2:]]


def read_cell(text: str) -> Any:
    """A default cell as a value: ``empty`` is "", backticks quote text, else YAML."""
    if text == "empty":
        return ""
    if text.startswith("`"):
        return text.strip("`")
    return yaml.safe_load(text)


def read_range(text: str) -> tuple[float, float, bool, bool] | tuple[Any, ...] | None:
    """``low..high`` or an interval as (low, high, low_open, high_open); choices as a tuple."""
    if not text:
        return None
    closed = re.fullmatch(r"(\S+)\.\.(\S+)", text)
    if closed:
        return float(closed[1]), float(closed[2]), False, False
    interval = re.fullmatch(r"([\[(])(\S+), (\S+)([\])])", text)
    if interval:
        low, high = float(interval[2]), float(interval[3])
        return low, high, interval[1] == "(", interval[4] == ")"
    return tuple("" if c == "empty" else c.strip("`") for c in text.split(", "))


def expected_range(spec: ParameterSpec) -> tuple[float, float, bool, bool] | tuple[Any, ...] | None:
    if spec.kind is bool or (not spec.choices and spec.low is None):
        return None
    if spec.choices:
        return tuple(str(c) for c in spec.choices)
    return float(spec.low), float(spec.high), spec.low_open, spec.high_open


def check_rows(rows: list[dict[str, str]], parameters: dict[str, NodeParameter]) -> None:
    assert [row["parameter"].strip("`") for row in rows] == list(parameters)
    for row in rows:
        name = row["parameter"].strip("`")
        parameter = parameters[name]
        default = read_cell(row["default"])
        assert default == parameter.default and type(default) is type(parameter.default), name
        assert read_range(row["range"]) == expected_range(parameter.spec), name
        meaning = row["meaning"].replace("\\|", "|").replace("&lt;", "<")
        assert meaning.startswith(parameter.spec.description), name
        assert meaning.endswith("; read-only") == parameter.read_only, name


def test_the_docs_and_the_config_file_are_what_the_tables_write():
    assert parameter_table.stale_files(REPO) == []


def test_node_md_lists_every_node_parameter_with_its_default_range_and_description():
    check_rows(table_rows(REPO / "docs" / "node.md", "node"), node_parameters(True))


def test_node_md_lists_every_objects_parameter_with_its_default_range_and_description():
    parameters = object_parameters()
    assert "objects.enabled" in parameters and "objects.confirm_hits" in parameters
    check_rows(table_rows(REPO / "docs" / "node.md", "objects"), parameters)


def test_detector_md_lists_every_mrad_field_with_its_default_range_and_description():
    defaults = MradParams()
    parameters = {n: NodeParameter(getattr(defaults, n), s) for n, s in PARAMETER_SPECS.items()}
    check_rows(table_rows(REPO / "docs" / "detector.md", "detector"), parameters)


def flatten(mapping: dict, prefix: str = "") -> dict[str, Any]:
    flat = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def test_the_config_file_sets_every_parameter_to_its_default_in_the_declared_type():
    document = yaml.safe_load((REPO / "config" / "mrad.yaml").read_text(encoding="utf-8"))
    values = flatten(document["/**"]["ros__parameters"])
    declared = declared_parameters(tf_available=True)
    assert list(values) == list(declared)
    for name, parameter in declared.items():
        # rcl takes a YAML value's type as the parameter's: 50 for a double would be refused.
        assert values[name] == parameter.default, name
        assert type(values[name]) is type(parameter.default), name


def test_the_check_finds_a_changed_default_and_write_puts_the_table_back(tmp_path, capsys):
    for relative in (*parameter_table.DOCUMENTS.values(), parameter_table.CONFIG):
        (tmp_path / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / relative, tmp_path / relative)
    node_md = tmp_path / "docs" / "node.md"
    text = node_md.read_text(encoding="utf-8")
    node_md.write_text(
        text.replace("| `tf_timeout_s` | double | 0.5 |", "| `tf_timeout_s` | double | 0.7 |")
    )
    config = tmp_path / "config" / "mrad.yaml"
    config.write_text(config.read_text().replace("mrad:\n", "mrad:\n      grid: 6\n", 1))
    assert parameter_table.main(["--check", "--root", str(tmp_path)]) == 1
    stale = capsys.readouterr().err.splitlines()
    assert len(stale) == 2 and "node.md" in stale[0] and "mrad.yaml" in stale[1]
    assert parameter_table.main(["--write", "--root", str(tmp_path)]) == 0
    assert node_md.read_text(encoding="utf-8") == text
    assert parameter_table.main(["--check", "--root", str(tmp_path)]) == 0


def test_a_document_without_its_table_lines_is_refused_in_one_line(tmp_path, capsys):
    for relative in (*parameter_table.DOCUMENTS.values(), parameter_table.CONFIG):
        (tmp_path / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / relative, tmp_path / relative)
    detector_md = tmp_path / "docs" / "detector.md"
    detector_md.write_text(detector_md.read_text().replace(parameter_table.END_MARKER, ""))
    before = detector_md.read_text()
    assert parameter_table.main(["--write", "--root", str(tmp_path)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "detector.md" in line and "detector parameter table" in line
    assert detector_md.read_text() == before  # nothing written


def test_the_printed_yaml_is_the_config_file():
    assert parameter_table.yaml_document() == (REPO / "config" / "mrad.yaml").read_text()


@pytest.mark.parametrize(
    ("spec", "text"),
    [
        (ParameterSpec(float, "", 0, 255), "0..255"),
        (ParameterSpec(float, "", 0, 1e12, low_open=True), "(0, 1e12]"),
        (ParameterSpec(float, "", 0, 1, high_open=True), "[0, 1)"),
        (ParameterSpec(int, "", 1, 1_000_000), "1..1e6"),
        (ParameterSpec(str, "", choices=("", "egl")), "empty, `egl`"),
        (ParameterSpec(bool, "", choices=(True, False)), ""),
    ],
)
def test_ranges_are_written_as_people_read_them(spec, text):
    assert parameter_table.range_text(spec) == text


# --- the tables themselves ---------------------------------------------------------------


class Reads(dict):
    """Parameter values that remember which names were read one by one."""

    def __init__(self, values: dict[str, Any]) -> None:
        super().__init__(values)
        self.read: set[str] = set()

    def __getitem__(self, name: str) -> Any:
        self.read.add(name)
        return super().__getitem__(name)


def test_node_config_has_a_field_of_its_type_for_each_parameter_the_pipeline_does_not_take():
    values = Reads(default_values(tf_available=True))
    pipeline_config_from(values)
    for_pipeline = values.read
    own = {item.name for item in fields(NodeConfig)} - {"pipeline", "objects"}
    assert own.isdisjoint(for_pipeline)
    assert own | for_pipeline == set(node_parameters(True))
    hints = get_type_hints(NodeConfig)
    parameters = node_parameters(True)
    for name in own:
        kind = parameters[name].spec.kind
        assert hints[name] == (tuple[float, float, float] if kind is list else kind), name


def test_the_default_config_holds_every_default():
    config = default_config(tf_available=True)
    for name, parameter in node_parameters(True).items():
        if hasattr(config, name):
            expected = parameter.default
            assert getattr(config, name) == (
                tuple(expected) if isinstance(expected, list) else expected
            )
    assert config.pipeline.params == MradParams()
    assert (
        config.pipeline.render.reference_scale == node_parameters(True)["reference_scale"].default
    )


def test_sections_hold_each_node_parameter_once():
    names = [name for section in NODE_TABLE for name in section.parameters]
    assert len(names) == len(set(names)) == len(node_parameters(True))
    assert all(section.parameters for section in NODE_TABLE)


def test_mrad_params_fields_are_the_detector_table_in_order_with_valid_defaults():
    assert list(PARAMETER_SPECS) == [item.name for item in fields(MradParams)]
    for item in fields(MradParams):
        spec = PARAMETER_SPECS[item.name]
        assert spec.description and item.name in (MradParams.__doc__ or ""), item.name
        assert spec.validated(item.name, item.default) == item.default, item.name
        assert (spec.low is None) == (spec.kind not in (int, float) or bool(spec.choices))
    assert PARAMETER_SPECS["colour_transfer"].choices == ("none", *DIRECTIONS)
    assert PARAMETER_SPECS["connectivity"].choices == (4, 8)
    assert PARAMETER_SPECS["transfer_gain"].choices == (True, False)


def test_launch_arguments_offer_exactly_the_choices_of_the_parameter_they_set():
    from allo_mrad_ros.ros.launch_arguments import ARGUMENTS

    parameters = node_parameters(True)
    forwarded = [a for a in ARGUMENTS if a.parameter in parameters]
    assert {a.parameter for a in forwarded} >= {"mesh", "pose_source", "image_transport"}
    for argument in forwarded:
        spec = parameters[argument.parameter].spec
        if spec.choices and spec.kind is str:
            assert argument.choices == spec.choices, argument.name
