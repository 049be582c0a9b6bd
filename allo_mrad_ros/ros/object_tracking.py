"""The node's object tracker: one :class:`~allo_mrad_ros.objects.ObjectTracker` fed frame by
frame from the thread that detects, started over when what it was built for changes.

The tracker is built for one camera (the image's full-resolution intrinsics: the detector's
regions are in the image's pixels, whatever ``mrad.process_scale``) and one set of
``objects.*`` parameters. A new camera_info, a parameter change, or a frame after frames
that were not tracked (no one subscribed to the objects) starts a new one: its objects
would otherwise carry rays of another camera or a gap the drift allowance does not cover.
The objects it held are reported ended, so ``~/objects/markers`` deletes them. An image
stamp earlier than the last one (a bag replayed from its start) ends every object inside the
tracker itself. Ids keep counting up across new trackers, so an id names one object for the
node's life.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.regions import Region
from allo_mrad_ros.objects import ObjectParams, ObjectTracker, TrackedObject


@dataclass(frozen=True)
class ObjectsUpdate:
    """One frame's objects: the live ones and those ended by this frame, by id.

    Attributes
    ----------
    objects : tuple of TrackedObject
        Tentative, confirmed, and ``ended`` ones (reported once, in the frame they end).
    tracker_ms : float
        The tracker's time for this frame.
    """

    objects: tuple[TrackedObject, ...]
    tracker_ms: float

    @property
    def anomalous(self) -> bool:
        """``decision: objects``: whether a confirmed object is in view."""
        return any(o.state == "confirmed" and o.in_view for o in self.objects)

    def count(self, state: str) -> int:
        """How many objects are in ``state``."""
        return sum(o.state == state for o in self.objects)


class ObjectTracking:
    """The tracker across frames (see the module text). Not thread-safe: one thread feeds it."""

    def __init__(self) -> None:
        self._tracker: ObjectTracker | None = None
        self._tracked_last = False
        # Added to the tracker's ids: the largest id reported by the trackers before it.
        self._id_base = 0
        self._largest_id = 0

    @property
    def tracker(self) -> ObjectTracker | None:
        """The tracker in use (None before the first tracked frame)."""
        return self._tracker

    def skip(self) -> None:
        """A frame was processed without tracking: the next tracked one starts over."""
        self._tracked_last = False

    def update(
        self,
        *,
        camera: CameraIntrinsics,
        params: ObjectParams,
        regions: Sequence[Region],
        pose: np.ndarray,
        depth: np.ndarray,
        stamp: float,
        mask: np.ndarray | None = None,
    ) -> ObjectsUpdate:
        """Track one frame (arguments as :meth:`ObjectTracker.update`; ``camera``: the
        image's full-resolution intrinsics).

        Raises
        ------
        ObjectsError
            For a malformed input (from the tracker; nothing is changed).
        """
        dropped: tuple[TrackedObject, ...] = ()
        tracker = self._tracker
        if (
            tracker is None
            or not self._tracked_last
            or tracker.camera != camera
            or tracker.params != params
        ):
            if tracker is not None:
                dropped = tuple(
                    replace(o, state="ended", in_view=False, region=None)
                    for o in self._numbered(tracker.objects)
                )
            self._id_base = self._largest_id
            tracker = self._tracker = ObjectTracker(params, camera)
        start = time.perf_counter()
        objects = tracker.update(regions, pose, depth, stamp, mask=mask)
        tracker_ms = 1e3 * (time.perf_counter() - start)
        self._tracked_last = True
        numbered = self._numbered(objects)
        if numbered:
            self._largest_id = max(self._largest_id, max(o.id for o in numbered))
        return ObjectsUpdate(dropped + numbered, tracker_ms)

    def _numbered(self, objects: Sequence[TrackedObject]) -> tuple[TrackedObject, ...]:
        if self._id_base == 0:
            return tuple(objects)
        return tuple(replace(o, id=o.id + self._id_base) for o in objects)
