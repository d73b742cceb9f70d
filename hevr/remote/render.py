"""A render of a :class:`~hevr.remote.volume.RemoteVolume`: the request goes to ``hevr serve``, the
image comes back as data, and the key holder decides whether it is the one it asked for.

The key holder computes the whole public side of the answer itself — the rays, the render plan,
the image's fields (shape, exponent, offset, bound, packing, hit mask, sample counts, info:
:func:`~hevr.rendering.pipeline.sums.image_fields`), the finishing units of a streamed frame — from the
request and the store's public metadata, exactly as :func:`hevr.render` does in process. The
server's ``.hevr`` answer is parsed by the format's strict reader and must agree field by field;
only its ciphertexts are taken. So the image (and its file) is the in-process one, byte for byte,
and a server cannot change what a frame means by editing its header.
Any answer these checks refuse is a :class:`hevr.RemoteAnswerError` (a :class:`hevr.RemoteError`
and an :class:`hevr.IntegrityError`: a faulty or lying server), never a busy or failed server's
error, so that an application can tell the two apart.

Verified renders: the key holder draws the seed *after* it holds the image (the server never
sees it before it has committed to the ciphertexts) and sends it in a second request; the
server's answer is one aggregate ciphertext; everything else of the
:class:`~hevr.rendering.verification.Verification` — store id, view, level, step, channel, exponent —
is this process's own request, never the server's word.
"""

from __future__ import annotations

import logging
import re
import secrets
import time
from typing import Any

import numpy as np

from ..backends import get_backend
from ..core.validate import check_int
from ..errors import HevrError, IntegrityError, ParameterError, RemoteAnswerError
from ..image import EncryptedImage, image_from_bytes
from ..image.checks import check_image
from ..image.tiles import TileLayout
from ..rendering.geometry.rays import cast_rays
from ..rendering.pipeline.graph import FinishGraph
from ..rendering.pipeline.sums import image_fields, with_colouring
from ..rendering.planning.planner import check_render_size, plan_render
from ..rendering.planning.request import at_level, level_step
from ..rendering.verification import Verification
from ..rendering.verify import resolve_verify
from . import schema
from .failures import check_answer
from .protocol import END, MAX_BODY, RenderRequest, VerifyRequest, image_limit, parse_json

log = logging.getLogger(__name__)

__all__ = ["render_remote"]

_DECIMAL = re.compile(r"[0-9]{1,2800}")  # ASCII digits only: str.isdigit() also takes '²'
_FIELDS = (
    "shape",
    "exponent",
    "offset",
    "fingerprint",
    "n",
    "tile",
    "pack_bits",
    "per_pack",
    "bound",
    "finish",
    "channel",
    "components",
    "info",
)


def _same(name: str, want: Any, got: Any) -> bool:
    if name in ("hits", "samples"):
        return got is not None and np.array_equal(np.asarray(want), np.asarray(got))
    if name == "shape":
        return tuple(want) == tuple(got)
    return want == got


