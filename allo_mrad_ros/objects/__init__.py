"""Anomalies as objects in the station frame: range evidence from one frame, triangulation
over frames, and a tracker that confirms and ends objects (no ROS; NumPy and SciPy only).

:class:`ObjectTracker` takes each frame's detection regions, camera pose and reference
depth (``docs/objects.md``).
"""

from allo_mrad_ros.objects.params import ObjectParams, ObjectsError
from allo_mrad_ros.objects.rays import RegionRays, region_rays
from allo_mrad_ros.objects.tracker import ObjectTracker, TrackedObject
from allo_mrad_ros.objects.triangulation import RayBatch, Triangulation, triangulate

__all__ = [
    "ObjectParams",
    "ObjectTracker",
    "ObjectsError",
    "RayBatch",
    "RegionRays",
    "TrackedObject",
    "Triangulation",
    "region_rays",
    "triangulate",
]
