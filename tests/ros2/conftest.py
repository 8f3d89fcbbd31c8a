"""The ROS 2 tests' fixtures: one rclpy context per test module on the session's private
domain, and ``rig``, which starts a calibration node under test beside a player node."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.ros2.rosenv import ros_context


@pytest.fixture(scope="module")
def ros() -> Iterator[Any]:
    with ros_context() as context:
        yield context


@pytest.fixture()
def rig(ros: Any, tmp_path: Path) -> Iterator[Callable[..., Any]]:
    """A function that starts a calibration node (with parameter overrides) and a player on
    topics of their own; both are destroyed after the test (tests/ros2/rig.py)."""
    from tests.ros2.rig import rig_fixture

    yield from rig_fixture(ros, tmp_path)
