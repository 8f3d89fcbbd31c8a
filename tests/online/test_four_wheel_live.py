"""The four-wheel car calibrated while driving (issue 37): the online calibrator and ``odocal
replay`` with ``[vehicle] model = "four_wheel"`` against batch, the truth and a wrong mapping."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.cli.main import EXIT_FAILED, EXIT_OK, main
from odocal.errors import ConfigError, DataError
from odocal.estimators.estimate import Status
from odocal.model.layout import FOUR_WHEEL
from odocal.online import front
from odocal.online.calibrator import OnlineCalibrator
from odocal.settings import Settings
from odocal.sim.four_wheel import with_front_axle
from odocal.sim.simulate import SimulatedDrive

FOUR = Settings().replace(vehicle={"model": "four_wheel"})


@pytest.fixture(scope="module")
def car() -> tuple[SimulatedDrive, np.ndarray]:
    sim, truth = with_front_axle(odocal.simulate(duration_s=1200.0, seed=3, noise="realistic"))
    return sim, truth.as_array()


def pushed(columns: dict[str, np.ndarray], settings: Settings = FOUR, step: int = 500,
           estimate_s: float | None = None) -> OnlineCalibrator:
    """A calibrator that took ``columns`` in chunks of ``step`` samples, the estimate taken
    every ``estimate_s`` of them (as replay and the node take it: its lag then follows)."""
    calibrator = OnlineCalibrator(settings)
    n, t = columns["t"].size, columns["t"]
    taken = t[0]
    for i in range(0, n, step):
        calibrator.push({k: v[i:i + step] for k, v in columns.items()})
        if estimate_s is not None and t[min(i + step, n) - 1] - taken >= estimate_s:
            calibrator.estimate()
            taken = t[min(i + step, n) - 1]
    return calibrator


def test_the_live_car_agrees_with_batch_and_the_truth(
        car: tuple[SimulatedDrive, np.ndarray]) -> None:
    sim, truth = car
    online = pushed(sim.drive.columns()).estimate()
    batch = odocal.calibrate(sim.drive, settings=FOUR).model_estimate
    assert online.model == batch.model == "four_wheel" and online.names == FOUR_WHEEL.names
    assert online.method == "online" and online.status is Status.CONVERGED
    assert online.identified == batch.identified and all(online.identified)
    diff = (online.theta.as_array() - batch.theta.as_array()) / batch.std
    assert np.all(np.abs(diff) < 1.0), dict(zip(online.names, diff.round(2), strict=True))
    np.testing.assert_allclose(online.std, batch.std, rtol=0.25)
    z = (online.theta.as_array() - truth) / online.std
    assert np.all(np.abs(z) < 3.0), dict(zip(online.names, z.round(2), strict=True))
    for verdict, std in zip(online.verdicts, online.std, strict=True):
        assert verdict.std == pytest.approx(std, rel=1e-12)
    front_fit = online.details.front
    assert front_fit is not None and front_fit.windows > 500
    assert online.details.front_kept_s == pytest.approx(1200.0, abs=1.0)
    assert online.details.to_dict()["front_axle"]["windows"] == front_fit.windows



def test_the_live_car_without_its_sideslip_keeps_the_wheelbase_and_the_ratio(
        car: tuple[SimulatedDrive, np.ndarray]) -> None:
    """As batch (tests/estimators/test_front_axle.py): without the sideslip column the front
    wheels are read without the wheels' excess in bends the rear fit found, and how far the
    fit would move with it is carried."""
    sim, truth = car
    columns = {k: v for k, v in sim.drive.columns().items() if k != "beta"}
    online = pushed(columns, estimate_s=30.0).estimate()
    told = np.array(online.identified)
    z = (online.theta.as_array() - truth) / online.std
    assert online.identified["ratio"] and online.identified["t_f"]
    assert np.all(np.abs(z[told]) < 3.0), dict(zip(online.names, z.round(2), strict=True))
    assert [f.name for f in online.details.findings].count("slid") == 1

def test_a_reference_off_the_rear_axle_is_taken_out_of_the_front_windows_as_batch_takes_it(
        car: tuple[SimulatedDrive, np.ndarray]) -> None:
    """A reference 1 m ahead of the rear axle and 0.3 m left: the rear fit finds the lever arm
    beside theta, and the front windows are made on the reference moved to the axle (left in,
    the steering offset came out 7.8 batch stds off, the wheelbase 3.3)."""
    from odocal.sim.departures import lever_arm

    sim, truth = car
    moved = lever_arm(sim, 1.0, 0.3)
    online = pushed(moved.drive.columns()).estimate()
    batch = odocal.calibrate(moved.drive, settings=FOUR).model_estimate
    arm = {n: (v, s) for n, v, s in online.details.departures}
    assert abs(arm["arm_x"][0] - 1.0) < 3 * arm["arm_x"][1]
    assert abs(arm["arm_y"][0] - 0.3) < 3 * arm["arm_y"][1]
    diff = (online.theta.as_array() - batch.theta.as_array()) / batch.std
    assert np.all(np.abs(diff) < 1.0), dict(zip(online.names, diff.round(2), strict=True))
    z = (online.theta.as_array() - truth) / online.std
    assert np.all(np.abs(z) < 3.0), dict(zip(online.names, z.round(2), strict=True))


def test_the_steering_lag_is_one_for_the_stream_found_on_all_its_driving() -> None:
    """Each block's windows take the steering's lag found on every block pooled (one sensor,
    one latency), as batch finds it on the whole drive, not each block's own (which scattered
    by 12 ms on this drive and moved the steering offset)."""
    from odocal.estimators.front_axle import front_windows

    sim, _ = with_front_axle(odocal.simulate(duration_s=1200.0, seed=2, noise="everything"))
    calibrator = pushed(sim.drive.columns())
    online = calibrator.estimate()
    kept = calibrator._front.windows(calibrator._alignment())
    assert kept is not None and len(kept.steering_lag_s) == 10
    assert np.ptp(kept.steering_lag_s) == 0.0
    batch = front_windows([sim.drive], FOUR, delay_s=online.details.delay_s)
    assert kept.steering_lag_s[0] == pytest.approx(batch.steering_lag_s[0], abs=1e-3)


def test_old_blocks_keep_their_windows_and_the_memory_keeps_the_latest_driving(
        car: tuple[SimulatedDrive, np.ndarray], monkeypatch: pytest.MonkeyPatch) -> None:
    """Blocks beyond RAW_S let their samples go (their windows kept as made); beyond
    MEMORY_S their windows leave, and the front's stds are those of the driving kept."""
    sim, _ = car
    monkeypatch.setattr(front, "BLOCK_S", 60.0)
    whole = pushed(sim.drive.columns()).estimate()
    monkeypatch.setattr(front, "RAW_S", 300.0)
    settled = pushed(sim.drive.columns(), estimate_s=60.0)
    blocks = settled._front._blocks                      # (the memory itself)
    assert sum(b.rows is None for b in blocks) >= 12 and blocks[-1].rows is not None
    est = settled.estimate()
    f = [FOUR_WHEEL.index(n) for n in ("c_f", "c_fd", "t_f", "L", "ratio", "s_0")]
    diff = (est.theta.as_array() - whole.theta.as_array())[f] / whole.std[f]
    assert np.all(np.abs(diff) < 0.25), diff.round(2)
    monkeypatch.setattr(front, "MEMORY_S", 400.0)
    recent = pushed(sim.drive.columns()).estimate()
    assert recent.details.front_kept_s <= 400.0 + 60.0
    assert np.all(recent.std[f[:3]] > 1.3 * whole.std[f[:3]])


