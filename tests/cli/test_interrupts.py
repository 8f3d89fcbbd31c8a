"""Ctrl-C at several moments of every long command (issue 40): the run ends with exit 130 and
one line, no traceback, no process of it left, and the results of an earlier run byte for byte
as they were, whenever the interrupt comes, even one that a library swallowed.

The moments are the stages each command announces (progress in line mode), not times: the same
moment on a fast and on a busy machine. How long each takes to stop is measured by
``benchmarks/bench_interrupts.py`` (speed is benchmark material, not a unit test's); here a
run that does not stop within a minute fails as a hang.
"""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

import odocal
from odocal.io import save_drive
from tests.interrupting import BIN, Outcome, interrupt_at

ROOT = Path(__file__).resolve().parents[2]
SOURCES = Path(odocal.__file__).resolve().parents[1]          # the odocal under test
SWALLOWING = [sys.executable, "-m", "tests.cli.swallowing"]
STUCK = [sys.executable, "-m", "tests.cli.stuck"]


def _odocal(*argv: str, cwd: Path) -> None:
    proc = subprocess.run([str(BIN / "odocal"), *argv], cwd=cwd, capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def place(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ten-minute drive, a five-minute one, and earlier results of each command."""
    tmp = tmp_path_factory.mktemp("interrupts")
    save_drive(odocal.simulate(duration_s=600.0, seed=40, noise="realistic").drive,
               tmp / "drive.parquet")
    save_drive(odocal.simulate(duration_s=300.0, seed=41, noise="realistic").drive,
               tmp / "small.parquet")
    _odocal("calibrate", "small.parquet", "--out", "prev", "-q", cwd=tmp)
    _odocal("replay", "small.parquet", "--out", "prevr", "-q", "--no-batch", cwd=tmp)
    _odocal("minimum", "small.parquet", "--out", "minimum.json", "-q", cwd=tmp)
    return tmp


def _stopped_cleanly(o: Outcome) -> None:
    assert o.reached, f"the moment never came: {o.stderr[-800:]}"
    assert not o.finished, "the run ended before it could be interrupted"
    assert o.code == 130, o.stderr[-2000:]
    said = [line for line in o.stderr.strip().splitlines() if not line.startswith("[")]
    assert len(said) == 1 and said[0].endswith(": interrupted"), o.stderr[-2000:]
    assert "Traceback" not in o.stderr and "leaked" not in o.stderr
    assert o.intact, "the earlier results changed"
    assert o.left == (), f"processes left: {o.left}"
    assert o.leftovers == (), f"temporary files left: {o.leftovers}"


# ---------------------------------------------------------------- at the stages they announce

@pytest.mark.parametrize("stage", ["inverse: fit ...",
                                   "comparing the methods: compensated, 3 fits ...",
                                   "comparing the methods: raw, 3 fits ...", "report ..."])
def test_calibrate_with_compare(place: Path, stage: str) -> None:
    _stopped_cleanly(interrupt_at(["calibrate", "drive.parquet", "--out", "prev", "--compare"],
                                  outputs=[place / "prev"], line=stage, cwd=place))


@pytest.mark.parametrize(("stage", "delay_s"), [("step 1: batches ...", 0.2),
                                                ("step 2: compensation ...", 0.2),
                                                ("step 3: identification ...", 0.0)])
def test_calibrate_compensated_with_workers(place: Path, stage: str, delay_s: float) -> None:
    _stopped_cleanly(interrupt_at(["calibrate", "drive.parquet", "--out", "prev", "--method",
                                   "compensated", "--workers", "2"],
                                  outputs=[place / "prev"], line=stage, delay_s=delay_s,
                                  cwd=place))


@pytest.mark.parametrize("delay_s", [0.0, 1.0, 3.0])
def test_minimum_with_workers(place: Path, delay_s: float) -> None:
    """The search's workers (its own, not scipy's pool) leave Ctrl-C to the program: no worker
    traceback, no leaked semaphore, no worker left."""
    _stopped_cleanly(interrupt_at(["minimum", "drive.parquet", "--out", "minimum.json",
                                   "--workers", "2"], outputs=[place / "minimum.json"],
                                  line="differential evolution, generation ...",
                                  delay_s=delay_s, cwd=place))


@pytest.mark.parametrize("update", ["     31.0 s", "    302.8 s", "    600.0 s"])
def test_replay(place: Path, update: str) -> None:
    """At its first update, in the middle, and at its end (then the batch calibration runs)."""
    _stopped_cleanly(interrupt_at(["replay", "drive.parquet", "--out", "prevr"],
                                  outputs=[place / "prevr"], line=update, cwd=place))


@pytest.fixture(scope="module")
def fleet(place: Path) -> tuple[Path, Path, list[tuple[object, ...]]]:
    """A fleet of 2 vehicles x 3 drives, the first two drives already in the store."""
    _odocal("simulate-fleet", "--out", "fleet", "--vehicles", "2", "--drives", "3",
            "--duration", "300", "-q", cwd=place)
    catalog = place / "fleet" / "catalog.csv"
    lines = catalog.read_text().splitlines()
    first = place / "first.csv"
    first.write_text("\n".join([lines[0]] + [ln.replace(",", ",fleet/", 1)
                                             for ln in lines[1:3]]) + "\n")
    store = place / "fleet.db"
    _odocal("fleet", "calibrate", str(first), "--store", str(store), "--workers", "2",
            "--no-drive-reports", "-q", cwd=place)
    return catalog, store, _rows(store)


def _rows(store: Path) -> list[tuple[object, ...]]:
    with sqlite3.connect(f"file:{store}?mode=ro", uri=True) as con:
        return sorted(con.execute("SELECT * FROM drives").fetchall())


@pytest.mark.parametrize(("stage", "delay_s"), [("starting the Dask workers ...", 0.0),
                                                ("starting the Dask workers ...", 0.5),
                                                ("drives ...", 0.0), ("pooled ...", 0.0)])
def test_fleet(place: Path, fleet: tuple[Path, Path, list[tuple[object, ...]]], stage: str,
               delay_s: float) -> None:
    """While the cluster's workers start (each ignores Ctrl-C from its first moment: none
    prints a traceback of its own), while drives are calibrated and while the pooled
    calibrations run: every row stored before stays as it was."""
    catalog, store, before = fleet
    o = interrupt_at(["fleet", "calibrate", str(catalog), "--store", str(store), "--workers",
                      "2", "--no-drive-reports"], outputs=[], line=stage, delay_s=delay_s,
                     cwd=place)
    _stopped_cleanly(o)
    after = _rows(store)
    assert set(before) <= set(after)


# ---------------------------------------------------------------- interrupts a library swallowed

@pytest.mark.parametrize(("command", "target", "output"), [
    (["calibrate", "drive.parquet", "--out", "prev", "--compare"],
     "odocal.output.results:write_results", "prev"),
    (["calibrate", "drive.parquet", "--out", "prev", "--method", "compensated"],
     "odocal.estimators.compensated:run", "prev"),
    (["replay", "drive.parquet", "--out", "prevr"],
     "odocal.output.results:write_replay_results", "prevr"),
    (["minimum", "small.parquet", "--out", "minimum.json", "--seed", "3"],
     "odocal.io.json_files:write_json", "minimum.json"),
])
def test_an_interrupt_a_library_swallowed_still_stops_the_run(place: Path, command: list[str],
                                                              target: str, output: str
                                                              ) -> None:
    """Ctrl-C that lands where a library drops it (here: writing the results, or the start of
    the method) never lets the run publish: the earlier results stay, exit 130 (on main the
    run went on, replaced them with its own, then said 'interrupted')."""
    o = interrupt_at([target, *command], outputs=[place / output], cwd=place,
                     program=SWALLOWING, signal_sent=False,
                     env={"PYTHONPATH": f"{ROOT}:{SOURCES}"})
    assert o.code == 130, o.stderr[-2000:]
    assert o.intact, "the interrupted run replaced the earlier results"
    assert "Traceback" not in o.stderr and o.left == () and o.leftovers == ()


@pytest.mark.parametrize(("command", "target", "output"), [
    (["calibrate", "small.parquet", "--out", "prev"], "odocal.output.results:write_results",
     "prev"),
    (["replay", "small.parquet", "--out", "prevr", "--no-batch"],
     "odocal.online.replay:replay", "prevr"),
])
def test_a_clean_up_that_never_ends_does_not_keep_the_program(place: Path,
                                                               command: list[str], target: str,
                                                               output: str) -> None:
    """Ctrl-C whose clean-up waits for ever (found in CI: closing the fleet's Dask client
    waited a minute for its scheduler): the program leaves on its own, exit 130 and one line
    (the hang is what fails here: the harness kills the run after 30 s). A temporary folder
    the stuck clean-up could not remove is removed by the next run, its writer being gone."""
    o = interrupt_at([target, *command], outputs=[place / output], cwd=place, program=STUCK,
                     signal_sent=False, timeout_s=30.0,
                     env={"PYTHONPATH": f"{ROOT}:{SOURCES}"})
    assert o.code == 130, o.stderr[-2000:]
    assert o.stderr.strip().splitlines()[-1].endswith(": interrupted"), o.stderr[-2000:]
    assert "Traceback" not in o.stderr
    assert o.intact and o.left == ()
    _odocal(*command, cwd=place)
    assert not list(place.glob(f".{output}.*"))


def test_simulate_fleet_leaves_no_half_a_fleet(place: Path) -> None:
    """Interrupted while it writes the drives (found by the hostile run: on main the folder was
    left with some drives and no catalog, and a rerun refused it as not empty)."""
    o = interrupt_at(["simulate-fleet", "--out", "half", "--vehicles", "3", "--drives", "4",
                      "--duration", "300"], outputs=[place / "half"], line="simulate",
                     delay_s=0.5, cwd=place)
    _stopped_cleanly(o)
    assert not (place / "half").exists()
