"""What the report page says, and what it leaves out when there is nothing to show (issue 25)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.report.data import MIN_DISTANCE_KM
from tests.conftest import run

PHONE = 390                                        # CSS pixels across a phone's screen


def _page(tmp_path: Path, capsys: pytest.CaptureFixture[str], drive: Any, *args: str) -> str:
    path = tmp_path / "d.parquet"
    odocal.save_drive(drive, path)
    out = tmp_path / "r"
    code, _, err = run(capsys, "calibrate", str(path), "--out", str(out), *args)
    assert code in (0, 3), err
    return (out / "report.html").read_text()


def test_a_short_drive_never_gets_the_green_verdict(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    drive = odocal.simulate(duration_s=120, seed=3, noise="realistic").drive
    assert drive.distance_m / 1000 < MIN_DISTANCE_KM
    page = _page(tmp_path, capsys, drive)
    assert 'class="verdict good"' not in page
    verdict = page.split('id="verdict">')[1].split("</div>")[0]
    km = sum(d.distance_m for d in [drive]) / 1000
    # said first, with the distance and the README's minimum, before the numbers that look good
    assert verdict.startswith(f"Drive too short to trust: {km:.2f} km of driving, less than "
                              f"the {MIN_DISTANCE_KM:g} km"), verdict


def test_a_long_drive_with_every_parameter_can_be_green(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str],
                                                        noisy_drive: Any) -> None:
    assert noisy_drive.drive.distance_m / 1000 > MIN_DISTANCE_KM
    page = _page(tmp_path, capsys, noisy_drive.drive, "--datasheet", "c_e=1.95,t_r=1.5")
    assert 'class="verdict good"' in page
    assert "<th>datasheet</th>" in page


def test_the_bootstrap_column_only_where_there_is_a_bootstrap(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], noisy_drive: Any) -> None:
    page = _page(tmp_path / "a", capsys, noisy_drive.drive)                 # the default
    assert "std (bootstrap)" not in page
    assert "datasheet (placeholder: no <span class='nowrap'>--datasheet</span>)" in page
    assert "from the covariance, as a fraction" in page         # no bootstrap in the caption
    page = _page(tmp_path / "b", capsys, noisy_drive.drive, "--method", "raw")
    assert "std (bootstrap)" in page
    assert "from the covariance (circles) and from the bootstrap (diamonds)" in page
    table = page.split('<table id="parameters">')[1].split("</table>")[0]
    rows = table.split("<tr>")[2:]
    assert rows and all(row.count("<td") == 6 for row in rows)
    # the bootstrap's standard deviations themselves, as calibration.json has them
    import json

    boot = json.loads((tmp_path / "b" / "r" / "calibration.json").read_text())["bootstrap"]
    cells = [row.split("<td")[4] for row in rows]
    assert all(any(ch.isdigit() for ch in cell) for cell in cells), cells
    assert boot is not None


def test_maps_time_seconds_from_the_start_of_the_log(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], short_drive: Any) -> None:
    import json

    # a log on the epoch clock: the map titles count seconds from the log's start
    drive = short_drive.drive
    columns = drive.columns()
    columns["t"] = columns["t"] + 1.7e9
    epoch = odocal.Drive.from_columns(columns, name=drive.name, metadata=drive.metadata)
    _page(tmp_path, capsys, epoch)
    maps = json.loads((tmp_path / "r" / "calibration.json").read_text())["report"]["map_segments"]
    assert maps and all(0 <= m["start_s"] <= drive.duration_s for m in maps), maps


def test_no_map_heading_without_a_map(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                      short_drive: Any) -> None:
    config = tmp_path / "long_segments.toml"
    config.write_text("[segments]\nvalidation_distance_m = 100000\n")
    page = _page(tmp_path, capsys, short_drive.drive, "--config", str(config))
    assert "<h2>Map</h2>" not in page and "fig-map" not in page


@pytest.mark.browser
def test_the_report_reads_on_a_phone(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                     noisy_drive: Any) -> None:
    """At a phone's width (390 x 844 CSS pixels): the page is no wider than the phone (a phone
    would zoom out to the widest element), every figure is drawn inside it, and a table wider
    than the phone scrolls inside its own box while the page stays put."""
    from tests.report.test_report import ARTIFACTS, _chromium

    executable = _chromium()
    if executable is None:
        pytest.skip("no Chromium on this machine (.ci/run installs Debian's chromium)")
    sync_api = pytest.importorskip("playwright.sync_api")
    _page(tmp_path, capsys, noisy_drive.drive, "--method", "raw")     # the widest table
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, headless=True,
                                    args=["--no-sandbox", "--disable-gpu", "--no-first-run"])
        page = browser.new_page(viewport={"width": PHONE, "height": 844}, device_scale_factor=2,
                                is_mobile=True, has_touch=True)
        page.goto((tmp_path / "r" / "report.html").as_uri())
        page.wait_for_load_state("load")
        layout = page.evaluate("""() => ({
            page: document.scrollingElement.scrollWidth, view: window.innerWidth,
            images: Array.from(document.images).map(i => {
                const r = i.getBoundingClientRect();
                return {id: i.parentElement.id, left: r.left, right: r.right, width: r.width,
                        height: r.height, natural: i.naturalWidth, complete: i.complete,
                        shown: getComputedStyle(i).visibility === 'visible'
                               && getComputedStyle(i).display !== 'none'};
            }),
            tables: Array.from(document.querySelectorAll('table')).map(t => ({
                id: t.id, right: t.getBoundingClientRect().right, scroll: t.scrollWidth,
                box: t.clientWidth, overflow: getComputedStyle(t).overflowX}))})""")
        wide = page.evaluate("""() => {
            const t = Array.from(document.querySelectorAll('table'))
                .find(t => t.scrollWidth > t.clientWidth + 1);
            if (!t) return null;
            t.scrollLeft = 10000;
            return {id: t.id, scrolled: t.scrollLeft, page: window.scrollX};
        }""")
        ARTIFACTS.mkdir(exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "report-phone.png"), full_page=True)
        browser.close()
    # a phone zooms out to the widest element: nothing may be wider than the phone
    assert layout["view"] == PHONE and layout["page"] <= PHONE + 1, layout
    assert layout["images"], layout
    for img in layout["images"]:                   # every figure drawn, whole, on the screen
        assert img["complete"] and img["natural"] > 300 and img["shown"], img
        assert img["left"] >= 0 and img["right"] <= PHONE + 1, img
        assert img["width"] > PHONE / 2 and img["height"] > 50, img
    for table in layout["tables"]:                 # wide tables scroll in their own box
        assert table["right"] <= PHONE + 1 and table["overflow"] == "auto", table
    assert wide is not None, layout                # the raw method's table is wider than a phone
    assert wide["scrolled"] > 0 and wide["page"] == 0, wide


def test_the_replay_report_times_alarms_from_the_start_of_the_log(tmp_path: Path) -> None:
    """A log on the epoch clock: the change is shown at 600 s, not at 1700000600 s; the log's
    name escaped."""
    from odocal.online.changes import Alarm
    from odocal.online.replay import ReplayResult, TraceRow
    from odocal.report.replay import write_replay_report

    start = 1.7e9
    estimate = odocal.calibrate(odocal.simulate(duration_s=300, seed=1).drive).estimate
    rows = tuple(TraceRow(t=start + t, distance_km=t / 100, theta=(1.95, 0.0, 1.5, 0.0),
                          std=(1e-3,) * 4, identified=(True,) * 4) for t in (60.0, 1200.0))
    alarm = Alarm(parameter="c_e", t=start + 600.0, detected_t=start + 700.0, distance_km=6.0,
                  detected_distance_km=7.0, relative_change=0.01, sigmas=5.0)
    result = ReplayResult(source="a<b>&.csv", estimate=estimate, trace=rows, alarms=(alarm,),
                          samples=1000, duration_s=1200.0, distance_km=12.0, elapsed_s=1.0)
    page = write_replay_report(result, tmp_path).read_text()
    table = page.split("<table id='alarms'>")[1].split("</table>")[0]
    assert "<td>600 s</td>" in table and "1700000" not in table, table
    assert "a&lt;b&gt;&amp;.csv" in page and "a<b>" not in page     # the name is text


def test_a_drive_files_name_is_shown_escaped(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """A file name is text, never markup: ``a<b>&.csv`` in the heading's line and in the next
    step's command (a straight drive leaves t_r and d to another log: the command names it)."""
    from tests.conftest import straight_drive

    path = tmp_path / "a<b>&.csv"
    odocal.save_drive(straight_drive(), path)
    code, _, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "r"))
    assert code in (0, 3), err
    page = (tmp_path / "r" / "report.html").read_text()
    assert "a<b>" not in page and "<b>&" not in page
    meta = page.split('<div class="meta">')[1].split("</div>")[0]
    assert meta.startswith("a&lt;b&gt;&amp;.csv &middot;"), meta
    command = page.split("<pre id='next-step'>")[1].split("</pre>")[0]
    assert command == "odocal calibrate a&lt;b&gt;&amp;.csv OTHER_LOG --out results/", command
