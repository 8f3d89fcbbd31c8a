"""The calibration report: one self-contained HTML page with its figures embedded, and the PNGs."""

from __future__ import annotations

import base64
import html
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from odocal._version import __version__
from odocal.estimators.estimate import Status
from odocal.io.atomic import write_bytes, write_text
from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_LABELS
from odocal.pipeline.result import CalibrationResult
from odocal.redaction import redact_text
from odocal.report.data import ReportData, build, parameter_rows
from odocal.report.render import Call, FigureSpec, Renderer
from odocal.report.style import CALIBRATED, CSS, RAW


@dataclass(frozen=True)
class Report:
    """What :func:`write_report` wrote, and the numbers it showed."""

    html_path: Path
    figure_paths: tuple[Path, ...]
    data: ReportData


Spec = FigureSpec | None

#: A map segment whose heading turns less than this is called straight.
MAP_TURN_DEG = 15.0


def _drive_label(name: str) -> str:
    """A drive's name as a title says it: the file's name, or a segment's route and number
    (comma2k19's ``ROUTE/40``)."""
    path = Path(name)
    return f"{path.parent.name}/{path.name}" if path.name.isdigit() else path.name


def _map(result: CalibrationResult, data: ReportData) -> Spec:
    if not data.maps:
        return None
    calls = [Call("plot_map", (m.reference, m.datasheet, m.calibrated),
                  {"title": f"{_drive_label(m.drive)}: {m.distance_m:.0f} m from "
                            f"{m.start_s:.0f} s"},
                  col=i) for i, m in enumerate(data.maps)]
    calls.append(Call("legend", kwargs={"fontsize": 8, "loc": "best"}))
    n = len(data.maps)
    turns = max(m.turn_rad for m in data.maps) >= np.deg2rad(MAP_TURN_DEG)
    which = ("the validation segment" if n == 1 else
             f"the {n} validation segments that turn most" if turns else
             f"{n} of the validation segments (none turns more than {MAP_TURN_DEG:g} degrees)")
    return FigureSpec("map", f"The map: {which}, each started at the reference's pose (the dot) "
                      "and driven on the wheels alone. Black is where the vehicle went (the "
                      "reference), red dashed where the wheels put it with the datasheet values, "
                      "blue with the calibrated ones: the closer blue stays to black, the better "
                      "the calibration. Positions in metres from the start.",
                      4.0 * n, 4.0, tuple(calls), cols=n)


