"""Range evidence from one frame: the rays through a detection region and its range interval.

A region seen where the reference shows station surface lies in front of that surface: its
range along its rays is at least ``min_range`` and below the surface's range behind its
pixels. Seen against space, all one view says is ``[min_range, max_range]``.

The reference depth is pyrender's z depth (metres along the optical axis; 0, or not finite,
where space is in view) at the reference's own resolution, which may be lower than the
image's: the region's box is read at the depth's resolution (the pixels the box overlaps),
and, when the detection mask is given, only where the mask is set.

Conventions: pixel centres at integer coordinates (OpenCV, ROS); a camera pose is the
optical frame (x right, y down, z forward) in the station frame (:mod:`~allo_mrad_ros.geometry`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.regions import Region
from allo_mrad_ros.geometry import PoseError, validate_transform
from allo_mrad_ros.objects.params import ObjectsError


@dataclass(frozen=True)
class RegionRays:
    """The rays through one region's pixels and the range interval one view gives it.

    Attributes
    ----------
    origin : numpy.ndarray
        (3,) the camera centre, station frame (every ray starts there).
    centre : numpy.ndarray
        (3,) unit ray through the region's centroid, station frame.
    directions : numpy.ndarray
        (n, 3) unit rays through the region's pixels, sampled at the depth's resolution
        (the mask's pixels within its box when the mask is given, else the box's).
    min_range, max_range : float
        The range interval along the rays, metres: the object lies at a range in
        ``[min_range, max_range)``; ``max_range`` is the surface's range behind the region
        (its ``surface_quantile``) when :attr:`over_surface`, else the stated maximum.
    over_surface : bool
        Whether station surface lies behind any of the region's pixels.
    extent_rad : float
        The angle the region's box spans (its larger side), radians.
    """

    origin: np.ndarray
    centre: np.ndarray
    directions: np.ndarray
    min_range: float
    max_range: float
    over_surface: bool
    extent_rad: float


def depth_camera(camera: CameraIntrinsics, depth_shape: tuple[int, ...]) -> CameraIntrinsics:
    """The intrinsics of ``camera`` at the depth image's size (the reference's scaling:
    per axis, the size ratio, with pixel edges kept)."""
    # Cached per camera and size: the tracker asks twice a frame for the same one.
    return _depth_camera(camera, tuple(depth_shape))


@lru_cache(maxsize=16)
def _depth_camera(camera: CameraIntrinsics, depth_shape: tuple[int, ...]) -> CameraIntrinsics:
    if len(depth_shape) != 2 or min(depth_shape) < 1:
        raise ObjectsError(f"depth must be a 2-D image, got shape {tuple(depth_shape)}")
    height, width = int(depth_shape[0]), int(depth_shape[1])
    sx, sy = width / camera.width, height / camera.height
    if abs(sx - sy) > 0.02 * max(sx, sy) + 1.0 / min(width, height):
        raise ObjectsError(
            f"depth {width}x{height} does not have the aspect of the camera's "
            f"{camera.width}x{camera.height} image"
        )
    return camera.resized(width, height)


def checked_pose(pose: object) -> np.ndarray:
    """``pose`` as a float64 rigid 4x4 transform, else :class:`ObjectsError`.

    The checks of :func:`~allo_mrad_ros.geometry.validate_transform`, with its tolerances,
    on the sixteen values as Python floats (the tracker checks a pose every frame: a dozen
    array operations on a 4x4 cost three times as much); a pose they refuse goes through
    ``validate_transform`` for its message (and its verdict)."""
    matrix = np.asarray(pose, dtype=np.float64)
    if matrix.shape == (4, 4):
        (a, b, c, _), (d, e, f, _), (g, h, i, _), (p, q, r, s) = rows = matrix.tolist()
        # Finite: a sum of finite values is finite unless it overflows (then the full check
        # decides).
        total = sum(rows[0]) + sum(rows[1]) + sum(rows[2]) + p + q + r + s
        # numpy.allclose(x, y, atol): |x - y| <= atol + 1e-5 |y| (the last row against
        # 0 0 0 1, atol 1e-9; R R^T against the identity, atol 1e-6).
        if (
            math.isfinite(total)
            and max(abs(p), abs(q), abs(r)) <= _ROW_ATOL
            and abs(s - 1.0) <= _ROW_ATOL + 1e-5
            and max(
                abs(a * a + b * b + c * c - 1.0),
                abs(d * d + e * e + f * f - 1.0),
                abs(g * g + h * h + i * i - 1.0),
            )
            <= _GRAM_ATOL + 1e-5
            and max(
                abs(a * d + b * e + c * f), abs(a * g + b * h + c * i), abs(d * g + e * h + f * i)
            )
            <= _GRAM_ATOL
            and a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) >= 0
        ):
            return matrix
    try:
        return validate_transform(pose, "camera pose")
    except PoseError as error:
        raise ObjectsError(str(error)) from None


# checked_pose's absolute tolerances (validate_transform's numpy.allclose atol).
_ROW_ATOL = 1e-9
_GRAM_ATOL = 1e-6


def depth_array(depth: object) -> np.ndarray:
    """``depth`` as a non-empty 2-D float32 array, its values as given (what reads it
    treats 0, negative or not finite values as space), else :class:`ObjectsError`."""
    array = np.asarray(depth)
    if array.ndim != 2 or array.size == 0 or not np.issubdtype(array.dtype, np.number):
        raise ObjectsError(
            f"depth must be a non-empty 2-D array of numbers, got shape {array.shape} "
            f"and dtype {array.dtype}"
        )
    return array.astype(np.float32, copy=False)


def checked_depth(depth: object) -> np.ndarray:
    """``depth`` as a 2-D float array with space (0, negative or not finite) set to 0."""
    array = depth_array(depth)
    surface = np.isfinite(array) & (array > 0)
    return array if surface.all() else np.where(surface, array, np.float32(0.0))


def camera_rays(camera: CameraIntrinsics, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, 3) unit rays of pixels ``(u, v)`` in ``camera``'s optical frame."""
    u = np.asarray(u, float)
    rays = np.ones((*u.shape, 3))  # z = 1, x and y written in
    rays[..., 0] = (u - camera.cx) / camera.fx
    rays[..., 1] = (np.asarray(v, float) - camera.cy) / camera.fy
    # numpy.linalg.norm's own sum (the same values, without its checks).
    return rays / np.sqrt(np.add.reduce(rays * rays, axis=-1, keepdims=True))


