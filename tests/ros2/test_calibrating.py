"""The node's calibrator beside it (``odocal.ros2.calibrating``, issue 41): the same events as in
the node's thread, deaf to Ctrl-C and SIGTERM, and a process that dies is named, never waited
for; with real rclpy nodes, a node whose calibrator dies goes on and says so."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.ros2.calibrating import (
    Beside,
    CalibratorLost,
    Event,
    InThread,
    LeftOut,
    Pushed,
    Updated,
)
from odocal.settings import Settings
from tests.ros2.rig import first_seconds, play, spin_until, without_sideslip
from tests.ros2.rosenv import require_rclpy

COLUMNS = ("t", "n_rl", "n_rr", "a_y", "yaw_rate", "x", "y", "psi")


@pytest.fixture(scope="module")
def drive() -> odocal.Drive:
    return without_sideslip(odocal.simulate(duration_s=100.0, seed=5, noise="realistic").drive)


@pytest.fixture(scope="module")
def blocks() -> list[dict[str, np.ndarray]]:
    """Two minutes of a simulated drive in replay's blocks of a second (40 rows)."""
    d = odocal.simulate(duration_s=120.0, seed=3, noise="realistic").drive
    cols = {k: np.asarray(getattr(d, k), dtype=float) for k in COLUMNS}
    return [{k: v[lo:lo + 40] for k, v in cols.items()} for lo in range(0, d.n_samples, 40)]


def _events(calibration: Beside | InThread, blocks: list[dict[str, np.ndarray]]
            ) -> list[Event]:
    for lo in range(0, len(blocks), 7):
        calibration.push(blocks[lo:lo + 7])
    calibration.estimate()
    events = calibration.settle()
    assert calibration.idle
    return events


def _summary(events: list[Event]) -> list[tuple[Any, ...]]:
    out: list[tuple[Any, ...]] = []
    for e in events:
        row: tuple[Any, ...] = (type(e).__name__, e.view.distance_km, e.view.samples,
                                e.view.halted, e.view.span_s)
        if isinstance(e, Updated):
            row += (e.estimate.status, tuple(e.estimate.theta.as_array()),
                    tuple(e.estimate.std), e.estimate.identified)
        out.append(row)
    return out


def test_beside_the_node_the_calibrator_answers_as_in_its_thread(
        blocks: list[dict[str, np.ndarray]]) -> None:
    """Every event in the same order with the same numbers, to the last bit: a push's
    blocks, an estimate every 30 s of data (three in two minutes) and the final one."""
    settings = Settings()
    beside = Beside(settings)
    try:
        there = _events(beside, blocks)
    finally:
        beside.close()
    here = _events(InThread(settings), blocks)
    assert _summary(there) == _summary(here)
    kinds = [type(e).__name__ for e in here]
    assert kinds.count("Updated") == 4 and kinds.count("Pushed") == len(range(0, len(blocks), 7))
    # the estimates at replay's moments: the first block's start + 30 s of data, then 30 s
    # after the block that took the one before (blocks of a second: 31, 61 and 91 blocks)
    assert [e.view.samples for e in here if isinstance(e, Updated)] == [1240, 2440, 3640, 4801]


def test_a_block_it_cannot_use_is_left_out_and_named(blocks: list[dict[str, np.ndarray]]
                                                     ) -> None:
    calibration = InThread(Settings())
    bad = {k: v.copy() for k, v in blocks[1].items()}
    bad["t"] = bad["t"][::-1].copy()                   # time going back within the block
    calibration.push([blocks[0], bad, blocks[2]])
    events = calibration.answers()
    assert [type(e) for e in events] == [LeftOut, Pushed]
    left = events[0]
    assert isinstance(left, LeftOut) and left.t0 == pytest.approx(float(bad["t"][0]))
    assert left.message and events[-1].view.samples == 80


