"""Where the fleet's tasks run, and every way that goes wrong: a missing mapping, a malformed or
silent scheduler, too many workers, a parent killed under its workers, Ctrl-C, a script without
the ``__main__`` guard. Real processes, real sockets, a real local Dask cluster: no mocks."""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from odocal.cli.main import main
from odocal.errors import InputFileError
from odocal.estimators.parallel import resolve_workers
from odocal.fleet.catalog import read_catalog
from odocal.fleet.engine import CONNECT_TIMEOUT_S, available_cores, dask_client
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import open_store

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def small_fleet(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """2 vehicles x 4 drives of 4 minutes."""
    return simulate_fleet(tmp_path_factory.mktemp("cluster") / "f", vehicles=2, drives=4,
                          duration_s=240.0, seed=5, plan="none")


def _one_drive(fleet: Any) -> Path:
    return sorted((fleet.catalog.parent / "car000").glob("*.parquet"))[0]


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie, dead but not yet reaped, counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False


def _gone(pids: list[int], limit_s: float) -> list[int]:
    """The pids still running after up to ``limit_s`` seconds."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        left = [p for p in pids if _alive(p)]
        if not left:
            return []
        time.sleep(0.05)
    return [p for p in pids if _alive(p)]


def _group(pgid: int) -> list[int]:
    """Running processes of the process group ``pgid`` (from /proc)."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            found.append(int(entry))
    return found


# ---------------------------------------------------------------- a missing mapping file

@pytest.mark.parametrize("make", ["missing", "folder", "fifo"])
def test_a_catalogs_mapping_file_that_is_not_a_file_is_one_line(
        small_fleet: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        make: str) -> None:
    mapping = tmp_path / "map.toml"
    if make == "folder":
        mapping.mkdir()
    elif make == "fifo":
        os.mkfifo(mapping)                        # reading it would block for ever
    catalog = tmp_path / "catalog.csv"
    catalog.write_text("vehicle,path,time,format,mapping\n"
                       f"v,{_one_drive(small_fleet)},2026-01-01,table,map.toml\n")
    with pytest.raises(InputFileError, match="row 1: mapping file"):
        read_catalog(catalog)
    started = time.monotonic()
    code = main(["fleet", "calibrate", str(catalog), "--store", str(tmp_path / "s.db"), "-q"])
    err = capsys.readouterr().err
    assert code == 1 and len(err.splitlines()) == 1 and "map.toml" in err
    # (a hang guard, not a speed limit: reading the FIFO would block for ever)
    assert time.monotonic() - started < 120
    assert not (tmp_path / "s.db").exists()       # refused before the store was made


# ---------------------------------------------------------------- scheduler addresses

@pytest.mark.parametrize("address", ["foo", "tcp://", "http://host:8786", "tcp://host:99999",
                                     "tcp://host:port", "tcp://exa mple:8786", "tcp://:8786",
                                     "tcp://\x1b[31mred:8786", "127.0.0.1"])
def test_a_malformed_scheduler_address_is_one_line(small_fleet: Any, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str],
                                                   address: str) -> None:
    code = main(["fleet", "calibrate", str(small_fleet.catalog), "--store",
                 str(tmp_path / "s.db"), "--scheduler", address, "-q"])
    err = capsys.readouterr().err
    assert code == 1 and len(err.splitlines()) == 1 and "scheduler" in err
    assert "\x1b" not in err and "Traceback" not in err
    assert not (tmp_path / "s.db").exists()


def _silent_server(accept: bool) -> tuple[socket.socket, int]:
    """A port that takes connections (``accept``: and holds them) and never says a word."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(64)
    held: list[Any] = []
    if accept:
        def take() -> None:
            while True:
                try:
                    held.append(server.accept())
                except OSError:
                    return
        threading.Thread(target=take, daemon=True).start()
    return server, int(server.getsockname()[1])


def _chatty_server() -> tuple[socket.socket, int]:
    """A port that answers every connection with an HTTP reply (not a Dask scheduler)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(64)

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.sendall(b"HTTP/1.0 200 OK\r\nContent-Length: 2\r\n\r\nhi" * 100)
    threading.Thread(target=serve, daemon=True).start()
    return server, int(server.getsockname()[1])


@pytest.mark.parametrize(("kind", "timeout"), [("accepts", 1.5), ("backlog", 1.0),
                                               ("http", 2.0)])
def test_a_scheduler_that_never_answers_is_given_up_after_the_timeout(
        small_fleet: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str,
        timeout: float) -> None:
    server, port = (_chatty_server() if kind == "http"
                    else _silent_server(accept=kind == "accepts"))
    try:
        started = time.monotonic()
        code = main(["fleet", "calibrate", str(small_fleet.catalog), "--store",
                     str(tmp_path / "s.db"), "--scheduler", f"tcp://127.0.0.1:{port}",
                     "--connect-timeout", str(timeout), "-q"])
        elapsed = time.monotonic() - started
    finally:
        server.close()
    err = capsys.readouterr().err
    assert code == 1 and len(err.splitlines()) == 1, err
    assert "scheduler" in err and "Traceback" not in err
    if kind == "http":        # (its bytes read as a message's sizes: "allocate 3.07 EiB")
        assert "answered, but not in Dask's protocol: not a Dask scheduler" in err, err
    # --connect-timeout is honoured (Dask alone waited over 100 s): a bound on behaviour,
    # with room for a loaded machine, not a speed figure
    assert elapsed < timeout + 30.0, elapsed
    assert not (tmp_path / "s.db").exists()


