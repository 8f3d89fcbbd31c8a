"""Evidence (issues 3 and 6): raw batch G-N and the three-step method.

    python benchmarks/bench_bias.py [--seeds 10] [--duration 1800] [--profiles white,slip,...]
                                    [--out results.json]

For every noisy simulator profile and seed, one calibration drive and one held-out validation drive
(another seed) are simulated. On the same selected segments of the calibration drive:

* ``raw``          batch G-N on all selected segments with the measured rates
* ``compensated``  the three-step method (step-1 batches, compensation, step 3 on all segments)
* ``raw-10``       batch G-N on one random batch of N = 10 (the paper's unit of comparison)
* ``comp-10``      step 3 on the same batch of 10 with its compensated rates (theta_BF)
* ``oracle``       step 3 on all segments with rates compensated with the *true* parameters: what
                   compensation gives when step 1 is perfect (a diagnostic of inheritance)

Printed per profile: each parameter's error against the truth (mean and standard deviation over
seeds), E_p on the held-out drives relative to the true parameters' E_p (mean over seeds), and for
every method's reported covariance the spread of error / reported std over seeds (1 is honest).
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

import odocal
from odocal.data.segments import (
    gather,
    gather_ragged,
    identification_segments,
    validation_segments,
)
from odocal.estimators.compensation import compensate_batch
from odocal.estimators.gauss_newton import gauss_newton
from odocal.estimators.validation import mean_error
from odocal.model.parameters import PARAMETER_NAMES
from odocal.settings import Settings

ARMS = ("raw", "compensated", "raw-10", "comp-10", "oracle")
REPORTED = ("raw", "compensated")
SCALE = np.array([1e3, 1e3, 1e3, 1e3])   # report every error in mm (or mm per m/s^2)


def one_run(profile: str, seed: int, duration: float, settings: Settings) -> dict[str, Any]:
    sim = odocal.simulate(duration_s=duration, seed=seed, noise=profile)
    held_out = odocal.simulate(duration_s=duration / 2, seed=10_000 + seed, noise=profile)
    truth = sim.true_parameters.as_array()
    drives = [sim.drive]
    segs = identification_segments(drives, settings.segments)
    selected = segs.subset(segs.selected)
    batch = gather(drives, selected)
    val = gather_ragged([held_out.drive], validation_segments([held_out.drive],
                                                               settings.segments))
    thetas: dict[str, np.ndarray] = {}
    stds: dict[str, list[float]] = {}

    raw = odocal.calibrate(sim.drive, settings=settings, method="raw")
    thetas["raw"] = raw.theta.as_array()
    comp = odocal.calibrate(sim.drive, settings=settings, method="compensated")
    thetas["compensated"] = comp.theta.as_array()
    for arm, result in (("raw", raw), ("compensated", comp)):
        stds[arm] = result.estimate.std.tolist()
    outcome = comp.three_step
    assert outcome is not None

    rng = np.random.default_rng(seed)
    ten = np.sort(rng.choice(len(batch), size=min(10, len(batch)), replace=False))
    thetas["raw-10"] = gauss_newton(batch.take(ten), settings=settings.identify).theta.as_array()
    c = outcome.compensation
    comp10 = batch.take(ten).with_wheel_rates(c.n_rl[ten], c.n_rr[ten])
    thetas["comp-10"] = gauss_newton(comp10, settings=settings.identify).theta.as_array()

    oracle = compensate_batch(batch, truth[None, :], settings.compensate, workers=2)
    thetas["oracle"] = gauss_newton(batch.with_wheel_rates(oracle.n_rl, oracle.n_rr),
                                    settings=settings.identify).theta.as_array()

    e_true = mean_error(truth, val)
    return {
        "profile": profile, "seed": seed,
        "error": {arm: (thetas[arm] - truth).tolist() for arm in ARMS},
        "E_p_ratio": {arm: mean_error(thetas[arm], val) / e_true for arm in ARMS},
        "E_p_true_m": e_true,
        "std": stds,
        "step1_picked_mean_error": (outcome.step1.thetas[outcome.step1.picked].mean(axis=0)
                                    - truth).tolist(),
    }


def summarise(runs: list[dict[str, Any]], profile: str) -> None:
    rows = [r for r in runs if r["profile"] == profile]
    print(f"\n== profile '{profile}': {len(rows)} seeds; errors in mm (d in mm per m/s^2) "
          "as mean +- std over seeds; E_p on held-out drives / E_p of the true parameters")
    print(f"  {'arm':<12}" + "".join(f"{n:>18}" for n in PARAMETER_NAMES) + f"{'E_p ratio':>12}")
    for arm in ARMS:
        err = np.array([r["error"][arm] for r in rows]) * SCALE
        ratio = np.array([r["E_p_ratio"][arm] for r in rows])
        cells = "".join(f"{m:>+9.3f} +-{s:6.3f}" for m, s in zip(err.mean(0), err.std(0),
                                                                  strict=True))
        print(f"  {arm:<12}{cells}{ratio.mean():>12.4f}")
    for arm in REPORTED:
        err = np.array([r["error"][arm] for r in rows])
        std = np.array([r["std"][arm] for r in rows])
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(std > 0, err / std, np.nan)
        print(f"  {arm:<12} error / reported std over seeds: spread "
              + ", ".join(f"{n} {np.nanstd(z[:, j]):.2f}" for j, n in enumerate(PARAMETER_NAMES))
              + "; RMS " + ", ".join(f"{np.sqrt(np.nanmean(z[:, j] ** 2)):.2f}"
                                      for j in range(4)))
    picked = np.array([r["step1_picked_mean_error"] for r in rows]) * SCALE
    cells = "".join(f"{m:>+9.3f} +-{s:6.3f}" for m, s in zip(picked.mean(0), picked.std(0),
                                                              strict=True))
    print(f"  {'step1 mean':<12}{cells}   (mean of the five step-1 sets compensation used)")
    comp = np.array([r["error"]["compensated"] for r in rows])
    pick = np.array([r["step1_picked_mean_error"] for r in rows])
    corr = [np.corrcoef(comp[:, j], pick[:, j])[0, 1] for j in range(4)]
    print("  correlation over seeds of the three-step error with the step-1 sets' mean error: "
          + ", ".join(f"{n} {c:+.2f}" for n, c in zip(PARAMETER_NAMES, corr, strict=True)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--duration", type=float, default=1800.0)
    parser.add_argument("--profiles", default="white,slip,quantised,reference,realistic")
    parser.add_argument("--out", help="write every run as JSON")
    args = parser.parse_args()
    settings = Settings()
    runs: list[dict[str, Any]] = []
    started = time.perf_counter()
    for profile in args.profiles.split(","):
        for seed in range(args.seeds):
            runs.append(one_run(profile, seed, args.duration, settings))
        summarise(runs, profile)
    print(f"\n{len(runs)} runs in {time.perf_counter() - started:.0f} s")
    if args.out:
        with open(args.out, "w", encoding="utf-8") as handle:
            json.dump(runs, handle, indent=1)


if __name__ == "__main__":
    main()
