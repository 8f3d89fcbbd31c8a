"""Writing outputs atomically, and never over one of the inputs."""

from __future__ import annotations

import contextlib
import glob
import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from odocal.errors import OutputError, shown


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def refuse_inputs(output: str | Path, inputs: Iterable[str | Path | None], *,
                  folder: bool = False) -> None:
    """Raise OutputError if writing ``output`` could change one of the ``inputs``, or could not
    be done at all (:func:`check_writable`).

    Paths are compared resolved (symbolic links followed) and by identity (a hard link is the
    same file). A ``folder`` output is replaced as a whole, so no input may lie inside it.
    """
    check_writable(output)
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
    "robot_localization", "trace.csv", "alarms.json", "trajectories"})


def _written_by_odocal(target: Path, names: set[str]) -> set[str]:
    """The names in ``target`` odocal wrote: those its marker lists (a folder from before the
    marker listed them: the names odocal writes)."""
    if RESULTS_MARKER not in names:
        return set(RESULTS_NAMES)
    try:
        lines = (target / RESULTS_MARKER).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return {RESULTS_MARKER}
    listed = {line[2:] for line in lines if line.startswith("- ")}
    return (listed or set(RESULTS_NAMES)) | {RESULTS_MARKER}


def _entries(folder: Path) -> list[str]:
    """Every file and folder under ``folder``, as sorted relative POSIX paths."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def _temporary(target: Path) -> str:
    """The prefix of ``target``'s temporary siblings: they carry the writer's process id, so a
    later run can tell a dead run's leftovers from a live run's work."""
    return f".{target.name}.{os.getpid()}."


def remove_leftovers(target: Path) -> None:
    """Remove the temporary siblings of ``target`` that a killed run left (their process is
    gone); a live run's are left alone."""
    parent = target.parent if str(target.parent) else Path(".")
    try:
        siblings = list(parent.glob(f".{glob.escape(target.name)}.*"))
    except OSError:
        return
    for path in siblings:
        rest = path.name[len(target.name) + 2:]
        pid, _, tail = rest.partition(".")
        if not pid.isdigit() or not (tail.endswith(".part") or tail.endswith(".old")):
            continue
        try:
            os.kill(int(pid), 0)
            continue                            # its writer still runs
        except ProcessLookupError:
            pass
        except OSError:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                path.unlink()


def file_name(name: str) -> str:
    """A file-system-safe name for ``name`` (a vehicle, a log), distinct for distinct names:
    one that needs cleaning gets a short hash of the original (``car/1`` -> ``car_1-5c6f...``),
    so it never lands on the file of a name that was already clean (``car_1``)."""
    clean = "".join(c if c.isalnum() or c in "-_." else "_" for c in name).lstrip(".")[:80]
    if clean == name and clean:
        return clean
    digest = hashlib.sha256(name.encode("utf-8", "surrogatepass")).hexdigest()[:10]
    return f"{clean or '_'}-{digest}"


#: Marks a folder ``odocal fleet calibrate --out`` writes (updated in place, run after run).
FLEET_MARKER = ".odocal-fleet"


def check_fleet_folder(target: Path) -> None:
    """OutputError unless ``target`` is absent, empty, or a fleet folder odocal wrote."""
    if not target.exists():
        return
    if not target.is_dir():
        raise OutputError(f"output '{shown(target)}' exists and is not a folder")
    names = sorted(p.name for p in target.iterdir())
    if names and FLEET_MARKER not in names:
        raise OutputError(f"output folder '{shown(target)}' holds '{shown(names[0])}', and "
                          "odocal did not write that folder: choose a new or an empty folder")


def check_writable(target: str | Path) -> None:
    """OutputError now, before any computation, if ``target`` could not be written later: its
    name too long for the file system, a file where a folder must be, no permission."""
    target = Path(target)
    ancestor = target.parent if str(target.parent) else Path(".")
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"cannot write '{shown(target)}': '{shown(ancestor)}' is a file, not "
                          "a folder")
    try:
        name_max = os.pathconf(ancestor, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    # the temporary sibling adds a dot, a random part and '.part'
    if len(os.fsencode(target.name)) + 20 > name_max:
        raise OutputError(f"cannot write '{shown(target)}': the name is longer than the file "
                          f"system allows ({name_max} bytes)")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write '{shown(target)}': no permission to write in "
                          f"'{shown(ancestor)}'")


def check_replaceable(target: Path) -> None:
    """OutputError unless ``target`` is absent, empty, or a results folder odocal wrote."""
    if not target.exists():
        return
    if not target.is_dir():
        raise OutputError(f"output '{target}' exists and is not a folder")
    names = {p.name for p in target.iterdir()}
    written = _written_by_odocal(target, names)
    if RESULTS_MARKER in names:      # every file and folder, at any depth, must be odocal's
        foreign = [e for e in _entries(target) if e not in written]
    else:
        foreign = sorted(names - written)
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise OutputError(f"output folder '{shown(target)}' holds '{shown(foreign[0])}'{more}, "
                          "which odocal did not write: odocal replaces the folder whole, so "
                          "move it out or choose another folder")


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
    remove_leftovers(target)
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=_temporary(target), suffix=".part",
                                    dir=parent))
    except OSError as exc:
        raise OutputError(f"cannot create the output folder '{target}': "
                          f"{exc.strerror or exc}") from None
    old = tmp.with_suffix(".old")
    try:
        yield tmp
        written = _entries(tmp)
        (tmp / RESULTS_MARKER).write_text(
            "written by odocal as a whole; replaced as a whole. It wrote:\n"
            + "".join(f"- {name}\n" for name in written), encoding="utf-8")
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
        remove_leftovers(target)
        fd, tmp = tempfile.mkstemp(prefix=_temporary(target), suffix=".part",
                                   dir=parent)
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