def render_remote(
    rv: Any,
    view: Any,
    spec: Any,
    *,
    level: int | None,
    digits: int,
    pack: bool,
    tile: int,
    client: Any,
    compute: bool,
    keep_sums: Any,
    finish: str,
    stream: Any,
    verify: Any,
    backend: str | None,
    progress: bool,
) -> EncryptedImage:
    """:func:`hevr.render`'s work for a remote volume (``spec`` checked by the caller)."""
    if client is not None:
        raise ParameterError(
            f"client: expected None for a remote volume (the server renders on its own cluster), "
            f"got {type(client).__name__}"
        )
    if not compute:
        raise ParameterError("compute: expected True for a remote volume (the server computes now), got False")
    if keep_sums is not None:
        raise ParameterError("keep_sums: expected None for a remote volume (the ray sums stay on the server)")
    if finish != "client":
        raise ParameterError(
            f"finish: expected 'client' for a remote volume (server finishing would send the "
            f"colouring to the server), got {finish!r}"
        )
    tile = check_int("tile", tile, 1, schema.MAX_SIDE)
    t0 = time.perf_counter()
    ev, cam = at_level(rv, view, level)
    spec_l = level_step(spec, ev, cam)
    verified = resolve_verify(verify, ev, finish, level=ev.level, compute=True, stream=stream is not None)
    checked = check_render_size(cam, ev.shape, ev.spacing, spec_l.step)
    rays = checked if checked is not None else cast_rays(cam, ev.shape, ev.spacing, spec_l.step)
    n = int(ev.public_key.n)
    plan = plan_render(
        n=n,
        spec=spec_l,
        meta=ev.meta,
        n_samples=rays.n_samples,
        digits=digits if spec_l.sampling == "trilinear" else 0,
        precision=0,
        comb_digits=1,
        pack=pack,
        combination=None,
        finish="client",
    )
    fields = image_fields(spec_l, plan, cam, rays.n_samples, ev.meta, tile, level=ev.level)
    req = RenderRequest(
        view=view,
        channel=spec.channel,
        sampling=spec.sampling,
        step=spec.step,
        level=ev.level,
        digits=int(digits),
        pack=bool(pack),
        tile=tile,
        backend=backend,
    )
    H, W = cam.height, cam.width
    limit = image_limit(H, W, plan.channels_out, ev.meta.ciphertext_bytes)
    server, where = rv.server, f"/v1/stores/{rv.store_id}"
    stats: dict = {
        "remote": server.url,
        "backend": "remote",
        "resident": None,
        "map_tasks": None,
        "finish_tasks": None,
        "reused_ray_sums": False,
    }
    if stream is not None:
        layout = TileLayout(W, H, tile)
        graph = FinishGraph.plan_units(plan, layout, rays.n_samples, n, "cpu")
        stream.start(graph, fields)
        units: list = [None] * len(graph.units)
        width = ev.meta.ciphertext_bytes
        for index, data in server.frames(f"{where}/stream", req.to_dict(), limit):
            if index == END:
                stats.update(_server_stats(data.get("stats") if isinstance(data.get("stats"), str) else None))
                break
            if not 0 <= index < len(units) or units[index] is not None or len(data) % width:
                raise RemoteAnswerError(
                    f"server {server.url}: the stream's unit {index}: expected a new unit of "
                    f"0-{len(units) - 1} of whole {width}-byte records"
                )
            unit = np.frombuffer(data, dtype=np.uint8).reshape(-1, width)
            try:  # its record count, range and plaintexts are checked there
                stream.unit(index, unit)
            except IntegrityError as exc:
                raise RemoteAnswerError(
                    f"server {server.url}: the stream's unit {index} does not fit the request ({exc})"
                ) from None
            units[index] = unit
        if any(u is None for u in units):
            raise RemoteAnswerError(
                f"server {server.url}: the stream ended with {sum(u is None for u in units)} of "
                f"{len(units)} units missing"
            )
        cts = graph.assemble(units)
        stats["gathered_bytes"] = sum(int(u.nbytes) for u in units)
    else:
        blob, headers = server.request(
            "POST", f"{where}/render", body=req.to_dict(), accept="application/vnd.hevr.image", limit=limit
        )
        try:
            got = image_from_bytes(blob, f"server {server.url}: the image")
        except HevrError as exc:
            raise RemoteAnswerError(
                f"server {server.url}: expected a valid .hevr image, got one that fails its checks ({exc})"
            ) from None
        for name in _FIELDS + ("hits", "samples"):
            if not _same(name, fields[name], getattr(got, name)):
                raise RemoteAnswerError(
                    f"server {server.url}: the image's {name!r} is not the one this request implies "
                    "(another render, or a forged header); no image is returned"
                )
        cts = got.ciphertexts
        stats["gathered_bytes"] = len(blob)
        stats.update(_server_stats(headers.get("x-hevr-stats")))
    stats["seconds"] = time.perf_counter() - t0
    img = EncryptedImage(ciphertexts=list(cts), stats=stats, **with_colouring(fields, spec_l))
    try:
        check_image(img)
    except IntegrityError as exc:
        raise RemoteAnswerError(
            f"server {server.url}: the image's ciphertexts do not fit the request ({exc})"
        ) from None
    be = get_backend("cpu")
    for t, c in enumerate(img.ciphertexts):  # every ciphertext in (0, n²) before the image is handed out
        if len(c) and be.first_out_of_range(be.from_bytes(np.ascontiguousarray(c)), n * n) is not None:
            raise RemoteAnswerError(
                f"server {server.url}: tile {t} of the image holds a value that is not a ciphertext "
                "(outside (0, n²)); no image is returned"
            )
    if verified:  # the image is fixed in this process: only now the seed (module docstring)
        t1 = time.perf_counter()
        seed = secrets.token_bytes(32)
        body = VerifyRequest(render=req, seed=seed).to_dict()
        raw, _ = server.request("POST", f"{where}/verify", body=body, limit=MAX_BODY)
        aggregate = _aggregate(raw, n, server.url)
        img.verification = Verification.of(
            ev,
            cam,
            spec_l.sampling,
            spec_l.step,
            plan.weight_digits,
            plan.channel,
            exponent=plan.exponent,
            aggregate=aggregate,
            seed=seed,
            server_s=time.perf_counter() - t1,
        )
        img.stats["verify_s"] = img.verification.server_s
        img.stats["seconds"] = time.perf_counter() - t0
    log.info("remote render %s %dx%d: %s", spec.channel, W, H, img.stats)
    return img


def _aggregate(raw: bytes, n: int, url: str) -> int:
    """The aggregate of a verification answer: :class:`hevr.remote.schema.Aggregate` (exactly
    ``{"aggregate": "<decimal>"}``), a ciphertext in (0, n²) (its length bounded before it is read
    as an integer)."""
    try:
        doc = parse_json(raw, "the verification answer")
    except HevrError as exc:
        raise RemoteAnswerError(f"server {url}: {exc}") from None
    agg = check_answer(schema.Aggregate, doc, url, "the verification answer").aggregate
    if not (_DECIMAL.fullmatch(agg) and len(agg) <= 2 * len(str(n)) and 0 < int(agg) < n * n):
        raise RemoteAnswerError(
            f"server {url}: the verification answer: aggregate: expected a ciphertext in (0, n²) "
            f"as a decimal string, got {len(agg)} digits"
        )
    return int(agg)


def _server_stats(text: str | None) -> dict:
    """The server's public statistics header, as data: only known keys of plain types."""
    if not text or len(text) > 1024:
        return {}
    try:
        doc = parse_json(text.encode("latin-1", "replace"), "X-Hevr-Stats")
    except HevrError:
        return {}
    if not isinstance(doc, dict):
        return {}
    out = {}
    for key, kinds in (
        ("map_tasks", int),
        ("finish_tasks", int),
        ("reused_ray_sums", bool),
        ("resident", bool),
        ("backend", str),
        ("seconds", float),
    ):
        v = doc.get(key)
        if isinstance(v, kinds) and not (kinds is int and isinstance(v, bool)):
            out[("server_" + key) if key in ("seconds", "backend") else key] = v if not isinstance(v, str) else v[:32]
    return out
