"""Settings: the paper's defaults, TOML, and rejected input."""

from __future__ import annotations

from pathlib import Path

import pytest

from odocal.errors import ConfigError, InputFileError
from odocal.settings import Settings, load_settings


def test_defaults_are_the_papers() -> None:
    s = Settings()
    assert (s.segments.length, s.segments.step, s.segments.yaw_rate_threshold_radps) == \
        (650, 100, 0.15)
    assert s.segments.validation_distance_m == 300.0
    assert s.identify.theta0 == (2.0, 0.0, 1.6, 0.0)
    assert s.identify.weights == (1.0, 1.0, 1600.0)
    assert s.identify.max_iterations == 5
    assert s.compensate.state_weights == (1.0, 1.0, 10.0)
    assert s.compensate.rate_change_weights == (1000.0, 1000.0)
    assert s.compensate.state_bounds == (5.0, 5.0, 0.5)
    assert s.compensate.rate_bound == 0.05
    assert (s.calibrate.step1_batches, s.calibrate.step1_batch_size, s.calibrate.step1_sets,
            s.calibrate.step3_batch_size) == (50, 10, 5, 5)


def test_toml_overrides_some_keys(tmp_path: Path) -> None:
    path = tmp_path / "odocal.toml"
    path.write_text("[segments]\nlength = 400\n\n[identify]\ntheta0 = [1.9, 0, 1.5, 0]\n"
                    "[compensate]\nsolver = \"osqp\"\n")
    s = load_settings(path)
    assert s.segments.length == 400 and s.segments.step == 100
    assert s.identify.theta0 == (1.9, 0.0, 1.5, 0.0)
    assert s.compensate.solver == "osqp"
    assert Settings().to_dict()["segments"]["length"] == 650


