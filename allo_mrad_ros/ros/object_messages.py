"""The tracked objects as messages: ``~/objects`` (vision_msgs/Detection3DArray) and
``~/objects/markers`` (visualization_msgs/MarkerArray for RViz), both in the station frame.

``~/objects`` holds the confirmed objects only: a consumer acts on it. The markers show every
live object, coloured by state, so a viewer sees an object from its first view to its
confirmation, and delete an object in the frame it ends.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import Point, Quaternion, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from allo_mrad_ros.geometry import matrix_to_quaternion
from allo_mrad_ros.objects import TrackedObject

# class_id of every hypothesis, ~/objects' and ~/detections'.
ANOMALY_CLASS = "anomaly"
# Marker namespaces: the object, its uncertainty, its label, and the station model.
OBJECT_NS = "mrad_objects"
UNCERTAINTY_NS = "mrad_object_uncertainty"
LABEL_NS = "mrad_object_ids"
STATION_NS = "mrad_station"
OBJECT_NAMESPACES = (OBJECT_NS, UNCERTAINTY_NS, LABEL_NS)
STATE_COLOURS = {
    "tentative": ColorRGBA(r=1.0, g=0.8, b=0.1, a=0.5),
    "confirmed": ColorRGBA(r=1.0, g=0.15, b=0.15, a=0.9),
}
UNCERTAINTY_COLOUR = ColorRGBA(r=0.3, g=0.6, b=1.0, a=0.25)
LABEL_COLOUR = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
# The uncertainty ellipsoid's half-axes: this many standard deviations along each principal
# axis of the position's covariance.
UNCERTAINTY_SIGMAS = 3.0
# Smallest marker side (m), so an object of unknown or tiny size stays visible.
MIN_MARKER_M = 0.05
LABEL_HEIGHT_M = 0.3


def _point(position: np.ndarray) -> Point:
    return Point(x=float(position[0]), y=float(position[1]), z=float(position[2]))


def _size(obj: TrackedObject) -> float:
    """The object's size in metres, 0 where the tracker has none yet."""
    size = float(obj.size)
    return size if math.isfinite(size) and size > 0 else 0.0


def pose_covariance(covariance: np.ndarray) -> list[float]:
    """A geometry_msgs/PoseWithCovariance covariance (6x6 row-major: x, y, z, then the three
    rotations) holding a 3x3 position covariance; the rotations' block is zero (unknown)."""
    full = np.zeros((6, 6))
    full[:3, :3] = np.asarray(covariance, float)
    return [float(v) for v in full.ravel()]


def anomaly_hypothesis(msg: Any, score: float) -> Any:
    """One vision_msgs/ObjectHypothesisWithPose of class ``anomaly`` with ``score`` (its
    pose left default); ``msg`` is the module of the message classes."""
    hypothesis = msg.ObjectHypothesisWithPose()
    hypothesis.hypothesis.class_id = ANOMALY_CLASS
    hypothesis.hypothesis.score = float(score)
    return hypothesis


def object_array(msg: Any, header: Header, objects: Sequence[TrackedObject]) -> Any:
    """A vision_msgs/Detection3DArray of the confirmed ``objects``, in ``header``'s frame
    (the station frame): per object its box (centre: its position; a cube of its size), id
    (``str(object id)``, stable for its life) and one hypothesis, class ``anomaly``, its
    score in [0, 1], its position with covariance. ``msg`` is the module of the classes."""
    detections = []
    for obj in objects:
        if obj.state != "confirmed":
            continue
        detection = msg.Detection3D()
        detection.header = header
        detection.id = str(obj.id)
        detection.bbox.center.position = _point(obj.position)
        detection.bbox.center.orientation.w = 1.0
        size = _size(obj)
        detection.bbox.size = Vector3(x=size, y=size, z=size)
        hypothesis = anomaly_hypothesis(msg, min(max(obj.score, 0.0), 1.0))
        hypothesis.pose.pose.position = _point(obj.position)
        hypothesis.pose.pose.orientation.w = 1.0
        hypothesis.pose.covariance = pose_covariance(obj.covariance)
        detection.results = [hypothesis]
        detections.append(detection)
    return msg.Detection3DArray(header=header, detections=detections)


