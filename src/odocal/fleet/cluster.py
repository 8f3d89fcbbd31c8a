"""Where a fleet's tasks run: the embedded local Dask cluster, or a scheduler the user names.

Every way this can go wrong ends in one line, never a hang or pages of Dask's errors:

* a scheduler is asked who it is before a client connects, and that question is given up
  after the timeout (Dask's own client waits without end on a port that accepts a connection
  and never speaks): one that never answers, or answers as something other than a Dask
  scheduler, is a :class:`~odocal.errors.ConfigError` after at most that long;
* Ctrl-C kills the local cluster's worker processes at once (their tasks are lost anyway;
  what is stored stays), so the run ends within a second;
* the local cluster's worker processes end with the process that started them, even when it
  is killed with SIGKILL (Linux: the kernel's parent-death signal; elsewhere a thread watches
  the parent);
* ``calibrate_fleet`` in a script without ``if __name__ == "__main__":`` makes each worker
  process run the script again as it starts (Python's ``spawn``): the workers stop at once and
  the caller gets one line that says to add the guard.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator
from multiprocessing import resource_tracker
from pathlib import Path
from typing import Any

from odocal.errors import ConfigError
from odocal.estimators.parallel import die_with_parent, interrupts_held

log = logging.getLogger(__name__)

#: Environment variable naming the file a worker process leaves when it finds itself started
#: by a script that calls ``calibrate_fleet`` unguarded.
_UNGUARDED_ENV = "ODOCAL_UNGUARDED_FLAG"

GUARD_MESSAGE = ("the script calls calibrate_fleet() unguarded, so each worker process "
                 "Python starts runs it again: put the call under "
                 "`if __name__ == \"__main__\":`")


def _shown(text: str) -> str:
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)[:200]


def probe_scheduler(address: str, timeout_s: float) -> dict[str, Any]:
    """Ask the process at ``address`` who it is; a ConfigError unless a Dask scheduler answers
    within ``timeout_s`` (a port that accepts and never speaks included)."""

    async def ask() -> Any:
        from distributed.comm import connect

        comm = await connect(address, timeout=timeout_s)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    where = f"cannot reach the Dask scheduler at {address}"
    _refused_now(address, timeout_s, where)
    answer: dict[str, Any] = {}

    def run() -> None:
        try:
            answer["reply"] = asyncio.run(asyncio.wait_for(ask(), timeout_s))
        except BaseException as exc:           # reported by the caller
            answer["error"] = exc

    # a thread of its own: the caller may have an event loop running (a notebook), and a peer
    # that never answers must not hold the caller beyond the timeout
    thread = threading.Thread(target=run, name="odocal-scheduler-probe", daemon=True)
    thread.start()
    thread.join(timeout_s + 2.0)
    if thread.is_alive() or isinstance(answer.get("error"), TimeoutError | asyncio.TimeoutError):
        raise ConfigError(f"{where}: no answer within {timeout_s:g} s (--connect-timeout)")
    if "error" in answer:
        exc = answer["error"]
        if isinstance(exc, MemoryError | ValueError | TypeError | KeyError):
            # Dask's protocol read the first bytes of something else as a message's sizes
            raise ConfigError(f"{address} answered, but not in Dask's protocol: not a Dask "
                              "scheduler (another service on that port?)")
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"{where}: {_shown(text)}")
    reply: Any = answer.get("reply")
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        what = f"a Dask {kind}" if isinstance(kind, str) else "something else"
        raise ConfigError(f"{address} answered as {_shown(str(what))}, not as a Dask scheduler")
    return reply


def _refused_now(address: str, timeout_s: float, where: str) -> None:
    """A ConfigError at once where nothing listens at a ``tcp://`` address (the host answers
    "connection refused", or is not known): Dask's own connect tries a refused port again and
    again until its timeout runs out. A host that does not answer at all is left to the
    timeout."""
    import socket

    protocol, _, rest = address.partition("://")
    if protocol != "tcp":
        return
    host, _, port = rest.rstrip("/").rpartition(":")
    host = host.strip("[]")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except ConnectionRefusedError:
        raise ConfigError(f"{where}: nothing listens there (connection refused); is the "
                          "scheduler running, and is the port right?") from None
    except socket.gaierror as exc:
        raise ConfigError(f"{where}: the host {_shown(host)!r} is not known "
                          f"({_shown(str(exc.strerror or exc))})") from None
    except (OSError, ValueError):               # a time-out, no route: Dask's connect says
        return


def refuse_unguarded_start() -> None:
    """Called where a cluster would start. In a process that Python is still starting from a
    script (``spawn`` re-runs the script), leave a flag for the parent and end quietly."""
    import multiprocessing.process

    if not getattr(multiprocessing.process.current_process(), "_inheriting", False):
        return
    flag = os.environ.get(_UNGUARDED_ENV)
    if flag:
        with contextlib.suppress(OSError):
            Path(flag).write_text("unguarded\n")
        os._exit(1)
    raise ConfigError(GUARD_MESSAGE)


@contextlib.contextmanager
def _guard_flag() -> Iterator[Path]:
    """A fresh flag path named in the environment the worker processes inherit while they
    start; removed afterwards."""
    folder = Path(tempfile.mkdtemp(prefix="odocal-guard-"))
    flag = folder / "flag"
    previous = os.environ.get(_UNGUARDED_ENV)
    os.environ[_UNGUARDED_ENV] = str(flag)
    try:
        yield flag
    finally:
        if previous is None:
            os.environ.pop(_UNGUARDED_ENV, None)
        else:
            os.environ[_UNGUARDED_ENV] = previous
        with contextlib.suppress(OSError):
            flag.unlink()
        with contextlib.suppress(OSError):
            folder.rmdir()


class _WorkerSetup:
    """A Dask worker plugin: the worker ignores Ctrl-C (the parent stops the cluster) and dies
    with the process that started the cluster."""

    def __init__(self, parent_pid: int) -> None:
        self.parent_pid = parent_pid

    def setup(self, worker: Any) -> None:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        die_with_parent(self.parent_pid)


def _worker_plugin() -> Any:
    from distributed import WorkerPlugin

    class WorkerSetup(_WorkerSetup, WorkerPlugin):
        pass

    return WorkerSetup(os.getpid())


@contextlib.contextmanager
def local_client(n: int) -> Iterator[Any]:
    """A client of an embedded cluster of ``n`` single-threaded worker processes on the
    loopback address (see the module docstring)."""
    refuse_unguarded_start()
    from distributed import Client, LocalCluster

    if not log.isEnabledFor(logging.INFO):
        # (and the IO loop's: a callback Dask's client runs while Ctrl-C closes it logs its
        # stack through tornado's logger, a traceback in a run that ends in one line)
        for name in ("distributed", "tornado.application"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
    # one compiled-kernel and BLAS thread per single-threaded worker process (set in the
    # workers' environment, never in this process, whose threads may have started)
    threads = {k: "1" for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    cluster: Any = None
    stopping = False
    try:
        with _guard_flag() as flag:
            try:
                # Ctrl-C blocked while the cluster starts: its IO-loop thread, created now,
                # keeps the blocked mask, and so does every worker process it spawns (the mask
                # survives fork and exec), so a terminal's Ctrl-C cannot land in a worker's
                # interpreter start-up ("Fatal Python error: init_import_site"); this process
                # gets it as soon as the cluster is up. The resource tracker is started
                # first, here: starting it later, from the IO loop, would unblock Ctrl-C there
                # (multiprocessing unblocks it after spawning the tracker, whatever the mask was)
                resource_tracker.ensure_running()
                with interrupts_held():
                    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                           silence_logs=logging.CRITICAL, env=threads)
            except Exception:
                if flag.exists():
                    # the cause is Dask's and multiprocessing's own confusion about a script
                    # importing itself again: a script's user reads the message, not that chain
                    # (the spawned process prints its own traceback already)
                    raise ConfigError(GUARD_MESSAGE) from None
                raise
            if flag.exists():
                raise ConfigError(GUARD_MESSAGE)
        client = Client(cluster)
        try:
            client.register_plugin(_worker_plugin(), name="odocal-worker-setup")
            yield client
        except KeyboardInterrupt:
            # the workers go first, and nothing is waited for long: closing the client
            # waits up to a minute for an answer of a scheduler that is busy going away
            stopping = True
            _kill_workers(cluster)
            raise
        finally:
            _close(client.close, within_s=2.0 if stopping else None)
    except KeyboardInterrupt:
        stopping = True
        if cluster is not None:
            _kill_workers(cluster)
        raise
    finally:
        if cluster is not None:
            _close(lambda: cluster.close(timeout=2), within_s=3.0 if stopping else None)


def _close(close: Callable[[], object], *, within_s: float | None) -> None:
    """Call ``close``, its errors ignored; with ``within_s``, on a daemon thread waited for that
    long at most (a run that is stopping: what is left undone ends with the process)."""
    def run() -> None:
        with contextlib.suppress(Exception):
            close()

    if within_s is None:
        run()
        return
    thread = threading.Thread(target=run, name="odocal-close", daemon=True)
    thread.start()
    thread.join(within_s)


def _kill_workers(cluster: Any) -> None:
    """Ctrl-C: the worker processes are killed now (their tasks are lost anyway; what is stored
    stays), so closing the cluster has nothing to wait for."""
    for worker in list(getattr(cluster, "workers", {}).values()):
        pid = getattr(worker, "pid", None)           # a Nanny: its worker process's id
        if isinstance(pid, int) and pid > 0:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
