"""Inputs named by URL: objects in S3 (and its compatibles), GCS, Azure Blob, behind HTTP(S).

Every place that takes a log, a catalog, a mapping or a settings file takes a URL as well as a
path: ``s3://BUCKET/KEY``, ``gs://BUCKET/KEY``, ``az://CONTAINER/BLOB`` (or ``abfs://``,
``abfss://``), ``http(s)://HOST/PATH`` and ``file:///PATH``, opened with fsspec (``pip install
'odocal[remote]'`` brings s3fs, gcsfs, adlfs and aiohttp).

Credentials and endpoints come only from each store's usual environment and profiles (for S3:
``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_SESSION_TOKEN``, ``AWS_ENDPOINT_URL``,
``AWS_PROFILE``; for HTTP: ``~/.netrc`` and the proxy variables). A URL that carries a password
(``https://user:secret@host/...``) is refused; a URL's query string (a pre-signed URL's
signature) is accepted but never shown: URLs as text (parsing, resolving a catalog's entries,
redaction for display) are :mod:`odocal.io.urls`'s; this module moves the bytes.

An object is read in one pass, in chunks (:data:`CHUNK_BYTES`), into a temporary file on the
reading machine (:func:`local_copy`), hashed on the way (SHA-256: the drive's identity, the same
as the same bytes on disk give); memory does not grow with the object. A transient failure (a
reset connection, a time-out, a 5xx answer) is retried from where the copy stopped, up to
:data:`ATTEMPTS` times. The object's version (S3's ETag or version id, HTTP's ETag or
Last-Modified and length) seen when the fleet was planned is pinned: an object that changed since,
or changes while it is read, is named, never half read. Streaming readers (``odocal replay``)
open the object itself (:func:`open_input`) and read it range by range (Parquet row groups).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import logging
import os
import posixpath
import shutil
import tempfile
import time
import tomllib
import urllib.parse
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from odocal.errors import (
    ConfigError,
    InputFileError,
    MissingDependencyError,
    OdocalError,
    OutputError,
    shown,
)
from odocal.io.urls import (  # noqa: F401 - the URL helpers, also named from here
    SCHEMES,
    SECRET_VARIABLES,
    check_url,
    clean,
    is_remote,
    is_url,
    join,
    local_path,
    name_of,
    redact,
    scheme_of,
)

log = logging.getLogger(__name__)

#: Bytes read per request while copying an object.
CHUNK_BYTES = 8 << 20
#: Tries of one request (the first and the retries) on a transient error.
ATTEMPTS = 4
#: Seconds to wait for a connection, and for each read, before the try counts as failed.
CONNECT_TIMEOUT_S = 10.0
READ_TIMEOUT_S = 60.0

#: Bytes this process has received from stores (for the fleet's figures; see bytes_read()).
_RECEIVED = [0]


def bytes_read() -> int:
    """Bytes of objects this process has read from stores so far."""
    return _RECEIVED[0]


# ----------------------------------------------------------------------- file systems

def _options(scheme: str) -> dict[str, Any]:
    """fsspec options: bounded time-outs and retries; credentials from the environment."""
    if scheme in ("s3", "s3a"):
        return {"skip_instance_cache": True, "config_kwargs": {
            "connect_timeout": CONNECT_TIMEOUT_S, "read_timeout": READ_TIMEOUT_S,
            "retries": {"max_attempts": 2, "mode": "standard"}}}
    if scheme in ("http", "https"):
        import aiohttp

        return {"skip_instance_cache": True, "client_kwargs": {
            "trust_env": True, "timeout": aiohttp.ClientTimeout(
                total=None, sock_connect=CONNECT_TIMEOUT_S, sock_read=READ_TIMEOUT_S)}}
    return {"skip_instance_cache": True}


_FILESYSTEMS: dict[tuple[int, str, str, str], Any] = {}
_STORE_VARIABLES = ("AWS_", "AZURE_", "GOOGLE_", "GCS", "HTTP_PROXY", "HTTPS_PROXY", "NO_PROXY",
                    "http_proxy", "https_proxy", "no_proxy", "NETRC")


def filesystem(url: str) -> tuple[Any, str]:
    """The fsspec file system for ``url`` (one per process, scheme and bucket) and the path
    within it."""
    check_url(url)
    scheme = scheme_of(url)
    package = SCHEMES[scheme]
    try:
        import fsspec
        import fsspec.core
        if package is not None:
            __import__(package)
    except ImportError as exc:
        raise MissingDependencyError(
            f"reading {scheme}:// URLs needs {package or 'fsspec'}: "
            "pip install 'odocal[remote]'") from exc
    netloc = urllib.parse.urlsplit(url).netloc
    # a new file system when the store's environment changed (credentials, endpoint, profile)
    environment = hashlib.sha256(repr(sorted(
        (k, v) for k, v in os.environ.items()
        if k.startswith(_STORE_VARIABLES))).encode()).hexdigest()
    key = (os.getpid(), scheme, netloc, environment)
    fs = _FILESYSTEMS.get(key)
    if fs is None:
        protocol = {"s3a": "s3", "gcs": "gs"}.get(scheme, scheme)
        fs = fsspec.filesystem(protocol, **_options(scheme))
        _FILESYSTEMS[key] = fs
    if scheme in ("http", "https"):
        return fs, url
    return fs, fsspec.core.strip_protocol(url) if scheme == "file" else fs._strip_protocol(url)


# ----------------------------------------------------------------------- errors

class RemoteError(InputFileError):
    """An object that cannot be read: missing, denied, unreachable, changed or cut short."""


def _status(exc: BaseException) -> int | None:
    for attr in ("status", "status_code", "code"):
        value = getattr(exc, attr, None)
        if isinstance(value, int):
            return value
    response = getattr(exc, "response", None)
    if isinstance(response, dict):
        meta = response.get("ResponseMetadata", {})
        if isinstance(meta.get("HTTPStatusCode"), int):
            return int(meta["HTTPStatusCode"])
    return None


def _unreachable(exc: BaseException) -> bool:
    names = {c.__name__ for c in type(exc).__mro__}
    if names & {"EndpointConnectionError", "ClientConnectorError", "ConnectTimeoutError",
                "ServerDisconnectedError", "ClientConnectionError", "ConnectionError",
                "gaierror", "ClientOSError", "ConnectTimeout"}:
        return True
    return isinstance(exc, OSError) and exc.errno in (errno.ECONNREFUSED, errno.EHOSTUNREACH,
                                                      errno.ENETUNREACH, errno.ECONNRESET)


def _chain(exc: BaseException) -> Iterator[BaseException]:
    seen: set[int] = set()
    item: BaseException | None = exc
    while item is not None and id(item) not in seen:
        seen.add(id(item))
        yield item
        item = item.__cause__ or item.__context__


def explain(exc: BaseException, url: str, what: str) -> RemoteError:
    """One line that names the object and says what went wrong (no secret in it)."""
    where = f"{what} '{shown(redact(url))}'"
    host = urllib.parse.urlsplit(url).netloc.rpartition("@")[2]
    chain = list(_chain(exc))
    status = next((s for s in (_status(e) for e in chain) if s is not None), None)
    scheme = scheme_of(url)
    hint = {"s3": "AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY or AWS_PROFILE",
            "s3a": "AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY or AWS_PROFILE",
            "gs": "GOOGLE_APPLICATION_CREDENTIALS or gcloud's login",
            "gcs": "GOOGLE_APPLICATION_CREDENTIALS or gcloud's login",
            "http": "~/.netrc", "https": "~/.netrc"}.get(scheme, "the store's credentials")
    # fsspec's HTTP file system calls every failure "not found": the cause says what it was
    if _is_changed(exc):
        text = f"{where} changed while it was read: not used; run again"
    elif any(_unreachable(e) or isinstance(e, TimeoutError) for e in chain):
        endpoint = f"the server {shown(host)}" if scheme in ("http", "https") \
            else "the store's endpoint"
        cause = next(e for e in chain if _unreachable(e) or isinstance(e, TimeoutError))
        text = f"{where}: {endpoint} cannot be reached ({_first(cause)})"
    elif status in (401, 403):
        text = f"{where}: access denied (check the credentials: {hint})"
    elif status == 404:
        text = f"{where} does not exist"
    elif status is not None and status >= 400:
        text = f"{where} cannot be read: the server answered {status}"
    elif any(isinstance(e, PermissionError) for e in chain):
        text = f"{where}: access denied (check the credentials: {hint})"
    elif any(isinstance(e, FileNotFoundError) for e in chain):
        text = f"{where} does not exist"
    else:
        text = f"{where} cannot be read: {_first(exc)}"
    return RemoteError(clean(text))


def _first(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return clean(f"{type(exc).__name__}: {text[0]}" if text and text[0] else type(exc).__name__)


def _is_transient(exc: BaseException) -> bool:
    chain = list(_chain(exc))
    if any(isinstance(e, OdocalError) for e in chain):
        return False
    status = next((s for s in (_status(e) for e in chain) if s is not None), None)
    if status is not None:
        return status >= 500 or status in (408, 429)
    if any(isinstance(e, FileNotFoundError | PermissionError) for e in chain[:1]) \
            and len(chain) == 1:
        return False
    names = {c.__name__ for e in chain for c in type(e).__mro__}
    return bool(names & {"ClientPayloadError", "ServerDisconnectedError", "ReadTimeoutError",
                         "ResponseStreamingError", "IncompleteReadError", "ClientOSError",
                         "TimeoutError", "ConnectionResetError", "ProtocolError"})


def _retry(call: Any, url: str, what: str) -> Any:
    """``call()`` with up to :data:`ATTEMPTS` tries on transient errors."""
    for attempt in range(1, ATTEMPTS + 1):
        try:
            return call()
        except OdocalError:
            raise
        except Exception as exc:
            if attempt == ATTEMPTS or not _is_transient(exc):
                raise explain(exc, url, what) from exc
            log.info("%s: %s; trying again", redact(url), _first(exc))
            time.sleep(0.2 * 4 ** (attempt - 1))
    raise AssertionError("unreachable")  # pragma: no cover


# ----------------------------------------------------------------------- objects

@dataclass(frozen=True)
class ObjectInfo:
    """What the store says of an object (or of a folder: a prefix and what lies under it).

    url : as given (may hold a query); size : bytes (a folder: in all); etag, version,
    modified : the store's words for this version of it, as far as it has them
    """

    url: str
    size: int
    etag: str | None = None
    version: str | None = None
    modified: str | None = None
    folder: bool = False
    listing: str | None = None           # a folder: the hash of its files' names, sizes, etags

    def fingerprint(self) -> str:
        """This version of this object at this URL (not its content: another URL of the same
        object has another fingerprint)."""
        text = "\0".join([redact(self.url), str(self.size), self.etag or "",
                          self.version or "", self.modified or "", self.listing or ""])
        return hashlib.sha256(text.encode()).hexdigest()

    def pin(self) -> dict[str, Any]:
        return {"size": self.size, "etag": self.etag, "version": self.version,
                "modified": self.modified}


def _info_of(url: str, raw: Mapping[str, Any]) -> ObjectInfo:
    etag = raw.get("ETag") or raw.get("etag") or raw.get("md5Hash")
    version = raw.get("VersionId") or raw.get("generation") or raw.get("version_id")
    modified = raw.get("LastModified") or raw.get("Last-Modified") or raw.get("mtime") \
        or raw.get("last_modified") or raw.get("updated")
    return ObjectInfo(url=url, size=int(raw.get("size") or 0),
                      etag=str(etag) if etag else None,
                      version=str(version) if version and version != "null" else None,
                      modified=str(modified) if modified else None)


def stat(url: str, what: str = "input") -> ObjectInfo:
    """The object (or folder) at ``url``; a :class:`RemoteError` that names it when it is
    missing, denied or unreachable."""
    fs, path = filesystem(url)
    raw = _retry(lambda: fs.info(path), url, what)
    if raw.get("type") == "directory":
        files = _retry(lambda: fs.find(path, detail=True), url, what)
        digest = hashlib.sha256()
        total = 0
        for name in sorted(files):
            item = files[name]
            rel = name[len(path.rstrip("/")) + 1:]
            info = _info_of(url, item)
            digest.update(f"{rel}\0{info.size}\0{info.etag or info.modified}\n".encode())
            total += info.size
        if not files:
            raise RemoteError(f"{what} '{shown(redact(url))}' is an empty folder")
        return ObjectInfo(url=url, size=total, folder=True, listing="dir:" + digest.hexdigest())
    info = _info_of(url, raw)
    if scheme_of(url) in ("http", "https") and "size" not in raw:
        raise RemoteError(f"{what} '{shown(redact(url))}': the server does not say how long "
                          "it is (no Content-Length): odocal cannot tell a whole read from a cut "
                          "one")
    return info


def _changed(url: str, what: str, pin: Mapping[str, Any] | None, now: ObjectInfo) -> None:
    if not pin:
        return
    for key in ("etag", "version", "size", "modified"):
        planned, current = pin.get(key), getattr(now, key)
        if planned is not None and current is not None and str(planned) != str(current):
            raise RemoteError(f"{what} '{shown(redact(url))}' changed since odocal first looked "
                              f"at it (its {key} is now {shown(clean(current), 60)}, was "
                              f"{shown(clean(planned), 60)}): not used; run again")


def _copy_file(url: str, dest: Path, what: str, pin: Mapping[str, Any] | None,
               before: ObjectInfo | None = None) -> tuple[int, str]:
    """Copy one object into ``dest`` in chunks; resumed where it stopped on a transient
    error. Returns the bytes copied and their SHA-256. ``before``: what the store said of it
    just now. An HTTP server that answers no byte ranges is read in one stream from the start
    (a failure then starts the copy again)."""
    fs, path = filesystem(url)
    before = before or stat(url, what)
    _changed(url, what, pin, before)
    expected = before.size
    done = 0
    digest = hashlib.sha256()
    streamed = False
    with open(dest, "wb") as out:
        attempt = 0
        while True:
            try:
                with (fs.open(path, "rb", block_size=0) if streamed else
                      fs.open(path, "rb", block_size=CHUNK_BYTES, cache_type="none")) as src:
                    if done:
                        src.seek(done)
                    while True:
                        block = src.read(CHUNK_BYTES)
                        if not block:
                            break
                        try:
                            out.write(block)
                        except OSError as exc:        # this machine's disk, not the store
                            raise OutputError(
                                f"cannot copy {what} '{shown(redact(url))}' into the "
                                f"temporary folder '{dest.parent.parent}': "
                                f"{exc.strerror or exc} (TMPDIR chooses the folder)") from exc
                        digest.update(block)
                        done += len(block)
                        _RECEIVED[0] += len(block)
                break
            except OdocalError:
                raise
            except Exception as exc:
                if not streamed and _no_ranges(exc):
                    streamed, done, digest = True, 0, hashlib.sha256()
                    out.seek(0)
                    out.truncate()
                    log.info("%s: the server answers no byte ranges; read as one stream",
                             redact(url))
                    continue
                if streamed:                          # (no resuming a stream: from the start)
                    done, digest = 0, hashlib.sha256()
                    out.seek(0)
                    out.truncate()
                _give_up_or_wait(exc, url, what, attempt := attempt + 1)
                continue
            break
    after = stat(url, what)
    _changed(url, what, before.pin(), after)
    if done != expected:
        raise RemoteError(f"{what} '{shown(redact(url))}' is cut short: {done} of its "
                          f"{expected} bytes arrived")
    return done, digest.hexdigest()


def _give_up_or_wait(exc: Exception, url: str, what: str, attempt: int) -> None:
    """After a failed read (try number ``attempt``): the RemoteError that explains it when it
    is not transient or the tries are spent, else a pause before the next try."""
    if isinstance(exc, FileNotFoundError | PermissionError) or _is_changed(exc):
        raise explain(exc, url, what) from exc
    passing = _is_transient(exc) or (isinstance(exc, OSError) and _unreachable(exc))
    if attempt >= ATTEMPTS or not passing:
        raise explain(exc, url, what) from exc
    log.info("%s: read stopped; going on", redact(url))
    time.sleep(0.2 * 4 ** (attempt - 1))


def _no_ranges(exc: BaseException) -> bool:
    """fsspec's word for an HTTP server that answered a byte range with the whole file."""
    return any(isinstance(e, ValueError) and "range requests" in str(e) for e in _chain(exc))


