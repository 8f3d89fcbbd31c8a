"""numba's ``njit`` with a disk cache keyed on every source a kernel runs, degrading gracefully.

Compiled kernels are cached on disk so that only the first run compiles them. numba keys its
cache on the file that defines a kernel (its time stamp and size) and the kernel's own bytecode,
not on what the kernel inlines or calls: the segment methods' kernels inline the model step of
:mod:`odocal.model.step`, and after an edit to the step they would go on running the old
equations from the cache. Here every cached kernel is keyed instead on the *contents* of every
odocal source file it reaches: its own file, the files of the functions and kernels it calls
(followed through their globals, recursively) and of the odocal modules it names. An edit to any
of them makes the next call compile afresh; undoing the edit finds the old entry again.

numba caches beside the source when that folder is writable, else in its user-wide cache folder
(or under ``NUMBA_CACHE_DIR``); on an installation that is read-only for the user running it,
with no writable home, numba has no cache at all. Then the kernels are compiled in memory on
every run instead: slower to start, never a traceback.

Kernels are serial: on the few cores a calibration has, threading a kernel's outer loop bought
less than it cost in compiling (``parallel=True`` doubled the first run's compile time), and
the work that does run in parallel (compensation, fleets) runs in processes.
"""

from __future__ import annotations

import hashlib
import logging
import types
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

try:
    from numba import njit
    from numba.core.caching import FunctionCache
    from numba.core.dispatcher import Dispatcher
except ImportError:          # the base install: numba comes with the compensated extra
    njit = None  # type: ignore[assignment]
    FunctionCache = object  # type: ignore[assignment,misc]
    Dispatcher = type(None)  # type: ignore[assignment,misc]

F = TypeVar("F", bound=Callable[..., Any])

#: Whether numba is installed (``pip install 'odocal[compensated]'``). Without it the kernels
#: run as the plain Python they are written in: the same numbers, slower (odocal's own GNSS/IMU
#: fusion about ten times); the compensated method refuses to start (:func:`require`).
AVAILABLE = njit is not None
#: The one line that adds numba.
INSTALL_HINT = "pip install 'odocal[compensated]'"


def require(what: str) -> None:
    """A one-line :class:`odocal.errors.MissingDependencyError` unless numba is installed."""
    if not AVAILABLE:
        from odocal.errors import MissingDependencyError

        raise MissingDependencyError(f"{what} needs numba, which is not installed: "
                                     f"{INSTALL_HINT}")
log = logging.getLogger(__name__)

#: The folder of the odocal package: the sources a kernel's key is made of lie under it.
_PACKAGE = Path(__file__).resolve().parents[1]


def _names(code: types.CodeType) -> Iterator[str]:
    """The global names ``code`` and the code objects nested in it refer to."""
    yield from code.co_names
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from _names(const)


def _ours(path: str | None) -> Path | None:
    """``path`` resolved, if it is a source file of the odocal package, else None."""
    if not path:
        return None
    resolved = Path(path).resolve()
    return resolved if resolved.suffix == ".py" and resolved.is_relative_to(_PACKAGE) else None


def kernel_sources(py_func: Callable[..., Any]) -> list[Path]:
    """Every odocal source file ``py_func`` runs code of, sorted: its own file, those of the
    functions and compiled kernels it refers to (recursively, through each one's globals, so a
    step function bound into a kernel counts with the file it was written in) and of the odocal
    modules it names (``step.wrap`` reaches step.py)."""
    files: set[Path] = set()
    seen: set[int] = set()
    stack: list[Any] = [py_func]
    while stack:
        func = stack.pop()
        if id(func) in seen:
            continue
        seen.add(id(func))
        own = _ours(func.__code__.co_filename)
        if own is not None:
            files.add(own)
        for name in set(_names(func.__code__)):
            obj = func.__globals__.get(name)
            if isinstance(obj, Dispatcher):
                obj = obj.py_func
            if isinstance(obj, types.FunctionType):
                stack.append(obj)
            elif isinstance(obj, types.ModuleType):
                module_file = _ours(getattr(obj, "__file__", None))
                if module_file is not None:
                    files.add(module_file)
    return sorted(files)


def sources_digest(py_func: Callable[..., Any]) -> str:
    """SHA-256 over the names (relative to the package) and contents of :func:`kernel_sources`."""
    digest = hashlib.sha256()
    for path in kernel_sources(py_func):
        digest.update(path.relative_to(_PACKAGE).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


class SourceKeyedCache(FunctionCache):
    """numba's per-function disk cache, with the index's freshness stamp replaced by
    :func:`sources_digest`: an index written for other sources is treated as empty (numba then
    compiles, and overwrites it). The digest is taken at the first lookup, when the module that
    defines the kernel has finished importing (its globals are all bound)."""

    def __init__(self, py_func: Callable[..., Any]) -> None:
        super().__init__(py_func)
        self._keyed = False

    def _key_on_sources(self) -> None:
        if not self._keyed:
            self._cache_file._source_stamp = ("odocal-sources", sources_digest(self._py_func))
            self._keyed = True

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        self._key_on_sources()
        return super().load_overload(sig, target_context)

    def save_overload(self, sig: Any, data: Any) -> None:
        self._key_on_sources()
        super().save_overload(sig, data)

    def holds_entries(self) -> bool:
        """Whether the disk holds compiled code of this kernel for the current sources (some
        signature: odocal's kernels are called with one)."""
        self._key_on_sources()
        try:
            return bool(self._cache_file._load_index())
        except Exception:                    # an unreadable index: numba itself recompiles
            log.debug("numba's cache index of %s cannot be read", self._name, exc_info=True)
            return False


def jit(func: F | None = None, *, inline: bool = False) -> Any:
    """``@jit`` or ``@jit(inline=True)``: nopython compilation, cached on disk (keyed on every
    source the kernel reaches) where possible. Inlined functions are not cached: they are
    compiled into the kernels that call them."""

    def decorate(f: F) -> Any:
        if njit is None:                     # plain Python (see AVAILABLE)
            return f
        # nogil: a kernel lets other threads run (the CLI loads the report's plotting library
        # in the background while the model computes)
        options: dict[str, Any] = {"error_model": "numpy", "nogil": True}
        if inline:
            options["inline"] = "always"
        dispatcher = njit(cache=False, **options)(f)
        if not inline:
            try:
                dispatcher._cache = SourceKeyedCache(dispatcher.py_func)
            except RuntimeError as exc:      # no cache locator: a read-only install
                log.debug("numba cache unavailable for %s (%s); compiling in memory",
                          f.__name__, exc)
        return dispatcher

    return decorate if func is None else decorate(func)


def uncached(kernels: Sequence[Any]) -> list[str] | None:
    """The names of ``kernels`` (dispatchers made by :func:`jit`) whose compiled code for the
    current sources is not on disk (their first call compiles them), or ``None`` where there is
    no disk cache at all (a read-only install: every run compiles)."""
    missing = []
    for kernel in kernels:
        cache = getattr(kernel, "_cache", None)
        if not isinstance(cache, SourceKeyedCache):
            return None
        if not cache.holds_entries():
            missing.append(kernel.py_func.__name__)
    return missing
