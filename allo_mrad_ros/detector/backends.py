"""Array backends: where the detector's per-pixel work runs.

The per-pixel stages of the cross score -- the cell statistics, the cell quantiles of the
photometric fit and the evaluation of each cell's quadratic form -- run on a backend chosen
once, at start:

``numpy``
    NumPy and OpenCV on the CPU (the default; no extra dependency).
``torch``, ``torch:cuda``, ``torch:cpu``
    PyTorch (an optional dependency), on the first CUDA GPU for ``torch`` when one is
    visible (else the CPU), on the named device otherwise. The CPU device is there to test
    the backend against the float64 oracle where no GPU is.

Every backend takes and returns NumPy arrays, so the rest of the detector (the per-cell
algebra in float64, post-processing, region growing) is the same code for all of them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import cache
from typing import Protocol

import numpy as np

from allo_mrad_ros.detector.photometric import cell_quantiles
from allo_mrad_ros.detector.quadratic import PixelQuadratic, evaluate_quadratics
from allo_mrad_ros.detector.statistics import CellStatistics, cell_statistics
from allo_mrad_ros.errors import InvalidInput

ARRAY_BACKENDS = ("numpy", "torch", "torch:cuda", "torch:cpu")
DEFAULT_BACKEND = "numpy"


class ArrayBackendError(InvalidInput):
    """An array backend is unknown or cannot run here (library or device missing).

    Named apart from :class:`allo_mrad_ros.errors.BackendError` (a resource failing while it
    works): the choice of backend is an option the user can change, so it is invalid input.
    """


class PixelBackend(Protocol):
    """The per-pixel operations a backend provides, NumPy arrays in and out.

    Each operation takes the arguments of the NumPy function it names and means the same;
    the NumPy backend (:data:`NUMPY`) is those functions themselves.
    """

    name: str
    """The backend and its device, e.g. ``numpy`` or ``torch:cuda:0``."""
    cell_statistics: Callable[[np.ndarray, int], CellStatistics]
    """Per-cell colour mean and covariance: :func:`.statistics.cell_statistics`."""
    cell_quantiles: Callable[[np.ndarray, int], np.ndarray]
    """Per-cell quantiles: :func:`.photometric.cell_quantiles`."""
    evaluate: Callable[[np.ndarray, int, Sequence[PixelQuadratic], bool], list[np.ndarray]]
    """Score maps of quadratic forms: :func:`.quadratic.evaluate_quadratics`."""


class NumpyBackend:
    """NumPy and OpenCV on the CPU: the reference every other backend is tested against."""

    name = "numpy"
    cell_statistics = staticmethod(cell_statistics)
    cell_quantiles = staticmethod(cell_quantiles)
    evaluate = staticmethod(evaluate_quadratics)


NUMPY = NumpyBackend()


@cache
def select_backend(spec: str = DEFAULT_BACKEND) -> PixelBackend:
    """Return the backend named ``spec`` (one of :data:`ARRAY_BACKENDS`), built once.

    Raises
    ------
    ArrayBackendError
        For an unknown name, PyTorch not installed, or ``torch:cuda`` with no CUDA device.
    """
    if spec not in ARRAY_BACKENDS:
        raise ArrayBackendError(
            f"array_backend must be one of {list(ARRAY_BACKENDS)}, got {spec!r}"
        )
    if spec == "numpy":
        return NUMPY
    try:
        import torch
    except ImportError as error:
        raise ArrayBackendError(
            f"array_backend {spec!r} needs PyTorch, which is not importable here ({error}); "
            "install the build for this machine's GPU (https://pytorch.org) or use 'numpy'"
        ) from error
    from allo_mrad_ros.detector.torch_backend import TorchBackend

    device = spec.partition(":")[2] or None
    if device == "cuda" and not torch.cuda.is_available():
        raise ArrayBackendError(
            f"array_backend {spec!r} needs a CUDA GPU, and PyTorch {torch.__version__} sees "
            "none here; use 'torch:cpu' or 'numpy'"
        )
    return TorchBackend(device)


def resolve_backend(backend: PixelBackend | str | None) -> PixelBackend:
    """A backend object from an object, a name, or None (the default)."""
    if backend is None:
        return NUMPY
    if isinstance(backend, str):
        return select_backend(backend)
    return backend
