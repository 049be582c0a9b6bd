"""What the detector derives from a reference image alone, kept while that image is reused.

A still or slowly moving camera reuses one rendered reference for many frames
(:mod:`allo_mrad_ros.render.reuse`). The reference's cell statistics, quantiles, colour
bins and edge map then need computing once: :func:`derived` returns the value a stage
would compute, from the cache when the image is the one the cache holds.

Only a read-only array is held (the renderer's references are), so a cached value can never
describe pixels changed since: a writable reference is computed afresh every frame. The
image is held by reference and compared by identity, so no other array can take its place.
Cached arrays are made read-only, so a stage that changed one in place would fail loudly.
:func:`read_only_cache` does the same for the tables a stage derives from image sizes and
parameters alone.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Hashable
from dataclasses import fields, is_dataclass
from typing import Any, ParamSpec, TypeVar

import numpy as np

T = TypeVar("T")
P = ParamSpec("P")


class ReferenceCache:
    """Values derived from one read-only reference image, for as long as it is used.

    Attributes
    ----------
    hits, misses : int
        Lookups answered from the cache and computed, since creation.
    """

    def __init__(self) -> None:
        self._reference: np.ndarray | None = None
        self._values: dict[Hashable, Any] = {}
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def use(self, reference: np.ndarray) -> None:
        """Make ``reference`` the cached image (its values kept when it already was)."""
        with self._lock:
            if reference is self._reference:
                return
            self._values.clear()
            self._reference = None if reference.flags.writeable else reference

    def value(self, image: np.ndarray, key: Hashable, compute: Callable[[], T]) -> T:
        """``compute()``, from the cache when ``image`` is the cached reference."""
        with self._lock:
            cacheable = self._reference is not None and image is self._reference
            if cacheable and key in self._values:
                self.hits += 1
                return self._values[key]
        result = compute()
        if cacheable:
            _freeze(result)
            with self._lock:
                if image is self._reference:
                    self._values[key] = result
                    self.misses += 1
        return result


def derived(
    cache: ReferenceCache | None, image: np.ndarray, key: Hashable, compute: Callable[[], T]
) -> T:
    """``compute()``, through ``cache`` when there is one (see :meth:`ReferenceCache.value`).

    ``key`` names what ``compute`` derives from ``image`` and every parameter it depends on.
    """
    if cache is None:
        return compute()
    return cache.value(image, key, compute)


def read_only_cache(maxsize: int) -> Callable[[Callable[P, T]], Callable[P, T]]:
    """Memoise a function of hashable arguments, its result made read-only.

    :func:`functools.lru_cache` hands every caller the same object, so an array one caller
    changed in place would change what every later call returns; read-only, the change
    raises instead.

    Parameters
    ----------
    maxsize : int
        Results kept, least recently used dropped first.

    Returns
    -------
    callable
        A decorator; the function it returns has ``cache_info`` and ``cache_clear`` as
        :func:`functools.lru_cache` gives them.
    """

    def decorate(function: Callable[P, T]) -> Callable[P, T]:
        @functools.wraps(function)
        def frozen(*args: P.args, **kwargs: P.kwargs) -> T:
            result = function(*args, **kwargs)
            _freeze(result)
            return result

        return functools.lru_cache(maxsize=maxsize)(frozen)

    return decorate


def _freeze(value: object) -> None:
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, tuple):
        for item in value:
            _freeze(item)
    elif is_dataclass(value) and not isinstance(value, type):
        for field in fields(value):
            _freeze(getattr(value, field.name))
