"""The work: ``POST /v1/stores/{store}/render`` (a whole frame), ``/stream`` (a per-voxel store's
frame, unit by unit as the cluster finishes them) and ``/verify`` (the aggregate a verified frame's
check needs). Each takes a slot of the concurrent-render limits first and runs on a worker thread
(:mod:`hevr.serve.jobs`); a request is checked whole (:class:`~hevr.remote.protocol.RenderRequest`)
before any work."""

from __future__ import annotations

import asyncio
import json
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
from ..jobs import render_image, stats_header, verify_aggregate
from ..problems import Problem, as_problem
from ..service import read_body
from .base import Caller, endpoint, service

__all__ = ["ROUTES"]


async def render(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    req = RenderRequest.from_dict(parse_json(await read_body(request), "body"))

    def run() -> tuple[bytes, str, str]:
        with svc.limits.slot(caller.name, caller.per_token):
            img = render_image(ev, req, client=svc.client, backend=svc.backend)
            if isinstance(img, (PackedImage, PackedColourImage, PackedSlice)):  # tiles as frames, then the end
                end = json.dumps({"ok": True, "stats": stats_header(img.stats)}).encode()
                tiles = [t for c in getattr(img, "components", [img]) for t in c.ciphertexts]
                blob = b"".join(pack_frame(i, np.ascontiguousarray(t).tobytes())
                                for i, t in enumerate(tiles)) + pack_frame(END, end)
                return blob, stats_header(img.stats), UNITS_MEDIA
            return img.to_bytes(), stats_header(img.stats), IMAGE_MEDIA

    blob, stats, media = await anyio.to_thread.run_sync(run)
    return Response(blob, media_type=media, headers={"X-Hevr-Stats": stats})


async def stream(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    req = RenderRequest.from_dict(parse_json(await read_body(request), "body"))
    if ev.meta.packing is not None:
        raise Problem(400, "bad request", f"stream: expected a per-voxel store, got the packed store "
                                          f"{ev.meta.store_id} (its frame comes whole from /render)")
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue = asyncio.Queue()
    slot = svc.limits.slot(caller.name, caller.per_token)
    slot.__enter__()  # a 429 now, before the stream starts

    class Sink:
        def start(self, finish: Any, fields: dict) -> None:
            pass

        def unit(self, i: int, packed: Any) -> None:
            loop.call_soon_threadsafe(queue.put_nowait, pack_frame(i, packed.tobytes()))

    def run() -> None:
        try:
            img = render_image(ev, req, client=svc.client, backend=svc.backend, stream=Sink())
            end = {"ok": True, "stats": stats_header(img.stats)}
        except Exception as exc:
            end = as_problem(exc).document()
        finally:
            slot.__exit__(None, None, None)
        loop.call_soon_threadsafe(queue.put_nowait, pack_frame(END, json.dumps(end).encode()))

    loop.run_in_executor(None, run)  # runs to its end even if the client leaves (its slot is freed then)

    async def frames():
        while True:
            frame = await queue.get()
            yield frame
            if int.from_bytes(frame[:4], "little") == END:
                return

    return StreamingResponse(frames(), media_type=UNITS_MEDIA)


async def verify(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    vr = VerifyRequest.from_dict(parse_json(await read_body(request), "body"))

    def run() -> int:
        with svc.limits.slot(caller.name, caller.per_token):
            return verify_aggregate(ev, vr.render, vr.seed, client=svc.client, backend=svc.backend)

    aggregate = await anyio.to_thread.run_sync(run)
    return JSONResponse({"aggregate": str(aggregate)})


ROUTES = [
    Route("/v1/stores/{store}/render", endpoint(render), methods=["POST"]),
    Route("/v1/stores/{store}/stream", endpoint(stream), methods=["POST"]),
    Route("/v1/stores/{store}/verify", endpoint(verify), methods=["POST"]),
]
