"""How close a method comes to the Cramér-Rao bound: one route, many draws of the noise alone.

    python benchmarks/bench_bound.py [--draws 100] [--route 0] [--duration 1200]
                                     [--methods inverse] [--profiles white-5x,markov,...]

For each profile, one simulated route (``--route`` seeds it) is driven with ``--draws`` draws of
the profile's noise (``simulate(noise_seed=...)``) and calibrated by each method. Printed per
parameter (mm, d in mm per m/s^2): the route's Cramér-Rao bound (:mod:`odocal.sim.bound`: the
smallest std any unbiased calibration can have with these wheel errors), the method's error std
over the draws, its mean error with the mean's standard error, the mean reported std, the
efficiency (bound^2 / error variance: 1 is the best any unbiased method can do; below 1, the
share of the data's information the method uses) and the mean |error|. The bound applies to
profiles whose wheel errors it counts and that count no ticks (:func:`odocal.sim.bound.applies`);
with the reference pose exact and the wheel errors only the ones the bound counts, an
efficiency near 1 says nothing is left to gain on that profile (the bound is above the true one
by at most 0.6% of a std: see :mod:`odocal.sim.bound`).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import odocal
from odocal.model.parameters import PARAMETER_NAMES
from odocal.settings import Settings
from odocal.sim.bound import applies
from odocal.sim.noise import NOISE_PROFILES

MM = 1e3
PROFILES = "white-5x,markov,heavy,slip,slip-heavy"


def one_profile(profile: str, route: int, draws: int, duration: float, methods: list[str],
                settings: Settings) -> None:
    first = odocal.simulate(duration_s=duration, seed=route, noise=profile, noise_seed=0)
    covariance = first.cramer_rao_bound()
    bound = np.full(4, np.nan) if covariance is None else np.sqrt(np.diag(covariance)) * MM
    truth = first.true_parameters.as_array()
    errors: dict[str, list[np.ndarray]] = {m: [] for m in methods}
    stds: dict[str, list[np.ndarray]] = {m: [] for m in methods}
    for k in range(draws):
        sim = first if k == 0 else odocal.simulate(duration_s=duration, seed=route,
                                                   noise=profile, noise_seed=k)
        for m in methods:
            est = odocal.calibrate(sim.drive, settings=settings, method=m).estimate
            ok = np.array(est.identified)
            errors[m].append(np.where(ok, est.theta.as_array() - truth, np.nan) * MM)
            stds[m].append(np.where(ok, est.std, np.nan) * MM)
    print(f"\n== {profile}: {NOISE_PROFILES[profile].description}; route {route}, "
          f"{draws} noise draws")
    print(f"  {'':<22}" + "".join(f"{n:>11}" for n in PARAMETER_NAMES))
    print(f"  {'Cramér-Rao bound':<22}" + "".join(f"{b:>11.3f}" if np.isfinite(b)
                                                   else f"{'-':>11}" for b in bound))
    for m in methods:
        e, s = np.array(errors[m]), np.array(stds[m])
        n = np.sum(np.isfinite(e), axis=0)
        spread = np.nanstd(e, axis=0, ddof=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            rows = {"error std": spread,
                    "mean error": np.nanmean(e, axis=0),
                    "its std. error": spread / np.sqrt(n),
                    "reported std": np.nanmean(s, axis=0),
                    "efficiency": bound**2 / spread**2 if applies(first.profile)
                    else np.full(4, np.nan),
                    "mean |error|": np.nanmean(np.abs(e), axis=0)}
        for i, (label, values) in enumerate(rows.items()):
            print(f"  {m if i == 0 else '':<8}{label:>14}"
                  + "".join(f"{v:>11.3f}" if np.isfinite(v) else f"{'-':>11}" for v in values))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=100)
    parser.add_argument("--route", type=int, default=0)
    parser.add_argument("--duration", type=float, default=1200.0)
    parser.add_argument("--methods", default="inverse")
    parser.add_argument("--profiles", default=PROFILES)
    args = parser.parse_args()
    started = time.perf_counter()
    settings = Settings()
    methods = args.methods.split(",")
    for profile in args.profiles.split(","):
        one_profile(profile, args.route, args.draws, args.duration, methods, settings)
    print(f"\n{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
