"""Selecting an array backend: names, missing libraries and devices, one object per name."""

import sys

import numpy as np
import pytest

from allo_mrad_ros.detector import detect
from allo_mrad_ros.detector.backends import (
    NUMPY,
    ArrayBackendError,
    resolve_backend,
    select_backend,
)


def test_numpy_is_the_default_and_one_object_serves_every_caller():
    assert resolve_backend(None) is NUMPY
    assert select_backend() is NUMPY and select_backend("numpy") is NUMPY
    assert resolve_backend("numpy") is NUMPY


def test_an_unknown_backend_is_named_with_the_choices():
    with pytest.raises(ArrayBackendError, match=r"array_backend must be one of .*'cupy'"):
        select_backend("cupy")


def test_pytorch_missing_is_the_reason_given(monkeypatch):
    # None in sys.modules makes `import torch` raise ImportError, as on a machine without it.
    monkeypatch.setitem(sys.modules, "torch", None)
    select_backend.cache_clear()
    try:
        with pytest.raises(ArrayBackendError, match=r"'torch:cpu' needs PyTorch"):
            select_backend("torch:cpu")
    finally:
        select_backend.cache_clear()


def test_a_cuda_backend_without_a_gpu_is_refused():
    torch = pytest.importorskip("torch", reason="PyTorch is not installed")
    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    with pytest.raises(ArrayBackendError, match="needs a CUDA GPU"):
        select_backend("torch:cuda")
    # Plain "torch" falls back to the CPU where no GPU is visible.
    assert select_backend("torch").name == "torch:cpu"


def test_every_backend_gives_numpys_detection_on_a_scene(backend):
    rng = np.random.default_rng(2)
    reference = np.zeros((135, 240, 3), np.uint8)
    reference[:, 80:] = (120, 118, 110)
    reference[40:90, 150:200] = 250
    query = np.repeat(np.repeat(reference, 4, axis=0), 4, axis=1)
    noise = rng.normal(0, 3, query.shape)
    query = np.clip(query.astype(np.float64) * 0.85 + 6 + noise, 0, 255).astype(np.uint8)
    query[200:260, 500:560] = (200, 60, 40)  # an object the reference lacks
    expected = detect(query, reference)
    found = detect(query, reference, backend=backend)
    tolerance = 1e-5 * float(np.abs(expected.raw_score).max()) + 1e-3
    np.testing.assert_allclose(found.raw_score, expected.raw_score, rtol=0, atol=tolerance)
    assert np.count_nonzero(found.mask != expected.mask) <= 1e-3 * found.mask.size
    assert found.anomalous and expected.anomalous
    assert found.mask[230, 530] == 255
