"""Writing outputs atomically, and never over one of the inputs."""

from __future__ import annotations

import contextlib
import glob
import hashlib
import os
import re
import shutil
import signal
import string
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from odocal import cancel
from odocal.errors import OutputError, shown


@contextlib.contextmanager
def _committing() -> Iterator[None]:
    """The moment a finished output replaces an earlier one: a run asked to stop (Ctrl-C, even
    one some library swallowed: :mod:`odocal.cancel`) stops here, before anything is replaced,
    and Ctrl-C is held back while the rename (or the two renames of a folder) happen, so that
    an interrupt never lands between them (the earlier folder moved aside, the new one not yet
    in its place)."""
    held = threading.current_thread() is threading.main_thread()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if held else None
    try:
        cancel.check()
        yield
    finally:
        if previous is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


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


#: The marker's first line; each later line is ``sha256sum``'s: the SHA-256 of a file odocal
#: wrote, two spaces, its path in the folder (``sha256sum -c .odocal-results`` checks them).
MARKER_HEAD = ("# written by odocal as a whole, replaced as a whole; it wrote these files "
               "(SHA-256, path):\n")


def _marker(target: Path) -> dict[str, str | None] | None:
    """What the marker in ``target`` says odocal wrote there: path -> SHA-256, or path -> None
    where an older odocal's marker listed names alone (``- NAME``); None where it cannot be
    read (then nothing in the folder is odocal's for sure)."""
    try:
        text = (target / RESULTS_MARKER).read_text(encoding="utf-8", errors="surrogateescape")
    except OSError:
        return None
    listed: dict[str, str | None] = dict(_parse_manifest(text))
    old = {line[2:]: None for line in text.splitlines() if line.startswith("- ")}
    if not listed and not old:
        return dict.fromkeys(RESULTS_NAMES)        # the oldest marker: no list at all
    return {**old, **listed}


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
    """OutputError unless ``target`` is absent, empty, or a results folder odocal wrote whose
    files nobody changed since (their SHA-256 in its marker); single files odocal wrote into it
    (listed with their SHA-256 in :data:`OUTPUTS_MANIFEST`: a simulated drive) are odocal's
    too."""
    if not target.exists():
        return
    if not target.is_dir():
        raise OutputError(f"output '{target}' exists and is not a folder")
    foreign, changed = _not_odocals(target)
    for found, why in ((foreign, "which odocal did not write"),
                       (changed, "changed since odocal wrote it")):
        if found:
            more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
            raise OutputError(f"output folder '{shown(target)}' holds '{shown(found[0])}'{more}, "
                              f"{why}: odocal replaces the folder whole, so move it out or "
                              "choose another folder")


def _not_odocals(target: Path) -> tuple[list[str], list[str]]:
    """The paths in ``target`` odocal did not write, and those it wrote that changed since."""
    names = {p.name for p in target.iterdir()}
    manifest = _read_manifest(target) if OUTPUTS_MANIFEST in names else {}
    ours = {RESULTS_MARKER, OUTPUTS_MANIFEST}
    foreign: list[str] = []
    changed: list[str] = []

    def judge(rel: str, digest: str | None) -> None:
        try:
            if digest is not None and _sha256(target / rel) != digest:
                changed.append(rel)
        except OSError:
            foreign.append(rel)

    if RESULTS_MARKER not in names:
        # a folder from before the marker: odocal's names at its top (or its single files)
        for name in sorted(names - ours):
            if name in manifest:
                judge(name, manifest[name])
            elif name not in RESULTS_NAMES:
                foreign.append(name)
        return foreign, changed
    marker = _marker(target)
    if marker is None:
        return sorted(names - {RESULTS_MARKER}) or [RESULTS_MARKER], changed
    for rel in _entries(target):                 # every file, at any depth, must be odocal's
        path = target / rel
        if rel in ours or (path.is_dir() and not path.is_symlink()):
            continue                             # (a folder: its files decide)
        if rel in marker and not (path.is_symlink() and marker[rel] is not None):
            judge(rel, marker[rel])
        elif "/" not in rel and rel in manifest and not path.is_symlink():
            judge(rel, manifest[rel])
        else:
            foreign.append(rel)
    return foreign, changed