@dataclass(frozen=True)
class _Footprint:
    """A region's pixels at the depth's resolution and the surface's range behind each."""

    u: np.ndarray  # image columns of the box's depth pixels' centres
    v: np.ndarray  # image rows of them
    surface_range: np.ndarray  # metres along each sampled pixel's ray; 0 where space
    inside: np.ndarray | None  # which of the box's pixels are sampled (None: all)

    def pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates of the sampled pixels, raster order."""
        uu, vv = np.meshgrid(self.u, self.v)
        if self.inside is not None:
            return uu[self.inside], vv[self.inside]
        return uu.ravel(), vv.ravel()


def _footprint(
    region: Region,
    camera: CameraIntrinsics,
    depth: np.ndarray,
    reference: CameraIntrinsics,
    mask: np.ndarray | None,
) -> _Footprint:
    sx, sy = reference.width / camera.width, reference.height / camera.height
    x, y, w, h = region.box
    c0 = min(max(math.floor(x * sx), 0), reference.width - 1)
    r0 = min(max(math.floor(y * sy), 0), reference.height - 1)
    c1 = min(max(math.ceil((x + w) * sx), c0 + 1), reference.width)
    r1 = min(max(math.ceil((y + h) * sy), r0 + 1), reference.height)
    cols = np.arange(c0, c1)
    rows = np.arange(r0, r1)
    # Each depth pixel's centre in image pixels, and its ray's length per unit z.
    u = (cols + 0.5) / sx - 0.5
    v = (rows + 0.5) / sy - 0.5
    xn = (u - camera.cx) / camera.fx
    yn = (v - camera.cy) / camera.fy
    stretch = np.sqrt((xn * xn)[None, :] + (yn * yn)[:, None] + 1.0)
    surface_range = depth[r0:r1, c0:c1] * stretch
    inside = None
    if mask is not None:
        ui = np.clip(np.floor((cols + 0.5) / sx).astype(np.int64), 0, camera.width - 1)
        vi = np.clip(np.floor((rows + 0.5) / sy).astype(np.int64), 0, camera.height - 1)
        inside = mask[np.ix_(vi, ui)] != 0
        if not inside.any():  # the region is smaller than a depth pixel: the whole box
            inside = None
    if inside is not None:
        surface_range = surface_range[inside]
    return _Footprint(u, v, surface_range.ravel(), inside)


@lru_cache(maxsize=8)
def _depth_grid(
    camera: CameraIntrinsics, reference: CameraIntrinsics
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per depth pixel, the length of its ray per unit z (as :func:`_footprint` computes
    it), and the image column and row each depth column and row samples the mask at."""
    sx, sy = reference.width / camera.width, reference.height / camera.height
    cols = np.arange(reference.width)
    rows = np.arange(reference.height)
    xn = ((cols + 0.5) / sx - 0.5 - camera.cx) / camera.fx
    yn = ((rows + 0.5) / sy - 0.5 - camera.cy) / camera.fy
    stretch = np.sqrt((xn * xn)[None, :] + (yn * yn)[:, None] + 1.0)
    ui = np.clip(np.floor((cols + 0.5) / sx).astype(np.int64), 0, camera.width - 1)
    vi = np.clip(np.floor((rows + 0.5) / sy).astype(np.int64), 0, camera.height - 1)
    for array in (stretch, ui, vi):
        array.setflags(write=False)
    return stretch, ui, vi


