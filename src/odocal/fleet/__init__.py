"""Fleets: many vehicles' drives calibrated on Dask, their history in SQLite, drift alarms.

:func:`odocal.fleet.engine.calibrate_fleet` is the library function behind
``odocal fleet calibrate``; :func:`odocal.fleet.simulate.simulate_fleet` behind
``odocal simulate-fleet``.

May import: :mod:`odocal.pipeline`, :mod:`odocal.output`, :mod:`odocal.report` and every layer
below them (a fleet task is a pipeline run with its report); not :mod:`odocal.cli`.
"""
