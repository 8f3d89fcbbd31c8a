"""What a calibration writes for other tools: calibration.json and parameter files.

May import: :mod:`odocal.pipeline` (its result types) and the layers below.
"""
