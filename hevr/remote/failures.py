"""What went wrong with an exchange with ``hevr serve``, as a typed :class:`hevr.RemoteError`.

:func:`refusal` turns an HTTP error status (and the server's problem document, parsed as data)
into :class:`~hevr.RemoteBusyError` (429, 503), :class:`~hevr.RemoteUnauthorisedError` (401,
403: says ``set HEVR_TOKEN`` / ``pass token=`` when none was sent),
:class:`~hevr.RemoteNotFoundError` (404), :class:`~hevr.RemoteRefusedError` (400, 405, 413, 415,
422) or a plain :class:`~hevr.RemoteError` (a server failure). :func:`transport_failure` turns a
failure without an answer into :class:`~hevr.RemoteTimeoutError` or
:class:`~hevr.RemoteConnectError`; for a TLS failure it says ``pass --cafile`` (a certificate
not trusted) or which scheme to use (``http://`` to a TLS port, ``https://`` to a plain one: a
short probe of the port tells). :func:`retry_after` and :func:`retry_wait`: the bounded retry's
waits. :func:`check_answer`: a JSON answer checked by its model of :mod:`hevr.remote.schema` (the
one definition of the protocol's documents, answers too), a :class:`~hevr.RemoteAnswerError`
naming the field otherwise.
"""

from __future__ import annotations

import email.utils
import secrets
import socket
import ssl
import time
from typing import Any
from urllib.parse import urlsplit

import httpx

from ..errors import (
    ParameterError,
    RemoteAnswerError,
    RemoteBusyError,
    RemoteConnectError,
    RemoteError,
    RemoteNotFoundError,
    RemoteRefusedError,
    RemoteTimeoutError,
    RemoteUnauthorisedError,
)
from .schema import check

__all__ = ["BUSY", "check_answer", "problem_text", "refusal", "retry_after", "retry_wait", "transport_failure"]

BUSY = (429, 503)  # the statuses retried: the server did not do the work (or gave up on it)
MAX_WAIT = 86400.0
_TOKEN_HINT = "set HEVR_TOKEN for hevr render --server, or pass token= to hevr.connect"
_CAFILE_HINT = "pass --cafile PEM (hevr.connect(..., cafile=PEM)) with the CA that signed the server's certificate"


def retry_after(value: Any, now: float | None = None) -> float | None:
    """Seconds a ``Retry-After`` header asks to wait: delay-seconds or an HTTP date (RFC 9110
    §10.2.3); None when absent or unreadable; at least 0, at most a day.

    >>> retry_after("3"), retry_after(None), retry_after("soon"), retry_after("-1")
    (3.0, None, None, None)
    >>> retry_after("Sun, 06 Nov 1994 08:49:37 GMT", now=784111767.0)
    10.0
    >>> retry_after("Sun, 06 Nov 1994 08:49:37 GMT", now=784111787.0)
    0.0
    """
    if not isinstance(value, str) or not value.strip() or len(value) > 64:
        return None
    text = value.strip()
    if text.isascii() and text.isdigit():
        return min(float(text), MAX_WAIT)
    try:
        when = email.utils.parsedate_to_datetime(text)
    except (TypeError, ValueError, IndexError):
        return None
    if when is None or when.tzinfo is None:
        return None
    return min(max(when.timestamp() - (time.time() if now is None else now), 0.0), MAX_WAIT)


def retry_wait(attempt: int, asked: float | None, jitter: float | None = None) -> float:
    """The wait before retry ``attempt`` (0, 1, …): what the server ``asked`` (Retry-After) plus
    up to 20 % (never earlier than asked), else 0.5 s, 1 s, 2 s, … × 0.5-1.5; at most a day.

    >>> retry_wait(0, 1.0, jitter=0.5), retry_wait(0, None, jitter=0.5), retry_wait(2, None, jitter=1.0)
    (1.1, 0.5, 3.0)
    """
    u = secrets.randbelow(2**53) / 2**53 if jitter is None else jitter  # the project's one source of randomness
    if asked is not None:
        return min(asked * (1.0 + 0.2 * u), MAX_WAIT)
    return min(0.5 * 2.0**attempt * (0.5 + u), MAX_WAIT)


def check_answer(model: Any, doc: Any, url: str, what: str) -> Any:
    """``doc`` (parsed JSON from the server at ``url``) validated by ``model``, a model of
    :mod:`hevr.remote.schema`; a :class:`hevr.RemoteAnswerError` naming the field otherwise.

    >>> from hevr.remote.schema import Aggregate
    >>> check_answer(Aggregate, {"aggregate": "42"}, "http://s", "the verification answer").aggregate
    '42'
    >>> check_answer(Aggregate, {"aggregate": "-5"}, "http://s", "the answer")
    Traceback (most recent call last):
    ...
    hevr.errors.RemoteAnswerError: server http://s: the answer: aggregate: expected a string matching ^[0-9]+$, got '-5'
    """
    try:
        return check(model, doc, what)
    except ParameterError as exc:
        text = str(exc)
        raise RemoteAnswerError(f"server {url}: {text if text.startswith(what) else f'{what}: {text}'}") from None


