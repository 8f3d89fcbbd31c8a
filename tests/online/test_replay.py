"""``odocal replay`` (issue 32): Ctrl-C at any moment, time stamps as the logger wrote them, and
alarms in words."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

import odocal
from odocal import cancel
from odocal.cli import interrupt
from odocal.cli.main import EXIT_OK
from odocal.online import replay as replay_module
from tests.conftest import interrupt as send_interrupt
from tests.conftest import run
from tests.online import departures as dep

BIN = Path(sys.executable).parent


def test_an_interrupt_a_library_swallows_still_stops_the_replay(
        tmp_path: Path, short_drive: odocal.SimulatedDrive, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C landing where compiled code drops it (pyarrow's check for pandas did, leaving the
    run going for 22 s and exit 0): the program's handler remembers it, the replay stops at its
    next update, exit 130 and one line; nothing is written."""
    path = tmp_path / "d.parquet"
    odocal.save_drive(short_drive.drive, path)
    monkeypatch.setattr(cancel, "_requested", [False])     # (the request it remembers)
    numbers = replay_module._numbers
    calls = []

    def swallowing(column: Any) -> Any:
        calls.append(1)
        if len(calls) == 1:
            try:
                interrupt._on_interrupt(2, None)       # what SIGINT does, here ...
            except KeyboardInterrupt:
                pass                                   # ... and what the library did with it
        return numbers(column)

    monkeypatch.setattr(replay_module, "_numbers", swallowing)
    code, _, err = run(capsys, "replay", str(path), "--out", str(tmp_path / "o"))
    assert code == 130
    assert err == "odocal replay: interrupted\n"
    assert not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def long_drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("replay") / "long.parquet"
    odocal.save_drive(odocal.simulate(duration_s=1800, seed=9, noise="realistic").drive, path)
    return path


def test_ctrl_c_stops_a_replay_with_130(long_drive: Path, tmp_path: Path) -> None:
    """A real SIGINT to a real run, once it is replaying (its first trace line is out)."""
    proc = subprocess.Popen([str(BIN / "odocal"), "replay", str(long_drive), "--out",
                             str(tmp_path / "o")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    assert proc.stdout is not None
    first = proc.stdout.readline()
    assert " km " in first, first
    assert proc.poll() is None, "the replay ended before it could be interrupted"
    err = send_interrupt(proc, 20, "the replay")
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["odocal replay: interrupted"]
    assert not (tmp_path / "o").exists()


_STARTING = """
import os, signal, sys

class Interrupting:                  # Ctrl-C while the command-line module is being imported
    def find_spec(self, name, path, target=None):
        if name == "odocal.cli.main":
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, Interrupting())
sys.argv = ["odocal", "replay", sys.argv[1], "--out", sys.argv[2]]
from odocal.cli import run
run()
"""


def test_ctrl_c_while_the_program_starts(long_drive: Path, tmp_path: Path) -> None:
    """Interrupted while it imports (before any command runs): exit 130, one line naming
    the command its first word is (was: a traceback; then "odocal: interrupted")."""
    proc = subprocess.run([sys.executable, "-c", _STARTING, str(long_drive),
                           str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr == "odocal replay: interrupted\n"
    assert not (tmp_path / "o").exists()


def test_replay_reads_time_stamps_and_says_what_changed(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    """A log whose t is a timestamp column (with a zone) and whose left tyre loses pressure
    half-way: replayed in seconds, the alarm names the wheel and its size; the batch
    calibration, which cannot read such a t, is skipped with a note rather than failing the
    replay."""
    d = dep.stepped(15, duration_s=480.0, at_s=240.0, relative=-0.015, wheel="left")
    cols = dict(d.columns)
    stamps = (np.datetime64("2026-03-01T08:00:00", "ns")
              + np.round(cols.pop("t") * 1e9).astype("timedelta64[ns]"))
    table = pa.table({"t": pa.array(stamps, type=pa.timestamp("ns", tz="Europe/Berlin")),
                      **{k: pa.array(v) for k, v in cols.items()}})
    path = tmp_path / "stamped.parquet"
    pq.write_table(table, path)
    code, out, err = run(capsys, "replay", str(path), "--out", str(tmp_path / "r"))
    assert code == EXIT_OK, err
    data = json.loads((tmp_path / "r" / "calibration.json").read_text())
    assert data["details"]["time_unit"] == "s" and data["details"]["sampling_s"] == 0.025
    assert data["duration_s"] == pytest.approx(480.0, abs=0.05)
    (alarm,) = json.loads((tmp_path / "r" / "alarms.json").read_text())["alarms"]
    assert alarm["parameter"] == "c_d" and alarm["wheel"] == "left"
    assert alarm["relative_change"] == pytest.approx(d.change["c_d"], rel=0.2)
    assert alarm["c_d_change_std_m"] > 0
    (line,) = [x for x in out.splitlines() if x.startswith("change:")]
    assert "the rear-left wheel's circumference alone (c_d" in line
    assert "since 2" in line                     # seconds from the log's start, not the epoch
    if data["batch"] is None:
        assert "note: no batch calibration to compare with" in out
    page = (tmp_path / "r" / "report.html").read_text()
    assert "the rear-left wheel&#x27;s circumference alone (c_d" in page


def test_replay_of_a_log_in_nanoseconds_reports_seconds(
        tmp_path: Path, short_drive: odocal.SimulatedDrive,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Integer epoch nanoseconds (beyond float's exact integers): updates every 30 s of driving,
    the trace and the duration in seconds (was: an update per chunk, 8e9 minutes)."""
    cols = {k: v for k, v in short_drive.drive.columns().items() if k in dep.COLUMNS}
    cols["t"] = np.round((cols["t"] + 1.7e9) * 1e9).astype(np.int64)
    path = tmp_path / "ns.csv"
    pacsv.write_csv(pa.table(cols), path)
    code, _, err = run(capsys, "replay", str(path), "--out", str(tmp_path / "r"), "-q",
                       "--no-report", "--no-batch")
    assert code == EXIT_OK, err
    data = json.loads((tmp_path / "r" / "calibration.json").read_text())
    assert data["details"]["time_unit"] == "ns"
    assert data["duration_s"] == pytest.approx(120.0, abs=0.01)
    trace = (tmp_path / "r" / "trace.csv").read_text().splitlines()
    assert 4 <= len(trace) - 1 <= 6                       # every 30 s, and the end
    assert float(trace[-1].split(",")[0]) == pytest.approx(1.7e9 + 120.0, abs=1e-3)


def test_the_estimate_is_due_every_update_s_of_data_from_the_first_sample() -> None:
    """One rule for replay and the ROS 2 node: the first estimate update_s after the first
    sample, then update_s after the last one taken (a chunk spanning more takes one)."""
    from odocal.online.calibrator import Updates

    u = Updates(30.0)
    spans = [None, (5.0, 20.0), (5.0, 34.9), (5.0, 35.0), (5.0, 64.0), (5.0, 66.0),
             (5.0, 200.0), (5.0, 229.0), (5.0, 230.0)]
    assert [u.due(s) for s in spans] == [False, False, False, True, False, True, True, False,
                                         True]
