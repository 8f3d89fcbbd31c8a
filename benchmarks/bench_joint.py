"""Speed of the joint estimator (issue 6): one Gauss-Newton step and the whole calibration.

    python benchmarks/bench_joint.py [--minutes 15,60,240]

For each drive length (simulated, realistic noise): the time of one Gauss-Newton step (assembling
and factorising the banded normal equations and solving through the Schur complement), and the
wall time and peak memory of ``odocal calibrate --method joint`` as a separate process.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import odocal
from odocal import joint
from odocal.settings import Settings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import run_measured


def step_time(drive: odocal.Drive, settings: Settings, repeat: int = 5) -> tuple[float, int]:
    """Median seconds of one assembled-and-solved Gauss-Newton step, and the unknowns."""
    data = joint._gather([drive], round(settings.joint.block_s / drive.t_s))
    noise = joint._initial_noise(settings)
    wt = joint._Weights.of(data, noise)
    z = np.concatenate([data.y, np.zeros((data.y.shape[0], 2))], axis=1)
    theta = np.asarray(settings.identify.theta0, dtype=np.float64)
    free = np.ones(4, dtype=bool)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        system = joint._assemble(z, theta, free, data, wt)
        joint._solve(system, system.g_z, system.g_t)
        times.append(time.perf_counter() - start)
    return statistics.median(times), z.size + 4


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", default="15,60,240")
    args = parser.parse_args()
    settings = Settings()
    print(f"{'drive':>8} {'samples':>8} {'unknowns':>9} {'G-N step s':>11} {'wall s':>7} "
          f"{'peak MB':>8}  iterations, noise rounds")
    for minutes in (float(m) for m in args.minutes.split(",")):
        sim = odocal.simulate(duration_s=minutes * 60, seed=1)
        step, unknowns = step_time(sim.drive, settings)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "drive.parquet"
            odocal.save_drive(sim.drive, path)
            out = Path(tmp) / "out"
            wall, peak = run_measured([sys.executable, "-m", "odocal.cli", "calibrate", str(path),
                                       "--out", str(out), "--method", "joint", "-q",
                                       "--no-report"])
            info = json.loads((out / "calibration.json").read_text())["joint"]
        print(f"{minutes:>6.0f} min {sim.drive.n_samples:>8} {unknowns:>9} {step:>11.4f} "
              f"{wall:>7.1f} {peak:>8.0f}  {info['iterations']}, "
              f"{len(info['noise_history']) - 1}")


if __name__ == "__main__":
    main()
