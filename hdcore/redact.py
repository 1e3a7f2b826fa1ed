"""A location's printable form: the one place where a URL's secrets are taken out of what hd writes.

A dataset URL may carry secrets: a user name and password (``https://user:PASSWORD@host/d``), a
token given as the user name (``https://TOKEN@host/d``), or query-string values (a presigned URL's
``?X-Amz-Signature=...``, ``?token=...``). hd keeps such a URL in memory for the reads themselves
and writes only :func:`printable_location`'s form of it: in every record (config.json, checkpoints,
report.json, report.md, detect.json, the view page, the mark of an interrupted ``hd pull``), every
summary and ``--json`` record, and every error line. :func:`redact_urls` does the same to every URL
inside a free text (what a protocol library says, which may quote the URL whole), and the terminal
passes every line it prints through it (docs/reliability.md, "Secrets in URLs").
"""

from __future__ import annotations

import os
import re

# What stands for a secret taken out of a URL.
REDACTED = "***"
# A URL: a scheme (RFC 3986: a letter, then letters, digits, +, . or -), then ``://``.
_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")
# A quote inside a URL (RFC 3986 allows ``'`` in user information, path, query and fragment: a password
# or token may hold one), not one that closes a quoted URL: one followed by the end of the text, a space
# or other quotes, maybe after punctuation that ends a sentence (``'URL': not found``, ``('URL')``).
_QUOTE_INSIDE = r"'(?![.,;:)\]}>'\"]*(?:[\s\"<>`]|$))"
# A URL inside a text: a scheme not inside a word or path, then one or more ``/`` (a URL read as a path
# has lost one: ``http:/host``), its user information (up to its ``@``, quotes and all), then up to the
# first space, double quote, backquote, angle bracket or closing quote.
_URL_IN_TEXT = re.compile(
    r"(?<![A-Za-z0-9+.\-/])[A-Za-z][A-Za-z0-9+.-]*:/+"
    rf"(?:[^\s/?#@<>\"`]*@)?(?:[^\s'\"<>`]|{_QUOTE_INSIDE})+"
)
# hd choice: the shortest secret of a URL that :func:`redact_text` also looks for outside URLs, characters
# (a shorter query value, ``?v=2``, is a setting rather than a secret; replacing it would garble the text).
MIN_SECRET_CHARS = 6
# Punctuation that ends a sentence rather than a URL (``{url}: not found``, ``(url)``).
_TRAILING = ".,;:)]}"


def printable_location(location: str | os.PathLike[str]) -> str:
    """How hd writes a location: a local path unchanged (as a string); a URL with its user
    information (user name and password: either may be a token) replaced by ``***``, every query
    value replaced by ``***`` (its key kept: ``?X-Amz-Signature=***``; an item without ``=`` is
    taken as a value) and a fragment by ``***``. Scheme, host, port and path are kept.

    >>> printable_location("https://user:pw@host:8080/d?X-Amz-Signature=abc&v=2#frag")
    'https://***@host:8080/d?X-Amz-Signature=***&v=***#***'
    """
    text = os.fspath(location)
    if not _URL.match(text):
        return text
    scheme, user, host, path, query, fragment = _url_parts(text)
    out = f"{scheme}://{REDACTED + '@' if user is not None else ''}{host}{path}"
    if query is not None:
        out += "?" + "&".join(_redacted_item(item) for item in query.split("&"))
    if fragment is not None:
        out += "#" + (REDACTED if fragment else "")
    return out


def _url_parts(url: str) -> tuple[str, str | None, str, str, str | None, str | None]:
    """A URL's scheme, user information (None without ``@``), host (and port), path, query (None
    without ``?``) and fragment (None without ``#``), split as RFC 3986 splits them (no decoding)."""
    scheme, rest = url.split("://", 1)
    end = min((i for i in (rest.find(mark) for mark in "/?#") if i != -1), default=len(rest))
    authority, tail = rest[:end], rest[end:]
    user, at, host = authority.rpartition("@")
    tail, hash_mark, fragment = tail.partition("#")
    path, question, query = tail.partition("?")
    return scheme, user if at else None, host, path, query if question else None, fragment if hash_mark else None


def _redacted_item(item: str) -> str:
    """One ``key=value`` item of a query string with its value redacted (an empty item kept)."""
    if not item:
        return item
    key, equals, _ = item.partition("=")
    return f"{key}={REDACTED}" if equals else REDACTED


def redact_urls(text: str) -> str:
    """``text`` with every URL in it in its :func:`printable_location` form (punctuation that ends
    the sentence after a URL is left outside it; a URL that a path has made ``http:/host/d`` too)."""

    def one(match: re.Match[str]) -> str:
        url = match.group(0)
        kept = url.rstrip(_TRAILING)
        scheme, slashes, rest = re.split(r"(:/+)", kept, maxsplit=1)
        printable = printable_location(f"{scheme}://{rest}")  # as a URL, whatever its slashes
        return f"{scheme}{slashes}{printable.split('://', 1)[1]}{url[len(kept) :]}"

    return _URL_IN_TEXT.sub(one, text)


def secrets_of(url: str) -> list[str]:
    """The secrets :func:`printable_location` takes out of ``url`` (its user information, each part of
    it, its query values and fragment), longest first; none for a local path."""
    if not _URL.match(url):
        return []
    _, user, _, _, query, fragment = _url_parts(url)
    found = [user, *(user or "").split(":"), fragment]
    found += [item.partition("=")[2] if "=" in item else item for item in (query or "").split("&")]
    return sorted({s for s in found if s}, key=len, reverse=True)


def redact_text(text: str, url: str) -> str:
    """``text`` (what a library said about reading ``url``) with every URL in it in its printable form
    and every secret of ``url`` (:func:`secrets_of`) of at least ``MIN_SECRET_CHARS`` characters
    replaced by ``***`` wherever it appears."""
    text = redact_urls(text)
    for secret in secrets_of(url):
        if len(secret) >= MIN_SECRET_CHARS:
            text = text.replace(secret, REDACTED)
    return text


def is_redacted(location: str | os.PathLike[str]) -> bool:
    """True for a URL that :func:`printable_location` has taken secrets out of (a record's form of a URL
    that carried them): it cannot be read as written, since its secrets are not kept."""
    text = os.fspath(location)
    if not _URL.match(text):
        return False
    _, user, _, _, query, fragment = _url_parts(text)
    values = [item.partition("=")[2] if "=" in item else item for item in (query or "").split("&")]
    return user == REDACTED or fragment == REDACTED or REDACTED in values
