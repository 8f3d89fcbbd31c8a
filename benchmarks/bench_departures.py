"""Departures from the model: is a calibration ever confidently wrong? (issue 32)

    python benchmarks/bench_departures.py [--seeds 5] [--duration 1200] [--methods inverse]
                                          [--departures reference-late,...] [--noise realistic]
                                          [--out runs.json]

Every departure of :data:`odocal.sim.departures.DEPARTURES` at each of its values, on
``--seeds`` simulated drives (truth known), is calibrated by each method through
:func:`odocal.calibrate` (the checks, the fit, the gate: what a user gets). A run ends

* **confident wrong**: a parameter reported identified lies more than three of its own standard
  deviations from the truth (for a change inside the log, from the truth after the change, where
  the calibration says it calibrated the part after the change; from both otherwise);
* **refused**: the checks or the gate reject the calibration (exit 3) with a named finding;
* **named**: it stands, with a finding that names the departure (a change, front wheels, ...);
* **right**: every identified parameter within three standard deviations.

Printed per departure, value and method: the shares of the four outcomes over the seeds, the
largest |z| of an identified parameter, the parameters reported identified, and the findings
seen. The target (issue 32): no confident wrong number for the default method.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from typing import Any

import numpy as np

import odocal
from odocal.model.parameters import PARAMETER_NAMES
from odocal.settings import Settings
from odocal.sim.departures import DEPARTURES, simulate_departure


def _truths(name: str, sim: Any, value: float) -> list[np.ndarray]:
    """The true theta before (and, for a change, after) the change."""
    first = sim.true_parameters.as_array()
    if name == "c_e-change":
        after = first.copy()
        after[0] *= 1.0 + value
        return [first, after]
    if name == "drift":
        end = first.copy()
        end[0] *= 1.0 + value
        return [end]
    if name == "pressure-change":
        left = first[0] + 0.5 * first[1]
        after = first.copy()
        after[0] -= 0.5 * value * left
        after[1] -= value * left
        return [first, after]
    return [first]


def one_run(name: str, value: float, seed: int, method: str, settings: Settings,
            noise: str, duration: float) -> dict[str, Any]:
    sim = simulate_departure(name, value, seed=seed, noise=noise, duration_s=duration)
    started = time.perf_counter()
    result = odocal.calibrate(sim.drive, settings=settings, method=method)
    est = result.estimate
    findings = [f.check.value for f in result.diagnosis.findings] if result.diagnosis else []
    refused = result.diagnosis is not None and result.diagnosis.fatal
    identified = np.array(est.identified)
    std = est.std
    zs = []
    for truth in _truths(name, sim, value):
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(identified & (std > 0), (est.theta.as_array() - truth) / std, 0.0)
        zs.append(z)
    z_best = min(zs, key=lambda z: float(np.max(np.abs(z))))
    wrong = bool(not refused and est.success and np.max(np.abs(z_best)) > 3.0)
    return {"departure": name, "value": value, "seed": seed, "method": method,
            "z": z_best.tolist(), "identified": identified.tolist(), "refused": refused,
            "success": est.success, "findings": findings, "wrong": wrong,
            "seconds": time.perf_counter() - started}


def _outcome(run: dict[str, Any], expected: set[str]) -> str:
    if run["wrong"]:
        return "wrong"
    if run["refused"]:
        return "refused"
    if expected & set(run["findings"]):
        return "named"
    return "right"


#: Findings that name each departure (a run that ends with one of them is "named").
NAMES = {"reference-late": {"reference-sync", "clock-offset", "reference-lag"},
         "heading-error": {"reference-heading", "heading-error"},
         "c_e-change": {"change-in-log"}, "pressure-change": {"change-in-log"},
         "front-wheels": {"front-wheels", "curve-excess"},
         "wheel-offset": {"wheel-offset", "moving-offset"},
         "a_y-offset": {"lateral-offset"}, "one-wheel-offset": {"wheel-skew"},
         "filtered-rates": {"reference-lag", "wheel-smoothing"},
         "a_y-scale": {"lateral-gain"}, "drift": {"drift"},
         "arm-ahead": {"reference-arm"}, "arm-left": {"reference-arm"}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--methods", default="inverse")
    ap.add_argument("--departures", default=",".join(DEPARTURES))
    ap.add_argument("--noise", default="realistic")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    settings = Settings()
    methods = args.methods.split(",")
    runs = []
    started = time.perf_counter()
    print(f"{'departure':16s} {'value':>6s} {'method':12s} {'wrong':>6s} {'refused':>7s} "
          f"{'named':>6s} {'right':>6s} {'max|z|':>7s}  identified (of seeds)  findings")
    for name in args.departures.split(","):
        dep = DEPARTURES[name]
        for value in dep.values:
            for method in methods:
                mine = [one_run(name, value, seed, method, settings, args.noise, args.duration)
                        for seed in range(args.seeds)]
                runs.extend(mine)
                counts = Counter(_outcome(r, NAMES.get(name, set())) for r in mine)
                zmax = max(float(np.max(np.abs(r["z"]))) for r in mine)
                ident = np.sum([r["identified"] for r in mine], axis=0)
                ident_text = " ".join(f"{p}:{int(k)}" for p, k in zip(PARAMETER_NAMES, ident,
                                                                       strict=True))
                seen = Counter(f for r in mine for f in set(r["findings"]))
                n = len(mine)
                print(f"{name:16s} {value:6g} {method:12s} {counts['wrong'] / n:6.0%} "
                      f"{counts['refused'] / n:7.0%} {counts['named'] / n:6.0%} "
                      f"{counts['right'] / n:6.0%} {zmax:7.1f}  {ident_text}  "
                      f"{', '.join(f'{k}:{c}' for k, c in sorted(seen.items()))}", flush=True)
    print()
    for method in methods:
        mine = [r for r in runs if r["method"] == method]
        wrong = sum(r["wrong"] for r in mine)
        print(f"{method}: {wrong} of {len(mine)} runs confidently wrong "
              f"({wrong / max(len(mine), 1):.1%})")
    print(f"({time.perf_counter() - started:.0f} s)")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(runs, f)


if __name__ == "__main__":
    main()
