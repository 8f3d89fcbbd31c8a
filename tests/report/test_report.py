"""The report: content, exports, and rendering in a real browser (headless Chromium)."""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

import odocal
from odocal.cli.main import EXIT_OK, main
from odocal.report import write_report
from odocal.report.html import _fmt
from odocal.report.render import Call, FigureSpec, Renderer, draw
from odocal.sim.simulate import SimulatedDrive
from tests.conftest import straight_drive

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
#: The figures each method's report shows.
FIGURES = {"inverse": ("map", "inverse", "segments", "coverage", "fitted", "uncertainty"),
           "compensated": ("map", "segments", "step1", "spread", "rates", "coverage", "fitted",
                           "uncertainty")}


def _calibrate(tmp_path_factory: pytest.TempPathFactory, drive: odocal.Drive,
               method: str) -> Path:
    path = tmp_path_factory.mktemp(f"report-{method}") / "drive.parquet"
    odocal.save_drive(drive, path)
    out = path.parent / "out"
    assert main(["calibrate", str(path), "--out", str(out), "--export", "yaml", "--export",
                 "json", "--method", method, "-q"]) == EXIT_OK
    return out


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory, noisy_drive: SimulatedDrive) -> Path:
    """The default method's results folder for a 15-minute realistic drive."""
    return _calibrate(tmp_path_factory, noisy_drive.drive, "inverse")


@pytest.mark.parametrize("method", sorted(FIGURES))
def test_report_files_and_numbers(method: str, tmp_path_factory: pytest.TempPathFactory,
                                  calibrated: Path, noisy_drive: SimulatedDrive) -> None:
    out = calibrated if method == "inverse" else _calibrate(tmp_path_factory,
                                                            noisy_drive.drive, method)
    page = (out / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>")
    assert "http://" not in page and "https://" not in page      # opens offline
    for name in FIGURES[method]:
        assert (out / "figures" / f"{name}.png").stat().st_size > 5000
        assert f"id='fig-{name}'" in page
    assert sorted(p.stem for p in (out / "figures").glob("*.png")) == sorted(FIGURES[method])
    data = json.loads((out / "calibration.json").read_text())
    assert data["method"] == method
    report = data["report"]
    assert report["verdict"] in page
    # a realistic 15-minute city drive identifies everything and validates far better
    assert report["verdict_level"] == "good"
    assert report["verdict"].startswith("Calibrated: the validation error E_p falls from")
    assert len(report["identifiability"]) == 4
    assert report["coverage"]["selected"] == data["segments_selected"]
    errors = report["validation_segment_errors_m"]
    assert np.mean(errors["calibrated"]) == pytest.approx(data["validation"]["E_p_m"])
    expected = {"datasheet", "calibrated"} | ({"raw"} if method == "compensated" else set())
    assert set(errors) == expected
    if method == "inverse":
        assert data["bootstrap"] is None      # the sandwich is checked on the noise matrix
    else:
        assert data["bootstrap"]["count"] == 200 and "agree" in data["bootstrap"]
    for name, value in data["theta"].items():       # as the parameter table prints them
        assert _fmt(name, value) in page
    # every caption says what its figure shows before any reference to the paper
    captions = re.findall(r"<figcaption>([^<]*)</figcaption>", page)
    assert len(captions) == len(FIGURES[method])
    for caption in captions:
        assert not caption.startswith("Fig") and len(caption) > 150, caption
        assert "of the paper" not in caption and "paper" not in caption.split("(the paper")[0]
    # the coverage shows what this method fitted
    fitted = report["coverage"]["fitted"]
    if method == "inverse":
        assert fitted["unit"] == "window" and fitted["fitted"] == data["details"]["windows"]
        assert fitted["clusters"] == data["details"]["clusters"] == data["used"]["clusters"]
        assert fitted["not_fitted"] == 0
    else:
        assert fitted["unit"] == "segment" and fitted["fitted"] == data["segments_used"]
        assert fitted["fitted"] + fitted["not_fitted"] == data["segments_total"]
        assert fitted["clusters"] == data["used"]["clusters"]
    assert f"fitted {'every 2 s window' if method == 'inverse' else fitted['fitted']}" in page


def test_exports(calibrated: Path) -> None:
    out = calibrated
    exported = json.loads((out / "odometry_parameters.json").read_text())
    data = json.loads((out / "calibration.json").read_text())
    assert exported["theta"] == data["theta"]
    assert np.array(exported["covariance"]).shape == (4, 4)
    text = (out / "odometry_parameters.yaml").read_text()
    assert "ros__parameters:" in text and "rear_track_width:" in text
    import yaml  # PyYAML: only to check the file parses the way ROS 2 would read it

    params = yaml.safe_load(text)["wheel_odometry"]["ros__parameters"]
    assert params["effective_wheel_circumference"] == pytest.approx(data["theta"]["c_e"])
    assert len(params["covariance"]) == 16


def test_drive_without_bends_names_what_it_cannot_identify(tmp_path: Path) -> None:
    result = odocal.calibrate(straight_drive(), method="raw")
    report = write_report(result, tmp_path)
    advice = {a.name: a for a in report.data.advice}
    assert advice["c_e"].identified
    for name in ("t_r", "d"):
        assert not advice[name].identified and "needs bends" in advice[name].text
        assert "0 s" in advice[name].text
    page = report.html_path.read_text()
    assert "t_r, d not identified" in page


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.mark.browser
def test_report_renders_in_headless_chromium(calibrated: Path) -> None:
    executable = _chromium()
    if executable is None:
        pytest.skip("no Chromium on this machine (.ci/run installs Debian's chromium)")
    sync_api = pytest.importorskip("playwright.sync_api")
    out = calibrated
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=executable, headless=True,
            args=["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync"])
        page = browser.new_page(viewport={"width": 1200, "height": 900})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto((out / "report.html").as_uri())
        page.wait_for_load_state("load")
        figures = page.evaluate("""() => Array.from(document.images).map(img => {
            const c = document.createElement('canvas');
            c.width = img.naturalWidth; c.height = img.naturalHeight;
            const ctx = c.getContext('2d'); ctx.drawImage(img, 0, 0);
            const d = ctx.getImageData(0, 0, c.width, c.height).data;
            let dark = 0;
            for (let i = 0; i < d.length; i += 4) if (d[i] + d[i + 1] + d[i + 2] < 600) dark++;
            return {id: img.parentElement.id, width: img.naturalWidth, complete: img.complete,
                    dark: dark / (d.length / 4)};
        })""")
        ARTIFACTS.mkdir(exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "report.png"), full_page=True)
        verdict = page.inner_text("#verdict")
        browser.close()
    assert errors == []
    assert {f["id"] for f in figures} == {f"fig-{name}" for name in FIGURES["inverse"]}
    for f in figures:
        assert f["complete"] and f["width"] > 300, f
        assert f["dark"] > 0.01, f                    # not blank: axes, lines, text drawn
    assert verdict.startswith("Calibrated: the validation error E_p falls from")
    assert (ARTIFACTS / "report.png").stat().st_size > 50_000


