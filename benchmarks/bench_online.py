"""The online calibrator: speed, latency, memory, agreement with batch, change detection.

    python benchmarks/bench_online.py [--seeds 5] [--long-hours 10] [--profiles ...]
                                      [--skip memory,matrix,hours,changes,real]

Printed:

* **speed**: one hour of 40 Hz samples pushed one second at a time on one core (numba and BLAS
  limited to one thread), total time and the 50th/99th percentile latency of a push;
* **memory**: peak memory (PSS of the process) of ``odocal replay --no-batch`` on a 15-minute and
  a ``--long-hours`` drive, and of the batch ``odocal calibrate --no-report`` on the long one;
* **matrix**: for every noise profile and seed (20-minute drives), the online estimate at the end
  against the batch default's (difference in batch standard deviations, largest over
  parameters) and both against the truth (mean |error|);
* **hours** (``--hour-profiles``, ``--hours-each``): ``odocal replay`` (a running estimate every
  30 s, then the final one) and batch on drives simulated at 100 Hz and put on the ROS 2 node's
  40 Hz grid, without the sideslip column: each one's z against the truth, RMS and largest;
* **changes**: a 0.2% step in c_e (and 0.5 mm in c_d) halfway through a one-hour drive: how often
  and how soon (distance) it is detected, over seeds; false alarms per hour on drives without;
* **real**: distance until c_e is known to 1 mm and t_r to 20 mm on the shared real logs;
* **car** (``[vehicle] model = "four_wheel"``, issue 37): ``odocal replay`` of one hour and of
  ``--long-hours`` of four-wheel driving against the rear axle's of the same files (time and
  peak memory), and over profiles and seeds of 20-minute drives the live car at the end against
  batch's (largest difference in batch stds, per parameter group) and against the truth (RMS
  and largest |z|).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _measure import run_measured

import odocal
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.online.calibrator import OnlineCalibrator
from odocal.sim.noise import NOISE_PROFILES


def push_all(drive: odocal.Drive, step: int = 40,
             calibrator: OnlineCalibrator | None = None) -> tuple[OnlineCalibrator, list[float]]:
    calibrator = calibrator or OnlineCalibrator()
    cols = drive.columns()
    latencies = []
    for i in range(0, drive.n_samples, step):
        chunk = {k: v[i:i + step] for k, v in cols.items()}
        started = time.perf_counter()
        calibrator.push(chunk)
        latencies.append(time.perf_counter() - started)
    return calibrator, latencies


def speed() -> None:
    drive = odocal.simulate(duration_s=3600, seed=5).drive
    push_all(odocal.simulate(duration_s=120, seed=6).drive)            # warm up
    started = time.perf_counter()
    calibrator, lat = push_all(drive)
    total = time.perf_counter() - started
    t0 = time.perf_counter()
    calibrator.estimate()
    est_ms = (time.perf_counter() - t0) * 1e3
    print(f"speed: one hour ({drive.n_samples} samples) pushed in {total:.2f} s on one core "
          f"({3600 / total:.0f}x real time); latency per one-second push: median "
          f"{np.median(lat) * 1e3:.2f} ms, p99 {np.percentile(lat, 99) * 1e3:.2f} ms, max "
          f"{np.max(lat) * 1e3:.1f} ms; estimate() {est_ms:.1f} ms")


def memory(hours: float) -> None:
    exe = str(Path(sys.executable).with_name("odocal"))
    work = Path(tempfile.mkdtemp(prefix="odocal-online-"))
    files = {}
    for label, seconds in (("15 min", 900.0), (f"{hours:g} h", hours * 3600.0)):
        path = work / f"{label.replace(' ', '')}.parquet"
        odocal.save_drive(odocal.simulate(duration_s=seconds, seed=8).drive, path)
        files[label] = path
    for label, path in files.items():
        wall, peak = run_measured([exe, "replay", str(path), "--out", str(work / f"r{label}"),
                                   "--no-batch", "--no-report", "-q"])
        print(f"memory: replay of a {label} drive: peak {peak:.0f} MB, {wall:.1f} s")
    long = files[f"{hours:g} h"]
    wall, peak = run_measured([exe, "calibrate", str(long), "--out", str(work / "batch"),
                               "--no-report", "-q"])
    print(f"memory: batch calibrate of the {hours:g} h drive: peak {peak:.0f} MB, {wall:.1f} s")


def matrix(profiles: list[str], seeds: int) -> None:
    print(f"matrix: online at the end vs batch default, {seeds} seeds of 20 minutes")
    print(f"  {'profile':<18}{'max |online-batch|/std':>24}"
          f"{'online mean|e| c_e,c_d,t_r,d (mm)':>44}{'batch mean|e|':>34}")
    for profile in profiles:
        diffs, e_on, e_ba = [], [], []
        for seed in range(seeds):
            sim = odocal.simulate(duration_s=1200, seed=seed, noise=profile)
            online = push_all(sim.drive)[0].estimate()
            batch = odocal.calibrate(sim.drive).estimate
            truth = sim.true_parameters.as_array()
            ok = np.array(batch.identified) & np.array(online.identified)
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.abs(online.theta.as_array() - batch.theta.as_array()) / batch.std
            diffs.append(float(np.max(np.where(ok, d, 0.0))))
            e_on.append(np.abs(online.theta.as_array() - truth) * 1e3)
            e_ba.append(np.abs(batch.theta.as_array() - truth) * 1e3)
        print(f"  {profile:<18}{max(diffs):>24.2f}"
              f"{' '.join(f'{v:8.3f}' for v in np.mean(e_on, axis=0)):>44}"
              f"{' '.join(f'{v:8.3f}' for v in np.mean(e_ba, axis=0)):>34}", flush=True)


def at_40_hz(drive: odocal.Drive) -> odocal.Drive:
    """``drive`` (100 Hz) as the ROS 2 node's default grid sees it: the wheels and a_y
    interpolated onto 40 Hz, the pose taken at 50 Hz and interpolated onto the same grid, no
    sideslip column (as every real log)."""
    t = drive.t
    grid = np.arange(t[0], t[-1], 0.025)
    pose_t = t[::2]

    def pose(v: np.ndarray) -> np.ndarray:
        return np.interp(grid, pose_t, v[::2])

    return odocal.Drive.from_columns({
        "t": grid, "n_rl": np.interp(grid, t, drive.n_rl), "n_rr": np.interp(grid, t, drive.n_rr),
        "a_y": np.interp(grid, t, drive.a_y), "x": pose(drive.x), "y": pose(drive.y),
        "psi": np.angle(np.exp(1j * pose(np.unwrap(drive.psi))))}, name=drive.name)


def hours(profiles: list[str], seeds: int, hours_each: float) -> None:
    """Live (``odocal replay``: a running estimate every 30 s, the final one) against batch on
    drives of ``hours_each`` hours at 40 Hz without a sideslip column: each one's z against the
    truth. (Before the departures were chosen afresh at every estimate, seed 5 of `realistic`
    gave c_e 15 stds off live.)"""
    from odocal.online.replay import replay

    print(f"hours: live against batch, {hours_each:g} h at 40 Hz without the sideslip column, "
          f"z against the truth (c_e c_d t_r d)")
    work = Path(tempfile.mkdtemp(prefix="odocal-hours-"))
    rows: dict[str, list[np.ndarray]] = {"batch": [], "live": []}
    for profile in profiles:
        for seed in range(1, seeds + 1):
            sim = odocal.simulate(duration_s=hours_each * 3600, seed=seed, noise=profile,
                                  t_s=0.01)
            drive = at_40_hz(sim.drive)
            path = work / f"{profile}-{seed}.parquet"
            odocal.save_drive(drive, path)
            truth = sim.true_parameters.as_array()
            started = time.perf_counter()
            live = replay(path).final
            live_s = time.perf_counter() - started
            batch = odocal.calibrate(drive).estimate
            line = []
            for label, est in (("batch", batch), ("live", live)):
                with np.errstate(divide="ignore", invalid="ignore"):
                    z = np.where(est.identified, (est.theta.as_array() - truth) / est.std, np.nan)
                rows[label].append(z)
                line.append(f"{label} {' '.join(f'{v:6.2f}' for v in z)}")
            print(f"  {profile:<11}{seed:>3}  {'   '.join(line)}   live {live_s:.1f} s",
                  flush=True)
    for label, zs in rows.items():
        z = np.array(zs)
        print(f"  {label:<6} RMS z {' '.join(f'{v:5.2f}' for v in np.sqrt(np.nanmean(z ** 2, 0)))}"
              f"   max |z| {' '.join(f'{v:5.2f}' for v in np.nanmax(np.abs(z), 0))}")


def changes(seeds: int) -> None:
    true = odocal.TRUE_PARAMETERS
    after = Parameters(true.c_e * 0.998, true.c_d - 0.0005, true.t_r, true.d)
    detected, delays_km, hours, false = 0, [], 0.0, 0
    for seed in range(seeds):
        sim = odocal.simulate(duration_s=3600, seed=100 + seed, noise="realistic",
                              change=(1800.0, after))
        cal = OnlineCalibrator()
        cols = sim.drive.columns()
        km_at_change = None
        for i in range(0, sim.drive.n_samples, 40):
            cal.push({k: v[i:i + 40] for k, v in cols.items()})
            if km_at_change is None and cols["t"][min(i + 40, cols["t"].size - 1)] >= 1800.0:
                km_at_change = cal.distance_km
        hits = [a for a in cal.alarms if a.detected_t >= 1800.0]
        false += len(cal.alarms) - len(hits)
        hours += 0.5
        if hits:
            detected += 1
            delays_km.append(hits[0].detected_distance_km - (km_at_change or 0.0))
        clean = odocal.simulate(duration_s=3600, seed=200 + seed, noise="realistic")
        false += len(push_all(clean.drive)[0].alarms)
        hours += 1.0
    print(f"changes: a 0.2% step in c_e (and -0.5 mm in c_d) halfway through a one-hour drive: "
          f"detected in {detected} of {seeds} drives; distance from the change to the alarm: "
          + (f"median {np.median(delays_km):.2f} km, max {np.max(delays_km):.2f} km"
             if delays_km else "-")
          + f"; false alarms: {false} in {hours:.1f} h of driving without a change")


def shared_logs() -> tuple[dict[str, odocal.Drive], dict[str, list[str]]] | None:
    """The shared real logs by name, and each car's (None where ../shared/data is not
    there)."""
    from odocal.preprocess.convert import convert

    data = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    if not data.is_dir():
        return None
    logs = {d.name: d for d in convert("nuscenes", [data / "nuscenes-can-bus-mini"])}
    segment = data / "comma2k19-example" / "2018-08-02--08-34-47" / "40"
    logs.update({f"comma2k19 {d.name}": d for d in convert("comma2k19", [segment])})
    groups = {"nuScenes Singapore car (5 scenes)": ["scene-0061", "scene-0916", "scene-1077",
                                                    "scene-0796", "scene-1100"],
              "nuScenes Boston car (2 scenes)": ["scene-0103", "scene-0655"],
              "comma2k19 segment": [n for n in logs if n.startswith("comma2k19")]}
    return logs, groups


def one_after_another(logs: list[odocal.Drive]) -> Iterator[dict[str, np.ndarray]]:
    """A car's logs as one stream (100 s apart), in chunks of 40 samples."""
    offset = 0.0
    for log in logs:
        cols = log.columns()
        cols = {**cols, "t": cols["t"] - cols["t"][0] + offset}
        offset = float(cols["t"][-1]) + 100.0
        for i in range(0, cols["t"].size, 40):
            yield {k: v[i:i + 40] for k, v in cols.items()}


