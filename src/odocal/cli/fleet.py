"""``odocal fleet ...`` and ``odocal simulate-fleet`` (Dask and the store load only when run)."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from odocal.cli.arguments import DURATION_S, SEED, WORKERS, add_config, add_quiet, integer, number
from odocal.cli.common import load_config, say
from odocal.estimators import DEFAULT_METHOD, METHOD_NAMES
from odocal.model import registry
from odocal.sim.limits import MAX_CIRCUMFERENCE_LOSS, MAX_DRIVES, MAX_VEHICLES


def _echo(text: str) -> None:
    """A line as the fleet goes (flushed: a long run shows it at once)."""
    say(text)
    sys.stdout.flush()


def _progress(args: argparse.Namespace) -> Any:
    if args.quiet:
        return None
    from odocal.cli.progress import Progress

    return Progress(True)


def _refused(line: str) -> None:
    """A catalog row left out, on stderr as it is known (the run goes on; it exits 1)."""
    from odocal.errors import shown

    sys.stderr.write(f"odocal fleet calibrate: error: {shown(line, 2000)}\n")
    sys.stderr.flush()


def _summary(run: Any) -> None:
    say(f"{run.drives} drives in the catalog: {run.stored_before} already stored, "
           f"{run.calibrated} calibrated now, {run.failed} could not be calibrated"
           + (f", {len(run.refused)} not read" if run.refused else "") + "; "
           f"{run.pooled} pooled calibrations; {run.elapsed_s:.1f} s")
    for reason, count in run.reasons[:3]:
        say(f"  not calibrated ({count} drive{'s' if count != 1 else ''}): {reason}")
    if run.alarms:
        say(f"{len(run.alarms)} alarm(s):")
        for a in run.alarms:
            say(f"  {a.vehicle} {a.parameter}: {a.message} "
                   f"(confidence {a.confidence:.3f}, detected after {a.drives_to_detect} "
                   f"drives, {a.km_to_detect:.0f} km)")
    else:
        say("no alarms")


def cmd_fleet_calibrate(args: argparse.Namespace) -> int:
    from odocal.fleet.engine import calibrate_fleet, require_dask

    require_dask()

    progress = _progress(args)
    if args.workers and not args.scheduler and not args.quiet:
        from odocal.fleet.engine import available_cores

        if args.workers > available_cores():
            sys.stderr.write(f"note: --workers {args.workers}: this machine has "
                             f"{available_cores()} cores; starting {available_cores()}\n")
    try:
        run = calibrate_fleet(args.catalog, args.store, settings=load_config(args.config),
                              method=args.method, scheduler=args.scheduler,
                              connect_timeout_s=args.connect_timeout,
                              workers=args.workers, out=args.out,
                              drive_reports=not args.no_drive_reports, progress=progress,
                              echo=None if args.quiet else _echo, refuse=_refused)
    finally:
        if progress is not None:
            progress.close()
    if not args.quiet:
        _summary(run)
        if args.out:
            say(f"wrote {Path(args.out) / 'report.html'} and {len(run.written) - 1} more files")
    if run.refused:
        sys.stderr.write(f"odocal fleet calibrate: error: {len(run.refused)} catalog row(s) "
                         "could not be used (named above); the others are stored\n")
        return 1
    if run.drives and run.failed == run.drives and run.reasons:
        # every drive failed: the settings or the logs are wrong for all of them, not weak
        sys.stderr.write("odocal fleet calibrate: error: no drive of the catalog could be "
                         f"calibrated; the commonest reason: {run.reasons[0][0]}\n")
        return 1
    return 0


def cmd_fleet_demo(args: argparse.Namespace) -> int:
    from odocal.fleet.engine import calibrate_fleet, require_dask

    require_dask()
    from odocal.fleet.simulate import simulate_fleet

    with tempfile.TemporaryDirectory(prefix="odocal-fleet-") as tmp:
        root = Path(tmp) / "fleet"
        out = Path(args.out) if args.out else None
        if out is not None and out.exists() and any(out.iterdir()):
            from odocal.errors import OutputError

            raise OutputError(f"'{out}' exists and is not empty; the demo writes a new folder")
        progress = _progress(args)
        try:
            fleet = simulate_fleet(root, vehicles=4, drives=args.drives, duration_s=300.0,
                                   seed=args.seed, plan="mixed", size=0.004, progress=progress)
            store = (out / "fleet.db") if out is not None else Path(tmp) / "fleet.db"
            if out is not None:
                out.mkdir(parents=True, exist_ok=True)
            run = calibrate_fleet(fleet.catalog, store, workers=args.workers, out=out,
                                  drive_reports=False, progress=progress,
                                  echo=None if args.quiet else _echo)
        finally:
            if progress is not None:
                progress.close()
        if not args.quiet:
            say("Simulated: 4 vehicles; car001 loses 0.4% of c_e (left rear tyre pressure), "
                   "car002 wears, car003 gets new tyres (declared), car000 has one mis-mapped "
                   "log.")
            for e in fleet.events:
                say(f"  truth: {e.vehicle} {e.kind} from drive {e.drive} ({e.time[:10]})")
            _summary(run)
            if out is not None:
                say(f"wrote {out / 'report.html'} and the store {store}")
    return 0


def cmd_fleet_alarms(args: argparse.Namespace) -> int:
    from odocal.fleet.engine import store_of

    with store_of(args.store) as db:
        alarms = db.alarms(args.vehicle)
    if args.json:
        say(json.dumps(alarms, indent=1))
    elif not alarms:
        say("no alarms")
    else:
        for a in alarms:
            say(f"{a['vehicle']} {a['parameter']} {a['kind']} since {a['time'][:10]}: "
                   f"{a['message']} (confidence {a['confidence']:.3f})")
    return 0


def cmd_fleet_history(args: argparse.Namespace) -> int:
    from odocal.errors import DataError
    from odocal.fleet.engine import store_of

    with store_of(args.store) as db:
        rows = db.drives(args.vehicle)
        layout = db.layout                     # the store's model's parameters
        if not rows:
            known = ", ".join(db.vehicles()[:10]) or "none"
            raise DataError(f"no drive of vehicle {args.vehicle!r} in '{args.store}' "
                            f"(vehicles: {known})")
    if args.json:
        for r in rows:
            for key in ("covariance", "findings", "input_hashes"):
                if isinstance(r.get(key), str):
                    r[key] = json.loads(r[key])
        say(json.dumps(rows, indent=1))
        return 0
    head = "time              status      " + "".join(
        f"{n + ' [' + layout.display[n][1] + ']':>24}" for n in layout.names) + "   E_p m"
    say(head)
    for r in rows:
        cells = []
        for n in layout.names:
            scale = layout.display[n][0]
            if r[n] is None:
                cells.append(f"{'-':>24}")
            else:
                mark = "" if r[f"{n}_identified"] else "*"
                cells.append(f"{r[n] * scale:>13.6g} ± {r[f'{n}_std'] * scale:<7.2g}{mark:1}")
        e_p = f"{r['e_p_m']:.3f}" if r["e_p_m"] is not None else "-"
        say(f"{r['time'][:16]:17} {r['status'][:11]:11} {''.join(cells)}   {e_p}"
               + (f"   event: {r['event']}" if r["event"] else "")
               + (f"   error: {r['error']}" if r["error"] else ""))
    say("* not identified by that drive (datasheet value)")
    return 0


def cmd_simulate_fleet(args: argparse.Namespace) -> int:
    from odocal.fleet.simulate import simulate_fleet

    progress = _progress(args)
    try:
        fleet = simulate_fleet(args.out, vehicles=args.vehicles, drives=args.drives,
                               duration_s=args.duration, seed=args.seed, noise=args.noise,
                               plan=args.plan, size=args.size, wear=args.wear,
                               model=args.model, progress=progress)
    finally:
        if progress is not None:
            progress.close()
    if not args.quiet:
        say(f"wrote {fleet.drives} drives, {fleet.catalog} and {fleet.truth}")
    return 0


def add_parsers(sub: Any) -> None:
    """Register ``fleet`` and ``simulate-fleet`` on the main parser's subcommands."""
    fleet = sub.add_parser("fleet", help="calibrate many vehicles' drives, keep their history, "
                                         "detect drift")
    fsub = fleet.add_subparsers(dest="fleet_command", required=True, metavar="ACTION")
    _add_fleet_calibrate(fsub)
    _add_fleet_queries(fsub)
    _add_fleet_demo(fsub)
    _add_simulate_fleet(sub)


