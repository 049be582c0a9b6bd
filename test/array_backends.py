"""The detector's array backends as pytest parameters: PyTorch's are marked skipped where
it is not installed, and :func:`skip_unless_runnable` skips a CUDA one without a GPU."""

from __future__ import annotations

import importlib.util

import pytest

_no_torch = pytest.mark.skipif(
    importlib.util.find_spec("torch") is None, reason="PyTorch is not installed"
)
ARRAY_BACKENDS = [
    pytest.param("numpy", id="numpy"),
    pytest.param("torch:cpu", id="torch-cpu", marks=_no_torch),
    pytest.param("torch:cuda", id="torch-cuda", marks=_no_torch),
]


def skip_unless_runnable(spec: str) -> None:
    """Skip the calling test when ``spec`` needs a CUDA GPU that PyTorch does not see."""
    if spec.startswith("torch:cuda"):
        torch = pytest.importorskip("torch", reason="PyTorch is not installed")
        if not torch.cuda.is_available():
            pytest.skip("no CUDA GPU visible to PyTorch")
