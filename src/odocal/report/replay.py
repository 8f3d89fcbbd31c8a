"""The report of ``odocal replay``: the online estimate against distance, alarms, batch answer."""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

import numpy as np

from odocal._version import __version__
from odocal.estimators.estimate import Estimate
from odocal.io.atomic import write_bytes, write_text
from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_NAMES
from odocal.online.changes import Alarm
from odocal.online.replay import ReplayResult
from odocal.redaction import redact_text
from odocal.report.render import Call, FigureSpec, Renderer

#: Convergence thresholds the report quotes: c_e to 1 mm, t_r to 20 mm.
CONVERGED_STD = {"c_e": 1e-3, "t_r": 20e-3}


def convergence_km(result: ReplayResult) -> dict[str, float | None]:
    """Distance driven until each quoted parameter was identified within its threshold."""
    out: dict[str, float | None] = {}
    names = result.trace[0].names if result.trace else PARAMETER_NAMES
    for name, limit in CONVERGED_STD.items():
        j = names.index(name)
        hit = [r.distance_km for r in result.trace
               if r.identified[j] and r.std[j] <= limit and not r.rejected]
        out[name] = hit[0] if hit else None
    return out


def alarm_words(alarm: Alarm) -> str:
    """What an alarm says, in words: which wheels changed, by how much and how sure."""
    share = alarm.relative_change * 100.0
    index = 0 if alarm.parameter == "c_e" else 1
    c_e = alarm.change_m[index] / alarm.relative_change if alarm.relative_change else 0.0
    std = alarm.std_m[index]
    sure = f" (+-{abs(std / c_e) * 100:.2f}%)" if math.isfinite(std) and c_e else ""
    if alarm.wheel == "both":
        what = "both rear wheels' circumference (c_e)"
    else:
        what = (f"the rear-{alarm.wheel} wheel's circumference alone (c_d; tyre pressure or a "
                "tyre change on that wheel)")
    return f"{what} changed by {share:+.2f}%{sure} of c_e"