def real() -> None:
    shared = shared_logs()
    if shared is None:
        print("real: ../shared/data not found; skipped")
        return
    logs, groups = shared
    print("real: distance until c_e is identified to 1 mm and t_r to 20 mm (online; a car's "
          "logs pushed one after another)")
    for label, names in groups.items():
        cal = OnlineCalibrator()
        first: dict[str, float | None] = {"c_e": None, "t_r": None}
        for k, chunk in enumerate(one_after_another([logs[n] for n in names])):
            cal.push(chunk)
            if k % 5 == 0:                        # every 200 samples
                est = cal.estimate()
                for n, limit in (("c_e", 1e-3), ("t_r", 20e-3)):
                    j = PARAMETER_NAMES.index(n)
                    if first[n] is None and est.identified[j] and est.std[j] <= limit:
                        first[n] = cal.distance_km
        est = cal.estimate()
        print(f"  {label:<36} {cal.distance_km:6.2f} km: c_e to 1 mm "
              + (f"after {first['c_e']:.2f} km" if first["c_e"] is not None else "not reached")
              + ", t_r to 20 mm "
              + (f"after {first['t_r']:.2f} km" if first["t_r"] is not None else "not reached")
              + "; at the end " + ", ".join(
                  f"{n} {v:.4f}+-{sd:.4f}" if ok else f"{n} not identified"
                  for n, v, sd, ok in zip(PARAMETER_NAMES, est.theta.as_array(), est.std,
                                          est.identified, strict=True)))


