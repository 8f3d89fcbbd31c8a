"""The front doors: calibrate (read -> check -> estimate -> judge), compare and reproduce.

May import every layer below it: :mod:`odocal.estimators`, :mod:`odocal.checks`,
:mod:`odocal.sim`, :mod:`odocal.preprocess`, :mod:`odocal.io`, :mod:`odocal.data`,
:mod:`odocal.model`; never :mod:`odocal.output`, :mod:`odocal.report`, :mod:`odocal.fleet` or
:mod:`odocal.cli`.
"""
