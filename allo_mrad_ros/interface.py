"""The package's ROS interface: topic names, frame ids and image encodings, in one place.

The node subscribes to these inputs, ``allo-bag write``/``play`` record and publish them,
the demo and the test feed publish them, and the launch file remaps them, so a played bag
needs no remapping. Plain strings only: importing this module needs no ROS installation.

=====================  ==================================  ==============================
input                  topic                               type
=====================  ==================================  ==============================
image                  ``/arm_camera/image_raw``           sensor_msgs/Image
camera info            ``/arm_camera/camera_info``         sensor_msgs/CameraInfo
pose (``topic``)       ``/arm_camera/pose``                geometry_msgs/PoseStamped
Sun direction          ``/allo/sun_direction``             geometry_msgs/Vector3Stamped
Sun strength           ``/allo/sun_strength``              std_msgs/Float32
celestial bodies       ``/allo/celestial_bodies``          visualization_msgs/MarkerArray
=====================  ==================================  ==============================

The node subscribes to these names *relative* (``arm_camera/image_raw``): at the root
namespace they are the topics above, under ``namespace:=arm2`` they move with the node.

Outputs are private to the node (``~/score`` 32FC1 with ``~/score/camera_info``, ``~/mask``
mono8, ``~/anomaly`` Bool, ``~/result`` DiagnosticArray and ``~/regions`` ImageMarker stamped
with the image header, ``~/reference`` rgb8 with ``~/reference/camera_info``, ``~/overlay``
rgb8) plus ``/diagnostics``.
"""

from __future__ import annotations

NODE_NAME = "mrad_detector"

# Inputs (also the topics `allo-bag write` records, so a played bag needs no remapping).
IMAGE_TOPIC = "/arm_camera/image_raw"
CAMERA_INFO_TOPIC = "/arm_camera/camera_info"
POSE_TOPIC = "/arm_camera/pose"
SUN_DIRECTION_TOPIC = "/allo/sun_direction"
SUN_STRENGTH_TOPIC = "/allo/sun_strength"
BODIES_TOPIC = "/allo/celestial_bodies"
# Ground truth recorded in bags (not read by the node).
MASK_TOPIC = "/allo/ground_truth/mask"
LABEL_TOPIC = "/allo/ground_truth/label"
# Sequences with ground-truth objects (format version 2): per-pixel object ids, and the
# objects' boxes at each frame's stamp.
INSTANCES_TOPIC = "/allo/ground_truth/instances"
OBJECTS_TOPIC = "/allo/ground_truth/objects"
TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"

# What the node subscribes to: the same names, relative, so they resolve in the node's
# namespace (``/arm2/arm_camera/image_raw`` under ``namespace:=arm2``) and, at the root,
# to the topics above that `allo-bag play` publishes.
IMAGE_INPUT = IMAGE_TOPIC.lstrip("/")
CAMERA_INFO_INPUT = CAMERA_INFO_TOPIC.lstrip("/")
POSE_INPUT = POSE_TOPIC.lstrip("/")
SUN_DIRECTION_INPUT = SUN_DIRECTION_TOPIC.lstrip("/")
SUN_STRENGTH_INPUT = SUN_STRENGTH_TOPIC.lstrip("/")
BODIES_INPUT = BODIES_TOPIC.lstrip("/")
# image_transport's convention: the compressed stream of image topic T is T + "/compressed".
COMPRESSED_SUFFIX = "/compressed"
IMAGE_TRANSPORTS = ("raw", "compressed")

# The node's outputs, relative to its private namespace.
SCORE_OUTPUT = "~/score"
SCORE_INFO_OUTPUT = "~/score/camera_info"
MASK_OUTPUT = "~/mask"
MASK_INFO_OUTPUT = "~/mask/camera_info"
ANOMALY_OUTPUT = "~/anomaly"
REFERENCE_OUTPUT = "~/reference"
OVERLAY_OUTPUT = "~/overlay"
OVERLAY_INFO_OUTPUT = "~/overlay/camera_info"
REFERENCE_INFO_OUTPUT = "~/reference/camera_info"
RESULT_OUTPUT = "~/result"
REGIONS_OUTPUT = "~/regions"
DETECTIONS_OUTPUT = "~/detections"
# Objects in the station frame (vision_msgs/Detection3DArray) and their RViz markers.
OBJECTS_OUTPUT = "~/objects"
OBJECT_MARKERS_OUTPUT = "~/objects/markers"
DIAGNOSTICS_TOPIC = "/diagnostics"

# Frame ids.
STATION_FRAME = "station"
# REP-103/105 naming: <camera>_optical_frame (z forward, x right, y down).
CAMERA_FRAME = "arm_camera_optical_frame"
HARDWARE_ID = "arm_camera"

# Image encodings the package writes.
RGB8 = "rgb8"
MONO8 = "mono8"
SCORE_ENCODING = "32FC1"

# visualization_msgs/Marker constants used for celestial bodies.
MARKER_SPHERE = 2
MARKER_ADD = 0
MARKER_MODIFY = 1
MARKER_DELETE = 2
