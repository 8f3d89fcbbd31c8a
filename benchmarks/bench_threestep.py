"""Speed and memory of the whole three-step calibration (issue 3) against drive length.

    python benchmarks/bench_threestep.py [--minutes 15,60,240] [--method compensated]

For each length a realistic drive is simulated and written to Parquet, then
``odocal calibrate --method compensated`` runs on it as a separate process (reading the file,
calibrating, validating, writing calibration.json; ``--report`` adds report.html); its wall time
and the peak memory of its whole process tree (PSS, workers included) are printed with the time
of each step from calibration.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import odocal

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import run_measured


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", default="15,60,240")
    parser.add_argument("--method", default="compensated")
    parser.add_argument("--report", action="store_true",
                        help="also write report.html (by default only calibration.json)")
    args = parser.parse_args()
    extra = [] if args.report else ["--no-report"]
    print(f"{'drive':>8} {'segments':>9} {'selected':>9} {'wall s':>8} {'peak MB':>8}   steps (s)")
    for minutes in (float(m) for m in args.minutes.split(",")):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "drive.parquet"
            odocal.save_drive(odocal.simulate(duration_s=minutes * 60, seed=1).drive, path)
            out = Path(tmp) / "out"
            wall, peak = run_measured([sys.executable, "-m", "odocal", "calibrate", str(path),
                                       "--out", str(out), "--method", args.method, "-q",
                                       *extra])
            data = json.loads((out / "calibration.json").read_text())
            steps = data.get("three_step", {}).get("timings_s", {})
            step_text = ", ".join(f"{k} {v:.1f}" for k, v in steps.items())
            print(f"{minutes:>6.0f} min {data['segments_total']:>9} {data['segments_used']:>9} "
                  f"{wall:>8.1f} {peak:>8.0f}   {step_text}")


if __name__ == "__main__":
    main()