def _is_changed(exc: BaseException) -> bool:
    return any(type(e).__name__ == "FileExpired" or _status(e) == 412
               or "pre-condition" in str(e).lower() for e in _chain(exc))


def list_folder(url: str, what: str = "folder") -> list[str]:
    """The relative names of the files under a folder (prefix) of an object store."""
    if scheme_of(url) in ("http", "https"):
        raise ConfigError(f"{what} '{shown(redact(url))}': an HTTP server lists no folders; "
                          "name the files (a catalog)")
    fs, root = filesystem(url)
    files = _retry(lambda: fs.find(root, detail=False), url, what)
    prefix = root.rstrip("/") + "/"
    return sorted(f[len(prefix):] for f in files if f.startswith(prefix))


@dataclass(frozen=True)
class LocalCopy:
    """An object copied to this machine: where, its SHA-256 (a folder: the listing's hash),
    how many bytes crossed the network."""

    path: Path
    sha256: str
    bytes_read: int


@contextlib.contextmanager
def local_copy(url: str, what: str = "input", *, pin: Mapping[str, Any] | None = None
               ) -> Iterator[LocalCopy]:
    """The object (or folder) at ``url`` as a temporary local file (folder) with the same
    name, removed afterwards. ``pin``: what :meth:`ObjectInfo.pin` said when the fleet was
    planned; an object that no longer matches it is not read."""
    folder = Path(tempfile.mkdtemp(prefix="odocal-remote-"))
    try:
        name = name_of(url) or "object"
        dest = folder / name
        info = stat(url, what)
        if info.folder:
            if pin:
                _changed(url, what, {"size": pin.get("size")}, info)
            fs, root = filesystem(url)
            files = _retry(lambda: fs.find(root, detail=False), url, what)
            total = 0
            prefix = root.rstrip("/") + "/"
            for item in sorted(files):
                rel = item[len(prefix):] if item.startswith(prefix) else posixpath.basename(item)
                target = dest / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                sub = url.rstrip("/") + "/" + urllib.parse.quote(rel)
                total += _copy_file(sub, target, what, None)[0]
            assert info.listing is not None
            yield LocalCopy(dest, info.listing, total)
            return
        size, digest = _copy_file(url, dest, what, pin, info)
        yield LocalCopy(dest, digest, size)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@contextlib.contextmanager
