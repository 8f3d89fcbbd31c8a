"""What may be shown or stored of a text that may hold a secret: no URL's user name, password,
query or fragment, no query-like ``?name=value`` tail of a path, no credential variable's value.

Every message odocal prints passes through :func:`odocal.errors.shown`, which calls
:func:`redact_text`; every URL odocal shows or stores passes :func:`redact_url` (README, "Fleets
where the data lives"). A pre-signed URL's signature and token live in its query, so a query is
never shown, whatever its names; a relative catalog entry with a query, or a path that
carries one, loses it too.

A leaf module: nothing of odocal imported.
"""

from __future__ import annotations

import logging
import os
import re
import urllib.parse

#: Environment variables whose values are secrets: never in a message, a log line or a store.
SECRET_VARIABLES = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN",
                    "AWS_SECURITY_TOKEN", "AZURE_STORAGE_KEY", "AZURE_STORAGE_ACCOUNT_KEY",
                    "AZURE_STORAGE_SAS_TOKEN", "AZURE_STORAGE_CONNECTION_STRING",
                    "AZURE_CLIENT_SECRET", "GOOGLE_OAUTH_ACCESS_TOKEN")

_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]+)://")
#: A URL in free text: up to a space, a quote, an angle bracket or a closing parenthesis that
#: follows a non-URL character.
_URL_IN_TEXT = re.compile(r"\b[A-Za-z][A-Za-z0-9+.-]+://[^\s'\"<>`]+")
_KEY = r"[A-Za-z0-9_.~%+-]+"
#: A query after a path (or a name): ``?name=value`` pairs, as written or percent-encoded
#: (``%3F``, ``%3D``, ``%26``); the name may be empty (``?=x``) and a value runs to a space or
#: quote.
_QUERY = re.compile(rf"(?:\?|%3[Ff])(?:{_KEY})?(?:=|%3[Dd])[^\s'\"<>`]*")


def is_url(source: object) -> bool:
    """True for ``scheme://...`` (two or more letters: ``C:\\`` stays a path)."""
    return isinstance(source, str) and _URL.match(source) is not None


def redact_url(source: object) -> str:
    """``source`` as it may be shown or stored: a URL without user, password, query and
    fragment (nor a query percent-encoded into its path); anything else with any query-like
    ``?name=value`` tail removed."""
    text = str(source)
    if not is_url(text):
        return _QUERY.sub("", text)
    try:
        parts = urllib.parse.urlsplit(text)
    except ValueError:                      # (an unbalanced [ in the host)
        scheme, _, rest = text.partition("://")
        rest = rest.rpartition("@")[2] if "@" in rest.split("/", 1)[0] else rest
        return _QUERY.sub("", f"{scheme}://{rest.split('?', 1)[0].split('#', 1)[0]}")
    host = parts.netloc.rpartition("@")[2]
    return _QUERY.sub("", urllib.parse.urlunsplit((parts.scheme, host, parts.path, "", "")))


def redact_text(text: object) -> str:
    """Free text (a message, a log line, a value from a store's library) as it may be shown:
    each URL in it redacted (:func:`redact_url`), any other query-like tail removed, and the
    values of the credential variables (:data:`SECRET_VARIABLES`) replaced by ``***``."""
    out = str(text)
    if "://" in out:
        out = _URL_IN_TEXT.sub(lambda m: redact_url(m.group(0)), out)
    if "?" in out or "%3" in out:
        out = _QUERY.sub("", out)
    for name in SECRET_VARIABLES:
        value = os.environ.get(name)
        if value and len(value) >= 4 and value in out:
            out = out.replace(value, "***")
    return out


class Redacting(logging.Formatter):
    """A log formatter whose lines (a library's, at -v, included) pass :func:`redact_text`."""

    def __init__(self, inner: logging.Formatter | None = None) -> None:
        super().__init__()
        self.inner = inner or logging.Formatter()

    def format(self, record: logging.LogRecord) -> str:
        return redact_text(self.inner.format(record))