def _add_fleet_calibrate(fsub: Any) -> None:
    """Register ``fleet calibrate`` on the ``fleet`` parser's actions."""
    p = fsub.add_parser("calibrate", help="calibrate a catalog of drives into the store")
    p.add_argument("catalog", metavar="CATALOG",
                   help="CSV/Parquet catalog (vehicle, path, time, ...), a path or a URL "
                        "(s3://, gs://, az://, https://), or a VEHICLE/DATE_* folder")
    p.add_argument("--store", required=True, metavar="DB", help="the fleet's SQLite file")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://HOST:PORT); default: a local cluster")
    p.add_argument("--connect-timeout", type=number(0.1, 3600.0, unit="s"), default=10.0,
                   metavar="S",
                   help="seconds to wait for --scheduler to answer (default 10)")
    p.add_argument("--workers", type=WORKERS, metavar="N",
                   help="local cluster worker processes (0 or default: one per core)")
    p.add_argument("--method", choices=METHOD_NAMES,
                   help=f"calibration method (default {DEFAULT_METHOD})")
    p.add_argument("--out", metavar="DIR",
                   help="write the fleet report, each drive's report and parameter files here")
    p.add_argument("--no-drive-reports", action="store_true",
                   help="with --out, skip each drive's own report")
    add_config(p)
    add_quiet(p)
    p.set_defaults(func=cmd_fleet_calibrate)


