"""One bounded HTTP exchange with ``hevr serve``: :class:`Connection`, the wire under
:class:`hevr.remote.client.Server`.

Everything the server sends is untrusted data, read with bounds:
* every answer's size is bounded *before* it is read — by what the request implies for an image
  (H·W·K·record width, :func:`image_limit`), by :data:`~hevr.remote.protocol.MAX_BODY`-sized
  limits for JSON — and the bytes are counted as they arrive (a ``Content-Length`` that says more
  is refused unread);
* the raw bytes are read, never decompressed: an answer with a ``Content-Encoding`` is refused
  (a compression bomb cannot expand here);
* redirects are not followed (a server cannot send the token, or the request, elsewhere);
* one deadline (``timeout`` seconds) bounds a whole exchange — connecting (within
  ``connect_timeout``), the status line, the headers, the body, the waits before retries — at the
  socket (:mod:`hevr.remote.transport`), so a server dribbling bytes, even of its headers, cannot
  hold the caller longer; the key holder's checks and decryption are not counted;
* a busy answer (429, 503) is retried at most ``retries`` times, after the ``Retry-After`` it
  asks for, within the deadline; nothing else is retried;
* JSON is parsed strictly (:func:`~hevr.remote.protocol.parse_json`), images by the ``.hevr``
  parser, and nothing is ever unpickled.

Every failure — unreachable, TLS, timeout, a problem document, a malformed answer — is a
:class:`hevr.RemoteError` naming the server and what was expected, typed so that an application
can tell them apart (:mod:`hevr.remote.failures`: busy, timed out, unreachable, unauthorised, not
found, refused, and :class:`hevr.RemoteAnswerError` for an answer the checks refused); ``httpx``,
``ssl`` and ``json`` exceptions never reach the caller.
"""

from __future__ import annotations

import contextlib
import json
import logging
import ssl
import time
from collections.abc import Iterator
from typing import Any, Literal, overload
from urllib.parse import urlsplit

import httpx

from ..errors import HevrError, ParameterError, RemoteAnswerError, RemoteBusyError, RemoteError
from .failures import problem_text, refusal, retry_wait, transport_failure
from .protocol import END, MAX_BODY, PROBLEM_MEDIA, UNITS_MEDIA, parse_json, unpack_head
from .transport import Deadline, DeadlineTransport

log = logging.getLogger(__name__)

__all__ = ["Connection"]


def _raw(r: httpx.Response) -> Iterator[bytes]:
    """The answer's raw bytes as they come (an injected transport's answer may be read already)."""
    return iter((r.content,)) if r.is_stream_consumed else r.iter_raw()


def _seconds(name: str, value: Any) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0 < value <= 86400:
        raise ParameterError(f"{name}: expected seconds in (0, 86400], got {value!r}")
    return float(value)


