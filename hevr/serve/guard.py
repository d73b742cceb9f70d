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
* **TLS handshake** (``handshake-timeout``, 10 s; asyncio's default is 60 s).
* **Connections** (``max-connections``, 1024, and ``per-address``, 64 from one client address):
  a new connection beyond either bound closes the oldest connection that is waiting for a request
  head (idle, or dribbling one) — from the same address for the per-address bound; only when every
  such connection is inside a request is the new one refused. So a flood of idle connections from
  one address (or all addresses) costs its sender its oldest ones, and a client that sends its
  request at once still gets through. Connections no longer count against a concurrency limit that
  answers 503: renders are bounded by the app (``--max-concurrent``, each token's ``concurrent``).

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

import logging
import time
from dataclasses import dataclass, fields
from typing import Any

import dask
import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from ..errors import ParameterError

log = logging.getLogger("hevr.serve")

__all__ = ["Deadlines", "Connections", "GuardedH11Protocol", "guarded_protocol"]

_KEYS = {"idle": "idle-timeout", "head": "head-timeout", "body": "body-timeout", "send": "send-timeout",
         "handshake": "handshake-timeout", "per_address": "per-address", "connections": "max-connections"}


@dataclass(frozen=True)
class Deadlines:
    """Seconds for each phase of a connection, and the bounds on connections (module docstring).

    >>> Deadlines().head, Deadlines(head=3).head, Deadlines().per_address
    (10.0, 3.0, 64)
    """

    idle: float = 5.0
    head: float = 10.0
    body: float = 10.0
    send: float = 30.0
    handshake: float = 10.0
    per_address: int = 64
    connections: int = 1024

    def __post_init__(self) -> None:
        for f in fields(self):
            value, key = getattr(self, f.name), f"hevr.serve.{_KEYS[f.name]}"
            if f.type == "int":
                if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 1_000_000:
                    raise ParameterError(f"{key}: expected a whole number from 1 to 1000000, got {value!r}")
            else:
                try:
                    seconds = float(value)
                except (TypeError, ValueError):
                    seconds = float("nan")
                if not 0.05 <= seconds <= 3600:  # NaN fails too
                    raise ParameterError(f"{key}: expected seconds from 0.05 to 3600, got {value!r}")
                object.__setattr__(self, f.name, seconds)

    @classmethod
    def from_config(cls) -> Deadlines:
        """The values of the ``hevr.serve.*`` Dask config keys (env ``DASK_HEVR__SERVE__…``), else the defaults."""
        given: dict[str, Any] = {}
        for name, key in _KEYS.items():
            value = dask.config.get(f"hevr.serve.{key}", None)
            if value is not None:
                given[name] = int(value) if isinstance(value, str) and name in ("per_address", "connections") \
                    and value.strip().isdigit() else value
        return cls(**given)


class Connections:
    """The open connections, per client address, in the order they began waiting for a head.

    :meth:`admit` keeps both bounds (module docstring); counters of what was closed are kept for the
    log and the tests (``closed``)."""

    def __init__(self, deadlines: Deadlines) -> None:
        self.deadlines = deadlines
        self.open: dict[Any, None] = {}
        self.by_address: dict[str, dict[Any, None]] = {}
        self.closed = {"idle": 0, "head": 0, "body": 0, "send": 0, "evicted": 0, "refused": 0}
        self._warned = 0.0

    def admit(self, conn: GuardedH11Protocol) -> bool:
        """Whether ``conn`` may stay open; makes room by closing the oldest waiting connection."""
        for bound, what in ((self.deadlines.per_address, "from one address"), (self.deadlines.connections, "in all")):
            pool = self.open if what == "in all" else self.by_address.get(conn.address, {})
            if len(pool) >= bound:
                waiting = [c for c in pool if c.waiting]
                if not waiting:
                    self._note("refused", f"{bound} connections {what} (all inside a request)", conn.address)
                    return False
                self._note("evicted", f"{bound} connections {what}", conn.address)
                min(waiting, key=lambda c: c.since).drop()  # removes it from both pools
        self.by_address.setdefault(conn.address, {})[conn] = None
        self.open[conn] = None
        return True

    def remove(self, conn: GuardedH11Protocol) -> None:
        self.open.pop(conn, None)
        mine = self.by_address.get(conn.address)
        if mine is not None:
            mine.pop(conn, None)
            if not mine:
                del self.by_address[conn.address]

    def _note(self, what: str, bound: str, address: str) -> None:
        self.closed[what] += 1
        now = time.monotonic()
        if now - self._warned >= 60:  # one line a minute under a flood, not one per connection
            self._warned = now
            log.warning("connections: at the bound of %s; the oldest waiting one closed or the new one "
                        "refused (latest: %s; %s so far)", bound, address, self.closed)


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline per phase and bounded connections (module docstring).
    Made per server by :func:`guarded_protocol`, which sets :attr:`registry`."""

    registry: Connections

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.limit_concurrency = None  # connections are bounded here; renders by the app
        self.address = "?"
        self.phase: str | None = None  # "head", "body" or None (inside the app, or closed)
        self.since = 0.0
        self._deadline: Any = None
        self._stall: Any = None

    @property
    def waiting(self) -> bool:
        """Whether the connection waits for a request head (fresh, idle keep-alive or dribbling)."""
        return self.phase == "head"

    # asyncio.Protocol and uvicorn's hooks
    def connection_made(self, transport: Any) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self.address = self.client[0] if self.client else "?"
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
        super().on_response_complete()  # arms the keep-alive timer (timeout_keep_alive_handler)
        if self.transport.is_closing():  # closed after this answer: its unsent bytes get the send deadline
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

    # the deadlines
    def _enter(self) -> None:
        """Start the phase h11's state of the client's side says (a head or a body to wait for)."""
        if self.transport is None or self.transport.is_closing():
            return
        state = self.conn.their_state
        phase = "head" if state is h11.IDLE else "body" if state is h11.SEND_BODY else None
        if phase == self.phase:
            return
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        self.phase, self.since = phase, time.monotonic()
        if phase is not None:
            seconds = self.registry.deadlines.head if phase == "head" else self.registry.deadlines.body
            self._deadline = self.loop.call_later(seconds, self._expire, phase)

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
        if self.transport.get_write_buffer_size() or why in ("send", "body"):
            self.transport.abort()  # nothing polite to wait for: unsent bytes, or a request cut short
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