@pytest.mark.parametrize(("text", "message"), [
    ("[segments]\nlenght = 400\n", r"unknown setting \[segments\] 'lenght'"),
    ("[segment]\nlength = 400\n", r"unknown section \[segment\]"),
    ("[segments]\nlength = 4.5\n", r"\[segments\] length = 4.5 is invalid: expected an integer"),
    ("[segments]\nlength = 3\n", r"length = 3 is invalid: expected an integer >= 10"),
    ("[identify]\ntheta0 = [2, 0, 1.6]\n", r"theta0 .* \(3 values where the model has 4\)"),
    ("[compensate]\nsolver = \"cvx\"\n", r"solver = 'cvx' is invalid"),
    ("[compensate]\nrate_bound = 1.5\n", r"rate_bound = 1.5 is invalid"),
    ("[inverse]\ncommon_wheel_error = \"maybe\"\n",
     r"common_wheel_error = 'maybe' is invalid: expected 'estimate' or 'off'"),
    ("segments = 3\n", r"\[segments\] must be a table"),
    ("[segments\n", r"is not valid TOML"),
])
def test_bad_settings_are_named(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_settings(path)


def test_missing_settings_file(tmp_path: Path) -> None:
    with pytest.raises(InputFileError, match="does not exist"):
        load_settings(tmp_path / "nope.toml")


def test_replace_checks_keys() -> None:
    s = Settings().replace(calibrate={"seed": 3})
    assert s.calibrate.seed == 3
    with pytest.raises(ConfigError, match="unknown setting"):
        Settings().replace(calibrate={"sed": 3})
    with pytest.raises(ConfigError, match="choose the method with --method"):
        Settings().replace(calibrate={"method": "raw"})


def test_the_documented_settings_example_is_valid() -> None:
    import tomllib
    from pathlib import Path

    from odocal.settings import settings_from_dict

    text = (Path(__file__).resolve().parents[1] / "docs" / "settings.md").read_text()
    start = text.index("```toml") + len("```toml")
    block = text[start:text.index("```", start)]
    settings = settings_from_dict(tomllib.loads(block))
    assert settings.fleet.cusum_h == 4.0 and settings.inverse.window_s == 2.0


@pytest.mark.parametrize(("text", "message"), [
    ("[identify]\nprior_std = [1e300, 0.01, 0.1, 0.005]\n",
     r"prior_std = \(1e\+300, .* expected 4 standard deviations from 1e-09 up to c_e 50, "
     r"c_d 50, t_r 30, d 1"),
    ("[identify]\nprior_std = [0.05, 0.01, 0.1, 1e300]\n", r"prior_std = .* up to c_e 50"),
    ("[identify]\nprior_std = [0.05, 0.0, 0.1, 0.005]\n", r"prior_std = .* from 1e-09"),
    ("[identify]\nprior_std = [1e-300, 0.01, 0.1, 0.005]\n", r"prior_std = .* from 1e-09"),
    ("[identify]\ntheta0 = [1e300, 0, 1.6, 0]\n",
     r"theta0 = .*\(c_e = 1e\+300 is not a wheeled vehicle's effective wheel circumference "
     r"\(0\.05 to 50 m\)"),
    ("[identify]\ntheta0 = [2.0, 1e300, 1.6, 0]\n", r"c_d = 1e\+300 .* \(\|c_d\| up to 50 m\)"),
    ("[identify]\ntheta0 = [2.0, 0, 1.6, -7]\n", r"d = -7 .* \(\|d\| up to 1 m/\(m/s\^2\)\)"),
    ("[identify]\ntheta0 = [0.3, 0.5, 1.6, 0]\n", r"c_d = 0\.5 m is not smaller than c_e"),
    ("[calibrate]\nseed = -1\n", r"\[calibrate\] seed = -1 is invalid: expected an integer"),
    ("[convert]\nrate_hz = 5.0\n", r"\[convert\] rate_hz = 5\.0 is invalid: expected a rate in "
                                    r"\[10, 1000\] Hz"),
])
def test_settings_no_vehicle_has_are_named(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_settings(path)


def test_prior_std_at_the_limits_is_taken() -> None:
    s = Settings().replace(identify={"prior_std": (50.0, 50.0, 30.0, 1.0)})
    assert s.identify.prior_std == (50.0, 50.0, 30.0, 1.0)
    assert Settings().replace(identify={"prior_std": (1e-9,) * 4}).identify.prior_std[0] == 1e-9


@pytest.mark.parametrize(("pairs", "message"), [
    ([("c_e", 1.84), ("c_e", 1.9)], r"--datasheet gives c_e twice \(1\.84 and 1\.9\): give each"),
    ([("t_r", 1.5), ("c_e", 1.9), ("t_r", 1.5)], r"gives t_r twice"),
    ([("c_e", 1e308)], r"--datasheet: c_e = 1e\+308 is not a wheeled vehicle's effective wheel "
                       r"circumference \(0\.05 to 50 m\)"),
    ([("c_e", float("nan"))], r"c_e = nan is not"),
    ([("t_r", float("-inf"))], r"t_r = -inf is not a wheeled vehicle's rear track width"),
    ([("t_r", 0.01)], r"t_r = 0\.01 is not"),
    ([("d", 5.0)], r"d = 5 is not .* load-transfer"),
    ([("c_x", 1.0)], r"'c_x' is not one of c_e, c_d, t_r, d"),
    ([("c_e", "1.9")], r"c_e = '1\.9' is not a number"),
    ([("c_e", True)], r"c_e = True is not a number"),
])
def test_datasheet_values_are_checked_once_each(pairs: list[tuple[str, object]],
                                                message: str) -> None:
    from odocal.settings import datasheet_values

    with pytest.raises(ConfigError, match=message):
        datasheet_values(pairs)


def test_datasheet_values_within_range_are_returned() -> None:
    from odocal.settings import datasheet_values

    assert datasheet_values([("c_e", 0.33), ("t_r", 0.4), ("d", -0.001)]) == {
        "c_e": 0.33, "t_r": 0.4, "d": -0.001}
    assert datasheet_values({"c_e": 50, "c_d": -49.0}) == {"c_e": 50.0, "c_d": -49.0}


# ----------------------------------------------------------- [checks]: the checks' thresholds

def test_check_thresholds_come_from_toml_and_survive_a_round_trip(tmp_path: Path) -> None:
    from odocal.settings import settings_from_dict

    path = tmp_path / "checks.toml"
    path.write_text("[checks]\ndead_wheel_share = 0.3\nheading_harmonic_sigmas = 2.5\n"
                    "change_min_side_clusters = 6\n")
    s = load_settings(path)
    assert (s.checks.dead_wheel_share, s.checks.heading_harmonic_sigmas,
            s.checks.change_min_side_clusters) == (0.3, 2.5, 6)
    assert s.checks.pose_jump_m == 5.0 and Settings().checks.dead_wheel_share == 0.2
    assert settings_from_dict(s.to_dict()) == s                  # as the fleet's tasks carry it


@pytest.mark.parametrize(("text", "message"), [
    ("dead_wheel_share = 1.5",
     r"^setting \[checks\] dead_wheel_share = 1\.5 is invalid: expected a number in \(0, 1\)$"),
    ("pose_jump_m = 0.0", r"\[checks\] pose_jump_m = 0\.0 is invalid: expected a positive "
                          r"finite number$"),
    ("heading_max_gap_rad = 4.0", r"heading_max_gap_rad = 4\.0 .* an angle in \(0, pi\) rad$"),
    ("sync_min_seconds = 2", r"sync_min_seconds = 2 .* an integer from 3 to 10\*\*9$"),
    ("lateral_min_slope = 1.2",
     r"lateral_min_slope/lateral_max_slope = \(1\.2, 2\.0\) is invalid: expected "
     r"0 < lateral_min_slope < 1 < lateral_max_slope$"),
    ("encoding_min_on_grid = 0.0", r"encoding_min_on_grid = 0\.0 .* in \(0, 1\]$"),
    ("change_min_side_clusters = 2.5", r"change_min_side_clusters = 2\.5 .* an integer$"),
    ("dead_wheel_shares = 0.3", r"unknown setting \[checks\] 'dead_wheel_shares'"),
    ("standstill_speed_mps = -1", r"standstill_speed_mps = -1\.0 .* positive finite"),
    ("heading_harmonic_sigmas = inf", r"heading_harmonic_sigmas = inf .* a finite number$"),
    ("change_min_side_clusters = 0", r"change_min_side_clusters = 0 .* from 1 to 10\*\*9$"),
    ("front_min_windows = 30", r"unknown setting \[checks\] 'front_min_windows'"),
])
def test_bad_check_thresholds_are_named_in_one_line(tmp_path: Path, text: str,
                                                    message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(f"[checks]\n{text}\n")
    with pytest.raises(ConfigError, match=message) as info:
        load_settings(path)
    assert "\n" not in str(info.value)


def test_every_check_threshold_says_why() -> None:
    """A docstring under each field of [checks] (its reason, read by the README's readers)."""
    import ast
    import inspect

    from odocal.settings import ChecksSettings

    body = ast.parse(inspect.getsource(ChecksSettings)).body[0].body  # type: ignore[attr-defined]
    undocumented = [node.target.id for node, after in zip(body, [*body[1:], None], strict=True)
                    if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and not (isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                             and isinstance(after.value.value, str))]
    assert undocumented == []
