"""The report shows what the numbers say (issue 30): bar lengths compare as the errors do,
captions say how to read each figure, the data coverage shows what the method fitted, a value
consistent with zero reads as such, and the checks' findings (a change inside the log, front
wheels, the departures taken out) reach the verdict and the page."""

from __future__ import annotations

import dataclasses
import html as html_lib
import io
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.collections import LineCollection, PolyCollection

import odocal
from odocal.checks.findings import Check
from odocal.model.layout import REAR_AXLE
from odocal.pipeline.result import CalibrationResult
from odocal.report.advice import ZERO_SIGMAS, consistent_with_zero
from odocal.report.data import build
from odocal.report.figures import RATIO_FLOOR, ratio_label
from odocal.report.html import _fitted, _page, _parameter_rows, segments_figure
from odocal.report.render import DPI, draw, figure
from odocal.report.style import CALIBRATED, DATASHEET
from odocal.sim import departures as dep
from odocal.sim.simulate import TRUE_PARAMETERS
from tests.conftest import run

# ------------------------------------------------------------------ bar lengths, as drawn


def _rgb(colour: str) -> np.ndarray:
    return np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)])


def _bars(png: bytes, colour: str, base: int | None = None) -> tuple[int, list[tuple[float, int]]]:
    """The bars of one fill colour standing on one baseline in a PNG: the baseline's row (the
    lowest row the colour reaches, unless given) and each bar's centre column and height in
    pixels, left to right."""
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    mask = np.abs(img - _rgb(colour)).sum(axis=2) <= 6
    if base is None:
        base = int(np.nonzero(mask)[0].max())
    columns = np.flatnonzero(mask[base])
    bars: list[tuple[float, int]] = []
    if not columns.size:
        return base, bars
    groups = np.split(columns, np.flatnonzero(np.diff(columns) > 1) + 1)
    for group in groups:
        heights = []
        for x in group:
            run = mask[:base + 1, x][::-1]
            heights.append(int(np.argmin(run)) if not run.all() else run.size)
        bars.append((float(group.mean()), int(np.median(heights))))
    return base, bars


