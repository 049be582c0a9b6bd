"""Reference rendering of the station CAD model (pyrender; OSMesa on CPU, EGL on a GPU).

Importing this package does not import pyrender or OpenGL: the backend is chosen first,
when a :class:`ReferenceRenderer` is built.
"""

from allo_mrad_ros.render.backend import RendererError, choose_backend
from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.render.provider import ReferenceProvider
from allo_mrad_ros.render.renderer import (
    DEFAULT_SCALE,
    DEFAULT_SHADOWS,
    ReferenceRenderer,
    scaled_keeping_aspect,
)
from allo_mrad_ros.render.settings import RenderSettings
from allo_mrad_ros.render.values import (
    LABEL_ANOMALY,
    LABEL_SPACE,
    LABEL_STATION,
    ExtraObject,
    RenderResult,
)

__all__ = [
    "DEFAULT_SCALE",
    "DEFAULT_SHADOWS",
    "LABEL_ANOMALY",
    "LABEL_SPACE",
    "LABEL_STATION",
    "CelestialBody",
    "ExtraObject",
    "ReferenceProvider",
    "ReferenceRenderer",
    "RenderResult",
    "RenderSettings",
    "RendererError",
    "choose_backend",
    "scaled_keeping_aspect",
]
