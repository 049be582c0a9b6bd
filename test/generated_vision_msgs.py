"""vision_msgs' message types generated from its own ``.msg`` files, for rclpy and for rosbags.

vision_msgs has no pip wheel, so the node's ``~/detections`` and ``~/objects`` publishers
exist only on a ROS distro. The tests build the Python package a distro's
``ros-<distro>-vision-msgs`` holds from the same definitions
(``test/data/vision_msgs_4_1_1/msg``) with the ROS wheels' own rosidl generators
(``rosidl_generator_c``, ``rosidl_typesupport_c``, ``..._fastrtps_c``,
``..._introspection_c``, ``rosidl_generator_py``) and a C compiler, as colcon's
``rosidl_generate_interfaces`` would; and rosbags' typestore from the same files, as an
independent reader of the bytes on the wire.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import os
import shutil
import subprocess
import sys
import sysconfig
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

MSG_DIR = Path(__file__).resolve().parent / "data" / "vision_msgs_4_1_1" / "msg"
PACKAGE = "vision_msgs"
# Dependencies first: the generators resolve a field's type from the files already named.
MESSAGES = (
    "Point2D",
    "Pose2D",
    "BoundingBox2D",
    "ObjectHypothesis",
    "ObjectHypothesisWithPose",
    "Detection2D",
    "Detection2DArray",
    "BoundingBox3D",
    "Detection3D",
    "Detection3DArray",
)
# The message packages vision_msgs' fields name (Header, PoseWithCovariance, Time).
DEPENDENCIES = ("std_msgs", "geometry_msgs", "builtin_interfaces")
# The typesupport libraries rosidl_typesupport_c loads by name at the first (de)serialisation.
DISPATCHED = ("rosidl_typesupport_fastrtps_c", "rosidl_typesupport_introspection_c")


def rosbags_typestore() -> object:
    """A rosbags typestore of the installed ROS release's types plus vision_msgs' from
    :data:`MSG_DIR` (rosbags parses the ``.msg`` text itself: no ROS code involved)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for name in MESSAGES:
        text = (MSG_DIR / f"{name}.msg").read_text()
        types.update(get_types_from_msg(text, f"{PACKAGE}/msg/{name}"))
    store.register(types)
    return store


def _prefix() -> Path:
    """Where the ROS packages are installed (``include/``, ``lib/``, ``share/``): the
    virtual environment with the wheels, ``/opt/ros/<distro>`` on a distro."""
    # The wheels' ament index is under the environment's prefix; a distro's setup sets it.
    os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
    ament = pytest.importorskip("ament_index_python", reason="it locates the ROS packages")
    return Path(ament.get_package_prefix("rosidl_runtime_c"))


def _generate(out: Path, prefix: Path) -> dict[str, Path]:
    """Run the rosidl generators over :data:`MSG_DIR`; the folders they wrote, by kind."""
    why = "the rosidl generators (ROS wheels or a distro's packages) build vision_msgs' types"
    adapter = pytest.importorskip("rosidl_adapter.msg", reason=why)
    generators = {
        "c": pytest.importorskip("rosidl_generator_c.cli", reason=why).GenerateC,
        "typesupport_c": pytest.importorskip(
            "rosidl_typesupport_c.cli", reason=why
        ).GenerateCTypesupport,
        "fastrtps_c": pytest.importorskip(
            "rosidl_typesupport_fastrtps_c.cli", reason=why
        ).GenerateFastRTPSCTypesupport,
        "introspection_c": pytest.importorskip(
            "rosidl_typesupport_introspection_c.cli", reason=why
        ).GenerateIntrospectionCTypesupport,
        "py": pytest.importorskip("rosidl_generator_py.cli", reason=why).GeneratePython,
    }
    idl = out / "idl"
    for name in MESSAGES:
        adapter.convert_msg_to_idl(
            MSG_DIR.parent, PACKAGE, Path("msg") / f"{name}.msg", idl / "msg"
        )
    files = [f"{idl}:msg/{name}.idl" for name in MESSAGES]
    folders = {
        "c": out / "c" / PACKAGE,
        "typesupport_c": out / "typesupport_c",
        "fastrtps_c": out / "fastrtps_c" / PACKAGE,
        "introspection_c": out / "introspection_c" / PACKAGE,
        "py": out / "site" / PACKAGE,
    }
    # The classes directly, not `rosidl generate`: the wheels register some entry points
    # twice (an egg-info beside a dist-info), which the command refuses.
    for kind, generator in generators.items():
        generator(kind).generate(PACKAGE, files, [prefix / "share"], folders[kind])
    return folders


