"""No silent garbage: outputs that could eat inputs, values no sensor produces, broken tables,
interrupts, and a fuzzer over the readers, the settings and the mappings."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import odocal
from odocal.cli.main import EXIT_ERROR, EXIT_USAGE, main
from odocal.data.drive import Drive
from odocal.errors import ConfigError, DataError, OdocalError, OutputError
from odocal.io import save_drive
from odocal.io.atomic import RESULTS_MARKER, refuse_inputs, results_folder
from odocal.io.drivefile import load_drive, read_table
from odocal.io.mapping import check_mapping, mapping_files
from odocal.settings import IdentifySettings, Settings, settings_from_dict
from odocal.sim.simulate import SimulatedDrive
from tests.conftest import interrupt, run

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def short(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("h") / "drive.parquet"
    save_drive(odocal.simulate(duration_s=300.0, seed=21, noise="white").drive, path)
    return path


def _with(drive: Drive, path: Path, **columns: np.ndarray) -> Path:
    cols = {**drive.columns(), **columns}
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({k: pa.array(np.asarray(v)) for k, v in cols.items()}), path)
    return path


# ---------------------------------------------------------------- outputs never eat inputs

def test_a_results_folder_may_not_hold_an_input(short: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "r1"
    folder.mkdir()
    inside = folder / "drive.parquet"
    inside.write_bytes(short.read_bytes())
    code, _, err = run(capsys, "calibrate", str(inside), "--out", str(folder), "--no-report")
    assert code == EXIT_ERROR and "holds the input" in err and inside.exists()
    config = folder / "odocal.toml"
    config.write_text("")
    code, _, err = run(capsys, "calibrate", str(short), "--config", str(config),
                       "--out", str(folder))
    assert code == EXIT_ERROR and "holds the input" in err and config.exists()


def test_hard_links_symlinks_and_mapped_files_are_inputs(tmp_path: Path) -> None:
    src = tmp_path / "wheels.csv"
    src.write_text("t,v\n0,1\n")
    hard = tmp_path / "hard.csv"
    os.link(src, hard)
    soft = tmp_path / "soft.csv"
    soft.symlink_to(src)
    for out in (hard, soft):
        with pytest.raises(OutputError, match="would overwrite"):
            refuse_inputs(out, [src])
    mapping = tmp_path / "map.toml"
    mapping.write_text('[wheels]\nfile = "wheels.csv"\ntime = "t"\n')
    assert mapping_files(mapping) == [tmp_path / "wheels.csv"]


def test_minimum_and_simulate_never_replace_what_exists(short: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    before = short.read_bytes()
    code, _, err = run(capsys, "minimum", str(short), "--out", str(short))
    assert code == EXIT_ERROR and "would overwrite" in err and short.read_bytes() == before
    base = tmp_path / "base.csv"
    assert main(["simulate", "--out", str(base), "--duration", "60", "-q"]) == 0
    truth = (tmp_path / "base.truth.json").read_text()
    code, _, err = run(capsys, "simulate", "--out", str(tmp_path / "base.parquet"),
                       "--duration", "60")
    assert code == EXIT_ERROR and "is the truth of" in err
    assert (tmp_path / "base.truth.json").read_text() == truth


def test_the_results_folder_is_written_whole(short: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str],
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "r"
    assert main(["calibrate", str(short), "--out", str(out), "-q"]) == 0
    first = (out / "calibration.json").read_bytes()
    assert (out / "report.html").exists() and (out / RESULTS_MARKER).exists()
    # a failure while writing leaves the earlier results exactly as they were
    import odocal.report.html as html

    def broken(*args: object, **kwargs: object) -> None:
        raise OutputError("disk full")

    monkeypatch.setattr(html, "write_report", broken)
    monkeypatch.setattr(odocal.report, "write_report", broken, raising=False)
    code, _, err = run(capsys, "calibrate", str(short), "--out", str(out), "--method", "raw")
    assert code == EXIT_ERROR and "disk full" in err
    assert (out / "calibration.json").read_bytes() == first
    monkeypatch.undo()
    # a later run without the report leaves no stale report or figures
    assert main(["calibrate", str(short), "--out", str(out), "--no-report", "-q"]) == 0
    assert not (out / "report.html").exists() and not (out / "figures").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".r.")]


def test_a_users_folder_is_never_replaced(short: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    mine = tmp_path / "home"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    with pytest.raises(OutputError, match="did not write"), results_folder(mine):
        pass
    assert (mine / "thesis.tex").read_text() == "precious"
    # a calibration.json among the user's files does not make the folder odocal's
    (mine / "calibration.json").write_text("{}")
    code, _, err = run(capsys, "calibrate", str(short), "--out", str(mine), "--no-report")
    assert code == EXIT_ERROR and "did not write" in err
    assert (mine / "thesis.tex").read_text() == "precious"
    # an older results folder (no marker, only odocal's files) is replaced whole
    older = tmp_path / "older"
    (older / "figures").mkdir(parents=True)
    (older / "calibration.json").write_text("{}")
    (older / "figures" / "stale.png").write_bytes(b"x")
    assert main(["calibrate", str(short), "--out", str(older), "--no-report", "-q"]) == 0
    assert not (older / "figures").exists() and (older / RESULTS_MARKER).exists()


# ---------------------------------------------------------------- values no sensor produces

@pytest.mark.parametrize(("column", "value", "message"), [
    ("a_y", 1e300, "beyond any car"),
    ("beta", 1e300, "beyond any car"),
    ("x", 1e300, "beyond any car"),
])
def test_impossible_values_are_refused(noisy_drive: SimulatedDrive, tmp_path: Path,
                                       column: str, value: float, message: str) -> None:
    d = noisy_drive.drive
    arr = getattr(d, column).copy()
    arr[len(arr) // 2:len(arr) // 2 + 5] += value          # not an isolated spike
    path = _with(d, tmp_path / "bad.parquet", **{column: arr})
    with pytest.raises(DataError, match=message):
        load_drive(path)


def test_isolated_wheel_spikes_are_repaired_and_counted(noisy_drive: SimulatedDrive,
                                                        tmp_path: Path) -> None:
    d = noisy_drive.drive
    rng = np.random.default_rng(0)
    n_rl = d.n_rl.copy()
    idx = rng.choice(np.arange(10, len(n_rl) - 10), size=int(0.004 * len(n_rl)), replace=False)
    idx = np.sort(idx)
    idx = idx[(np.diff(idx, prepend=-5) > 2) & (np.diff(idx, append=10**9) > 2)]   # isolated
    n_rl[idx] = 1000.0
    repaired = load_drive(_with(d, tmp_path / "spiky.parquet", n_rl=n_rl))
    assert repaired.metadata["repaired"] == {"n_rl": len(idx)}
    clean = load_drive(_with(d, tmp_path / "clean.parquet"))
    assert np.max(np.abs(repaired.n_rl - clean.n_rl)) < 0.5
    result = odocal.calibrate(repaired, method="raw")
    assert abs(result.theta.c_d - noisy_drive.true_parameters.c_d) < 0.002
    n_rl[::50] = 1000.0                                     # 2%: a broken column, not spikes
    with pytest.raises(DataError, match="corrupt or in another unit"):
        load_drive(_with(d, tmp_path / "broken.parquet", n_rl=n_rl))


def test_non_finite_settings_and_parameters(short: Path, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    for bad in ({"identify": {"theta0": [float("nan"), 0.0, 1.5, 0.0]}},
                {"segments": {"validation_distance_m": float("inf")}},
                {"inverse": {"window_s": float("nan")}}):
        with pytest.raises(ConfigError, match="finite"):
            settings_from_dict(bad)
    with pytest.raises(ConfigError, match="theta0"):
        Settings(identify=IdentifySettings(theta0=(float("nan"), 0.0, 1.5, 0.0)))
    with pytest.raises(ConfigError, match="finite"):
        Settings().replace(fleet={"excess_floor": (0.0002, float("nan"), 0.002, 0.0001)})
    params = tmp_path / "p.json"
    params.write_text('{"theta": {"c_e": 1e300, "c_d": 0, "t_r": 1.5, "d": 0}}')
    code, _, err = run(capsys, "validate", str(short), "--params", str(params))
    assert code == EXIT_ERROR and "not those of a wheeled vehicle" in err
    assert err.count("\n") == 1
    with pytest.raises(DataError, match="not finite"):
        odocal.validate(short, np.array([np.nan, 0.0, 1.5, 0.0]))


def test_drive_built_by_hand_is_checked(clean_drive: SimulatedDrive) -> None:
    import dataclasses

    d = clean_drive.drive
    n = d.n_rl.copy()
    n[5] = np.nan
    with pytest.raises(DataError, match="NaN"):
        dataclasses.replace(d, n_rl=n)
    with pytest.raises(DataError, match="sampling time"):
        dataclasses.replace(d, t_s=-0.025)


# ---------------------------------------------------------------- broken tables

def test_duplicated_boolean_and_garbage_columns(tmp_path: Path) -> None:
    dup = tmp_path / "dup.csv"
    dup.write_text("t,n_rl,n_rl\n0,1,2\n")
    with pytest.raises(DataError, match="more than once"):
        read_table(dup)
    boolean = tmp_path / "bool.csv"
    boolean.write_text("t,n_rl\n0,true\n1,false\n")
    with pytest.raises(DataError, match="true/false"):
        read_table(boolean)
    garbage = tmp_path / "garbage.csv"
    garbage.write_bytes(b"t,n_rl\n0,\x1b[2J\x07boom\n")
    with pytest.raises(DataError) as info:
        read_table(garbage)
    assert "\x1b" not in str(info.value) and "\x07" not in str(info.value)


def test_a_folder_and_the_same_drive_twice(short: Path, tmp_path: Path) -> None:
    with pytest.raises(OdocalError, match="is a folder"):
        load_drive(tmp_path)
    copy = tmp_path / "copy.parquet"
    copy.write_bytes(short.read_bytes())
    with pytest.raises(DataError, match="same drive"):
        odocal.calibrate([short, copy])
    link = tmp_path / "link.parquet"
    link.symlink_to(short)
    with pytest.raises(DataError, match="same drive"):
        odocal.calibrate([short, link])


# ---------------------------------------------------------------- interrupts

def test_sigint_stops_a_run_promptly(tmp_path: Path) -> None:
    drive = tmp_path / "long.parquet"
    save_drive(odocal.simulate(duration_s=3600.0, seed=2, noise="realistic").drive, drive)
    proc = subprocess.Popen([str(BIN / "odocal"), "calibrate", str(drive), "--method",
                             "compensated", "--out", str(tmp_path / "o"), "--workers", "2"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    # interrupted once it is computing (its progress lines say where it is), however fast
    # the machine: not after a fixed time
    assert proc.stderr is not None
    for line in proc.stderr:
        if "step 2" in line:
            break
    assert proc.poll() is None, "the run ended before it could be interrupted"
    sent = time.monotonic()
    err = interrupt(proc, 20, "the run")
    stopped = time.monotonic() - sent
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err
    assert stopped < 20
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------- fuzzing

_quiet = settings(max_examples=60, deadline=None,
                  suppress_health_check=[HealthCheck.function_scoped_fixture])


@_quiet
@given(st.binary(max_size=400))
def test_any_bytes_as_a_drive_file_give_a_drive_or_an_odocal_error(tmp_path: Path,
                                                                   data: bytes) -> None:
    for name in ("fuzz.csv", "fuzz.parquet"):
        path = tmp_path / name
        path.write_bytes(data)
        try:
            load_drive(path)
        except OdocalError:
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fuzz.csv", "fuzz.parquet"]


_cells = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
                   st.text(max_size=8), st.booleans())


@_quiet
@given(st.lists(st.lists(_cells, min_size=9, max_size=9), min_size=0, max_size=30))
def test_any_csv_with_the_drive_columns_gives_a_drive_or_an_odocal_error(
        tmp_path: Path, rows: list[list[object]]) -> None:
    path = tmp_path / "t.csv"
    header = "t,n_rl,n_rr,a_y,beta,x,y,psi,yaw_rate"
    path.write_text(header + "\n" + "\n".join(",".join(str(c).replace(",", ";")
                                                       .replace("\n", " ") for c in r)
                                              for r in rows) + "\n")
    try:
        load_drive(path)
    except OdocalError:
        pass


_values = st.recursive(st.one_of(st.integers(), st.floats(), st.text(max_size=5), st.booleans()),
                       lambda inner: st.lists(inner, max_size=4), max_leaves=6)


@_quiet
@given(st.dictionaries(st.sampled_from(["identify", "segments", "inverse", "gate",
                                        "fleet", "online", "nonsense"]),
                       st.dictionaries(st.text(min_size=1, max_size=24), _values, max_size=3)
                       | st.dictionaries(st.sampled_from(["theta0", "max_iterations",
                                                          "window_s", "cusum_h",
                                                          "validation_distance_m"]),
                                         _values, max_size=3),
                       max_size=3))
def test_any_settings_give_settings_or_a_config_error(data: dict[str, object]) -> None:
    try:
        settings_from_dict(data)  # type: ignore[arg-type]
    except OdocalError:
        pass


@_quiet
@given(st.dictionaries(st.sampled_from(["wheels", "pose", "imu", "gnss", "other"]),
                       st.one_of(_values, st.dictionaries(
                           st.sampled_from(["file", "time", "topic", "n_rl", "speed", "unit",
                                            "offset_s", "x"]), _values, max_size=4)),
                       max_size=3))
def test_any_mapping_gives_a_mapping_or_a_config_error(data: dict[str, object]) -> None:
    try:
        check_mapping(data)
    except OdocalError:
        pass


# ---------------------------------------------------------------- smaller

def test_small_cli_promises(short: Path, tmp_path: Path,
                            capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "calibrate", str(short), "--scene", "scene-0001", "--out",
                       str(tmp_path / "o"))
    assert code == EXIT_USAGE and "--scene" in err and "--from nuscenes" in err
    code, out, err = run(capsys, "validate", str(short), "-q")
    assert code == 0 and out == "" and err == ""
    code, out, _ = run(capsys, "demo", "--duration", "300", "--no-compare", "-q")
    assert out == ""
    code, out, _ = run(capsys, "demo", "--duration", "300", "--no-compare")
    assert "--out" in out
    code, _, err = run(capsys, "inspect", "x", "--from", "table", "--workers", "2")
    assert code == 2 and "unrecognized arguments: --workers" in err
    # not a terminal: each stage announces itself on stderr
    proc = subprocess.run([str(BIN / "odocal"), "calibrate", str(short), "--out",
                           str(tmp_path / "o2"), "--no-report"], capture_output=True, text=True)
    assert proc.returncode == 0 and "] read ..." in proc.stderr
    assert "] validation ..." in proc.stderr
    written = [line for line in proc.stdout.splitlines() if line.startswith("wrote ")]
    assert written == [f"wrote {tmp_path / 'o2' / 'calibration.json'}"]
