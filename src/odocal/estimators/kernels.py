"""Which compiled kernels each method runs, and whether numba's disk cache holds them.

The default and ``raw`` methods compile nothing (the model's rollouts and Jacobians are numpy:
:mod:`odocal.model.jacobians`); the compensated method runs the compensation QP's Riccati
kernels (:mod:`odocal.estimators.compensation.riccati`: ``_pdas_batch``, which calls ``_pdas``
and ``_sweep``, compiled and cached with it).
Its first run after an install, or after an edit to any source a kernel inlines, compiles them:
the command line says so before the silent wait (:func:`compile_note`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

#: The cached kernels each method's first run compiles (module, kernel), and about how many
#: seconds each takes to compile (measured on two cores with an empty cache, rounded up).
METHOD_KERNELS: dict[str, tuple[tuple[str, str], ...]] = {
    "compensated": (("riccati", "_pdas_batch"),),
}
COMPILE_S: dict[str, float] = {"_pdas_batch": 3.0}


#: Where the kernels of METHOD_KERNELS live.
_MODULES = {"riccati": "odocal.estimators.compensation.riccati"}


def _kernel(module: str, name: str) -> Any:
    import importlib

    return getattr(importlib.import_module(_MODULES[module]), name)


def uncached_kernels(methods: Sequence[str] = tuple(METHOD_KERNELS)) -> list[str] | None:
    """The kernels ``methods`` need that numba's disk cache lacks for the current sources
    (their first call compiles them), sorted by name; ``None`` where there is no disk cache at
    all (a read-only install: every run compiles)."""
    from odocal.model._jit import uncached

    wanted = sorted({k for m in methods for k in METHOD_KERNELS.get(m, ())},
                    key=lambda k: k[1])
    if not wanted:
        return []
    return uncached([_kernel(module, name) for module, name in wanted])


def compile_note(methods: Sequence[str]) -> str | None:
    """The line to print before the silent wait of a first compilation, or None if there is
    none (the kernels are cached, or ``methods`` need none)."""
    from odocal.model._jit import AVAILABLE

    if not AVAILABLE:                    # nothing is compiled (and compensated refuses to run)
        return None
    missing = uncached_kernels(methods)
    if missing == []:
        return None
    if missing is None:
        return ("note: numba cannot cache the numerical kernels here (a read-only install): "
                "they are compiled on every run, some seconds before the fit starts")
    seconds = sum(COMPILE_S.get(k, 2.0) for k in missing)
    return (f"note: compiling the numerical kernels once (about {seconds:.0f} s, longer on a "
            "slow machine); later runs start at once")