def open_input(url: str, what: str = "input") -> Iterator[Any]:
    """The object at ``url`` opened for random access (range reads): for streaming readers
    that need not hold it whole (Parquet row groups, CSV blocks)."""
    fs, path = filesystem(url)
    info = stat(url, what)
    if info.folder:
        raise RemoteError(f"{what} '{shown(redact(url))}' is a folder, not a file")
    handle = _retry(lambda: fs.open(path, "rb", block_size=CHUNK_BYTES), url, what)
    if not _serves_ranges(handle, info, url, what):
        # an HTTP server that answers no byte ranges: the object is copied here in one
        # stream (to disk, not to memory) and read from the copy
        with contextlib.suppress(Exception):
            handle.close()
        log.info("%s: the server answers no byte ranges; copied here first", redact(url))
        with local_copy(url, what, pin=info.pin()) as copy, open(copy.path, "rb") as local:
            yield local
        return
    try:
        yield _Guarded(handle, url, what)
    finally:
        with contextlib.suppress(Exception):
            handle.close()
    _changed(url, what, info.pin(), stat(url, what))


def _serves_ranges(handle: Any, info: ObjectInfo, url: str, what: str) -> bool:
    """Whether a range read of ``handle`` works: asked of an HTTP(S) object's last byte (an
    object store always answers ranges)."""
    if scheme_of(url) not in ("http", "https") or info.size < 2:
        return True
    try:
        handle.seek(info.size - 1)
        _retry(lambda: handle.read(1), url, what)
        handle.seek(0)
    except RemoteError as exc:
        if _no_ranges(exc):
            return False
        raise
    return True


