"""Fleets: many vehicles' drives calibrated on Dask, their history in SQLite, drift alarms.

:func:`odocal.fleet.engine.calibrate_fleet` is the library function behind
``odocal fleet calibrate``; :func:`odocal.fleet.simulate.simulate_fleet` behind
``odocal simulate-fleet``.
"""
