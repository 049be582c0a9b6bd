"""A stand-in of the ``tf2_ros`` Python module, written from tf2's own code and documentation.

tf2_ros has no wheel, so ``pose_source: tf`` is tested against this module (installed into
``sys.modules`` as ``tf2_ros``). It follows, from ros2/geometry2:

* ``tf2/src/buffer_core.cpp``: ``validateFrameId`` (an empty frame id, or one starting with
  '/', is an ``InvalidArgumentException``; an unknown one a ``LookupException``, "does not
  exist"); ``setTransformImpl`` strips a leading '/' from the frames of a stored transform and
  ignores one whose frames are equal or empty; frames of two unconnected trees give a
  ``ConnectivityException``; time 0 means the latest time all links of the chain share.
* ``tf2/src/cache.cpp``: ``TimeCache::findClosest`` (a lone sample serves only its own stamp;
  later than the newest sample is "extrapolation into the future", earlier than the oldest
  "into the past", both ``ExtrapolationException``; in between, translation is interpolated
  linearly and rotation by slerp). Static transforms hold at every time.
* ``tf2_ros_py/tf2_ros/buffer.py``: ``lookup_transform`` is ``can_transform`` with the
  timeout (polling every 20 ms until the transform can be made or the timeout passes), then
  ``lookup_transform_core``, which raises.

``TransformListener`` subscribes to nothing (tf2_msgs has no wheel either): a test stores
transforms with ``Buffer.set_transform`` as the listener would.
"""

from __future__ import annotations

import itertools
import threading
import time as wall
import types

import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.duration import Duration

# tf2's BufferCore keeps 10 s of history by default (BUFFER_CORE_DEFAULT_CACHE_TIME).
DEFAULT_CACHE_S = 10.0
# tf2_ros's default timeout: no wait.
NO_WAIT = Duration()


class TransformException(Exception):
    """Base of every tf2 lookup error."""


class LookupException(TransformException):
    """A frame does not exist."""


class ConnectivityException(TransformException):
    """The frames are in two unconnected trees."""


class ExtrapolationException(TransformException):
    """The time is outside the stored samples."""


class InvalidArgumentException(TransformException):
    """An empty or '/'-prefixed frame id."""


class TimeoutException(TransformException):
    """Raised by the asynchronous waits (not used by ``lookup_transform``)."""


def _matrix(transform) -> np.ndarray:
    t, q = transform.translation, transform.rotation
    x, y, z, w = np.array([q.x, q.y, q.z, q.w]) / np.linalg.norm([q.x, q.y, q.z, q.w])
    matrix = np.eye(4)
    matrix[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    matrix[:3, 3] = [t.x, t.y, t.z]
    return matrix


def _quaternion(rotation: np.ndarray) -> np.ndarray:
    """(x, y, z, w) of a rotation matrix (Shepperd's method, w >= 0 branch first)."""
    m = rotation
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i], q[j], q[k] = s / 4, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
    return np.asarray(q)


def _slerp(q0: np.ndarray, q1: np.ndarray, ratio: float) -> np.ndarray:
    dot = float(np.dot(q0, q1))
    if dot < 0:  # the shorter way round, as tf2::Quaternion::slerp
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + ratio * (q1 - q0)
        return q / np.linalg.norm(q)
    angle = np.arccos(dot)
    return (np.sin((1 - ratio) * angle) * q0 + np.sin(ratio * angle) * q1) / np.sin(angle)


def _interpolate(older: np.ndarray, newer: np.ndarray, ratio: float) -> np.ndarray:
    out = np.eye(4)
    out[:3, 3] = older[:3, 3] + ratio * (newer[:3, 3] - older[:3, 3])
    q = _slerp(_quaternion(older[:3, :3]), _quaternion(newer[:3, :3]), ratio)
    stand_in = types.SimpleNamespace(
        translation=types.SimpleNamespace(x=0.0, y=0.0, z=0.0),
        rotation=types.SimpleNamespace(x=q[0], y=q[1], z=q[2], w=q[3]),
    )
    out[:3, :3] = _matrix(stand_in)[:3, :3]
    return out


