"""Ctrl-C at many moments of every long command: how long it takes to stop, and what it leaves.

    python benchmarks/bench_interrupts.py [--only calibrate-compare,compensated,minimum,replay,
        fleet] [--minutes 20] [--times 0.3,0.5,1,2,5] [--delays 0,0.4]

For each command, on a simulated drive of ``--minutes`` (the fleet: 6 drives of 5 minutes), with
the results of an earlier run in place at its ``--out``: Ctrl-C (SIGINT to the whole process
group, as a terminal sends it) at each stage the command announces (``ODOCAL_PROGRESS=lines``)
plus ``--delays`` seconds, and at ``--times`` seconds from the start. Printed per moment: the
exit code, the seconds from the signal to the exit, whether the earlier results are byte for byte
as they were, the processes of the run still alive 2 s after its exit, temporary files left
beside the output, and whether stderr holds a traceback or anything but one line. The last line
counts the moments that stopped cleanly within a second.
"""

from __future__ import annotations

import argparse
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.interrupting import BIN, Outcome, interrupt_at


def _odocal(*argv: str, cwd: Path) -> str:
    proc = subprocess.run([str(BIN / "odocal"), *argv], cwd=cwd, capture_output=True, text=True,
                          env={**__import__("os").environ, "ODOCAL_PROGRESS": "lines"})
    if proc.returncode not in (0, 3):
        raise SystemExit(f"odocal {' '.join(argv)} failed: {proc.stderr}")
    return proc.stderr


def _stages(stderr: str) -> list[str]:
    """The stage lines a run announced, in order, each once ("[  1.2 s] read ..." -> "read")."""
    out: list[str] = []
    for line in stderr.splitlines():
        if line.startswith("[") and line.rstrip().endswith(" ..."):
            stage = line.split("] ", 1)[1].rstrip()
            if stage not in out:
                out.append(stage)
    return out


def _rows(db: Path) -> list[tuple[object, ...]]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:
        return sorted(con.execute("SELECT task_key, c_e, c_d, t_r, d FROM drives").fetchall())


def _report(name: str, moment: str, o: Outcome, extra_ok: bool = True) -> bool:
    tail = o.stderr.strip().splitlines()[-1:] or [""]
    trace = "traceback" if "Traceback" in o.stderr else ""
    ok = o.clean and extra_ok and (o.finished or o.stop_s <= 1.0)
    state = "finished first" if o.finished else f"exit {o.code}"
    print(f"{name:<18} {moment:<58} {state:>14} {o.stop_s:6.2f} s  intact {o.intact!s:<5} "
          f"left {len(o.left)}  leftovers {len(o.leftovers)} {trace:<9} "
          f"{'ok' if ok else 'DEFECT: ' + tail[0][:60]}")
    return ok


def _moments(stages: Sequence[str], delays: Sequence[float], times: Sequence[float]
             ) -> list[tuple[str | None, float]]:
    return [(s, d) for s in stages for d in delays] + [(None, t) for t in times]


def run(name: str, argv: list[str], outputs: list[Path], cwd: Path, stages: list[str],
        delays: Sequence[float], times: Sequence[float], check: object = None) -> list[bool]:
    results = []
    for line, delay in _moments(stages, delays, times):
        moment = f"at '{line}' +{delay:g} s" if line else f"{delay:g} s after the start"
        o = interrupt_at(argv, outputs=outputs, line=line, delay_s=delay, cwd=cwd)
        extra = check() if callable(check) else True
        results.append(_report(name, moment[:58], o, bool(extra)))
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="calibrate-compare,compensated,minimum,replay,fleet")
    parser.add_argument("--minutes", type=float, default=20.0)
    parser.add_argument("--times", default="0.3,0.5,1,2,5")
    parser.add_argument("--delays", default="0,0.4")
    args = parser.parse_args()
    only = args.only.split(",")
    times = [float(x) for x in args.times.split(",") if x]
    delays = [float(x) for x in args.delays.split(",") if x]
    tmp = Path(tempfile.mkdtemp(prefix="bench-interrupts-"))
    ok: list[bool] = []
    started = time.perf_counter()
    try:
        _odocal("simulate", "--out", "drive.parquet", "--duration", str(args.minutes * 60),
                "--seed", "3", "-q", cwd=tmp)
        _odocal("simulate", "--out", "small.parquet", "--duration", "300", "--seed", "4", "-q",
                cwd=tmp)
        if "calibrate-compare" in only:
            full = _odocal("calibrate", "drive.parquet", "--out", "prev", "--compare", cwd=tmp)
            ok += run("calibrate-compare", ["calibrate", "drive.parquet", "--out", "prev",
                                            "--compare"], [tmp / "prev"], tmp, _stages(full),
                      delays, times)
        if "compensated" in only:
            full = _odocal("calibrate", "drive.parquet", "--out", "prevc", "--method",
                           "compensated", "--workers", "2", cwd=tmp)
            ok += run("compensated", ["calibrate", "drive.parquet", "--out", "prevc", "--method",
                                      "compensated", "--workers", "2"], [tmp / "prevc"], tmp,
                      _stages(full), delays, times)
        if "minimum" in only:
            _odocal("minimum", "small.parquet", "--out", "minimum.json", "-q", cwd=tmp)
            stages = ["reachable minimum: differential evolution, generation ..."]
            ok += run("minimum", ["minimum", "drive.parquet", "--out", "minimum.json",
                                  "--workers", "2"], [tmp / "minimum.json"], tmp, stages,
                      [0.0, 0.5, 2.0, 5.0], times)
        if "replay" in only:
            _odocal("replay", "drive.parquet", "--out", "prevr", cwd=tmp)
            # its moments: updates it prints (every 60 s of the log), and the batch comparison
            stages = [f"{t:9.1f} s" for t in (61.0, 302.8, 603.6, 1176.0, 1200.0)]
            ok += run("replay", ["replay", "drive.parquet", "--out", "prevr"], [tmp / "prevr"],
                      tmp, stages, delays, [0.3, 0.35, 0.4, 0.45, 0.5, 0.55, *times])
        if "fleet" in only:
            _odocal("simulate-fleet", "--out", "fleet", "--vehicles", "2", "--drives", "3",
                    "--duration", "300", "-q", cwd=tmp)
            catalog = tmp / "fleet" / "catalog.csv"
            lines = catalog.read_text().splitlines()
            (tmp / "first.csv").write_text("\n".join(
                [lines[0]] + [ln.replace(",", ",fleet/", 1) for ln in lines[1:3]]) + "\n")
            _odocal("fleet", "calibrate", "first.csv", "--store", "fleet.db", "--workers", "2",
                    "--no-drive-reports", cwd=tmp)
            rows = _rows(tmp / "fleet.db")
            full = _odocal("fleet", "calibrate", str(catalog), "--store", "probe.db",
                           "--workers", "2", cwd=tmp)
            (tmp / "probe.db").unlink()

            def kept() -> bool:
                return set(rows) <= set(_rows(tmp / "fleet.db"))

            ok += run("fleet", ["fleet", "calibrate", str(catalog), "--store", "fleet.db",
                                "--workers", "2", "--no-drive-reports"], [], tmp,
                      _stages(full), delays, times, check=kept)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{sum(ok)} of {len(ok)} moments stopped cleanly within a second "
          f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
