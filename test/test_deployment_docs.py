"""The user documentation of deployment: the robot recipe uses the middleware's defaults."""

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent / "docs"


def _section(text: str, title: str) -> str:
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert match, f"no section {title!r}"
    return match.group(1)


def test_the_robot_recipe_exports_no_loopback_profile():
    distro = (DOCS / "distro.md").read_text()
    deploy = _section(distro, "Deploying on a robot")
    commands = "\n".join(re.findall(r"```bash\n(.*?)```", deploy, re.DOTALL))
    assert "ros2 launch" in commands
    assert "FASTDDS_DEFAULT_PROFILES_FILE" not in commands and "fastdds_loopback" not in commands
    # The install commands neither.
    install = "\n".join(re.findall(r"```bash\n(.*?)```", _section(distro, "Install"), re.DOTALL))
    assert "fastdds_loopback" not in install


def test_the_docs_say_what_is_tested_with_stand_ins():
    distro = (DOCS / "distro.md").read_text()
    tested = _section(distro, "What is tested here, and with what")
    for name in ("vision_msgs", "tf2_ros", "launch_ros"):
        assert name in tested and "stand-in" in tested


def test_the_node_doc_names_the_optical_frame_convention():
    node = (DOCS / "node.md").read_text()
    assert "<camera>_optical_frame" in node and "REP-103/105" in node


FAST_DDS_SETTING = re.compile(r"FAST(?:DDS|RTPS)_[A-Z_]+(?:=[A-Z_]+\b)?|config/fastdds_\w+\.xml")


def test_node_md_defers_to_distro_md_on_dds_settings():
    # One place says how to set DDS up for a robot (distro.md): node.md names only the tests'
    # and the pip route's loopback profile, no transport or segment setting of its own, and
    # its DDS section points to distro.md, which names everything node.md names.
    node = (DOCS / "node.md").read_text()
    distro = (DOCS / "distro.md").read_text()
    named = set(FAST_DDS_SETTING.findall(node))
    assert named == {"FASTDDS_DEFAULT_PROFILES_FILE", "config/fastdds_loopback.xml"}, named
    assert "segment_size" not in node
    assert named <= set(FAST_DDS_SETTING.findall(distro))
    assert "distro.md#deploying-on-a-robot" in _section(node, "Large images and DDS")
