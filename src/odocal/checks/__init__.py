"""The data against the model, before a fit, and the quality gate after it.

Every entry point (``calibrate``, ``replay``, the online calibrator, the fleet's tasks) goes
through these checks; findings are codes and numbers, words are made in :mod:`odocal.report`.

May import: :mod:`odocal.data`, :mod:`odocal.model` and the leaves (:mod:`odocal.settings`,
:mod:`odocal.errors`, :mod:`odocal.arrays`, :mod:`odocal.correlation`).
"""
