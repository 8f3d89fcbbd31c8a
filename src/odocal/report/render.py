"""Drawing the report's figures from plain data, in this process or in forked helpers.

A figure is described by a :class:`FigureSpec`: its size, its grid of axes and a list of calls
of the plot functions in :mod:`odocal.report.figures` with their (numpy) arguments. Specs are
built without matplotlib and are small, so they travel to helper processes cheaply; the helpers
draw them and send back PNG bytes.

A :class:`Renderer` started before the calibration forks its helpers while the process is still
light, and they import matplotlib at once, on the otherwise idle core, while the calibration
computes: by the time the figures are wanted, the plotting library is loaded.
"""

from __future__ import annotations

import io
import multiprocessing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

DPI = 110
#: The report's colours: reference, datasheet, calibrated, raw G-N, step-1 batches.
REFERENCE, DATASHEET, CALIBRATED, RAW, STEP1 = "#222222", "#d62728", "#1f77b4", "#ff7f0e", "#999999"


@dataclass(frozen=True)
class Call:
    """One call ``figures.<function>(axes[row][col], *args, **kwargs)``; ``row`` None: all axes
    of the first row are passed as a list (for functions that draw on several axes)."""

    function: str
    args: tuple[Any, ...] = ()
    kwargs: dict[str, Any] = field(default_factory=dict)
    row: int | None = 0
    col: int = 0


@dataclass(frozen=True)
class FigureSpec:
    """What to draw for one figure of the page."""

    name: str
    caption: str
    width: float
    height: float
    calls: tuple[Call, ...]
    rows: int = 1
    cols: int = 1


def draw(spec: FigureSpec) -> bytes:
    """The PNG of one figure."""
    from matplotlib.figure import Figure

    from odocal.report import figures

    fig = Figure(figsize=(spec.width, spec.height), layout="constrained")
    axes = fig.subplots(spec.rows, spec.cols, squeeze=False)
    for call in spec.calls:
        target: Any = list(axes[0]) if call.row is None else axes[call.row][call.col]
        getattr(figures, call.function)(target, *call.args, **call.kwargs)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, pil_kwargs={"compress_level": 3})
    return buffer.getvalue()


def _preload() -> None:
    from odocal.parallel import ignore_interrupts

    ignore_interrupts()
    import matplotlib.backends.backend_agg
    import matplotlib.figure  # noqa: F401

    import odocal.report.figures  # noqa: F401


class Renderer:
    """Draws figure specs, in ``workers`` forked helpers (started now), or in this process
    (``workers = 0``).

    Use as a context manager; start it early (before heavy imports and computation) so that the
    helpers load matplotlib while the caller works.
    """

    def __init__(self, workers: int = 0) -> None:
        self._pool: Any = None
        if workers > 0 and "fork" in multiprocessing.get_all_start_methods():
            context = multiprocessing.get_context("fork")
            self._pool = context.Pool(workers, initializer=_preload)

    def draw(self, specs: Sequence[FigureSpec]) -> list[bytes]:
        if self._pool is None:
            return [draw(s) for s in specs]
        return list(self._pool.map(draw, specs, chunksize=1))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
