"""The launch file names only things the package installs; the config file is valid."""

import ast
import importlib
import importlib.util
import re
from pathlib import Path

import pytest
import yaml

from allo_mrad_ros.ros.parameters import declared_parameters, detector_parameters, validate

REPO = Path(__file__).resolve().parent.parent
LAUNCH_FILE = REPO / "launch" / "detect.launch.py"


def console_scripts():
    text = (REPO / "setup.py").read_text()
    return dict(re.findall(r'"([\w-]+) = ([\w.]+:\w+)"', text))


def launch_tree():
    return ast.parse(LAUNCH_FILE.read_text())


def node_calls(tree):
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, "id", None) in (
            "Node",
            "LifecycleNode",
        ):
            yield {k.arg: k.value for k in call.keywords}


def test_every_executable_of_this_package_is_an_installed_console_script():
    pytest.importorskip("rclpy", reason="the node module needs rclpy")
    scripts = console_scripts()
    names = []
    for keywords in node_calls(launch_tree()):
        package = keywords["package"]
        if isinstance(package, ast.Name) and package.id == "PACKAGE":
            executable = keywords["executable"].value
            names.append(executable)
            assert executable in scripts, f"{executable} is not a console script in setup.py"
            module, function = scripts[executable].split(":")
            assert hasattr(importlib.import_module(module), function)
    assert sorted(names) == ["mrad_detector", "mrad_detector_lifecycle"]


def test_every_package_file_the_launch_file_names_exists_and_is_installed():
    tree = launch_tree()
    named = []
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, "id", None) == "PathJoinSubstitution":
            parts = [e.value for e in call.args[0].elts if isinstance(e, ast.Constant)]
            named.append(Path(*parts))
    assert Path("config", "mrad.yaml") in named and Path("config", "mrad.rviz") in named
    setup = (REPO / "setup.py").read_text()
    for path in named:
        assert (REPO / path).is_file(), path
        assert f'_files("{path.parts[0]}/*")' in setup, f"{path.parts[0]}/ is not installed"


