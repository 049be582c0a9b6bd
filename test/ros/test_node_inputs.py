"""The node's inputs on their own: which Sun lights a frame when a parameter and a topic
both give one."""

import dataclasses

import numpy as np
import pytest
from rclpy.qos_overriding_options import QoSOverridingOptions
from std_msgs.msg import Float32

from allo_mrad_ros.ros.inputs import NodeInputs
from allo_mrad_ros.ros.parameters import detector_parameters, node_config_from, node_parameters

pytestmark = pytest.mark.ros


def _config(**changes):
    declared = {**node_parameters(False), **detector_parameters()}
    config = node_config_from({name: p.default for name, p in declared.items()})
    return dataclasses.replace(config, **changes)


def test_a_sun_parameter_applies_until_a_sun_topic_has_given_one():
    # Parameters, the Sun strength callback and snapshots never reach the node.
    inputs = NodeInputs(
        object(),
        _config(sun_direction=(0.0, 0.0, 1.0), sun_strength=1.0),
        lambda: True,
        QoSOverridingOptions.with_default_policies,
    )
    inputs.configure(_config(sun_direction=(0.0, 1.0, 0.0), sun_strength=2.0))
    state = inputs.snapshot()
    assert np.allclose(state.sun_direction, (0.0, 1.0, 0.0)) and state.sun_strength == 2.0
    inputs.on_sun_strength(Float32(data=3.0))
    inputs.configure(_config(sun_direction=(1.0, 0.0, 0.0), sun_strength=4.0))
    state = inputs.snapshot()
    assert np.allclose(state.sun_direction, (0.0, 1.0, 0.0)) and state.sun_strength == 3.0
    assert state.config.sun_strength == 4.0  # the settings themselves are the new ones
    assert np.allclose(inputs.sun_direction, (0.0, 1.0, 0.0))
