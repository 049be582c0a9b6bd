"""ALLO sequences as rosbag2 bags, bag replay without ROS, and offline evaluation.

One console script, ``allo-bag``, with five subcommands:

``write``
    A sequence folder (ALLO sequence format v1) becomes a rosbag2 bag (MCAP or SQLite3)
    with the message definitions of ROS 2 Humble, Jazzy or Kilted (:mod:`.writer`).
``info``
    Topics, types, message counts, duration and image sizes of a bag (:mod:`.info`).
``play``
    Publishes a bag over DDS with rclpy at its recorded rate (:mod:`.play`).
``evaluate``, ``ablate``
    Offline evaluation and the paper's Table II sweeps from :mod:`allo_mrad_ros.evaluation`,
    on a sequence folder or a bag (:mod:`.bag_source` reads bags for it).

The topic names (:mod:`allo_mrad_ros.interface`) are also what the detector node
subscribes to; message layouts are in :mod:`.topics` and :mod:`.message_factory`. Nothing
here needs a ROS installation except ``play``, which needs rclpy and the message packages of
the bag's topics.
"""

from rosbag_tools.topics import DEFAULT_TOPICS, DISTROS, TopicNames

__all__ = ["DEFAULT_TOPICS", "DISTROS", "TopicNames"]
