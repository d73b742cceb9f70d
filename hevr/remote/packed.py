"""A packed store's frame on ``hevr serve``, as the key holder renders it (:func:`hevr.render` on a
:class:`~hevr.remote.volume.RemoteVolume` of a packed store).

The key holder plans the frame itself, with the same
:meth:`~hevr.rendering.packed.plan.SlicePlan.of_store` the server calls on the same request, so it
knows how many combined values every reduce tile holds. The server's answer
(:mod:`hevr.remote.protocol`: one frame per tile, in tile order, then the end frame) is read
with that bound and must hold exactly those records, each a ciphertext in (0, n²); everything
else of the :class:`~hevr.rendering.packed.PackedImage` (plan, exponent, offset, span) is this
process's. A transfer-function or emphasis frame asks for the vector channel: its k components
come back component-major and the colouring never leaves this process. A verified frame's seed is
drawn after the values are in hand and sent in a second request; the answer is one aggregate (all
components at once: :mod:`hevr.rendering.packed.verified`), and the
verification record's metadata is the store's as this process parsed it, whose owner's MAC the
decryption checks.
"""

from __future__ import annotations

import logging
import secrets
import time
from typing import Any

import numpy as np

from ..backends import get_backend
from ..errors import ParameterError, RemoteAnswerError
from ..rendering.packed.colour import PackedColourImage
from ..rendering.packed.image import PackedImage
from ..rendering.packed.plan import SlicePlan
from ..rendering.packed.plane_image import PackedSlice
from ..rendering.packed.planes import PlanePlan
from ..rendering.packed.verified import PackedVerification
from ..store.packing import mantissa_range
from .protocol import END, MAX_BODY, RenderRequest, VerifyRequest, packed_limit
from .render import _aggregate, _server_stats

log = logging.getLogger(__name__)

__all__ = ["render_remote_packed", "render_remote_packed_slice"]


def _tiles(
    server: Any, where: str, req: RenderRequest, counts: list[int], width: int, n: int
) -> tuple[list[np.ndarray], dict]:
    """The answer of ``/render`` for a packed store: exactly ``len(counts)`` frames in order, frame t
    of ``counts[t]`` records of ``width`` bytes, every record a ciphertext in (0, n²); and the
    server's public statistics."""
    be = get_backend("cpu")
    tiles: list = []
    stats: dict = {"layout": "packed", "remote": server.url, "backend": "remote"}
    for index, data in server.frames(f"{where}/render", req.to_dict(), packed_limit(counts, width)):
        if index == END:
            stats.update(_server_stats(data.get("stats") if isinstance(data.get("stats"), str) else None))
            break
        t = len(tiles)
        if index != t or t >= len(counts) or len(data) != counts[t] * width:
            raise RemoteAnswerError(
                f"server {server.url}: the packed answer's tile {index}: expected tile {t} of "
                f"{len(counts)} with {counts[t] if t < len(counts) else 0} records of {width} bytes, "
                f"got {len(data)} bytes; no image is returned"
            )
        recs = np.frombuffer(data, np.uint8).reshape(-1, width).copy()
        if len(recs) and be.first_out_of_range(be.from_bytes(recs), n * n) is not None:
            raise RemoteAnswerError(
                f"server {server.url}: tile {t} of the packed answer holds a value that is not a "
                "ciphertext (outside (0, n²)); no image is returned"
            )
        tiles.append(recs)
    if len(tiles) != len(counts):
        raise RemoteAnswerError(
            f"server {server.url}: the packed answer: expected {len(counts)} tiles, got {len(tiles)}; "
            "no image is returned"
        )
    return tiles, stats


def _verification(
    server: Any, where: str, req: RenderRequest, meta: Any, channel: str, k: int, n: int, level: int = 0, name: str = ""
) -> PackedVerification:
    """The second round, after the values are in this process: a fresh seed, the server's one
    aggregate; the record's every other field is this process's own."""
    t1 = time.perf_counter()
    seed = secrets.token_bytes(32)
    raw, _ = server.request(
        "POST", f"{where}/verify", body=VerifyRequest(render=req, seed=seed).to_dict(), limit=MAX_BODY
    )
    return PackedVerification(
        aggregate=_aggregate(raw, n, server.url),
        seed=seed,
        meta=meta,
        level=level,
        channel=channel,
        components=k,
        server_s=time.perf_counter() - t1,
        drawn_here=True,
        drawn_at=time.time(),
        known_name=name,
    )


