"""The four-wheel model's equations on the real logs (issue 37): what the front wheels and the
steering identify, against the cars' datasheets.

Every shared log carries four wheel speeds and a steering-wheel angle, which odocal's readers
take into the drive's further inputs (``Drive.inputs``: ``n_fl``, ``n_fr``, ``steer``):
nuScenes' ``zoe_veh_info`` (a Renault Zoe, wheelbase 2.588 m) and comma2k19's
``CAN/wheel_speed`` and ``CAN/steering_angle`` (a Toyota RAV4 of the XA40 generation, 2.660
m). With the drive's reference motion at the rear axle, this script fits
the front axle's and the steering's parameters of :mod:`odocal.model.four_wheel`
(``c_f, c_fd, t_f, L, ratio, s_0``) by Gauss-Newton on one-second windows: each window's
front wheels' mean and difference revolutions (:func:`~odocal.model.four_wheel.inverse_step`
summed: odocal's channels) and its mean
steering-wheel angle (:func:`~odocal.model.four_wheel.steering`, moving steps). Each channel
is weighted by its own robust residual scale, refitted; the covariance is the sandwich over
clusters of five consecutive windows (errors that last a few seconds stay inside one).

It is a plain fit, not odocal's default estimator (no lag, no error model with the speed, no
departures): the figures say whether the drives carry the information, not what odocal's
calibration of a four-wheel car will state.

Run: ``python benchmarks/bench_four_wheel.py [--data ../shared/data]``.
"""

from __future__ import annotations

import argparse
import itertools
import os
from pathlib import Path

import numpy as np

import odocal
from odocal.data.drive import Drive
from odocal.estimators.front_axle import std_from_information as _std
from odocal.model.four_wheel import FOUR_WHEEL, inverse_step, steering
from odocal.model.kinematics import motion_increments
from odocal.model.vehicle import MODEL
from odocal.preprocess.convert import convert
from odocal.settings import Settings
from odocal.sim.four_wheel import with_front_axle

#: The parameters fitted here (the front axle's and the steering's), by position in theta.
FITTED = FOUR_WHEEL.indices(("c_f", "c_fd", "t_f", "L", "ratio", "s_0"))
WINDOW_S, CLUSTER, MIN_MOVE_M = 1.0, 5, 2.0


def _windows(drive: Drive, fl: np.ndarray, fr: np.ndarray, steer_rad: np.ndarray) -> dict:
    """One-second windows of a drive's steps: the reference motion per step and the measured
    front revolutions and mean steering angle per window."""
    k = max(1, round(WINDOW_S / drive.t_s))
    out: dict[str, list[np.ndarray]] = {n: [] for n in ("ds", "dpsi", "a_y", "revs", "steer")}
    for a, b in drive.pieces:
        n = (b - a - 1) // k
        if n < 1:
            continue
        ds, dpsi = motion_increments(drive.x[a:b], drive.y[a:b], drive.psi[a:b], drive.beta[a:b])
        cut = n * k
        out["ds"].append(ds[:cut].reshape(n, k))
        out["dpsi"].append(dpsi[:cut].reshape(n, k))
        out["a_y"].append(drive.a_y[a:b - 1][:cut].reshape(n, k))
        revs = np.column_stack([fl[a:b - 1], fr[a:b - 1]])[:cut] * drive.t_s
        out["revs"].append(revs.reshape(n, k, 2).sum(axis=1))
        out["steer"].append(steer_rad[a:b - 1][:cut].reshape(n, k))
    w = {name: np.concatenate(parts) for name, parts in out.items()}
    moving = w["ds"].sum(axis=1) > MIN_MOVE_M
    return {name: value[moving] for name, value in w.items()}