@pytest.mark.parametrize(("exchange", "check"), [
    ({"n_fl": "n_rl", "n_fr": "n_rr", "n_rl": "n_fl", "n_rr": "n_fr"}, "wheel-mapping"),
    ({"n_fl": "n_fr", "n_fr": "n_fl"}, "wheel-mapping"),
    ({"n_fl": "n_rl", "n_rl": "n_fl"}, "wheel-mapping"),
], ids=["axles", "front sides", "left side"])
def test_wheel_columns_exchanged_are_refused_live_as_batch_refuses_them(
        exchange: dict[str, str], check: str) -> None:
    sim, _ = with_front_axle(odocal.simulate(duration_s=600.0, seed=4, noise="realistic"))
    columns = {exchange.get(k, k): v for k, v in sim.drive.columns().items()}
    est = pushed(columns).estimate()
    assert est.status is Status.REJECTED
    fatal = [f.check.value for f in est.details.findings if f.severity.name == "FATAL"]
    assert check in fatal, fatal
    batch = odocal.calibrate(odocal.Drive.from_columns(columns, name="exchanged"),
                             settings=FOUR).model_estimate
    assert batch.status is Status.REJECTED


def test_the_live_car_refuses_fading_and_samples_without_front_wheels(
        car: tuple[SimulatedDrive, np.ndarray]) -> None:
    with pytest.raises(ConfigError, match=r"does not fade its evidence: set \[online\] "
                                          r"forgetting_s = 0"):
        OnlineCalibrator(FOUR.replace(online={"forgetting_s": 600.0}))
    rear = {k: v[:200] for k, v in car[0].drive.columns().items() if k not in ("n_fl",)}
    calibrator = OnlineCalibrator(FOUR)
    with pytest.raises(DataError, match=r"needs the front wheels' rates \(n_fl, n_fr\), and "
                                        r"the pushed samples lack n_fl"):
        calibrator.push(rear)
    assert calibrator.details_samples() == 0