def _spec(function: str = "plot_map") -> FigureSpec:
    line = np.array([[0.0, 0.0], [3.0, 1.0], [5.0, 4.0]])
    return FigureSpec("test", "", 3.0, 2.0, (Call(function, (line, line, line),
                                                   {"title": "a test"}),))


def test_the_helpers_draw_what_this_process_draws_and_leave_nothing_behind() -> None:
    specs = [_spec(), _spec(), _spec()]
    here = [draw(s) for s in specs]
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    renderer = Renderer(2)
    assert renderer.draw(specs) == here
    drawing = [p for p in psutil.Process().children(recursive=True) if p.pid not in before]
    assert len(drawing) == 1                          # the host (its drawing process is done)
    with pytest.raises(AttributeError, match="no_such_figure"):
        renderer.draw([_spec(), _spec("no_such_figure")])
    assert renderer.draw(specs[:1]) == here[:1]       # still usable after a figure failed
    renderer.close()
    assert _gone([p.pid for p in drawing], 20)


def _gone(pids: list[int], timeout: float) -> bool:
    """Whether every process in ``pids`` has ended (a zombie has) within ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        alive = []
        for pid in pids:
            with contextlib.suppress(psutil.NoSuchProcess):
                if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                    alive.append(pid)
        if not alive or time.monotonic() > deadline:
            return not alive
        time.sleep(0.05)


def _start_and_vanish(pids: Path) -> None:
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    renderer = Renderer(2)
    renderer.draw([_spec(), _spec()])
    pids.write_text(" ".join(str(p.pid) for p in psutil.Process().children(recursive=True)
                             if p.pid not in before))
    os._exit(0)                                       # no close(), no exit handlers


def test_the_helpers_end_when_their_caller_dies_without_closing_them(tmp_path: Path) -> None:
    pids = tmp_path / "pids"
    caller = multiprocessing.get_context("fork").Process(target=_start_and_vanish, args=(pids,))
    caller.start()
    caller.join(120)
    assert caller.exitcode == 0
    helpers = [int(p) for p in pids.read_text().split()]
    assert len(helpers) == 1
    assert _gone(helpers, 20)