def _predict(theta: np.ndarray, w: dict) -> tuple[np.ndarray, np.ndarray]:
    """Each window's [fl, fr, steering] (N, 3) and the Jacobian in the fitted parameters."""
    revs, jac = inverse_step(theta, w["ds"], w["dpsi"], w["a_y"])
    angle, jac_s = steering(theta, w["ds"], w["dpsi"])
    moving = w["ds"] > 0.02                          # the angle of a step that barely moves
    count = np.maximum(moving.sum(axis=1), 1)        # is mostly its reference noise
    mean_angle = np.where(moving, angle, 0.0).sum(axis=1) / count
    mean_jac = np.where(moving[..., None], jac_s, 0.0).sum(axis=1) / count[:, None]
    fl, fr = revs[:, :, 0].sum(axis=1), revs[:, :, 1].sum(axis=1)
    j_fl, j_fr = jac[:, :, 0].sum(axis=1), jac[:, :, 1].sum(axis=1)
    # the axle's channels, as odocal's error model has them: the wheels' mean and difference
    pred = np.column_stack([0.5 * (fl + fr), fr - fl, mean_angle])
    j = np.stack([0.5 * (j_fl + j_fr), j_fr - j_fl, mean_jac], axis=1)
    return pred, j[:, :, FITTED]


def fit(windows: list[dict], theta0: np.ndarray, *, steering_tells_l: bool = False,
        limit_scale: float = 1.0) -> tuple[np.ndarray, ...]:
    """Gauss-Newton over every log's windows from the datasheet ``theta0``: theta, the fitted
    parameters' covariance (the cluster sandwich), their standard deviations from the
    information alone, the channels' robust scales, and which parameters the drives identify
    (odocal's rule, judged on the information: a standard deviation below half the datasheet's
    uncertainty, the layout's ``prior_std``; the others keep their datasheet value).

    ``steering_tells_l`` False: the steering's equations estimate the ratio and the offset
    only, and L is the front wheels' (an M-estimator whose estimating equations leave out the
    steering's derivative in L; the sandwich carries L's uncertainty into the ratio). At
    small angles the steering says ``ratio L`` alone, and the little it says of L by itself
    (the arctangent's bend) is what an unmodelled steering (understeer, a ratio that varies
    with the angle, a lag) moves first."""
    told = np.ones((3, len(FITTED)))
    if not steering_tells_l:
        told[2, FITTED.index(FOUR_WHEEL.index("L"))] = 0.0
    limit = 0.5 * limit_scale * np.array(FOUR_WHEEL.prior_std)[list(FITTED)]
    measured = np.concatenate([np.column_stack([w["revs"].mean(axis=1),
                                                w["revs"][:, 1] - w["revs"][:, 0],
                                                w["steer"].mean(axis=1)]) for w in windows])
    theta = np.array(theta0, dtype=float)
    free = np.ones(len(FITTED), dtype=bool)
    scale = np.array([np.std(measured[:, c]) + 1e-9 for c in range(3)])

    def normal(theta: np.ndarray) -> tuple[np.ndarray, ...]:
        parts = [_predict(theta, w) for w in windows]
        pred = np.concatenate([q for q, _ in parts])
        jac = np.concatenate([j for _, j in parts]) / scale[None, :, None]
        r = (measured - pred) / scale
        return (np.einsum("ncp,ncq->pq", told * jac, jac), np.einsum("ncp,nc->p", told * jac, r),
                np.einsum("ncp,nc->np", told * jac, r), pred,
                np.einsum("ncp,ncq->pq", told * jac, told * jac))

    for _ in range(4):                   # judge, fit the identified, refit the channels' scales
        *_, told_info = normal(theta)    # what the equations that estimate each one say
        free = np.ones(len(FITTED), dtype=bool)
        while free.any():                # hold the weakest, judge the rest again (as odocal)
            std = np.full(len(FITTED), np.inf)
            std[free] = _std(told_info[np.ix_(free, free)])
            worst = int(np.argmax(np.where(free, std / limit, -np.inf)))
            if std[worst] < limit[worst]:
                break
            free[worst] = False
        theta = np.array(theta0, dtype=float)
        index = np.array(FITTED)[free]
        for _ in range(50):
            a, g, _, pred, _ = normal(theta)
            step = np.linalg.solve(a[np.ix_(free, free)], g[free])
            theta[index] += step
            if np.all(np.abs(step) < 1e-10 * np.maximum(1.0, np.abs(theta[index]))):
                break
        residual = measured - pred
        scale = 1.4826 * np.median(np.abs(residual - np.median(residual, axis=0)), axis=0)
    a, _, scores, _, told_info = normal(theta)
    bread = np.zeros_like(a)
    bread[np.ix_(free, free)] = np.linalg.inv(a[np.ix_(free, free)])
    # clusters of CLUSTER consecutive windows within each log
    labels = np.concatenate([np.arange(len(w["ds"])) // CLUSTER + 10_000 * i
                             for i, w in enumerate(windows)])
    sums = np.array([scores[labels == c].sum(axis=0) for c in np.unique(labels)])
    g = len(sums)
    meat = sums.T @ sums * g / max(g - 1, 1)
    informed = np.sqrt(np.abs(np.diag(bread @ told_info @ bread.T)))
    return theta, bread @ meat @ bread.T, informed, scale, free