def _compile(folders: dict[str, Path], out: Path, prefix: Path) -> None:
    """Build the five libraries and the Python extension into the package's folder."""
    import numpy

    package = folders["py"]
    include = prefix / "include"
    roots = [
        out / "c",
        out / "fastrtps_c",
        out / "introspection_c",
        Path(sysconfig.get_paths()["include"]),
        Path(numpy.get_include()),
        include,
        *sorted(path for path in include.iterdir() if path.is_dir()),
    ]

    def library(name: str, sources: list[Path], libraries: list[str], cxx: bool = False) -> None:
        # The soname lets rosidl_typesupport_c's load by name find the one already loaded.
        command = [
            "g++" if cxx else "gcc",
            "-shared",
            "-fPIC",
            "-w",
            *(f"-I{root}" for root in roots),
            *map(str, sources),
            "-o",
            str(package / name),
            f"-Wl,-soname,{name}",
            "-Wl,-rpath,$ORIGIN",
            f"-Wl,-rpath,{prefix / 'lib'}",
            f"-L{package}",
            f"-L{prefix / 'lib'}",
            *(f"-l{lib}" for lib in libraries),
        ]
        subprocess.run(command, check=True, capture_output=True, text=True)

    own = f"{PACKAGE}__rosidl_generator_c"
    c_deps = [f"{dep}__rosidl_generator_c" for dep in DEPENDENCIES]
    library(f"lib{own}.so", sorted(folders["c"].rglob("*.c")), ["rosidl_runtime_c", *c_deps])
    library(
        f"lib{PACKAGE}__rosidl_typesupport_fastrtps_c.so",
        sorted(folders["fastrtps_c"].rglob("*.cpp")),
        [own, "rosidl_runtime_c", "rosidl_typesupport_fastrtps_c", "fastcdr", "rcutils"]
        + [f"{dep}__rosidl_typesupport_fastrtps_c" for dep in DEPENDENCIES]
        + c_deps,
        cxx=True,
    )
    library(
        f"lib{PACKAGE}__rosidl_typesupport_introspection_c.so",
        sorted(folders["introspection_c"].rglob("*.c")),
        [own, "rosidl_runtime_c"]
        + [f"{dep}__rosidl_typesupport_introspection_c" for dep in DEPENDENCIES],
    )
    library(
        f"lib{PACKAGE}__rosidl_typesupport_c.so",
        sorted(folders["typesupport_c"].rglob("*.cpp")),
        [own, "rosidl_runtime_c", "rosidl_typesupport_c", "rcpputils", "rcutils"],
        cxx=True,
    )
    library(
        f"lib{PACKAGE}__rosidl_generator_py.so",
        sorted((package / "msg").glob("*_s.c")),
        [own, "rosidl_runtime_c", "rcutils"]
        + [f"{dep}__rosidl_generator_py" for dep in DEPENDENCIES]
        + c_deps,
    )
    library(
        f"{PACKAGE}_s__rosidl_typesupport_c{sysconfig.get_config_var('EXT_SUFFIX')}",
        [package / f"_{PACKAGE}_s.ep.rosidl_typesupport_c.c"],
        [f"{PACKAGE}__rosidl_generator_py", f"{PACKAGE}__rosidl_typesupport_c", own],
    )
    (package / "__init__.py").write_text('"""vision_msgs generated for the tests."""\n')


def build(out: Path) -> Path:
    """Generate and compile vision_msgs under ``out``; the folder to put on ``sys.path``.
    Skips the calling test, naming what is missing, where the generators or a compiler are
    not installed."""
    for compiler in ("gcc", "g++"):
        if shutil.which(compiler) is None:
            pytest.skip(f"{compiler} compiles the generated vision_msgs")
    prefix = _prefix()
    folders = _generate(out, prefix)
    try:
        _compile(folders, out, prefix)
    except subprocess.CalledProcessError as error:
        raise AssertionError(f"compiling vision_msgs failed:\n{error.stderr}") from error
    return folders["py"].parent


@contextlib.contextmanager
def importable(site: Path) -> Iterator[ModuleType]:
    """``vision_msgs.msg`` from ``site`` importable while the block runs; afterwards the
    package is gone from ``sys.modules`` and ``sys.path``, so other tests see no vision_msgs."""
    for kind in DISPATCHED:
        # rosidl_typesupport_c opens these by name, through a search path read at start-up;
        # loaded here first with their soname, the dynamic loader hands back these copies.
        ctypes.CDLL(str(site / PACKAGE / f"lib{PACKAGE}__{kind}.so"), mode=ctypes.RTLD_GLOBAL)
    sys.path.insert(0, str(site))
    try:
        yield importlib.import_module(f"{PACKAGE}.msg")
    finally:
        sys.path.remove(str(site))
        for name in [name for name in sys.modules if name.split(".")[0] == PACKAGE]:
            del sys.modules[name]