class _Guarded:
    """A remote file whose errors name the object (and keep no secret)."""

    def __init__(self, handle: Any, url: str, what: str) -> None:
        self._handle, self._url, self._what = handle, url, what

    def _call(self, name: str, *args: Any) -> Any:
        method = getattr(self._handle, name)
        try:
            return _retry(lambda: method(*args), self._url, self._what)
        except RemoteError:
            raise
        except Exception as exc:
            raise explain(exc, self._url, self._what) from exc

    def read(self, size: int = -1) -> bytes:
        data = bytes(self._call("read", size))
        _RECEIVED[0] += len(data)
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        return int(self._handle.seek(offset, whence))

    def tell(self) -> int:
        return int(self._handle.tell())

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True

    def close(self) -> None:
        self._handle.close()

    @property
    def closed(self) -> bool:
        return bool(self._handle.closed)

    @property
    def size(self) -> int:
        return int(self._handle.size)


def read_text(source: str | Path, what: str) -> str:
    """A small text file (settings, mapping) from a path or URL."""
    local = local_path(source)
    if local is not None:
        from odocal.errors import input_file

        return input_file(local, what).read_text(encoding="utf-8")
    with local_copy(str(source), what) as copy:
        try:
            return copy.path.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{what} '{shown(redact(source))}' is not UTF-8 text") from exc


