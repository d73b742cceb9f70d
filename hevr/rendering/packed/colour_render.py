"""Rendering a packed store's transfer-function and emphasis frames: the k components through the
scalar frame's plan, map, merge and the tags' round (:mod:`hevr.rendering.packed.colour` describes the
frame and its :class:`~hevr.rendering.packed.colour.PackedColourImage`).
"""

from __future__ import annotations

import logging
import secrets
import time
import uuid
from typing import Any

import gmpy2
import numpy as np
from dask.delayed import delayed

from ...backends import get_backend
from ...backends.base import OpCounter
from ...colour import Colouring
from ...crypto.tags import data_channel, tag_channel
from ...errors import ParameterError
from ...runtime.scheduler import active_client
from ...runtime.scheduler import compute as run_tasks
from ...store.packing import mantissa_range
from ..pipeline.kernel import plan_products
from ..verify import resolve_verify
from .colour import PackedColourImage
from .graph import column_pairs, map_graph, merge_tile, render_context, resident_bricks
from .image import PackedImage
from .plan import SlicePlan
from .verified import PackedVerification, aggregate_tile

log = logging.getLogger(__name__)

__all__ = [
    "colour_aggregate",
    "map_components",
    "merge_components",
    "render_packed_colour",
    "render_packed_colour_request",
]


def map_components(
    ev: Any,
    plan: SlicePlan,
    indices: list,
    backend: str,
    tiles: list[int],
    residents: list | None = None,
    channel: str = "vector",
) -> tuple[list[list[tuple[np.ndarray, np.ndarray]]], dict]:
    """The partial accumulators of a column of bricks for each of the vector channel's k components
    (``channel="vector_tag"``: of their tags), cut by the tiles ``tiles``: per tile a list of k
    (keys, records), and the operations counted. One product plan for the column, run on the k
    components' batches together."""
    be = get_backend(backend)
    width = ev.meta.ciphertext_bytes
    k = ev.meta.components(data_channel(channel))
    per_brick = [
        r.batches[channel] if r is not None else ev.read_brick(idx, channel, backend=be)
        for idx, r in zip(indices, residents or [None] * len(indices))
    ]
    keys, local, weights = column_pairs(plan, indices, [len(b[0]) for b in per_brick])
    empty = (np.zeros(0, np.int64), np.zeros((0, width), np.uint8))
    if not len(keys):
        return [[empty] * k for _ in tiles], {"map": 0, "pairs": 0}
    comps = [per_brick[0][c] if len(per_brick) == 1 else be.concat([b[c] for b in per_brick]) for c in range(k)]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    uniq = keys[starts]
    indptr = np.r_[starts, len(keys)].astype(np.int64)
    counter = OpCounter()
    pp = plan_products(indptr, local, weights, len(comps[0]))
    values = be.ray_products(pp, comps, int(ev.public_key.nsquare), counter)
    recs = [be.to_bytes(v, width) for v in values]
    where = plan.tile_of(uniq)
    parts = [[(uniq[where == t], r[where == t]) for r in recs] for t in tiles]
    return parts, {"map": counter.modmuls, "pairs": int(len(keys)) * k}


def merge_components(
    plan: SlicePlan, t: int, n: int, width: int, backend: str, k: int, *parts: Any
) -> tuple[list[np.ndarray], dict[str, int]]:
    """Tile ``t`` of each component: :func:`~hevr.rendering.packed.graph.merge_tile` on the
    component's partial accumulators (``parts``: per map task a list of k (keys, records))."""
    out: list[np.ndarray] = []
    ops: dict[str, int] = {}
    for c in range(k):
        recs, counts = merge_tile(plan, t, n, width, backend, *[p[c] for p in parts])
        out.append(recs)
        for name, v in counts.items():
            ops[name] = ops.get(name, 0) + v
    return out, ops


