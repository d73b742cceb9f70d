"""The bounds on ``hevr serve``'s connections: the deadlines of each phase of a connection and the
connection counts (:class:`Deadlines`, Dask config keys under ``hevr.serve``), the per-address key
(:func:`address_group`: an IPv6 client's /64), and the registry of open connections that makes room
for a new one by closing the oldest waiting for a request head (:class:`Connections`). The rules are
:mod:`hevr.serve.guard`'s module docstring; its protocol keeps them.
"""

from __future__ import annotations

import ipaddress
import logging
import time
from collections import OrderedDict
from dataclasses import dataclass, fields
from typing import Any

import dask

from ..core.validate import check_int
from ..errors import ParameterError

log = logging.getLogger("hevr.serve")

__all__ = ["Connections", "Deadlines", "address_group"]

_KEYS = {
    "idle": "idle-timeout",
    "head": "head-timeout",
    "body": "body-timeout",
    "send": "send-timeout",
    "handshake": "handshake-timeout",
    "per_address": "per-address",
    "connections": "max-connections",
}


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
                check_int(key, value, 1, 1_000_000)
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
                given[name] = (
                    int(value)
                    if isinstance(value, str) and name in ("per_address", "connections") and value.strip().isdigit()
                    else value
                )
        return cls(**given)


_NAT64 = ipaddress.IPv6Network("64:ff9b::/96")


def address_group(host: Any) -> str:
    """The key of the per-address bound for a client's address: an IPv4 address as it is, an IPv6
    address's /64 (what one subscriber is given), an IPv4-mapped IPv6 address or one of NAT64's
    well-known prefix (64:ff9b::/96, IPv4 clients of an IPv6-only server) its IPv4 address;
    anything else (a Unix socket's peer) as it is.

    >>> address_group("10.0.0.7"), address_group("::ffff:10.0.0.7"), address_group("64:ff9b::a00:7")
    ('10.0.0.7', '10.0.0.7', '10.0.0.7')
    >>> address_group("2001:db8:1:2:aaaa::1"), address_group("2001:DB8:1:2::ffff%eth0"), address_group("?")
    ('2001:db8:1:2::/64', '2001:db8:1:2::/64', '?')
    """
    try:
        ip = ipaddress.ip_address(str(host).split("%", 1)[0])
    except ValueError:
        return str(host)
    if ip.version == 4:
        return str(ip)
    if ip.ipv4_mapped is not None:
        return str(ip.ipv4_mapped)
    if ip in _NAT64:
        return str(ipaddress.IPv4Address(int(ip) & 0xFFFFFFFF))
    return str(ipaddress.IPv6Network((int(ip) >> 64 << 64, 64)))


class Connections:
    """The open connections, per client address (:func:`address_group`), and those waiting for a
    request head in the order they began waiting (so the oldest is found at once under a flood).

    :meth:`admit` keeps both bounds (module docstring); a connection reports each change of whether
    it waits with :meth:`mark`. Counters of what was closed are kept for the log and the tests
    (``closed``)."""

    def __init__(self, deadlines: Deadlines) -> None:
        self.deadlines = deadlines
        self.open: dict[Any, None] = {}
        self.by_address: dict[str, dict[Any, None]] = {}
        self.waiting: OrderedDict[Any, None] = OrderedDict()
        self.waiting_by: dict[str, OrderedDict[Any, None]] = {}
        self.closed = {"idle": 0, "head": 0, "body": 0, "send": 0, "evicted": 0, "refused": 0}
        self._warned = 0.0

    def admit(self, conn: Any) -> bool:
        """Whether ``conn`` may stay open; makes room by closing the oldest waiting connection."""
        for bound, what in ((self.deadlines.per_address, "from one address"), (self.deadlines.connections, "in all")):
            per = what != "in all"
            if len(self.by_address.get(conn.address, ()) if per else self.open) >= bound:
                waiting = self.waiting_by.get(conn.address) if per else self.waiting
                if not waiting:
                    self._note("refused", f"{bound} connections {what} (all inside a request)", conn.address)
                    return False
                self._note("evicted", f"{bound} connections {what}", conn.address)
                next(iter(waiting)).drop()  # removes it from every pool
        self.by_address.setdefault(conn.address, {})[conn] = None
        self.open[conn] = None
        self.mark(conn, conn.waiting)
        return True

    def mark(self, conn: Any, waiting: bool) -> None:
        """``conn`` (open) began waiting for a request head (the newest waiting), or stopped waiting."""
        if conn not in self.open:
            return
        if waiting:
            self.waiting[conn] = None
            self.waiting.move_to_end(conn)
            mine = self.waiting_by.setdefault(conn.address, OrderedDict())
            mine[conn] = None
            mine.move_to_end(conn)
        else:
            self._unwait(conn)

    def remove(self, conn: Any) -> None:
        self._unwait(conn)
        self.open.pop(conn, None)
        mine = self.by_address.get(conn.address)
        if mine is not None:
            mine.pop(conn, None)
            if not mine:
                del self.by_address[conn.address]

    def _unwait(self, conn: Any) -> None:
        self.waiting.pop(conn, None)
        mine = self.waiting_by.get(conn.address)
        if mine is not None:
            mine.pop(conn, None)
            if not mine:
                del self.waiting_by[conn.address]

    def _note(self, what: str, bound: str, address: str) -> None:
        self.closed[what] += 1
        now = time.monotonic()
        if now - self._warned >= 60:  # one line a minute under a flood, not one per connection
            self._warned = now
            log.warning(
                "connections: at the bound of %s; the oldest waiting one closed or the new one "
                "refused (latest: %s; %s so far)",
                bound,
                address,
                self.closed,
            )
