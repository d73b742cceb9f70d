"""Verified renders: the server's tag sums and the client's check (issue 28; the scheme and its
soundness: :mod:`hevr.crypto.tags`).

A verifiable store (``encrypt_volume(..., verifiable=True)``) holds beside every channel ``c`` a tag
channel ``c_tag`` of E(α·m_v + β_v). A render with ``verify`` (the default on such a store)

1. renders the image as usual; its ciphertexts are then fixed, in the client's hands;
2. draws a fresh seed (:func:`secrets.token_bytes`) and only then asks the server for one more
   graph: the tag channel's ray sums T_{r,k} with exactly the image's plan (same bricks, weights,
   merges: :func:`~hevr.rendering.pipeline.graph.build_sums_graph`), and per image tile one aggregation
   task, A_t = Π_{r,k} T_{r,k}^{ρ_{r,k}} mod n², ρ_{r,k} the 62-bit coefficient of index
   r·K + k of the seed's stream (:func:`hevr.crypto.tags.coefficients_at`), computed as one
   multi-exponentiation row by the backend;
3. keeps A = Π_t A_t with the image (:class:`~hevr.rendering.verification.Verification`, in this
   process only).

Decryption checks before it returns any pixel (:meth:`~hevr.rendering.verification.Verification.check`):
with S'_{r,k} the ray sums the image decrypts to (its values less the public offset, client finishing)
and B_{r,k} = Σ_v w_{r,v}·β_{v,k} recomputed here from the public geometry (the same
:func:`~hevr.rendering.geometry.weights.brick_weights` the map tasks use, brick by brick, and the PRF:
:mod:`hevr.rendering.tag_betas`),

    D(A) ≡ α·Σ ρ_{r,k}·S'_{r,k} + Σ ρ_{r,k}·B_{r,k}   (mod n),

else :class:`hevr.VerificationError` and no image. The client's cost: the geometry of every brick
(tens of ms at the paper case), the β of the voxels the rays reach (SHAKE-256, 16 bytes each), exact
weighted sums in numpy and one decryption. The server's: the tag map (as much again as the image's)
and ~8 products per ray and component for the aggregate (62-bit exponents, 8-bit windows).

Which store. The tags prove "this is the render of the store with id ``store_id``" — the id the
store's own metadata states. A server holding several verifiable stores of one key (other patients,
an older version) could answer with another, and a store without tags renders unverified under
``verify=None``. Against a server that may lie, pass ``verify=<store id>`` (``ev.meta.store_id`` as
:func:`hevr.encrypt_volume` returned it, printed by ``hevr encrypt``; ``hevr render --verify ID``):
the render is then verified and refused for any other store; ``verify=True`` at least refuses a store
without tags.

Scope. Camera renders and slices with client finishing, at any pyramid level (a level's tags are
built as its values are: β_L(v) = 125·Σ of its 8 children's,
:func:`~hevr.rendering.tag_betas.level_betas`), streamed or resident (the tag channel is always
streamed). Not verified: server finishing (``finish="server"``: its pixels are not the ray sums the
tags protect), ``compute=False`` and the streaming viewer; ``verify=True`` there is refused with a
:class:`hevr.ParameterError`, and the default ``verify=None`` renders them unverified with a
warning.
"""

from __future__ import annotations

import logging
import re
import secrets
import time
from typing import Any

import dask
import gmpy2
import numpy as np

from ..backends import get_backend
from ..crypto.tags import (
    coefficients_at,
    tag_channel,
)
from ..errors import ParameterError, VerificationError
from ..runtime.scheduler import compute as run_tasks
from ..store.known import check_known
from .geometry.rays import RaySet
from .pipeline.graph import build_sums_graph
from .pipeline.kernel import plan_products
from .verification import Verification

log = logging.getLogger(__name__)
_STORE_ID = re.compile(r"[0-9a-f]{16}")
_WARNED: set = set()

__all__ = ["aggregate_for", "aggregate_tile", "resolve_verify", "tag_aggregate"]