def render_packed_colour(
    ev: Any,
    camera: Any,
    sampling: str,
    colouring: Colouring | None,
    *,
    tile: int = 32,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
    weight_bits: int | None = None,
    channel: str = "vector",
) -> PackedColourImage:
    """Render the vector (or gradient) channel's k components of a packed store for a parallel
    ``camera`` with the scalar frame's plan (module docstring); the request checks are
    :func:`render_packed_colour_request`'s."""
    meta = ev.meta
    if channel not in ("vector", "gradient") or getattr(meta, channel) is None:
        extra = ", gradient=True" if channel == "gradient" else ""
        raise ParameterError(
            f"ev: expected a packed store with the {channel} channel, got the store {meta.store_id} "
            f"without it; encrypt it with vector_dims=k{extra}"
        )
    cl, backend = render_context(ev, backend, client)
    t0 = time.perf_counter()
    plan = SlicePlan.of_store(meta, camera, sampling, tile, weight_bits)  # the scalar's slots checked
    info = getattr(meta, channel)
    vlo, vhi = mantissa_range((0.0, 1.0), info.exponent)
    plan.check_slots(vhi - vlo)  # and the components': no sum carries into the next slot
    if plan.n_tiles == 0:
        log.warning(
            "render: no ray of this %dx%d camera hits the packed volume: the image is empty; aim it at the "
            "volume (hevr.Camera.orbit looks at its centre)",
            camera.width,
            camera.height,
        )
    resident = resident_bricks(ev, channel, backend, cl)
    k = meta.components(channel)
    n, width = int(ev.public_key.n), meta.ciphertext_bytes
    plain = ev._plain()
    tag = f"{meta.store_id}-{uuid.uuid4().hex}"
    per_tile, maps = map_graph(plain, plan, backend, resident, channel, tag, map_components)  # k per task
    fin = [
        delayed(merge_components, pure=True, nout=2)(
            plan, t, n, width, backend, k, *per_tile[t], dask_key_name=f"hevr-packed-tile-{channel}-{tag}-{t}"
        )
        for t in range(plan.n_tiles)
    ]
    results = run_tasks(fin + maps, client=cl, progress=progress, desc="render")
    counts = {"map": sum(m["map"] for m in results[len(fin) :]), "pairs": sum(m["pairs"] for m in results[len(fin) :])}
    for r in results[: len(fin)]:
        for name, v in r[1].items():
            counts[name] = counts.get(name, 0) + v
    per_comp = [[r[0][c] for r in results[: len(fin)]] for c in range(k)]
    stats = {
        "layout": "packed",
        "channel": channel,
        "components": k,
        "backend": backend,
        "map_tasks": len(maps),
        "finish_tasks": len(fin),
        "resident": resident is not None,
        "ops": counts,
        "rays": int(np.prod(plan.geometry.size)),
        "ciphertexts": int(sum(len(t) for c in per_comp for t in c)),
        "seconds": time.perf_counter() - t0,
    }
    log.info(
        "render packed %s/%s %dx%d: %s",
        colouring.mode if colouring is not None else channel,
        sampling,
        camera.width,
        camera.height,
        stats,
    )
    comps = [
        PackedImage(
            plan=plan,
            camera=camera,
            fingerprint=meta.fingerprint,
            n=n,
            exponent=info.exponent,
            offset=0,
            span=vhi - vlo,
            ciphertexts=tiles_c,
            store_id=meta.store_id,
            stats=stats,
            meta=meta,
            level=0,
        )
        for tiles_c in per_comp
    ]
    return PackedColourImage(components=comps, colouring=colouring, stats=stats, channel=channel)


