"""Anomalies as objects in the station frame, confirmed over frames: :class:`ObjectTracker`.

Per frame the tracker is given the detection's regions, the camera pose, the reference
depth and the frame's stamp. It

1. turns each region into a ray through its centroid with a range interval
   (:func:`~allo_mrad_ros.objects.rays.observe`);
2. projects every object into the image with its covariance (grown by the drift allowed
   since its last hit) and decides whether it is in view: in front of the camera, inside
   the image and not hidden behind station surface (its depth beyond the reference depth at
   its pixel by more than ``occlusion_margin`` plus three of its depth's standard deviations);
3. associates regions with objects by optimal assignment
   (:func:`scipy.optimize.linear_sum_assignment`) of the squared Mahalanobis distance between
   a region's centroid and an object's projection, gated by ``gate_sigma`` and by the ratio
   of the region's extent to the object's projected extent;
4. adds each matched region's ray to its object and starts a tentative object from each
   unmatched region scoring ``min_region_score`` (one view: the range interval; a fainter
   one, down to ``hit_region_score``, only continues an object);
5. re-triangulates the objects that got a ray (:mod:`.triangulation`);
6. confirms a tentative object after ``confirm_hits`` hits in its last ``confirm_window``
   in-view frames, once parallax places it nearer than ``max_range``, neither behind the
   surface nor nearer than ``min_range``, while its newest rays pass through it as one
   point's would (``residual_quantile``) and its newest regions are of one size
   (``steady_size_ratio``); ends an object after ``end_misses`` consecutive
   in-view misses (a hidden or out-of-view object is not missed), and a tentative one not
   hit for ``tentative_timeout_s``.

Something that keeps one direction in the station frame while the camera moves (the Moon, a
star, glare locked to the Sun) has no parallax: its range stays undetermined and it is never
confirmed.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from operator import attrgetter
from typing import Any, Literal

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.regions import Region
from allo_mrad_ros.objects.params import ObjectParams, ObjectsError
from allo_mrad_ros.objects.rays import (
    Observations,
    checked_pose,
    depth_array,
    depth_camera,
    observe,
)
from allo_mrad_ros.objects.triangulation import RayBatch, Triangulation, triangulate

State = Literal["tentative", "confirmed", "ended"]
# Cost of a gated-out pair in the assignment (never chosen over a gated-in one).
_FORBIDDEN = 1e12
# A ray seen against space bounds the triangulation's range by this multiple of max_range
# only: rays that keep one direction (the Moon, glare) meet at infinity, and an object held
# at max_range would drift off their next region (a new id every few frames). max_range
# still decides confirmation (range_resolved).
_SPACE_FAR = 1e3
# Columns of a track's ring of rays (_Table.rays): origin 0:3, direction 3:6, then these.
_VARIANCE, _STAMP, _LOW, _HIGH, _EXTENT = 6, 7, 8, 9, 10
_COLUMNS = 11
_EYE3 = np.eye(3)
# steady_size_ratio (or partial_size_ratio) at or above this drops the test (its range's
# top: 1e6).
_NO_SIZE_TEST = 1e6
# The angular variance, rad^2, of an anchor ray left out of the position (_partial): its
# weight nothing beside any region's (pixel noise over a focal length: 1e-4 rad^2 or less).
_WEIGHTLESS = 1e6
# A distance below which an estimate is taken to be at the camera (no direction).
_TINY = 1e-12
# A record is made without the frozen dataclass's __init__: its fields' dict set at once.
_new_record = object.__new__
_set_fields = object.__setattr__


@dataclass(frozen=True)
class TrackedObject:
    """One object as the tracker holds it after a frame.

    Attributes
    ----------
    id : int
        Stable for the object's life, never reused by the tracker.
    state : {"tentative", "confirmed", "ended"}
        ``ended`` is reported once, in the frame the object ends.
    position : numpy.ndarray
        (3,) station frame, metres.
    covariance : numpy.ndarray
        (3, 3) of :attr:`position`, m^2.
    size : float
        Metres: the angle of its regions' larger box side times their range (median).
    score : float
        In [0, 1]: the sum of its regions' scores over its last ``confirm_window`` in-view
        frames, divided by ``confirm_window`` (a miss adds 0).
    range_resolved : bool
        Parallax places it nearer than ``max_range`` (by ``parallax_sigma``).
    in_view : bool
        In this frame's image and not hidden.
    region : int or None
        The index, in the regions given this frame, of the region matched with it.
    hits : int
        Regions matched with it so far.
    first_stamp, last_hit_stamp : float
        When it was first and last seen.
    """

    id: int
    state: State
    position: np.ndarray
    covariance: np.ndarray
    size: float
    score: float
    range_resolved: bool
    in_view: bool
    region: int | None
    hits: int
    first_stamp: float
    last_hit_stamp: float


@dataclass(frozen=True)
class _Sightings:
    """Estimates seen from one camera position: distances (n,) and unit directions (n, 3),
    sizes (n,), direction noises (n,) and covariances (n of (3, 3), gathered as needed)."""

    distances: np.ndarray
    directions: np.ndarray
    sizes: np.ndarray
    noises: np.ndarray
    covariances: Sequence[np.ndarray]


def _ray_rows(
    observations: Observations, variance: np.ndarray, stamp: float, max_range: float
) -> np.ndarray:
    """(n, _COLUMNS) each observation's ray as a row of a track's ray table: built once a
    frame, so that adding a ray to a track is one row copy (a write per column per track
    cost a twentieth of the frame). A ray seen against space (its interval up to
    ``max_range``) bounds the range at ``_SPACE_FAR`` times that (set here, once a ray)."""
    rows = np.empty((len(observations), _COLUMNS))
    rows[:, 0:3] = observations.origin
    rows[:, 3:6] = observations.directions
    rows[:, _VARIANCE] = variance
    rows[:, _STAMP] = stamp
    rows[:, _LOW] = observations.low
    high = observations.high
    rows[:, _HIGH] = np.where(high >= max_range, max_range * _SPACE_FAR, high)
    rows[:, _EXTENT] = observations.extent_px
    return rows


def _ranges_along(positions: np.ndarray, packed: np.ndarray) -> np.ndarray:
    """(B, R): how far along each ray of ``packed`` (ring rows: origin, unit direction) each
    object's point ``positions`` (B, 3) lies."""
    offset = positions[:, None, :] - packed[..., 0:3]
    return np.einsum("brj,brj->br", offset, packed[..., 3:6])


