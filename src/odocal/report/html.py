"""The calibration report: one self-contained HTML page with its figures embedded, and the PNGs."""

from __future__ import annotations

import base64
import html
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from odocal._version import __version__
from odocal.io.atomic import write_bytes, write_text
from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_LABELS
from odocal.pipeline.result import CalibrationResult
from odocal.report.data import ReportData, build, parameter_rows
from odocal.report.render import Call, FigureSpec, Renderer
from odocal.report.style import CALIBRATED, RAW


@dataclass(frozen=True)
class Report:
    """What :func:`write_report` wrote, and the numbers it showed."""

    html_path: Path
    figure_paths: tuple[Path, ...]
    data: ReportData


Spec = FigureSpec | None


def _map(result: CalibrationResult, data: ReportData) -> Spec:
    if not data.maps:
        return None
    calls = [Call("plot_map", (m.reference, m.datasheet, m.calibrated),
                  {"title": f"{Path(m.drive).name} at {m.start_s:.0f} s, {m.distance_m:.0f} m"},
                  col=i) for i, m in enumerate(data.maps)]
    calls.append(Call("legend", kwargs={"fontsize": 8, "loc": "best"}))
    return FigureSpec("map", "Reference trajectory and dead reckoning with the datasheet and the "
                      "calibrated parameters, on the validation segments that turn most.",
                      4.0 * len(data.maps), 4.0, tuple(calls), cols=len(data.maps))


def _step1(result: CalibrationResult, data: ReportData) -> Spec:
    ts = result.three_step
    if ts is None or not np.isfinite(ts.step1.validation_m).any():
        return None
    s1 = ts.step1
    ranks = [int(np.flatnonzero(s1.order == p)[0]) for p in s1.picked]
    raw = float(data.segment_errors["raw"].mean()) if "raw" in data.segment_errors else None
    return FigureSpec("step1", "Fig. 4 of the paper: validation errors of the step-1 batches.",
                      8.0, 3.4, (Call("plot_step1_sorted", (s1.validation_m[s1.order], ranks), {
                          "final_m": result.validation.mean_error_m if result.validation
                          else None, "raw_m": raw}),))


def _spread(result: CalibrationResult, data: ReportData) -> Spec:
    ts = result.three_step
    if ts is None:
        return None
    estimates = [("batch G-N, measured rates", ts.raw.theta.as_array(), ts.raw.std, RAW),
                 ("three-step (calibrated)", result.theta.as_array(), result.estimate.std,
                  CALIBRATED)]
    return FigureSpec("spread", "Figs. 5 and 7 of the paper: the parameters of every step-1 "
                      "batch, and the final estimates with one standard deviation.", 10.0, 3.2,
                      (Call("plot_parameter_spread", (ts.step1.thetas, list(ts.step1.picked),
                                                      estimates,
                                                      result.estimate.datasheet.as_array()),
                            row=None),), cols=4)


def _rates(result: CalibrationResult, data: ReportData) -> Spec:
    ts = result.three_step
    if ts is None or result.batch is None:
        return None
    # the segments a block at a time (a long drive's batch is copied out of it when asked)
    peaks = np.concatenate([np.abs(part.inputs.a_y).max(axis=1)
                            for part in result.batch.parts(256)])
    busiest = int(np.argmax(peaks))
    u = result.batch.part(busiest, busiest + 1).inputs
    t = np.arange(u.n_rl.shape[1], dtype=np.float64) * result.batch.t_s
    return FigureSpec("rates", "Fig. 6 of the paper: measured and compensated wheel rates on the "
                      "selected segment with the highest lateral acceleration.", 8.0, 3.2,
                      (Call("plot_rates", (t, np.column_stack([u.n_rl[0], u.n_rr[0]]),
                                           np.column_stack([ts.compensation.n_rl[busiest],
                                                            ts.compensation.n_rr[busiest]]))),))


def _inverse(result: CalibrationResult, data: ReportData) -> Spec:
    from odocal.estimators.inverse import InverseDetails

    d = result.estimate.details
    if not isinstance(d, InverseDetails) or d.windows == 0:
        return None
    calls = tuple(Call("plot_inverse_fit", (d.measured, d.residual), {"channel": c}, col=c)
                  for c in (0, 1))
    return FigureSpec("inverse", f"The fit: each {d.window_s:.0f} s window's measured wheel "
                      "revolutions against those the reference motion implies with the "
                      "calibrated parameters.", 10.0, 3.6, calls, cols=2)


