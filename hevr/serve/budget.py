"""The cost bound of every request of ``hevr serve``: what one render may cost, what a token and the
server may have in flight, and the running renders' cancellation (issue 48).

Checked from the request's public parameters before any work (:meth:`Budget.check`), each refusal a
422 problem document naming the parameter and the server's option:

1. ``step``: a camera's step at least ``min_step`` of the smallest voxel spacing (default 0.25: four
   samples a voxel; a slice's samples are its slab, whatever its step);
2. ``width, height``: at most ``max_pixels`` pixels (``--max-pixels``, default 1024² = 1 048 576,
   four times the viewer's 512² frame; the planner's own limit allows 4096²);
3. ``tile``: at least ``ceil(max(W, H) / 64)`` (at most 64 tiles a side, 4096 in all: a tile is a
   task of the graph per brick it meets);
4. ``backend``: null or the server's own (``--backend``; a client cannot move a server sized for
   ``cuda`` onto its CPU);
5. ``products``: the render's modular products P (:func:`hevr.rendering.planning.request.request_cost`:
   P = ⌈C·c·Σ_r n_r·max(b, 10)/10⌉, b the weights' bits: ``digits`` 9 costs three times the
   default 3) at most ``max_products`` (``--max-products``, default 2^33 ≈ 8.6·10^9).

The default of ``max_products`` serves the viewer: a 512² trilinear frame of the 4 vector components
through a 512×512×300 CT at step 1 takes P = 9.3·10^8 at the viewer's orbit and at most
512²·785·8·4 = 6.6·10^9 (every ray as long as the diagonal). Refused by the defaults: a 2048² or
4096² image (pixels), ``tile`` 1 at 256² (tile), ``step`` 10^-6 (step), a 1024² trilinear frame of
that CT's vector channel close up (distance 400, the CT filling the frame: P = 1.26·10^10).

In flight (:class:`Limits`, a 429 with ``Retry-After``): the renders at once (``--max-concurrent``,
a token's ``concurrent``), the products of one token's running renders
(``--max-token-products``, default 2·``max_products``) and of all (``max_concurrent``·``max_products``).
The count comes first (:meth:`Limits.enter`, free), then the estimate (:meth:`Budget.estimate`:
it casts the rays: 0.07 s of CPU at 512² and 0.27 s at 1024², idle, 0.26 and 0.77 s on a loaded
2-core machine, half the pipeline's own cast; so at most ``max_concurrent`` run at once, and the
last :data:`CACHED` are kept by store and request, a 0.1 ms hit), then the products
(:meth:`Limits.charge`). A running render holds a :class:`hevr.runtime.cancel.Scope`: a client that
leaves, or the server's shutdown (:meth:`Limits.close`), cancels its tasks on the cluster.

The settings are Dask config keys (``hevr.serve.max-products``, ``hevr.serve.max-token-products``,
``hevr.serve.max-pixels``; ``DASK_HEVR__SERVE__MAX_PRODUCTS`` … in the environment), which the CLI's
options set, or a :class:`Budget` given to :func:`hevr.serve.app.create_app`.

>>> b = Budget.from_config()
>>> b.max_products == 2**33 and b.token_products == 2**34 and b.max_pixels == 1024**2
True
>>> b.min_tile(256, 256), b.min_tile(512, 512), b.min_tile(1024, 100)
(4, 8, 16)
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, overload

import dask

from ..backends import AUTO
from ..core.limits import MAX_IMAGE_PIXELS
from ..core.validate import check_int
from ..errors import ParameterError
from ..rendering.geometry.camera import Camera
from ..rendering.planning.request import RenderCost, request_cost
from ..runtime.cancel import Scope, cancel_soon
from .problems import Problem

__all__ = [
    "Budget",
    "Limits",
    "MAX_PRODUCTS_KEY",
    "MAX_PIXELS_KEY",
    "MAX_TOKEN_PRODUCTS_KEY",
    "Slot",
    "check_backend",
    "parse_count",
]

MAX_PRODUCTS_KEY = "hevr.serve.max-products"
MAX_TOKEN_PRODUCTS_KEY = "hevr.serve.max-token-products"
MAX_PIXELS_KEY = "hevr.serve.max-pixels"
DEFAULT_MAX_PRODUCTS = 2**33
DEFAULT_MAX_PIXELS = 1024 * 1024
MAX_PRODUCTS_CAP = 2**62
TILES_SIDE = 64
MIN_STEP = 0.25  # of the smallest voxel spacing
CACHED = 256  # estimates kept (by store and request)


def parse_count(name: str, value: Any, cap: int) -> int:
    """A count in [1, ``cap``] of a setting or an option: an integer, a whole float, or their text
    (``"8e9"``, ``"1048576"``); else a :class:`~hevr.errors.ParameterError` naming ``name``.

    >>> parse_count("--max-products", "8e9", 2**62), parse_count("k", 1e6, 2**62), parse_count("k", " 42 ", 99)
    (8000000000, 1000000, 42)
    >>> parse_count("--max-products", "8.5", 2**62)
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: --max-products: expected a whole number in [1, 4611686018427387904], got '8.5'
    """
    given = value
    if isinstance(value, str):
        try:
            value = float(value.strip()) if any(c in value for c in ".eE") else int(value.strip())
        except ValueError:
            pass
    if isinstance(value, float) and value.is_integer() and abs(value) <= 2.0**63:
        value = int(value)
    if isinstance(given, str) and not isinstance(value, int):
        raise ParameterError(f"{name}: expected a whole number in [1, {cap}], got {given!r}")
    return check_int(name, value, 1, cap)


@overload
def _setting(key: str, default: int, cap: int) -> int: ...


@overload
def _setting(key: str, default: None, cap: int) -> int | None: ...


def _setting(key: str, default: int | None, cap: int) -> int | None:
    value = dask.config.get(key, None)
    return default if value is None else parse_count(key, value, cap)


def check_backend(requested: str | None, server: str | None) -> None:
    """Refuse (422, naming ``backend``) a request's backend other than the server's: null, or the
    one the server runs (``auto`` when it was given none).

    >>> check_backend(None, "cuda"); check_backend("cuda", "cuda"); check_backend("auto", None)
    >>> check_backend("cpu", "cuda")
    Traceback (most recent call last):
    ...
    hevr.serve.problems.Problem: backend: expected null or 'cuda' (this server's), got 'cpu'
    """
    own = server or AUTO
    if requested is not None and requested != own:
        raise Problem(
            422, "backend not offered", f"backend: expected null or {own!r} (this server's), got {requested!r}"
        )


@dataclass(frozen=True)
class Budget:
    """What one render may cost on this server (module docstring); ``max_token_products`` None:
    twice ``max_products``."""

    max_products: int = DEFAULT_MAX_PRODUCTS
    max_pixels: int = DEFAULT_MAX_PIXELS
    max_token_products: int | None = None
    min_step: float = MIN_STEP

    @classmethod
    def from_config(cls) -> Budget:
        """The budget of the Dask config keys (module docstring), else the defaults."""
        return cls(
            _setting(MAX_PRODUCTS_KEY, DEFAULT_MAX_PRODUCTS, MAX_PRODUCTS_CAP),
            _setting(MAX_PIXELS_KEY, DEFAULT_MAX_PIXELS, MAX_IMAGE_PIXELS),
            _setting(MAX_TOKEN_PRODUCTS_KEY, None, MAX_PRODUCTS_CAP),
        )

    @property
    def token_products(self) -> int:
        return self.max_token_products if self.max_token_products is not None else 2 * self.max_products

    @staticmethod
    def min_tile(width: int, height: int) -> int:
        return max(1, -(-max(width, height) // TILES_SIDE))

    def check(self, ev: Any, req: Any) -> RenderCost:
        """The cost of the :class:`~hevr.remote.protocol.RenderRequest` ``req`` on the store ``ev``,
        or a 422 :class:`~hevr.serve.problems.Problem` naming the limit it passes (module docstring):
        :meth:`check_request`, then :meth:`estimate`."""
        self.check_request(ev, req)
        return self.estimate(ev, req)

    def check_request(self, ev: Any, req: Any) -> None:
        """The limits of the request's parameters (step, pixels, tile): free, before any work."""
        view = req.view
        floor = self.min_step * min(ev.spacing)
        if isinstance(view, Camera) and req.step < floor:
            raise _over(
                f"step: expected at least {floor:g} on this server ({self.min_step:g} of the smallest voxel "
                f"spacing, {min(ev.spacing):g}), got {req.step:g}"
            )
        w, h = view.width, view.height
        if w * h > self.max_pixels:
            raise _over(
                f"width, height: expected an image of at most {self.max_pixels} pixels on this server "
                f"(--max-pixels), got {w}x{h} = {w * h} pixels"
            )
        if req.tile < self.min_tile(w, h):
            raise _over(
                f"tile: expected at least {self.min_tile(w, h)} for a {w}x{h} image on this server (at most "
                f"{TILES_SIDE} tiles a side), got {req.tile}"
            )

    def estimate(self, ev: Any, req: Any) -> RenderCost:
        """The request's cost (:func:`~hevr.rendering.planning.request.request_cost`; it casts the
        rays: call it after :meth:`check_request`, on a thread), or a 422 over ``max_products``; the
        last :data:`CACHED` are kept by store and request."""
        key = _cost_key(ev, req)
        with _LOCK:
            cost = _COSTS.get(key) if key is not None else None
            if cost is not None:
                _COSTS.move_to_end(key)  # least recently used goes first, not the oldest
        if cost is None:
            cost = request_cost(
                ev, req.view, req.channel, req.sampling, req.step, req.level, req.digits, req.weight_bits
            )
            if key is not None:
                with _LOCK:
                    _COSTS[key] = cost
                    while len(_COSTS) > CACHED:
                        _COSTS.popitem(last=False)
        if cost.products > self.max_products:
            raise _over(
                f"products: expected at most {self.max_products:.3g} for one render on this server "
                f"(--max-products), got an estimated {cost.products:.3g} ({cost.describe()})"
            )
        if cost.products > self.token_products:
            raise _over(
                f"products: expected at most {self.token_products:.3g} in flight for a token on this server "
                f"(--max-token-products), got an estimated {cost.products:.3g} for one render"
            )
        return cost


_LOCK = threading.Lock()
_COSTS: OrderedDict = OrderedDict()


def _cost_key(ev: Any, req: Any) -> tuple | None:
    """What an estimate depends on: the store (its id and geometry) and the request (its key)."""
    sid = getattr(ev.meta, "store_id", None)
    if sid is None:
        return None
    return sid, tuple(ev.shape), tuple(ev.spacing), req.key()


def _over(detail: str) -> Problem:
    return Problem(422, "render over the server's budget", detail)


class Slot:
    """One admitted render (:meth:`Limits.enter`): its token's name, the products charged to it
    and its cancellation scope; released once (:meth:`Limits.release`, from any path)."""

    __slots__ = ("name", "products", "scope", "released")

    def __init__(self, name: str) -> None:
        self.name, self.products, self.scope, self.released = name, 0, Scope(), False


class Limits:
    """What runs now: renders and their products per token name and in all, and each render's
    cancellation :class:`~hevr.runtime.cancel.Scope` (thread-safe: released from render threads)."""

    def __init__(self, max_concurrent: int, budget: Budget | None = None) -> None:
        self.max_concurrent = int(max_concurrent)
        self.budget = budget if budget is not None else Budget()
        self.lock = threading.Lock()
        self.idle = threading.Condition(self.lock)
        self.running: dict[str, int] = {}
        self.products: dict[str, int] = {}
        self.total = 0
        self.total_products = 0
        self.scopes: set[Scope] = set()
        self.closed = False

    def enter(self, name: str, per_token: int) -> Slot:
        """A render's place, counted (a 429 when the token or the server runs its most renders now;
        a 503 once closed): before any work, its estimate included."""
        held = Slot(name)
        with self.lock:
            self._admit(name, per_token)
            self.running[name] = self.running.get(name, 0) + 1
            self.total += 1
            self.scopes.add(held.scope)
        return held

    def charge(self, held: Slot, products: int) -> None:
        """Add the render's estimated ``products`` to its token's and the server's in flight (a 429
        over :attr:`Budget.token_products` or ``max_concurrent``·``max_products``)."""
        products = int(products)
        with self.lock:
            self._afford(held.name, products)
            held.products += products
            self.products[held.name] = self.products.get(held.name, 0) + products
            self.total_products += products

    def release(self, held: Slot) -> None:
        """Free the render's place and products (once: a second call does nothing)."""
        with self.lock:
            if held.released:
                return
            held.released = True
            self.running[held.name] -= 1
            self.products[held.name] = self.products.get(held.name, 0) - held.products
            self.total -= 1
            self.total_products -= held.products
            self.scopes.discard(held.scope)
            self.idle.notify_all()

    @contextmanager
    def slot(self, name: str, per_token: int, products: int = 0) -> Iterator[Scope]:
        """:meth:`enter`, :meth:`charge` and, at the block's end, :meth:`release`: the block runs in
        the slot's scope."""
        held = self.enter(name, per_token)
        try:
            self.charge(held, products)
            yield held.scope
        finally:
            self.release(held)

    def _admit(self, name: str, per_token: int) -> None:
        if self.closed:
            raise Problem(
                503,
                "server shutting down",
                "render: expected a running server, got one shutting down",
                {"Retry-After": "5"},
            )
        if self.total >= self.max_concurrent or self.running.get(name, 0) >= per_token:
            raise Problem(
                429,
                "too many concurrent renders",
                f"concurrent renders: expected at most {per_token} for this token and "
                f"{self.max_concurrent} on this server, got one more; retry shortly",
                {"Retry-After": "1"},
            )

    def _afford(self, name: str, products: int) -> None:
        mine, limit = self.products.get(name, 0), self.budget.token_products
        if mine and mine + products > limit:
            raise Problem(
                429,
                "too much work in flight",
                f"products in flight: expected at most {limit:.3g} for this token (--max-token-products), "
                f"got {mine:.3g} running and an estimated {products:.3g} more; retry when a render ends",
                {"Retry-After": "5"},
            )
        limit = self.max_concurrent * self.budget.max_products
        if self.total_products and self.total_products + products > limit:
            raise Problem(
                429,
                "too much work in flight",
                f"products in flight: expected at most {limit:.3g} on this server (--max-concurrent × "
                f"--max-products), got {self.total_products:.3g} running and an estimated {products:.3g} "
                "more; retry when a render ends",
                {"Retry-After": "5"},
            )

    def open(self) -> None:
        """Admit renders again (an application started anew after a :meth:`close`)."""
        with self.lock:
            self.closed = False

    def cancel_all(self, reason: str = "the server is shutting down") -> None:  # jobs.SHUTDOWN
        """Refuse new renders and cancel the running ones, each from a thread of its own: returns at
        once (the app's lifespan calls it on the event loop)."""
        with self.lock:
            self.closed = True
            scopes = list(self.scopes)
        for scope in scopes:
            cancel_soon(scope, reason)

    def close(self, timeout: float = 5.0, reason: str = "the server is shutting down") -> bool:
        """:meth:`cancel_all`, then wait up to ``timeout`` seconds for the renders' threads to end
        (blocks: call it on a thread of its own); whether they all did."""
        self.cancel_all(reason)
        deadline = time.monotonic() + timeout
        with self.lock:
            while self.total and time.monotonic() < deadline:
                self.idle.wait(max(0.01, deadline - time.monotonic()))
            return self.total == 0