def _row_medians(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Each row's median over its ``valid`` entries (each row has one at least): what
    ``numpy.nanmedian`` gives with the others set to NaN, without its masked-array cost."""
    if valid.all():  # every row full (a full ring): its middle columns
        ordered = np.sort(values, axis=1)
        middle = values.shape[1]
        return (ordered[:, (middle - 1) // 2] + ordered[:, middle // 2]) / 2.0
    ordered = np.sort(np.where(valid, values, np.inf), axis=1)
    count = valid.sum(axis=1)
    rows = np.arange(len(values))
    return (ordered[rows, (count - 1) // 2] + ordered[rows, count // 2]) / 2.0


# A line of sight: distance from the camera and unit direction, of one estimate (a float
# and (3,)) or of n (arrays (n,) and (n, 3)).
_Sight = tuple[Any, np.ndarray]


def same_object(
    one: tuple[np.ndarray, np.ndarray, float, float],
    others: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    camera: np.ndarray,
    limit: float,
) -> np.ndarray:
    """Which of ``others`` may be one thing with ``one``, seen from the ``camera`` position:
    their extents meet in the image and in range. Two things apart in the image are two
    however uncertain their ranges: the image tells them apart where the triangulation
    cannot yet.

    In the image, the angle between them less half their summed angular sizes is at most
    zero, or its square within ``limit`` times the summed variances of their directions (a
    thing the detection splits leaves a few pixels between its parts). In range, the range
    gap less half their summed sizes is at most zero, or its square within ``limit`` times
    its variance (the two covariances along their lines of sight).

    Parameters
    ----------
    one : tuple
        Position (3,) and covariance (3, 3) in the station frame, size across (metres) and
        the standard deviation of its direction (radians).
    others : tuple
        The same for ``n`` estimates: positions (n, 3), covariances (n, 3, 3), sizes (n,)
        and direction noises (n,).
    camera : numpy.ndarray
        The camera's position (3,), station frame.
    limit : float
        A squared gap's bound in variances (a chi-square quantile of 1 degree of freedom).

    Returns
    -------
    numpy.ndarray
        (n,) bool.
    """
    position, covariance, size, noise = one
    positions, covariances, sizes, noises = (np.asarray(a, dtype=np.float64) for a in others)
    distances, directions = _line_of_sight(positions, camera)
    return _same_object(
        (_sight_of(position, camera), covariance, size, noise),
        _Sightings(distances, directions, sizes, noises, covariances),
        limit,
    )


def _same_object(
    one: tuple[_Sight, np.ndarray, float, float], others: _Sightings, limit: float
) -> np.ndarray:
    """:func:`same_object` from lines of sight (``one``: its line of sight, covariance, size
    and direction noise): the range test only for those that meet ``one`` in the image,
    their covariances gathered for those alone."""
    sight, covariance, size, noise = one
    sights = (others.distances, others.directions)
    meet = _meet_in_image(sight, size, noise, sights, others.sizes, others.noises, limit)
    near = np.flatnonzero(meet)
    if len(near):
        meet[near] = _meet_in_range(
            sight,
            covariance,
            size,
            (others.distances[near], others.directions[near]),
            np.array([others.covariances[i] for i in near]),
            others.sizes[near],
            limit,
        )
    return meet


def _meet_in_image(
    sight: _Sight,
    size: float,
    noise: float,
    sights: _Sight,
    sizes: np.ndarray,
    noises: np.ndarray,
    limit: float,
) -> np.ndarray:
    """The image half of :func:`same_object`, from lines of sight."""
    (distance, direction), (distances, directions) = sight, sights
    angles = np.arccos(np.clip(directions @ direction, -1.0, 1.0))
    gap = angles - 0.5 * (size / distance + sizes / distances)
    return (gap <= 0.0) | (gap**2 <= limit * (noise**2 + noises**2))


def _meet_in_range(
    sight: _Sight,
    covariance: np.ndarray,
    size: float,
    sights: _Sight,
    covariances: np.ndarray,
    sizes: np.ndarray,
    limit: float,
) -> np.ndarray:
    """The range half of :func:`same_object`, from lines of sight."""
    (distance, direction), (distances, directions) = sight, sights
    gap = np.abs(distances - distance) - 0.5 * (size + sizes)
    variance = direction @ covariance @ direction + np.einsum(
        "ni,nij,nj->n", directions, covariances, directions
    )
    return (gap <= 0.0) | (gap**2 <= limit * variance)


# The margins by which a pair must pass the same-object test in scalars
# (ObjectTracker._meets_again) to stand for the vectorised test: far above what rounding
# can move either (an angle from arccos near 0 carries about 1e-8 rad of it; the rest is
# relative, about 1e-15).
_ANGLE_MARGIN = 1e-6  # radians
_RELATIVE_MARGIN = 1e-6


def _surely_within(gap: float, margin: float, bound: float) -> bool:
    """Whether ``gap <= 0 or gap**2 <= bound`` holds however ``gap`` moves by ``margin``
    and ``bound`` by its relative margin (the test of :func:`_meet_in_image` and
    :func:`_meet_in_range`, passed with room to spare)."""
    return gap + margin <= 0.0 or (abs(gap) + margin) ** 2 <= bound * (1.0 - _RELATIVE_MARGIN)


def _scalar_sight(
    position: np.ndarray, camera: np.ndarray
) -> tuple[float, tuple[float, float, float]]:
    """:func:`_sight_of` in Python floats: the distance and unit direction."""
    (x, y, z), (cx, cy, cz) = position.tolist(), camera.tolist()
    x, y, z = x - cx, y - cy, z - cz
    distance = max(math.sqrt(x * x + y * y + z * z), _TINY)
    return distance, (x / distance, y / distance, z / distance)


def _scalar_variance(
    unit: tuple[float, float, float], covariance: np.ndarray
) -> tuple[float, float]:
    """``unit . covariance . unit`` in Python floats, and the sum of the covariance's
    magnitudes (the scale of that product's rounding)."""
    (a, b, c), (d, e, f), (g, h, i) = covariance.tolist()
    x, y, z = unit
    value = x * (a * x + b * y + c * z) + y * (d * x + e * y + f * z) + z * (g * x + h * y + i * z)
    return value, sum(map(abs, (a, b, c, d, e, f, g, h, i)))


def _sight_of(position: np.ndarray, camera: np.ndarray) -> _Sight:
    """The line of sight of one ``position`` (3,) from ``camera``."""
    distances, directions = _line_of_sight(np.asarray(position, dtype=np.float64)[None], camera)
    return float(distances[0]), directions[0]


def _line_of_sight(positions: np.ndarray, camera: np.ndarray) -> _Sight:
    """Distances (n,) of ``positions`` (n, 3) from ``camera`` and their unit directions."""
    lines = positions - camera
    distances = np.maximum(np.sqrt(np.einsum("ni,ni->n", lines, lines)), _TINY)
    return distances, lines / distances[:, None]


class _Track:
    """An object's state: where its ring of newest rays stands (the rays are in the
    tracker's :class:`_Table`) and what was derived from them."""

    __slots__ = (
        "capacity",
        "coherent",
        "consistent",
        "count",
        "covariance",
        "first_stamp",
        "head",
        "hits",
        "id",
        "last_hit",
        "met",
        "misses",
        "position",
        "resolved",
        "score",
        "size",
        "state",
        "window",
        "window_hits",
        "window_score",
    )

    def __init__(self, track_id: int, capacity: int, window: int, stamp: float) -> None:
        self.id = track_id
        self.state: State = "tentative"
        # Its rays are its ring in the table (_Table.rays): how many it holds and where the
        # next goes.
        self.capacity = capacity
        self.count = 0
        self.head = 0
        self.position = np.zeros(3)
        self.covariance = np.eye(3)
        self.size = 0.0
        self.resolved = False
        self.consistent = True
        self.coherent = True
        # Per in-view frame: hit or miss, and the region's score (0 for a miss).
        self.window: deque[tuple[bool, float]] = deque(maxlen=window)
        self.window_hits = 0  # the window's hits and scores summed (kept with it)
        self.window_score = 0.0
        self.score = 0.0  # its record's score, from window_score (changes with it only)
        self.misses = 0
        self.hits = 0
        # The confirmed object it was last found a second track of (None: none).
        self.met: _Track | None = None
        self.first_stamp = stamp
        self.last_hit = stamp

    def push(self, hit: bool, score: float) -> None:
        """One more in-view frame in the window: hit or miss, and the region's score."""
        window = self.window
        if len(window) == window.maxlen:
            old_hit, old_score = window[0]
            self.window_hits -= old_hit
            self.window_score -= old_score
        window.append((hit, score))
        self.window_hits += hit
        self.window_score += score
        self.score = min(1.0, max(self.window_score, 0.0) / window.maxlen)

    def next_slot(self) -> int:
        """The place in its ring for one more ray, taken (the oldest ray's once full)."""
        slot = self.head
        self.head = (slot + 1) % self.capacity
        self.count = min(self.count + 1, self.capacity)
        return slot


class _Table:
    """The live objects' rays and estimates as arrays, a row per object in the tracker's
    order: what the association and the triangulation read of every object each frame,
    written row by row as objects change (gathered from fifty objects each frame, they cost
    a thirtieth of the frame; a frame's new rays are one write).

    ``rays`` holds each object's ring of its newest ``capacity`` rays, one row of
    _COLUMNS per ray (:func:`_ray_rows`; an empty place has a range interval of 1)."""

    __slots__ = ("capacity", "covariance", "last_hit", "position", "rays", "size")

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.rays = np.zeros((0, capacity, _COLUMNS))
        self.position = np.zeros((0, 3))
        self.covariance = np.zeros((0, 3, 3))
        self.size = np.zeros(0)
        self.last_hit = np.zeros(0)

    def append(self, tracks: Sequence[_Track]) -> None:
        """Rows for new ``tracks``, at the end."""
        if not tracks:
            return
        rings = np.zeros((len(tracks), self.capacity, _COLUMNS))
        rings[..., _LOW] = rings[..., _HIGH] = 1.0
        self.rays = np.concatenate([self.rays, rings])
        self.position = np.concatenate([self.position, [t.position for t in tracks]])
        self.covariance = np.concatenate([self.covariance, [t.covariance for t in tracks]])
        self.size = np.concatenate([self.size, [t.size for t in tracks]])
        self.last_hit = np.concatenate([self.last_hit, [t.last_hit for t in tracks]])

    def keep(self, rows: Sequence[bool]) -> None:
        """Only the ``rows`` set (the objects that go on)."""
        kept = np.asarray(rows, dtype=bool)
        self.rays = self.rays[kept]
        self.position = self.position[kept]
        self.covariance = self.covariance[kept]
        self.size = self.size[kept]
        self.last_hit = self.last_hit[kept]


class ObjectTracker:
    """Track anomalies as objects in the station frame (see the module text).

    Parameters
    ----------
    params : ObjectParams
        The tracker's parameters.
    camera : CameraIntrinsics
        Full-resolution intrinsics of the images the regions are found in.

    Notes
    -----
    Not thread-safe: feed it from one thread, frames in time order (a stamp earlier than
    the last one ends every object and starts over, as a replayed bag does).
    """

    def __init__(self, params: ObjectParams, camera: CameraIntrinsics) -> None:
        if not isinstance(params, ObjectParams):
            raise ObjectsError(f"params must be ObjectParams, got {type(params)}")
        if not isinstance(camera, CameraIntrinsics):
            raise ObjectsError(f"camera must be CameraIntrinsics, got {type(camera)}")
        self.params = params
        self.camera = camera
        self._focal = math.sqrt(camera.fx * camera.fy)
        # The chi-square quantile of the rays' residuals, by degrees of freedom (inf: no test).
        degrees = np.arange(2 * params.max_rays + 1)
        self._chi2_limit = (
            np.full(len(degrees), np.inf)
            if params.residual_quantile >= 1.0
            else chi2.ppf(params.residual_quantile, np.maximum(degrees, 1))
        )
        # A squared gap (in the image or in range), in variances, within which extents meet.
        self._duplicate_limit = float(chi2.ppf(params.duplicate_quantile, 1))
        self._tracks: list[_Track] = []
        self._table = _Table(params.max_rays)  # the rays and estimates of _tracks
        # Confirmed objects that ended, for reacquire_s: id, end stamp and last estimate.
        self._lost: list[tuple[int, float, tuple[np.ndarray, np.ndarray, float]]] = []
        self._next_id = 1
        self._last_stamp: float | None = None

    def reset(self) -> None:
        """Forget every object (ids keep counting up)."""
        self._tracks = []
        self._table = _Table(self.params.max_rays)
        self._lost = []
        self._last_stamp = None

    @property
    def objects(self) -> tuple[TrackedObject, ...]:
        """The live objects after the last frame (no frame's region, not in view)."""
        return tuple(self._record(track, False, None) for track in self._tracks)

    def update(
        self,
        regions: Sequence[Region],
        pose: np.ndarray,
        depth: np.ndarray,
        stamp: float,
        *,
        mask: np.ndarray | None = None,
    ) -> tuple[TrackedObject, ...]:
        """Take one frame; return every live object and those ended by this frame.

        Parameters
        ----------
        regions : sequence of Region
            The detection's regions (:attr:`DetectionResult.regions`), in the camera's
            full-resolution pixels.
        pose : numpy.ndarray
            4x4 camera-to-station pose (optical frame) of the frame.
        depth : numpy.ndarray
            The frame's reference z depth in metres (0 or not finite where space is in
            view), at the reference's resolution (the image's aspect).
        stamp : float
            The frame's time, seconds.
        mask : numpy.ndarray, optional
            The detection mask (the camera's size): a region's range evidence is read only
            under its set pixels.

        Returns
        -------
        tuple of TrackedObject
            Ordered by id.

        Raises
        ------
        ObjectsError
            For a malformed pose, depth, mask, region or stamp (nothing is changed).
        """
        params = self.params
        if (
            isinstance(stamp, bool)
            or not isinstance(stamp, int | float)
            or not math.isfinite(stamp)
        ):
            raise ObjectsError(f"stamp must be a finite number of seconds, got {stamp!r}")
        stamp = float(stamp)
        pose = checked_pose(pose)
        # Not cleaned: what reads the depth takes 0, negative and non-finite as space.
        depth = depth_array(depth)
        reference = depth_camera(self.camera, depth.shape)
        if mask is not None and np.shape(mask) != (self.camera.height, self.camera.width):
            raise ObjectsError(
                f"mask shape {np.shape(mask)} differs from the camera's "
                f"{self.camera.height}x{self.camera.width}"
            )
        observations = observe(
            regions,
            pose,
            self.camera,
            depth,
            mask=mask,
            min_range=params.min_range,
            max_range=params.max_range,
            surface_quantile=params.surface_quantile,
            min_score=min(params.min_region_score, params.hit_region_score),
        )
        ended: list[TrackedObject] = []
        if self._last_stamp is not None and stamp < self._last_stamp:
            ended = [self._record(t, False, None, state="ended") for t in self._tracks]
            self._tracks = []
            self._table = _Table(self.params.max_rays)
            self._lost = []
        self._last_stamp = stamp

        tracks = self._tracks
        table = self._table
        # The centroids' variances along x and y (the association's) and their larger, as an
        # angle (the triangulation's).
        pixel_variance = self._pixel_variances(observations)
        in_view, matches = self._associate(
            table, observations, pixel_variance, pose, depth, reference, stamp
        )
        # Per table row, the index of the region matched with it this frame (None: none).
        region_of: list[int | None] = [None] * len(tracks)
        updated: list[_Track] = []
        updated_rows: list[int] = []  # their rows in the table
        slots: list[int] = []  # where each one's new ray goes in its ring
        new_rays: list[int] = []  # and which observation that is
        ray_rows = _ray_rows(
            observations, pixel_variance.max(axis=1) / self._focal**2, stamp, params.max_range
        )
        scores = observations.scores.tolist()
        indices = observations.indices.tolist()
        for row, j in matches:
            track = tracks[row]
            slots.append(track.next_slot())
            new_rays.append(j)
            track.push(True, scores[j])
            track.misses = 0
            track.hits += 1
            track.last_hit = stamp
            region_of[row] = indices[j]
            updated.append(track)
            updated_rows.append(row)
        table.last_hit[updated_rows] = stamp
        # The objects in view and not matched: a miss each (found in one array operation,
        # not a test per object).
        missed = in_view.copy()
        missed[updated_rows] = False
        for row in missed.nonzero()[0].tolist():
            track = tracks[row]
            track.push(False, 0.0)
            track.misses += 1
        taken = {j for _, j in matches}
        first_new = len(tracks)
        for j in range(len(observations)):
            # Only a region scoring min_region_score starts an object; a fainter one (down to
            # hit_region_score) only continues one.
            if j in taken or scores[j] < params.min_region_score:
                continue
            track = _Track(self._next_id, params.max_rays, params.confirm_window, stamp)
            self._next_id += 1
            slots.append(track.next_slot())
            new_rays.append(j)
            track.push(True, scores[j])
            track.hits = 1
            region_of.append(indices[j])
            tracks.append(track)
            updated.append(track)
        table.append(tracks[first_new:])
        updated_rows += range(first_new, len(tracks))
        table.rays[updated_rows, slots] = ray_rows[new_rays]
        self._refine(updated, updated_rows, stamp)

        # A new object is in view (its region is in the image).
        visible = in_view.tolist()  # Python bools: read once per object below
        visible += [True] * (len(tracks) - len(visible))
        live: list[_Track] = []
        records: list[TrackedObject] = []
        confirmed = [t for t in tracks if t.state == "confirmed"]
        camera = pose[:3, 3]
        # The confirmed objects' lines of sight (built when a candidate first asks).
        confirmed_sights: _Sightings | None = None
        self._lost = [lost for lost in self._lost if stamp - lost[1] <= params.reacquire_s]
        end_misses, timeout = params.end_misses, params.tentative_timeout_s
        confirm_hits = params.confirm_hits
        for track, seen, region in zip(tracks, visible, region_of, strict=True):
            state = track.state
            if track.misses >= end_misses or (
                state == "tentative" and stamp - track.last_hit > timeout
            ):
                if track.state == "confirmed" and params.reacquire_s > 0:
                    estimate = (track.position, track.covariance, track.size)
                    self._lost.append((track.id, stamp, estimate))
                track.state = "ended"
            elif (
                state == "tentative"
                and track.window_hits >= confirm_hits
                and track.resolved
                and track.consistent
                and track.coherent
            ):
                # A track held back as a second track is most often held back by the same
                # object frame after frame: that one is asked first, alone.
                duplicate = self._meets_again(track, confirmed, camera)
                if not duplicate:
                    if confirmed_sights is None:
                        confirmed_sights = self._sightings(confirmed, camera)
                    duplicate = self._duplicate(track, confirmed, confirmed_sights, camera)
                if not duplicate:
                    track.state = "confirmed"
                    confirmed.append(track)
                    confirmed_sights = None  # one more: built again when next asked
                    lost_id = self._reacquired(track, camera)
                    if lost_id is not None:
                        # Its tentative id ends; the object it is goes on under its old one.
                        ended.append(self._record(track, False, None, state="ended"))
                        track.id = lost_id
            record = self._record(track, seen, region)
            if track.state == "ended":
                ended.append(record)
            else:
                live.append(track)
                records.append(record)
        kept = self._within_capacity(live, ended, stamp)
        if len(kept) < len(live):  # the records of those it ended are in ended
            ids = {t.id for t in kept}
            records = [r for r in records if r.id in ids]
        if len(kept) < len(tracks):
            table.keep([t.state != "ended" for t in tracks])
        self._tracks = kept
        return tuple(sorted(records + ended, key=attrgetter("id")))

    # ------------------------------------------------------------------ steps
    def _pixel_variances(self, observations: Observations) -> np.ndarray:
        """(n, 2) each observation's centroid variance along the image's x and y, pixels^2:
        the image edge's share only along the axis across the edge it touches."""
        base = self._centroid_variance(observations.extent_px)
        return base[:, None] + (self.params.edge_sigma_fraction * observations.edge_px) ** 2

    def _associate(
        self,
        table: _Table,
        observations: Observations,
        pixel_variance: np.ndarray,
        pose: np.ndarray,
        depth: np.ndarray,
        reference: CameraIntrinsics,
        stamp: float,
    ) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """Which objects (the ``table``'s) are in view, and the (object row, observation)
        pairs matched (``pixel_variance``: :meth:`_pixel_variances` of the observations)."""
        params = self.params
        count = len(table.size)
        if count == 0:
            return np.zeros(0, dtype=bool), []
        camera = self.camera
        position, covariance, size = table.position, table.covariance, table.size
        age = stamp - table.last_hit
        drift = (params.drift_speed * np.maximum(age, 0.0)) ** 2
        covariance = covariance + drift[:, None, None] * _EYE3
        rotation = pose[:3, :3]
        local = (position - pose[:3, 3]) @ rotation  # camera frame
        z = local[:, 2]
        front = z > params.min_range
        safe_z = np.where(front, z, 1.0)
        u = camera.fx * local[:, 0] / safe_z + camera.cx
        v = camera.fy * local[:, 1] / safe_z + camera.cy
        # d(u, v)/d(station point): the projection's Jacobian in the camera frame, rotated.
        jacobian = np.zeros((count, 2, 3))
        jacobian[:, 0, 0] = camera.fx / safe_z
        jacobian[:, 0, 2] = -camera.fx * local[:, 0] / safe_z**2
        jacobian[:, 1, 1] = camera.fy / safe_z
        jacobian[:, 1, 2] = -camera.fy * local[:, 1] / safe_z**2
        jacobian = jacobian @ rotation.T
        projected = jacobian @ covariance @ jacobian.transpose(0, 2, 1)
        inside = (
            front & (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5) & (v < camera.height - 0.5)
        )
        # Hidden: beyond the surface at its pixel by the margin and 3 sigma of its depth.
        sx, sy = reference.width / camera.width, reference.height / camera.height
        # Clipped with minimum and maximum (numpy.clip's dispatch costs more than both).
        cols = np.minimum(
            np.maximum(np.floor((u + 0.5) * sx).astype(np.int64), 0), reference.width - 1
        )
        rows = np.minimum(
            np.maximum(np.floor((v + 0.5) * sy).astype(np.int64), 0), reference.height - 1
        )
        surface = np.where(inside, depth[rows, cols], 0.0)
        axis = rotation[:, 2]
        depth_sigma = np.sqrt(np.maximum(np.einsum("i,bij,j->b", axis, covariance, axis), 0.0))
        hidden = (surface > 0) & (z > surface + params.occlusion_margin + 3.0 * depth_sigma)
        in_view = inside & ~hidden
        if len(observations) == 0:
            return in_view, []

        # A region cut by the image edge is uncertain across that edge only: along it, its
        # centroid is as good as any (an isotropic spread let an edge region match objects
        # anywhere along the edge).
        du = observations.pixels[None, :, 0] - u[:, None]
        dv = observations.pixels[None, :, 1] - v[:, None]
        # The camera position's noise moves the projection by position_sigma / z radians.
        position_px2 = (params.position_sigma * self._focal / safe_z) ** 2
        s00 = projected[:, None, 0, 0] + position_px2[:, None] + pixel_variance[None, :, 0]
        s11 = projected[:, None, 1, 1] + position_px2[:, None] + pixel_variance[None, :, 1]
        s01 = projected[:, None, 0, 1]
        determinant = s00 * s11 - s01 * s01
        distance2 = (du * du * s11 - 2.0 * du * dv * s01 + dv * dv * s00) / determinant
        expected = np.maximum(size * self._focal / safe_z, 1.0)
        extent = np.maximum(observations.extent_px, 1.0)
        ratio = np.maximum(extent[None, :] / expected[:, None], expected[:, None] / extent[None, :])
        gate = (
            front[:, None] & (distance2 <= params.gate_sigma**2) & (ratio <= params.size_ratio_max)
        )
        if not gate.any():
            return in_view, []
        candidates = gate.any(axis=1).nonzero()[0]
        cost = np.where(gate[candidates], distance2[candidates], _FORBIDDEN)
        rows_, cols_ = linear_sum_assignment(cost)
        objects = candidates[rows_]
        kept = gate[objects, cols_]
        matches = list(zip(objects[kept].tolist(), cols_[kept].tolist(), strict=True))
        return in_view, matches

    def _refine(self, tracks: list[_Track], rows: list[int], stamp: float) -> None:
        """Re-triangulate ``tracks`` (in one batch) and update their derived state, and their
        ``rows`` of the table."""
        if not tracks:
            return
        params = self.params
        capacity = params.max_rays
        batch = len(tracks)
        table, rows_ = self._table, np.array(rows)  # an index array once, read four times
        packed = table.rays[rows_]
        stamps = packed[..., _STAMP]
        counts = np.array([t.count for t in tracks])
        filled = np.arange(capacity)[None, :] < counts[:, None]
        anchor = (np.array([t.head for t in tracks]) - 1) % capacity  # each ring's newest ray
        age = stamp - stamps
        valid = filled & (age <= params.history_s)
        index = np.arange(batch)
        valid[index, anchor] = True
        # The rays that place the object: not those of regions showing a part of it only
        # (_partial); the anchor stays (the triangulation's frame), weightless if partial.
        partial = self._partial(packed, valid, table.position[rows_])
        placing = valid & ~partial
        placing[index, anchor] = True
        variance = np.where(placing, packed[..., _VARIANCE], 1.0)
        variance[index, anchor] = np.where(
            partial[index, anchor], _WEIGHTLESS, variance[index, anchor]
        )
        # Shaped by the ring tables and with each anchor valid (set above): unchecked.
        rays = RayBatch.unchecked(
            origins=packed[..., 0:3],
            directions=packed[..., 3:6],
            angular_variance=variance,
            extra_variance=(params.drift_speed * np.maximum(age, 0.0)) ** 2
            + params.position_sigma**2,
            low=packed[..., _LOW],
            high=packed[..., _HIGH],  # beyond max_range against space (_ray_rows)
            valid=placing,
            anchor=anchor,
        )
        solution = triangulate(rays)
        # Python values, read once (an element read from an array costs as much as a list).
        resolved, consistent = (checks.tolist() for checks in self._range_checks(solution, rays))
        # The residual test gates confirmation only: run where the rest would confirm (a
        # few objects, found in Python).
        coherent = [True] * batch
        candidates = [
            i
            for i, track in enumerate(tracks)
            if track.state == "tentative"
            and track.window_hits >= params.confirm_hits
            and resolved[i]
            and consistent[i]
        ]
        # Sizes in metres from every valid ray, those left out of the position too (the
        # solution's ranges are 0 for those).
        ranges = solution.ranges
        if partial.any():
            ranges = np.where(valid, _ranges_along(solution.position, packed), 0.0)
        sizes_m = packed[..., _EXTENT] / self._focal * ranges
        if candidates:
            which = np.array(candidates)
            tested = self._coherent(solution, rays, counts, which)
            if params.steady_size_ratio < _NO_SIZE_TEST:
                tested &= self._steady(sizes_m, rays, valid, counts, which)
            for i, coherent_ in zip(candidates, tested.tolist(), strict=True):
                coherent[i] = coherent_
        sizes = _row_medians(sizes_m, valid)
        table.position[rows_] = solution.position
        table.covariance[rows_] = solution.covariance
        table.size[rows_] = sizes
        for track, position, covariance, size, resolved_, consistent_, coherent_ in zip(
            tracks,
            solution.position,
            solution.covariance,
            sizes.tolist(),
            resolved,
            consistent,
            coherent,
            strict=True,
        ):
            track.position = position
            track.covariance = covariance
            track.size = size
            track.resolved = resolved_
            track.consistent = consistent_
            track.coherent = coherent_

    def _partial(self, packed: np.ndarray, valid: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """(B, R) bool: which of each object's ``valid`` rays (``packed``: its ring's rows)
        come from a region smaller than its largest region by more than
        ``partial_size_ratio`` (sizes in metres: a region's extent times its range along the
        ray from the object's last estimate, ``positions`` (B, 3); a camera that approaches a
        thing sees one size).

        Such a region shows a part of the thing. Its centroid lies anywhere on the thing
        and, as the detection grows over it, moves across it the same way frame after
        frame: an offset no independent pixel noise describes (no variance makes it average
        out), which the triangulation would read as parallax and place the object metres
        off along its line of sight while its stated spread shrinks. Those rays are left
        out of the position (they still count as hits and for association). An object's
        first ray (no estimate yet) is its largest: none is partial."""
        ratio = self.params.partial_size_ratio
        if ratio >= _NO_SIZE_TEST:
            return np.zeros(valid.shape, dtype=bool)
        ranges = np.maximum(_ranges_along(positions, packed), self.params.min_range)
        sizes = np.where(valid, packed[..., _EXTENT] * ranges, 0.0)
        return valid & (sizes.max(axis=1)[:, None] > ratio * sizes)

    def _steady(
        self,
        sizes: np.ndarray,
        rays: RayBatch,
        valid: np.ndarray,
        counts: np.ndarray,
        which: np.ndarray,
    ) -> np.ndarray:
        """Whether the ``sizes`` (metres across the line of sight, per ray) of each object's
        newest rays (at most ``confirm_window``; only the objects ``which``) lie within
        ``steady_size_ratio`` of each other. A detection that shows a part of a thing and
        grows or shrinks on it moves its centroid on the thing, the same way frame after
        frame: counted as independent pixel noise, that drift passes for parallax and the
        object would be confirmed off its place (metres off along the line of sight where
        the drift runs with the camera's motion). Sizes in metres: an object the camera
        approaches keeps its size. ``valid``: the rays to compare (those of partial regions
        too: the rays' own mask leaves them out of the position)."""
        capacity = valid.shape[1]
        back = np.arange(min(self.params.confirm_window, capacity))
        rows = which[:, None]
        places = (rays.anchor[which, None] - back) % capacity
        recent = (back < counts[rows]) & valid[rows, places]
        newest = sizes[rows, places]
        largest = np.where(recent, newest, 0.0).max(axis=1)
        smallest = np.where(recent, newest, np.inf).min(axis=1)
        return largest <= self.params.steady_size_ratio * smallest

    def _coherent(
        self, solution: Triangulation, rays: RayBatch, counts: np.ndarray, which: np.ndarray
    ) -> np.ndarray:
        """Whether each object's newest rays pass through its estimate as one point's would:
        the sum of their squared angular residuals, each over its variance (the
        triangulation's weights), within the ``residual_quantile`` of a chi-square of
        ``2 n`` degrees of freedom for the newest ``n`` rays (at most ``confirm_window``;
        ``2 n - 3`` when they are all its rays). Regions of different things joined into one
        object (glare that changes shape, a blob's parts) fail it. Only the newest rays
        count: the drift allowed to older ones (``drift_speed``) would absorb their
        scatter. ``counts`` are the rays each object's ring holds; only the objects ``which``
        (indices into the batch) are tested."""
        # The newest rays: the ring's places before its head (the anchor), gathered.
        capacity = rays.valid.shape[1]
        back = np.arange(min(self.params.confirm_window, capacity))
        rows = which[:, None]
        places = (rays.anchor[which, None] - back) % capacity
        recent = (back < counts[rows]) & rays.valid[rows, places]
        offset = solution.position[rows] - rays.origins[rows, places]
        along = solution.ranges[rows, places]
        across2 = np.maximum(np.einsum("brj,brj->br", offset, offset) - along**2, 0.0)
        front = along > 0
        safe = np.where(front, along, 1.0)
        variance = rays.angular_variance[rows, places] * safe**2 + rays.extra_variance[rows, places]
        # A ray the estimate lies behind is as far from it as a ray can be.
        terms = np.where(recent, np.where(front, across2 / variance, np.inf), 0.0)
        count = recent.sum(axis=1)
        dof = 2 * count - np.where(count == rays.valid[which].sum(axis=1), 3, 0)
        limit = self._chi2_limit[np.clip(dof, 0, len(self._chi2_limit) - 1)]
        return (dof < 1) | (terms.sum(axis=1) <= limit)

    def _duplicate(
        self,
        track: _Track,
        confirmed: list[_Track],
        sights: _Sightings,
        camera: np.ndarray,
    ) -> bool:
        """Whether ``track`` is a second track of one of the ``confirmed`` objects (their
        ``sights``), seen from the ``camera`` position (:func:`same_object`); the first it
        meets is kept as ``track.met``. A detection that splits one thing into regions the
        gate keeps apart (a blanket's folds, a wrench's head and handle) starts a second
        track of it; confirmed, it would be a second object where there is one."""
        track.met = None
        if self.params.duplicate_quantile == 0.0:
            return False
        met = np.flatnonzero(self._one_with(track, sights, camera))
        if not len(met):
            return False
        track.met = confirmed[met[0]]
        return True

    def _meets_again(self, track: _Track, confirmed: list[_Track], camera: np.ndarray) -> bool:
        """Whether ``track`` is still a second track of ``track.met``, the confirmed object
        :meth:`_duplicate` found it one of, when that is still among the ``confirmed``: by
        :func:`same_object`'s rule for this one pair in scalars, passed with margins that the
        rounding of the vectorised test cannot cross (so it answers as that test would).
        False where not so sure: the full test decides."""
        other = track.met
        if other is None or self.params.duplicate_quantile == 0.0 or other not in confirmed:
            return False
        limit = self._duplicate_limit
        sights = [_scalar_sight(estimate.position, camera) for estimate in (track, other)]
        (distance, direction), (other_distance, other_direction) = sights
        # In the image: the angle between them less half their angular sizes.
        (x, y, z), (ox, oy, oz) = direction, other_direction
        cosine = x * ox + y * oy + z * oz
        angle = math.acos(min(max(cosine, -1.0), 1.0))
        gap = angle - 0.5 * (track.size / distance + other.size / other_distance)
        # Both directions' noise, as _direction_noise gives it, squared.
        focal2 = self._focal**2
        noise2 = (
            self._centroid_variance(self._focal * track.size / distance)
            + self._centroid_variance(self._focal * other.size / other_distance)
        ) / focal2
        if not _surely_within(gap, _ANGLE_MARGIN, limit * noise2):
            return False
        # In range: the range gap less half their sizes, against the variance along both
        # lines of sight (less a bound on its rounding).
        range_gap = abs(other_distance - distance) - 0.5 * (track.size + other.size)
        variance, rounding = _scalar_variance(direction, track.covariance)
        other_variance, other_rounding = _scalar_variance(other_direction, other.covariance)
        variance += other_variance
        rounding += other_rounding
        margin = _RELATIVE_MARGIN * (distance + other_distance)
        return _surely_within(range_gap, margin, limit * (variance - _RELATIVE_MARGIN * rounding))

    def _reacquired(self, track: _Track, camera: np.ndarray) -> int | None:
        """The id of the object lost within ``reacquire_s`` that ``track`` is
        (:func:`same_object` against its last estimate; the most recently lost first), taken
        off the lost list; None if none."""
        if not self._lost:
            return None
        lost = self._sightings([estimate for _, _, estimate in self._lost], camera)
        found = np.flatnonzero(self._one_with(track, lost, camera))
        if not len(found):
            return None
        lost_id = self._lost[found[-1]][0]
        del self._lost[found[-1]]
        return lost_id

    def _one_with(self, track: _Track, others: _Sightings, camera: np.ndarray) -> np.ndarray:
        """(n,) bool: which of ``others`` ``track`` may be one thing with
        (:func:`same_object`, each direction as noisy as a region of its angular size)."""
        if not len(others.sizes):
            return np.zeros(0, dtype=bool)
        sight = _sight_of(track.position, camera)
        noise = self._direction_noise(track.size / sight[0])
        one = (sight, track.covariance, track.size, noise)
        return _same_object(one, others, self._duplicate_limit)

    def _sightings(
        self,
        estimates: Sequence[_Track] | Sequence[tuple[np.ndarray, np.ndarray, float]],
        camera: np.ndarray,
    ) -> _Sightings:
        """The lines of sight from ``camera`` of tracks, or of (position, covariance, size)
        estimates, with their sizes, direction noises and covariances (kept as given)."""
        rows = [
            (e.position, e.covariance, e.size) if isinstance(e, _Track) else e for e in estimates
        ]
        positions = np.array([r[0] for r in rows]).reshape(-1, 3)
        sizes = np.array([r[2] for r in rows], dtype=np.float64)
        distances, directions = _line_of_sight(positions, camera)
        noises = self._direction_noise(sizes / distances)
        return _Sightings(distances, directions, sizes, noises, [r[1] for r in rows])

    def _direction_noise(self, angular_size: Any) -> Any:
        """The standard deviation, radians, of the direction of a region ``angular_size``
        across (radians): the association's centroid noise (:meth:`_centroid_variance`)."""
        return np.sqrt(self._centroid_variance(self._focal * angular_size)) / self._focal

    def _centroid_variance(self, extent_px: Any) -> Any:
        """A region's centroid variance, pixels^2, for its extent (pixels), away from the
        image's edge: ``pixel_sigma`` and ``extent_sigma_fraction`` of the extent."""
        params = self.params
        return params.pixel_sigma**2 + (params.extent_sigma_fraction * extent_px) ** 2

    def _range_checks(
        self, solution: Triangulation, rays: RayBatch
    ) -> tuple[np.ndarray, np.ndarray]:
        """Whether parallax alone places each object nearer than ``max_range``, and whether
        it places it within the anchor's interval: neither behind the surface nor nearer
        than ``min_range`` (rays that keep their place in the image while the camera turns,
        as a lens flare does, meet at the camera)."""
        params = self.params
        k = params.parallax_sigma
        rho, rho_sigma = solution.free_inverse_range()
        if k == 0:
            resolved = np.ones(len(rho), dtype=bool)
        else:
            resolved = rho - k * rho_sigma > 1.0 / params.max_range
        high = rays.high[np.arange(len(rays.anchor)), rays.anchor]
        # Where the rays leave the range undetermined, they do not say it is behind.
        determined = np.isfinite(rho_sigma)
        farthest = rho + k * np.where(determined, rho_sigma, 0.0)
        behind = determined & (farthest < 1.0 / (high + params.occlusion_margin))
        # Nothing may be nearer than min_range: while the rays' own estimate is, it is not
        # confirmed (no margin of standard deviations, or a thing near the camera, with a
        # wide spread while few rays have seen it, would be confirmed before they agree).
        too_near = determined & (rho > 1.0 / params.min_range)
        return resolved, ~(behind | too_near)

    def _within_capacity(
        self, live: list[_Track], ended: list[TrackedObject], stamp: float
    ) -> list[_Track]:
        """``live`` cut to ``max_objects``, ending the stalest tentative objects first."""
        excess = len(live) - self.params.max_objects
        if excess <= 0:
            return live
        order = sorted(live, key=lambda t: (t.state == "confirmed", t.last_hit, t.id))
        dropped = {t.id for t in order[:excess]}
        for track in order[:excess]:
            track.state = "ended"
            ended.append(self._record(track, False, None))
        return [t for t in live if t.id not in dropped]

    def _record(
        self, track: _Track, in_view: bool, region: int | None, state: State | None = None
    ) -> TrackedObject:
        # Filled without the frozen dataclass's __init__ (a setattr per field): fifty
        # objects a frame made that a tenth of the tracker's time. The fields are the same.
        record = _new_record(TrackedObject)
        _set_fields(
            record,
            "__dict__",
            {
                "id": track.id,
                "state": state or track.state,
                "position": track.position,
                "covariance": track.covariance,
                "size": track.size,
                "score": track.score,
                "range_resolved": track.resolved,
                "in_view": in_view,
                "region": region,
                "hits": track.hits,
                "first_stamp": track.first_stamp,
                "last_hit_stamp": track.last_hit,
            },
        )
        return record
