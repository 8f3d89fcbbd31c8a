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
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from numba import njit

F = TypeVar("F", bound=Callable[..., Any])
log = logging.getLogger(__name__)


#: The cached kernels of :mod:`odocal.model.compiled` each method's first run compiles, and
#: about how many seconds each takes to compile (measured on two cores, rounded up).
METHOD_KERNELS: dict[str, tuple[str, ...]] = {
    "raw": ("_r_factor_kernel",),
    "compensated": ("_r_factor_kernel", "_step_jacobian_kernel"),
}
COMPILE_S: dict[str, float] = {"_r_factor_kernel": 2.0, "_step_jacobian_kernel": 5.0}


def uncached_kernels(methods: Sequence[str] = tuple(METHOD_KERNELS)) -> list[str] | None:
    """The kernels ``methods`` need that numba's disk cache lacks (their first call compiles
    them), as numba itself looks them up: beside the source, under ``NUMBA_CACHE_DIR`` or in the
    user-wide cache folder, for this numba and this version of the source. ``None`` where there
    is no disk cache at all (a read-only install: every run compiles)."""
    names = sorted({k for m in methods for k in METHOD_KERNELS.get(m, ())})
    if not names:
        return []
    from odocal.model import compiled

    missing = []
    for name in names:
        cache = getattr(getattr(compiled, name, None), "_cache", None)
        index = getattr(cache, "_cache_file", None)
        if index is None:                    # numba's NullCache: compiled in memory each run
            return None
        try:
            fresh = bool(index._load_index())
        except Exception:                    # numba's private API changed
            fresh = _index_files(name)
        if not fresh:
            missing.append(name)
    return missing


def _index_files(name: str) -> bool:
    """Fallback: an index file of ``name`` beside the source or under ``NUMBA_CACHE_DIR``."""
    import os
    from pathlib import Path

    custom = os.environ.get("NUMBA_CACHE_DIR")
    places = [Path(custom)] if custom else [Path(__file__).parent / "__pycache__"]
    return any(next(place.rglob(f"compiled.{name}-*.nbi"), None) is not None
               for place in places if place.is_dir())


def kernels_cached(methods: Sequence[str] = tuple(METHOD_KERNELS)) -> bool:
    """Whether the kernels ``methods`` need are in numba's disk cache (see
    :func:`uncached_kernels`)."""
    return uncached_kernels(methods) == []


def compile_note(methods: Sequence[str]) -> str | None:
    """The line to print before the silent wait of a first compilation, or None if there is
    none (the kernels are cached, or ``methods`` need none)."""
    missing = uncached_kernels(methods)
    if missing == []:
        return None
    if missing is None:
        return ("note: numba cannot cache the numerical kernels here (a read-only install): "
                "they are compiled on every run, some seconds before the fit starts")
    seconds = sum(COMPILE_S.get(k, 2.0) for k in missing)
    return (f"note: compiling the numerical kernels once (about {seconds:.0f} s, longer on a "
            "slow machine); later runs start at once")


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
