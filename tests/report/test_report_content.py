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
    assert "km of driving, less than the" in page


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
    assert "datasheet (placeholder: no --datasheet)" in page
    page = _page(tmp_path / "b", capsys, noisy_drive.drive, "--method", "raw")
    assert "std (bootstrap)" in page
    table = page.split('<table id="parameters">')[1].split("</table>")[0]
    assert all(row.count("<td") == 6 for row in table.split("<tr>")[2:])


def test_no_map_heading_without_a_map(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                      short_drive: Any) -> None:
    config = tmp_path / "long_segments.toml"
    config.write_text("[segments]\nvalidation_distance_m = 100000\n")
    page = _page(tmp_path, capsys, short_drive.drive, "--config", str(config))
    assert "<h2>Map</h2>" not in page and "fig-map" not in page


@pytest.mark.browser
def test_the_report_reads_on_a_phone(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                     noisy_drive: Any) -> None:
    from tests.report.test_report import ARTIFACTS, _chromium

    executable = _chromium()
    if executable is None:
        pytest.skip("no Chromium on this machine (.ci/run installs Debian's chromium)")
    sync_api = pytest.importorskip("playwright.sync_api")
    _page(tmp_path, capsys, noisy_drive.drive, "--method", "raw")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, headless=True,
                                    args=["--no-sandbox", "--disable-gpu", "--no-first-run"])
        page = browser.new_page(viewport={"width": PHONE, "height": 844}, device_scale_factor=2,
                                is_mobile=True)
        page.goto((tmp_path / "r" / "report.html").as_uri())
        page.wait_for_load_state("load")
        layout = page.evaluate("""() => ({
            page: document.scrollingElement.scrollWidth, view: window.innerWidth,
            images: Array.from(document.images).map(i => i.getBoundingClientRect().right),
            tables: Array.from(document.querySelectorAll('table')).map(
                t => t.getBoundingClientRect().right)})""")
        ARTIFACTS.mkdir(exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "report-phone.png"), full_page=False)
        browser.close()
    # a phone zooms out to the widest element: nothing may be wider than the phone
    assert layout["view"] == PHONE and layout["page"] <= PHONE + 1, layout
    assert all(right <= PHONE + 1 for right in layout["images"]), layout
    assert all(right <= PHONE + 1 for right in layout["tables"]), layout
