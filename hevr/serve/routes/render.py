"""The work: ``POST /v1/stores/{store}/render`` (a whole frame), ``/stream`` (a per-voxel store's
frame, unit by unit as the cluster finishes them) and ``/verify`` (the aggregate a verified frame's
check needs). A request is checked whole (:class:`~hevr.remote.protocol.RenderRequest`), then
(:func:`_admit`): its parameters against the server's budget (step, pixels, tile, backend: free),
a place among the renders running (:meth:`~hevr.serve.budget.Limits.enter`: a token at its
``concurrent`` limit gets its 429 before any estimate), the estimate of its products (on a thread:
it casts the rays) and their room in flight. Each then runs on a thread of anyio's pool
(:func:`hevr.serve.jobs.run_job`), cancelled on the cluster when its client leaves (logged
"client left; render cancelled"; a /stream's whether or not its answer had started) or when the
server shuts down."""

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
from starlette.types import Receive, Scope, Send

from ...remote.protocol import END, IMAGE_MEDIA, UNITS_MEDIA, RenderRequest, VerifyRequest, pack_frame, parse_json
from ...rendering.packed import PackedImage
from ...rendering.packed.colour import PackedColourImage
from ...rendering.packed.plane_image import PackedSlice
from ...runtime.cancel import Cancelled, cancel_soon
from ..budget import Slot, check_backend
from ..jobs import CLIENT_GONE, SHUTDOWN, render_image, run_job, stats_header, verify_aggregate
from ..problems import Problem, as_problem
from ..service import Service, read_body
from .base import Caller, ClientLeft, endpoint, service

log = logging.getLogger("hevr.serve")

__all__ = ["ROUTES"]


async def _admit(svc: Service, caller: Caller, ev: Any, req: RenderRequest) -> Slot:
    """The request's slot of the server's limits, charged with its estimated products; or its
    refusal: the budget's 422s, the limits' 429s (the count before the estimate), 503 once closed."""
    svc.budget.check_request(ev, req)
    check_backend(req.backend, svc.backend)
    held = svc.limits.enter(caller.name, caller.per_token)
    try:
        cost = await anyio.to_thread.run_sync(svc.budget.estimate, ev, req)
        svc.limits.charge(held, cost.products)
    except BaseException:
        svc.limits.release(held)
        raise
    return held


def _cancelled(request: Request, caller: Caller, reason: str) -> Exception:
    """What a cancelled render answers: nothing to a client that left (logged), else a 503."""
    if reason == CLIENT_GONE:
        log.info("client left; render cancelled: %s %s (token %s)", request.method, request.url.path, caller.name)
        return ClientLeft()
    return Problem(
        503, "render cancelled", f"render: expected to finish, got cancelled ({reason})", {"Retry-After": "5"}
    )


async def _run(request: Request, caller: Caller, held: Slot, work: Any) -> Any:
    try:
        return await run_job(request, service(request).limits, held, work)
    except Cancelled as exc:
        raise _cancelled(request, caller, str(exc.args[0] if exc.args else "")) from None


