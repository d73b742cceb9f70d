"""Deadlines for every byte of a request, and bounded connections: uvicorn's h11 protocol, guarded.

A stranger without a token must not be able to stall ``hevr serve`` by opening connections and
sending nothing, or a byte now and then (issue 48, item 1). :class:`GuardedH11Protocol` wraps
uvicorn's h11 protocol with these rules (the defaults of :class:`Deadlines`; each is a Dask config
key under ``hevr.serve``, e.g. ``DASK_HEVR__SERVE__HEAD_TIMEOUT=20``):

* **Idle** (``idle-timeout``, 5 s): a connection that sends nothing for 5 s, fresh or between two
  requests (keep-alive), is closed.
* **Head** (``head-timeout``, 10 s): a request's line and headers must be complete 10 s after the
  connection was made or the previous response was sent, however the bytes trickle in; else the
  connection is closed.
* **Body** (``body-timeout``, 10 s): the whole body must arrive within 10 s of the head (request
  bodies are at most 64 KiB: :data:`~hevr.remote.protocol.MAX_BODY`); else the connection is closed
  and the handler sees the client gone.
* **Send** (``send-timeout``, 30 s): a client that stops reading its answer (the transport's write
  buffer stays above its high-water mark) for 30 s is cut off.
* **TLS handshake** (``handshake-timeout``, 10 s; asyncio's default is 60 s). A TLS connection
  counts against the bounds below from its TCP accept (:func:`over_tls`), not from the end of its
  handshake, so connections that never finish one cannot exhaust the open files.
* **Connections** (``max-connections``, 1024, and ``per-address``, 64 from one client address: an
  IPv6 client's /64, :func:`address_group`): a new connection beyond either bound closes the oldest
  connection that is waiting for a request head (idle, dribbling one, or in its TLS handshake) —
  from the same address for the per-address bound; only when every such connection is inside a
  request is the new one refused. So a flood of idle connections costs its sender its oldest ones,
  and a client that sends its request at once still gets through. Renders are bounded by the app
  (``--max-concurrent``, each token's ``concurrent``), not here.
* **Answered early**: a request answered before its body came (a 401 before the body of a
  ``POST``) closes the connection once the answer is written; it is not left waiting for a body.
* **No upgrades**: a WebSocket upgrade request is served as a plain HTTP request (the protocol never
  hands its connection to another), so every connection leaves the bounds when it closes.

Why uvicorn with these rules, not another server (measured on loopback, 2026-11-28, 300
connections: 100 idle, 100 sending one head byte a second, 100 one body byte a second after a
valid head, 20-25 s): uvicorn 0.54 as configured before (``timeout_keep_alive=5``,
``limit_concurrency=256``) closed none of the idle or head-dribbling connections, and answered
every other request 503 while 256 were open; hypercorn 0.18 (``read_timeout=10``,
``keep_alive_timeout=5``) closed the idle and head-dribbling ones after 5 s but kept every body
dribbler open for the whole run (its read timeout restarts with each byte) and has no per-address
bound. A deadline per phase of the exchange, not per read, is what bounds a dribbler; it takes
these few hooks on uvicorn's protocol (``connection_made``, ``data_received``,
``on_response_complete``, ``pause_writing``), which h11's connection state makes exact. With this
protocol every one of 500 such connections is closed within its deadline while an authorised
render succeeds (tests/serve/test_deadlines.py; run with uvicorn 0.54 and 0.29, the oldest the
``serve`` extra allows). The h11 protocol serves whether or not httptools is installed.
"""

from __future__ import annotations

import asyncio
import logging
import ssl
import sys
import time
from asyncio.sslproto import SSLProtocol
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from .connections import Connections, Deadlines, address_group

log = logging.getLogger("hevr.serve")