def problem_text(doc: Any) -> str:
    """What a problem document says, as one printable line: its title and detail (each at most 500
    characters), or that there was none; anything else in it is ignored (it is the server's data).

    >>> problem_text({"title": "bad request", "detail": "step: expected a number", "status": 400})
    'bad request; step: expected a number'
    >>> problem_text({"title": "x\\ny", "detail": 5}), problem_text(None)
    ('x?y', 'no problem document')
    """
    detail = title = None
    if isinstance(doc, dict):
        detail = doc.get("detail") if isinstance(doc.get("detail"), str) else None
        title = doc.get("title") if isinstance(doc.get("title"), str) else None
    text = "; ".join(x[:500] for x in (title, detail) if x) or "no problem document"
    return "".join(c if c.isprintable() else "?" for c in text)


def refusal(
    url: str, what: str, status: int, doc: Any, headers: Any, token_sent: bool, tries: int = 1, waited: float = 0.0
) -> RemoteError:
    """The typed error of an HTTP error ``status`` (module docstring); ``doc`` the problem
    document (or None), ``tries`` and ``waited`` what the bounded retry did before it."""
    problem = doc if isinstance(doc, dict) else None
    base = f"server {url}: {what}: HTTP {status}: {problem_text(doc)}"
    if status in BUSY:
        asked = retry_after(headers.get("retry-after") if headers is not None else None)
        after = f"; the server asks to retry after {asked:g} s" if asked is not None else ""
        tried = f" (busy through {tries} tries over {waited:.1f} s)" if tries > 1 else ""
        return RemoteBusyError(
            f"{base}{after}{tried}: busy, retry later", status=status, problem=problem, retry_after=asked
        )
    if status in (401, 403):
        hint = (
            f"no token was sent: {_TOKEN_HINT}"
            if not token_sent
            else "the token was not accepted: check HEVR_TOKEN / token= (expected a token this server's operator gave)"
        )
        return RemoteUnauthorisedError(f"{base} ({hint})", status=status, problem=problem)
    if status == 404:
        return RemoteNotFoundError(
            f"{base} (no store served under that name or id, or not to this token)", status=status, problem=problem
        )
    if status in (400, 405, 413, 415, 422):
        return RemoteRefusedError(base, status=status, problem=problem)
    return RemoteError(base, status=status, problem=problem)


def transport_failure(
    url: str, what: str, exc: BaseException, *, expired: bool, timeout: float, connect_timeout: float
) -> RemoteError:
    """The typed error of an exchange that got no valid HTTP answer (module docstring)."""
    where = f"server {url}: {what}"
    text = "".join(c if c.isprintable() else "?" for c in str(exc)[:200])
    if isinstance(exc, httpx.ConnectTimeout) and not expired:
        return RemoteTimeoutError(
            f"{where}: timeout: expected a connection within {connect_timeout:g} s, got none "
            "(is the server up and reachable? connect_timeout / --connect-timeout)"
        )
    if expired or isinstance(exc, httpx.TimeoutException):
        return RemoteTimeoutError(
            f"{where}: timeout: expected an answer within {timeout:g} s, got none (the "
            "server may be busy, slow or gone; the key holder's decryption is not counted; a "
            "larger timeout / --timeout may do)"
        )
    parts = urlsplit(url)
    host, port = parts.hostname or "", parts.port or (443 if parts.scheme == "https" else 80)
    probe = min(connect_timeout, 3.0)
    if parts.scheme == "https" and ("CERTIFICATE_VERIFY_FAILED" in text or "certificate verify failed" in text):
        return RemoteConnectError(f"{where}: TLS: the server's certificate is not trusted ({text}): {_CAFILE_HINT}")
    if (
        parts.scheme == "https"
        and isinstance(exc, httpx.ConnectError)
        and "SSL" in text
        and _speaks_http(host, port, probe)
    ):
        return RemoteConnectError(
            f"{where}: TLS failed ({text}): the server speaks plain HTTP on port {port}: use "
            f"http://{parts.netloc} (or serve TLS: hevr serve --tls-cert/--tls-key)"
        )
    if (
        parts.scheme == "http"
        and isinstance(exc, (httpx.ReadError, httpx.RemoteProtocolError))
        and _speaks_tls(host, port, probe)
    ):
        return RemoteConnectError(
            f"{where}: the server closed the connection without an HTTP answer: it speaks TLS "
            f"on port {port}: use https://{parts.netloc}"
        )
    kind = type(exc).__name__
    if isinstance(exc, httpx.ConnectError):
        return RemoteConnectError(f"{where}: ConnectError: {text} (is the server up at this address?)")
    if isinstance(exc, (httpx.RemoteProtocolError, httpx.ReadError, httpx.WriteError)):
        return RemoteConnectError(f"{where}: {kind}: {text} (the connection failed before a whole answer came)")
    return RemoteError(f"{where}: {kind}: {text}")


def _speaks_tls(host: str, port: int, timeout: float) -> bool:
    """Whether ``host:port`` completes a TLS handshake (its certificate unchecked: only the scheme is asked)."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock, ctx.wrap_socket(sock):
            return True
    except (OSError, ValueError):
        return False


def _speaks_http(host: str, port: int, timeout: float) -> bool:
    """Whether ``host:port`` answers a plain HTTP request with an HTTP status line."""
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            sock.sendall(f"HEAD / HTTP/1.0\r\nHost: {host}\r\n\r\n".encode("ascii", "replace"))
            return sock.recv(5) == b"HTTP/"
    except (OSError, ValueError):
        return False
