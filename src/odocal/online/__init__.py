"""Calibrating while driving: the streaming calibrator and ``odocal replay``.

Owns :class:`~odocal.online.calibrator.OnlineCalibrator` (the default estimator's core, its
sums folded over time, behind the same checks as batch) and the replay of a log through it.

May import: :mod:`odocal.estimators`, :mod:`odocal.checks`, :mod:`odocal.data`,
:mod:`odocal.io`, :mod:`odocal.model` and the leaves.
"""