# Deadlines, Connections and address_group are hevr.serve.connections', named here too (the protocol's bounds)
__all__ = ["Deadlines", "Connections", "GuardedH11Protocol", "address_group", "guarded_protocol", "over_tls"]


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline per phase and bounded connections (module docstring).
    Made per server by :func:`guarded_protocol`, which sets :attr:`registry`."""

    registry: Connections

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.limit_concurrency = None  # connections are bounded here; renders by the app
        self.ws_protocol_class = None  # never hand the connection to another protocol (module docstring)
        self.address = "?"
        self.handshake: _Handshake | None = None  # the TLS connection's entry until its handshake was done
        self.tls = False  # over TLS: a connection the guard closes is aborted (no close_notify is owed)
        self.phase: str | None = None  # "head", "body" or None (inside the app, or closed)
        self.since = 0.0
        self._deadline: Any = None
        self._stall: Any = None

    @property
    def waiting(self) -> bool:
        """Whether the connection waits for a request head (fresh, idle keep-alive or dribbling)."""
        return self.phase == "head"

    # asyncio.Protocol and uvicorn's hooks
    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        self.address = address_group(self.client[0]) if self.client else "?"
        if self.handshake is not None:  # its place in the bounds, taken at the TCP accept
            self.registry.remove(self.handshake)
            self.handshake = None
        self._enter()
        if not self.registry.admit(self):
            self._close(None)
            return
        # uvicorn's keep-alive timer, armed for a fresh connection too: the first byte cancels it
        self.timeout_keep_alive_task = self.loop.call_later(self.timeout_keep_alive, self.timeout_keep_alive_handler)

    def connection_lost(self, exc: Exception | None) -> None:
        self.registry.remove(self)
        self._cancel()
        self.phase = None
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._enter()

    def on_response_complete(self) -> None:
        if self.conn.their_state is h11.SEND_BODY and not self.transport.is_closing():
            self.transport.close()  # answered before its body came (a 401, a 413): read no more of it
        super().on_response_complete()  # arms the keep-alive timer (timeout_keep_alive_handler)
        if self.transport.is_closing():  # closed after this answer: its unsent bytes get the send deadline
            self._leave()
            if self.transport.get_write_buffer_size() and self._stall is None:
                self._stall = self.loop.call_later(self.registry.deadlines.send, self._expire, "send")
            return
        self._enter()

    def pause_writing(self) -> None:
        super().pause_writing()
        if self._stall is None:
            self._stall = self.loop.call_later(self.registry.deadlines.send, self._expire, "send")

    def resume_writing(self) -> None:
        super().resume_writing()
        if self._stall is not None:
            self._stall.cancel()
            self._stall = None

    def timeout_keep_alive_handler(self) -> None:
        self._idle()

    def handle_websocket_upgrade(self, event: Any) -> None:
        """Not reached (``ws_protocol_class`` is ``None``); should a uvicorn upgrade anyway, the
        request is answered 400 and the connection closed, never handed to another protocol."""
        self.registry.remove(self)
        self._cancel()
        self.phase = None
        self.send_400_response("hevr serve: expected an HTTP request, got a WebSocket upgrade")  # and closes

    def _unsupported_upgrade_warning(self) -> None:  # uvicorn's two WARNING lines for each: a stranger's log flood
        log.debug("%s: an upgrade request, served as plain HTTP", self.address)

    # the deadlines
    def _enter(self) -> None:
        """Start the phase h11's state of the client's side says (a head or a body to wait for)."""
        if self.transport is None or self.transport.is_closing():
            return
        state = self.conn.their_state
        phase = "head" if state is h11.IDLE else "body" if state is h11.SEND_BODY else None
        if phase == self.phase:
            return
        self._leave()
        self.phase, self.since = phase, time.monotonic()
        self.registry.mark(self, phase == "head")
        if phase is not None:
            seconds = self.registry.deadlines.head if phase == "head" else self.registry.deadlines.body
            self._deadline = self.loop.call_later(seconds, self._expire, phase)

    def _leave(self) -> None:
        """End the current phase (its deadline cancelled; no longer waiting for a head)."""
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        if self.phase == "head":
            self.registry.mark(self, False)
        self.phase = None

    def _idle(self) -> None:
        self.timeout_keep_alive_task = None
        if self.phase == "head" and self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            self._close("idle")

    def _expire(self, phase: str) -> None:
        if phase == "send":
            self._stall = None
        else:
            self._deadline = None
            if phase != self.phase:
                return
        if not self.transport.is_closing() or phase == "send":
            self._close(phase)

    def drop(self) -> None:
        """Close this connection now to make room for a new one (:meth:`Connections.admit`)."""
        self._close(None)

    def _close(self, why: str | None) -> None:
        if why is not None:
            self.registry.closed[why] += 1
            log.debug("%s: closed, %s deadline passed", self.address, why)
        self.registry.remove(self)
        self._cancel()
        self.phase = None
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.keep_alive = False
        if self.tls or self.transport.get_write_buffer_size() or why in ("send", "body"):
            # nothing polite to wait for: unsent bytes, a request cut short, or TLS, whose polite close
            # waits for the peer's close_notify with the socket open (30 s on 3.11, for ever on 3.10)
            self.transport.abort()
        else:
            self.transport.close()

    def _cancel(self) -> None:
        for name in ("_deadline", "_stall"):
            handle = getattr(self, name)
            if handle is not None:
                handle.cancel()
                setattr(self, name, None)
        self._unset_keepalive_if_required()


def guarded_protocol(deadlines: Deadlines) -> tuple[type[GuardedH11Protocol], Connections]:
    """A protocol class for one server (uvicorn's ``Config(http=...)``) and its connection registry."""
    registry = Connections(deadlines)
    return type("HevrH11Protocol", (GuardedH11Protocol,), {"registry": registry}), registry


class _Handshake(SSLProtocol):
    """A TLS connection from its TCP accept to the end of its handshake, in the bounds as a
    connection waiting for a head (the oldest is closed first to make room); asyncio's own TLS
    server calls the protocol only once the handshake is done (:func:`over_tls`)."""

    waiting = True

    def __init__(self, app: GuardedH11Protocol, context: ssl.SSLContext, seconds: float) -> None:
        # the close after an answer (a 401 before its body) waits for the peer's close_notify at most
        # as long as a handshake (asyncio's default: 30 s; 3.10 has no such bound)
        # typeshed says waiter: Future and ssl_handshake_timeout: int; asyncio takes None (no waiter) and
        # seconds as a float, as its own TLS servers pass them
        if sys.version_info >= (3, 11):
            t = seconds
            super().__init__(app.loop, app, context, None, True, ssl_handshake_timeout=t, ssl_shutdown_timeout=t)  # type: ignore[arg-type]
        else:  # pragma: no cover - Python 3.10
            super().__init__(app.loop, app, context, None, server_side=True, ssl_handshake_timeout=seconds)
        self.registry, self.address, self.refused = app.registry, "?", False
        self.raw: asyncio.Transport | None = None
        app.handshake, app.tls = self, True

    def connection_made(self, transport: Any) -> None:
        self.raw = transport
        peer = transport.get_extra_info("peername")
        self.address = address_group(peer[0]) if isinstance(peer, tuple) and peer else "?"
        if not self.registry.admit(self):
            self.refused = True
            transport.abort()
            return
        super().connection_made(transport)

    def connection_lost(self, exc: BaseException | None) -> None:
        self.registry.remove(self)
        if not self.refused:
            super().connection_lost(exc)

    def drop(self) -> None:
        """Close this connection now to make room for a new one (:meth:`Connections.admit`)."""
        self.registry.remove(self)
        if self.raw is not None:  # always: admitted in connection_made, which sets it
            self.raw.abort()


def over_tls(app: GuardedH11Protocol, context: ssl.SSLContext, seconds: float) -> SSLProtocol:
    """The protocol for a TLS connection to ``app`` (a server's ``loop.create_server(..., ssl=None)``
    factory returns it): the TLS handshake, with a deadline of ``seconds``, counted in ``app``'s
    bounds from the TCP accept; then ``app`` as over plain TCP. The same
    :class:`asyncio.sslproto.SSLProtocol` as asyncio's own TLS servers use."""
    return _Handshake(app, context, seconds)