@lru_cache(maxsize=8)
def _box_scaling(
    camera: CameraIntrinsics, reference: CameraIntrinsics
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per image axis (x, y): the depth's pixels per image pixel, and the depth's last
    pixel and size along it (what a box's depth pixels are clipped to)."""
    scale = np.array([reference.width / camera.width, reference.height / camera.height])
    size = np.array([reference.width, reference.height])
    last = size - 1
    for array in (scale, last, size):
        array.setflags(write=False)
    return scale, last, size


class _FrameRanges:
    """One frame's surface ranges at the depth's resolution, for many regions: what
    :func:`_footprint` computes per region (the same values), with the per-pixel geometry
    computed once per camera."""

    __slots__ = ("_depth", "_last", "_mask", "_scale", "_size", "_stretch", "_ui", "_vi")

    def __init__(
        self,
        camera: CameraIntrinsics,
        depth: np.ndarray,
        reference: CameraIntrinsics,
        mask: np.ndarray | None,
    ) -> None:
        self._stretch, self._ui, self._vi = _depth_grid(camera, reference)
        self._scale, self._last, self._size = _box_scaling(camera, reference)
        self._depth = depth
        self._mask = mask

    def surface_ranges(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The surface ranges behind the depth pixels of each of ``boxes`` ((n, 4) of
        ``x, y, w, h``), under the mask if any (all of a box's where it sets none: the
        region is smaller than a depth pixel): every box's in raster order, boxes in order,
        and the box each belongs to. The values :func:`_footprint` gives each region,
        gathered for all boxes at once (a slice of the depth and the mask per box cost more
        than the gathering)."""
        # Each box's first depth column and row, and the column and row past its last (both
        # axes at once).
        corner, side = boxes[:, :2], boxes[:, 2:]
        first = np.minimum(np.maximum(np.floor(corner * self._scale), 0), self._last)
        first = first.astype(np.int64)
        end = np.minimum(np.maximum(np.ceil((corner + side) * self._scale), first + 1), self._size)
        (c0, r0), (c1, r1) = first.T, end.astype(np.int64).T
        widths = c1 - c0
        counts = widths * (r1 - r0)
        box = np.arange(len(boxes)).repeat(counts)
        # Each pixel's place in its box, raster order: its row and column there.
        place = np.arange(len(box)) - (counts.cumsum() - counts).repeat(counts)
        row_in_box, col_in_box = np.divmod(place, widths[box])
        rows = r0[box] + row_in_box
        cols = c0[box] + col_in_box
        ranges = self._depth[rows, cols] * self._stretch[rows, cols]
        if self._mask is not None:
            inside = self._mask[self._vi[rows], self._ui[cols]] != 0
            any_inside = np.bincount(box[inside], minlength=len(boxes)) > 0
            keep = inside | ~any_inside[box]
            ranges, box = ranges[keep], box[keep]
        return ranges, box


def surface_bound(surface_range: np.ndarray, quantile: float) -> float | None:
    """The ``quantile`` of the positive ``surface_range`` values (the lower of two order
    statistics, no interpolation), or None where all are space."""
    # Positive and finite: a depth given unchecked (depth_array) may hold NaN or inf.
    surface = surface_range[(surface_range > 0) & (surface_range < np.inf)]
    if surface.size == 0:
        return None
    k = min(math.floor(quantile * (surface.size - 1)), surface.size - 1)
    return float(np.partition(surface, k)[k])


def surface_bounds(
    values: np.ndarray, region: np.ndarray, count: int, quantile: float
) -> np.ndarray:
    """:func:`surface_bound` of the ``values`` of each of ``count`` regions at once
    (``region``: the region of each value; NaN where all of a region's are space): one sort
    of all of them, by region and then by value."""
    if count == 0:
        return np.zeros(0)
    surface = (values > 0) & (values < np.inf)
    values, region = values[surface], region[surface]
    sizes = np.bincount(region, minlength=count)
    ordered = values[np.lexsort((values, region))]
    starts = sizes.cumsum() - sizes
    k = np.minimum(np.floor(quantile * (sizes - 1)).astype(np.int64), sizes - 1)
    found = sizes > 0
    picked = ordered[np.where(found, starts + np.maximum(k, 0), 0)] if ordered.size else None
    return np.where(found, picked, np.nan) if picked is not None else np.full(count, np.nan)


def region_rays(
    region: Region,
    pose: np.ndarray,
    camera: CameraIntrinsics,
    depth: np.ndarray,
    *,
    mask: np.ndarray | None = None,
    min_range: float = 0.3,
    max_range: float = 50.0,
    surface_quantile: float = 0.1,
) -> RegionRays:
    """The rays through ``region``'s pixels in the station frame and its range interval.

    Parameters
    ----------
    region : Region
        A region of a :class:`~allo_mrad_ros.detector.DetectionResult` (its box and
        centroid are in ``camera``'s pixels).
    pose : numpy.ndarray
        4x4 camera-to-station pose of the frame (optical frame).
    camera : CameraIntrinsics
        Full-resolution intrinsics of the image the region was found in.
    depth : numpy.ndarray
        The reference's z depth for this frame (any resolution with the image's aspect; 0
        or not finite where space is in view).
    mask : numpy.ndarray, optional
        The detection mask at ``camera``'s resolution: only its set pixels in the region's
        box count.
    min_range, max_range : float
        The nearest range an object may have, and the farthest one seen against space may.
    surface_quantile : float
        The quantile of the surface ranges behind the region that bounds its range.

    Returns
    -------
    RegionRays

    Raises
    ------
    ObjectsError
        For a malformed pose, depth or mask, or a range interval that is empty.
    """
    pose = checked_pose(pose)
    depth = checked_depth(depth)
    reference = depth_camera(camera, depth.shape)
    if mask is not None and np.shape(mask) != (camera.height, camera.width):
        raise ObjectsError(
            f"mask shape {np.shape(mask)} differs from the camera's {camera.height}x{camera.width}"
        )
    if not 0 < min_range < max_range:
        raise ObjectsError(f"need 0 < min_range < max_range, got {min_range}, {max_range}")
    footprint = _footprint(region, camera, depth, reference, mask)
    bound = surface_bound(footprint.surface_range, surface_quantile)
    rotation = pose[:3, :3]
    directions = camera_rays(camera, *footprint.pixels()) @ rotation.T
    centre = camera_rays(camera, *np.array(region.centroid)[:, None])[0] @ rotation.T
    # A region before a surface nearer than min_range keeps a range interval of one point.
    upper = max_range if bound is None else max(min(bound, max_range), min_range)
    return RegionRays(
        origin=pose[:3, 3].copy(),
        centre=centre,
        directions=directions,
        min_range=float(min_range),
        max_range=float(upper),
        over_surface=bound is not None,
        extent_rad=extent_rad(region, camera),
    )


def extent_rad(region: Region, camera: CameraIntrinsics) -> float:
    """The angle of the larger side of ``region``'s box, radians (small-angle)."""
    _, _, w, h = region.box
    return float(max(w / camera.fx, h / camera.fy))


@dataclass(frozen=True)
class Observations:
    """One frame's regions as rays: what the tracker associates and adds to objects.

    Attributes
    ----------
    origin : numpy.ndarray
        (3,) camera centre, station frame.
    directions : numpy.ndarray
        (n, 3) unit rays through the regions' centroids, station frame.
    pixels : numpy.ndarray
        (n, 2) the centroids, image pixels.
    low, high : numpy.ndarray
        (n,) each region's range interval.
    over_surface : numpy.ndarray
        (n,) bool.
    extent_px : numpy.ndarray
        (n,) the larger side of each region's box, pixels.
    edge_px : numpy.ndarray
        (n, 2) each region's box side across the image edges it touches, per image axis:
        its width where it touches the left or right edge, its height where it touches the
        top or bottom (0 otherwise): the object may extend beyond the image there, and the
        centroid of what shows is not the object's along that axis (only along it).
    scores : numpy.ndarray
        (n,) each region's score.
    indices : numpy.ndarray
        (n,) int, the position of each in the regions given.
    """

    origin: np.ndarray
    directions: np.ndarray
    pixels: np.ndarray
    low: np.ndarray
    high: np.ndarray
    over_surface: np.ndarray
    extent_px: np.ndarray
    edge_px: np.ndarray
    scores: np.ndarray
    indices: np.ndarray

    def __len__(self) -> int:
        return len(self.indices)


def observe(
    regions: Sequence[Region],
    pose: np.ndarray,
    camera: CameraIntrinsics,
    depth: np.ndarray,
    *,
    mask: np.ndarray | None,
    min_range: float,
    max_range: float,
    surface_quantile: float,
    min_score: float = 0.0,
) -> Observations:
    """The centroid rays and range intervals of ``regions`` (those scoring at least
    ``min_score``); ``pose`` and ``depth`` already checked (:func:`checked_pose`,
    :func:`depth_array`: values not positive or not finite are space). The interval of
    each is :func:`region_rays`'s."""
    reference = depth_camera(camera, depth.shape)
    frame = _FrameRanges(camera, depth, reference, mask)
    kept: list[int] = []
    shapes: list[float] = []
    scores: list[float] = []
    for index, region in enumerate(regions):
        if not isinstance(region, Region):
            raise ObjectsError(f"region {index} must be a detector Region, got {type(region)}")
        if region.score < min_score:
            continue
        kept.append(index)
        # One flat list for both below (numpy reads a list of tuples at twice the cost).
        shapes += (*region.box, *region.centroid)
        scores.append(region.score)
    shape_array = np.asarray(shapes, dtype=np.float64).reshape(-1, 6)
    box_array, pixel_array = shape_array[:, :4], shape_array[:, 4:]
    values, owner = frame.surface_ranges(box_array)
    bound = surface_bounds(values, owner, len(kept), surface_quantile)
    corner, side = box_array[:, :2], box_array[:, 2:]
    # Each box's side across the image edges it touches: x at the left or right, y at the
    # top or bottom.
    touches = (corner <= 0) | (corner + side >= (camera.width, camera.height))
    surface = ~np.isnan(bound)
    # A region before a surface nearer than min_range keeps a range interval of one point.
    high = np.where(surface, np.maximum(np.minimum(bound, max_range), min_range), max_range)
    directions = camera_rays(camera, pixel_array[:, 0], pixel_array[:, 1]) @ pose[:3, :3].T
    return Observations(
        origin=pose[:3, 3].copy(),
        directions=directions.reshape(-1, 3),
        pixels=pixel_array,
        low=np.full(len(kept), float(min_range)),
        high=np.asarray(high, dtype=np.float64),
        over_surface=surface,
        extent_px=side.max(axis=1),
        edge_px=np.where(touches, side, 0.0),
        scores=np.asarray(scores, dtype=np.float64),
        indices=np.asarray(kept, dtype=np.int64),
    )
