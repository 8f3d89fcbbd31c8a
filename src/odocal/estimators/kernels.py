"""Which compiled kernels each method runs, and whether numba's disk cache holds them.

The default and ``raw`` methods compile nothing (the model's rollouts and Jacobians are numpy:
:mod:`odocal.model.jacobians`); the compensated method runs the compensation QP's Riccati
kernels (:mod:`odocal.estimators.compensation.riccati`: ``_pdas_batch``, which calls ``_pdas``
and ``_sweep``, compiled and cached with it).
Its first run after an install, or after an edit to any source a kernel inlines, compiles them:
the command line says so before the silent wait (:func:`compile_note`), and a calibration
compiles them in a forked process from its start (:func:`compile_in_background`), beside
the reading, the checks and step 1, so that step 2 loads them from the cache.
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


def kernels_cached(methods: Sequence[str] = tuple(METHOD_KERNELS)) -> bool:
    """Whether the kernels ``methods`` need are in numba's disk cache."""
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


#: The forked processes compiling kernels for this one (:func:`compile_in_background`).
_PENDING: list[int] = []
#: How long :func:`ready` waits for them before it stops them and lets the first call compile.
_READY_TIMEOUT_S = 300.0


def compile_in_background(methods: Sequence[str]) -> None:
    """Compile the kernels ``methods`` need, where numba's disk cache lacks them, in a forked
    process that writes them to the cache, while this one goes on (:func:`ready` waits for it
    before the first kernel call, which then loads the kernel from the cache). Nothing where
    there is nothing to compile, no disk cache to hand the kernels over, or other threads in
    this process (a fork copies only the calling thread: a lock another one holds would never
    be released in the child)."""
    import os
    import threading

    if _PENDING or threading.active_count() > 1:
        return
    missing = uncached_kernels(methods)
    if not missing:
        return
    pid = os.fork()
    if pid == 0:                                    # the child: compile, write, leave
        code = 1
        try:
            _warm(missing)
            code = 0
        finally:
            os._exit(code)
    _PENDING.append(pid)


def ready() -> None:
    """Wait for the kernels :func:`compile_in_background` compiles (at most a few minutes;
    then the first call compiles them itself)."""
    import os
    import signal
    import time

    while _PENDING:
        pid = _PENDING.pop()
        deadline = time.monotonic() + _READY_TIMEOUT_S
        try:
            while os.waitpid(pid, os.WNOHANG) == (0, 0):
                if time.monotonic() > deadline:
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)
                    break
                time.sleep(0.01)
        except ChildProcessError:                   # (collected already)
            pass


def _warm(kernels: Sequence[str]) -> None:
    """Call ``kernels`` once on a tiny problem (their compilation writes the disk cache)."""
    import numpy as np

    if "_pdas_batch" in kernels:
        from odocal.estimators.compensation.problem import build_problems
        from odocal.estimators.compensation.riccati import solve_riccati_batch
        from odocal.model.parameters import Inputs
        from odocal.model.vehicle import MODEL
        from odocal.settings import CompensateSettings

        k = 4
        rates = np.full((1, k), 2.0)
        inputs = Inputs(n_rl=rates, n_rr=rates * 1.01, beta=np.zeros((1, k)),
                        a_y=np.zeros((1, k)))
        reference = np.zeros((1, k + 1, 3))
        reference[0, :, 0] = np.arange(k + 1) * 0.1
        theta = np.asarray(MODEL.layout.placeholder, dtype=np.float64)
        solve_riccati_batch(build_problems(theta, inputs, reference, 0.025,
                                           CompensateSettings()))
