"""What ``hevr serve`` runs for a request: the render pipeline of :func:`hevr.render`, on the
server's Dask cluster, for a checked :class:`~hevr.remote.protocol.RenderRequest`.

A request names a channel, not a mode (the colouring stays with the key holder), so a frame is
always finished on the client: ``scalar`` is the X-ray's sums, ``vector`` and ``gradient`` the
encoded density components that emphasis and transfer functions colour on the client. A packed
store's frame (:mod:`hevr.rendering.packed`) is planned from the same request by the same
:meth:`~hevr.rendering.packed.plan.SlicePlan.of_store` the key holder calls. The server never
holds a private key; these functions take none.

A render runs on a worker thread of anyio's pool in its slot of the server's limits
(:func:`run_job`; a /stream's too): it is cancelled on the cluster (:class:`hevr.runtime.cancel.Scope`,
:func:`hevr.runtime.scheduler.compute`) when its client leaves (:data:`CLIENT_GONE`; polled every
:data:`POLL_S` seconds), when the request's task is cancelled, or when the server shuts down
(:meth:`hevr.serve.budget.Limits.cancel_all`). Its slot is released on every path, the thread's
end or, when the thread never started (cancelled while waiting for one), :func:`run_job`'s.

The render runs with the server's backend only (:func:`hevr.serve.budget.check_backend` refuses
another), and its public statistics (:func:`stats_header`) say nothing of other tokens' renders.
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Callable
from typing import Any, TypeVar

import anyio
from starlette.requests import Request

from ..backends import resolve_backend_name
from ..errors import ParameterError
from ..image import EncryptedImage
from ..image.tiles import TileLayout
from ..remote.protocol import RenderRequest
from ..rendering.geometry.camera import Camera
from ..rendering.geometry.plane import Plane
from ..rendering.geometry.rays import cast_rays
from ..rendering.packed import PackedImage
from ..rendering.packed.colour import PackedColourImage
from ..rendering.packed.colour_render import colour_aggregate, render_packed_colour
from ..rendering.packed.plan import SlicePlan
from ..rendering.packed.plane_image import PackedSlice, render_packed_slice, slice_aggregate
from ..rendering.packed.planes import PlanePlan
from ..rendering.packed.request import render_packed_request
from ..rendering.packed.verified import aggregate_for as packed_aggregate_for
from ..rendering.planning.planner import check_render_size
from ..rendering.planning.request import at_level, check_request, level_step
from ..rendering.verify import aggregate_for
from ..rendering.view import render_view
from ..runtime import cancel
from ..runtime.cancel import cancel_soon

__all__ = [
    "CLIENT_GONE",
    "POLL_S",
    "SHUTDOWN",
    "cancel_soon",
    "render_image",
    "run_job",
    "stats_header",
    "verify_aggregate",
]

CLIENT_GONE = "client left"  # the reason of a render cancelled because its client went away (its log status: 499)
SHUTDOWN = "the server is shutting down"  # the reason of a render cancelled as the server stops
POLL_S = 0.25  # how often a running render asks whether its client is still there
T = TypeVar("T")


async def run_job(request: Request, limits: Any, held: Any, work: Callable[[], T]) -> T:
    """``work()`` on a worker thread of anyio's pool as the job of ``held`` (a
    :class:`~hevr.serve.budget.Slot` of ``limits``, entered and charged before: its 429s come before
    any work), released when the work ends, or here if its thread never started. Cancelled when the
    client leaves, when the server cancels the awaiting task or closes its limits (:data:`SHUTDOWN`);
    then :class:`~hevr.runtime.cancel.Cancelled` with the reason (``exc.args[0]``: :data:`CLIENT_GONE`, ...)."""
    job = held.scope
    gate = threading.Lock()
    state = {"started": False, "dropped": False}

    def thread() -> T:
        with gate:
            if state["dropped"]:  # the awaiting task gave up before a thread took this
                raise cancel.Cancelled(job.reason or SHUTDOWN)
            state["started"] = True
        try:
            with cancel.scope(job):
                return work()
        except Exception:
            if job.cancelled:  # whatever the cancelled work raised: the reason
                raise cancel.Cancelled(job.reason) from None
            raise
        finally:
            limits.release(held)

    async def watch() -> None:
        while not job.cancelled:
            await asyncio.sleep(POLL_S)
            if await request.is_disconnected():
                cancel_soon(job, CLIENT_GONE)

    watcher = asyncio.ensure_future(watch())
    try:
        return await anyio.to_thread.run_sync(thread, abandon_on_cancel=True)
    except asyncio.CancelledError:  # the server cancels its requests' tasks as it stops: the work goes too,
        cancel_soon(job, SHUTDOWN)  # and the client is told so (a 503, not a dropped connection)
        raise cancel.Cancelled(SHUTDOWN) from None
    finally:
        watcher.cancel()
        with gate:
            if not state["started"]:  # no thread took it (cancelled while waiting for one): release here
                state["dropped"] = True
                limits.release(held)


_PLACEHOLDER_DENSITY = 0.5  # make_spec wants one for a vector channel; client finishing never uses it


def _mode(req: RenderRequest) -> tuple[str, float | None, bool]:
    """The (mode, density, gradient) whose client-finished plan sums ``req.channel``."""
    if req.channel == "scalar":
        return "xray", None, False
    return "emphasize", _PLACEHOLDER_DENSITY, req.channel == "gradient"


def _step(req: RenderRequest) -> float:
    if isinstance(req.view, Plane) and req.step != req.view.slab_step:
        raise ParameterError(
            f"step: expected the plane's slab_step {req.view.slab_step:g} for a slice, got {req.step:g}"
        )
    return req.step


def _packed_plane(ev: Any, req: RenderRequest) -> Plane:
    """The plane of a slice request on a packed store (the scalar channel, its slab step)."""
    if req.channel != "scalar":
        raise ParameterError(
            f"channel: expected 'scalar' for a slice of the packed store {ev.meta.store_id}, got {req.channel!r}"
        )
    _step(req)
    if not isinstance(req.view, Plane):  # the callers ask for a plane's slice only
        raise ParameterError(f"view: expected a plane for a slice of the packed store {ev.meta.store_id}, got a camera")
    return req.view


def _packed_view(ev: Any, req: RenderRequest) -> Camera:
    """The camera of a request on a packed store (the scalar channel's X-rays; the vector channel's
    k components where the store has it)."""
    offered = ("scalar",) + tuple(ch for ch in ("vector", "gradient") if getattr(ev.meta, ch) is not None)
    if req.channel not in offered:
        raise ParameterError(
            f"channel: expected {' or '.join(map(repr, offered))} on the packed store "
            f"{ev.meta.store_id}, got {req.channel!r}"
        )
    if not isinstance(req.view, Camera):
        raise ParameterError(
            f"view: expected a camera on the packed store {ev.meta.store_id} (its slices are not served), got a plane"
        )
    return req.view


def render_image(
    ev: Any, req: RenderRequest, *, client: Any, backend: str | None = None, stream: Any = None
) -> EncryptedImage | PackedImage | PackedColourImage | PackedSlice:
    """The client-finished image of ``req`` on the store ``ev`` (``stream``: handed every
    finishing unit as it completes, :class:`hevr.rendering.pipeline.stream.StreamDecryptor`'s interface);
    a packed store's unverified :class:`~hevr.rendering.packed.PackedImage` (its tiles are the answer)."""
    if ev.meta.packing is not None:
        if stream is not None:
            raise ParameterError(
                f"stream: expected a per-voxel store, got the packed store {ev.meta.store_id} "
                "(its frame comes whole from /render)"
            )
        if isinstance(req.view, Plane):  # a slice: the same PlanePlan the key holder builds
            return render_packed_slice(
                ev, _packed_plane(ev, req), req.sampling, client=client, progress=False, backend=backend
            )
        view = _packed_view(ev, req)
        if req.channel != "scalar":  # the k components, coloured by the key holder (the server sees no colouring)
            if req.step != 1.0 or req.level:
                raise ParameterError(f"step/level: expected 1.0 and 0 for the {req.channel} channel of a packed store")
            check_render_size(view, ev.shape, ev.spacing, 1.0)
            return render_packed_colour(
                ev,
                view,
                req.sampling,
                None,
                tile=req.tile,
                client=client,
                progress=False,
                backend=backend,
                weight_bits=req.weight_bits,
                channel=req.channel,
            )
        return render_packed_request(
            ev,
            view,
            "xray",
            req.sampling,
            req.step,
            None,
            None,
            tile=req.tile,
            client=client,
            progress=False,
            backend=backend,
            compute=True,
            keep_sums=None,
            level=req.level or None,
            gradient=False,
            finish="client",
            verify=False,
            weight_bits=req.weight_bits,
        )
    if req.weight_bits is not None:
        raise ParameterError(f"weight_bits: expected null for a per-voxel store, got {req.weight_bits}")
    mode, density, gradient = _mode(req)
    plane = isinstance(req.view, Plane)
    img = render_view(
        ev,
        req.view,
        mode,
        req.sampling,
        _step(req),
        density,
        None,
        digits=req.digits,
        precision=4,
        comb_digits=4,
        pack=req.pack,
        tile=req.tile,
        cache=True,
        client=client,
        progress=False,
        backend=backend,
        compute=True,
        keep_sums=None,
        views=(Plane,) if plane else (Camera,),
        level=req.level or None,
        gradient=gradient,
        finish="client",
        stream=stream,
        verify=False,
    )
    assert isinstance(img, EncryptedImage)  # compute=True: the image, not a dask Delayed
    return img


def verify_aggregate(ev: Any, req: RenderRequest, seed: bytes, *, client: Any, backend: str | None = None) -> int:
    """The tag aggregate of ``req``'s render for the key holder's ``seed``
    (:func:`hevr.rendering.verify.aggregate_for`; the store must have tags)."""
    if ev.meta.packing is not None and isinstance(req.view, Plane):
        slice_plane = _packed_plane(ev, req)
        plane_plan = PlanePlan.build(
            slice_plane, ev.meta.shape, ev.meta.spacing, ev.meta.brick, ev.meta.packing, req.sampling
        )
        name = resolve_backend_name(backend, int(ev.public_key.n).bit_length(), client=client)
        return slice_aggregate(ev, plane_plan, name, client, False, seed)[0]
    if ev.meta.packing is not None:
        camera = _packed_view(ev, req)
        if req.step != 1.0 or (req.level and req.channel != "scalar"):
            raise ParameterError("step/level: expected 1.0 on a packed store (and level 0 for its vector channels)")
        ev_l, level_view = at_level(ev, camera, req.level or None)  # a level the owner encrypted: its own plan and tags
        check_render_size(level_view, ev_l.shape, ev_l.spacing, 1.0)  # the render's size limits, before any work
        plan = SlicePlan.of_store(ev_l.meta, level_view, req.sampling, req.tile, req.weight_bits)
        name = resolve_backend_name(backend, int(ev.public_key.n).bit_length(), client=client)
        if req.channel != "scalar":
            return colour_aggregate(ev_l, plan, name, client, False, seed, req.channel)[0]
        return packed_aggregate_for(ev_l, plan, name, client, False, seed)[0]
    mode, density, gradient = _mode(req)
    plane = isinstance(req.view, Plane)
    spec, digits, _, _ = check_request(
        ev,
        req.view,
        mode,
        req.sampling,
        _step(req),
        density,
        None,
        req.digits,
        4,
        4,
        (Plane,) if plane else (Camera,),
        gradient,
        "client",
    )
    ev_l, view = at_level(ev, req.view, req.level or None)
    spec = level_step(spec, ev_l, view)
    if not ev_l.meta.tags:
        raise ParameterError(f"verify: expected a verifiable store, got the store {ev.meta.store_id} without tags")
    checked = check_render_size(view, ev_l.shape, ev_l.spacing, spec.step)
    rays = checked if checked is not None else cast_rays(view, ev_l.shape, ev_l.spacing, spec.step)
    layout = TileLayout(view.width, view.height, req.tile)
    name = resolve_backend_name(backend, int(ev.public_key.n).bit_length(), client=client)
    return aggregate_for(
        ev_l,
        view,
        rays,
        spec.sampling,
        spec.step,
        digits if spec.sampling == "trilinear" else 0,
        spec.channel,
        req.tile,
        layout.n_tiles,
        name,
        client,
        False,
        seed,
    )


STATS = ("finish_tasks", "resident", "backend", "seconds")  # not map_tasks nor reused_ray_sums: see stats_header


def stats_header(stats: dict) -> str:
    """The render's public statistics as one line of JSON (the ``X-Hevr-Stats`` header): the
    :data:`STATS` only. The render cache is the server's, across tokens: ``reused_ray_sums`` (and
    ``map_tasks``, 0 for a reused render) would tell a token that another just rendered this view.

    >>> stats_header({"map_tasks": 0, "reused_ray_sums": True, "finish_tasks": 2, "backend": "cpu"})
    '{"finish_tasks":2,"backend":"cpu"}'
    """
    keep = {k: stats[k] for k in STATS if k in stats}
    return json.dumps(keep, separators=(",", ":"))
