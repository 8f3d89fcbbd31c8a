"""The fleet report: one self-contained HTML page, and each vehicle's parameter files.

Per vehicle: each identified parameter's history with one-std bars, its baselines (with the
drive-to-drive scatter) and its alarms and declared events; a table of the vehicles to
recalibrate; links to each drive's own report where one was written.
"""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from odocal._version import __version__
from odocal.fleet.drift import parse_stamp
from odocal.fleet.store import Store
from odocal.io.atomic import FLEET_MARKER, file_name, write_bytes, write_text
from odocal.model.layout import REAR_AXLE, Layout
from odocal.model.parameters import Parameters
from odocal.output.export import Calibrated, export, targets_for
from odocal.pipeline.odometry import OdometryNoise
from odocal.redaction import redact_text
from odocal.report.render import Call, FigureSpec, Renderer
from odocal.report.style import CSS


def _history_spec(vehicle: str, rows: Sequence[Mapping[str, Any]],
                  baselines: Sequence[Mapping[str, Any]],
                  alarms: Sequence[Mapping[str, Any]],
                  layout: Layout = REAR_AXLE) -> FigureSpec | None:
    """Vehicle ``vehicle``'s history figure: a panel per parameter of its model (``layout``),
    two to a row."""
    ok_rows = [r for r in rows if r["success"]]
    if not ok_rows:
        return None
    t0 = parse_stamp(rows[0]["time"])

    def day(text: str) -> float:
        return (parse_stamp(text) - t0).total_seconds() / 86400.0

    days = np.array([day(r["time"]) for r in ok_rows])
    end = float(days.max()) if len(days) else 0.0
    events = [day(r["time"]) for r in rows if r.get("event")]
    calls = []
    for j, name in enumerate(layout.names):
        mine = sorted((b for b in baselines if b["parameter"] == name), key=lambda b: b["since"])
        spans = []
        for k, b in enumerate(mine):
            start = day(b["since"])
            stop = day(mine[k + 1]["since"]) if k + 1 < len(mine) else end
            ends = [day(a["time"]) for a in alarms
                    if a["parameter"] == name and day(a["time"]) > start]
            stop = min([stop, *ends])
            band = float(np.hypot(b["std"], b["excess_std"]))
            spans.append((start, stop, float(b["value"]), band))
        calls.append(Call("plot_history", (
            days, np.array([r[name] for r in ok_rows], dtype=float),
            np.array([r[f"{name}_std"] for r in ok_rows], dtype=float),
            np.array([bool(r[f"{name}_identified"]) for r in ok_rows])),
            {"name": name, "baselines": spans,
             "alarms": [day(a["time"]) for a in alarms if a["parameter"] == name],
             "events": events, "xlabel": f"days since {t0.date().isoformat()}"},
            row=j // 2, col=j % 2))
    calls.append(Call("legend", (), {"fontsize": 7, "loc": "best"}, row=0, col=0))
    rows_of_panels = (layout.size + 1) // 2
    return FigureSpec(name=f"history_{_safe(vehicle)}", caption=f"{vehicle}: every drive's "
                      "estimate with one standard deviation, baselines and changes",
                      width=10.0, height=2.8 * rows_of_panels, calls=tuple(calls),
                      rows=rows_of_panels, cols=2)


_safe = file_name  # vehicles whose names clean alike keep apart


def _fmt(name: str, value: float | None, std: float | None = None,
         layout: Layout = REAR_AXLE) -> str:
    if value is None:
        return "-"
    scale, unit = layout.display[name]
    text = f"{value * scale:.6g}"
    if std is not None and std > 0:
        text += f" &plusmn; {std * scale:.2g}"
    return f"{text} {html.escape(unit)}"


def _pooled_by_vehicle(store: Store) -> dict[str, Mapping[str, Any]]:
    latest: dict[str, Mapping[str, Any]] = {}
    for p in store.pooled():
        newer = p["vehicle"] not in latest or p["time"] >= latest[p["vehicle"]]["time"]
        if p["success"] and newer:
            latest[p["vehicle"]] = p
    return latest


def _exports(store: Store, out: Path, datasheet: Parameters) -> list[Path]:
    written: list[Path] = []
    names = store.layout.names
    for vehicle, p in _pooled_by_vehicle(store).items():
        noise = (OdometryNoise(p["speed_std_mps"], p["yaw_rate_std_radps"], 0)
                 if p.get("speed_std_mps") is not None else None)
        calibrated = Calibrated(
            theta=Parameters(*(p[n] for n in names), layout=store.layout),
            datasheet=datasheet, std=tuple(p[f"{n}_std"] for n in names),
            identified=tuple(bool(p[f"{n}_identified"]) for n in names),
            method=p["method"] or "", noise=noise,
            source=f"fleet store, vehicle {vehicle}, {len(json.loads(p['drives']))} drives up to "
                   f"{p['time']}")
        written += export(calibrated, out / "vehicles" / _safe(vehicle),
                          targets_for(store.layout))
    return written


def write_fleet_outputs(store: Store, out: Path, *, datasheet: Parameters | None = None
                        ) -> tuple[Path, ...]:
    """``report.html``, ``figures/history_*.png`` and ``vehicles/ID/TARGET/*`` in ``out``."""
    from odocal.settings import Settings

    datasheet = datasheet or Parameters(
        *Settings().replace(vehicle={"model": store.model}).identify.theta0, layout=store.layout)
    out.mkdir(parents=True, exist_ok=True)
    (out / FLEET_MARKER).write_text("written by odocal fleet calibrate; updated in place\n")
    drives, alarms, baselines = store.drives(), store.alarms(), store.baselines()
    vehicles = sorted({r["vehicle"] for r in drives})
    specs = [s for v in vehicles
             if (s := _history_spec(v, [r for r in drives if r["vehicle"] == v],
                                    [b for b in baselines if b["vehicle"] == v],
                                    [a for a in alarms if a["vehicle"] == v],
                                    store.layout)) is not None]
    with Renderer() as renderer:
        pngs = renderer.draw(specs)
    figures = out / "figures"
    for old in figures.glob("history_*.png"):
        old.unlink()                 # no figure of a vehicle no longer in the store stays
    written: list[Path] = []
    for spec, png in zip(specs, pngs, strict=True):
        path = figures / f"{spec.name}.png"
        write_bytes(path, png)
        written.append(path)
    exports = _exports(store, out, datasheet)
    page = _page(out, drives, alarms, _pooled_by_vehicle(store),
                 {s.name: (s.caption, png) for s, png in zip(specs, pngs, strict=True)},
                 store.layout)
    report = out / "report.html"
    write_text(report, redact_text(page))          # no secret on the page
    return (report, *written, *exports)


def _page(out: Path, drives: Sequence[Mapping[str, Any]], alarms: Sequence[Mapping[str, Any]],
          pooled: Mapping[str, Mapping[str, Any]],
          pngs: Mapping[str, tuple[str, bytes]], layout: Layout = REAR_AXLE) -> str:
    vehicles = sorted({r["vehicle"] for r in drives})
    failed = sum(1 for r in drives if not r["success"])
    alarm_rows = "".join(
        f"<tr><td>{html.escape(a['vehicle'])}</td><td>{a['parameter']}</td><td>{a['kind']}</td>"
        f"<td>{a['time'][:10]}</td><td>{a['detected_time'][:10]}</td>"
        f"<td>{a['relative_change'] * 100:+.3f}%</td><td>{a['confidence']:.3f}</td>"
        f"<td>{a['drives_to_detect']} / {a['km_to_detect']:.0f} km</td>"
        f"<td class='text'>{html.escape(a['message'])}</td></tr>" for a in alarms)
    sections = [_vehicle_section(out, v, drives, pooled, pngs, layout) for v in vehicles]
    recal = sorted({a["vehicle"] for a in alarms})
    recal_rows = "".join(
        f"<tr><td><a href='#{_safe(v)}'>{html.escape(v)}</a></td><td class='text'>"
        f"{html.escape('; '.join(a['message'] for a in alarms if a['vehicle'] == v))}</td></tr>"
        for v in recal)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width">
<title>odocal fleet report</title><style>{CSS} td.text {{ text-align: left; }}</style></head>
<body><main>
<h1>Fleet calibration report</h1>
<p class="meta">odocal {__version__} &middot; {len(vehicles)} vehicles &middot; {len(drives)} drives
({failed} not calibrated) &middot; {len(alarms)} alarms</p>
<h2>Vehicles to recalibrate</h2>
{"<table><tr><th>vehicle</th><th>why</th></tr>" + recal_rows + "</table>" if recal
 else "<p class='verdict good'>No vehicle's parameters changed beyond its baseline.</p>"}
<h2>Alarms</h2>
{"<table><tr><th>vehicle</th><th>parameter</th><th>kind</th><th>since</th><th>detected</th>"
 "<th>change</th><th>confidence</th><th>to detect</th><th>message</th></tr>" + alarm_rows
 + "</table>" if alarms else "<p>None.</p>"}
{"".join(sections)}
<p class="meta">Every number on this page is in the fleet store (SQLite); each vehicle's
parameter files are in vehicles/ID/.</p>
</main></body></html>
"""


def _vehicle_section(out: Path, v: str, drives: Sequence[Mapping[str, Any]],
                     pooled: Mapping[str, Mapping[str, Any]],
                     pngs: Mapping[str, tuple[str, bytes]], layout: Layout = REAR_AXLE) -> str:
    """Vehicle ``v``'s section: its pooled calibration, its history figure, and its drives,
    each linked to its own report where there is one (relative to ``out`` where inside it)."""
    mine = [r for r in drives if r["vehicle"] == v]
    p = pooled.get(v)
    current = (" &middot; ".join(f"{n} = {_fmt(n, p[n], p[f'{n}_std'], layout)}"
                                 if p[f"{n}_identified"] else f"{n} not identified"
                                 for n in layout.names)
               if p else "no pooled calibration")
    fig = pngs.get(f"history_{_safe(v)}")
    img = (f'<figure><img alt="history of {html.escape(v)}" src="data:image/png;base64,'
           f'{base64.b64encode(fig[1]).decode("ascii")}"><figcaption>{html.escape(fig[0])}'
           "</figcaption></figure>" if fig else "")
    links = []
    for r in mine:
        label = f"{r['time'][:16]} {html.escape(r['status'])}"
        if r.get("error"):
            label += f": {html.escape(r['error'])}"
        if r.get("report") and Path(r["report"]).exists():
            try:
                rel = Path(r["report"]).resolve().relative_to(out.resolve())
                label = f'<a href="{html.escape(rel.as_posix())}">{label}</a>'
            except ValueError:
                label = f'<a href="{html.escape(Path(r["report"]).as_uri())}">{label}</a>'
        links.append(f"<li>{label}</li>")
    return (f"<h2 id='{_safe(v)}'>{html.escape(v)}</h2><p>{len(mine)} drives; "
            f"current (pooled) calibration: {current}</p>{img}"
            f"<details><summary>drives</summary><ul>{''.join(links)}</ul></details>")
