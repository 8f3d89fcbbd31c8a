"""numba's ``njit`` with a cache that degrades gracefully.

Compiled kernels are cached on disk so that only the first run compiles them. numba caches beside
the source when that folder is writable, else in its user-wide cache folder; on an installation
that is read-only for the user running it, with no writable home, numba refuses to decorate a
cached function at all ("cannot cache function ..."). Then the kernels are compiled in memory on
every run instead: slower to start, never a traceback.

Parallel kernels (``parallel=True``) split their outer loop over segments across threads; each
segment's result is computed alone, so results do not depend on the number of threads.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any, TypeVar

import numba
from numba import njit

# Parallel kernels run on numba's own work queue unless the user chose a threading layer: it is
# fork-safe (odocal's process pools fork after kernels have run; GNU OpenMP would abort there).
if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"  # type: ignore[attr-defined]

F = TypeVar("F", bound=Callable[..., Any])
log = logging.getLogger(__name__)


def jit(func: F | None = None, *, parallel: bool = False, inline: bool = False) -> Any:
    """``@jit`` or ``@jit(parallel=True)``: nopython compilation, cached where possible."""

    def decorate(f: F) -> Any:
        # nogil: a kernel lets other threads run (the CLI loads the report's plotting library
        # in the background while the model computes)
        options: dict[str, Any] = {"parallel": parallel, "error_model": "numpy", "nogil": True}
        if inline:
            options["inline"] = "always"
        try:
            return njit(cache=not inline, **options)(f)
        except RuntimeError as exc:          # no cache locator: a read-only install
            log.debug("numba cache unavailable for %s (%s); compiling in memory",
                      f.__name__, exc)
            return njit(cache=False, **options)(f)

    return decorate if func is None else decorate(func)