def _step1(result: CalibrationResult, data: ReportData) -> Spec:
    ts = result.three_step
    if ts is None or not np.isfinite(ts.step1.validation_m).any():
        return None
    s1 = ts.step1
    ranks = [int(np.flatnonzero(s1.order == p)[0]) for p in s1.picked]
    raw = float(data.segment_errors["raw"].mean()) if "raw" in data.segment_errors else None
    cal = result.settings.calibrate
    return FigureSpec("step1", "Step 1 of the three-step method: a batch Gauss-Newton fit on "
                      f"each of {s1.validation_m.size} random batches of "
                      f"{cal.step1_batch_size} selected segments, one bar per batch, sorted by "
                      "its validation error E_p (linear scale from 0). The blue bars are the "
                      f"{len(s1.picked)} batches picked at equal steps through that order as "
                      "starting points for step 2; the lines are the final calibration's E_p "
                      "and that of one fit on all segments. Bars of similar height mean the "
                      "batches agree (the paper's Fig. 4).",
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
    return FigureSpec("spread", "The parameters each step-1 batch gave (grey points; those "
                      "picked for step 2 as blue squares) beside the final estimates with one "
                      "standard deviation (error bars), one panel per parameter; the dotted "
                      "line is the datasheet value. A tight cloud means the drive determines "
                      "the parameter; a wide one that the batches disagree (the paper's Figs. 5 "
                      "and 7).", 10.0, 3.2,
                      (Call("plot_parameter_spread", (ts.step1.thetas, list(ts.step1.picked),
                                                      estimates,
                                                      result.estimate.datasheet.as_array()),
                            row=None),), cols=4)


def _rates(result: CalibrationResult, data: ReportData) -> Spec:
    ts = result.three_step
    if ts is None or result.batch is None:
        return None
    # the segments a block at a time (a long drive's batch is copied out of it when asked)
    batch = result.batch
    peaks = np.concatenate([np.abs(batch.input_rows("a_y", lo, lo + 256)).max(axis=1)
                            for lo in range(0, len(batch), 256)])
    busiest = int(np.argmax(peaks))
    u = result.batch.part(busiest, busiest + 1).inputs
    t = np.arange(u.n_rl.shape[1], dtype=np.float64) * result.batch.t_s
    return FigureSpec("rates", "Step 2, the compensation, on the selected segment with the "
                      "highest lateral acceleration: each rear wheel's measured rotation rate "
                      "(thin) and the rate the optimal-control step chose so that the model "
                      "follows the reference (thick). The gap between them is what the method "
                      "takes for wheel noise and slip; step 3 fits the parameters to the thick "
                      "lines (the paper's Fig. 6).", 8.0, 3.2,
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
    return FigureSpec("inverse", f"The fit: one point per {d.window_s:.0f} s window of driving. "
                      "Across, the wheel revolutions the reference's motion implies with the "
                      "calibrated parameters; up, those the wheels counted. Left the mean of "
                      "the two wheels (it carries the distance, and c_e), right the right "
                      "wheel's minus the left's (it carries the turning, and c_d, t_r, d). On "
                      "the diagonal the model explains a window exactly; the scatter about it "
                      "is the noise the uncertainty is computed from.", 10.0, 3.6, calls, cols=2)


def _segments(result: CalibrationResult, data: ReportData) -> Spec:
    if not data.segment_errors:
        return None
    return segments_figure(data.segment_errors, result.settings.segments.validation_distance_m)


def segments_figure(errors: dict[str, np.ndarray], segment_m: float) -> FigureSpec:
    """The validation errors per segment: in metres on a linear axis, and as a fraction of the
    datasheet values' (``errors``: per parameter set, each segment's mean position error)."""
    sets = ("the datasheet values (red), the batch Gauss-Newton fit on the measured rates "
            "(orange) and the calibrated parameters (blue)" if "raw" in errors
            else "the datasheet values (red) and the calibrated ones (blue)")
    return FigureSpec("segments", f"Validation: each segment is a stretch of about "
                      f"{segment_m:.0f} m of the drive driven on the wheels alone from the "
                      "reference's pose at its start; its error is the mean distance from the "
                      f"reference along the way. Top: the errors in metres with {sets}, on "
                      "a linear scale from zero, so a bar twice as long is twice the error. "
                      "Bottom: the same "
                      "errors as a fraction of the datasheet values' on that stretch (1/10: ten "
                      "times smaller), on a log scale that keeps small fractions readable; a "
                      "point above the dashed line at 1 is a stretch the calibration made "
                      "worse. The stretches come from the drive the parameters were fitted on "
                      "(--compare scores on held-out time).",
                      8.0, 5.4, (Call("plot_segment_errors", (errors,)),
                                 Call("plot_error_ratio", (errors,), row=1)),
                      rows=2, height_ratios=(3.0, 2.0))


def _coverage(result: CalibrationResult, data: ReportData) -> Spec:
    threshold = result.settings.segments.yaw_rate_threshold_radps
    return FigureSpec("coverage", "What the drive holds: the time spent at each speed (left) "
                      "and at each yaw rate (right; positive turns left). Beyond the dashed "
                      f"lines (+-{threshold:g} rad/s) the vehicle is in a bend: t_r and d show "
                      "only there, c_e and c_d in any driving.", 10.0, 3.0, (
                          Call("plot_histogram", data.speed_hist, {"xlabel": "speed [m/s]"}),
                          Call("plot_histogram", data.yaw_hist,
                               {"xlabel": "yaw rate [rad/s]", "marks": (-threshold, threshold),
                                "mark_label": "bend threshold"}, col=1)), cols=2)


def _fitted(result: CalibrationResult, data: ReportData) -> Spec:
    f = data.fitted
    if f is None:
        return None
    threshold = result.settings.segments.yaw_rate_threshold_radps
    minutes = f.drives[-1][1] > 300.0
    scale = 1 / 60 if minutes else 1.0
    spans = tuple((a * scale, b * scale, name) for a, b, name in f.drives)
    if f.unit == "window":
        what = (f"What the {result.method} method fitted: every {f.length_s:.0f} s window in "
                "which the vehicle moves, straight or turning, each drawn where it lies in "
                "the drive (across) at the height of its largest yaw rate (up). Neighbouring "
                "windows share their errors and form clusters (the shades alternate from one "
                "to the next): the clusters are the independent pieces of evidence the "
                "uncertainty rests on.")
    else:
        what = (f"What the {result.method} method fitted: its identification segments "
                f"({f.length_s:.0f} s each, overlapping), each a line where it lies in the "
                "drive (across) at the height of its largest yaw rate (up); blue where the "
                "method fitted it, grey where it was too straight for the selection rule. "
                "Overlapping segments form clusters (the shades alternate from one to the "
                "next), the independent pieces of evidence the uncertainty rests on.")
    after = (" Only the part after the change inside the log (see the checks) was fitted."
             if f.after_change_s is not None else "")
    return FigureSpec("fitted", what + " The strip beneath shows each drive in grey and the "
                      "time the fit used in blue." + after, 10.0, 3.2, (
                          Call("plot_fitted", (f.start_s * scale, f.stop_s * scale,
                                               f.peak_yaw_radps, f.fitted, f.cluster, spans,
                                               f.used_spans() * scale),
                               {"threshold": threshold, "unit": f.unit,
                                "time_unit": "min" if minutes else "s",
                                "change": f.after_change_s * scale
                                if f.after_change_s is not None else None}),))


def _uncertainty(result: CalibrationResult, data: ReportData) -> Spec:
    ident = result.settings.identify
    sources = "the covariance" + (" (circles) and from the bootstrap (diamonds)"
                                  if result.bootstrap is not None else "")
    return FigureSpec("uncertainty", "How precisely the drive determines each parameter: its "
                      f"standard deviation from {sources}, as a fraction of the datasheet "
                      "uncertainty ([identify] prior_std), on a log scale (1/100: the drive "
                      "knows it a hundred times better than the datasheet). A parameter is "
                      "identified when its point lies below the dashed limit.", 6.0, 3.2, (
                          Call("plot_uncertainty", (
                              result.estimate.std,
                              result.bootstrap.std if result.bootstrap is not None else None,
                              np.asarray(ident.prior_std), result.estimate.identified,
                              ident.identifiable_ratio)),))


#: Every figure of the page, in page order.
FIGURES: dict[str, Callable[[CalibrationResult, ReportData], Spec]] = {
    "map": _map, "inverse": _inverse, "step1": _step1, "spread": _spread, "rates": _rates,
    "segments": _segments, "coverage": _coverage, "fitted": _fitted,
    "uncertainty": _uncertainty}


def _figures(result: CalibrationResult, data: ReportData,
             renderer: Renderer) -> dict[str, tuple[str, bytes]]:
    """name -> (caption, PNG bytes) of every figure this result has."""
    specs = [spec for make in FIGURES.values() if (spec := make(result, data)) is not None]
    return {s.name: (s.caption, png) for s, png in zip(specs, renderer.draw(specs), strict=True)}


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


def _identified(row: dict[str, object], rejected: bool) -> str:
    """The table's last cell: whether the data identify the parameter, and what that says."""
    if rejected:
        return "<td class='no'>rejected</td>"
    if not row["identified"]:
        return "<td class='no'>no</td>"
    if row["consistent_with_zero"]:
        # identified, but the value does not show that the effect exists
        return "<td class='zero'>yes: consistent with zero</td>"
    return "<td class='yes'>yes</td>"


def _parameter_rows(result: CalibrationResult) -> list[str]:
    """The result table's rows: each parameter, datasheet, calibrated, std, verdict."""
    from odocal.estimators.estimate import Status

    e = html.escape
    rejected = result.estimate.status is Status.REJECTED
    rows = []
    for row, label in zip(parameter_rows(result), PARAMETER_LABELS, strict=True):
        name = row["name"]
        ident = row["identified"]
        cal = _fmt(name, row["calibrated"]) if ident else "not identified"
        rows.append(
            f"<tr><td><b>{name}</b> {e(label)}</td><td>{_fmt(name, row['datasheet'])}</td>"
            f"<td>{cal}</td><td>{_fmt(name, row['std']) if ident else '-'}</td>"
            + (f"<td>{_fmt(name, row['bootstrap_std']) if ident else '-'}</td>"
               if row["bootstrap_std"] is not None else "")
            + _identified(row, rejected) + "</tr>")
    return rows


#: How each severity of a finding reads, and its list style.
_SEVERITY = {0: ("note", "sev-note"), 1: ("limits the calibration", "sev-fallback"),
             2: ("refuses the calibration", "sev-fatal")}


def _checks(result: CalibrationResult) -> str:
    """The checks' findings, each with what it means for the calibration."""
    from odocal.report.advice import finding_text

    items = []
    for f in result.diagnosis.findings:
        word, style = _SEVERITY[int(f.severity)]
        items.append(f"<li class='{style}'><b>{word}</b>: "
                     f"{html.escape(finding_text(f, result.settings))}</li>")
    if not items:
        return ""
    return ("<h2>Checks of the data against the model</h2><ul id='checks'>" + "".join(items)
            + "</ul>")


def _corrections(data: ReportData) -> str:
    """What was measured of the sensors' departures from the model, and what was taken out."""
    if not data.corrections:
        return ""
    e = html.escape
    rows = "".join(f"<tr><td>{e(c.what)}</td><td>{e(c.measured)}</td>"
                   f"<td class='{'yes' if c.taken_out else 'meta'}'>"
                   f"{'yes' if c.taken_out else 'no'}</td><td>{e(c.note)}</td></tr>"
                   for c in data.corrections)
    return ("<h2>Corrections before the fit</h2><p>What odocal measured of the sensors' "
            "departures from the model, against the reference, and took out where the data "
            "determine it: the calibration above stands on the corrected data.</p>"
            "<table id='corrections'><tr><th>what</th><th>measured</th><th>taken out</th>"
            f"<th>how</th></tr>{rows}</table>")


def _coverage_text(result: CalibrationResult, data: ReportData) -> str:
    """What the drive holds and what the method fitted, in words."""
    cov = data.coverage
    f = data.fitted
    seg = result.settings.segments
    threshold = seg.yaw_rate_threshold_radps
    logged = f"{cov['duration_s'] / 60:.1f} min logged"
    bends = f"{cov['bend_s']:.0f} s of {cov['moving_s']:.0f} s of driving are in bends."
    short = (f" {cov['time_in_pieces_too_short_s']:.0f} s lie in pieces too short for a "
             "segment." if cov['time_in_pieces_too_short_s'] else "")
    drives = len(result.drives)
    from_drives = f"from {drives} drive{'s' if drives != 1 else ''}"
    if f is None:
        why = ("the vehicle does not move" if result.diagnosis.standstill
               else "the checks refused the data (see below)" if result.diagnosis.fatal
               else f"the drives hold too little moving data for the {result.method} method")
        return f"<p id='fitted-text'>Nothing was fitted: {why}. {bends}{short}</p>"
    method = html.escape(result.method)
    if f.unit == "window":
        text = (f"The {method} method fitted every {f.length_s:.0f} s window in which "
                f"the vehicle moves, straight or turning: {f.count} windows "
                f"({f.fitted_s() / 60:.1f} min of the {logged}) in {f.clusters} clusters, "
                f"{from_drives}. {f.in_bends(threshold)} of them turn faster than "
                f"{threshold:g} rad/s: t_r and d rest on those.")
    else:
        total = f.fitted.size
        rule = (f"those whose peak yaw rate exceeds {threshold:g} rad/s (the selection rule); "
                f"{total - f.count} were too straight"
                if f.count < total else
                f"every one: only {cov['selected']} pass the selection rule (a peak yaw rate "
                f"above {threshold:g} rad/s), too few to fit alone")
        text = (f"The {method} method fitted {f.count} of the {total} identification "
                f"segments of {seg.length} samples ({f.length_s:.1f} s; a new one every "
                f"{seg.step} samples, so they overlap), in {f.clusters} clusters, "
                f"{from_drives}: {rule}. They cover {f.fitted_s() / 60:.1f} min of the "
                f"{logged}.")
    if f.after_change_s is not None:
        text += (" The log changes inside (see the checks): the parameters are those after "
                 "the change (the part before it has c_e and c_d of its own, and informs the "
                 "rest), and only the part after it was validated.")
    return f"<p id='fitted-text'>{text} {bends}{short}</p>"


def _advice_style(name: str, identified: bool, data: ReportData) -> str:
    if not identified:
        return "no"
    return "zero" if name in data.zero else "yes"


def _validation(result: CalibrationResult, data: ReportData) -> str:
    """E_p of the datasheet values, raw G-N and the calibration, in one line."""
    if result.validation is None or result.datasheet_validation is None:
        return ""
    parts = [f"datasheet {result.datasheet_validation.mean_error_m:.3f} m"]
    if "raw" in data.segment_errors:
        parts.append(f"batch G-N on measured rates {data.segment_errors['raw'].mean():.3f} m")
    parts.append(f"<b>calibrated {result.validation.mean_error_m:.3f} m</b>")
    return (f"<p>Validation error E_p over {html.escape(result.validation_text())}: "
            + " &rarr; ".join(parts) + "</p>")


def _speed_scale(result: CalibrationResult) -> str:
    """Where the wheels were speeds, what c_e means: the speed signal's scale factor."""
    from odocal.report.summary import speed_note

    speed = result.speed_scale
    if speed is None:
        return ""
    text = speed_note(speed, float(result.theta.c_e)).removeprefix("note: ")
    return f"<p id='speed-scale'>{html.escape(text[:1].upper() + text[1:])}.</p>"


def _next_step(result: CalibrationResult, data: ReportData) -> str:
    """What to do next, with the command that does it."""
    e = html.escape
    files = [str(d.metadata.get("source", "")) for d in result.drive_data]
    sources = (" ".join(Path(f).name for f in files) if files and all(
        f.endswith((".csv", ".parquet")) for f in files) else "LOG ...")
    if result.estimate.status is Status.REJECTED:
        text, command = ("Fix what the checks name above (the mapping's units, columns or "
                         "signs), look at the streams again, then calibrate again:",
                         "odocal inspect --from FORMAT LOG --mapping MAP.toml")
    elif result.estimate.unidentified:
        text, command = (f"{', '.join(result.estimate.unidentified)} need more or other "
                         "driving (above): calibrate these logs together with one that has "
                         "it (with this run's --from and --datasheet):",
                         f"odocal calibrate {sources} OTHER_LOG --out results/")
    else:
        text, command = ("Check the calibration on a drive it was not fitted on, then hand it "
                         "to your localisation stack (--export autoware, ros2_control, "
                         "robot_localization, yaml):",
                         "odocal validate OTHER_LOG --params calibration.json")
    return f"<h2>Next step</h2><p>{e(text)}</p><pre id='next-step'>{e(command)}</pre>"


def _result_table(result: CalibrationResult) -> str:
    """The parameter table (datasheet, calibrated, standard deviations, identified) and a line
    on the covariance and the bootstrap beneath it."""
    e = html.escape
    rows = _parameter_rows(result)
    boot = result.bootstrap
    from odocal.settings import datasheet_stated

    sheet = ("datasheet" if datasheet_stated(result.estimate.datasheet)
             else "datasheet (placeholder: no <span class='nowrap'>--datasheet</span>)")
    boot_head = "<th>std (bootstrap)</th>" if boot is not None else ""
    return f"""<table id="parameters"><tr><th>parameter</th><th>{sheet}</th><th>calibrated</th>
<th>std (covariance)</th>{boot_head}<th>identified</th></tr>
{''.join(rows)}</table>
<p class="meta">Covariance: {e(result.estimate.covariance_kind.value)}.
{e(boot.message[:1].upper() + boot.message[1:]) + '.' if boot is not None
 else 'No bootstrap.'}</p>{_car_table(result)}"""


def _car_table(result: CalibrationResult) -> str:
    """The four-wheel car's table (its rear axle joined with the front axle and the steering)
    where ``[vehicle] model`` chose it; nothing for the rear axle."""
    vehicle = result.vehicle_estimate
    if vehicle is None or vehicle.status is Status.REJECTED:
        return ""
    e = html.escape
    layout = vehicle.theta.layout
    theta, sheet, std = vehicle.theta.as_array(), vehicle.datasheet.as_array(), vehicle.std
    rows = []
    for j, name in enumerate(layout.names):
        ok = bool(vehicle.identified[j])
        rows.append(f"<tr><td><b>{name}</b> {e(layout.labels[j])}</td>"
                    f"<td>{_fmt(name, float(sheet[j]))}</td>"
                    f"<td>{_fmt(name, float(theta[j])) if ok else 'not identified'}</td>"
                    f"<td>{_fmt(name, float(std[j])) if ok else '-'}</td>"
                    f"<td class='{'yes' if ok else 'no'}'>{'yes' if ok else 'no'}</td></tr>")
    return (f"<h3>The {e(vehicle.model)} model: the rear axle joined with the front axle and "
            "the steering</h3><table id='car'><tr><th>parameter</th><th>datasheet</th>"
            "<th>calibrated</th><th>std (covariance)</th><th>identified</th></tr>"
            f"{''.join(rows)}</table>")


def _page(result: CalibrationResult, data: ReportData,
          figs: dict[str, tuple[str, str]]) -> str:
    e = html.escape
    val = _validation(result, data)

    def fig(name: str) -> str:
        if name not in figs:
            return ""
        caption, uri = figs[name]
        return (f"<figure id='fig-{name}'><img alt='{e(caption)}' src='{uri}'>"
                f"<figcaption>{e(caption)}</figcaption></figure>")

    cov = data.coverage
    warnings = "".join(f"<li>{e(w)}</li>" for w in result.warnings)
    advice = "".join(f"<li class='{_advice_style(a.name, a.identified, data)}'>"
                     f"<b>{a.name}</b>: <span style='color:#222'>{e(a.text)}</span></li>"
                     for a in data.advice)
    drives = ", ".join(e(Path(d.name).name) for d in result.drives)
    comparison = _comparison(result)
    paper = fig("step1") + fig("spread") + fig("rates") if result.three_step else ""
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>odocal calibration report</title><style>{CSS}</style></head>
<body><main>
<h1>Wheel-odometry calibration</h1>
<div class="meta">{drives} &middot; method {e(result.method)} &middot; odocal {__version__}
&middot; {cov['distance_m'] / 1000:.2f} km, {cov['duration_s'] / 60:.1f} min</div>
<div class="verdict {data.verdict_level}" id="verdict">{e(data.verdict)}</div>
<h2>Result</h2>
{_result_table(result)}
{_speed_scale(result)}
{val}
{comparison}
{"<h2>Map</h2>" + fig('map') if 'map' in figs else ""}
{"<h2>The fit</h2>" + fig('inverse') if 'inverse' in figs else ""}
<h2>Validation</h2>{fig('segments')}
{"<h2>Inside the three-step method</h2>" + paper if paper else ""}
<h2>Uncertainty</h2>{fig('uncertainty')}
<h2>Data coverage</h2>
{_coverage_text(result, data)}
{fig('fitted')}
{fig('coverage')}
<h2>Identifiability</h2><ul id="identifiability">{advice}</ul>
{_checks(result)}
{_corrections(data)}
{"<h2>Warnings</h2><ul>" + warnings + "</ul>" if warnings else ""}
{_next_step(result, data)}
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
    write_text(html_path, redact_text(_page(result, data, uris)))  # no secret on the page
    if progress:
        progress("report", 1, 1)
    return Report(html_path=html_path, figure_paths=tuple(paths), data=data)

