"""``--method raw``: batch Gauss-Newton (METHOD 3) on every selected segment, measured rates.

The paper's identification without its compensation: the wheel rates as measured drive the
rollouts, so wheel noise biases ``t_r`` and ``c_e`` (errors in variables) as it grows.
"""

from __future__ import annotations

from odocal.estimators.base import MethodOutcome, Prepared, ProgressCallback
from odocal.estimators.gauss_newton import Linearisation, bootstrap_terms, gauss_newton
from odocal.settings import Settings


def run(prep: Prepared, settings: Settings,
        progress: ProgressCallback | None = None) -> MethodOutcome:
    """Identify theta from the selected segments with their measured wheel rates."""
    if progress:
        progress("identify", 0, 1)
    kept: list[Linearisation] = []
    est = gauss_newton(prep.batch, settings=settings.identify, clusters=prep.clusters,
                       held=prep.held, method="raw", keep=kept)
    if progress:
        progress("identify", 1, 1)
    return MethodOutcome(estimate=est, bootstrap=bootstrap_terms(prep.batch, est, prep.clusters,
                                                                 settings, at_estimate=kept[-1]))
