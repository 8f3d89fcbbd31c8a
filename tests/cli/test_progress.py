"""No silent waits: long commands say what they do, how far they are and how long is left
(issue 25)."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.cli import progress as progress_module
from odocal.cli.progress import ENV, Progress
from tests.conftest import run

BIN = Path(sys.executable).parent
#: tqdm's count and time: "3/10 [00:01<00:02]" (spent < left)
COUNTED = re.compile(r"(\d+)/(\d+) \[\d\d:\d\d<(\?|\d\d:\d\d)\]")


def _odocal(*argv: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN / "odocal"), *argv], capture_output=True, text=True,
                          timeout=600, env={**os.environ, **(env or {})})


def _screen(text: str) -> str:
    """What a terminal shows of tqdm's output: a carriage return goes back to the start of the
    line and what follows overwrites it (blank lines dropped)."""
    text = re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "", text)
    kept = []
    for line in text.split("\n"):
        shown = ""
        for part in line.split("\r"):
            shown = part + shown[len(part):]
        if shown.strip():
            kept.append(shown.rstrip())
    return "\n".join(kept)


# -- the Progress class ---------------------------------------------------------------------

def test_a_counted_stage_draws_a_bar_with_its_count_and_time_left() -> None:
    out = io.StringIO()
    bars = Progress(True, mode="bars", stream=out)
    for done in range(11):
        bars("step 1: batches", done, 10)
    bars.close()
    counts = [(int(a), int(b)) for a, b, _ in COUNTED.findall(out.getvalue())]
    assert (0, 10) in counts and (5, 10) in counts
    assert "step 1: batches" in out.getvalue()


def test_a_one_step_stage_shows_its_clock_not_a_bar_from_0_to_1(
        monkeypatch: pytest.MonkeyPatch) -> None:
    out = io.StringIO()
    bars = Progress(True, mode="bars", stream=out)
    bars("read", 0, 1)
    bars("read", 1, 1)
    assert "0/1" not in out.getvalue() and "1/1" not in out.getvalue()
    assert "read ... 0 s" in out.getvalue()
    assert _screen(out.getvalue()) == ""                   # a quick stage is wiped at its end
    monkeypatch.setattr(progress_module, "SLOW_S", 0.0)     # a slow one stays, with its time
    bars("report", 0, 1)
    bars("report", 1, 1)
    bars.close()
    assert re.fullmatch(r"report: done in \d+\.\d s", _screen(out.getvalue())), out.getvalue()


def test_the_clock_of_an_open_stage_moves_while_it_reports_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import time

    monkeypatch.setattr(progress_module, "TICK_S", 0.05)
    out = io.StringIO()
    bars = Progress(True, mode="bars", stream=out)
    bars("compiling", 0, 1)
    time.sleep(0.4)
    bars.close()
    assert out.getvalue().count("compiling ... ") >= 4      # redrawn by the ticker


def test_lines_where_there_is_no_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(progress_module, "LINE_EVERY_S", 0.0)
    monkeypatch.setattr(progress_module, "SLOW_S", 0.0)
    out = io.StringIO()
    lines = Progress(True, stream=out)                      # a StringIO is not a terminal
    assert lines.mode == "lines"
    for done in range(5):
        lines("reachable minimum", done, 4)
    text = out.getvalue()
    assert re.search(r"\] reachable minimum \.\.\.\n", text)
    assert re.search(r"reachable minimum: 2/4, \d+ s so far, about \d+ s left", text)
    assert "reachable minimum: done in" in text
    assert "\r" not in text


def test_quiet_and_the_environment_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    out = io.StringIO()
    quiet = Progress(False, mode="bars", stream=out)
    quiet("read", 0, 1)
    quiet("read", 1, 1)
    assert quiet.mode == "off" and out.getvalue() == ""
    monkeypatch.setenv(ENV, "bars")
    assert Progress(True, stream=io.StringIO()).mode == "bars"   # into a pipe, on request
    monkeypatch.setenv(ENV, "off")
    assert Progress(True, stream=io.StringIO()).mode == "off"
    monkeypatch.setenv(ENV, "nonsense")
    assert Progress(True, stream=io.StringIO()).mode == "lines"


# -- the commands ---------------------------------------------------------------------------

def _quick_minimum(tmp_path: Path) -> Path:
    config = tmp_path / "quick.toml"
    config.write_text("[minimum]\nmax_generations = 6\npopulation = 5\n")
    return config


def test_minimum_shows_its_generations_with_the_time_left(
        tmp_path: Path, short_drive: Any, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(short_drive.drive, drive)
    config = _quick_minimum(tmp_path)
    monkeypatch.setenv(ENV, "bars")
    code, out, err = run(capsys, "minimum", str(drive), "--config", str(config))
    assert code == 0, err
    assert "minimum E_p" in out
    generations = [(int(a), int(b)) for a, b, _ in COUNTED.findall(err)]
    assert (0, 6) in generations and any(0 < a < 6 for a, _ in generations), err
    assert "reachable minimum: differential evolution, generation" in err
    code, out, err = run(capsys, "minimum", str(drive), "--config", str(config), "-q")
    assert code == 0 and err == ""


def test_reproduce_names_every_stage(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    config = _quick_minimum(tmp_path)
    monkeypatch.setenv(ENV, "bars")
    code, out, err = run(capsys, "reproduce", "--distance-km", "6", "--config", str(config))
    assert code == 0, err
    assert "Section 6.5" in out
    for stage in ("simulating a 6 km drive ...", "segments ...", "Fig. 4: step-1 batches:",
                  "Table 1: compensating the examined batch:",
                  "Table 1, Fig. 7: G-N fits on the examined batch:",
                  "whole drive: batch G-N on measured rates ...", "whole drive, step 1: batches:",
                  "whole drive, step 2: compensation:", "whole drive, step 3: identification",
                  "reachable minimum: differential evolution, generation:"):
        assert stage in err, (stage, err)
    assert not re.search(r"\b[01]/1 \[", err)             # no bar jumps from 0/1 to 1/1
    assert COUNTED.search(err)
    code, out, err = run(capsys, "reproduce", "--distance-km", "6", "--no-minimum", "-q")
    assert code == 0 and err == ""


def test_the_demo_counts_the_comparison_fits(capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ENV, "bars")
    code, _, err = run(capsys, "demo", "--duration", "600")
    assert code in (0, 3), err
    for method in ("inverse", "compensated", "raw"):
        assert f"comparing the methods: {method}, 3 fits:" in err
    assert "3/3" in err


# -- the first compilation ------------------------------------------------------------------

def test_the_first_run_of_a_segment_method_says_it_compiles(tmp_path: Path,
                                                            short_drive: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(short_drive.drive, drive)
    cold = {"NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    first = _odocal("calibrate", str(drive), "--out", str(tmp_path / "a"), "--method",
                    "compensated", "--no-report", env=cold)
    assert first.returncode in (0, 3), first.stderr
    assert re.search(r"note: compiling the numerical kernels once \(about \d+ s", first.stderr)
    again = _odocal("calibrate", str(drive), "--out", str(tmp_path / "b"), "--method",
                    "compensated", "--no-report", env=cold)
    assert "compiling" not in again.stderr                    # cached now
    # raw's rollouts and Jacobians are numpy: nothing to compile, with any cache
    raw = _odocal("calibrate", str(drive), "--out", str(tmp_path / "c"), "--method", "raw",
                  "--no-report", env={"NUMBA_CACHE_DIR": str(tmp_path / "empty")})
    assert raw.returncode in (0, 3), raw.stderr
    assert "compiling" not in raw.stderr
    default = _odocal("calibrate", str(drive), "--out", str(tmp_path / "d"), "--no-report",
                      env={"NUMBA_CACHE_DIR": str(tmp_path / "other")})
    assert "compiling" not in default.stderr                  # the default compiles nothing


def test_the_cache_is_looked_up_per_kernel(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    from odocal.estimators.kernels import compile_note, uncached_kernels

    assert uncached_kernels(["inverse"]) == [] and compile_note(["inverse"]) is None
    # the kernels resolve their cache folder when the module is imported: ask a fresh process
    probe = subprocess.run(
        [sys.executable, "-c", "from odocal.estimators.kernels import uncached_kernels as u; "
         "print(u(['raw']), u(['compensated']))"], capture_output=True, text=True, timeout=300,
        env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "empty")})
    assert probe.stdout.split("\n")[0] == \
        "[] ['_pdas_batch']", \
        probe.stderr
