"""Evidence on the real data in ../shared/data (issues 4 and 6).

    python benchmarks/bench_realdata.py [--data ../shared/data]
                                        [--methods inverse,raw,compensated]

nuScenes (two Renault Zoe cars): the Singapore car calibrated on its turning scenes and validated
on its other scenes; the Boston car calibrated on its two scenes; and, per car, leave-one-scene-out
validation (calibrate on all scenes but one, validate on that one). comma2k19: odocal's GNSS/IMU
fusion against comma's global_pose, and what the straight highway drive identifies.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

import odocal
from odocal.data.segments import validation_segments
from odocal.model.parameters import PARAMETER_NAMES
from odocal.preprocess.convert import convert
from odocal.settings import Settings

SINGAPORE_TURNS = ("scene-0061", "scene-0916", "scene-1077")
SINGAPORE = (*SINGAPORE_TURNS, "scene-0796", "scene-1100")
BOSTON = ("scene-0103", "scene-0655")


def fmt_theta(result: odocal.CalibrationResult) -> str:
    ident = result.estimate
    parts = []
    for name, value, std, ok in zip(PARAMETER_NAMES, result.theta.as_array(), ident.std,
                                    ident.identified, strict=True):
        scale, unit = (1e3, "mm") if name in ("c_d", "d") else (1.0, "m")
        parts.append(f"{name} {value * scale:.4f}+-{std * scale:.4f} {unit}" if ok
                     else f"{name} not identified")
    return ", ".join(parts)


#: The nuScenes scenes are 20 s and 90-250 m long: validation segments of 80 m fit in them.
NUSCENES = Settings().replace(segments={"validation_distance_m": 80.0})


def nuscenes(data: Path, methods: list[str]) -> None:
    settings = NUSCENES
    drives = {d.name: d for d in convert("nuscenes", [data / "nuscenes-can-bus-mini"])}
    print("== nuScenes: every scene converted:")
    for name, d in sorted(drives.items()):
        conv = d.metadata["conversion"]
        print(f"  {name}: {d.duration_s:.1f} s, {d.distance_m:.0f} m, peak yaw rate "
              f"{np.abs(d.yaw_rate).max():.3f} rad/s; {conv['wheel_offset']['message']}")
    for method in methods:
        print(f"\n-- method {method}")
        sg = odocal.calibrate([drives[s] for s in SINGAPORE_TURNS], method=method,
                              settings=settings)
        held_out = [drives[s] for s in SINGAPORE if s not in SINGAPORE_TURNS]
        cal = odocal.validate(held_out, sg.theta, settings=settings)
        ds = odocal.validate(held_out, sg.estimate.datasheet, settings=settings)
        print(f"  Singapore car, calibrated on {', '.join(SINGAPORE_TURNS)}: {fmt_theta(sg)}")
        print(f"    validated on scene-0796 and scene-1100 ({len(cal.segments)} segment(s) of "
              f"~{settings.segments.validation_distance_m:.0f} m, "
              f"{cal.segments.distance_m.sum():.0f} m): E_p {cal.mean_error_m:.3f} m "
              f"(datasheet {ds.mean_error_m:.3f} m)")
        bos = odocal.calibrate([drives[s] for s in BOSTON], method=method, settings=settings)
        print(f"  Boston car, calibrated on {', '.join(BOSTON)}: {fmt_theta(bos)}")
        diff = bos.theta.c_d - sg.theta.c_d
        spread = float(np.hypot(bos.estimate.std[1], sg.estimate.std[1]))
        print(f"  c_d Boston - Singapore: {diff * 1e3:+.2f} mm ({abs(diff) / spread:.0f} "
              "standard deviations)")
        for car, scenes in (("Singapore", SINGAPORE), ("Boston", BOSTON)):
            rows = []
            for out in scenes:
                train = [drives[s] for s in scenes if s != out]
                if not len(validation_segments([drives[out]], settings.segments)):
                    rows.append(f"{out}: no validation segment ({drives[out].distance_m:.0f} m)")
                    continue
                r = odocal.calibrate(train, method=method, settings=settings)
                e = odocal.validate(drives[out], r.theta, settings=settings).mean_error_m
                e0 = odocal.validate(drives[out], r.estimate.datasheet,
                                     settings=settings).mean_error_m
                rows.append(f"{out}: {e:.3f} m (datasheet {e0:.3f})")
            print(f"  {car} leave-one-scene-out E_p: " + "; ".join(rows))


def comma(data: Path, methods: list[str]) -> None:
    seg = data / "comma2k19-example" / "2018-08-02--08-34-47" / "40"
    fused = convert("comma2k19", [seg], settings=Settings().replace(convert={"reference":
                                                                               "fused"}))[0]
    own = convert("comma2k19", [seg], settings=Settings().replace(convert={"reference":
                                                                             "gnss-imu"}))[0]
    t = fused.t[(fused.t >= own.t[0]) & (fused.t <= own.t[-1])]
    fx, fy, fp = (np.interp(t, fused.t, v) for v in (fused.x, fused.y, fused.psi))
    ox, oy, op = (np.interp(t, own.t, v) for v in (own.x, own.y, own.psi))
    dx, dy = ox - fx, oy - fy
    along, cross = dx * np.cos(fp) + dy * np.sin(fp), -dx * np.sin(fp) + dy * np.cos(fp)
    dpsi = np.degrees(np.remainder(op - fp + np.pi, 2 * np.pi) - np.pi)
    print("\n== comma2k19: odocal's GNSS/IMU fusion (u-blox + IMU) against comma's global_pose")
    print(f"  RMS position difference {np.sqrt(np.mean(dx**2 + dy**2)):.3f} m (max "
          f"{np.max(np.hypot(dx, dy)):.3f}); mean along-track {along.mean():+.2f} m, cross-track "
          f"{cross.mean():+.2f} m; about those means {along.std():.3f} / {cross.std():.3f} m")
    print(f"  RMS heading difference {np.sqrt(np.mean(dpsi**2)):.3f} deg (mean {dpsi.mean():+.3f}, "
          f"std {dpsi.std():.3f}); comma's own orientation differs from its velocity course by a "
          "like amount (the camera's mounting yaw)")
    for reference, drive in (("fused", fused), ("gnss-imu", own)):
        for method in methods:
            r = odocal.calibrate(drive, method=method)
            assert r.validation is not None and r.datasheet_validation is not None
            print(f"  reference {reference}, {method}: {fmt_theta(r)}; E_p "
                  f"{r.validation.mean_error_m:.3f} m (datasheet "
                  f"{r.datasheet_validation.mean_error_m:.3f}); scale c_e/2.0 = "
                  f"{r.theta.c_e / 2.0:.4f}")
            for name in r.estimate.unidentified:
                print(f"    {name}: {r.estimate.verdict(name)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(os.environ.get("ODOCAL_SHARED_DATA",
                                  Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--methods", default="inverse,raw,compensated")
    args = parser.parse_args()
    methods = args.methods.split(",")
    nuscenes(args.data, methods)
    comma(args.data, methods)


if __name__ == "__main__":
    main()
