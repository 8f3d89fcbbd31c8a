"""Shared fixtures: simulated drives (cached per session) and the shared real data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.simulate import SimulatedDrive

ROOT = Path(__file__).resolve().parents[1]


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
