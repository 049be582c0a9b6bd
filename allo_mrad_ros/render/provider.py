"""The reference of a view for one camera: :class:`ReferenceProvider`, which owns the
renderer and, with reuse bounds, warps its last render to nearby views."""

from __future__ import annotations

from os import PathLike
from typing import Any

import cv2
import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render.renderer import ReferenceRenderer, scaled_keeping_aspect
from allo_mrad_ros.render.reuse import ReferenceReuse, View
from allo_mrad_ros.render.settings import RenderSettings


class ReferenceProvider:
    """Renders the reference of a :class:`~allo_mrad_ros.view.View` for one camera.

    Owns the OpenGL renderer: build, use and close it on one thread. With
    ``render.reuse`` set, a view close to the last rendered one gets that render warped
    (:class:`~allo_mrad_ros.render.reuse.ReferenceReuse`); :attr:`reuse` counts both.

    Parameters
    ----------
    mesh : path-like, trimesh object or None
        Station model (None: the package's model).
    camera : CameraIntrinsics
        Full-resolution intrinsics of the camera.
    render : RenderSettings
        Scale, shadows, body culling, backend, reuse bounds.
    """

    def __init__(
        self,
        mesh: str | PathLike[str] | Any | None,
        camera: CameraIntrinsics,
        render: RenderSettings,
    ) -> None:
        self.settings = render
        self._camera = camera
        # The renderer's own rule: the reference keeps the image's aspect ratio.
        self.reference_camera = scaled_keeping_aspect(camera, render.reference_scale)
        self.reuse: ReferenceReuse | None = None
        # What one render must give: the reference's own size, or with reuse the keyframe's
        # (the reference plus the reuse margin).
        self._output = self.reference_camera
        if render.reuse is not None:
            self.reuse = ReferenceReuse(
                self.reference_camera, render.reuse, self.reference_camera.width / camera.width
            )
            self._output = self.reuse.wide_camera
        # Rendered at supersampling times the output's size, averaged down to it.
        self._supersampling = render.supersampling
        self.renderer = ReferenceRenderer(
            mesh,
            self._output,
            scale=float(render.supersampling),
            backend=render.render_backend or None,
            shadows=render.shadows,
            cull_bodies=render.cull_bodies,
        )

    @property
    def camera(self) -> CameraIntrinsics:
        """Full-resolution intrinsics the references are rendered for."""
        return self._camera

    def render(self, view: View, time_s: float | None = None) -> np.ndarray:
        """The reference RGB image of ``view``, the Sun's disc included.

        ``time_s`` is the frame's time (its stamp), which limits how long a render is
        reused; None leaves age unchecked. With reuse the array is read-only (it may be the
        last render's own).
        """
        if self.reuse is None:
            return self._render(view)[0]
        return self.reuse.reference(view, time_s, self._render)

    def render_with_depth(
        self, view: View, time_s: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`render`'s reference and its depth: H x W float32 z depth in metres along
        the camera's optical axis (pyrender's linear depth), 0 where space is in view.

        With reuse, the depth is warped with the colour and measured from ``view``'s
        camera; both arrays are then read-only. Asking for the depth costs a depth read
        back (and, with reuse, a warp of the depth); :meth:`render` never pays for it.
        """
        if self.reuse is None:
            return self._render(view, depth=True)
        return self.reuse.reference_with_depth(view, time_s, self._render)

    def _render(self, view: View, depth: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """One render at the output's size, with its depth when asked or with reuse (the
        warp needs it)."""
        result = self.renderer.render(
            view.T_station_camera,
            view.sun_direction,
            view.sun_strength,
            view.sky_bodies,
            depth=depth or self.reuse is not None,
        )
        rgb, depth_image = result.rgb, result.depth
        if self._supersampling > 1:
            size = (self._output.width, self._output.height)
            rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
            if depth_image is not None:
                # A depth is one surface's, not a blend of a near and a far one.
                depth_image = cv2.resize(depth_image, size, interpolation=cv2.INTER_NEAREST)
        return rgb, depth_image

    def warm_up(self) -> None:
        """Render once from a pose looking at the station, outside any reuse: the first
        render compiles the shaders and fills the GL caches (several times a frame's time)."""
        low, high = self.renderer.station_bounds
        centre = (low + high) / 2.0
        eye = centre + np.array([0.0, -1.0, 0.3]) * 2.0 * float(np.linalg.norm(high - low))
        self.renderer.render(look_at(eye, centre), (0.3, -0.5, 0.8))

    def close(self) -> None:
        """Release the GL context."""
        self.renderer.close()