def colour_aggregate(
    ev: Any, plan: SlicePlan, backend: str, client: Any, progress: bool, seed: bytes, channel: str = "vector"
) -> tuple[int, dict]:
    """The server's half of a colour frame's tags' round for ``seed``: the vector tags' k components
    through the frame's plan in one map per column (:func:`map_components` on ``vector_tag``), per
    tile and component one aggregate with component j's coefficients from j·``plan.n_values``
    (:func:`~hevr.rendering.packed.verified.aggregate_tile`), and their product: one ciphertext for
    all k, A = Π_j A_j (the key holder checks D(A) = Σ_j (α·Σρ·V_j + Σρ·β_j) at once)."""
    meta = ev.meta
    if not meta.tags:
        raise ParameterError(f"verify: expected a verifiable store, got the packed store {meta.store_id} without tags")
    k = meta.components(channel)
    n, width = int(ev.public_key.n), meta.ciphertext_bytes
    tag = f"{meta.store_id}-{uuid.uuid4().hex}"
    per_tile, maps = map_graph(ev._plain(), plan, backend, None, tag_channel(channel), tag, map_components)
    tasks = [
        delayed(aggregate_tile, pure=True, nout=2)(
            plan,
            t,
            n,
            width,
            backend,
            seed,
            c * plan.n_values,
            *[p[c] for p in per_tile[t]],
            dask_key_name=f"hevr-packed-verify-{channel}-{tag}-{t}-{c}",
        )
        for t in range(plan.n_tiles)
        if per_tile[t]
        for c in range(k)
    ]
    results = run_tasks(tasks + maps, client=client, progress=progress, desc="verify") if tasks else []
    n2 = gmpy2.mpz(n) * n
    A = gmpy2.mpz(1)
    ops = {"map": sum(m["map"] for m in results[len(tasks) :])}
    for rec, counts in results[: len(tasks)]:
        if rec is not None:
            A = A * gmpy2.mpz(int.from_bytes(np.asarray(rec, np.uint8).tobytes(), "big")) % n2
        for name, v in counts.items():
            ops[name] = ops.get(name, 0) + v
    return int(A), ops


def render_packed_colour_request(
    ev: Any,
    camera: Any,
    mode: Any,
    density: Any,
    nodes: Any,
    sampling: Any,
    *,
    verify: Any,
    tile: Any,
    client: Any,
    progress: bool,
    backend: Any,
    weight_bits: Any,
    channel: str = "vector",
) -> PackedColourImage:
    """A transfer-function or emphasis frame of a packed store with the vector channel, after the
    request checks every packed frame has (:func:`hevr.rendering.packed.request.render_packed_request`):
    the colouring checked here (:class:`hevr.colour.Colouring`), ``verify`` resolved as for an X-ray
    (a verifiable store's colour frames are verified by default: :func:`colour_aggregate`)."""
    colouring = Colouring(mode, density, nodes)  # mode, density, nodes: checked before any work
    verified = resolve_verify(verify, ev, "client", level=getattr(ev, "level", 0), compute=True, stream=False)
    if getattr(ev, "remote", None) is not None:  # a store on hevr serve: the k components come from there
        return ev.render_packed_request(
            camera,
            sampling,
            tile=tile,
            weight_bits=weight_bits,
            backend=backend,
            client=client,
            verify=verified,
            colouring=colouring,
            channel=channel,
        )
    image = render_packed_colour(
        ev,
        camera,
        sampling,
        colouring,
        tile=tile,
        client=client,
        progress=progress,
        backend=backend,
        weight_bits=weight_bits,
        channel=channel,
    )
    if verified:  # the second round, as for an X-ray: the values are fixed here before the seed is drawn
        t0 = time.perf_counter()
        seed = secrets.token_bytes(32)
        A, ops = colour_aggregate(
            ev, image.plan, image.stats["backend"], active_client(client), progress, seed, channel
        )
        level = int(getattr(ev, "level", 0) or 0)
        image.verification = PackedVerification(
            aggregate=A,
            seed=seed,
            meta=ev.base if level else ev.meta,
            level=level,
            channel=channel,
            components=len(image.components),
            ops=ops,
            server_s=time.perf_counter() - t0,
            drawn_here=True,
            drawn_at=time.time(),
            known_name=str(ev.path),
        )
        image.stats["verify"] = {"server_s": image.verification.server_s, "ops": ops}
    return image
