"""What the node needs of rclpy that rclpy keeps private, read in this one place.

rclpy holds a node's parameter overrides (``--ros-args -p``, ``--params-file`` and the
``parameter_overrides`` argument) in ``Node._parameter_overrides`` and offers no public
accessor for them in any distribution from Humble to Kilted (rclcpp's
``get_parameter_overrides`` has no rclpy twin). The node reads them to name the value a user
gave when rclpy refuses to declare it, to warn about an override that names no parameter, and
to refuse a ``qos_overrides.*`` override that nothing applied. ``test/ros/test_rclpy_compat.py``
checks this module against the rclpy installed (the CI's Kilted wheels; a venv without rclpy
skips it), so a change of rclpy shows there, not as a wrong value in the node.

It also says what differs between the distributions the node runs on: a publisher's
``matched`` event (rclpy of Iron and later: Jazzy, Kilted), which Humble's rclpy lacks
(:func:`matched_event_callbacks`); and, from Iron on, rclpy passes a subscription callback
of two arguments the message info (the middleware's source and reception timestamps, which
time a frame from its publication), where Humble's passes none (:func:`message_info_callback`).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any

from allo_mrad_ros.errors import BackendError


class RclpyCompatError(BackendError):
    """The installed rclpy does not keep what this module reads where it expects it."""


def parameter_overrides(node: Any) -> Mapping[str, Any]:
    """The parameter overrides rclpy applies to ``node``'s declarations: name to
    ``rclpy.parameter.Parameter``, read-only.

    Raises
    ------
    RclpyCompatError
        Where this rclpy keeps no mapping ``Node._parameter_overrides``.
    """
    overrides = getattr(node, "_parameter_overrides", None)
    if not isinstance(overrides, Mapping):
        raise RclpyCompatError(
            f"this rclpy keeps no parameter overrides where allo_mrad_ros reads them "
            f"(Node._parameter_overrides is {type(overrides).__name__}); "
            "allo_mrad_ros.ros.rclpy_compat must learn where it keeps them now"
        )
    return MappingProxyType(overrides)


def matched_event_callbacks(on_matched: Callable[[Any], None]) -> Any | None:
    """Publisher event callbacks that call ``on_matched`` each time a subscription matches
    or leaves the publisher, where this rclpy has the publishers' matched event
    (``PublisherEventCallbacks(matched=...)``, Iron and later); None where it has not
    (Humble), so the caller polls ``get_subscription_count`` instead.

    The other events keep rclpy's default callbacks (the incompatible QoS warning).
    """
    try:
        from rclpy.event_handler import PublisherEventCallbacks
    except ImportError:  # Humble keeps them in rclpy.qos_event
        from rclpy.qos_event import PublisherEventCallbacks
    if "matched" not in inspect.signature(PublisherEventCallbacks).parameters:
        return None
    return PublisherEventCallbacks(matched=on_matched)


def message_info_callback(
    callback: Callable[[Any, Mapping[str, int] | None], None],
) -> Callable[..., None]:
    """A subscription callback that calls ``callback(msg, info)``: ``info`` is rclpy's
    message info (``source_timestamp``, ``received_timestamp``, ns on the system clock)
    where rclpy passes one, else None."""
    from rclpy.subscription import Subscription

    if hasattr(Subscription, "CallbackType"):  # rclpy tells the two kinds of callback apart
        return lambda msg, info: callback(msg, info)
    return lambda msg: callback(msg, None)