async def render(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    req = RenderRequest.from_dict(parse_json(await read_body(request), "body"))
    held = await _admit(svc, caller, ev, req)

    def run() -> tuple[bytes, str, str]:
        img = render_image(ev, req, client=svc.client, backend=svc.backend)
        if isinstance(img, (PackedImage, PackedColourImage, PackedSlice)):  # tiles as frames, then the end
            end = json.dumps({"ok": True, "stats": stats_header(img.stats)}).encode()
            tiles = [t for c in getattr(img, "components", [img]) for t in c.ciphertexts]
            blob = b"".join(pack_frame(i, np.ascontiguousarray(t).tobytes()) for i, t in enumerate(tiles)) + pack_frame(
                END, end
            )
            return blob, stats_header(img.stats), UNITS_MEDIA
        return img.to_bytes(), stats_header(img.stats), IMAGE_MEDIA

    blob, stats, media = await _run(request, caller, held, run)
    return Response(blob, media_type=media, headers={"X-Hevr-Stats": stats})


class _Stream:
    """A /stream's answer: its frames, and its render cancelled (:data:`CLIENT_GONE`) when the answer
    ends before the end frame, whether or not the frames' generator ever started; it ends with the
    render's work."""

    status_code = 200

    def __init__(self, frames: Any, held: Slot, ended: list, work: asyncio.Future) -> None:
        self.frames, self.held, self.ended, self.work = frames, held, ended, work  # the work: held while this is

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await StreamingResponse(self.frames, media_type=UNITS_MEDIA)(scope, receive, send)
        finally:  # cancelled, closed or failed before the end: the client is gone, so is the render
            if not self.ended[0]:
                cancel_soon(self.held.scope, CLIENT_GONE)
            if not self.work.done():  # the request lasts until its render's thread ended (and logged)
                await asyncio.wait({self.work})


async def stream(request: Request, caller: Caller) -> Response | _Stream:
    svc = service(request)
    ev = svc.store(request, caller.token)
    req = RenderRequest.from_dict(parse_json(await read_body(request), "body"))
    if ev.meta.packing is not None:
        raise Problem(
            400,
            "bad request",
            f"stream: expected a per-voxel store, got the packed store "
            f"{ev.meta.store_id} (its frame comes whole from /render)",
        )
    held = await _admit(svc, caller, ev, req)  # a 429 now, before the stream starts
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue = asyncio.Queue()
    ended = [False]

    class Sink:
        def start(self, finish: Any, fields: dict) -> None:
            pass

        def unit(self, i: int, packed: Any) -> None:
            loop.call_soon_threadsafe(queue.put_nowait, pack_frame(i, packed.tobytes()))

    def run() -> dict:
        try:
            img = render_image(ev, req, client=svc.client, backend=svc.backend, stream=Sink())
        except Exception as exc:
            if held.scope.cancelled:
                raise  # run_job: Cancelled with the reason
            return as_problem(exc).document()  # the end frame says why
        return {"ok": True, "stats": stats_header(img.stats)}

    def finished(task: asyncio.Future) -> None:  # the end frame, after every unit (queued before it)
        exc = task.exception() if not task.cancelled() else Cancelled(SHUTDOWN)
        if exc is None:
            end = task.result()
        else:
            reason = str(exc.args[0] if exc.args else "") if isinstance(exc, Cancelled) else ""
            answer = _cancelled(request, caller, reason) if isinstance(exc, Cancelled) else as_problem(exc)
            end = answer.document() if isinstance(answer, Problem) else {"ok": False, "detail": CLIENT_GONE}
        queue.put_nowait(pack_frame(END, json.dumps(end).encode()))

    work = asyncio.ensure_future(run_job(request, svc.limits, held, run))  # on anyio's pool; a client
    work.add_done_callback(finished)  # that leaves cancels it (run_job's watcher, or _Stream's end)

    async def frames():
        while not ended[0]:
            frame = await queue.get()
            ended[0] = int.from_bytes(frame[:4], "little") == END
            yield frame

    return _Stream(frames(), held, ended, work)


async def verify(request: Request, caller: Caller) -> Response:
    svc = service(request)
    ev = svc.store(request, caller.token)
    vr = VerifyRequest.from_dict(parse_json(await read_body(request), "body"))
    held = await _admit(svc, caller, ev, vr.render)

    def run() -> int:
        return verify_aggregate(ev, vr.render, vr.seed, client=svc.client, backend=svc.backend)

    aggregate = await _run(request, caller, held, run)
    return JSONResponse({"aggregate": str(aggregate)})


ROUTES = [
    Route("/v1/stores/{store}/render", endpoint(render), methods=["POST"]),
    Route("/v1/stores/{store}/stream", endpoint(stream), methods=["POST"]),
    Route("/v1/stores/{store}/verify", endpoint(verify), methods=["POST"]),
]