def read_toml(source: str | Path, what: str) -> dict[str, Any]:
    """A TOML file from a URL (settings, mapping), its errors naming the URL."""
    text = read_text(source, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} '{shown(redact(source))}' is not valid TOML: {exc}") from exc
    except RecursionError as exc:
        raise ConfigError(f"{what} '{shown(redact(source))}' nests tables or arrays too deeply "
                          "to read") from exc


def relabelled(exc: OdocalError, local: Path, url: str) -> OdocalError:
    """``exc`` (raised reading the local copy) with the copy's path replaced by the URL."""
    text = str(exc).replace(str(local), redact(url)).replace(str(local.parent), redact(url))
    new = type(exc)(clean(text))
    new.__cause__ = exc
    return new


@contextlib.contextmanager
def readable(source: str | Path, what: str = "input", *,
             pin: Mapping[str, Any] | None = None) -> Iterator[tuple[Path, str | None]]:
    """A local path for ``source``: itself, or a temporary copy of a remote object, with the
    SHA-256 the copy had (None for a local path). Errors raised inside that name the copy are
    given the URL's name."""
    local = local_path(source)
    if local is not None:
        yield local, None
        return
    url = str(source)
    with local_copy(url, what, pin=pin) as copy:
        try:
            yield copy.path, copy.sha256
        except OdocalError as exc:
            raise relabelled(exc, copy.path, url) from exc


@contextlib.contextmanager
def local_inputs(sources: Any, mapping: str | Path | None = None
                 ) -> Iterator[tuple[list[Any], Any]]:
    """Raw logs (and a mapping file) for a reader that needs local files: each remote one
    copied here for the duration (streamed, see :func:`local_copy`), the rest as given."""
    with contextlib.ExitStack() as stack:
        local = [stack.enter_context(readable(s, "log"))[0] if is_remote(s) else s
                 for s in sources]
        if mapping is not None and is_remote(mapping):
            mapping = stack.enter_context(mapping_here(str(mapping)))
        yield local, mapping


@contextlib.contextmanager
def mapping_here(mapping: str) -> Iterator[Path]:
    """A remote mapping file copied here, with the files it names copied beside it from beside
    it (the ``table`` format's files)."""
    from odocal.io.mapping import mapping_files

    with readable(mapping, "mapping file") as (local, _):
        for named in mapping_files(local):
            rel = named.relative_to(local.parent).as_posix()
            target = local.parent / rel
            try:
                with local_copy(join(mapping, rel), "mapping's file") as copy:
                    target.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(copy.path, target)
            except RemoteError as exc:
                if "does not exist" not in str(exc):   # else it may be among the sources
                    raise
        yield local
