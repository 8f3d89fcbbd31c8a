"""The report's colours: one per kind of trajectory or parameter set, in every figure."""

from __future__ import annotations

#: Reference, datasheet, calibrated, raw G-N, step-1 batches.
REFERENCE, DATASHEET, CALIBRATED, RAW, STEP1 = "#222222", "#d62728", "#1f77b4", "#ff7f0e", "#999999"
#: The lighter shade of the calibrated colour: neighbouring clusters of fitted data alternate.
FITTED_ALT = "#7fb2dc"