def _strip(frame: str) -> str:
    return frame[1:] if frame.startswith("/") else frame


def _seconds(stamp_ns: int) -> str:
    return f"{stamp_ns / 1e9:.6f}"


class Buffer:
    """tf2_ros.Buffer: stores transforms, looks them up at a time, waits up to a timeout."""

    def __init__(self, cache_time: Duration | None = None, node=None) -> None:
        self._cache_ns = (
            cache_time.nanoseconds if cache_time is not None else int(DEFAULT_CACHE_S * 1e9)
        )
        self._lock = threading.Lock()
        # child -> [(stamp_ns, parent, matrix)], oldest first; child -> (parent, matrix).
        self._dynamic: dict[str, list[tuple[int, str, np.ndarray]]] = {}
        self._static: dict[str, tuple[str, np.ndarray]] = {}
        self.lookups: list[tuple[str, str, int, float]] = []

    # --- storing ----------------------------------------------------------------------------

    def set_transform(self, transform: TransformStamped, authority: str) -> bool:
        return self._store(transform, static=False)

    def set_transform_static(self, transform: TransformStamped, authority: str) -> bool:
        return self._store(transform, static=True)

    def _store(self, transform: TransformStamped, static: bool) -> bool:
        parent = _strip(str(transform.header.frame_id))
        child = _strip(str(transform.child_frame_id))
        if not parent or not child or parent == child:
            return False  # tf2 warns and ignores it (TF_SELF_TRANSFORM, TF_NO_FRAME_ID, ...)
        matrix = _matrix(transform.transform)
        stamp = transform.header.stamp.sec * 10**9 + transform.header.stamp.nanosec
        with self._lock:
            if static:
                self._static[child] = (parent, matrix)
                return True
            samples = self._dynamic.setdefault(child, [])
            samples.append((stamp, parent, matrix))
            samples.sort(key=lambda sample: sample[0])
            newest = samples[-1][0]
            samples[:] = [s for s in samples if s[0] >= newest - self._cache_ns]
        return True

    # --- looking up -------------------------------------------------------------------------

    def _frames(self) -> set[str]:
        parents = {p for samples in self._dynamic.values() for _, p, _ in samples}
        return {*self._dynamic, *self._static, *parents, *(p for p, _ in self._static.values())}

    def _validate(self, argument: str, frame: str) -> None:
        if not frame:
            raise InvalidArgumentException(
                f'Invalid argument "{frame}" passed to {argument} - in tf2 frame_ids cannot be '
                "empty"
            )
        if frame.startswith("/"):
            raise InvalidArgumentException(
                f'Invalid argument "{frame}" passed to {argument} - in tf2 frame_ids cannot '
                "start with a '/'"
            )
        if frame not in self._frames():
            raise LookupException(f'"{frame}" passed to {argument} does not exist. ')

    def _chain(self, frame: str) -> list[str]:
        """``frame`` and its ancestors up to its tree's root."""
        chain = [frame]
        while True:
            link = self._static.get(chain[-1]) or (
                (self._dynamic[chain[-1]][-1][1], None) if chain[-1] in self._dynamic else None
            )
            if link is None:
                return chain
            chain.append(link[0])

    def _link(self, child: str, stamp: int) -> np.ndarray:
        """T_parent_child at ``stamp`` (TimeCache::findClosest and interpolate)."""
        if child in self._static:
            return self._static[child][1]
        samples = self._dynamic[child]
        if stamp == 0:
            return samples[-1][2]
        if len(samples) == 1:
            if samples[0][0] == stamp:
                return samples[0][2]
            raise ExtrapolationException(
                f"Lookup would require extrapolation at time {_seconds(stamp)}, but only time "
                f"{_seconds(samples[0][0])} is in the buffer"
            )
        if stamp > samples[-1][0]:
            raise ExtrapolationException(
                "Lookup would require extrapolation into the future.  Requested time "
                f"{_seconds(stamp)} but the latest data is at time {_seconds(samples[-1][0])}"
            )
        if stamp < samples[0][0]:
            raise ExtrapolationException(
                "Lookup would require extrapolation into the past.  Requested time "
                f"{_seconds(stamp)} but the earliest data is at time {_seconds(samples[0][0])}"
            )
        for (t0, _, older), (t1, _, newer) in itertools.pairwise(samples):
            if t0 <= stamp <= t1:
                ratio = 0.0 if t1 == t0 else (stamp - t0) / (t1 - t0)
                return _interpolate(older, newer, ratio)
        raise AssertionError("unreachable")

    def _root_from(self, chain: list[str], stamp: int) -> np.ndarray:
        transform = np.eye(4)
        for child in chain[:-1]:
            transform = self._link(child, stamp) @ transform
        return transform

    def lookup_transform_core(self, target_frame: str, source_frame: str, time) -> TransformStamped:
        with self._lock:
            self._validate("lookupTransform argument target_frame", target_frame)
            self._validate("lookupTransform argument source_frame", source_frame)
            stamp = time.nanoseconds
            target_chain, source_chain = self._chain(target_frame), self._chain(source_frame)
            if target_chain[-1] != source_chain[-1]:
                raise ConnectivityException(
                    f"Could not find a connection between '{target_frame}' and '{source_frame}' "
                    "because they are not part of the same tree.Tf has two or more unconnected "
                    "trees."
                )
            if stamp == 0:  # the latest time every dynamic link of the chain has
                latest = [
                    self._dynamic[f][-1][0]
                    for f in {*target_chain, *source_chain}
                    if f in self._dynamic and f not in self._static
                ]
                stamp = min(latest) if latest else 0
            matrix = np.linalg.inv(self._root_from(target_chain, stamp)) @ self._root_from(
                source_chain, stamp
            )
        msg = TransformStamped()
        msg.header.frame_id, msg.child_frame_id = target_frame, source_frame
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
        t = msg.transform.translation
        t.x, t.y, t.z = (float(v) for v in matrix[:3, 3])
        r = msg.transform.rotation
        r.x, r.y, r.z, r.w = (float(v) for v in _quaternion(matrix[:3, :3]))
        return msg

    def can_transform_core(self, target_frame: str, source_frame: str, time) -> tuple[bool, str]:
        try:
            self.lookup_transform_core(target_frame, source_frame, time)
        except TransformException as error:
            return False, str(error)
        return True, ""

    def can_transform(self, target_frame, source_frame, time, timeout=NO_WAIT) -> bool:
        if timeout != NO_WAIT:
            end = wall.monotonic() + timeout.nanoseconds / 1e9
            while (
                wall.monotonic() < end
                and not self.can_transform_core(target_frame, source_frame, time)[0]
            ):
                wall.sleep(0.02)
        return self.can_transform_core(target_frame, source_frame, time)[0]

    def lookup_transform(self, target_frame, source_frame, time, timeout=NO_WAIT):
        self.lookups.append(
            (target_frame, source_frame, time.nanoseconds, timeout.nanoseconds / 1e9)
        )
        self.can_transform(target_frame, source_frame, time, timeout)
        return self.lookup_transform_core(target_frame, source_frame, time)


class TransformListener:
    """Keeps the buffer it is given; subscribes to nothing (no tf2_msgs wheel)."""

    def __init__(self, buffer: Buffer, node, *args, **kwargs) -> None:
        self.buffer, self.node = buffer, node


def module() -> types.ModuleType:
    """A fresh ``tf2_ros`` module made of this stand-in."""
    made = types.ModuleType("tf2_ros")
    for name in (
        "TransformException",
        "LookupException",
        "ConnectivityException",
        "ExtrapolationException",
        "InvalidArgumentException",
        "TimeoutException",
        "Buffer",
        "TransformListener",
    ):
        setattr(made, name, globals()[name])
    return made
