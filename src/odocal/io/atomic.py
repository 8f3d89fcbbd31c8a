"""Writing outputs atomically, and never over one of the inputs."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from odocal.errors import OutputError


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def refuse_inputs(output: str | Path, inputs: Iterable[str | Path | None], *,
                  folder: bool = False) -> None:
    """Raise OutputError if writing ``output`` could change one of the ``inputs``.

    Paths are compared resolved (symbolic links followed) and by identity (a hard link is the
    same file). A ``folder`` output is replaced as a whole, so no input may lie inside it.
    """
    out = Path(output).resolve()
    for item in inputs:
        if item is None:
            continue
        src = Path(item).resolve()
        inside = folder and out in src.parents
        if out == src or _same(out, src) or (src in out.parents and src.is_file()) or inside:
            what = "holds" if inside else "would overwrite"
            raise OutputError(f"output '{output}' {what} the input '{item}'; "
                              "choose another output path")


#: Marks a folder odocal wrote as a whole (and may therefore replace as a whole).
RESULTS_MARKER = ".odocal-results"


#: What odocal writes into a results folder (an older one, written before the marker existed,
#: may be replaced if it holds nothing else).
RESULTS_NAMES = frozenset({
    "calibration.json", "report.html", "figures", "odometry_parameters.yaml",
    "odometry_parameters.json", "compensated_inputs.parquet", "autoware", "ros2_control",
    "robot_localization", "trace.csv", "alarms.json"})


def check_replaceable(target: Path) -> None:
    """OutputError unless ``target`` is absent, empty, or a results folder odocal wrote."""
    if not target.exists():
        return
    if not target.is_dir():
        raise OutputError(f"output '{target}' exists and is not a folder")
    names = {p.name for p in target.iterdir()}
    if names and RESULTS_MARKER not in names and not names <= RESULTS_NAMES:
        raise OutputError(f"output folder '{target}' holds files odocal did not write; "
                          "choose a new or an empty folder")


@contextlib.contextmanager
def results_folder(target: str | Path) -> Iterator[Path]:
    """Yield a new temporary folder beside ``target``; on success it replaces ``target`` whole.

    A failed run leaves ``target`` as it was; a finished one leaves no file of an earlier run.
    An existing ``target`` must be empty, hold the marker odocal leaves, or hold only what odocal
    writes: odocal never deletes a folder with anything of the user's in it.
    """
    target = Path(target)
    check_replaceable(target)
    parent = target.parent if str(target.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".part", dir=parent))
    except OSError as exc:
        raise OutputError(f"cannot create the output folder '{target}': "
                          f"{exc.strerror or exc}") from None
    old = tmp.with_suffix(".old")
    try:
        yield tmp
        (tmp / RESULTS_MARKER).write_text("written by odocal as a whole; replaced as a whole\n")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
        moved = target.exists()
        if moved:
            os.replace(target, old)
        try:
            os.replace(tmp, target)
        except OSError:
            if moved:                    # put the earlier results back
                os.replace(old, target)
            raise
    except OSError as exc:
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def atomic_path(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; move it onto ``target`` only on success.

    Readers of ``target`` see the old file or the complete new one, never a partial write.
    """
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=parent)
    except OSError as exc:
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from None
    os.close(fd)
    tmp_path = Path(tmp)
    # mkstemp creates the file private (0600); give it the permissions a new file gets
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except OSError as exc:
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()


def write_text(target: str | Path, text: str) -> None:
    """Write ``text`` to ``target`` atomically (UTF-8)."""
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_bytes(target: str | Path, data: bytes) -> None:
    """Write ``data`` to ``target`` atomically."""
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)
