"""The calibration report: figures (functions that take an ax) and the HTML page."""

from odocal.report.html import Report, write_report

__all__ = ["Report", "write_report"]