def flatten(parameters, prefix=""):
    for key, value in parameters.items():
        if isinstance(value, dict):
            yield from flatten(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def test_config_file_sets_only_declared_parameters_with_valid_values():
    document = yaml.safe_load((REPO / "config" / "mrad.yaml").read_text())
    values = dict(flatten(document["/**"]["ros__parameters"]))
    declared = declared_parameters(tf_available=True)
    assert set(values) == set(declared)
    for name, value in values.items():
        validate(name, declared[name], value)
    for name, parameter in detector_parameters().items():
        assert values[name] == parameter.default, f"{name}: config and library defaults differ"
    for name in ("reference_scale", "shadows"):
        assert values[name] == declared[name].default, f"{name}: config and node defaults differ"


@pytest.mark.skipif(
    importlib.util.find_spec("launch_ros") is None, reason="launch_ros needs a ROS 2 distro"
)
def test_generate_launch_description_loads():
    spec = importlib.util.spec_from_file_location("detect_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    assert len(description.entities) >= 2


class _Recorded:
    """Stands in for a launch class: keeps its arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _LaunchConfiguration(_Recorded):
    def perform(self, context):
        return context[self.args[0]]


class _DeclareLaunchArgument(_Recorded):
    """Stands in for launch's DeclareLaunchArgument, refusing what the real one refuses: an
    empty ``choices``, a plain default that is not one of them (at construction) and a given
    value that is not one of them, compared exactly (:meth:`check`, as its ``execute``)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        choices = kwargs.get("choices")
        if choices is not None:
            if not choices:
                raise RuntimeError("Provided choices arg is empty.")
            default = kwargs.get("default_value")
            if isinstance(default, str) and default not in choices:
                raise RuntimeError(f'Provided default_value "{default}" is not in choices')

    def check(self, value):
        choices = self.kwargs.get("choices")
        if choices is not None and value not in choices:
            raise RuntimeError(
                f'Argument "{self.args[0]}" provided value "{value}" is not valid. Valid '
                f"options are: {choices}"
            )


class _Node(_Recorded):
    """Stands in for launch_ros's Node: keyword arguments only, as the real one takes."""

    is_lifecycle_node = False

    def __init__(self, *args, **kwargs):
        if args:
            raise TypeError("Node() takes keyword arguments only")
        super().__init__(**kwargs)


class _LifecycleNode(_Node):
    """launch_ros's LifecycleNode: a ``name`` is required (Jazzy and later), and Humble's
    takes ``namespace`` as a required keyword too."""

    is_lifecycle_node = True

    def __init__(self, **kwargs):
        if kwargs.get("name") is None:
            raise RuntimeError("'name' must not be None.'")
        if "namespace" not in kwargs:
            raise TypeError("LifecycleNode() missing required keyword argument: 'namespace'")
        super().__init__(**kwargs)


# lifecycle_msgs' Transition ids and the state labels rcl_lifecycle publishes in its
# TransitionEvent (what OnStateTransition compares start_state and goal_state with).
TRANSITIONS = {"configure": 1, "cleanup": 2, "activate": 3, "deactivate": 4}
VALID_TRANSITION_IDS = range(0, 9)  # ChangeState.valid_transitions: CREATE (0) to DESTROY (8)
STATE_LABELS = {
    "unknown", "unconfigured", "inactive", "active", "finalized", "configuring", "cleaningup",
    "shuttingdown", "activating", "deactivating", "errorprocessing",
}  # fmt: skip


class _ChangeState:
    """launch_ros.events.lifecycle.ChangeState: keyword-only, refuses an unknown transition
    id with ValueError, as the real event does."""

    def __init__(self, *, lifecycle_node_matcher, transition_id):
        if transition_id not in VALID_TRANSITION_IDS:
            raise ValueError(f"given transition_id of '{transition_id}'")
        self.lifecycle_node_matcher, self.transition_id = lifecycle_node_matcher, transition_id


class _EmitEvent:
    """launch.actions.EmitEvent(*, event): the event is required by keyword."""

    def __init__(self, *, event):
        self.event = event


class _OnStateTransition:
    """launch_ros.event_handlers.OnStateTransition: refuses a target that is not a lifecycle
    node (RuntimeError, as the real one) and matches a transition as the real one does:
    each of target, start_state and goal_state given must equal the event's. A state label
    rcl never publishes is refused too: the real handler would silently never fire."""

    def __init__(self, *, entities, target_lifecycle_node=None, start_state=None, goal_state=None):
        if target_lifecycle_node is not None and not target_lifecycle_node.is_lifecycle_node:
            raise RuntimeError('OnStateTransition requires a "LifecycleNode" action as the target')
        for label in (start_state, goal_state):
            if label is not None and label not in STATE_LABELS:
                raise ValueError(f"{label!r} is no state label rcl_lifecycle publishes")
        self.entities, self.target = entities, target_lifecycle_node
        self.start_state, self.goal_state = start_state, goal_state

    def matches(self, action, start_state, goal_state):
        return (
            (self.target is None or action is self.target)
            and (self.start_state is None or self.start_state == start_state)
            and (self.goal_state is None or self.goal_state == goal_state)
        )


class _RegisterEventHandler:
    def __init__(self, event_handler):
        self.event_handler = event_handler


def _launch_module(monkeypatch):
    """detect.launch.py executed against stand-ins of launch and launch_ros."""
    import sys
    import types

    names = {
        "launch": {"LaunchDescription": _Recorded},
        "launch.actions": {
            "DeclareLaunchArgument": _DeclareLaunchArgument,
            "OpaqueFunction": _Recorded,
            "EmitEvent": _EmitEvent,
            "RegisterEventHandler": _RegisterEventHandler,
        },
        "launch.conditions": {"IfCondition": _Recorded},
        # launch.events.matches_action: a matcher true for the one action given.
        "launch.events": {"matches_action": lambda target: lambda action: action is target},
        "launch.substitutions": {
            "LaunchConfiguration": _LaunchConfiguration,
            "PathJoinSubstitution": _Recorded,
        },
        "launch_ros.actions": {"Node": _Node, "LifecycleNode": _LifecycleNode},
        "launch_ros.event_handlers": {"OnStateTransition": _OnStateTransition},
        "launch_ros.events.lifecycle": {"ChangeState": _ChangeState},
        "launch_ros.substitutions": {"FindPackageShare": _Recorded},
    }
    try:
        import lifecycle_msgs.msg  # noqa: F401  (the real ids, where ROS messages are installed)
    except ImportError:
        transition = type(
            "Transition", (), {f"TRANSITION_{k.upper()}": v for k, v in TRANSITIONS.items()}
        )
        names["lifecycle_msgs.msg"] = {"Transition": transition}
        monkeypatch.setitem(sys.modules, "lifecycle_msgs", types.ModuleType("lifecycle_msgs"))
    monkeypatch.setitem(sys.modules, "launch_ros", types.ModuleType("launch_ros"))
    for name, attributes in names.items():
        module = types.ModuleType(name)
        module.__dict__.update(attributes)
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("detect_launch_stubbed", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def launched_entities(monkeypatch, **given):
    """The actions the launch file makes when the user gives ``given`` arguments."""
    module = _launch_module(monkeypatch)
    description = module.generate_launch_description()
    declared = {}
    arguments = [e for e in description.args[0] if isinstance(e, _DeclareLaunchArgument)]
    for entity in arguments:
        declared[entity.args[0]] = entity.kwargs["default_value"]
    opaque = description.args[0][-1]
    context = {name: default for name, default in declared.items()}
    context["config"] = "/home/user/my.yaml"
    context.update(given)
    for entity in arguments:  # what `ros2 launch` checks before any node is made
        entity.check(context[entity.args[0]])
    return declared, opaque.kwargs["function"](context)


def launched_nodes(monkeypatch, **given):
    """The node actions' arguments the launch file makes when the user gives ``given``."""
    declared, entities = launched_entities(monkeypatch, **given)
    detector, rviz = entities[:2]
    return declared, detector.kwargs, rviz.kwargs


def test_launch_forwards_no_parameter_over_the_config_when_no_argument_is_given(monkeypatch):
    declared, detector, rviz = launched_nodes(monkeypatch)
    assert detector["parameters"] == ["/home/user/my.yaml"]
    assert detector["remappings"] == []
    assert detector["namespace"] == "" and rviz["namespace"] == ""
    assert rviz["parameters"] == []
    for name in ("mesh", "pose_source", "use_sim_time", "image_transport", "image_topic"):
        assert declared[name] == "", f"{name} has a launch default that would override"


def test_launch_forwards_exactly_the_arguments_given(monkeypatch):
    _, detector, rviz = launched_nodes(
        monkeypatch,
        pose_source="topic",
        use_sim_time="true",
        namespace="arm2",
        image_topic="/cam/image_rect",
        bodies_topic="/allo/celestial_bodies",
    )
    config, overrides = detector["parameters"]
    assert config == "/home/user/my.yaml"
    assert overrides == {"pose_source": "topic", "use_sim_time": True}
    assert detector["namespace"] == "arm2" and rviz["namespace"] == "arm2"
    assert rviz["parameters"] == [{"use_sim_time": True}]
    assert sorted(detector["remappings"]) == [
        ("allo/celestial_bodies", "/allo/celestial_bodies"),
        ("arm_camera/image_raw", "/cam/image_rect"),
    ]


def test_a_value_real_launch_refuses_is_refused_by_the_stand_in(monkeypatch):
    # Real launch compares a given value with the declared choices exactly: "True" is not
    # "true" (launch/actions/declare_launch_argument.py, DeclareLaunchArgument.execute).
    for name, value in (("use_sim_time", "True"), ("rviz", "yes"), ("respawn", "True")):
        with pytest.raises(RuntimeError, match=f'Argument "{name}" provided value "{value}"'):
            launched_nodes(monkeypatch, **{name: value})
    with pytest.raises(RuntimeError, match="not in choices"):
        _DeclareLaunchArgument("x", default_value="maybe", choices=["true", "false"])


def test_a_boolean_argument_that_is_not_true_or_false_is_refused_by_name():
    # Behind launch's own check: a launch file that names no choices still gets the name.
    from allo_mrad_ros.ros.launch_arguments import LaunchArgumentError, parameter_overrides

    with pytest.raises(LaunchArgumentError, match="use_sim_time"):
        parameter_overrides({"use_sim_time": "yes"})


def test_every_node_input_can_be_remapped_from_the_launch_file():
    from allo_mrad_ros import interface
    from allo_mrad_ros.ros.launch_arguments import ARGUMENTS

    inputs = {a.input_topic for a in ARGUMENTS if a.input_topic}
    # camera_info is not remapped on its own: it follows the image (image_transport's rule).
    assert inputs == {
        interface.IMAGE_INPUT,
        interface.POSE_INPUT,
        interface.SUN_DIRECTION_INPUT,
        interface.SUN_STRENGTH_INPUT,
        interface.BODIES_INPUT,
    }


def test_mesh_argument_describes_what_happens_when_not_given():
    from allo_mrad_ros.ros.launch_arguments import ARGUMENTS

    mesh = next(a for a in ARGUMENTS if a.name == "mesh")
    assert "not given: the parameter file's mesh" in mesh.description


def test_rviz_topics_are_relative_so_they_follow_the_launch_namespace():
    """RViz runs in the node's namespace: its topics must resolve there, to the node's."""
    from allo_mrad_ros import interface

    document = yaml.safe_load((REPO / "config" / "mrad.rviz").read_text())
    displays = document["Visualization Manager"]["Displays"]
    topics = [d["Topic"]["Value"] for d in displays if "Topic" in d]
    outputs = {
        f"{interface.NODE_NAME}/{o[2:]}"
        for o in (
            interface.OVERLAY_OUTPUT,
            interface.MASK_OUTPUT,
            interface.SCORE_OUTPUT,
            interface.REFERENCE_OUTPUT,
            interface.OBJECT_MARKERS_OUTPUT,
        )
    }
    assert set(topics) == outputs | {interface.BODIES_INPUT}
    assert not any(topic.startswith("/") for topic in topics)


def test_relative_inputs_resolve_at_the_root_to_the_topics_allo_bag_plays():
    from allo_mrad_ros import interface
    from rosbag_tools.topics import DEFAULT_TOPICS

    pairs = {
        interface.IMAGE_INPUT: DEFAULT_TOPICS.image,
        interface.CAMERA_INFO_INPUT: DEFAULT_TOPICS.camera_info,
        interface.POSE_INPUT: DEFAULT_TOPICS.pose,
        interface.SUN_DIRECTION_INPUT: DEFAULT_TOPICS.sun_direction,
        interface.SUN_STRENGTH_INPUT: DEFAULT_TOPICS.sun_strength,
        interface.BODIES_INPUT: DEFAULT_TOPICS.bodies,
    }
    for relative, played in pairs.items():
        assert not relative.startswith("/") and "/" + relative == played


def test_enumerated_launch_arguments_declare_their_choices_and_log_level_is_forwarded(
    monkeypatch,
):
    module = _launch_module(monkeypatch)
    description = module.generate_launch_description()
    declared = {
        entity.args[0]: entity.kwargs
        for entity in description.args[0]
        if isinstance(entity, _Recorded) and entity.args
    }
    assert set(declared["pose_source"]["choices"]) == {"", "tf", "topic"}
    assert set(declared["image_transport"]["choices"]) == {"", "raw", "compressed"}
    assert set(declared["use_sim_time"]["choices"]) == {"", "true", "false"}
    assert set(declared["rviz"]["choices"]) == {"true", "false"}
    assert declared["log_level"]["default_value"] == "info"
    assert {"debug", "info", "warn", "error", "fatal"} <= set(declared["log_level"]["choices"])
    for name, kwargs in declared.items():
        if "choices" in kwargs:
            assert kwargs["default_value"] in kwargs["choices"], name
    _, detector, _ = launched_nodes(monkeypatch, log_level="debug")
    # The node's logger only: rcl and the middleware keep their level.
    assert detector["arguments"] == ["--ros-args", "--log-level", "mrad_detector:=debug"]
    _, detector, _ = launched_nodes(monkeypatch, log_level="warn", namespace="arm2")
    assert detector["arguments"] == ["--ros-args", "--log-level", "arm2.mrad_detector:=warn"]


def test_respawn_is_a_launch_argument_off_by_default(monkeypatch):
    from allo_mrad_ros.ros.launch_arguments import LaunchArgumentError

    declared, detector, _ = launched_nodes(monkeypatch)
    assert declared["respawn"] == "false" and float(declared["respawn_delay"]) >= 0
    assert detector["respawn"] is False
    _, detector, _ = launched_nodes(monkeypatch, respawn="true", respawn_delay="5")
    assert detector["respawn"] is True and detector["respawn_delay"] == 5.0
    for delay in ("-1", "soon", "inf", "nan"):
        with pytest.raises(LaunchArgumentError, match="respawn_delay"):
            launched_nodes(monkeypatch, respawn="true", respawn_delay=delay)


def _transition_ids():
    try:
        from lifecycle_msgs.msg import Transition
    except ImportError:
        return TRANSITIONS
    return {name: getattr(Transition, f"TRANSITION_{name.upper()}") for name in TRANSITIONS}


def test_lifecycle_starts_the_managed_node_and_autostart_configures_then_activates(monkeypatch):
    ids = _transition_ids()
    assert ids == TRANSITIONS  # the stand-in's ids are lifecycle_msgs' own
    declared, entities = launched_entities(monkeypatch)
    assert declared["lifecycle"] == "false" and declared["autostart"] == "true"
    assert type(entities[0]) is _Node and len(entities) == 2  # the plain node, no events
    _, entities = launched_entities(monkeypatch, lifecycle="true", namespace="arm2")
    detector, rviz, register, configure = entities
    assert type(detector) is _LifecycleNode
    assert detector.kwargs["executable"] == "mrad_detector_lifecycle"
    assert detector.kwargs["name"] == "mrad_detector" and detector.kwargs["namespace"] == "arm2"
    plain = launched_nodes(monkeypatch, namespace="arm2")[1]
    same = {k: v for k, v in plain.items() if k != "executable"}
    assert {k: v for k, v in detector.kwargs.items() if k != "executable"} == same
    # On start: configure, aimed at this node only.
    assert configure.event.transition_id == ids["configure"]
    assert configure.event.lifecycle_node_matcher(detector)
    assert not configure.event.lifecycle_node_matcher(rviz)
    # The transitions the node goes through; activate follows a successful configure only.
    handler = register.event_handler
    fired = [
        (start, goal)
        for start, goal in (
            ("unconfigured", "configuring"),
            ("configuring", "inactive"),
            ("inactive", "activating"),
            ("activating", "active"),
            ("active", "deactivating"),
            ("deactivating", "inactive"),  # a user's deactivate stays deactivated
            ("configuring", "unconfigured"),  # a failed configure
        )
        if handler.matches(detector, start, goal)
    ]
    assert fired == [("configuring", "inactive")]
    assert not handler.matches(rviz, "configuring", "inactive")
    (activate,) = handler.entities
    assert activate.event.transition_id == ids["activate"]
    assert activate.event.lifecycle_node_matcher(detector)


def test_lifecycle_without_autostart_waits_unconfigured_and_bad_values_are_refused(monkeypatch):
    _, entities = launched_entities(monkeypatch, lifecycle="true", autostart="false")
    assert len(entities) == 2 and type(entities[0]) is _LifecycleNode
    _, entities = launched_entities(monkeypatch, autostart="false")
    assert type(entities[0]) is _Node
    for name, value in (("lifecycle", "True"), ("autostart", "yes")):
        with pytest.raises(RuntimeError, match=f'Argument "{name}" provided value "{value}"'):
            launched_entities(monkeypatch, **{name: value})


def test_the_launch_stand_ins_refuse_what_real_launch_ros_refuses():
    with pytest.raises(RuntimeError, match="'name' must not be None"):
        _LifecycleNode(namespace="")
    with pytest.raises(TypeError, match="namespace"):
        _LifecycleNode(name="mrad_detector")
    with pytest.raises(ValueError, match="transition_id"):
        _ChangeState(lifecycle_node_matcher=lambda a: True, transition_id=42)
    with pytest.raises(RuntimeError, match="LifecycleNode"):
        _OnStateTransition(entities=[], target_lifecycle_node=_Node(name="x"))
    with pytest.raises(ValueError, match="INACTIVE"):
        _OnStateTransition(entities=[], goal_state="INACTIVE")
    with pytest.raises(TypeError):
        _EmitEvent(_ChangeState(lifecycle_node_matcher=lambda a: True, transition_id=1))
