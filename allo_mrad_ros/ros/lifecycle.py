"""The managed (lifecycle) variant of ``mrad_detector``: ``mrad_detector_lifecycle``.

Same parameters, topics and diagnostics as the plain node (the default), brought up in steps
so a launch system can order them:

* constructed (unconfigured): parameters declared and validated (an invalid value still
  refuses to start, exit 2);
* configure: loads the station mesh, creates the outputs, diagnostics and pose source and
  starts the processing threads (the render thread builds the renderer for the camera of the
  first camera_info); a bad mesh or QoS override fails the transition with one log line;
* activate: processing starts: the node subscribes to the image and camera_info while an
  output has a subscriber;
* deactivate: unsubscribes the image and camera_info; cleanup stops the threads and removes
  what configure created.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node

from allo_mrad_ros import interface
from allo_mrad_ros.ros.node import MradDetectorNode, run_node
from allo_mrad_ros.ros.parameters import (
    ParameterError,
)


class MradDetectorLifecycleNode(LifecycleNodeMixin, MradDetectorNode):
    """``mrad_detector`` as a managed node (see the module's description of each step)."""

    def __init__(
        self,
        command_line: dict[str, Any] | None = None,
        params_files: dict[Path, list[str]] | None = None,
        **kwargs: Any,
    ) -> None:
        Node.__init__(self, interface.NODE_NAME, **kwargs)
        LifecycleNodeMixin.__init__(self, enable_communication_interface=True)
        MradDetectorNode.__init__(self, command_line, params_files, managed=True)
        self._built: tuple[set, set, set] | None = None

    def _entities(self) -> tuple[set, set, set]:
        return set(self.publishers), set(self.subscriptions), set(self.timers)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        before = self._entities()
        try:
            self._build()
        except ParameterError as error:
            self.get_logger().error(f"configure failed: {error}")
            self._remove_built(before)
            return TransitionCallbackReturn.FAILURE
        self._built = before
        self._stop_inputs()  # inactive: no image is received until activate
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._start_inputs()
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_inputs()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return super().on_shutdown(state)

    def _teardown(self) -> None:
        self._stop_inputs()
        # The pose source is configure's: detached, the next configure's input subscription
        # (made before its new pose source) cannot subscribe this one's topic again.
        self._inputs.pose_source = None
        if self._worker is not None:
            self._worker.stop()
            self._worker = None
        if self._built is not None:
            self._remove_built(self._built)
            self._built = None

    def _remove_built(self, before: tuple[set, set, set]) -> None:
        """Destroy the publishers, subscriptions and timers made since ``before``."""
        publishers, subscriptions, timers = self._entities()
        for publisher in publishers - before[0]:
            self.destroy_publisher(publisher)
        for subscription in subscriptions - before[1]:
            self.destroy_subscription(subscription)
        for timer in timers - before[2]:
            self.destroy_timer(timer)


def main(argv: list[str] | None = None) -> int:
    """Run the managed node until shutdown (``ros2 run allo_mrad_ros mrad_detector_lifecycle``);
    it waits unconfigured for ``ros2 lifecycle set /mrad_detector configure``."""
    return run_node(MradDetectorLifecycleNode, argv)


if __name__ == "__main__":
    sys.exit(main())
