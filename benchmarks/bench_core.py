"""Core timings (issue 2): one batch Gauss-Newton, and `odocal calibrate` on a one-hour drive.

    python benchmarks/bench_core.py [--repeat 20] [--duration 3600]

Prints the median time of one batch G-N identification (N = 10 segments, K = 650, from the
datasheet values, the paper's i_max = 5) and the wall time and peak memory of the command
``odocal calibrate`` on a simulated one-hour drive (both methods), run as a subprocess so that
reading the file and starting Python are included.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import odocal
from odocal.data.segments import gather, identification_segments
from odocal.estimators.gauss_newton import gauss_newton
from odocal.settings import Settings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import run_measured


def batch_gauss_newton(repeat: int) -> None:
    settings = Settings()
    sim = odocal.simulate(duration_s=3600, seed=1, noise="realistic")
    segs = identification_segments([sim.drive], settings.segments)
    selected = np.flatnonzero(segs.selected)
    rng = np.random.default_rng(0)
    times = []
    iterations = []
    for _ in range(repeat):
        batch = gather([sim.drive], segs.subset(rng.choice(selected, 10, replace=False)))
        start = time.perf_counter()
        result = gauss_newton(batch, settings=settings.identify)
        times.append(time.perf_counter() - start)
        iterations.append(result.iterations)
    print(f"batch G-N, N = 10 segments, K = 650: median {statistics.median(times) * 1e3:.1f} ms, "
          f"min {min(times) * 1e3:.1f} ms, max {max(times) * 1e3:.1f} ms over {repeat} batches "
          f"({statistics.mean(iterations):.1f} iterations on average)")


def calibrate_command(duration: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        drive = Path(tmp) / "drive.parquet"
        odocal.save_drive(odocal.simulate(duration_s=duration, seed=1, noise="realistic").drive,
                          drive)
        for method in ("raw", "compensated"):
            wall, peak_mb = run_measured([sys.executable, "-m", "odocal", "calibrate",
                                          str(drive), "--out", str(Path(tmp) / method),
                                          "--method", method, "-q", "--no-report"])
            print(f"odocal calibrate --method {method} --no-report, "
                  f"{duration / 60:.0f}-minute drive: {wall:.1f} s wall, peak memory "
                  f"{peak_mb:.0f} MB (PSS, all processes)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--duration", type=float, default=3600.0)
    args = parser.parse_args()
    batch_gauss_newton(args.repeat)
    calibrate_command(args.duration)


if __name__ == "__main__":
    main()
