"""Shared fixtures: simulated drives (cached per session) and the shared real data."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

# One BLAS thread per test process (and per odocal the tests start): two pytest workers on two
# cores, each with a BLAS pool as wide as the machine, spend most of their time spinning
# against each other (a 0.6 s test took 7 s). Set before numpy loads its BLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest
from hypothesis import settings

import odocal
from odocal.cli.main import main
from odocal.sim.simulate import SimulatedDrive

ROOT = Path(__file__).resolve().parents[1]

# Property tests run the same examples on every run (the test command must fail, or pass, the same
# way each time); what they once found is pinned with @example beside each test. No example
# database: a failure seen on one machine must not change what another machine runs.
settings.register_profile("odocal", derandomize=True, database=None, deadline=None,
                          print_blob=True)
settings.load_profile(os.environ.get("ODOCAL_HYPOTHESIS_PROFILE", "odocal"))


def shared_data_dir() -> Path:
    """``$ODOCAL_SHARED_DATA`` or ``../shared/data`` beside the project."""
    env = os.environ.get("ODOCAL_SHARED_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real driving data not found at {path} (set ODOCAL_SHARED_DATA)")
    return path


@pytest.fixture(scope="session")
def clean_drive() -> SimulatedDrive:
    """A noise-free 10-minute city drive."""
    return odocal.simulate(duration_s=600.0, seed=11, noise="none")


@pytest.fixture(scope="session")
def noisy_drive() -> SimulatedDrive:
    """A 15-minute city drive with the realistic noise profile."""
    return odocal.simulate(duration_s=900.0, seed=12, noise="realistic")


@pytest.fixture(scope="session")
def short_drive() -> SimulatedDrive:
    """A two-minute realistic drive (for importers and streams)."""
    return odocal.simulate(duration_s=120, seed=2, noise="realistic")


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


# helpers shared by several test modules

def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:          # argparse usage errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def straight_drive(seconds: float = 240.0) -> odocal.Drive:
    """A straight road with speed changes and noisy wheels: no bends at all."""
    from odocal.model.kinematics import rollout, wheel_rates_for
    from odocal.model.parameters import Inputs

    theta = odocal.TRUE_PARAMETERS.as_array()
    rng = np.random.default_rng(8)
    t = np.arange(int(seconds * 40) + 1) * 0.025
    v = 9.0 + 4.0 * np.sin(0.1 * t)
    zero = np.zeros_like(t)
    n_rl, n_rr = wheel_rates_for(theta, v, zero, zero)
    poses = rollout(theta, Inputs(n_rl[:-1], n_rr[:-1], zero[:-1], zero[:-1]),
                    np.array([0.0, 0.0, 0.3]), 0.025)
    return odocal.Drive.from_columns(
        {"t": t, "n_rl": n_rl + 0.02 * rng.standard_normal(t.size),
         "n_rr": n_rr + 0.02 * rng.standard_normal(t.size), "a_y": zero,
         "x": poses[:, 0], "y": poses[:, 1], "psi": poses[:, 2]}, name="straight")


def interrupt(proc: subprocess.Popen[str], timeout: float, what: str) -> str:
    """Ctrl-C to ``proc``'s process group (started with ``start_new_session``); its stderr.

    Fails the test (after killing the group) when it has not ended within ``timeout`` s.
    """
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail(f"Ctrl-C did not stop {what}")
    return err
