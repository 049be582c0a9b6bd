"""Every model format the documents list loads, its readers' modules are declared, and an
unreadable file is refused on one line that names the file and the format."""

from __future__ import annotations

import importlib
import inspect
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh

from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.render.model import MESH_FORMATS, format_name, load_model

ROOT = Path(__file__).resolve().parents[2]
# What trimesh's reader of each listed format imports beyond NumPy. TEXT stands for the
# decoder of text that is not UTF-8, which depends on trimesh's major version.
TEXT = "text decoder"
READERS = {
    "glb": (TEXT, "PIL"),
    "gltf": (TEXT, "PIL"),
    "obj": (TEXT, "PIL"),
    "stl": (TEXT,),
    "ply": (),
    "off": (TEXT,),
    "3mf": ("lxml", "networkx"),
    "dae": ("collada", "lxml", "PIL"),
}
# The two install routes: their requirements file and the decoder of their trimesh
# (trimesh 5, pinned for pip, uses charset_normalizer; trimesh 4, the distro's, chardet).
ROUTES = {
    "pip": ("requirements.txt", "charset_normalizer"),
    "distro": ("requirements-distro.txt", "chardet"),
}
# A reader's module -> its pip distribution and its rosdep key (None: rosdep has none, so
# requirements-distro.txt installs it on a distribution).
PROVIDERS = {
    "charset_normalizer": ("charset-normalizer", None),
    "chardet": ("chardet", None),
    "lxml": ("lxml", "python3-lxml"),
    "networkx": ("networkx", "python3-networkx"),
    "collada": ("pycollada", "python3-collada"),
    "PIL": ("pillow", "python3-pil"),
}
# The OBJ of a user whose exporter wrote a Latin-1 comment.
LATIN1_OBJ = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n# caf\xe9\n"


def requirement_names(path: Path) -> dict[str, str]:
    """Requirement name -> the rest of its line (version pin or range)."""
    found = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            name = re.split(r"[<>=!~;\[ ]", line, maxsplit=1)[0]
            found[name.lower()] = line[len(name) :]
    return found


def exec_depends() -> set[str]:
    root = ET.parse(ROOT / "package.xml").getroot()
    return {e.text.strip() for e in root if e.tag in ("exec_depend", "depend")}


def reader_modules(route: str) -> set[str]:
    text = ROUTES[route][1]
    return {text if m == TEXT else m for modules in READERS.values() for m in modules}


def this_route() -> str:
    """The route this environment was installed by: pip where trimesh is requirements.txt's."""
    pinned = requirement_names(ROOT / "requirements.txt")["trimesh"]
    return "pip" if pinned == f"=={trimesh.__version__}" else "distro"


def test_the_formats_the_documents_list_are_the_ones_known():
    text = (ROOT / "meshes" / "README.md").read_text()
    pattern = r"\*\*Format\.\*\* Anything `trimesh.load` reads: (.*?), named by"
    listed = re.search(pattern, text, re.S)
    assert listed, "meshes/README.md no longer lists the formats where this test reads them"
    names = re.sub(r"\([^)]*\)", "", " ".join(listed.group(1).split()))
    tokens = {t.strip().lower() for t in re.split(r"[,/+]", names) if t.strip()}
    tokens.discard("mtl")  # an OBJ's material library, read with it
    assert tokens == set(MESH_FORMATS) == set(READERS)


def test_this_trimesh_decodes_text_with_its_routes_module_and_every_reader_is_installed():
    route = this_route()
    decoder = ROUTES[route][1]
    assert decoder in inspect.getsource(trimesh.util.decode_text), (
        f"trimesh {trimesh.__version__} decodes text otherwise: update ROUTES and the requirements"
    )
    for module in sorted(reader_modules(route)):
        importlib.import_module(module)


@pytest.mark.parametrize("route", sorted(ROUTES))
def test_every_reader_module_is_declared_on_each_route(route):
    requirements = requirement_names(ROOT / ROUTES[route][0])
    missing = []
    for module in sorted(reader_modules(route)):
        assert module in PROVIDERS, f"say where {module} comes from"
        distribution, key = PROVIDERS[module]
        if route == "pip":
            if not requirements.get(distribution, "").startswith("=="):
                missing.append(f"pin {distribution} in requirements.txt")
        elif key is None and distribution not in requirements:
            missing.append(f"add {distribution} to requirements-distro.txt")
        elif key is not None and key not in exec_depends():
            missing.append(f"add <exec_depend>{key}</exec_depend> to package.xml")
    assert missing == []


def test_a_latin1_obj_loads(tmp_path):
    path = tmp_path / "m.obj"
    path.write_bytes(LATIN1_OBJ)
    (group,) = load_model(path)
    assert len(group.faces) == 1
    np.testing.assert_array_equal(np.sort(group.positions[:, 0]), [0.0, 0.0, 1.0])


def box_file(folder: Path, suffix: str) -> Path:
    """A 1 m box written by trimesh's own exporter in the format of ``suffix``."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    path = folder / f"box.{suffix}"
    if suffix == "gltf":  # a JSON file and its buffers
        for name, data in trimesh.Scene(box).export(file_type="gltf").items():
            (folder / ("box.gltf" if name == "model.gltf" else name)).write_bytes(data)
        return path
    data = box.export(file_type=suffix)
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


@pytest.mark.parametrize("suffix", sorted(MESH_FORMATS))
def test_each_listed_format_loads(tmp_path, suffix):
    groups = load_model(box_file(tmp_path, suffix))
    assert sum(len(g.faces) for g in groups) == 12
    positions = np.vstack([g.positions for g in groups])
    np.testing.assert_allclose(np.ptp(positions, axis=0), 1.0, atol=1e-6)


GARBAGE = bytes(range(256)) * 8


@pytest.mark.parametrize("suffix", sorted(MESH_FORMATS))
def test_a_garbage_file_of_each_format_is_refused_naming_file_and_format(tmp_path, suffix):
    path = tmp_path / f"station.{suffix}"
    path.write_bytes(GARBAGE)
    with pytest.raises(InvalidInput) as raised:
        load_model(path)
    message = str(raised.value)
    assert "\n" not in message
    assert str(path) in message and format_name(path) in message
    assert "module" not in message.lower()


def test_an_empty_file_and_an_unknown_suffix_are_refused_by_name(tmp_path):
    empty = tmp_path / "station.obj"
    empty.write_bytes(b"")
    with pytest.raises(InvalidInput, match=r"station\.obj: the OBJ file is empty"):
        load_model(empty)
    unknown = tmp_path / "station.step"
    unknown.write_bytes(b"ISO-10303-21;")
    with pytest.raises(InvalidInput, match=r"station\.step: its suffix \(\.step\) names no"):
        load_model(unknown)


def test_a_missing_reader_is_the_installations_fault_not_the_files(tmp_path, monkeypatch):
    path = tmp_path / "station.3mf"
    path.write_bytes(GARBAGE)

    def no_lxml(*args, **kwargs):
        raise ModuleNotFoundError("No module named 'lxml'", name="lxml")

    monkeypatch.setattr(trimesh, "load", no_lxml)
    with pytest.raises(InvalidInput) as raised:
        load_model(path)
    message = str(raised.value)
    assert str(path) in message and "cannot read 3MF files" in message
    assert "install the package's requirements" in message
