"""The model object is the one place the parameter layout lives (issue 30)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.estimators import fitting
from odocal.estimators.windows import WindowBuilder
from odocal.model.kinematics import motion_increments
from odocal.model.layout import REAR_AXLE, Layout, ParameterSpec
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.model.vehicle import MODEL, SERIES
from odocal.settings import Settings

SRC = Path(odocal.__file__).parent

#: What the four-parameter layout looks like written out: a size, an index of theta, a slice.
LITERAL_LAYOUT = [
    r"reshape\(4\)", r"\(4, ?4\)", r"\b(np\.)?(zeros|ones|empty|eye|full)\(\(?4[,)]",
    r"(\b|_|\.)(th|theta|theta0|p)\[[0-3]\]", r"\[:4\]", r"\brange\(4\)", r"\bP = 5\b",
    r"tuple\[(float|bool|str), (float|bool|str), (float|bool|str), (float|bool|str)\]",
    r"\(False, False, False, False\)", r"\[0 if name", r"\bn_theta = 4\b",
    r"\b(shape|of shape) \((\.\.\., )?[A-Z]?,? ?4\)", r", 4\)\)",
]


def test_no_module_outside_model_writes_the_layout_out() -> None:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if path.relative_to(SRC).parts[0] == "model":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if "(not theta)" in line:                 # four of something else, said so
                continue
            for pattern in LITERAL_LAYOUT:
                if re.search(pattern, line):
                    found.append(f"{path.relative_to(SRC)}:{number}: {line.strip()}")
    assert found == []


#: The rear axle's equations written out (issue 37): each wheel's circumference from c_e and
#: c_d, the yaw from the wheels' difference over the track, the midpoint heading of (1).
VEHICLE_EQUATIONS = [
    r"c_d ?/ ?2", r"0\.5 ?\* ?\w*\.?c_d\b", r"\bn_rr\w*(\[[^]]*\])? ?- ?\w*\.?n_rl",
    r"/ ?\w*\.?t_r\b", r"\+ ?0\.5 ?\* ?(turn|dpsi)\b", r"0\.5 ?\* ?dpsi ?\+",
    r"\(s_rr ?- ?s_rl\)",
]


def _code_lines(path: Path) -> dict[int, str]:
    """The code of each line of ``path``, without its comments and strings."""
    import tokenize

    lines: dict[int, list[str]] = {}
    with path.open("rb") as f:
        for tok in tokenize.tokenize(f.readline):
            if tok.type in (tokenize.COMMENT, tokenize.STRING, tokenize.ENCODING, tokenize.NL,
                            tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT):
                continue
            lines.setdefault(tok.start[0], []).append(tok.string)
    return {n: " ".join(parts) for n, parts in lines.items()}


def test_no_module_outside_model_writes_a_vehicle_equation() -> None:
    """The equations of a vehicle live in its model's module; everywhere else takes them from
    the model (body_map, geometry, channel_gains, wheel_changes, midpoint_heading ...)."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if path.relative_to(SRC).parts[0] == "model":
            continue
        for number, code in _code_lines(path).items():
            squeezed = code.replace(" . ", ".").replace(" [ ", "[").replace(" ]", "]")
            for pattern in VEHICLE_EQUATIONS:
                if re.search(pattern, squeezed):
                    found.append(f"{path.relative_to(SRC)}:{number}: {squeezed}")
    assert found == []


def test_the_patterns_find_what_they_are_for(tmp_path: Path) -> None:
    """The two scans above catch the forms they forbid (a scan that finds nothing proves
    nothing)."""
    sample = tmp_path / "sample.py"
    sample.write_text("a = self._theta[0]\nleft = th.c_e + th.c_d / 2.0\n"
                      "w = (d.n_rr[a:b] - d.n_rl[a:b]) * c / t_r  # a comment: c_d / 2\n"
                      "h = psi + 0.5 * turn\ns = 'c_d / 2 in a string'\n")
    code = _code_lines(sample)
    squeezed = {n: c.replace(" . ", ".").replace(" [ ", "[").replace(" ]", "]")
                for n, c in code.items()}
    hits = {n for n, c in squeezed.items()
            for pattern in VEHICLE_EQUATIONS if re.search(pattern, c)}
    assert hits == {2, 3, 4}
    assert any(re.search(p, "a = self._theta[0]") for p in LITERAL_LAYOUT)


