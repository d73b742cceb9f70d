"""The work: ``POST /v1/stores/{store}/render`` (a whole frame), ``/stream`` (a per-voxel store's
frame, unit by unit as the cluster finishes them) and ``/verify`` (the aggregate a verified frame's
check needs). A request is checked whole (:class:`~hevr.remote.protocol.RenderRequest`) and
against the server's budget (:mod:`hevr.serve.budget`: step, pixels, tile, products) before any
work; each then takes a slot of the limits (renders and products in flight) and runs on a worker
thread (:func:`hevr.serve.jobs.run_job`), cancelled on the cluster when its client leaves (logged
"client left; render cancelled") or when the server shuts down."""

from __future__ import annotations

import asyncio
import json
import logging
from typing import Any

import anyio
import numpy as np
from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from ...remote.protocol import END, IMAGE_MEDIA, UNITS_MEDIA, RenderRequest, VerifyRequest, pack_frame, parse_json
from ...rendering.packed import PackedImage
from ...rendering.packed.colour import PackedColourImage
from ...rendering.packed.plane_image import PackedSlice
from ..._cancel import Cancelled, scope
from ..jobs import CLIENT_LEFT, cancel_soon, render_image, run_job, stats_header, verify_aggregate
from ..problems import Problem, as_problem
from ..service import Service, read_body
from .base import Caller, ClientLeft, endpoint, service

log = logging.getLogger("hevr.serve")

__all__ = ["ROUTES"]


async def _checked(svc: Service, ev: Any, req: RenderRequest) -> int:
    """The request's products, or its refusal by the server's budget (on a thread: it casts the rays)."""
    return (await anyio.to_thread.run_sync(svc.budget.check, ev, req)).products


def _cancelled(request: Request, caller: Caller, reason: str) -> Exception:
    """What a cancelled render answers: nothing to a client that left (logged), else a 503."""
    if reason == CLIENT_LEFT:
        log.info("client left; render cancelled: %s %s (token %s)", request.method, request.url.path, caller.name)
        return ClientLeft()
    return Problem(503, "render cancelled", f"render: expected to finish, got cancelled ({reason})",
                   {"Retry-After": "5"})


async def _run(request: Request, caller: Caller, products: int, work: Any) -> Any:
    svc = service(request)
    try:
        return await run_job(request, svc.limits.slot(caller.name, caller.per_token, products), work)
    except Cancelled as exc:
        raise _cancelled(request, caller, str(exc.args[0] if exc.args else "")) from None


async def render(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    req = RenderRequest.from_dict(parse_json(await read_body(request), "body"))
    products = await _checked(svc, ev, req)

    def run() -> tuple[bytes, str, str]:
        img = render_image(ev, req, client=svc.client, backend=svc.backend)
        if isinstance(img, (PackedImage, PackedColourImage, PackedSlice)):  # tiles as frames, then the end
            end = json.dumps({"ok": True, "stats": stats_header(img.stats)}).encode()
            tiles = [t for c in getattr(img, "components", [img]) for t in c.ciphertexts]
            blob = b"".join(pack_frame(i, np.ascontiguousarray(t).tobytes())
                            for i, t in enumerate(tiles)) + pack_frame(END, end)
            return blob, stats_header(img.stats), UNITS_MEDIA
        return img.to_bytes(), stats_header(img.stats), IMAGE_MEDIA

    blob, stats, media = await _run(request, caller, products, run)
    return Response(blob, media_type=media, headers={"X-Hevr-Stats": stats})


async def stream(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    req = RenderRequest.from_dict(parse_json(await read_body(request), "body"))
    if ev.meta.packing is not None:
        raise Problem(400, "bad request", f"stream: expected a per-voxel store, got the packed store "
                                          f"{ev.meta.store_id} (its frame comes whole from /render)")
    products = await _checked(svc, ev, req)
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue = asyncio.Queue()
    slot = svc.limits.slot(caller.name, caller.per_token, products)
    job = slot.__enter__()  # a 429 now, before the stream starts

    class Sink:
        def start(self, finish: Any, fields: dict) -> None:
            pass

        def unit(self, i: int, packed: Any) -> None:
            loop.call_soon_threadsafe(queue.put_nowait, pack_frame(i, packed.tobytes()))

    def run() -> None:
        try:
            with scope(job):
                img = render_image(ev, req, client=svc.client, backend=svc.backend, stream=Sink())
            end = {"ok": True, "stats": stats_header(img.stats)}
        except Exception as exc:  # the end frame says why (a client that left reads nothing more)
            answer = _cancelled(request, caller, job.reason) if job.cancelled else as_problem(exc)
            end = answer.document() if isinstance(answer, Problem) else {"ok": False, "detail": CLIENT_LEFT}
        finally:
            slot.__exit__(None, None, None)
        loop.call_soon_threadsafe(queue.put_nowait, pack_frame(END, json.dumps(end).encode()))

    loop.run_in_executor(None, run)  # its slot is freed at its end; a client that leaves cancels it

    async def frames():
        ended = False
        try:
            while not ended:
                frame = await queue.get()
                ended = int.from_bytes(frame[:4], "little") == END
                yield frame
        finally:  # the client went away (the response was cancelled or closed): so does the render
            if not ended and not job.cancelled:
                cancel_soon(job, CLIENT_LEFT)

    return StreamingResponse(frames(), media_type=UNITS_MEDIA)


async def verify(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    vr = VerifyRequest.from_dict(parse_json(await read_body(request), "body"))
    products = await _checked(svc, ev, vr.render)

    def run() -> int:
        return verify_aggregate(ev, vr.render, vr.seed, client=svc.client, backend=svc.backend)

    aggregate = await _run(request, caller, products, run)
    return JSONResponse({"aggregate": str(aggregate)})


ROUTES = [
    Route("/v1/stores/{store}/render", endpoint(render), methods=["POST"]),
    Route("/v1/stores/{store}/stream", endpoint(stream), methods=["POST"]),
    Route("/v1/stores/{store}/verify", endpoint(verify), methods=["POST"]),
]