@contextlib.contextmanager
def results_folder(target: str | Path) -> Iterator[Path]:
    """Yield a new temporary folder beside ``target``; on success it replaces ``target`` whole.

    A failed run leaves ``target`` as it was; a finished one leaves no file of an earlier run.
    An existing ``target`` must be empty, hold the marker odocal leaves, or hold only what odocal
    writes: odocal never deletes a folder with anything of the user's in it.
    """
    target = _followed(Path(target))          # a link to the folder stays a link
    check_replaceable(target)
    parent = target.parent if str(target.parent) else Path(".")
    remove_leftovers(target)
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=_temporary(target), suffix=".part",
                                    dir=parent))
    except OSError as exc:
        raise OutputError(f"cannot create the output folder '{target}': "
                          f"{exc.strerror or exc}") from exc
    old = tmp.with_suffix(".old")
    try:
        yield tmp
        files = [rel for rel in _entries(tmp) if (tmp / rel).is_file()]
        (tmp / RESULTS_MARKER).write_text(
            MARKER_HEAD + "".join(_manifest_line(_sha256(tmp / rel), rel) for rel in files),
            encoding="utf-8", errors="surrogateescape")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
        with _committing():
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
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from exc
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def new_folder(target: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``target`` (which must be absent or an empty folder);
    on success it becomes ``target``. A failed or interrupted run leaves no half-written
    folder (and ``target`` as it was)."""
    target = Path(target)
    parent = target.parent if str(target.parent) else Path(".")
    remove_leftovers(target)
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=_temporary(target), suffix=".part", dir=parent))
    except OSError as exc:
        raise OutputError(f"cannot create the folder '{shown(target)}': "
                          f"{exc.strerror or exc}") from exc
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
        with _committing():
            if target.is_dir() and not any(target.iterdir()):
                target.rmdir()
            os.rename(tmp, target)
    except OSError as exc:
        raise OutputError(f"cannot write '{shown(target)}': {exc.strerror or exc}") from exc
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


#: Lists the single files odocal wrote in a folder, in ``sha256sum``'s format (the SHA-256 of
#: the content, two spaces, the name): a later run replaces a file only where this line still
#: matches its content (``sha256sum -c .odocal-outputs`` checks them by hand).
OUTPUTS_MANIFEST = ".odocal-outputs"


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _manifest_line(digest: str, name: str) -> str:
    """One line as ``sha256sum`` writes it (a name with a newline or a backslash escaped)."""
    if "\\" in name or "\n" in name:
        return "\\" + digest + "  " + name.replace("\\", "\\\\").replace("\n", "\\n") + "\n"
    return f"{digest}  {name}\n"


def _read_manifest(folder: Path) -> dict[str, str]:
    """Name -> SHA-256 of the files odocal recorded writing in ``folder``."""
    try:
        text = (folder / OUTPUTS_MANIFEST).read_text(encoding="utf-8", errors="surrogateescape")
    except OSError:
        return {}
    return _parse_manifest(text)


def _parse_manifest(text: str) -> dict[str, str]:
    """``sha256sum``'s lines (other lines ignored) as name -> SHA-256."""
    out: dict[str, str] = {}
    for line in text.split("\n"):
        escaped = line.startswith("\\")
        digest, sep, name = line[1 if escaped else 0:].partition("  ")
        if not sep or len(digest) != 64 or not all(c in string.hexdigits for c in digest):
            continue
        if escaped:
            name = re.sub(r"\\(.)", lambda m: "\n" if m.group(1) == "n" else m.group(1), name)
        out[name] = digest
    return out


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """An exclusive lock on ``folder`` (its manifest's writers take turns)."""
    try:
        import fcntl
    except ImportError:                      # pragma: no cover - not on POSIX
        yield
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)                         # closing releases the lock


def _record(target: Path, digest: str) -> None:
    """Note in the folder's manifest that odocal wrote ``target`` with this content (entries
    of files that are gone are dropped)."""
    folder = target.parent
    with _locked(folder):
        entries = _read_manifest(folder)
        entries[target.name] = digest
        lines = [_manifest_line(d, n) for n, d in sorted(entries.items())
                 if n == target.name or (folder / n).exists()]
        manifest = folder / OUTPUTS_MANIFEST
        tmp = folder / f".{OUTPUTS_MANIFEST}.{os.getpid()}.part"
        tmp.write_text("".join(lines), encoding="utf-8", errors="surrogateescape")
        os.replace(tmp, manifest)


def _followed(target: Path) -> Path:
    """``target``, or the path a symbolic link there points to (the link stays a link)."""
    return target.resolve() if target.is_symlink() else target


def check_output_file(target: str | Path) -> None:
    """OutputError now, before any computation, unless ``target`` may be written: absent, or a
    file odocal wrote there whose content nobody changed since (its manifest line,
    :data:`OUTPUTS_MANIFEST`). odocal replaces only what it wrote."""
    given = Path(target)
    target = _followed(given)
    check_writable(target)
    if not target.exists():
        return
    if target.is_dir():
        raise OutputError(f"output '{shown(given)}' is a folder: name a file in it")
    if not target.is_file():
        raise OutputError(f"output '{shown(given)}' exists and is not a regular file")
    recorded = _read_manifest(target.parent).get(target.name)
    try:
        same = recorded is not None and recorded == _sha256(target)
    except OSError as exc:
        raise OutputError(f"cannot read '{shown(given)}': {exc.strerror or exc}") from exc
    if not same:
        why = "changed since odocal wrote it" if recorded else "odocal did not write it"
        raise OutputError(f"output '{shown(given)}' exists and {why}: odocal replaces only "
                          "files it wrote, so choose another name or move it out of the way")


@contextlib.contextmanager
def atomic_path(target: str | Path, *, owned: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; move it onto ``target`` only on success.

    Readers of ``target`` see the old file or the complete new one, never a partial write.
    ``owned``: ``target`` is a file of the user's folder (a command's ``--out``): it may
    replace only a file odocal wrote (:func:`check_output_file`), a link there is followed, and
    the folder's manifest records what was written.
    """
    target = Path(target)
    if owned:
        check_output_file(target)
        target = _followed(target)
    parent = target.parent if str(target.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        remove_leftovers(target)
        fd, tmp = tempfile.mkstemp(prefix=_temporary(target), suffix=".part",
                                   dir=parent)
    except OSError as exc:
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from exc
    os.close(fd)
    tmp_path = Path(tmp)
    # mkstemp creates the file private (0600); give it the permissions a new file gets
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)
    try:
        yield tmp_path
        digest = _sha256(tmp_path) if owned else ""
        with _committing():
            os.replace(tmp_path, target)
            if owned:
                _record(target, digest)
    except OSError as exc:
        raise OutputError(f"cannot write '{target}': {exc.strerror or exc}") from exc
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()


def write_text(target: str | Path, text: str, *, owned: bool = False) -> None:
    """Write ``text`` to ``target`` atomically (UTF-8); ``owned``: see :func:`atomic_path`."""
    with atomic_path(target, owned=owned) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_bytes(target: str | Path, data: bytes) -> None:
    """Write ``data`` to ``target`` atomically."""
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)
