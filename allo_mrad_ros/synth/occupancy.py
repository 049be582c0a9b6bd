"""Where the station is: a voxel occupancy grid for ALLO's placement rules.

ALLO rejects an anomaly that intersects the station, sits inside it or is hidden from the
camera. Exact mesh queries would need trimesh's optional ``rtree``/``embree`` dependencies;
a solid voxel grid answers all three questions with array look-ups, for any station model
the renderer accepts. The grid is conservative by up to one voxel: an object that close to
the hull counts as intersecting.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from allo_mrad_ros.render.model import ModelSource, load_model
from allo_mrad_ros.synth.config import SynthError
from allo_mrad_ros.synth.objects import sample_triangles

DEFAULT_PITCH_M = 0.15
# Space left around the station's bounding box inside the grid.
_MARGIN_VOXELS = 3
_CHUNK = 4096  # triangles sampled at once, to bound memory


class StationOccupancy:
    """Solid voxel model of the station (hull and interior).

    Parameters
    ----------
    triangles : numpy.ndarray
        (m, 3, 3) station triangles in the station frame, metres.
    pitch : float
        Voxel size in metres (default 0.15).

    Attributes
    ----------
    pitch : float
        Voxel size.
    origin : numpy.ndarray
        Station-frame position of the corner of voxel (0, 0, 0).
    solid : numpy.ndarray
        (nx, ny, nz) bool: voxels on the hull or enclosed by it.
    """

    def __init__(self, triangles: np.ndarray, pitch: float = DEFAULT_PITCH_M) -> None:
        triangles = np.asarray(triangles, dtype=np.float64)
        if triangles.ndim != 3 or triangles.shape[1:] != (3, 3) or len(triangles) == 0:
            raise SynthError(f"triangles must be (m, 3, 3) with m > 0, got {triangles.shape}")
        if not np.all(np.isfinite(triangles)):
            raise SynthError("station triangles must be finite")
        if not 0.01 <= pitch <= 2.0:
            raise SynthError(f"pitch must be in [0.01, 2] m, got {pitch!r}")
        self.pitch = float(pitch)
        corners = triangles.reshape(-1, 3)
        low, high = corners.min(axis=0), corners.max(axis=0)
        self.origin = low - _MARGIN_VOXELS * self.pitch
        shape = np.ceil((high - self.origin) / self.pitch).astype(int) + _MARGIN_VOXELS + 1
        if np.prod(shape) > 400_000_000:
            raise SynthError(f"station too large for a {pitch} m grid ({shape.tolist()} voxels)")
        hull = np.zeros(shape, dtype=bool)
        # Samples at half the pitch mark every voxel the hull passes through, near enough:
        # a leak would only leave a module's interior unfilled, and the hull and
        # line-of-sight tests still reject objects placed in there.
        for start in range(0, len(triangles), _CHUNK):
            points = sample_triangles(triangles[start : start + _CHUNK], self.pitch / 2.0)
            index = np.floor((points - self.origin) / self.pitch).astype(np.int64)
            hull[index[:, 0], index[:, 1], index[:, 2]] = True
        self.solid = ndimage.binary_fill_holes(hull)
        # One voxel of margin absorbs the grid's rounding for the intersection test.
        self._blocked = ndimage.binary_dilation(self.solid, iterations=1)
        self._surface = np.argwhere(hull) * self.pitch + self.origin + self.pitch / 2
        self._tree = cKDTree(self._surface)

    @classmethod
    def from_model(
        cls, model: ModelSource | None, pitch: float = DEFAULT_PITCH_M
    ) -> StationOccupancy:
        """Build the grid from a station model as the renderer loads it.

        Parameters
        ----------
        model : path, trimesh.Trimesh, trimesh.Scene or None
            The station model; None for the package's ``meshes/station.glb``.
        pitch : float
            Voxel size in metres.
        """
        if model is None:
            from allo_mrad_ros.resources import share_path

            model = share_path("meshes", "station.glb")
        groups = load_model(model)
        triangles = np.vstack([g.positions.astype(np.float64)[g.faces] for g in groups])
        return cls(triangles, pitch)

    @property
    def surface_points(self) -> np.ndarray:
        """(n, 3) centres of the hull voxels: points on the station, station frame."""
        return self._surface

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounds of the hull voxels."""
        return np.array([self._surface.min(axis=0), self._surface.max(axis=0)])

    def _lookup(self, grid: np.ndarray, points: np.ndarray) -> np.ndarray:
        index = np.floor((np.asarray(points, dtype=np.float64) - self.origin) / self.pitch)
        index = index.astype(np.int64)
        inside = np.all((index >= 0) & (index < np.array(grid.shape)), axis=-1)
        result = np.zeros(index.shape[:-1], dtype=bool)
        hit = index[inside]
        result[inside] = grid[hit[:, 0], hit[:, 1], hit[:, 2]]
        return result

    def is_solid(self, points: np.ndarray) -> np.ndarray:
        """Per point: inside the station or on its hull."""
        return self._lookup(self.solid, points)

    def intersects(self, points: np.ndarray) -> bool:
        """Whether any point touches the station (within one voxel of its hull or inside)."""
        return bool(np.any(self._lookup(self._blocked, points)))

    def clearance(self, point: np.ndarray) -> float:
        """Distance from ``point`` to the station's hull in metres (0 inside it)."""
        point = np.asarray(point, dtype=np.float64).reshape(3)
        if self.is_solid(point[None])[0]:
            return 0.0
        distance, _ = self._tree.query(point)
        return max(0.0, float(distance) - self.pitch / 2)

    def occluded(self, eye: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Per point: whether the station lies on the line of sight from ``eye``.

        The last voxel and a half before each point are not tested, so a point on an object
        lying next to the hull is not hidden by the hull behind or beside it.

        Parameters
        ----------
        eye : numpy.ndarray
            (3,) camera position.
        points : numpy.ndarray
            (n, 3) target points.

        Returns
        -------
        numpy.ndarray
            (n,) bool.
        """
        eye = np.asarray(eye, dtype=np.float64).reshape(3)
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        offsets = points - eye
        lengths = np.linalg.norm(offsets, axis=1)
        step = self.pitch / 3.0
        count = max(2, int(np.ceil(lengths.max(initial=0.0) / step)))
        t = np.arange(count) * step  # metres from the eye
        usable = t[None, :] < (lengths[:, None] - 1.5 * self.pitch)
        directions = offsets / np.maximum(lengths[:, None], 1e-12)
        samples = eye + t[None, :, None] * directions[:, None, :]
        return np.any(self._lookup(self.solid, samples) & usable, axis=1)