def _heights(png: bytes, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The datasheet (red) and calibrated (blue) bars' heights in pixels, per segment (nan
    where a bar is too short to find)."""
    base, red = _bars(png, DATASHEET)
    _, blue = _bars(png, CALIBRATED, base)
    assert len(red) == n, red
    width = float(np.median(np.diff([x for x, _ in red]))) / 2 if n > 1 else 20.0
    paired = np.full(n, np.nan)
    for i, (x, _) in enumerate(red):
        mine = [h for bx, h in blue if x < bx < x + 1.5 * width]
        if mine:
            paired[i] = mine[0]
    return np.array([h for _, h in red], dtype=float), paired


def test_validation_bars_are_as_long_as_the_errors_in_the_report(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], noisy_drive: Any) -> None:
    """In the report's PNG, every bar's height in pixels is one scale times its error, from
    zero (a log axis from 0.1 m made a 10 m bar twice a 0.3 m one, not 33 times)."""
    path = tmp_path / "d.parquet"
    odocal.save_drive(noisy_drive.drive, path)
    assert run(capsys, "calibrate", str(path), "--out", str(tmp_path / "r"), "-q")[0] == 0
    errors = json.loads((tmp_path / "r" / "calibration.json").read_text())[
        "report"]["validation_segment_errors_m"]
    ds, cal = np.array(errors["datasheet"]), np.array(errors["calibrated"])
    red, blue = _heights((tmp_path / "r" / "figures" / "segments.png").read_bytes(), ds.size)
    found = np.isfinite(blue)
    values = np.concatenate([ds, cal[found]])
    pixels = np.concatenate([red, blue[found]])
    (scale, offset), *_ = np.linalg.lstsq(np.column_stack([values, np.ones_like(values)]),
                                          pixels, rcond=None)
    assert abs(offset) < 2.0, offset                       # the bars stand on zero
    assert np.max(np.abs(scale * values + offset - pixels)) < 1.6
    assert np.all(scale * cal[~found] < 2.5)               # only slivers too thin to find
    # the ratio a reader sees is the ratio of the errors
    tall = found & (blue > 20)
    assert tall.sum() >= 3
    np.testing.assert_allclose(red[tall] / blue[tall], ds[tall] / cal[tall], rtol=0.12)


def test_a_bar_fifty_times_another_reads_in_both_panels() -> None:
    """Top: linear from zero, the 10 m bar 50 times the 0.2 m one and the small one still a
    visible bar. Bottom: the ratio itself, as points on a log axis labelled with fractions,
    where 1/50 sits log-proportionally between 1/10 and 1."""
    errors = {"datasheet": np.array([10.0, 5.0, 8.0, 2.0]),
              "calibrated": np.array([0.2, 2.5, 4.0, 3.0])}
    fig = figure(segments_figure(errors, 300.0))
    fig.canvas.draw()
    top, bottom = fig.axes[:2]
    assert top.get_yscale() == "linear" and top.get_ylim()[0] == 0.0
    heights = {}
    for coll, name in zip([c for c in top.collections if isinstance(c, PolyCollection)],
                          ("datasheet", "calibrated"), strict=True):
        pixels = [top.transData.transform(p.vertices) for p in coll.get_paths()]
        heights[name] = np.array([v[:, 1].max() - v[:, 1].min() for v in pixels])
        zero = top.transData.transform((0, 0))[1]
        assert all(abs(v[:, 1].min() - zero) < 1e-6 for v in pixels)   # every bar from zero
    np.testing.assert_allclose(heights["datasheet"] / heights["calibrated"],
                               errors["datasheet"] / errors["calibrated"], rtol=1e-9)
    assert heights["calibrated"][0] * DPI / fig.dpi >= 3.0       # 0.2 m: a bar, not a hair
    assert bottom.get_yscale() == "log"
    (points,) = [c for c in bottom.collections if c.get_offsets().shape[0] == 4]
    ratio = errors["calibrated"] / errors["datasheet"]
    np.testing.assert_allclose(np.asarray(points.get_offsets())[:, 1], ratio)
    low, high = bottom.get_ylim()
    assert low < ratio.min() and high > ratio.max()             # every point on the axes
    labels = {t.get_text() for t in bottom.get_yticklabels()}
    for tick, label in zip(bottom.get_yticks(), bottom.get_yticklabels(), strict=True):
        if low <= tick <= high:
            assert label.get_text() == ratio_label(tick)
    assert "1/10" in labels and "1" in labels
    y = [bottom.transData.transform((1, r))[1] for r in (0.02, 0.1, 1.0)]
    assert (y[0] - y[2]) / (y[1] - y[2]) == pytest.approx(np.log(0.02) / np.log(0.1))


def test_count_axes_have_integer_ticks() -> None:
    errors = {"datasheet": np.linspace(1.0, 4.0, 7), "calibrated": np.linspace(0.5, 1.0, 7)}
    fig = figure(segments_figure(errors, 300.0))
    fig.canvas.draw()
    for ax in fig.axes[:2]:
        low, high = ax.get_xlim()
        ticks = [t for t in ax.get_xticks() if low <= t <= high]
        assert 2 <= len(ticks) <= 7 and all(float(t).is_integer() for t in ticks), ticks


def test_uncertainty_is_points_on_a_log_axis_not_bars() -> None:
    from matplotlib.figure import Figure

    from odocal.report.figures import plot_uncertainty

    ax = Figure().add_subplot()
    prior = np.array([0.05, 0.01, 0.10, 0.005])
    std = np.array([0.0005, 0.001, 0.02, 0.0])
    plot_uncertainty(ax, std, None, prior, (True, True, True, False), 0.5)
    assert not [c for c in ax.collections if isinstance(c, PolyCollection)] and not ax.patches
    (points,) = [c for c in ax.collections if c.get_offsets().shape[0]]
    np.testing.assert_allclose(np.asarray(points.get_offsets())[:, 1], [0.01, 0.1, 0.2])
    assert [t.get_text() for t in ax.texts] == ["not\nidentified"]
    assert ax.texts[0].get_position()[0] == 3                 # over d, the one not identified


# ------------------------------------------------------- the page's words, for each finding


@pytest.fixture(scope="module")
def changed() -> CalibrationResult:
    """A 15-minute drive whose c_e grows 1.2% at 400 s, logged with an IMU rolled 2.9 degrees,
    wheels reading 0.03 rev/s at standstill, a compass heading (4 degrees) and a reference
    0.4 s late: the part after the change is calibrated, the departures taken out."""
    after = TRUE_PARAMETERS.replace(c_e=TRUE_PARAMETERS.c_e * 1.012)
    sim = odocal.simulate(duration_s=900.0, seed=41, noise="realistic", change=(400.0, after))
    sim = dep.wheel_offset(sim, 0.03)
    sim = dep.lateral_offset(sim, 0.5)
    sim = dep.heading_error(sim, np.deg2rad(4.0), phase_rad=-1.1)
    sim = dep.reference_delay(sim, 0.4)
    return odocal.calibrate(sim.drive)


def _text(page: str) -> str:
    """What a reader sees of a page (tags dropped, entities decoded)."""
    return html_lib.unescape(re.sub(r"<[^>]+>", "", page))


def test_a_change_inside_the_log_is_never_the_plain_green_verdict(
        changed: CalibrationResult) -> None:
    (change,) = [f for f in changed.diagnosis.findings if f.check is Check.CHANGE_IN_LOG]
    data = build(changed)
    assert data.verdict_level == "partial"
    assert data.verdict.startswith(f"A change inside the log: c_e changed by {change.value:+.2%} "
                                   f"at t = {change.reference:.0f} s of ")
    assert "the calibration is of the part after the change" in data.verdict
    assert "up to 300 m each) after the change" in data.verdict
    page = _page(changed, data, {})
    assert 'class="verdict partial"' in page
    assert ("<li class='sev-fallback'><b>limits the calibration</b>: c_e changed by"
            in page)
    # the map's segments lie after the change, timed from the start of the log
    assert data.maps and all(m.start_s >= change.reference for m in data.maps), data.maps
    # what was fitted: every window, the part before the change with c_e and c_d of its own
    fitted = data.fitted
    assert fitted is not None and fitted.unit == "window"
    assert fitted.count == changed.estimate.details.windows
    assert fitted.after_change_s == pytest.approx(change.reference)
    assert fitted.start_s.min() < change.reference < fitted.start_s.max()
    text = _text(page)
    assert (f"fitted every 2 s window in which the vehicle moves, straight or turning: "
            f"{fitted.count} windows") in text
    assert ("the parameters are those after the change (the part before it has c_e and c_d "
            "of its own, and informs the rest), and only the part after it was validated"
            in text)


def test_the_fitted_figure_draws_the_windows_fitted(changed: CalibrationResult) -> None:
    data = build(changed)
    spec = _fitted(changed, data)
    assert spec is not None
    fig = figure(spec)
    ax = fig.axes[0]
    lines = [c for c in ax.collections if isinstance(c, LineCollection)]
    windows, strip = lines[0], lines[-1]
    assert len(windows.get_segments()) == data.fitted.count      # one line per window
    spans = np.array([[s[0, 0], s[1, 0]] for s in strip.get_segments()])
    # the strip's blue is the time fitted (minutes), before the change and after it
    assert np.sum(spans[:, 1] - spans[:, 0]) == pytest.approx(data.fitted.fitted_s() / 60)
    change = data.fitted.after_change_s / 60
    assert spans[:, 0].min() < change < spans[:, 1].max()
    assert any(line.get_xdata()[0] == pytest.approx(change) for line in ax.lines
               if line.get_label() == "change inside the log")
    assert ax.get_xlabel() == "time [min]"


def test_the_departures_taken_out_are_named_with_their_numbers(
        changed: CalibrationResult) -> None:
    found = changed.departures
    assert found is not None
    data = build(changed)
    assert ("measured and taken out before the fit: a heading error varying with the heading "
            f"(up to {np.degrees(found.heading_amplitude_rad):.1f} degrees), the wheel rates' "
            "offset at standstill (+0.030, +0.030 rev/s)") in data.verdict
    rows = {c.what: c for c in data.corrections}
    # a_y's offset is the one fit's: its value and std in the table, and named
    (fitted,) = [v for n, v, _ in changed.estimate.details.departures if n == "lateral_offset"]
    assert fitted == pytest.approx(0.5, abs=0.03)
    offset = rows["a_y's offset (in the fit)"]
    assert offset.taken_out and offset.measured.startswith(f"{fitted:+.4g} +-")
    heading = rows["the reference heading's error varying with the heading (a compass)"]
    assert heading.taken_out and heading.measured == (
        f"up to {np.degrees(found.heading_amplitude_rad):.1f} degrees")
    clock = rows["the wheel stream's clock against the reference's (in the fit)"]
    assert clock.taken_out and clock.measured.startswith(
        f"{abs(changed.estimate.details.delay_s):.3f}")
    assert changed.estimate.details.delay_s == pytest.approx(-0.4, abs=0.05)
    page = _page(changed, data, {})
    notes = re.findall(r"<li class='sev-note'><b>note</b>: ([^<]*)</li>", page)
    assert any("taken out before the fit" in n for n in notes), notes
    assert any("a_y reads +0.50" in n and "crossfall" in n for n in notes)
    table = page.split("<table id='corrections'>")[1].split("</table>")[0]
    assert table.count("<tr>") == len(data.corrections) + 1
    assert json.dumps(data.to_dict()["corrections"])          # in calibration.json as well


def test_front_wheels_are_refused_and_nothing_reads_as_calibrated() -> None:
    sim = dep.front_wheels(odocal.simulate(duration_s=600.0, seed=44, noise="realistic"), 2.9)
    result = odocal.calibrate(sim.drive)
    data = build(result)
    assert data.verdict_level == "bad"
    assert data.verdict.startswith("Do not use: the wheel speeds turn as wheels ")
    page = _page(result, data, {})
    cells = re.findall(r"<td class='(\w+)'>([^<]*)</td></tr>", page.split(
        '<table id="parameters">')[1].split("</table>")[0])
    assert cells == [("no", "rejected")] * 4
    assert "<li class='sev-fatal'><b>refuses the calibration</b>: the wheel speeds turn" in page
    assert "nothing else the fit took in (a lever arm, a smoothed reference, slip) explains it" \
        in _text(page)


# ---------------------------------------------------------------- consistent with zero


def _with_d_at(result: CalibrationResult, sigmas: float) -> CalibrationResult:
    est = result.estimate
    theta = est.theta.as_array().copy()
    j = REAR_AXLE.index("d")
    theta[j] = sigmas * est.std[j]
    return dataclasses.replace(result, estimate=dataclasses.replace(
        est, theta=odocal.Parameters.from_array(theta)))


@pytest.mark.parametrize(("sigmas", "zero"), [(1.95, True), (-1.95, True), (2.05, False),
                                              (-2.05, False)])
def test_d_within_two_std_of_zero_reads_consistent_with_zero(
        changed: CalibrationResult, sigmas: float, zero: bool) -> None:
    assert ZERO_SIGMAS == 2.0
    result = _with_d_at(changed, sigmas)
    assert result.estimate.identified[REAR_AXLE.index("d")]
    assert ("d" in consistent_with_zero(result.estimate)) is zero
    (row,) = [r for r in _parameter_rows(result) if "<b>d</b>" in r]
    if zero:
        assert row.endswith("<td class='zero'>yes: consistent with zero</td></tr>")
        assert "d consistent with zero: no measurable load transfer" in build(result).verdict
    else:
        assert row.endswith("<td class='yes'>yes</td></tr>")
        assert "consistent with zero" not in build(result).verdict


@pytest.mark.browser
def test_a_real_drives_report_reads_right_in_a_browser(
        shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The README's real log: its c_d is within two std of zero; in Chromium the table says
    so in a colour that is not the green of "yes", the CLI says it in a note, and no caption
    names a figure of the paper before saying what it shows."""
    from tests.report.test_report import _chromium

    executable = _chromium()
    if executable is None:
        pytest.skip("no Chromium on this machine (.ci/run installs Debian's chromium)")
    sync_api = pytest.importorskip("playwright.sync_api")
    scenes = [a for s in ("0061", "0796", "0916", "1077") for a in ("--scene", f"scene-{s}")]
    code, out, err = run(capsys, "calibrate", "--from", "nuscenes",
                         str(shared_data / "nuscenes-can-bus-mini"), *scenes, "--datasheet",
                         "c_e=1.95,t_r=1.51", "--out", str(tmp_path / "zoe"))
    assert code == 0, err
    data = json.loads((tmp_path / "zoe" / "calibration.json").read_text())
    c_d, std = data["theta"]["c_d"], data["std"]["c_d"]
    assert data["identified"]["c_d"] and abs(c_d) <= 2 * std     # the README's log, as it is
    assert data["report"]["consistent_with_zero"] == ["c_d"]
    assert (f"note: c_d = {c_d * 1000:+.3g} mm +-{std * 1000:.3g} mm is identified but "
            "consistent with zero") in out
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, headless=True,
                                    args=["--no-sandbox", "--disable-gpu", "--no-first-run"])
        page = browser.new_page(viewport={"width": 1200, "height": 900})
        page.goto((tmp_path / "zoe" / "report.html").as_uri())
        page.wait_for_load_state("load")
        shown = page.evaluate("""() => {
            const rows = Array.from(document.querySelectorAll('#parameters tr')).slice(1);
            return {
              rows: rows.map(r => { const c = r.cells[r.cells.length - 1];
                                    return [r.cells[0].innerText, c.innerText,
                                            getComputedStyle(c).color]; }),
              verdict: document.querySelector('#verdict').innerText,
              captions: Array.from(document.querySelectorAll('figcaption'))
                             .map(c => c.innerText),
              coverage: document.querySelector('#fitted-text').innerText};
        }""")
        browser.close()
    cells = {row[0].split()[0]: (row[1], row[2]) for row in shown["rows"]}
    green = "rgb(46, 155, 62)"
    assert cells["c_d"][0] == "yes: consistent with zero" and cells["c_d"][1] != green
    assert cells["c_e"] == ("yes", green)
    assert "c_d consistent with zero" in shown["verdict"]
    assert len(shown["captions"]) == 6
    for caption in shown["captions"]:
        assert not caption.startswith("Fig") and len(caption) > 150, caption
    assert shown["coverage"].startswith(
        f"The inverse method fitted every 2 s window in which the vehicle moves, straight or "
        f"turning: {data['details']['windows']} windows")
    assert f"in {data['details']['clusters']} clusters, from 4 drives" in shown["coverage"]


def test_errors_of_zero_are_drawn_at_the_floor() -> None:
    """A noise-free calibration's error is ~0: its ratio is drawn at the floor, pointing
    down; a segment whose datasheet error is 0 has no ratio (and no point)."""
    errors = {"datasheet": np.array([3.0, 0.0]), "calibrated": np.array([0.0, 0.0])}
    fig = figure(segments_figure(errors, 300.0))
    bottom = fig.axes[1]
    shown = [c for c in bottom.collections if c.get_offsets().shape[0]]
    assert len(shown) == 1 and shown[0].get_offsets().tolist() == [[1.0, RATIO_FLOOR]]
    assert bottom.get_ylim()[0] < RATIO_FLOOR
    assert draw(segments_figure(errors, 300.0)).startswith(b"\x89PNG")