CAR = odocal.Settings().replace(vehicle={"model": "four_wheel"})


def car_replay(hours: float) -> None:
    """``odocal replay`` of four-wheel drives as the car and as the rear axle."""
    from odocal.sim.four_wheel import with_front_axle

    exe = str(Path(sys.executable).with_name("odocal"))
    work = Path(tempfile.mkdtemp(prefix="odocal-car-"))
    config = work / "car.toml"
    config.write_text('[vehicle]\nmodel = "four_wheel"\n')
    for label, seconds in (("1 h", 3600.0), (f"{hours:g} h", hours * 3600.0)):
        path = work / f"{label.replace(' ', '')}.parquet"
        sim, _ = with_front_axle(odocal.simulate(duration_s=seconds, seed=8))
        odocal.save_drive(sim.drive, path)
        for model, extra in (("rear axle", []), ("car", ["--config", str(config)])):
            wall, peak = run_measured([exe, "replay", str(path), *extra, "--out",
                                       str(work / f"r{label}{model}"), "--no-batch",
                                       "--no-report", "-q"])
            print(f"car: replay of {label} as the {model}: {wall:.1f} s, peak {peak:.0f} MB",
                  flush=True)


def car_matrix(profiles: list[str], seeds: int) -> None:
    """The live car at the end of 20-minute drives against batch's and the truth."""
    from odocal.sim.four_wheel import with_front_axle

    rear, front = slice(0, 4), slice(4, None)
    print(f"car: live at the end vs batch, {seeds} seeds of 20 minutes per profile")
    print(f"  {'profile':<18}{'max|live-batch|/std rear, front':>34}{'live RMS z':>12}"
          f"{'live max|z|':>13}{'batch RMS z':>13}{'batch max|z|':>14}")
    all_z = []
    for profile in profiles:
        diffs, z_on, z_ba = [], [], []
        for seed in range(seeds):
            sim, truth = with_front_axle(odocal.simulate(duration_s=1200, seed=seed,
                                                         noise=profile))
            online = push_all(sim.drive, calibrator=OnlineCalibrator(CAR))[0].estimate()
            batch = odocal.calibrate(sim.drive, settings=CAR).model_estimate
            ok = np.array(batch.identified) & np.array(online.identified)
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.abs(online.theta.as_array() - batch.theta.as_array()) / batch.std
                zo = (online.theta.as_array() - truth.as_array()) / online.std
                zb = (batch.theta.as_array() - truth.as_array()) / batch.std
            d = np.where(ok, d, 0.0)
            diffs.append((float(np.max(d[rear])), float(np.max(d[front]))))
            z_on += list(zo[np.array(online.identified)])
            z_ba += list(zb[np.array(batch.identified)])
        all_z += z_on
        dr, df = np.max(diffs, axis=0)
        print(f"  {profile:<18}{dr:>17.2f}, {df:<15.2f}{np.sqrt(np.mean(np.square(z_on))):>12.2f}"
              f"{np.max(np.abs(z_on)):>13.2f}{np.sqrt(np.mean(np.square(z_ba))):>13.2f}"
              f"{np.max(np.abs(z_ba)):>14.2f}", flush=True)
    print(f"  all: {len(all_z)} values, live RMS z {np.sqrt(np.mean(np.square(all_z))):.2f}, "
          f"|z| > 3: {int(np.sum(np.abs(all_z) > 3))}")


