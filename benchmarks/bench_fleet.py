"""Fleets: throughput on the local Dask cluster, and drift detection against a simulated truth.

    python benchmarks/bench_fleet.py [--skip throughput,detection] [--vehicles 20]
        [--drives 10] [--duration 900] [--sizes 0.001,0.002,0.0035] [--detect-vehicles 20]
        [--quiet-vehicles 40]

Printed:

* **throughput**: ``--vehicles`` x ``--drives`` simulated drives of ``--duration`` s (no events)
  calibrated on the embedded local cluster with 1 and with 2 worker processes: wall time, drives
  per minute, speed-up, peak memory (RSS) of each worker, and whether both runs stored the same
  answers (to the last digit);
* **detection**: per pressure-loss size, ``--detect-vehicles`` vehicles of 12 ten-minute drives,
  the loss at a random drive (6 to 8): share of vehicles whose c_e change is detected within 5
  drives, and the median and 90th percentile delay in drives and km; alarms before the loss
  count as false;
* **false alarms** per 1,000 drives without an event: the throughput fleet, ``--quiet-vehicles``
  more vehicles of 12 ten-minute drives, and every drive before a loss.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from odocal.fleet.engine import calibrate_fleet, dask_client
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import open_store


def _worker_rss_mb(client: Any) -> list[float]:
    def rss() -> float:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    return sorted(client.run(rss).values())


def _answers(store: Path) -> dict[str, tuple[Any, ...]]:
    with open_store(store, create=False) as db:
        return {r["task_key"]: (r["c_e"], r["c_d"], r["t_r"], r["d"], r["c_e_std"], r["status"])
                for r in db.drives()}


def throughput(tmp: Path, vehicles: int, drives: int, duration: float) -> tuple[int, int]:
    started = time.perf_counter()
    fleet = simulate_fleet(tmp / "tp", vehicles=vehicles, drives=drives, duration_s=duration,
                           seed=100, plan="none")
    print(f"simulated {fleet.drives} drives of {duration:.0f} s in "
          f"{time.perf_counter() - started:.0f} s")
    lines = fleet.catalog.read_text().splitlines()
    warm = fleet.catalog.with_name("warm.csv")
    warm.write_text("\n".join(lines[:3]) + "\n")
    stores = {}
    rates = {}
    for workers in (1, 2):
        store = tmp / f"tp{workers}.db"
        with dask_client(workers=workers) as client:
            calibrate_fleet(warm, tmp / f"warm{workers}.db", client=client)   # import, compile
            started = time.perf_counter()
            run = calibrate_fleet(fleet.catalog, store, client=client)
            wall = time.perf_counter() - started
            memory = _worker_rss_mb(client)
        rates[workers] = run.calibrated / wall * 60.0
        stores[workers] = store
        print(f"{workers} worker(s): {run.calibrated} drives in {wall:.1f} s = "
              f"{rates[workers]:.1f} drives/min; peak RSS per worker "
              f"{', '.join(f'{m:.0f}' for m in memory)} MB; {run.failed} failed")
    same = _answers(stores[1]) == _answers(stores[2])
    print(f"speed-up 2 vs 1 worker: {rates[2] / rates[1]:.2f}x (target >= 1.7x); "
          f"same answers: {same}")
    alarms = len(run.alarms)
    print(f"alarms on these event-free drives: {alarms}")
    return fleet.drives, alarms


def detection(tmp: Path, sizes: list[float], vehicles: int, quiet: int) -> tuple[int, int]:
    quiet_drives, false_alarms = 0, 0
    with dask_client() as client:
        for size in sizes:
            fleet = simulate_fleet(tmp / f"p{size}", vehicles=vehicles, drives=12,
                                   duration_s=600.0, seed=int(size * 1e5), plan="pressure",
                                   size=size)
            run = calibrate_fleet(fleet.catalog, tmp / f"p{size}.db", client=client)
            truth = json.loads(fleet.truth.read_text())
            delays, kms, detected = [], [], 0
            for e in truth["events"]:
                if e["kind"] != "pressure":
                    continue
                quiet_drives += e["drive"]
                mine = [a for a in run.alarms if a.vehicle == e["vehicle"]]
                false_alarms += sum(1 for a in mine if a.time.isoformat() < e["time"])
                hits = [a for a in mine if a.parameter == "c_e"
                        and a.time.isoformat() >= e["time"]]
                if not hits:
                    continue
                first = min(hits, key=lambda a: a.detected_time)
                history = truth["vehicles"][e["vehicle"]]["drives"]
                index = next(d["drive"] for d in history
                             if d["time"] == first.detected_time.isoformat())
                delay = index - e["drive"] + 1
                delays.append(delay)
                kms.append(first.km_to_detect)
                detected += delay <= 5
            n = sum(1 for e in truth["events"] if e["kind"] == "pressure")
            print(f"pressure loss {size * 100:.2f}% of c_e: detected within 5 drives in "
                  f"{detected}/{n} vehicles ({detected / n * 100:.0f}%, target 95% at 0.2%); "
                  f"delay median {np.median(delays) if delays else float('nan'):.0f} drives, "
                  f"90th percentile {np.percentile(delays, 90) if delays else float('nan'):.0f}"
                  f" drives; km median {np.median(kms) if kms else float('nan'):.1f}")
        fleet = simulate_fleet(tmp / "quiet", vehicles=quiet, drives=12, duration_s=600.0,
                               seed=7, plan="none")
        run = calibrate_fleet(fleet.catalog, tmp / "quiet.db", client=client)
        quiet_drives += fleet.drives
        false_alarms += len(run.alarms)
    print(f"false alarms: {false_alarms} on {quiet_drives} event-free drives of the detection "
          "fleets")
    return quiet_drives, false_alarms


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--skip", default="")
    ap.add_argument("--vehicles", type=int, default=20)
    ap.add_argument("--drives", type=int, default=10)
    ap.add_argument("--duration", type=float, default=900.0)
    ap.add_argument("--sizes", default="0.001,0.002,0.0035")
    ap.add_argument("--detect-vehicles", type=int, default=20)
    ap.add_argument("--quiet-vehicles", type=int, default=40)
    args = ap.parse_args()
    skip = set(args.skip.split(","))
    quiet_drives = alarms = 0
    with tempfile.TemporaryDirectory() as tmp:
        if "throughput" not in skip:
            quiet_drives, alarms = throughput(Path(tmp), args.vehicles, args.drives,
                                              args.duration)
        if "detection" not in skip:
            more_drives, more_alarms = detection(Path(tmp), [float(s) for s in
                                                             args.sizes.split(",")],
                                                 args.detect_vehicles, args.quiet_vehicles)
            quiet_drives += more_drives
            alarms += more_alarms
    if quiet_drives:
        print(f"false alarms per 1,000 event-free drives: {alarms / quiet_drives * 1000:.1f} "
              f"({alarms} on {quiet_drives}; target < 5)")


if __name__ == "__main__":
    main()
