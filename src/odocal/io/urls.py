"""URLs as text: which ones odocal reads, how a catalog's entry resolves against the catalog's
URL, and how a URL is shown and stored (no credentials, no query). Nothing here opens anything:
the transfer is :mod:`odocal.io.remote`'s.

``s3://BUCKET/KEY``, ``gs://BUCKET/KEY``, ``az://CONTAINER/BLOB`` (or ``abfs://``,
``abfss://``), ``http(s)://HOST/PATH`` and ``file:///PATH``. A URL that carries a password
(``https://user:secret@host/...``) is refused; a URL's query string (a pre-signed URL's
signature and token) is accepted and used, but never shown or stored: :func:`redact` strips
user names, passwords, queries and fragments from every URL odocal prints or stores, and
:func:`clean` also removes the values of the credential variables from any text that came from
a store's client library (:mod:`odocal.redaction`).
"""

from __future__ import annotations

import posixpath
import re
import urllib.parse
from collections.abc import Mapping
from pathlib import Path

from odocal.errors import ConfigError, DataError, shown
from odocal.redaction import SECRET_VARIABLES, is_url, redact_text, redact_url

__all__ = ["SCHEMES", "SECRET_VARIABLES", "check_url", "clean", "is_remote", "is_url", "join",
           "local_path", "name_of", "redact", "scheme_of"]

#: URL scheme -> the package that opens it (None: built into fsspec)
SCHEMES: Mapping[str, str | None] = {
    "s3": "s3fs", "s3a": "s3fs", "gs": "gcsfs", "gcs": "gcsfs", "az": "adlfs", "abfs": "adlfs",
    "abfss": "adlfs", "http": "aiohttp", "https": "aiohttp", "file": None}

_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+)://")


def scheme_of(url: str) -> str:
    match = _URL.match(url)
    return match.group(1).lower() if match else ""


def redact(source: object) -> str:
    """``source`` as it may be shown or stored: a URL without user, password, query and
    fragment; a path as given, but for a query-like ``?name=value`` tail
    (:func:`odocal.redaction.redact_url`)."""
    return redact_url(source)


def clean(text: object) -> str:
    """Text from a store's client library, safe to show: URLs redacted, credential values
    (:data:`SECRET_VARIABLES`) replaced by ``***``, one line."""
    return " ".join(redact_text(text).split())


def check_url(url: str, what: str = "input") -> None:
    """ConfigError for a scheme odocal does not read or a URL that carries a password."""
    scheme = scheme_of(url)
    if scheme not in SCHEMES:
        raise ConfigError(f"{what} '{shown(redact(url))}': odocal reads "
                          f"{', '.join(s + '://' for s in SCHEMES)} URLs, not {scheme}://")
    try:
        netloc = urllib.parse.urlsplit(url).netloc
    except ValueError as exc:
        raise ConfigError(f"{what} '{shown(redact(url))}' is not a valid URL: {exc}") from exc
    if "@" in netloc and ":" in netloc.rpartition("@")[0]:
        raise ConfigError(f"{what} '{shown(redact(url))}' carries a password: give credentials "
                          "through the store's environment or profile (for HTTP: ~/.netrc), "
                          "never in the URL")
    if scheme != "file" and not netloc:
        raise ConfigError(f"{what} '{shown(redact(url))}' names no bucket or host")


def local_path(source: str | Path) -> Path | None:
    """The local path of a path or a ``file://`` URL; None for a remote URL."""
    if isinstance(source, Path) or not is_url(source):
        return Path(source)
    if scheme_of(source) == "file":
        return Path(urllib.parse.unquote(urllib.parse.urlsplit(source).path))
    return None


def is_remote(source: object) -> bool:
    return isinstance(source, str) and is_url(source) and scheme_of(source) != "file"


def join(base: str, relative: str) -> str:
    """``relative`` (a catalog's or mapping's entry) resolved against the URL ``base`` (the
    catalog's own URL): beside it, like a relative path beside a file. A URL stays as it is.
    The base's query (a pre-signed catalog's signature) is not carried over; the entry's own
    query (``car1/d.parquet?X-Amz-Signature=...``: a pre-signed object) is kept, as the query
    of the URL it resolves to (and so never shown)."""
    if is_url(relative):
        return relative
    parts = urllib.parse.urlsplit(base)
    rel, _, query = relative.replace("\\", "/").partition("?")
    rel = rel.partition("#")[0]
    path = rel if rel.startswith("/") else posixpath.join(posixpath.dirname(parts.path), rel)
    parts_out: list[str] = []
    for part in path.split("/"):
        if part == "..":
            if not parts_out:
                raise DataError(f"'{shown(relative)}' climbs above the root of "
                                f"'{shown(redact(base))}'")
            parts_out.pop()
        elif part not in ("", "."):
            parts_out.append(part)
    norm = "/" + "/".join(parts_out)
    return urllib.parse.urlunsplit((parts.scheme, parts.netloc, urllib.parse.quote(
        urllib.parse.unquote(norm), safe="/~!$&'()*+,;=:@%"), query.partition("#")[0], ""))


def name_of(source: str | Path) -> str:
    """The last part of a path or URL (``drive.parquet``)."""
    if isinstance(source, str) and is_url(source):
        return posixpath.basename(urllib.parse.unquote(
            urllib.parse.urlsplit(source).path).rstrip("/"))
    return Path(source).name