def test_the_layout_names_and_orders_every_parameter() -> None:
    assert MODEL.layout is REAR_AXLE
    assert PARAMETER_NAMES == REAR_AXLE.names == ("c_e", "c_d", "t_r", "d")
    assert [REAR_AXLE.index(n) for n in REAR_AXLE.names] == list(range(REAR_AXLE.size))
    theta = Parameters(c_e=1.9, c_d=-0.002, t_r=1.5, d=0.001)
    assert REAR_AXLE.named(theta.as_array().tolist()) == theta.as_dict()
    assert Parameters.from_array(theta.as_array()) == theta
    assert Settings().identify.theta0 == REAR_AXLE.placeholder
    assert Settings().identify.prior_std == REAR_AXLE.prior_std
    with pytest.raises(KeyError, match="not a parameter"):
        REAR_AXLE.index("wheelbase")
    with pytest.raises(ValueError, match="not one of"):
        Layout(parameters=REAR_AXLE.parameters[:3], scale="c_e", track="t_r", difference="c_d",
               load="d", differential=(), bends=(), lengths=())
    spec = ParameterSpec("x", "m", "x", 1.0, "m", 0.0, 1.0)
    assert spec.name == "x"


def test_the_estimators_are_sized_by_the_model() -> None:
    """The default method's p and its covariance come from the layout: theta first, then the
    departures' nuisance parameters; the settings refuse a theta0 of another size."""
    from odocal.estimators import departures

    assert fitting.THETA == slice(0, MODEL.size)
    assert fitting.P == MODEL.size + len(departures.NUISANCES) == departures.P
    assert [departures.at(n) for n in departures.NAMES] == list(range(MODEL.size, fitting.P))
    p = fitting.pack(np.arange(MODEL.size, dtype=float), kappa=7.0, offset=8.0)
    assert p[fitting.THETA].tolist() == list(range(MODEL.size))
    assert p[fitting.KAPPA] == 7.0 and p[fitting.OFFSET] == 8.0
    est = odocal.calibrate(odocal.simulate(duration_s=300, seed=1, noise="white").drive).estimate
    assert est.covariance.shape == (MODEL.size, MODEL.size)
    assert len(est.verdicts) == len(est.free) == MODEL.size
    with pytest.raises(odocal.ConfigError, match="3 values where the model has 4"):
        Settings().replace(identify={"theta0": (1.9, 0.0, 1.5)})


def test_the_window_prediction_is_the_step_run_backwards_summed() -> None:
    """MODEL.predict from a window's moments equals MODEL.inverse_step summed over its steps,
    revolutions and Jacobian, for any theta (the series is exact to (d a / C)^SERIES)."""
    sim = odocal.simulate(duration_s=120, seed=4, noise="none")
    d = sim.drive
    t_s, length = d.t_s, 80
    builder = WindowBuilder(t_s=t_s, length=length, margin=0, cluster_steps=650)
    builder.add(d.t, d.n_rl, d.n_rr, d.a_y, d.beta, d.x, d.y, d.psi)
    windows = builder.windows()
    ds, dpsi = motion_increments(d.x, d.y, d.psi, d.beta)
    rng = np.random.default_rng(2)
    for theta in (sim.true_parameters.as_array(),
                  np.array([2.05, 0.005, 1.4, 0.0015]) + 1e-3 * rng.standard_normal(4)):
        predicted, jac = MODEL.predict(theta, windows.at(0.0, 0.0)[0])
        revs, step_jac = MODEL.inverse_step(theta, ds, dpsi, d.a_y[:-1])
        first = np.searchsorted(d.t, windows.t0)
        rows = first[:, None] + np.arange(length)[None, :]
        np.testing.assert_allclose(predicted, revs[rows].sum(axis=1), rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(jac, step_jac[rows].sum(axis=1), rtol=1e-5, atol=1e-9)
    assert SERIES >= 3