def test_a_closed_scheduler_port_is_refused_at_once(small_fleet: Any, tmp_path: Path) -> None:
    """Nothing listens there: the host says so at once, and so does odocal, whatever the
    timeout (on main it waited the whole --connect-timeout: here an hour)."""
    closed = socket.socket()
    closed.bind(("127.0.0.1", 0))
    port = int(closed.getsockname()[1])
    closed.close()                                   # bound, then freed: nothing listens
    proc = subprocess.run([str(BIN / "odocal"), "fleet", "calibrate", str(small_fleet.catalog),
                           "--store", str(tmp_path / "s.db"), "--scheduler",
                           f"tcp://127.0.0.1:{port}", "--connect-timeout", "3600", "-q"],
                          capture_output=True, text=True, timeout=120)   # a hang guard
    assert proc.returncode == 1 and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert "connection refused" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "s.db").exists()


def test_the_connect_timeout_defaults_to_10_s_and_is_checked(
        small_fleet: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from odocal.cli.main import build_parser

    args = build_parser().parse_args(["fleet", "calibrate", "c.csv", "--store", "s.db"])
    assert args.connect_timeout == CONNECT_TIMEOUT_S == 10.0
    for bad in ("0", "-1", "1e9", "nan"):
        with pytest.raises(SystemExit) as exit_:
            main(["fleet", "calibrate", str(small_fleet.catalog), "--store",
                  str(tmp_path / "s.db"), "--scheduler", "tcp://127.0.0.1:1",
                  "--connect-timeout", bad, "-q"])
        err = capsys.readouterr().err
        # a number out of its range on the command line: a usage error, as everywhere
        assert exit_.value.code == 2, (bad, err)
        assert "argument --connect-timeout: " in err.splitlines()[-1], (bad, err)
        assert not (tmp_path / "s.db").exists()


# ---------------------------------------------------------------- workers

def test_workers_are_capped_at_the_cores(small_fleet: Any, tmp_path: Path) -> None:
    cores = available_cores()
    assert resolve_workers(1000) == cores and resolve_workers(0) == cores
    assert resolve_workers(1) == 1
    with dask_client(workers=1000) as client:
        assert len(client.scheduler_info()["workers"]) == cores
    proc = subprocess.run([str(BIN / "odocal"), "fleet", "calibrate", str(small_fleet.catalog),
                           "--store", str(tmp_path / "s.db"), "--workers", "1000"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    notes = [line for line in proc.stderr.splitlines() if "--workers 1000" in line]
    assert len(notes) == 1 and str(cores) in notes[0]


_POOL_SCRIPT = """
import os, sys, time
from odocal.estimators.parallel import map_chunks

def work(i):
    open(os.path.join(sys.argv[1], f"{i}.pid"), "w").write(str(os.getpid()))
    time.sleep(120)
    return i

if __name__ == "__main__":
    map_chunks(work, [0, 1], workers=2)
"""

_DASK_SCRIPT = """
import os, sys, time
from odocal.fleet.engine import dask_client

if __name__ == "__main__":
    with dask_client(workers=2) as client:
        pids = client.run(os.getpid)
        open(sys.argv[1] + "/workers", "w").write(" ".join(str(p) for p in pids.values()))
        time.sleep(120)
"""


@pytest.mark.parametrize("script", [_POOL_SCRIPT, _DASK_SCRIPT], ids=["pool", "dask"])
def test_workers_die_when_their_parent_is_killed(tmp_path: Path, script: str) -> None:
    """SIGKILL to the parent alone (not its group): its worker processes end too."""
    path = tmp_path / "parent.py"
    path.write_text(textwrap.dedent(script))
    parent = subprocess.Popen([sys.executable, str(path), str(tmp_path)], cwd=ROOT,
                              start_new_session=True, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while time.monotonic() < deadline and len(workers) < 2:
            time.sleep(0.1)
            files = [tmp_path / "workers"] if "dask" in script else \
                sorted(tmp_path.glob("*.pid"))
            text = " ".join(f.read_text() for f in files if f.exists())
            workers = [int(p) for p in text.split() if p.isdigit()]
        assert len(workers) == 2, "the workers did not start"
        assert all(_alive(p) for p in workers) and parent.pid not in workers
        parent.kill()                              # SIGKILL: no handler, no cleanup runs
        parent.wait()
        assert _gone(workers, 5.0) == [], "workers outlived their killed parent"
    finally:
        if _group(parent.pid):
            os.killpg(parent.pid, signal.SIGKILL)


# ---------------------------------------------------------------- Ctrl-C

_MASK_SCRIPT = """
from odocal.fleet.engine import dask_client

def blocked():
    status = open("/proc/self/status").read().splitlines()
    return int(next(line for line in status if line.startswith("SigBlk:")).split()[1], 16)

if __name__ == "__main__":
    with dask_client(workers=2) as client:
        print(" ".join(str(mask) for mask in client.run(blocked).values()))
"""


def test_the_workers_are_born_with_ctrl_c_blocked(tmp_path: Path) -> None:
    """A terminal's Ctrl-C goes to every process of its group, the workers included: one that
    lands while a worker's interpreter starts (before any handler can be set) printed "Fatal
    Python error: init_import_site" and a stack. The workers are spawned with SIGINT blocked
    (on main, multiprocessing's resource tracker, started from Dask's IO loop, unblocked it
    there, and the workers were born with nothing blocked)."""
    path = tmp_path / "mask.py"
    path.write_text(_MASK_SCRIPT)
    proc = subprocess.run([sys.executable, str(path)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    masks = [int(m) for m in proc.stdout.split()]
    assert len(masks) == 2
    assert all(mask & (1 << (signal.SIGINT - 1)) for mask in masks), masks


def _stored(store: Path) -> int:
    try:
        with sqlite3.connect(f"file:{store}?mode=ro", uri=True, timeout=30) as db:
            return int(db.execute("SELECT count(*) FROM drives").fetchone()[0])
    except sqlite3.Error:
        return 0


@pytest.mark.parametrize("after", [1, 3])
def test_ctrl_c_ends_a_fleet_run_within_a_second(small_fleet: Any, tmp_path: Path,
                                                  after: int) -> None:
    store = tmp_path / "s.db"
    proc = subprocess.Popen([str(BIN / "odocal"), "fleet", "calibrate",
                             str(small_fleet.catalog), "--store", str(store), "--workers", "2",
                             "--out", str(tmp_path / "out")],
                            start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while _stored(store) < after and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    before = _stored(store)
    started = time.monotonic()
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=30)
    finally:
        if _group(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    elapsed = time.monotonic() - started
    assert proc.returncode == 130 and err.strip().endswith("interrupted"), err
    said = [line for line in err.strip().splitlines() if not line.startswith("[")]
    assert said == ["odocal fleet: interrupted"], err      # progress lines aside
    # (a stopped run, not one that finishes first: the run still had minutes to go; the time
    # itself, about 0.1 s on a quiet machine, is benchmark material, not a unit test's)
    assert elapsed < 60.0, f"Ctrl-C took {elapsed:.2f} s"        # a hang guard
    assert _gone(_group(proc.pid), 3.0) == []
    with open_store(store, create=False, read_only=True) as db:
        assert len(db.drives()) >= before
    assert not list(tmp_path.rglob("*.part")), "a temporary folder was left"


# ---------------------------------------------------------------- the __main__ guard

def test_a_script_without_the_main_guard_is_told_in_one_line(small_fleet: Any,
                                                              tmp_path: Path) -> None:
    script = tmp_path / "fleet_script.py"
    script.write_text("from odocal.fleet.engine import calibrate_fleet\n"
                      f"calibrate_fleet({str(small_fleet.catalog)!r}, "
                      f"{str(tmp_path / 's.db')!r}, workers=2)\n")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert proc.returncode == 1
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("odocal.errors.ConfigError") and '__name__ == "__main__"' in last
    assert proc.stderr.count("Traceback") == 1 and len(proc.stderr.splitlines()) < 25
    assert "distributed" not in proc.stderr.replace("odocal", "")
    guarded = tmp_path / "guarded.py"
    guarded.write_text("from odocal.fleet.engine import calibrate_fleet\n"
                       "if __name__ == '__main__':\n"
                       f"    run = calibrate_fleet({str(small_fleet.catalog)!r}, "
                       f"{str(tmp_path / 'g.db')!r}, workers=2)\n"
                       "    print(run.calibrated)\n")
    ok = subprocess.run([sys.executable, str(guarded)], capture_output=True, text=True,
                        timeout=600, cwd=tmp_path)
    assert ok.returncode == 0 and ok.stdout.split() == ["8"], ok.stderr


# ---------------------------------------------------------------- the store under Ctrl-C

def test_a_transaction_that_never_began_ends_with_its_own_error(tmp_path: Path) -> None:
    """BEGIN refused (another writer holds the file): the caller sees why, not 'cannot
    rollback'; nothing is stored and the store stays usable."""
    path = tmp_path / "s.db"
    with open_store(path) as store:
        store.db.execute("PRAGMA busy_timeout = 50")
        other = sqlite3.connect(path, isolation_level=None)
        other.execute("BEGIN IMMEDIATE")
        try:
            with pytest.raises(sqlite3.OperationalError, match="locked"):
                store.add_drive({"task_key": "k", "vehicle": "v", "time": "t", "source": "s",
                                 "status": "converged", "success": True})
        finally:
            other.execute("ROLLBACK")
            other.close()
        assert store.drives() == []
        store.add_drive({"task_key": "k", "vehicle": "v", "time": "t", "source": "s",
                         "status": "converged", "success": True})
        assert [r["task_key"] for r in store.drives()] == ["k"]
