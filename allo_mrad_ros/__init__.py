"""allo_mrad_ros: model-reference anomaly detection for space-station proximity operations.

The detector core (:mod:`allo_mrad_ros.detector`) is pure NumPy/OpenCV and knows nothing of
ROS; ROS lives at the edges (the node, the bag tools).
"""

__version__ = "0.1.0"