def ellipsoid(
    covariance: np.ndarray, sigmas: float = UNCERTAINTY_SIGMAS
) -> tuple[Quaternion, Vector3]:
    """The orientation and the diameters of the ellipsoid ``sigmas`` standard deviations
    along each principal axis of a 3x3 covariance (an RViz SPHERE's pose and scale)."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + np.transpose(covariance)))
    if np.linalg.det(vectors) < 0:  # a rotation, not a reflection
        vectors[:, 2] = -vectors[:, 2]
    q = matrix_to_quaternion(vectors)
    diameters = 2.0 * sigmas * np.sqrt(np.maximum(values, 0.0))
    diameters = np.maximum(diameters, 1e-3)
    return (
        Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        Vector3(x=float(diameters[0]), y=float(diameters[1]), z=float(diameters[2])),
    )


def _marker(header: Header, ns: str, marker_id: int, kind: int) -> Marker:
    marker = Marker(header=header, ns=ns, id=marker_id, type=kind, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    return marker


def object_markers(
    header: Header,
    objects: Sequence[TrackedObject],
    *,
    station_mesh: str = "",
    changed_only: bool = False,
) -> MarkerArray:
    """RViz markers of ``objects`` in ``header``'s frame (the station frame).

    Per live object: a sphere at its position as wide as its size, coloured by state
    (tentative yellow, confirmed red); its uncertainty, an ellipsoid of
    :data:`UNCERTAINTY_SIGMAS` standard deviations along each principal axis of its
    position's covariance; and its id and state as text above it (a tentative object whose
    range parallax has not yet resolved says so: it waits for the camera to move). An ended
    object's three markers are
    deleted. ``station_mesh``: a ``file://`` or ``package://`` URI of the station model,
    drawn first (with its own materials) so the objects are seen on it; empty: none.
    ``changed_only``: only the objects a region hit this frame (the only ones whose position,
    size or state changed) and the ended ones: RViz keeps the others' markers as they were.
    """
    markers = []
    if station_mesh:
        station = _marker(header, STATION_NS, 0, Marker.MESH_RESOURCE)
        station.mesh_resource = station_mesh
        station.mesh_use_embedded_materials = True  # a colour of all zeros keeps them
        station.scale = Vector3(x=1.0, y=1.0, z=1.0)
        markers.append(station)
    for obj in objects:
        if changed_only and obj.region is None and obj.state != "ended":
            continue
        if obj.state == "ended":
            for ns in OBJECT_NAMESPACES:
                markers.append(Marker(header=header, ns=ns, id=obj.id, action=Marker.DELETE))
            continue
        side = max(_size(obj), MIN_MARKER_M)
        sphere = _marker(header, OBJECT_NS, obj.id, Marker.SPHERE)
        sphere.pose.position = _point(obj.position)
        sphere.scale = Vector3(x=side, y=side, z=side)
        sphere.color = STATE_COLOURS.get(obj.state, STATE_COLOURS["tentative"])
        spread = _marker(header, UNCERTAINTY_NS, obj.id, Marker.SPHERE)
        spread.pose.position = _point(obj.position)
        spread.pose.orientation, spread.scale = ellipsoid(obj.covariance)
        spread.color = UNCERTAINTY_COLOUR
        label = _marker(header, LABEL_NS, obj.id, Marker.TEXT_VIEW_FACING)
        label.pose.position = _point(np.asarray(obj.position) + np.array([0.0, 0.0, side]))
        label.scale.z = LABEL_HEIGHT_M
        label.color = LABEL_COLOUR
        label.text = f"{obj.id} {obj.state}"
        if obj.state == "tentative" and not obj.range_resolved:
            # What it waits for: the arm to move far enough for parallax to place it.
            label.text += ", range unresolved"
        markers += [sphere, spread, label]
    return MarkerArray(markers=markers)