def render_remote_packed(
    rv: Any,
    camera: Any,
    sampling: str,
    *,
    tile: int,
    weight_bits: int | None,
    backend: str | None,
    client: Any,
    verify: bool,
    colouring: Any = None,
    channel: str = "vector",
    asked: Any = None,
) -> PackedImage | PackedColourImage:
    """A packed frame of ``camera`` rendered by the server of ``rv`` (request checked by the caller):
    an X-ray, or with a ``colouring`` (kept here, never sent) the k components of ``channel``
    (vector, or gradient), answered component-major (component j's tiles are frames j·T … j·T + T − 1).
    ``rv`` may be a pyramid level's view (``camera`` in its frame); ``asked``: the camera as the
    caller gave it, in level 0's frame, which the request names with the level."""
    if client is not None:
        raise ParameterError(
            f"client: expected None for a remote volume (the server renders on its own cluster), "
            f"got {type(client).__name__}"
        )
    t0 = time.perf_counter()
    meta = rv.meta  # the level's (its packing, exponent and offset); base: level 0's, with the owner's MAC
    base = rv.base if rv.level else meta
    plan = SlicePlan.of_store(meta, camera, sampling, tile, weight_bits)
    channel = "scalar" if colouring is None else channel
    k = meta.components(channel)
    if channel != "scalar":
        vlo, vhi = mantissa_range((0.0, 1.0), getattr(meta, channel).exponent)
        plan.check_slots(vhi - vlo)  # as the server does: no component's sum may carry
    counts = [(j1 - j0) * (b1 - b0) for j0, j1, b0, b1 in map(plan.tile_bounds, range(plan.n_tiles))] * k
    level = int(rv.level or 0)
    req = RenderRequest(
        view=camera if asked is None else asked,
        channel=channel,
        sampling=sampling,
        step=1.0,
        level=level,
        tile=plan.tile,
        backend=backend,
        weight_bits=weight_bits,
    )
    server, where = rv.server, f"/v1/stores/{rv.store_id}"
    n = int(rv.public_key.n)
    tiles, stats = _tiles(server, where, req, counts, meta.ciphertext_bytes, n)
    stats["seconds"] = time.perf_counter() - t0
    T = plan.n_tiles
    if channel == "scalar":
        lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent)
        img: Any = PackedImage(
            plan=plan,
            camera=camera,
            fingerprint=meta.fingerprint,
            n=n,
            exponent=meta.scalar.exponent,
            offset=meta.packing.offset,
            span=hi - lo,
            ciphertexts=tiles,
            store_id=meta.store_id,
            stats=stats,
            meta=base,
            level=level,
        )
    else:
        comps = [
            PackedImage(
                plan=plan,
                camera=camera,
                fingerprint=meta.fingerprint,
                n=n,
                exponent=getattr(meta, channel).exponent,
                offset=0,
                span=vhi - vlo,
                ciphertexts=tiles[j * T : (j + 1) * T],
                store_id=meta.store_id,
                stats=stats,
                meta=meta,
                level=0,
            )
            for j in range(k)
        ]
        img = PackedColourImage(components=comps, colouring=colouring, stats=stats, channel=channel)
    if verify:  # the values are fixed in this process: only now the seed
        img.verification = _verification(server, where, req, base, channel, k, n, level, str(rv.path))
        img.stats["verify_s"] = img.verification.server_s
        img.stats["seconds"] = time.perf_counter() - t0
    log.info("remote packed render %dx%d: %s", camera.width, camera.height, img.stats)
    return img


def render_remote_packed_slice(
    rv: Any, plane: Any, sampling: str, *, backend: str | None, client: Any, verify: bool
) -> PackedSlice:
    """A packed store's slice rendered by the server of ``rv``: planned here with the same
    :class:`~hevr.rendering.packed.planes.PlanePlan` the server builds, its merge tiles read as
    frames with exact sizes, every ciphertext checked; verified as a frame is (request checked by
    the caller)."""
    if client is not None:
        raise ParameterError(
            f"client: expected None for a remote volume (the server renders on its own cluster), "
            f"got {type(client).__name__}"
        )
    t0 = time.perf_counter()
    meta = rv.meta
    plan = PlanePlan.build(plane, meta.shape, meta.spacing, meta.brick, meta.packing, sampling)
    counts = [v1 - v0 for v0, v1 in map(plan.tile_bounds, range(plan.n_tiles))]
    req = RenderRequest(view=plane, channel="scalar", sampling=sampling, step=plane.slab_step, level=0, backend=backend)
    server, where = rv.server, f"/v1/stores/{rv.store_id}"
    tiles, stats = _tiles(server, where, req, counts, meta.ciphertext_bytes, int(rv.public_key.n))
    lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent)
    stats["seconds"] = time.perf_counter() - t0
    img = PackedSlice(
        plan=plan,
        plane=plane,
        fingerprint=meta.fingerprint,
        n=int(rv.public_key.n),
        exponent=meta.scalar.exponent,
        offset=meta.packing.offset,
        span=hi - lo,
        ciphertexts=tiles,
        store_id=meta.store_id,
        stats=stats,
        tags=bool(meta.tags),
    )
    if verify:
        img.verification = _verification(server, where, req, meta, "scalar", 1, int(rv.public_key.n), name=str(rv.path))
    return img