def test_the_calibrators_process_ignores_ctrl_c_and_sigterm(
        blocks: list[dict[str, np.ndarray]]) -> None:
    """A terminal's Ctrl-C reaches every process of the node's group: the calibrator's goes on
    (the node ends it after the final estimate)."""
    beside = Beside(Settings())
    try:
        pid = beside._process.pid
        assert pid is not None
        beside.push(blocks[:3])
        assert [type(e) for e in beside.settle()] == [Pushed]     # it runs: it has answered
        ignored = int(next(line.split()[1] for line in
                           Path(f"/proc/{pid}/status").read_text().splitlines()
                           if line.startswith("SigIgn:")), 16)
        assert ignored & (1 << (signal.SIGINT - 1)) and ignored & (1 << (signal.SIGTERM - 1))
        os.kill(pid, signal.SIGINT)
        os.kill(pid, signal.SIGTERM)
        beside.push(blocks[3:6])
        assert [type(e) for e in beside.settle()] == [Pushed]
        assert beside._process.is_alive()
    finally:
        beside.close()
    assert beside._process.exitcode == 0                      # its pipe closed: it ended


def test_a_calibrator_that_died_is_named_not_waited_for(blocks: list[dict[str, np.ndarray]]
                                                        ) -> None:
    beside = Beside(Settings())
    try:
        beside.push(blocks[:3])
        beside.settle()
        os.kill(beside._process.pid or 0, signal.SIGKILL)
        beside._process.join(timeout=10)
        with pytest.raises(CalibratorLost, match=r"ended \(exit code -9\)"):
            beside.push(blocks[3:6])         # (its pipe is broken: said at once)
            beside.settle()
        assert beside.idle
    finally:
        beside.close()


def test_a_frozen_calibrator_never_holds_up_the_node(blocks: list[dict[str, np.ndarray]]
                                                    ) -> None:
    """A calibrator that stops answering (SIGSTOP: it and its reader frozen): the node's sends
    never wait (far more than the pipe holds go out), and waiting for its answers ends after
    the timeout with the process ended and named (the hostile test's node stalled its
    odometry and hung at Ctrl-C)."""
    beside = Beside(Settings())
    try:
        beside.push(blocks[:2])
        beside.settle()
        pid = beside._process.pid or 0
        os.kill(pid, signal.SIGSTOP)
        for _ in range(60):                     # about 2 MB of rows: the pipe holds 64 KiB
            beside.push(blocks)
        assert beside.backlog == 60 and not beside.idle
        with pytest.raises(CalibratorLost, match="did not answer within 2 s; it was ended"):
            beside.settle(timeout_s=2.0)
        assert not beside._process.is_alive() and beside._process.exitcode == -signal.SIGKILL
    finally:
        beside.close()


def test_a_node_whose_calibrator_died_says_so_and_goes_on(rig: Any, drive: odocal.Drive
                                                          ) -> None:
    require_rclpy()
    r = rig(calibrator_process=True)
    d = drive
    play(r.executor, r.player, r.node, first_seconds(d, 40.0))
    calibration = r.node._calibration
    assert isinstance(calibration, Beside)
    spin_until(r.executor, lambda: r.node.updates >= 1, "the first estimate")
    os.kill(calibration._process.pid or 0, signal.SIGKILL)
    calibration._process.join(timeout=10)
    heard = len(r.player.odometry)
    later = odocal.Drive.from_columns({k: v[1600:] for k, v in d.columns().items()},
                                      name=d.name)
    play(r.executor, r.player, r.node, later)
    spin_until(r.executor, lambda: any("calibrator's process ended" in s.message
                                       for s in r.player.statuses()), "the ERROR status")
    [*_, last] = r.player.statuses()
    assert last.level == b"\x02" and "exit code -9" in last.message
    spin_until(r.executor, lambda: len(r.player.odometry) > heard + 0.9 * later.n_samples,
               "the odometry after it")
    started = time.monotonic()
    assert r.node.finish() is r.node.estimate
    assert time.monotonic() - started < 30.0                   # (a hang guard)