class Connection:
    """HTTP requests to ``hevr serve`` with bounds (module docstring); :class:`hevr.remote.client.Server`
    adds the API. Thread-safe for requests; close it (or use it as a context manager) to release its
    connections."""

    def __init__(
        self,
        url: str,
        token: str | None = None,
        cafile: str | None = None,
        timeout: float = 60.0,
        *,
        connect_timeout: float = 10.0,
        retries: int = 2,
        transport: Any = None,
    ) -> None:
        if not isinstance(url, str):
            raise ParameterError(f"url: expected 'http(s)://host:port', got {type(url).__name__}")
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname or parts.query or parts.fragment:
            raise ParameterError(f"url: expected 'http(s)://host[:port]', got {url[:100]!r}")
        if parts.username or parts.password:
            raise ParameterError("url: expected no user or password in the URL (pass token=)")
        if token is not None and (
            not isinstance(token, str)
            or not token
            or not token.isprintable()
            or len(token) > 4096
            or any(c.isspace() for c in token)
        ):
            raise ParameterError("token: expected the server's bearer token (printable, no spaces)")
        self.timeout = _seconds("timeout", timeout)
        self.connect_timeout = _seconds("connect_timeout", connect_timeout)
        if not isinstance(retries, int) or isinstance(retries, bool) or not 0 <= retries <= 10:
            raise ParameterError(f"retries: expected an int in [0, 10], got {retries!r}")
        if transport is not None and not isinstance(transport, httpx.BaseTransport):
            raise ParameterError(f"transport: expected an httpx.BaseTransport, got {type(transport).__name__}")
        if cafile is not None and parts.scheme != "https":
            raise ParameterError("cafile: expected an https:// url with a CA file, got an http:// url")
        if transport is None:
            try:
                context = (
                    ssl.create_default_context(cafile=str(cafile))
                    if cafile is not None
                    else httpx.create_ssl_context(trust_env=False)
                )
            except (OSError, ssl.SSLError) as exc:
                raise ParameterError(
                    f"cafile: expected a PEM CA bundle, got {str(cafile)[:100]!r} ({type(exc).__name__})"
                ) from None
            transport = DeadlineTransport(context)
        self.url = url.rstrip("/")
        self.retries = retries
        self._token = token
        headers = {"Accept-Encoding": "identity", "User-Agent": "hevr"}
        self._http = httpx.Client(
            base_url=self.url,
            headers=headers,
            transport=transport,
            follow_redirects=False,
            timeout=httpx.Timeout(self.timeout, connect=self.connect_timeout),
            trust_env=False,
        )

    def __repr__(self) -> str:  # never the token
        return f"Server({self.url!r})"

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Connection:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- requests -------------------------------------------------------------------
    def _headers(self, accept: str) -> dict[str, str]:
        h = {"Accept": f"{accept}, {PROBLEM_MEDIA}"}
        if self._token is not None:
            h["Authorization"] = f"Bearer {self._token}"
        return h

    def request(
        self,
        method: str,
        path: str,
        *,
        body: dict[str, Any] | None = None,
        accept: str = "application/json",
        limit: int = MAX_BODY,
    ) -> tuple[bytes, dict[str, str]]:
        """One request; the answer's bytes (at most ``limit``) and headers, or a RemoteError."""
        (answer,) = list(self._exchange(method, path, body, accept, limit, frames=False))
        return answer

    def frames(self, path: str, body: dict[str, Any], limit: int) -> Iterator[tuple[int, bytes | dict[str, Any]]]:
        """The frames (index, bytes) of a units stream, each as it arrives, then (END, the end
        frame's JSON object, a dict), checked here: a problem there is a RemoteError. The deadline counts
        only the time spent waiting here, not the caller's between frames."""
        for index, data in self._exchange("POST", path, body, UNITS_MEDIA, limit, frames=True):
            if index == END:
                status = self._json(data, "the stream's end")
                if status.get("ok") is not True:
                    raise self._problem(200, status, "a finished stream")
                yield END, status
                return
            yield index, data
        raise RemoteAnswerError(f"server {self.url}: expected the stream's end frame, got the end of the answer")

    @overload
    def _exchange(
        self, method: str, path: str, body: dict[str, Any] | None, accept: str, limit: int, frames: Literal[False]
    ) -> Iterator[tuple[bytes, dict[str, str]]]: ...

    @overload
    def _exchange(
        self, method: str, path: str, body: dict[str, Any] | None, accept: str, limit: int, frames: Literal[True]
    ) -> Iterator[tuple[int, bytes]]: ...

    def _exchange(
        self, method: str, path: str, body: dict[str, Any] | None, accept: str, limit: int, frames: bool
    ) -> Iterator[tuple[bytes, dict[str, str]] | tuple[int, bytes]]:
        """The answer's (bytes, headers), or with ``frames`` the units stream's frames (index, bytes)."""
        content = None if body is None else json.dumps(body, separators=(",", ":")).encode()
        headers = self._headers(accept)
        if content is not None:
            headers["Content-Type"] = "application/json"
        clock = Deadline(self.timeout)
        what = f"{method} {path}"
        try:
            with self._answer(method, path, content, headers, clock, what) as r:
                status = r.status_code
                media = r.headers.get("content-type", "").split(";")[0].strip().lower()
                if media != accept:
                    raise RemoteAnswerError(
                        f"server {self.url}: {what}: expected {accept}, got {media[:60]!r}", status=status
                    )
                declared = r.headers.get("content-length")
                if declared is not None and (not declared.isdigit() or int(declared) > limit):
                    raise RemoteAnswerError(
                        f"server {self.url}: {what}: expected at most {limit} bytes, got "
                        f"Content-Length {declared[:20]} (refused unread)",
                        status=status,
                    )
                if not frames:
                    yield self._read(r, limit, clock, what), dict(r.headers)
                    return
                yield from self._frames(r, limit, clock, what)
        except RemoteError:
            raise
        except (httpx.HTTPError, ssl.SSLError, OSError, ValueError) as exc:
            raise transport_failure(
                self.url, what, exc, expired=clock.expired(), timeout=self.timeout, connect_timeout=self.connect_timeout
            ) from None

    @contextlib.contextmanager
    def _answer(
        self, method: str, path: str, content: bytes | None, headers: dict[str, str], clock: Deadline, what: str
    ) -> Iterator[httpx.Response]:
        """The open response of status 200, its head checked; an error status is a typed error, a
        busy one (429, 503) retried at most ``retries`` times within the deadline."""
        for attempt in range(self.retries + 1):
            with contextlib.ExitStack() as stack:
                with clock.running():
                    r = stack.enter_context(self._http.stream(method, path, content=content, headers=headers))
                status = r.status_code
                encoding = r.headers.get("content-encoding", "identity").strip().lower()
                if encoding not in ("", "identity"):
                    raise RemoteAnswerError(
                        f"server {self.url}: {what}: expected an answer without "
                        f"Content-Encoding, got {encoding[:40]!r} (refused unread)",
                        status=status,
                    )
                if 300 <= status < 400:
                    location = r.headers.get("location", "?")[:100]
                    hint = (
                        f" (use {self.url.replace('http://', 'https://', 1)})"
                        if self.url.startswith("http://") and location.startswith("https://")
                        else ""
                    )
                    raise RemoteError(
                        f"server {self.url}: {what}: expected an answer, got a redirect (HTTP {status}) "
                        f"to {location!r}, not followed{hint}",
                        status=status,
                    )
                if status == 200:
                    yield r
                    return
                err = self._refusal(r, clock, what, attempt + 1)
            if not isinstance(err, RemoteBusyError) or attempt >= self.retries:
                raise err
            wait = retry_wait(attempt, err.retry_after)
            if wait >= clock.remaining():  # not worth waiting to time out: say busy now
                raise err
            log.info("server %s: %s: HTTP %s (busy), retrying in %.1f s", self.url, what, status, wait)
            with clock.running():
                time.sleep(wait)
        raise AssertionError("unreachable")  # pragma: no cover

    def _refusal(self, r: httpx.Response, clock: Deadline, what: str, tries: int) -> RemoteError:
        media = r.headers.get("content-type", "").split(";")[0].strip().lower()
        raw = self._read(r, MAX_BODY, clock, what)
        doc = None
        if media in (PROBLEM_MEDIA, "application/json"):
            try:
                doc = parse_json(raw, "problem")
            except HevrError:
                doc = None
        return refusal(self.url, what, r.status_code, doc, r.headers, self._token is not None, tries, clock.spent())

    def _late(self, what: str) -> RemoteError:
        return transport_failure(
            self.url,
            what,
            httpx.ReadTimeout("deadline"),
            expired=True,
            timeout=self.timeout,
            connect_timeout=self.connect_timeout,
        )

    def _read(self, r: httpx.Response, limit: int, clock: Deadline, what: str) -> bytes:
        buf = bytearray()
        with clock.running():
            for chunk in _raw(r):
                buf += chunk
                if len(buf) > limit:
                    raise RemoteAnswerError(
                        f"server {self.url}: {what}: expected at most {limit} bytes, got more "
                        "(the rest refused unread)",
                        status=r.status_code,
                    )
                if clock.expired():
                    raise self._late(what)
        return bytes(buf)

    def _frames(self, r: httpx.Response, limit: int, clock: Deadline, what: str) -> Iterator[tuple[int, bytes]]:
        buf = bytearray()
        total = 0
        chunks = _raw(r)
        while True:
            with clock.running():
                chunk = next(chunks, None)
                if chunk is not None and clock.expired():
                    raise self._late(what)
            if chunk is None:
                break
            total += len(chunk)
            if total > limit:
                raise RemoteAnswerError(f"server {self.url}: {what}: expected at most {limit} bytes of units, got more")
            buf += chunk
            while len(buf) >= 8:
                index, length = unpack_head(bytes(buf[:8]))
                if length > limit:
                    raise RemoteAnswerError(f"server {self.url}: {what}: a frame of {length} bytes (at most {limit})")
                if len(buf) < 8 + length:
                    break
                data = bytes(buf[8 : 8 + length])
                del buf[: 8 + length]
                yield index, data
                if index == END:
                    if buf:
                        raise RemoteAnswerError(f"server {self.url}: {what}: expected nothing after the end frame")
                    return
        if buf:
            raise RemoteAnswerError(f"server {self.url}: {what}: the stream ended inside a frame (truncated)")

    def _json(self, raw: bytes, what: str, limit: int = MAX_BODY) -> dict[str, Any]:
        try:
            doc = parse_json(raw, what, limit)
        except HevrError as exc:
            raise RemoteAnswerError(f"server {self.url}: {exc}") from None
        if not isinstance(doc, dict):
            raise RemoteAnswerError(f"server {self.url}: {what}: expected a JSON object, got {type(doc).__name__}")
        return doc

    def _problem(self, status: int, doc: Any, what: str) -> RemoteError:
        return RemoteError(
            f"server {self.url}: {what}: HTTP {status}: {problem_text(doc)}",
            status=status,
            problem=doc if isinstance(doc, dict) else None,
        )