def _inputs(drive: Drive) -> dict:
    return _windows(drive, drive.inputs["n_fl"], drive.inputs["n_fr"], drive.inputs["steer"])


def _nuscenes(data: Path) -> list[dict]:
    return [_inputs(d) for d in convert("nuscenes", [data / "nuscenes-can-bus-mini"])]


def _comma(data: Path) -> list[dict]:
    seg = data / "comma2k19-example" / "2018-08-02--08-34-47" / "40"
    # m/s as the rates of a 1 m wheel: c_f comes out as the speed signal's scale
    return [_inputs(d) for d in convert("comma2k19", [seg], settings=Settings().replace(
        convert={"wheel_circumference_m": 1.0}))]


def simulated(seeds: range, duration_s: float, noise: str) -> None:
    """The plain fit on simulated four-wheel drives (:mod:`odocal.sim.four_wheel`): each
    identified parameter's error over its standard deviation."""
    z: dict[str, list[float]] = {FOUR_WHEEL.names[i]: [] for i in FITTED}
    held: dict[str, int] = dict.fromkeys(z, 0)
    for seed in seeds:
        sim, truth = with_front_axle(odocal.simulate(duration_s=duration_s, seed=seed,
                                                     noise=noise))
        theta0 = np.array(FOUR_WHEEL.placeholder)
        theta0[:MODEL.size] = truth.as_array()[:MODEL.size]
        theta, _, informed, _, free = fit([_inputs(sim.drive)], theta0)
        for j, index in enumerate(FITTED):
            name = FOUR_WHEEL.names[index]
            if free[j]:
                z[name].append(float((theta[index] - truth.as_array()[index]) / informed[j]))
            else:
                held[name] += 1
    print(f"\nsimulated four-wheel drives, {len(seeds)} seeds x {duration_s:g} s, noise "
          f"{noise!r}: the error over the std of each identified parameter")
    _print_z(z, held)


def _print_z(z: dict[str, list[float]], held: dict[str, int]) -> None:
    """Each parameter's RMS and largest |z| over the drives that identify it."""
    for name, values in z.items():
        v = np.array(values)
        line = (f"  {name:<6} RMS z {np.sqrt(np.mean(v ** 2)):5.2f}, max |z| "
                f"{np.max(np.abs(v)):5.2f} over {v.size}" if v.size else f"  {name:<6} -")
        print(line + (f"; not identified in {held[name]}" if held[name] else ""))


