"""Every subset of the shared Singapore scenes, calibrated by the default method (issue 36).

    PYTHONPATH=src python benchmarks/bench_subsets.py [--data ../shared/data]

The five nuScenes Singapore scenes of ``nuscenes-can-bus-mini``, every subset of them (31, of
which 26 have two or more scenes) calibrated through :func:`odocal.calibrate` as a user would
(``--scene`` repeated). Printed per subset: the status, t_r and its standard deviation (or why
it is not identified), the parameters identified and the departures the fit took in; then the
counts issue 36 quoted (subsets of two or more that stop at the iteration limit, that leave t_r
at its placeholder, that are refused) and every parameter a scene added took away. The same
rules are tests in ``tests/pipeline/test_real_subsets.py``; this prints the figures.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import time
from pathlib import Path

import odocal
from odocal.estimators.estimate import Status
from odocal.preprocess.convert import convert

SINGAPORE = ("scene-0061", "scene-0796", "scene-0916", "scene-1077", "scene-1100")
ROOT = Path(__file__).resolve().parents[1]


def _identified(result: odocal.CalibrationResult) -> set[str]:
    est = result.estimate
    return {n for n, ok in zip(est.theta.as_dict(), est.identified, strict=True) if ok}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    args = ap.parse_args()
    scenes = {d.name: d for d in convert("nuscenes", [args.data / "nuscenes-can-bus-mini"])}
    logging.disable(logging.WARNING)
    results: dict[frozenset[str], odocal.CalibrationResult] = {}
    start = time.perf_counter()
    print(f"{'subset':<34} {'status':<16} {'t_r m':>8} {'std':>7}  identified  departures")
    for k in range(1, len(SINGAPORE) + 1):
        for names in itertools.combinations(SINGAPORE, k):
            result = odocal.calibrate([scenes[n] for n in names])
            results[frozenset(names)] = result
            est = result.estimate
            ident = _identified(result)
            t_r = (f"{est.theta.t_r:8.4f} {est.std[2]:7.4f}" if "t_r" in ident
                   else f"{'held':>8} {'':>7}")
            departures = ",".join(d[0] for d in getattr(est.details, "departures", ()) or ())
            label = "+".join(n.removeprefix("scene-") for n in names)
            print(f"{label:<34} {est.status.name.lower():<16} {t_r}  "
                  f"{','.join(sorted(ident)) or '-':<10}  {departures or '-'}")
    many = {s: r for s, r in results.items() if len(s) >= 2}
    stopped = sum(r.estimate.status is Status.ITERATION_LIMIT for r in many.values())
    held = sum("t_r" not in _identified(r) for r in many.values())
    refused = sum(r.estimate.status is Status.REJECTED for r in many.values())
    lost = [f"{'+'.join(sorted(s))} + {n}: {p}"
            for s, r in results.items() for n in set(SINGAPORE) - s
            for p in sorted(_identified(r) - _identified(results[s | {n}]))]
    print(f"\nof {len(many)} subsets of two or more scenes: {stopped} stop at the iteration "
          f"limit, {held} leave t_r at its placeholder, {refused} refused")
    print(f"parameters a scene added took away: {len(lost)}")
    for line in lost:
        print("  " + line)
    print(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
