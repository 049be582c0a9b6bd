"""How references are rendered: :class:`RenderSettings`, validated when built."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.render.renderer import DEFAULT_SCALE, DEFAULT_SHADOWS
from allo_mrad_ros.render.reuse import ReuseBounds

RENDER_BACKENDS = ("", "osmesa", "egl")
DEFAULT_SUPERSAMPLING = 1
"""The reference's supersampling factor (see :class:`RenderSettings`): 1, as the frame
decision's operating point was chosen with it (docs/detector.md, "The reference")."""
MAX_SUPERSAMPLING = 4


class RenderSettingsError(InvalidInput):
    """An invalid render setting (scale, backend, reuse bounds)."""


@dataclass(frozen=True)
class RenderSettings:
    """How the reference is rendered.

    Parameters
    ----------
    reference_scale : float
        Linear scale of the rendered reference, (0, 1].
    shadows : bool
        Directional shadows from the Sun.
    cull_bodies : bool
        Draw celestial bodies only when in view (False exists to measure what culling saves).
    render_backend : str
        ``osmesa``, ``egl``, or empty to choose.
    reuse : ReuseBounds or None
        Warp the last rendered reference to a later view while these bounds allow
        (:mod:`allo_mrad_ros.render.reuse`); None renders every view. Frames must then
        come in their time order.
    supersampling : int
        The reference is rendered at this many times its size along each axis and
        area-averaged down to it (1..4; 1 renders it at its size): an edge or a structure
        thinner than a reference pixel (a panel seen edge-on, a handrail) then gets its share
        of the pixel instead of appearing in some pixels and not in others. The depth is
        sampled, not averaged.
    """

    reference_scale: float = DEFAULT_SCALE
    shadows: bool = DEFAULT_SHADOWS
    cull_bodies: bool = True
    render_backend: str = ""
    reuse: ReuseBounds | None = None
    # Last, so that positional construction from the fields above keeps its meaning.
    supersampling: int = DEFAULT_SUPERSAMPLING

    def __post_init__(self) -> None:
        scale = self.reference_scale
        if isinstance(scale, bool) or not isinstance(scale, int | float):
            raise RenderSettingsError(f"reference_scale must be a number, got {scale!r}")
        if not (math.isfinite(scale) and 0 < scale <= 1):
            raise RenderSettingsError(f"reference_scale must be in (0, 1], got {scale!r}")
        factor = self.supersampling
        if isinstance(factor, bool) or not isinstance(factor, numbers.Integral):
            raise RenderSettingsError(f"supersampling must be an integer, got {factor!r}")
        if not 1 <= factor <= MAX_SUPERSAMPLING:
            raise RenderSettingsError(
                f"supersampling must be in 1..{MAX_SUPERSAMPLING}, got {factor!r}"
            )
        if self.render_backend not in RENDER_BACKENDS:
            raise RenderSettingsError(
                f"render_backend must be one of {list(RENDER_BACKENDS)}, "
                f"got {self.render_backend!r}"
            )
        if self.reuse is not None and not isinstance(self.reuse, ReuseBounds):
            raise RenderSettingsError(f"reuse must be ReuseBounds or None, got {self.reuse!r}")