def _spec(result: ReplayResult, batch: Estimate | None) -> FigureSpec:
    rows = result.trace
    distance = np.array([r.distance_km for r in rows])
    calls = []
    names = result.estimate.names
    for j, name in enumerate(names):
        # a rejected estimate was never published: a gap in its line (trace.csv has it)
        calls.append(Call("plot_trace", (distance, np.array([r.theta[j] for r in rows]),
                                         np.array([r.std[j] for r in rows]),
                                         np.array([r.identified[j] and not r.rejected
                                                   for r in rows])),
                          {"name": name,
                           "batch": float(batch.theta.as_array()[j])
                           if batch is not None and batch.identified[j] else None,
                           "batch_std": float(batch.std[j]) if batch is not None else None,
                           "alarms_km": [a.detected_distance_km for a in result.alarms]},
                          row=j // 2, col=j % 2))
    calls.append(Call("legend", kwargs={"fontsize": 7, "loc": "best"}))
    grid = math.ceil(len(names) / 2)
    return FigureSpec("trace", "The online estimate of each parameter against the distance "
                      "driven, with its one-standard-deviation band (gaps where the estimate "
                      "was rejected by the checks or the gate); the batch calibration of "
                      "the whole log for comparison; red lines where a change was detected.",
                      10.0, 3.0 * grid, tuple(calls), rows=grid, cols=2)


def _fmt(name: str, value: float) -> str:
    scale, unit = PARAMETER_DISPLAY[name]
    return f"{value * scale:.{3 if scale != 1.0 else 5}f} {unit}"


def rejected_updates(result: ReplayResult) -> list[tuple[float, str]]:
    """Where (km) estimates were rejected, and by which checks (codes), in trace order."""
    return [(r.distance_km, r.rejected_by) for r in result.trace if r.rejected]


def _rejected_text(result: ReplayResult) -> str:
    """The report's paragraph on the updates whose estimate was rejected (none: nothing)."""
    rows = rejected_updates(result)
    if not rows:
        return ""
    checks = sorted({c for _, by in rows for c in by.split(",") if c})
    text = (f"{len(rows)} of {len(result.trace)} updates were rejected by the checks or the "
            f"gate ({', '.join(checks) or 'the gate'}), between {rows[0][0]:.2f} and "
            f"{rows[-1][0]:.2f} km: never published (status REJECTED in trace.csv).")
    if result.published_km is not None:
        text += (" The final estimate was among them: the table shows the last estimate that "
                 f"was not, from {result.published_km:.2f} km.")
    return f"<p id='rejected'>{html.escape(text)}</p>"


def _convergence_text(result: ReplayResult) -> str:
    return "; ".join(f"{n} to {CONVERGED_STD[n] * 1000:.0f} mm after "
                     + (f"{km:.2f} km" if km is not None else "not within this log")
                     for n, km in convergence_km(result).items())


def _parameter_rows(est: Estimate, batch: Estimate | None) -> list[str]:
    """The parameter table's rows: each parameter online (at the end of the log) and from the
    batch calibration of the whole log, if there is one."""
    e = html.escape
    rows = []
    layout = est.theta.layout
    for j, (name, label) in enumerate(zip(layout.names, layout.labels, strict=True)):
        online = (f"{_fmt(name, est.theta.as_array()[j])} &plusmn; {_fmt(name, est.std[j])}"
                  if est.identified[j] else "not identified")
        cmp = "-"
        if batch is not None:
            cmp = (f"{_fmt(name, batch.theta.as_array()[j])} &plusmn; {_fmt(name, batch.std[j])}"
                   if batch.identified[j] else "not identified")
        rows.append(f"<tr><td><b>{name}</b> {e(label)}</td><td>{online}</td><td>{cmp}</td></tr>")
    return rows


def _alarm_rows(result: ReplayResult) -> str:
    """The alarms table's rows, one per change detected (empty: none)."""
    e = html.escape
    # the log's own clock may be epoch seconds: times are shown from the log's start (the last
    # trace row is the end of the log)
    start = result.trace[-1].t - result.duration_s if result.trace else 0.0
    return "".join(
        f"<tr><td>{a.parameter}</td><td>{a.t - start:.0f} s</td><td>{a.distance_km:.2f} km</td>"
        f"<td>{a.detected_distance_km:.2f} km</td><td>{a.relative_change * 100:+.3f}%</td>"
        f"<td>{e(alarm_words(a))}</td></tr>"
        for a in result.alarms)


def write_replay_report(result: ReplayResult, out_dir: str | Path, *,
                        batch: Estimate | None = None,
                        renderer: Renderer | None = None) -> Path:
    """Write ``report.html`` and ``figures/trace.png`` into ``out_dir``."""
    out = Path(out_dir)
    spec = _spec(result, batch)
    own = renderer is None
    draw = Renderer() if renderer is None else renderer
    try:
        (png,) = draw.draw([spec])
    finally:
        if own:
            draw.close()
    write_bytes(out / "figures" / "trace.png", png)
    e = html.escape
    rows = _parameter_rows(result.estimate, batch)
    alarms = _alarm_rows(result)
    rejected = _rejected_text(result)
    conv_text = _convergence_text(result)
    uri = "data:image/png;base64," + base64.b64encode(png).decode("ascii")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>odocal replay</title>
<style>body{{font-family:system-ui,sans-serif;margin:0;background:#f6f7f9;color:#222}}
main{{max-width:1100px;margin:0 auto;padding:24px}} table{{border-collapse:collapse;
background:white}} th,td{{padding:6px 12px;border-bottom:1px solid #e2e4e8;text-align:right}}
td:first-child,th:first-child{{text-align:left}} img{{max-width:100%}}
.meta{{color:#666}}</style></head><body><main>
<h1>Online calibration (replay)</h1>
<p class="meta">{e(Path(result.source).name)} &middot; {result.duration_s / 60:.1f} min,
{result.distance_km:.2f} km &middot; {result.samples} samples in {result.elapsed_s:.1f} s
&middot; odocal {__version__}</p>
<p id="convergence">Converged: {e(conv_text)}.</p>
{rejected}
<table id="parameters"><tr><th>parameter</th><th>online (end of log)</th>
<th>batch (whole log)</th></tr>{''.join(rows)}</table>
<h2>Estimate against distance</h2>
<figure id="fig-trace"><img alt="online estimate against distance" src="{uri}">
<figcaption>{e(spec.caption)}</figcaption></figure>
<h2>Changes detected</h2>
{"<table id='alarms'><tr><th>parameter</th><th>since (from the log's start)</th><th>at</th>"
 "<th>detected at</th><th>change</th><th>what changed</th></tr>" + alarms + "</table>" if alarms
 else "<p id='alarms'>None.</p>"}
<p class="meta">The numbers are in calibration.json, trace.csv and alarms.json.</p>
</main></body></html>
"""
    path = out / "report.html"
    write_text(path, redact_text(page))            # no secret on the page
    return path
