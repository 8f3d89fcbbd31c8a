"""The calibration report: figures (functions that take an ax) and the HTML page.

May import: :mod:`odocal.pipeline` (its result types) and every layer below it, and
:mod:`odocal.online` (the replay's trace); not :mod:`odocal.output`, :mod:`odocal.fleet` or
:mod:`odocal.cli`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from odocal.report.html import Report, write_report

__all__ = ["Report", "write_report"]


def __getattr__(name: str) -> Any:
    # the page module loads the calibration; odocal.report.render stays light without it
    if name in __all__:
        from odocal.report import html

        return getattr(html, name)
    raise AttributeError(f"module 'odocal.report' has no attribute {name!r}")