def calibrated(seeds: range, duration_s: float, noise: str, *, sideslip: bool = True) -> None:
    """odocal's four-wheel calibration (``[vehicle] model = "four_wheel"``: the default
    method's rear axle joined with the front axle and the steering) on simulated four-wheel
    drives: each identified parameter's error over its stated standard deviation
    (``sideslip=False``: the drives without their sideslip column, as real logs come)."""
    settings = Settings().replace(vehicle={"model": "four_wheel"})
    z: dict[str, list[float]] = {n: [] for n in FOUR_WHEEL.names}
    held = dict.fromkeys(z, 0)
    seconds = []
    for seed in seeds:
        sim, truth = with_front_axle(odocal.simulate(duration_s=duration_s, seed=seed,
                                                     noise=noise))
        drive = sim.drive
        if not sideslip:
            drive = Drive.from_columns({k: v for k, v in drive.columns().items()
                                        if k != "beta"}, name=drive.name)
        result = odocal.calibrate(drive, settings=settings)
        est = result.model_estimate
        seconds.append(result.timings_s.get("front axle", 0.0) / max(result.elapsed_s, 1e-9))
        for j, name in enumerate(est.names):
            if est.identified[j]:
                z[name].append(float((est.theta.as_array()[j] - truth.as_array()[j])
                                     / est.std[j]))
            else:
                held[name] += 1
    print(f"\nodocal calibrate, four_wheel model, {len(seeds)} seeds x {duration_s:g} s, noise "
          f"{noise!r}{'' if sideslip else ', without the sideslip column'} (the front axle's "
          f"share of the time: {np.mean(seconds):.0%})")
    _print_z(z, held)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path(os.environ.get(
        "ODOCAL_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")))
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--duration", type=float, default=1200.0)
    parser.add_argument("--calibrate", nargs="*", metavar="NOISE",
                        help="only odocal's four-wheel calibration, on these noise profiles")
    parser.add_argument("--no-sideslip", action="store_true",
                        help="with --calibrate: the drives without their sideslip column")
    args = parser.parse_args()
    if args.calibrate is not None:
        for noise in args.calibrate or ("white", "realistic", "everything", "slip", "heavy"):
            calibrated(range(1, args.seeds + 1), args.duration, noise,
                       sideslip=not args.no_sideslip)
        return
    for noise in ("white", "realistic"):
        simulated(range(1, args.seeds + 1), args.duration, noise)
    datasheet = np.array(FOUR_WHEEL.placeholder)
    speeds = datasheet.copy()
    speeds[FOUR_WHEEL.index("c_f")] = 1.0             # comma's m/s: a 1 m wheel's rates
    cars = (("nuScenes Renault Zoe (Singapore, Boston scenes)", _nuscenes(args.data), 2.588,
             datasheet),
            ("comma2k19 Toyota RAV4 (one 60 s segment)", _comma(args.data), 2.660, speeds))
    for (name, windows, wheelbase, theta0), tells in itertools.product(cars, (False, True)):
        theta, cov, informed, scale, free = fit(windows, theta0, steering_tells_l=tells)
        std = np.sqrt(np.diag(cov))
        n = sum(len(w["ds"]) for w in windows)
        how = ("the steering's arctangent also tells L" if tells
               else "L from the front wheels only")
        print(f"\n{name}, {how}: {n} moving one-second windows; channel scales: front "
              f"wheels' mean {scale[0]:.4f} rev, their difference {scale[1]:.4f} rev, steering "
              f"{np.rad2deg(scale[2]):.3f} deg")
        for j, index in enumerate(FITTED):
            spec = FOUR_WHEEL.parameters[index]
            if not free[j]:
                print(f"  {spec.name:<6} not identified (datasheet {theta[index]:g} kept)")
                continue
            line = (f"  {spec.name:<6} {theta[index] * spec.display_scale:12.5f} "
                    f"+- {informed[j] * spec.display_scale:9.5f} (sandwich "
                    f"{std[j] * spec.display_scale:9.5f}) {spec.display_unit}")
            if spec.name == "L":
                line += (f"   datasheet {wheelbase:.3f} m, z = "
                         f"{(theta[index] - wheelbase) / informed[j]:+.2f}")
            print(line)
        i_l, i_r = FITTED.index(FOUR_WHEEL.index("L")), FITTED.index(FOUR_WHEEL.index("ratio"))
        if not free[i_l] and free[i_r]:  # the steering says ratio x L alone
            held = theta[FOUR_WHEEL.index("L")]
            print(f"  (with L held, the steering says ratio x L = "
                  f"{theta[FOUR_WHEEL.index('ratio')] * held:.3f} +- {informed[i_r] * held:.3f} "
                  f"m; the ratio above is for L = {held:g} m, the car's datasheet L divides it)")
        if not free[i_l]:                # what L would be, judged against the prior itself
            loose, _, loose_std, _, loose_free = fit(windows, theta0, steering_tells_l=tells,
                                                     limit_scale=2.0)
            if loose_free[i_l]:
                value, sd = loose[FOUR_WHEEL.index("L")], loose_std[i_l]
                print(f"  (L fitted anyway, identified to within the datasheet's 0.2 m: "
                      f"{value:.4f} +- {sd:.4f} m, z = {(value - wheelbase) / sd:+.2f}; ratio "
                      f"{loose[FOUR_WHEEL.index('ratio')]:.3f} +- {loose_std[i_r]:.3f})")
        if free[i_l] and free[i_r]:
            print(f"  correlation of L and ratio: {cov[i_l, i_r] / (std[i_l] * std[i_r]):+.3f}")


if __name__ == "__main__":
    main()
