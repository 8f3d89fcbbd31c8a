"""The live path against drives that depart from the model (issue 32), 5 seeds per departure.

    python benchmarks/bench_departures_live.py [--seeds 5] [--only NAME,...] [--skip issue]
                                               [--duration 1200]

Two tables. First, the live path's own departures (``tests/online/departures.py``): each
simulated with a different value per seed (other delays, offsets, step sizes and times, parking
durations) and pushed one second at a time through an :class:`~odocal.OnlineCalibrator`, as
``odocal replay`` does. Printed per departure:

* **confident wrong**: the share of runs whose final estimate reports a parameter identified
  with the truth more than 3 of its standard deviations away (the target: 0); beside it, the
  same drives through batch (``odocal.calibrate``, against the truth at the end of the drive);
* **rejected**: runs that end ``REJECTED`` (a named finding, no numbers) and the findings;
* **not identified**: parameters reported not identified, summed over the runs;
* **false alarms**: alarms where nothing changed (or before the change);
* for changes of 1% or more: **detected** within 2 km of the change, the distance from the
  change to the alarm, and the alarm's size error against the true change (target: within a
  fifth).

Second, the issue's departures as ``benchmarks/bench_departures.py`` runs them on the batch path
(:data:`odocal.sim.departures.DEPARTURES`, every value, ``--seeds`` seeds, ``--duration`` s):
per departure and value the shares of runs ending confident wrong (for a change inside the log:
wrong against the truth after it where an alarm was raised, against both otherwise), refused
(``REJECTED``, a named finding), named (a finding or an alarm names the departure) and right,
with the largest |z| of a parameter reported identified.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from odocal.model.parameters import PARAMETER_NAMES  # noqa: E402
from odocal.online.calibrator import OnlineCalibrator  # noqa: E402
from tests.online import departures as dep  # noqa: E402

#: name -> one departed drive per seed (the value differs with the seed)
DEPARTURES: dict[str, Callable[[int], dep.Departed]] = {
    "parked after the drive": lambda s: dep.parked(
        s, drive_s=600, park_s=(300, 480, 600, 720, 420)[s % 5],
        jitter_m=(0.02, 0.01, 0.03, 0.02, 0.02)[s % 5], wheel_noise=s % 5 == 4),
    "30 s of wheel slip": lambda s: dep.slipping(
        s, duration_s=600, at_s=(250, 180, 320, 400, 280)[s % 5], slip_s=30,
        fraction=(0.3, 0.65, -0.4, 0.08, 0.15)[s % 5],
        wheels=("both", "left", "both", "both", "right")[s % 5]),
    "30 s reversing, unsigned wheels": lambda s: dep.reversing(
        s, duration_s=600, at_s=(200, 350, 150, 420, 280)[s % 5], reverse_s=30,
        speed_scale=(0.3, 0.2, 0.4, 0.25, 0.35)[s % 5]),
    "c_e step (tyre pressure)": lambda s: dep.stepped(
        s, duration_s=600, at_s=(300, 250, 350, 280, 320)[s % 5],
        relative=(-0.02, 0.01, 0.03, -0.01, 0.015)[s % 5]),
    "one wheel's circumference (c_d)": lambda s: dep.stepped(
        s, duration_s=600, at_s=(300, 260, 340, 290, 310)[s % 5],
        relative=(-0.01, 0.02, -0.015, 0.01, -0.02)[s % 5],
        wheel=("left", "right", "right", "left", "left")[s % 5]),
    "reference delayed": lambda s: dep.reference_delay(
        s, duration_s=600, delay_s=(0.25, -0.25, 0.35, 0.5, -0.4)[s % 5]),
    "a_y offset": lambda s: dep.lateral_offset(
        s, duration_s=600, offset_mps2=(0.5, -0.3, 0.8, -0.6, 0.2)[s % 5]),
    "wheel-rate offset": lambda s: dep.wheel_offset(
        s, duration_s=600, offset_revps=(0.05, 0.03, 0.08, 0.02, 0.1)[s % 5]),
    "truncated wheel speeds": lambda s: dep.truncated(
        s, duration_s=600, step=(1.0, 0.1, 2.0, 0.5, 1.0)[s % 5],
        unit=("rpm", "km/h", "rpm", "km/h", "km/h")[s % 5]),
    "one-sided turning": lambda s: dep.one_sided(
        s, duration_s=600, speed_mps=(10.0, 14.0, 8.0, 12.0, 16.0)[s % 5],
        pattern=("left", "slalom", "left", "slalom", "left")[s % 5]),
}


def run(d: dep.Departed, *, chunk: int = 40) -> dict[str, object]:
    """Push the drive and judge the end: confident wrong, rejected, alarms."""
    cal = OnlineCalibrator()
    cols = d.columns
    at_change: float | None = None
    for i in range(0, cols["t"].size, chunk):
        cal.push({k: v[i:i + chunk] for k, v in cols.items()})
        if d.change_t is not None and at_change is None and cols["t"][
                min(i + chunk, cols["t"].size - 1)] >= d.change_t:
            at_change = cal.distance_km
    est = cal.estimate()
    theta, std = est.theta.as_array(), est.std
    truth = d.truth.as_array()
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(std > 0, (theta - truth) / std, 0.0)
    wrong = [n for n, zz, ok in zip(PARAMETER_NAMES, z, est.identified, strict=True)
             if ok and abs(zz) > 3.0]
    rejected = est.status.name == "REJECTED"
    findings = [f.check.value for f in est.details.findings
                if int(f.severity) >= 1] if est.details is not None else []
    alarms = list(cal.alarms)
    hits = [a for a in alarms if d.change_t is not None and a.detected_t >= d.change_t]
    # the same drive through batch (odocal.calibrate), for comparison
    import odocal

    try:
        batch = odocal.calibrate(odocal.Drive.from_columns(cols)).estimate
    except odocal.OdocalError:
        batch_wrong = False
    else:
        b_std = batch.std
        with np.errstate(divide="ignore", invalid="ignore"):
            bz = np.where(b_std > 0, (batch.theta.as_array() - truth) / b_std, 0.0)
        batch_wrong = batch.status.name != "REJECTED" and bool(
            np.any(np.abs(bz[np.array(batch.identified)]) > 3.0))
    out: dict[str, object] = {
        "batch_wrong": batch_wrong,
        "wrong": wrong if not rejected else [], "rejected": rejected, "findings": findings,
        "held": 4 - sum(est.identified), "false": len(alarms) - len(hits[:1]) if d.changes
        else len(alarms), "max_z": float(np.max(np.abs(z))) if len(z) else 0.0}
    if d.changes:
        hit = hits[0] if hits else None
        out["detected_km"] = (hit.detected_distance_km - (at_change or 0.0)) if hit else None
        if hit is not None:
            true = d.change[hit.parameter]
            out["size_error"] = abs(hit.relative_change - true) / abs(true)
            out["size"] = (hit.relative_change, true, hit.parameter, hit.wheel)
    return out


def _issue_truths(name: str, sim: Any, value: float) -> list[np.ndarray]:
    """The true theta before (and, for a change, after) the change; a drift's at the end of
    the drive (bench_departures.py's, imported from beside this script)."""
    from bench_departures import _truths

    return _truths(name, sim, value)


def issue_table(seeds: int, duration: float, only: list[str]) -> None:
    from odocal.sim.departures import DEPARTURES, simulate_departure

    print(f"\nthe issue's departures on the live path ({seeds} seeds, {duration:g} s drives "
          "unless the departure sets its length)")
    print(f"{'departure':<18}{'value':>8}{'confident wrong':>17}{'refused':>9}{'named':>7}"
          f"{'right':>7}{'max |z|':>9}  findings / alarms")
    total = wrong_total = 0
    for name, departure in DEPARTURES.items():
        if only and not any(o in name for o in only):
            continue
        for value in departure.values:
            outcome: Counter[str] = Counter()
            worst, seen = 0.0, Counter()
            for seed in range(seeds):
                sim = simulate_departure(name, value, seed=seed, duration_s=duration)
                cal = OnlineCalibrator()
                cols = sim.drive.columns()
                for i in range(0, sim.drive.n_samples, 40):
                    cal.push({k: v[i:i + 40] for k, v in cols.items()})
                est = cal.estimate()
                truths = _issue_truths(name, sim, value)
                if len(truths) > 1 and cal.alarms:
                    truths = truths[1:]                # the estimate is of the part after it
                theta, std, ok = est.theta.as_array(), est.std, np.array(est.identified)
                with np.errstate(divide="ignore", invalid="ignore"):
                    z = [np.where(std > 0, (theta - t) / std, 0.0) for t in truths]
                best = min(z, key=lambda zz: float(np.max(np.abs(zz[ok]), initial=0.0)))
                largest = float(np.max(np.abs(best[ok]), initial=0.0))
                notes = [f.check.value for f in est.details.findings if int(f.severity) >= 0
                         and f.check.value not in ("data-repaired",)]
                notes += [f"alarm {a.parameter} {a.relative_change:+.2%}" for a in cal.alarms]
                seen.update(notes)
                if est.status.name == "REJECTED":
                    outcome["refused"] += 1
                elif largest > 3.0:
                    outcome["wrong"] += 1
                    worst = max(worst, largest)
                elif notes:
                    outcome["named"] += 1
                    worst = max(worst, largest)
                else:
                    outcome["right"] += 1
                    worst = max(worst, largest)
            total += seeds
            wrong_total += outcome["wrong"]
            print(f"{name:<18}{value:>8g}{outcome['wrong'] / seeds:>17.0%}"
                  f"{outcome['refused'] / seeds:>9.0%}{outcome['named'] / seeds:>7.0%}"
                  f"{outcome['right'] / seeds:>7.0%}{worst:>9.1f}  "
                  + ", ".join(f"{k} x{v}" for k, v in seen.most_common(4)), flush=True)
    print(f"confident wrong on the live path: {wrong_total} of {total} runs")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--only", default="")
    parser.add_argument("--skip", default="", help="own,issue: leave out a table")
    parser.add_argument("--duration", type=float, default=1200.0,
                        help="drive length of the issue's departures (s)")
    parser.add_argument("-v", "--verbose", action="store_true", help="a line per run")
    args = parser.parse_args()
    only = [n for n in args.only.split(",") if n]
    skip = set(args.skip.split(","))
    if "own" not in skip:
        own_table(args.seeds, only, args.verbose)
    if "issue" not in skip:
        issue_table(args.seeds, args.duration, only)


def own_table(seeds: int, only: list[str], verbose: bool) -> None:
    print(f"live path (OnlineCalibrator, 1 s chunks), {seeds} seeds per departure, "
          "each seed another value")
    print(f"{'departure':<34}{'confident wrong':>16}{'(batch)':>8}{'rejected':>9}{'not id.':>8}"
          f"{'false alarms':>13}{'detected <2 km':>15}{'km to alarm':>13}{'size error':>12}"
          f"{'s':>6}")
    for name, make in DEPARTURES.items():
        if only and not any(o in name for o in only):
            continue
        started = time.perf_counter()
        results = []
        for seed in range(seeds):
            d = make(seed)
            r = run(d)
            results.append((d, r))
            if verbose:
                print(f"    seed {seed}: {r}", flush=True)
        n = len(results)
        wrong = sum(bool(r["wrong"]) for _, r in results)
        batch_wrong = sum(bool(r["batch_wrong"]) for _, r in results)
        rejected = sum(bool(r["rejected"]) for _, r in results)
        held = sum(int(r["held"]) for _, r in results)  # type: ignore[call-overload]
        false = sum(int(r["false"]) for _, r in results)  # type: ignore[call-overload]
        changes = [r for d, r in results if d.changes]
        detected = sum(1 for r in changes if r.get("detected_km") is not None
                       and float(r["detected_km"]) <= 2.0)  # type: ignore[arg-type]
        km = [float(r["detected_km"]) for r in changes  # type: ignore[arg-type]
              if r.get("detected_km") is not None]
        err = [float(r["size_error"]) for r in changes  # type: ignore[arg-type]
               if r.get("size_error") is not None]
        print(f"{name:<34}{f'{wrong}/{n}':>16}{f'{batch_wrong}/{n}':>8}{f'{rejected}/{n}':>9}"
              f"{held:>8}{false:>13}"
              + (f"{f'{detected}/{len(changes)}':>15}"
                 f"{f'{np.median(km):.2f} / {max(km):.2f}' if km else '-':>13}"
                 f"{f'{max(err) * 100:.0f}%' if err else '-':>12}" if changes
                 else f"{'':>15}{'':>13}{'':>12}")
              + f"{time.perf_counter() - started:6.0f}", flush=True)
        named = Counter(f for _, r in results for f in r["findings"])  # type: ignore[attr-defined]
        if named:
            print(f"{'':<6}findings: " + ", ".join(f"{k} x{v}" for k, v in named.most_common()))
        for _, r in results:
            if r["wrong"]:
                print(f"{'':<6}confident wrong: {', '.join(r['wrong'])}"  # type: ignore[arg-type]
                      f" (largest |z| {r['max_z']:.1f})")
    print("km to alarm: median / largest distance from the change to the alarm; size error: "
          "the largest |alarm - truth| / |truth|")


if __name__ == "__main__":
    main()
