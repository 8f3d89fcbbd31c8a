"""Speed of ``odocal calibrate`` by stage, for every method and drive length (issues 14, 24, 30).

    python benchmarks/bench_pipeline.py [--minutes 15,60,600] [--methods inverse,raw,...]
                                        [--no-first-run]

``four_wheel`` among the methods is the default method with ``[vehicle] model = "four_wheel"``
(issue 37: the rear axle's fit, then the front axle's and the steering's); the drives then carry
a four-wheel car's front wheels and steering (:func:`odocal.sim.four_wheel.with_front_axle`),
which the other methods leave unread.

For each simulated drive (realistic noise) and method, ``odocal calibrate`` runs as a separate
process once with the report (the wall time a user waits, and the peak memory of the process
tree) and three times with ``--no-report``. The split by stage comes from ``timings_s`` in
calibration.json (each stage's best of the three runs: the machine's noise only adds time);
"start" is the rest of the fastest ``--no-report`` run (starting Python, imports, writing the
file) and "report" the difference between the run with the report and that one. The last
column is the wall time per hour of driving, and "x default" the wall time over the default
method's on the same drive, in the same run (the machine is shared: ratios travel, seconds less).

"first run" is the one-hour drive's wall time with the report on a fresh install: numba's cache
pointed at an empty folder (``NUMBA_CACHE_DIR``), so every kernel the method uses is compiled
then, as on a user's first run; beside it the same run warm and their ratio.

Issue 30's targets are printed against the figures: every method within 1.5x of the default
for one hour with its report; ten hours in at most 15 s and under 800 MB for every method; the
first run after a fresh install within 1.5x of a warm one.

Wall time is a fixed cost (starting Python, imports, numba loading its kernels: about 1 s) plus
a cost per hour of driving, so the wall time per hour of a 15-minute drive is mostly the fixed
cost. Linear growth is checked on the computation (the stages' sum): its time per hour between
successive lengths (15 min to 1 h, 1 h to 4 h) should not grow by more than 20%. It falls where
fixed costs inside the stages (numba's first calls, a few tenths of a second) spread over more
driving; on a quiet machine the spread between the two is within about 20%, but noise of a few
hundredths of a second in a 15-minute drive's stages moves the first figure by 0.1 s/h.

Before timing, one untimed run compiles and caches the numba kernels.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _measure import run_measured

import odocal
from odocal.estimators import METHOD_NAMES
from odocal.sim.four_wheel import with_front_axle

#: Runs without the report per drive and method (each stage's best is kept).
RUNS = 3
#: Issue 30's targets: one hour with its report within this many times the default's...
TARGET_RATIO = 1.5
#: ...ten hours within these seconds and MB, for every method...
TARGET_10H_S, TARGET_10H_MB = 15.0, 800.0
#: ...and the first run after a fresh install within this many times a warm one.
TARGET_FIRST_RUN = 1.5
STAGES = ("read", "checks", "segments", "inverse: fit", "step 1: batches", "step 2: compensation",
          "step 3: identification", "identify", "bootstrap",
          "validation", "front axle")
#: The four-wheel model's row: the default method on the four-wheel model's settings.
FOUR_WHEEL = "four_wheel"


def _simulated(duration_s: float, seed: int, four_wheel: bool) -> odocal.Drive:
    sim = odocal.simulate(duration_s=duration_s, seed=seed)
    return (with_front_axle(sim)[0] if four_wheel else sim).drive


def _method_args(method: str, work: Path) -> list[str]:
    if method != FOUR_WHEEL:
        return ["--method", method]
    config = work / "four_wheel.toml"
    config.write_text('[vehicle]\nmodel = "four_wheel"\n')
    return ["--method", "inverse", "--config", str(config)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", default="15,60,600")
    parser.add_argument("--methods", default=",".join(METHOD_NAMES))
    parser.add_argument("--no-first-run", action="store_true")
    args = parser.parse_args()
    exe = str(Path(sys.executable).with_name("odocal"))
    work = Path(tempfile.mkdtemp(prefix="odocal-bench-"))
    warm = work / "warm.parquet"
    four = FOUR_WHEEL in args.methods.split(",")
    odocal.save_drive(_simulated(300, 99, four), warm)
    for method in args.methods.split(","):
        run_measured([exe, "calibrate", str(warm), "--out", str(work / "w"),
                      *_method_args(method, work), "-q"])
    print(f"{'drive':>8} {'method':<12} {'wall s':>7} {'peak MB':>8} {'start':>6} "
          + " ".join(f"{s.split(':')[0][:9]:>9}" for s in STAGES)
          + f" {'report':>7} {'s per h':>8} {'x default':>9}")
    compute: dict[str, list[tuple[float, float]]] = {}
    default_wall: dict[int, float] = {}
    verdicts: list[str] = []
    for minutes in (int(m) for m in args.minutes.split(",")):
        drive = work / f"drive{minutes}.parquet"
        odocal.save_drive(_simulated(60.0 * minutes, 1, four), drive)
        for method in args.methods.split(","):
            out = work / f"{method}{minutes}"
            wall, peak = run_measured([exe, "calibrate", str(drive), "--out", str(out),
                                       *_method_args(method, work), "-q"])
            walls, stage_runs = [], []
            for attempt in range(RUNS):
                folder = Path(f"{out}n{attempt}")
                bare, _ = run_measured([exe, "calibrate", str(drive), "--out", str(folder),
                                        *_method_args(method, work), "-q", "--no-report"])
                walls.append(bare)
                stage_runs.append(json.loads((folder / "calibration.json").read_text())
                                  ["timings_s"])
            # each stage's best over the runs: the machine's noise only ever adds time
            timings = {k: min(t[k] for t in stage_runs) for k in stage_runs[0]}
            bare = min(walls)
            start = bare - sum(timings.values())
            compute.setdefault(method, []).append((minutes / 60, sum(timings.values())))
            cells = " ".join(f"{timings[s]:>9.2f}" if s in timings else f"{'':>9}"
                             for s in STAGES)
            default_wall.setdefault(minutes, wall)
            print(f"{minutes:>5} min {method:<12} {wall:>7.2f} {peak:>8.0f} {start:>6.2f} "
                  f"{cells} {wall - bare:>7.2f} {wall / (minutes / 60):>8.2f} "
                  f"{wall / default_wall[minutes]:>9.2f}", flush=True)
            if minutes == 60:
                ratio = wall / default_wall[minutes]
                verdicts.append(f"  {method:<12} one hour with the report {wall:5.2f} s, "
                                f"{ratio:.2f}x the default's "
                                f"{'ok' if ratio <= TARGET_RATIO else 'MISS'} "
                                f"(target {TARGET_RATIO}x)")
            if minutes == 600:
                ok = wall <= TARGET_10H_S and peak < TARGET_10H_MB
                verdicts.append(f"  {method:<12} ten hours with the report {wall:5.1f} s, "
                                f"{peak:4.0f} MB {'ok' if ok else 'MISS'} "
                                f"(target <= {TARGET_10H_S:.0f} s, < {TARGET_10H_MB:.0f} MB)")
    if all(len(points) >= 2 for points in compute.values()):
        print("\ncomputation per hour of driving between successive lengths (it may fall, as fixed "
              "costs inside the stages spread over more driving; it should not grow by more "
              "than 20%)")
        for method, points in compute.items():
            pairs = list(itertools.pairwise(points))
            rates = [(t1 - t0) / (h1 - h0) for (h0, t0), (h1, t1) in pairs]
            growth = max(b / a - 1 for a, b in itertools.pairwise(rates)) if len(rates) > 1 \
                else 0.0
            cells = "  ".join(f"{h0 * 60:.0f}-{h1 * 60:.0f} min {r:.2f} s/h"
                              for ((h0, _), (h1, _)), r in zip(pairs, rates, strict=True))
            print(f"  {method:<12} {cells}  spread {100 * (max(rates) / min(rates) - 1):.0f}%, "
                  f"growth {100 * growth:+.0f}% {'ok' if growth <= 0.2 else 'MISS'}")

    if verdicts:
        print("\nagainst issue 30's targets")
        print("\n".join(verdicts))

    if not args.no_first_run:
        first_run(exe, work, args.methods.split(","))


def first_run(exe: str, work: Path, methods: list[str]) -> None:
    """A one-hour drive with the report: on a fresh install (an empty numba cache) and warm."""
    drive = work / "drive60.parquet"
    if not drive.exists():
        odocal.save_drive(_simulated(3600.0, 1, FOUR_WHEEL in methods), drive)
    print("\nfirst run after a fresh install (one hour, with the report; numba cache empty)")
    for method in methods:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tempfile.mkdtemp(prefix="nb-")))}
        cold, _ = run_measured([exe, "calibrate", str(drive), "--out", str(work / "cold"),
                                *_method_args(method, work), "-q"], env=env)
        warm = min(run_measured([exe, "calibrate", str(drive), "--out", str(work / "warm"),
                                 *_method_args(method, work), "-q"], env=env)[0]
                   for _ in range(2))
        print(f"  {method:<12} first run {cold:6.2f} s, warm {warm:6.2f} s: "
              f"{cold / warm:.2f}x {'ok' if cold <= TARGET_FIRST_RUN * warm else 'MISS'} "
              f"(target {TARGET_FIRST_RUN}x)", flush=True)


if __name__ == "__main__":
    main()
