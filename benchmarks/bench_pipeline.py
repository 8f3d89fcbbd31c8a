"""Speed of ``odocal calibrate`` by stage, for every method and drive length (issue 14).

    python benchmarks/bench_pipeline.py [--minutes 15,60,240] [--methods inverse,raw,...]

For each simulated drive (realistic noise) and method, ``odocal calibrate`` runs as a separate
process once with the report (the wall time a user waits, and the peak memory of the process
tree) and three times with ``--no-report``. The split by stage comes from ``timings_s`` in
calibration.json (each stage's best of the three runs: the machine's noise only adds time);
"start" is the rest of the fastest ``--no-report`` run (starting Python, imports, writing the
file) and "report" the difference between the run with the report and that one. The last
column is the wall time per hour of driving.

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
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _measure import run_measured

import odocal
from odocal.estimators import METHOD_NAMES

#: Runs without the report per drive and method (each stage's best is kept).
RUNS = 3
STAGES = ("read", "checks", "segments", "inverse: fit", "step 1: batches", "step 2: compensation",
          "step 3: identification", "identify", "bootstrap",
          "validation")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", default="15,60,240")
    parser.add_argument("--methods", default=",".join(METHOD_NAMES))
    args = parser.parse_args()
    exe = str(Path(sys.executable).with_name("odocal"))
    work = Path(tempfile.mkdtemp(prefix="odocal-bench-"))
    warm = work / "warm.parquet"
    odocal.save_drive(odocal.simulate(duration_s=300, seed=99).drive, warm)
    for method in args.methods.split(","):
        run_measured([exe, "calibrate", str(warm), "--out", str(work / "w"), "--method", method,
                      "-q"])
    print(f"{'drive':>8} {'method':<12} {'wall s':>7} {'peak MB':>8} {'start':>6} "
          + " ".join(f"{s.split(':')[0][:9]:>9}" for s in STAGES)
          + f" {'report':>7} {'s per h':>8}")
    compute: dict[str, list[tuple[float, float]]] = {}
    for minutes in (int(m) for m in args.minutes.split(",")):
        drive = work / f"drive{minutes}.parquet"
        odocal.save_drive(odocal.simulate(duration_s=60.0 * minutes, seed=1).drive, drive)
        for method in args.methods.split(","):
            out = work / f"{method}{minutes}"
            wall, peak = run_measured([exe, "calibrate", str(drive), "--out", str(out),
                                       "--method", method, "-q"])
            walls, stage_runs = [], []
            for attempt in range(RUNS):
                folder = Path(f"{out}n{attempt}")
                bare, _ = run_measured([exe, "calibrate", str(drive), "--out", str(folder),
                                        "--method", method, "-q", "--no-report"])
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
            print(f"{minutes:>5} min {method:<12} {wall:>7.2f} {peak:>8.0f} {start:>6.2f} "
                  f"{cells} {wall - bare:>7.2f} {wall / (minutes / 60):>8.2f}", flush=True)
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

if __name__ == "__main__":
    main()
