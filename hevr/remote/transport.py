"""One deadline for a whole exchange with ``hevr serve``: :class:`Deadline` and :class:`DeadlineTransport`.

httpx's timeouts are per operation (connect, each read, each write): a server that sends one
byte of its status line or headers a second never trips a read timeout, and the headers are read
inside httpx, out of reach of a check in the caller's loop. So the key holder's client
(:mod:`hevr.remote.client`) sends its requests through :class:`DeadlineTransport`, an httpx
transport over httpcore's connection pool whose network backend gives every socket operation at
most the time left of the exchange's :class:`Deadline` (and fails at once when none is left):
connecting, the TLS handshake, sending the request, and every read of the head and the body.
The deadline of the calling thread is the one that runs (:meth:`Deadline.running`): the time the
caller spends between the frames of a stream (the key holder decrypting units as they come) is
not counted, only the time spent waiting on the server.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpcore
import httpx

__all__ = ["Deadline", "DeadlineTransport", "current_deadline"]

_LOCAL = threading.local()
_MAP = (  # httpcore's errors as httpx's (the most specific first), as httpx's own transport maps them
    (httpcore.ConnectTimeout, httpx.ConnectTimeout),
    (httpcore.ReadTimeout, httpx.ReadTimeout),
    (httpcore.WriteTimeout, httpx.WriteTimeout),
    (httpcore.PoolTimeout, httpx.PoolTimeout),
    (httpcore.TimeoutException, httpx.TimeoutException),
    (httpcore.ConnectError, httpx.ConnectError),
    (httpcore.ReadError, httpx.ReadError),
    (httpcore.WriteError, httpx.WriteError),
    (httpcore.NetworkError, httpx.NetworkError),
    (httpcore.UnsupportedProtocol, httpx.UnsupportedProtocol),
    (httpcore.RemoteProtocolError, httpx.RemoteProtocolError),
    (httpcore.LocalProtocolError, httpx.LocalProtocolError),
    (httpcore.ProtocolError, httpx.ProtocolError),
)


class Deadline:
    """A budget of ``seconds`` of waiting on the server, spent only while :meth:`running`.

    >>> d = Deadline(2.0)
    >>> d.remaining() == 2.0 and not d.expired()
    True
    >>> with d.running():
    ...     current_deadline() is d
    True
    >>> current_deadline() is None and 0 < d.remaining() <= 2.0
    True
    """

    def __init__(self, seconds: float) -> None:
        self.seconds = float(seconds)
        self._spent = 0.0
        self._since: float | None = None

    def spent(self) -> float:
        """Seconds spent so far (the running stretch included)."""
        return self._spent + (time.monotonic() - self._since if self._since is not None else 0.0)

    def remaining(self) -> float:
        return self.seconds - self.spent()

    def expired(self) -> bool:
        return self.remaining() <= 0

    @contextlib.contextmanager
    def running(self) -> Iterator[Deadline]:
        """Count the time of the block, and make this the calling thread's deadline in it (the one
        :class:`DeadlineTransport`'s sockets obey)."""
        previous = getattr(_LOCAL, "deadline", None)
        _LOCAL.deadline = self
        outer = self._since is not None
        if not outer:
            self._since = time.monotonic()
        try:
            yield self
        finally:
            if not outer and self._since is not None:
                self._spent += time.monotonic() - self._since
                self._since = None
            _LOCAL.deadline = previous


def current_deadline() -> Deadline | None:
    """The calling thread's running :class:`Deadline` (None outside :meth:`Deadline.running`)."""
    return getattr(_LOCAL, "deadline", None)


def _clamp(timeout: float | None, timeout_error: type[Exception]) -> float | None:
    """``timeout`` shortened to the running deadline's time left; ``timeout_error`` when none is left."""
    deadline = current_deadline()
    if deadline is None:
        return timeout
    left = deadline.remaining()
    if left <= 0:
        raise timeout_error(f"the exchange's deadline of {deadline.seconds:g} s passed")
    left = max(left, 1e-3)  # a socket timeout of 0 would make the socket non-blocking
    return left if timeout is None else min(timeout, left)


class _Stream(httpcore.NetworkStream):
    """A connection whose every operation obeys the running deadline."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner

    def read(self, max_bytes: int, timeout: float | None = None) -> bytes:
        return self._inner.read(max_bytes, _clamp(timeout, httpcore.ReadTimeout))

    def write(self, buffer: bytes, timeout: float | None = None) -> None:
        self._inner.write(buffer, _clamp(timeout, httpcore.WriteTimeout))

    def close(self) -> None:
        self._inner.close()

    def start_tls(self, ssl_context: Any, server_hostname: str | None = None, timeout: float | None = None) -> _Stream:
        return _Stream(self._inner.start_tls(ssl_context, server_hostname, _clamp(timeout, httpcore.ConnectTimeout)))

    def get_extra_info(self, info: str) -> Any:
        return self._inner.get_extra_info(info)


class _Backend(httpcore.NetworkBackend):
    """httpcore's synchronous backend, its connections wrapped in :class:`_Stream`."""

    def __init__(self) -> None:
        self._inner = httpcore.SyncBackend()

    def connect_tcp(
        self,
        host: str,
        port: int,
        timeout: float | None = None,
        local_address: str | None = None,
        socket_options: Any = None,
    ) -> _Stream:
        return _Stream(
            self._inner.connect_tcp(host, port, _clamp(timeout, httpcore.ConnectTimeout), local_address, socket_options)
        )

    def connect_unix_socket(self, path: str, timeout: float | None = None, socket_options: Any = None) -> _Stream:
        return _Stream(self._inner.connect_unix_socket(path, _clamp(timeout, httpcore.ConnectTimeout), socket_options))

    def sleep(self, seconds: float) -> None:
        self._inner.sleep(seconds)


@contextlib.contextmanager
def _mapped() -> Iterator[None]:
    try:
        yield
    except Exception as exc:
        mapped = _httpx_error(exc)
        if mapped is exc:
            raise
        raise mapped from exc


def _httpx_error(exc: Exception) -> Exception:
    for core, ours in _MAP:
        if isinstance(exc, core):
            return ours(str(exc))
    return exc


class _Body(httpx.SyncByteStream):
    def __init__(self, stream: Any) -> None:
        self._stream = stream

    def __iter__(self) -> Iterator[bytes]:
        with _mapped():
            yield from self._stream

    def close(self) -> None:
        if hasattr(self._stream, "close"):
            self._stream.close()


class DeadlineTransport(httpx.BaseTransport):
    """An HTTP/1.1 transport (httpcore's pool) whose sockets obey the calling thread's running
    :class:`Deadline` (module docstring); ``ssl_context``: the TLS trust of ``https`` URLs."""

    def __init__(self, ssl_context: Any) -> None:
        self._pool = httpcore.ConnectionPool(
            ssl_context=ssl_context,
            max_connections=100,
            max_keepalive_connections=20,
            keepalive_expiry=5.0,
            http1=True,
            http2=False,
            network_backend=_Backend(),
        )

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        req = httpcore.Request(
            method=request.method,
            url=httpcore.URL(
                scheme=request.url.raw_scheme,
                host=request.url.raw_host,
                port=request.url.port,
                target=request.url.raw_path,
            ),
            headers=request.headers.raw,
            content=request.stream,
            extensions=request.extensions,
        )
        with _mapped():
            resp = self._pool.handle_request(req)
        return httpx.Response(
            status_code=resp.status, headers=resp.headers, stream=_Body(resp.stream), extensions=resp.extensions
        )

    def close(self) -> None:
        self._pool.close()