def _segments(result: CalibrationResult, data: ReportData) -> Spec:
    if not data.segment_errors:
        return None
    return FigureSpec("segments", "Fig. 8 of the paper: mean position error on each validation "
                      "segment.", 8.0, 3.4, (Call("plot_segment_errors", (data.segment_errors,)),))


def _coverage(result: CalibrationResult, data: ReportData) -> Spec:
    threshold = result.settings.segments.yaw_rate_threshold_radps
    return FigureSpec("coverage", "Data coverage: time at each speed and yaw rate, and which "
                      "segments the selection rule kept.", 10.0, 3.0, (
                          Call("plot_histogram", data.speed_hist, {"xlabel": "speed [m/s]"}),
                          Call("plot_histogram", data.yaw_hist,
                               {"xlabel": "yaw rate [rad/s]", "marks": (-threshold, threshold),
                                "mark_label": "selection threshold"}, col=1),
                          Call("plot_selection", (result.segments.peak_yaw_rate_radps,
                                                  threshold), col=2)), cols=3)


def _uncertainty(result: CalibrationResult, data: ReportData) -> Spec:
    ident = result.settings.identify
    sources = "the covariance" + (" and from the bootstrap" if result.bootstrap is not None
                                  else "")
    return FigureSpec("uncertainty", f"Standard deviations from {sources}, relative to the "
                      "datasheet uncertainty.", 6.0, 3.2, (
                          Call("plot_uncertainty", (
                              result.estimate.std,
                              result.bootstrap.std if result.bootstrap is not None else None,
                              np.asarray(ident.prior_std), result.estimate.identified,
                              ident.identifiable_ratio)),))


#: Every figure of the page, in page order.
FIGURES: dict[str, Callable[[CalibrationResult, ReportData], Spec]] = {
    "map": _map, "inverse": _inverse, "step1": _step1, "spread": _spread, "rates": _rates,
    "segments": _segments, "coverage": _coverage, "uncertainty": _uncertainty}


def _figures(result: CalibrationResult, data: ReportData,
             renderer: Renderer) -> dict[str, tuple[str, bytes]]:
    """name -> (caption, PNG bytes) of every figure this result has."""
    specs = [spec for make in FIGURES.values() if (spec := make(result, data)) is not None]
    return {s.name: (s.caption, png) for s, png in zip(specs, renderer.draw(specs), strict=True)}


_CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif; margin: 0;
       color: #222; background: #f6f7f9; }
