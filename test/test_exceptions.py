"""One exception hierarchy: every exception class of both packages derives from AlloError.

Every module of ``allo_mrad_ros`` and ``rosbag_tools`` is imported (a module whose external
dependency, such as a ROS package, is missing here is skipped and named); every Exception
subclass they define must derive from :class:`~allo_mrad_ros.errors.AlloError` and from one
of its two kinds, and no two may share a name. Signals that must not be caught as errors
(``staging.Interrupted``, a KeyboardInterrupt) are not Exception subclasses and stay apart.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

import pytest

from allo_mrad_ros.errors import AlloError, BackendError, InvalidInput, lookup

PACKAGES = ("allo_mrad_ros", "rosbag_tools")
ROOTS = {AlloError, InvalidInput, BackendError}


def module_names() -> list[str]:
    names = []
    for package in PACKAGES:
        root = importlib.import_module(package)
        names.append(package)
        for info in pkgutil.walk_packages(root.__path__, f"{package}."):
            if not info.name.endswith(".__main__"):  # runs the command line when imported
                names.append(info.name)
    return names


MODULES = module_names()


def import_or_skip(name: str) -> ModuleType | None:
    """The module, or None when an external dependency (not one of ours) is missing."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as error:
        missing = (error.name or "").split(".")[0]
        if missing in PACKAGES or not missing:
            raise
        return None


def defined_exceptions() -> tuple[list[type], list[str]]:
    """Every Exception subclass the importable modules define, and the modules skipped."""
    skipped = [name for name in MODULES if import_or_skip(name) is None]
    found, pending = [], [Exception]
    seen: set[type] = set()
    while pending:
        for subclass in pending.pop().__subclasses__():
            if subclass in seen:
                continue
            seen.add(subclass)
            pending.append(subclass)
            if subclass.__module__.split(".")[0] in PACKAGES:
                found.append(subclass)
    return found, skipped


def test_there_are_modules_and_exceptions_to_check():
    exceptions, skipped = defined_exceptions()
    assert len(MODULES) > 100
    assert len(skipped) < len(MODULES) // 2, f"most modules could not be imported: {skipped}"
    # Those the hierarchy was broken by, and a few of every part, are found.
    names = {cls.__name__ for cls in exceptions}
    assert {"AlloError", "ColourTransferError", "PhotometricError", "SequenceError"} <= names
    assert {"ArrayBackendError", "BagReadError", "IntegrityError"} <= names


def test_every_exception_class_derives_from_allo_error_through_one_kind():
    exceptions, _ = defined_exceptions()
    outside = [
        f"{cls.__module__}.{cls.__qualname__}"
        for cls in exceptions
        if not issubclass(cls, AlloError)
        or (cls not in ROOTS and not issubclass(cls, InvalidInput | BackendError))
    ]
    assert outside == [], f"derive these from errors.InvalidInput or errors.BackendError: {outside}"


def test_no_two_exception_classes_share_a_name():
    exceptions, _ = defined_exceptions()
    by_name: dict[str, list[str]] = {}
    for cls in exceptions:
        by_name.setdefault(cls.__name__, []).append(f"{cls.__module__}.{cls.__qualname__}")
    shared = {name: where for name, where in by_name.items() if len(where) > 1}
    assert shared == {}


@pytest.mark.parametrize(
    ("module", "name"),
    [
        ("allo_mrad_ros.detector.backends", "ArrayBackendError"),
        ("allo_mrad_ros.detector.colour_transfer", "ColourTransferError"),
        ("allo_mrad_ros.detector.photometric", "PhotometricError"),
        ("allo_mrad_ros.ros.recorder", "RecorderError"),
        ("benchmarks.stations", "StationError"),
        ("rosbag_tools.integrity", "IntegrityError"),
    ],
)
def test_the_rebased_errors_are_still_value_errors(module, name):
    # Callers that catch ValueError keep catching them.
    loaded = import_or_skip(module)
    if loaded is None:
        pytest.skip(f"{module} needs a dependency missing here")
    cls = getattr(loaded, name)
    assert issubclass(cls, InvalidInput) and issubclass(cls, ValueError)


@pytest.mark.parametrize("name", MODULES)
def test_every_module_imports_or_lacks_only_an_external_dependency(name):
    if import_or_skip(name) is None:
        pytest.skip(f"{name}: an external dependency is missing here")


def test_lookup_returns_the_entry_or_raises_the_given_error_listing_the_choices():
    table = {"hub": 1, "spine": 2}
    assert lookup(table, "spine", what="layout", error=InvalidInput) == 2
    with pytest.raises(BackendError) as raised:
        lookup(table, "ring", what="outpost layout", error=BackendError)
    assert str(raised.value) == "unknown outpost layout 'ring'; choose from hub, spine"


def test_an_unknown_outpost_layout_and_preset_name_their_choices():
    from allo_mrad_ros.render.outpost_model import LAYOUTS, OutpostError, build_outpost
    from allo_mrad_ros.synth.config import PRESETS, SynthError, preset

    with pytest.raises(
        OutpostError, match=f"^unknown outpost layout 'x'; choose from {', '.join(LAYOUTS)}$"
    ):
        build_outpost("x")
    with pytest.raises(SynthError, match=f"^unknown preset 'x'; choose from {', '.join(PRESETS)}$"):
        preset("x")
