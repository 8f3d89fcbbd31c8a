"""What a calibration writes for other tools: calibration.json and parameter files.

May import: :mod:`odocal.pipeline` (its result types), :mod:`odocal.report` and
:mod:`odocal.online` (what a replay found), and the layers below.
"""