main { max-width: 1100px; margin: 0 auto; padding: 24px; }
h1 { font-size: 1.6em; margin: 0 0 4px 0; } h2 { font-size: 1.2em; margin-top: 28px; }
.meta { color: #666; font-size: 0.9em; }
.verdict { padding: 12px 16px; border-radius: 6px; font-weight: 600; margin: 16px 0; }
.good { background: #e3f4e5; border-left: 6px solid #2e9b3e; }
.partial { background: #fff5dd; border-left: 6px solid #d9a400; }
.bad { background: #fde6e6; border-left: 6px solid #c62828; }
table { border-collapse: collapse; background: white; margin: 8px 0; display: block;
        width: fit-content; max-width: 100%; overflow-x: auto; }
th, td { padding: 6px 12px; border-bottom: 1px solid #e2e4e8; text-align: right; }
td:not(:first-child), .nowrap { white-space: nowrap; }
th { background: #eef0f3; } td:first-child, th:first-child { text-align: left; }
figure { background: white; margin: 12px 0; padding: 8px; border-radius: 6px; }
figure img { max-width: 100%; height: auto; display: block; }
@media (max-width: 600px) { main { padding: 12px; } th, td { padding: 4px 6px; } }
figcaption { color: #555; font-size: 0.9em; margin-top: 4px; }
ul { line-height: 1.5; } .no { color: #c62828; } .yes { color: #2e9b3e; }
"""


def _fmt(name: str, value: float | None) -> str:
    if value is None:
        return "-"
    scale, unit = PARAMETER_DISPLAY[name]
    digits = 3 if name in ("c_d", "d") else 5
    return f"{value * scale:.{digits}f} {unit}"


class _borrowed:
    """A renderer the caller owns: used, not closed."""

    def __init__(self, renderer: Renderer) -> None:
        self.renderer = renderer

    def __enter__(self) -> Renderer:
        return self.renderer

    def __exit__(self, *exc: object) -> None:
        return None


def _comparison(result: CalibrationResult) -> str:
    """The methods compared on held-out data (``--compare``), or nothing."""
    c = result.comparison
    if c is None:
        return ""
    truth = any(s.truth_error is not None for s in c.scores)
    head = "<tr><th>method</th><th>held-out E_p</th>" + (
        "".join(f"<th>error {n}</th>" for n in ("c_e", "c_d", "t_r", "d")) if truth else "") \
        + "<th>status</th></tr>"
    rows = []
    for s in c.scores:
        cells = [f"<td><b>{html.escape(s.method)}</b></td>",
                 f"<td>{s.held_out_e_p_m:.3f} m</td>" if s.held_out_e_p_m is not None
                 else "<td>-</td>"]
        if truth:
            cells += [f"<td>{_fmt(n, s.truth_error[n])}</td>" if s.truth_error else "<td>-</td>"
                      for n in ("c_e", "c_d", "t_r", "d")]
        cells.append(f"<td>{html.escape(s.status)}</td>")
        rows.append(f"<tr{' class=yes' if s.method in c.favoured else ''}>{''.join(cells)}</tr>")
    return (f"<h2>The methods compared</h2><p id='compare-verdict'>{html.escape(c.verdict)}. "
            f"Each method calibrated on alternate {c.block_s:.0f} s blocks and was validated on "
            "the others (and the other way round).</p>"
            f"<table id='compare'>{head}{''.join(rows)}</table>")


def _parameter_rows(result: CalibrationResult) -> list[str]:
    """The result table's rows: each parameter, datasheet, calibrated, std, verdict."""
    e = html.escape
    rows = []
    for row, label in zip(parameter_rows(result), PARAMETER_LABELS, strict=True):
        name = row["name"]
        ident = row["identified"]
        cal = _fmt(name, row["calibrated"]) if ident else "not identified"
        rows.append(
            f"<tr><td><b>{name}</b> {e(label)}</td><td>{_fmt(name, row['datasheet'])}</td>"
            f"<td>{cal}</td><td>{_fmt(name, row['std']) if ident else '-'}</td>"
            + (f"<td>{_fmt(name, row['bootstrap_std']) if ident else '-'}</td>"
               if row["bootstrap_std"] is not None else "") +
            f"<td class='{'yes' if ident else 'no'}'>{'yes' if ident else 'no'}</td></tr>")
    return rows


def _validation(result: CalibrationResult, data: ReportData) -> str:
    """E_p of the datasheet values, raw G-N and the calibration, in one line."""
    if result.validation is None or result.datasheet_validation is None:
        return ""
    parts = [f"datasheet {result.datasheet_validation.mean_error_m:.3f} m"]
    if "raw" in data.segment_errors:
        parts.append(f"batch G-N on measured rates {data.segment_errors['raw'].mean():.3f} m")
    parts.append(f"<b>calibrated {result.validation.mean_error_m:.3f} m</b>")
    return (f"<p>Validation error E_p over {len(result.validation.segments)} segments "
            f"({result.validation.segments.distance_m.sum() / 1000:.2f} km): "
            + " &rarr; ".join(parts) + "</p>")


def _page(result: CalibrationResult, data: ReportData,
          figs: dict[str, tuple[str, str]]) -> str:
    e = html.escape
    rows = _parameter_rows(result)
    val = _validation(result, data)

    def fig(name: str) -> str:
        if name not in figs:
            return ""
        caption, uri = figs[name]
        return (f"<figure id='fig-{name}'><img alt='{e(caption)}' src='{uri}'>"
                f"<figcaption>{e(caption)}</figcaption></figure>")

    cov = data.coverage
    boot = result.bootstrap
    from odocal.settings import datasheet_stated

    sheet = ("datasheet" if datasheet_stated(result.estimate.datasheet)
             else "datasheet (placeholder: no <span class='nowrap'>--datasheet</span>)")
    boot_head = "<th>std (bootstrap)</th>" if boot is not None else ""
    from odocal.report.advice import finding_text

    warnings = "".join(f"<li>{e(w)}</li>" for w in result.warnings)
    checks = "".join(f"<li class='{['yes', 'partial', 'no'][int(f.severity)]}'>"
                     f"{e(finding_text(f, result.settings))}</li>"
                     for f in result.diagnosis.findings)
    advice = "".join(f"<li class='{'yes' if a.identified else 'no'}'><b>{a.name}</b>: "
                     f"<span style='color:#222'>{e(a.text)}</span></li>" for a in data.advice)
    drives = ", ".join(e(Path(d.name).name) for d in result.drives)
    comparison = _comparison(result)
    paper = fig("step1") + fig("spread") + fig("rates") if result.three_step else ""
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>odocal calibration report</title><style>{_CSS}</style></head>
<body><main>
<h1>Wheel-odometry calibration</h1>
<div class="meta">{drives} &middot; method {e(result.method)} &middot; odocal {__version__}
&middot; {cov['distance_m'] / 1000:.2f} km, {cov['duration_s'] / 60:.1f} min</div>
<div class="verdict {data.verdict_level}" id="verdict">{e(data.verdict)}</div>
<h2>Result</h2>
<table id="parameters"><tr><th>parameter</th><th>{sheet}</th><th>calibrated</th>
<th>std (covariance)</th>{boot_head}<th>identified</th></tr>
{''.join(rows)}</table>
<p class="meta">Covariance: {e(result.estimate.covariance_kind.value)}.
{e(boot.message[:1].upper() + boot.message[1:]) + '.' if boot is not None
 else 'No bootstrap.'}</p>
{val}
{comparison}
{"<h2>Map</h2>" + fig('map') if 'map' in figs else ""}
{"<h2>The fit</h2>" + fig('inverse') if 'inverse' in figs else ""}
<h2>Validation</h2>{fig('segments')}
{"<h2>The paper's views</h2>" + paper if paper else ""}
<h2>Uncertainty</h2>{fig('uncertainty')}
<h2>Data coverage</h2>
<p>{cov['segments']} identification segments of {result.settings.segments.length} samples;
{cov['selected']} passed the selection rule (peak yaw rate above
{result.settings.segments.yaw_rate_threshold_radps} rad/s), {cov['not_selected']} were too
straight{f"; {cov['time_in_pieces_too_short_s']:.0f} s lie in pieces too short for a segment"
         if cov['time_in_pieces_too_short_s'] else ""}.
{cov['bend_s']:.0f} s of {cov['moving_s']:.0f} s of driving are in bends.</p>
{fig('coverage')}
<h2>Identifiability</h2><ul id="identifiability">{advice}</ul>
{"<h2>Checks of the data against the model</h2><ul id='checks'>" + checks + "</ul>"
 if checks else ""}
{"<h2>Warnings</h2><ul>" + warnings + "</ul>" if warnings else ""}
<p class="meta">Every number on this page is in calibration.json.</p>
</main></body></html>
"""


def write_report(result: CalibrationResult, out_dir: str | Path, *,
                 progress: Callable[[str, int, int], None] | None = None,
                 renderer: Renderer | None = None) -> Report:
    """Write ``report.html`` and ``figures/*.png`` into ``out_dir``.

    ``renderer`` draws the figures (start one early, see :class:`Renderer`); without one they
    are drawn in this process.
    """
    out = Path(out_dir)
    if progress:
        progress("report", 0, 1)
    data = build(result)
    with Renderer() if renderer is None else _borrowed(renderer) as draw:
        pngs = _figures(result, data, draw)
    paths = []
    for name, (_, png) in pngs.items():
        path = out / "figures" / f"{name}.png"
        write_bytes(path, png)
        paths.append(path)
    uris = {name: (caption, "data:image/png;base64," + base64.b64encode(png).decode("ascii"))
            for name, (caption, png) in pngs.items()}
    html_path = out / "report.html"
    write_text(html_path, _page(result, data, uris))
    if progress:
        progress("report", 1, 1)
    return Report(html_path=html_path, figure_paths=tuple(paths), data=data)

