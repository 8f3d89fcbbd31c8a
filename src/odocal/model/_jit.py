"""numba's ``njit`` with a cache that degrades gracefully.

Compiled kernels are cached on disk so that only the first run compiles them. numba caches beside
the source when that folder is writable, else in its user-wide cache folder; on an installation
that is read-only for the user running it, with no writable home, numba refuses to decorate a
cached function at all ("cannot cache function ..."). Then the kernels are compiled in memory on
every run instead: slower to start, never a traceback.

Kernels are serial: on the few cores a calibration has, threading a kernel's outer loop bought
less than it cost in compiling (``parallel=True`` doubled the first run's compile time), and
the work that does run in parallel (compensation, fleets) runs in processes.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, TypeVar

from numba import njit

F = TypeVar("F", bound=Callable[..., Any])
log = logging.getLogger(__name__)


def kernels_cached() -> bool:
    """Whether numba's disk cache holds the compiled kernels of :mod:`odocal.model.compiled`
    (beside the source, or under ``NUMBA_CACHE_DIR``): without them the first call compiles."""
    import os
    from pathlib import Path

    custom = os.environ.get("NUMBA_CACHE_DIR")
    places = [Path(custom)] if custom else [Path(__file__).parent / "__pycache__"]
    return any(next(place.rglob("compiled.*.nbi"), None) is not None
               for place in places if place.is_dir())


def jit(func: F | None = None, *, inline: bool = False) -> Any:
    """``@jit`` or ``@jit(inline=True)``: nopython compilation, cached where possible."""

    def decorate(f: F) -> Any:
        # nogil: a kernel lets other threads run (the CLI loads the report's plotting library
        # in the background while the model computes)
        options: dict[str, Any] = {"error_model": "numpy", "nogil": True}
        if inline:
            options["inline"] = "always"
        try:
            return njit(cache=not inline, **options)(f)
        except RuntimeError as exc:          # no cache locator: a read-only install
            log.debug("numba cache unavailable for %s (%s); compiling in memory",
                      f.__name__, exc)
            return njit(cache=False, **options)(f)

    return decorate if func is None else decorate(func)