def _add_fleet_queries(fsub: Any) -> None:
    """Register ``fleet alarms`` and ``fleet history``, the store's two read-only queries."""
    p = fsub.add_parser("alarms", help="list the alarms in the store")
    p.add_argument("--store", required=True, metavar="DB",
                   help="the fleet's SQLite file (written by fleet calibrate)")
    p.add_argument("--vehicle", metavar="ID", help="only this vehicle's alarms")
    p.add_argument("--json", action="store_true", help="a JSON list, one object per alarm")
    add_quiet(p)
    p.set_defaults(func=cmd_fleet_alarms)

    p = fsub.add_parser("history", help="one vehicle's estimates over time")
    p.add_argument("--store", required=True, metavar="DB",
                   help="the fleet's SQLite file (written by fleet calibrate)")
    p.add_argument("--vehicle", required=True, metavar="ID", help="the vehicle, as the catalog "
                                                                  "names it")
    p.add_argument("--json", action="store_true", help="a JSON list, one object per drive")
    add_quiet(p)
    p.set_defaults(func=cmd_fleet_history)


def _add_fleet_demo(fsub: Any) -> None:
    """Register ``fleet demo`` on the ``fleet`` parser's actions."""
    p = fsub.add_parser("demo", help="simulate a small fleet with events and calibrate it "
                                     "(under a minute)")
    p.add_argument("--out", metavar="DIR", help="keep the store and the fleet report here")
    p.add_argument("--drives", type=integer(2, MAX_DRIVES), default=10, metavar="N",
                   help=f"drives per vehicle (default 10, from 2 to {MAX_DRIVES})")
    p.add_argument("--seed", type=SEED, default=0, metavar="N",
                   help="simulation seed (default 0)")
    p.add_argument("--workers", type=WORKERS, metavar="N",
                   help="local cluster worker processes (0 or default: one per core)")
    add_quiet(p)
    p.set_defaults(func=cmd_fleet_demo)


def _add_simulate_fleet(sub: Any) -> None:
    """Register ``simulate-fleet`` on the main parser's subcommands."""
    from odocal.sim.noise import NOISE_PROFILES

    p = sub.add_parser("simulate-fleet", help="write a simulated fleet with known truth and "
                                              "events")
    p.add_argument("--out", required=True, metavar="DIR", help="new folder for the fleet")
    p.add_argument("--vehicles", type=integer(1, MAX_VEHICLES), default=8, metavar="N",
                   help=f"vehicles (default 8, from 1 to {MAX_VEHICLES})")
    p.add_argument("--drives", type=integer(2, MAX_DRIVES), default=12, metavar="N",
                   help=f"drives per vehicle (default 12, from 2 to {MAX_DRIVES})")
    p.add_argument("--duration", type=DURATION_S, default=900.0, metavar="S",
                   help="length of each drive (default 900, at most 86400)")
    p.add_argument("--seed", type=SEED, default=0, metavar="N",
                   help="simulation seed (default 0)")
    p.add_argument("--noise", choices=sorted(NOISE_PROFILES), default="realistic",
                   metavar="PROFILE",
                   help=f"noise profile (default realistic): {', '.join(NOISE_PROFILES)}")
    p.add_argument("--plan", choices=("mixed", "pressure", "wear", "tyres", "none"),
                   default="mixed", help="which events (default mixed: one kind per vehicle)")
    p.add_argument("--size", type=number(0.0, MAX_CIRCUMFERENCE_LOSS), default=0.002,
                   metavar="SHARE",
                   help="relative c_e loss of a pressure event (default 0.002, at most 0.05)")
    p.add_argument("--wear", type=number(0.0, MAX_CIRCUMFERENCE_LOSS), default=0.003,
                   metavar="SHARE",
                   help="relative c_e loss by wear over a vehicle's history (default 0.003, "
                        "at most 0.05)")
    p.add_argument("--model", choices=registry.names(), default=registry.DEFAULT,
                   help="vehicle model (default rear_axle): four_wheel adds the front wheels "
                        "(n_fl, n_fr) and the steering-wheel angle (steer) to every drive; "
                        "calibrate it with [vehicle] model = \"four_wheel\" in --config")
    add_quiet(p)
    p.set_defaults(func=cmd_simulate_fleet)