def resolve_verify(verify: Any, ev: Any, finish: str, *, level: int, compute: bool, stream: bool) -> bool:
    """Whether a render is verified: ``verify`` checked against what the store and request allow
    (module docstring); None: yes where the store is verifiable (or recorded so in the key holder's
    known stores, :mod:`hevr.store.known`, which also refuses another store under a known name) and
    the request supported; a store id: yes, and only for that store (:class:`hevr.VerificationError`
    for another). ``stream``: a streamed frame (verified when it has settled: :func:`hevr.render_frame`)."""
    if isinstance(verify, str):  # the store id the owner recorded: verify, and refuse any other store
        if not _STORE_ID.fullmatch(verify):
            raise ParameterError(
                f"verify: expected True, False, None or a store id of 16 lower-case hex digits, got {verify[:40]!r}"
            )
        if ev.meta.store_id != verify:
            raise VerificationError(
                f"verify: expected the store {verify}, got the store {ev.meta.store_id} at "
                f"{ev.path}: another store (of the same key?) was served; nothing was rendered"
            )
    elif verify is not None and not isinstance(verify, (bool, np.bool_)):
        raise ParameterError(f"verify: expected True, False, None or a store id, got {verify!r}")
    if verify is not None and not verify:
        return False
    check_known(ev)  # another store, or one stripped of its tags, under a known name: refused here
    why = (
        "the store has no tags (encrypt it with verifiable=True)"
        if not ev.meta.tags
        else "finish='server' (verification checks the ray sums, which client finishing decrypts)"
        if finish != "client"
        else "compute=False (the check needs a second round after the image)"
        if not compute
        else None
    )
    if why is None:
        return True
    if verify:
        raise ParameterError(f"verify: expected a request that can be verified, got {why}")
    if not ev.meta.tags:  # every render: a store without tags is a silent downgrade otherwise
        log.warning(
            "render: not verified: %s, store %s (a lying server is not caught; verify=False silences this)",
            why,
            ev.meta.store_id,
        )
    elif (ev.meta.store_id, why) not in _WARNED:  # once per store and reason
        _WARNED.add((ev.meta.store_id, why))
        log.warning("render: not verified: %s", why)
    return False


def aggregate_tile(
    merged: Any, seed: bytes, width: int, components: int, nsquare: int, backend: str = "cpu"
) -> np.ndarray | None:
    """One server task: A_t = Π T_{r,k}^{ρ_{r,k}} mod n² over a tile's merged tag sums ``(rays,
    records)`` as one ``(W,)`` record (None: no ray of the tile has tag sums)."""
    if merged is None:
        return None
    rays, recs = merged
    if not len(rays):
        return None
    be = get_backend(backend)
    ids = (np.asarray(rays, np.int64)[:, None] * components + np.arange(components)).reshape(-1)
    rho = coefficients_at(seed, ids)
    batch = be.from_bytes(np.ascontiguousarray(recs).reshape(-1, width))
    plan = plan_products(np.array([0, ids.size]), np.arange(ids.size), rho, ids.size)
    (out,) = be.ray_products(plan, [batch], nsquare)
    return be.to_bytes(out, width)[0]


def tag_aggregate(
    ev: Any,
    camera: Any,
    rays: RaySet,
    sampling: str,
    step: float,
    digits: int,
    channel: str,
    tile: int,
    n_tiles: int,
    backend: str,
    client: Any,
    progress: bool,
    exponent: int = 0,
) -> Verification:
    """Steps 2-3 of the module docstring, after the image: a fresh seed drawn here, the tag
    channel's graph with the image's plan and one aggregation task per tile; the
    :class:`Verification` to keep."""
    seed = secrets.token_bytes(32)
    t0 = time.perf_counter()
    A = aggregate_for(ev, camera, rays, sampling, step, digits, channel, tile, n_tiles, backend, client, progress, seed)
    return Verification.of(
        ev,
        camera,
        sampling,
        step,
        digits,
        channel,
        exponent=exponent,
        aggregate=A,
        seed=seed,
        server_s=time.perf_counter() - t0,
    )


def aggregate_for(
    ev: Any,
    camera: Any,
    rays: RaySet,
    sampling: str,
    step: float,
    digits: int,
    channel: str,
    tile: int,
    n_tiles: int,
    backend: str,
    client: Any,
    progress: bool,
    seed: bytes,
) -> int:
    """The server's half of the round for the coefficients of ``seed``: A = Π_t A_t mod n² over the
    tag channel's ray sums of the image's plan (``hevr serve`` runs it for a seed the key holder sent
    after it held the image)."""
    plain = ev._plain()  # the tags are always read from the store
    graph = build_sums_graph(plain, camera, rays, sampling, step, digits, tag_channel(channel), tile, n_tiles, backend)
    K, W, n2 = ev.meta.components(channel), ev.meta.ciphertext_bytes, int(ev.public_key.nsquare)
    task = dask.delayed(aggregate_tile, pure=True)
    tasks = [task(graph.delayed(t), seed, W, K, n2, backend) for t in range(n_tiles) if graph.merged.get(t) is not None]
    parts = run_tasks(tasks, client=client, progress=progress, desc="verify") if tasks else []
    A = gmpy2.mpz(1)
    for rec in parts:
        if rec is not None:
            A = A * gmpy2.mpz(int.from_bytes(np.asarray(rec, np.uint8).tobytes(), "big")) % n2
    return int(A)
