"""The ROS 2 edge of the package: the ``mrad_detector`` node and its message conversions.

Only this subpackage (and ``rosbag_tools``) imports rclpy and message packages; the
detector core knows nothing of ROS.
"""