def car_real() -> None:
    """The live car on the shared real logs (a car's logs one after another) against batch's
    four-wheel calibration of the same logs."""
    shared = shared_logs()
    if shared is None:
        print("car real: ../shared/data not found; skipped")
        return
    logs, groups = shared
    print("car real: the live car (logs one after another) against batch's of the same logs")
    for label, names in groups.items():
        cal = OnlineCalibrator(CAR)
        for chunk in one_after_another([logs[n] for n in names]):
            cal.push(chunk)
        live = cal.estimate()
        batch = odocal.calibrate([logs[n] for n in names], settings=CAR).model_estimate
        words = []
        for j, name in enumerate(live.names):
            if live.identified[j] or batch.identified[j]:
                lv = f"{live.theta.as_array()[j]:.4f}+-{live.std[j]:.4f}" \
                    if live.identified[j] else "-"
                bv = f"{batch.theta.as_array()[j]:.4f}+-{batch.std[j]:.4f}" \
                    if batch.identified[j] else "-"
                words.append(f"{name} {lv} (batch {bv})")
        print(f"  {label:<22} {live.status.name}: " + "; ".join(words), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--long-hours", type=float, default=10.0)
    parser.add_argument("--profiles", default=",".join(p for p in NOISE_PROFILES if p != "none"))
    parser.add_argument("--skip", default="")
    parser.add_argument("--car-profiles", default="white,realistic,slip,heavy,everything")
    parser.add_argument("--car-hours", type=float, default=3.0)
    parser.add_argument("--only", default="", help="run only these parts (comma-separated)")
    parser.add_argument("--hour-profiles", default="realistic,everything")
    parser.add_argument("--hours-each", type=float, default=1.0)
    args = parser.parse_args()
    skip = set(args.skip.split(","))
    if args.only:
        skip = ({"speed", "memory", "matrix", "hours", "changes", "real", "car"}
                - set(args.only.split(",")))
    if "speed" not in skip:
        speed()
    if "memory" not in skip:
        memory(args.long_hours)
    if "matrix" not in skip:
        matrix(args.profiles.split(","), args.seeds)
    if "hours" not in skip:
        hours(args.hour_profiles.split(","), args.seeds, args.hours_each)
    if "changes" not in skip:
        changes(args.seeds)
    if "real" not in skip:
        real()
    if "car" not in skip:
        car_replay(args.car_hours)
        car_matrix(args.car_profiles.split(","), args.seeds)
        car_real()


if __name__ == "__main__":
    main()
