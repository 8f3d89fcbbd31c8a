"""How far a segment method's standard deviations are widened against the default method's on
the same drives (``pipeline/calibrate._against_the_default``), pinned to numbers worked out by
hand (issue 38: the widening with ``np.minimum`` for ``np.maximum`` lived through every test)."""

from __future__ import annotations

import numpy as np
import pytest

from odocal.estimators.estimate import CovarianceKind, Estimate, Identified, Status
from odocal.estimators.inverse import Screen
from odocal.model.parameters import Parameters
from odocal.pipeline.calibrate import _against_the_default
from odocal.settings import Settings

THETA = np.array([2.0, 0.001, 1.6, 0.002])


def _estimate(std: np.ndarray) -> Estimate:
    theta = Parameters.from_array(THETA)
    return Estimate(method="raw", theta=theta, datasheet=theta,
                    covariance=np.diag(std ** 2), covariance_kind=CovarianceKind.CLUSTER_ROBUST,
                    free=(True,) * 4, verdicts=tuple(Identified(float(s), 1.0) for s in std),
                    status=Status.CONVERGED)


def test_a_segment_methods_std_reaches_the_default_methods_and_their_distance() -> None:
    settings = Settings()                  # prior_std d 0.005, identifiable_ratio 0.5
    std = np.array([1e-4, 1e-4, 1e-3, 1e-4])
    screened = Screen(findings=(),
                      theta=THETA + np.array([1e-3, 0.0, 3e-4, 0.0]),
                      std=np.array([1e-4, 4e-4, 1e-4, np.nan]),
                      free=np.array([True, True, True, False]))
    factor = _against_the_default(_estimate(std), screened, settings)
    # c_e: 1 mm apart, the default's std 0.1 mm: the reach is the larger of half the distance
    # (0.5 mm) and a third of it plus two of the default's std ((1 + 0.2) / 3 = 0.4 mm)
    assert factor[0] == pytest.approx(5e-4 / 1e-4, rel=1e-9)
    # c_d: the same value, the default four times surer than the segment method is not: its
    # 0.4 mm (and the reach 2 * 0.4 / 3 mm lies below it)
    assert factor[1] == pytest.approx(4.0, rel=1e-9)
    # t_r: the segment method's own 1 mm is wider than the reach (0.3 + 0.2) / 3 mm: no widening
    assert factor[2] == 1.0
    # d: the default does not identify it: past its identifiability limit, 1.01 * 0.5 * 0.005
    assert factor[3] == pytest.approx(1.01 * 0.5 * 0.005 / 1e-4, rel=1e-9)


def test_the_widening_is_applied_to_what_the_method_returns(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from odocal.estimators.base import MethodOutcome
    from odocal.pipeline import calibrate

    std = np.array([1e-4, 1e-4, 1e-3, 1e-4])
    screened = Screen(findings=(), theta=THETA + np.array([1e-3, 0.0, 0.0, 0.0]),
                      std=np.full(4, 1e-4), free=np.ones(4, dtype=bool))
    monkeypatch.setitem(calibrate.METHODS, "raw",   # type: ignore[index]
                        lambda prep, settings, progress: MethodOutcome(_estimate(std)))
    _, widened, boot = calibrate._checked_by_bootstrap("raw", None,  # type: ignore[arg-type]
                                                       Settings(), None, screened)
    assert boot is None
    # c_e to the reach of 0.5 mm (as above); the others at their own (wider than the reach)
    np.testing.assert_allclose(widened.widening, [5.0, 1.0, 1.0, 1.0], rtol=1e-9)
    np.testing.assert_allclose(widened.std, [5e-4, 1e-4, 1e-3, 1e-4], rtol=1e-9)