def test_forgetting_before_a_change_leaves_the_front_windows_after_it() -> None:
    live = front.LiveFront(FOUR, 0.01, "test")
    closed = 0
    for start in range(0, 600, 30):                     # 20 chunks of 30 s
        t = start + 0.01 * np.arange(3000)
        closed += live.add(np.column_stack([t, np.zeros((t.size, len(front.COLUMNS) - 1))]))
    assert closed == 4 and live.kept_s == pytest.approx(599.99)
    live.forget_before(250.0)
    # what began before the change left: the driving kept starts at a chunk after it
    assert 599.99 - 250.0 - front.BLOCK_S <= live.kept_s <= 599.99 - 250.0


def test_replay_of_a_car_writes_its_ten_parameters(tmp_path: Path) -> None:
    drive = tmp_path / "car.parquet"
    assert main(["simulate", "--out", str(drive), "--model", "four_wheel", "--duration", "600",
                 "--seed", "2", "-q"]) == EXIT_OK
    config = tmp_path / "car.toml"
    config.write_text('[vehicle]\nmodel = "four_wheel"\n')
    out = tmp_path / "out"
    assert main(["replay", str(drive), "--config", str(config), "--out", str(out),
                 "-q"]) == EXIT_OK
    with (out / "trace.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0])[2:12] == list(FOUR_WHEEL.names)
    last = rows[-1]
    data = json.loads((out / "calibration.json").read_text())
    assert data["model"] == "four_wheel" and data["batch"]["model"] == "four_wheel"
    assert float(last["L"]) == pytest.approx(data["theta"]["L"])
    truth = json.loads((tmp_path / "car.truth.json").read_text())["theta"]
    for name in ("c_f", "t_f", "ratio"):
        assert data["identified"][name]
        assert abs(data["theta"][name] - truth[name]) < 3.5 * data["std"][name], name
    assert (out / "report.html").is_file() and (out / "figures" / "trace.png").is_file()
    html = (out / "report.html").read_text()
    assert "<b>ratio</b>" in html and "<b>L</b>" in html


def _replayed(columns: dict[str, np.ndarray], tmp_path: Path,
              capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """``odocal replay`` of ``columns`` as the car (no batch): its exit code and what it
    printed."""
    import pandas as pd

    tmp_path.mkdir(parents=True, exist_ok=True)
    drive = tmp_path / "drive.parquet"
    pd.DataFrame(columns).to_parquet(drive)
    config = tmp_path / "car.toml"
    config.write_text('[vehicle]\nmodel = "four_wheel"\n')
    capsys.readouterr()
    code = main(["replay", str(drive), "--config", str(config), "--out",
                 str(tmp_path / "out"), "--no-batch", "-q", "--no-report"])
    said = capsys.readouterr()
    return code, said.out + said.err


@pytest.mark.parametrize("exchange", [
    {"n_fl": "n_rl", "n_fr": "n_rr", "n_rl": "n_fl", "n_rr": "n_fr"},
    {"n_fl": "n_rl", "n_rl": "n_fl"},
], ids=["axles", "left side"])
def test_replay_of_a_car_with_wheels_exchanged_fails_in_one_line(
        exchange: dict[str, str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Refused with the finding, as batch refuses it, although the running updates took in
    wheel offsets that blur the front wheels' sign (the left side was published as converged
    until the final estimate judged the departures afresh): named now on the wheels alone, a
    side's front wheel travelling less than its rear one in bends."""
    sim, _ = with_front_axle(odocal.simulate(duration_s=600.0, seed=5, noise="realistic"))
    columns = {exchange.get(k, k): v for k, v in sim.drive.columns().items()}
    code, said = _replayed(columns, tmp_path, capsys)
    assert code == EXIT_FAILED
    lines = [line for line in said.splitlines() if line.strip()]
    assert len(lines) == 1 and "exchanged? map them the other way round" in lines[0], said
    assert "less than the" in lines[0]


def test_replay_of_a_car_says_what_it_left_out(car: tuple[SimulatedDrive, np.ndarray],
                                               tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """Front wheels never measured, a steering angle in degrees: the rear axle is calibrated,
    and the replay says what it could not use (batch says it when it reads the log)."""
    sim, _ = car
    columns = {k: v[:24000] for k, v in sim.drive.columns().items()}
    nan = {**columns, "n_fl": np.full(24000, np.nan), "n_fr": np.full(24000, np.nan)}
    code, said = _replayed(nan, tmp_path / "nan", capsys)
    assert code == EXIT_OK
    assert "holds no sample with both front wheels' rates measured" in said
    degrees = {**columns, "steer": np.degrees(columns["steer"])}
    code, said = _replayed(degrees, tmp_path / "deg", capsys)
    assert code == EXIT_OK
    assert re.search(r"warning: .* column steer reaches [\d.]+ rad, beyond any car", said)
    assert "note: steering ratio (steering-wheel over road-wheel angle) is not identified" \
        in said


def test_replay_streams_a_cars_bag_with_its_front_wheels_and_the_steering_it_names(
        tmp_path: Path) -> None:
    """A bag's JointState of four wheels and a steering wheel: the front wheels are found by
    their names, the steering only where the mapping names its joint (never guessed)."""
    from tests.bagwriter import write_bag

    sim, _ = with_front_axle(odocal.simulate(duration_s=300.0, seed=2, noise="realistic"))
    bag = write_bag(sim.drive, tmp_path / "car.mcap", "mcap")
    config = tmp_path / "car.toml"
    config.write_text('[vehicle]\nmodel = "four_wheel"\n')
    mapping = tmp_path / "bag.toml"
    mapping.write_text('[wheels]\ntopic = "/joint_states"\nsteering = "steering_wheel"\n'
                       'steering_unit = "rad"\n')
    found = {}
    for name, extra in (("named", ["--mapping", str(mapping)]), ("unnamed", [])):
        out = tmp_path / name
        assert main(["replay", str(bag), "--from", "rosbag", *extra, "--config", str(config),
                     "--out", str(out), "--no-batch", "-q", "--no-report"]) == EXIT_OK
        found[name] = json.loads((out / "calibration.json").read_text())
    named, unnamed = found["named"], found["unnamed"]
    assert named["model"] == unnamed["model"] == "four_wheel"
    assert named["identified"]["c_f"] and unnamed["identified"]["c_f"]
    assert named["identified"]["ratio"] and not unnamed["identified"]["ratio"]
    assert named["samples"] > 0.9 * sim.drive.n_samples


def test_a_running_update_fits_the_front_again_once_its_windows_grew_by_a_tenth(
        car: tuple[SimulatedDrive, np.ndarray]) -> None:
    """A replay's updates: the front axle's last fit joined with the rear axle of now until
    the windows grew by REFIT_GROWTH; an estimate asked for otherwise fits every window."""
    sim, _ = car
    columns = sim.drive.columns()
    half = columns["t"].size // 2
    calibrator = pushed({k: v[:half] for k, v in columns.items()})
    first = calibrator.estimate(running=True)
    fitted = first.details.front.windows
    t = columns["t"]
    more = int(np.searchsorted(t, t[half] + 40.0))            # 20 more windows of 2 s
    for i in range(half, more, 500):
        calibrator.push({k: v[i:min(i + 500, more)] for k, v in columns.items()})
    stale = calibrator.estimate(running=True)
    assert stale.details.front.windows == fitted
    f = [FOUR_WHEEL.index(n) for n in ("c_f", "t_f", "L", "ratio")]
    np.testing.assert_allclose(stale.std[f], first.std[f], rtol=0.05)
    fresh = calibrator.estimate()
    assert fitted + 15 <= fresh.details.front.windows < front.REFIT_GROWTH * fitted
    for i in range(more, columns["t"].size, 500):
        calibrator.push({k: v[i:i + 500] for k, v in columns.items()})
    assert calibrator.estimate(running=True).details.front.windows > 1.9 * fitted


def test_a_refused_final_estimate_is_said_with_what_is_published_instead(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The rear axle's replay of a log whose left rear column holds the front wheel: the
    final estimate names the front wheel and is refused; the published one is the last that
    was not, and the replay says so (it said nothing)."""
    import pandas as pd

    sim, _ = with_front_axle(odocal.simulate(duration_s=600.0, seed=5, noise="realistic"))
    columns = {{"n_fl": "n_rl", "n_rl": "n_fl"}.get(k, k): v
               for k, v in sim.drive.columns().items()}
    drive = tmp_path / "drive.parquet"
    pd.DataFrame(columns).to_parquet(drive)
    capsys.readouterr()
    assert main(["replay", str(drive), "--out", str(tmp_path / "out"), "--no-batch", "-q",
                 "--no-report"]) == EXIT_OK
    said = capsys.readouterr()
    assert re.search(r"note: the final estimate was refused \(.*front wheels mapped as the "
                     r"rear ones.*\); published: the last estimate that was not, from "
                     r"[\d.]+ km", said.out + said.err)


def test_a_change_of_the_front_tyres_alone_is_named_and_widens_c_f(
        car: tuple[SimulatedDrive, np.ndarray]) -> None:
    """Both front tyres 2% smaller from halfway on (the rear wheels as they were: the rear's
    change detector sees nothing): batch and live name the change, and c_f (the mix of the
    two) carries a std that covers the tyres of now (it came out 9 of its stds off). The drive
    without a change is not named."""
    from odocal.checks.findings import Diagnosis
    from odocal.estimators.front_axle import mapping_findings

    sim, truth = car
    columns = sim.drive.columns()
    after = columns["t"] >= 600.0
    changed = {**columns, "n_fl": np.where(after, columns["n_fl"] / 1.02, columns["n_fl"]),
               "n_fr": np.where(after, columns["n_fr"] / 1.02, columns["n_fr"])}
    c_f = FOUR_WHEEL.index("c_f")
    now = truth[c_f] * 1.02
    live = pushed(changed).estimate()
    batch = odocal.calibrate(odocal.Drive.from_columns(changed, name="front tyres"),
                             settings=FOUR)
    for est, findings in ((live, live.details.findings),
                          (batch.model_estimate, batch.diagnosis.findings)):
        named = [f for f in findings if f.check.value == "front-axle" and f.name == "change"]
        assert len(named) == 1 and named[0].severity.name == "FALLBACK"
        assert named[0].value == pytest.approx(-0.0196, abs=0.002) and named[0].reference < -5
        assert abs(est.theta.as_array()[c_f] - now) < 2.0 * est.std[c_f]
        assert est.verdicts[c_f].std == pytest.approx(est.std[c_f], rel=1e-12)
    clean = pushed(columns).estimate()
    assert clean.details.front.change is None
    assert not [f for f in mapping_findings(clean, Diagnosis(())) if f.name == "change"]


@pytest.mark.parametrize("fault", ["sign", "unit"])
def test_a_steering_angle_wrong_for_the_whole_stream_is_left_out_of_every_block(fault: str) -> None:
    """The steering's sign flipped, or radians sent where degrees were said: a block that turns
    enough shows it, and the angle is left out of every block's windows (one sensor), as batch
    leaves it out of the drive, named. Before, the blocks too straight to judge it kept it:
    the live front fit lost the front track and the wheelbase (batch keeps them) and said they
    needed bends."""
    import dataclasses

    sim, _ = with_front_axle(odocal.simulate(duration_s=300.0, seed=5, noise="realistic"))
    steer = sim.drive.inputs["steer"]
    wrong = -steer if fault == "sign" else np.radians(steer)
    drive = dataclasses.replace(sim.drive, inputs={**sim.drive.inputs, "steer": wrong})
    calibrator = pushed(drive.columns(), step=40)
    online = calibrator.estimate()
    batch = odocal.calibrate(drive, settings=FOUR).model_estimate
    assert online.identified == batch.identified
    assert online.identified["t_f"] and online.identified["L"]
    assert not online.identified["ratio"] and not online.identified["s_0"]
    np.testing.assert_allclose(online.std[4:8], batch.std[4:8], rtol=0.25)
    said = [f.name for f in online.details.findings if f.check.value == "steering"]
    assert any(name.startswith(f"{fault}|") for name in said), said
    assert calibrator._front is not None and calibrator._front.steering_fault is not None


def test_the_cars_blocks_and_estimate_do_not_hang_on_how_the_samples_were_pushed() -> None:
    """A block holds BLOCK_S of samples from its first, whatever the chunks: the live car
    pushed 7 samples at a time and 3000 at a time gives one estimate (before, blocks closed at
    the first chunk past their span, and the ROS 2 node, which pushes other chunks than
    replay, stood 0.3-0.9 std from replay on 20-minute drives)."""
    sim, _ = with_front_axle(odocal.simulate(duration_s=600.0, seed=4, noise="realistic"))
    small = pushed(sim.drive.columns(), step=7)
    spans = [(b.first_t, b.last_t) for b in small._front._blocks] if small._front else []
    assert len(spans) == 5 and all(last - first < front.BLOCK_S for first, last in spans)
    a = small.estimate()
    for step in (3000, 10000):          # (10000 samples: a chunk longer than a block)
        large = pushed(sim.drive.columns(), step=step)
        assert large._front is not None
        assert spans == [(b.first_t, b.last_t) for b in large._front._blocks]
        b = large.estimate()
        np.testing.assert_allclose(a.theta.as_array(), b.theta.as_array(), rtol=1e-9,
                                   atol=1e-12)
        np.testing.assert_allclose(a.std, b.std, rtol=1e-6)
