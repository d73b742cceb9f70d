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
3. keeps A = Π_t A_t with the image (:class:`Verification`, in this process only).

Decryption checks before it returns any pixel (:meth:`Verification.check`): with S'_{r,k} the ray
sums the image decrypts to (its values less the public offset, client finishing) and B_{r,k} =
Σ_v w_{r,v}·β_{v,k} recomputed here from the public geometry (the same
:func:`~hevr.rendering.geometry.weights.brick_weights` the map tasks use, brick by brick, and the PRF),

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
built as its values are: β_L(v) = 125·Σ of its 8 children's, :func:`level_betas`), streamed or
resident (the tag channel is always streamed). Not verified: server finishing (``finish="server"``:
its pixels are not the ray sums the tags protect), ``compute=False`` and the streaming viewer;
``verify=True`` there is refused with a :class:`hevr.ParameterError`, and the default
``verify=None`` renders them unverified with a warning.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import re
import secrets
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import dask
import gmpy2
import numpy as np

from ..backends import get_backend
from ..crypto.tags import (
    aggregate_holds,
    betas,
    coefficients_at,
    tag_channel,
    tag_key_of,
    weighted_beta_total,
)
from ..errors import HevrError, IntegrityError, ParameterError, VerificationError
from ..runtime.scheduler import compute as run_tasks
from ..store.authenticity import authenticated_fields, check_metadata_mac
from ..store.known import check_known, record_verified
from ..store.metadata import VolumeMetadata
from ..store.pyramid import LEVEL_FACTOR
from ..volume.pyramid import MAX_LEVELS, level_shape
from .geometry.footprint import brick_footprints
from .geometry.plane import view_from_dict
from .geometry.rays import RaySet, cast_rays
from .geometry.weights import brick_bounds, brick_weights
from .pipeline.graph import build_sums_graph
from .pipeline.kernel import plan_products

log = logging.getLogger(__name__)
_STORE_ID = re.compile(r"[0-9a-f]{16}")
_WARNED: set = set()

__all__ = ["Verification", "aggregate_for", "aggregate_tile", "level_betas", "resolve_verify", "tag_aggregate"]


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


_CHILDREN = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)])  # z, y, x offsets of 8 children


def level_betas(
    key: Any,
    store_id: str,
    channel: str,
    component: int,
    level: int,
    voxels: Any,
    base_shape: tuple,
    cache: dict | None = None,
) -> np.ndarray:
    """β of the flat voxel indices ``voxels`` of pyramid ``level`` as ``(len, nl)`` uint32 limbs: the
    level's tags are built as its values are (:mod:`hevr.store.pyramid`), 125 ⊗ the product of the 8
    children's (clamped at the far edges, as there), so β_L(v) = 125·Σ β_{L−1}(child), down to level
    0's PRF values — in numpy, in 16-bit pieces with carries (``cache`` as for :func:`betas`).

    >>> from hevr.crypto.tags import TagKey
    >>> k = TagKey(1, bytes(32), 2**200)
    >>> as_int = lambda a: [int.from_bytes(r.astype("<u4").tobytes(), "little") for r in a]
    >>> b0 = as_int(level_betas(k, "s", "scalar", 0, 0, range(8), (2, 2, 2)))
    >>> as_int(level_betas(k, "s", "scalar", 0, 1, [0], (2, 2, 2))) == [125 * sum(b0)]
    True
    >>> as_int(level_betas(k, "s", "scalar", 0, 1, [0], (1, 1, 1))) == [125 * 8 * b0[0]]  # itself 8 times
    True
    """
    v = np.asarray(voxels, dtype=np.int64).reshape(-1)
    if level == 0:
        return betas(key, store_id, channel, 0, component, v, cache)
    shape, below = level_shape(base_shape, level), level_shape(base_shape, level - 1)
    zyx = np.stack(np.unravel_index(v, shape), axis=1)
    kids = np.minimum(zyx[:, None, :] * 2 + _CHILDREN[None], np.asarray(below) - 1).reshape(-1, 3)
    uniq, inverse = np.unique(np.ravel_multi_index(tuple(kids.T), below), return_inverse=True)
    sub = level_betas(key, store_id, channel, component, level - 1, uniq, base_shape, cache)
    pieces = np.ascontiguousarray(sub, dtype="<u4").view("<u2").astype(np.uint64)  # (U, P), each < 2^16
    x = pieces[inverse.reshape(-1, 8)].sum(axis=1) * np.uint64(LEVEL_FACTOR)  # < 8·125·2^16 < 2^26
    cols = [x[:, j] for j in range(x.shape[1])]
    j = 0
    while j < len(cols):  # carries into 16-bit pieces, as many as needed
        carry = cols[j] >> np.uint64(16)
        cols[j] = cols[j] & np.uint64(0xFFFF)
        if carry.any():
            if j + 1 == len(cols):
                cols.append(np.zeros_like(carry))
            cols[j + 1] = cols[j + 1] + carry
        j += 1
    if len(cols) % 2:
        cols.append(np.zeros_like(cols[0]))
    out = np.stack(cols, axis=1).astype("<u2")
    return np.ascontiguousarray(out).view("<u4")


def _footprint_rays(rays: RaySet, rect: tuple, hit: np.ndarray) -> RaySet:
    """The hit rays of the pixel rectangle ``rect`` (rows ``[r0, r1)``, columns ``[c0, c1)``) as a
    subset of ``rays`` (global pixel ids kept): what a map task casts for its brick, so its weights
    are the same (every ray's geometry is computed elementwise)."""
    if rays.pixel_ids is not None:  # already a subset: as it is
        return rays
    r0, r1, c0, c1 = rect
    W = rays.width
    ids = (np.arange(r0, r1)[:, None] * W + np.arange(c0, c1)[None, :]).reshape(-1)
    ids = ids[hit[ids]]
    return dataclasses.replace(
        rays,
        origins=rays.origins[ids],
        directions=rays.directions[ids],
        t_enter=rays.t_enter[ids],
        t_exit=rays.t_exit[ids],
        n_samples=rays.n_samples[ids],
        pixel_ids=ids,
        t_index=None if rays.t_index is None else rays.t_index[ids],
    )


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


@dataclass(frozen=True, repr=False)
class Verification:
    """What the client keeps of a verified render: the aggregate A, the seed of the coefficients
    and the public geometry to recompute Σρ·B (no secret: A is a ciphertext)."""

    aggregate: int
    seed: bytes
    store_id: str
    channel: str
    shape: tuple
    spacing: tuple
    brick: tuple
    camera: Any
    sampling: str
    step: float
    digits: int
    components: int
    n: int
    level: int = 0
    base_shape: tuple = ()
    exponent: int = 0
    server_s: float = 0.0
    meta: Any = None  # the store's (level-0) VolumeMetadata the render used; its owner's MAC is checked
    drawn_here: bool = False  # the seed was drawn in this process (not read from a file)
    known_name: str = dataclasses.field(default="", compare=False)  # rendered under (known stores; not in files)
    drawn_at: float = 0.0  # when (seconds since the epoch; a file's stamp keeps it as rendered_at)

    def __repr__(self) -> str:
        return f"Verification({self.channel}, {self.components} per ray, seed …)"

    @classmethod
    def of(
        cls,
        ev: Any,
        camera: Any,
        sampling: str,
        step: float,
        digits: int,
        channel: str,
        *,
        exponent: int,
        aggregate: int,
        seed: bytes,
        server_s: float = 0.0,
    ) -> Verification:
        """The record of a round on the volume (or level view) ``ev`` as the key holder knows it:
        every field but the aggregate comes from this process, never from the server — with the
        store's metadata this process rendered with, whose owner's MAC :meth:`check` verifies."""
        base = ev.base if ev.level else ev.meta  # level 0's VolumeMetadata
        return cls(
            aggregate=int(aggregate),
            seed=seed,
            store_id=ev.meta.store_id,
            channel=channel,
            shape=ev.shape,
            spacing=ev.spacing,
            brick=ev.brick,
            camera=camera,
            sampling=sampling,
            step=step,
            digits=digits,
            components=ev.meta.components(channel),
            n=int(ev.public_key.n),
            level=ev.level,
            exponent=int(exponent),
            base_shape=tuple(base.shape),
            server_s=server_s,
            meta=base,
            drawn_here=True,
            drawn_at=time.time(),
            known_name=str(ev.path),
        )

    def to_dict(self) -> dict[str, Any]:
        """The record a ``.hevr`` file carries (public: a ciphertext, a seed, the request's geometry)."""
        return {
            "version": 2,
            "aggregate": str(self.aggregate),
            "seed": self.seed.hex(),
            "store_id": self.store_id,
            "channel": self.channel,
            "shape": [int(x) for x in self.shape],
            "spacing": [float(x) for x in self.spacing],
            "brick": [int(x) for x in self.brick],
            "view": self.camera.to_dict(),
            "sampling": self.sampling,
            "step": float(self.step),
            "digits": int(self.digits),
            "components": int(self.components),
            "level": int(self.level),
            "base_shape": [int(x) for x in (self.base_shape or self.shape)],
            "exponent": int(self.exponent),
            "metadata": self.meta.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Any, n: int, where: str = "image") -> Verification:
        """Parse :meth:`to_dict`'s record under the image's modulus ``n``;
        :class:`hevr.IntegrityError` names the first wrong field."""

        def bad(name: str, expected: str) -> IntegrityError:
            got = d.get(name) if isinstance(d, dict) else d
            return IntegrityError(
                f"{where}: header field 'verification.{name}': expected {expected}, got {str(got)[:80]!r}"
            )

        fields = {
            "version",
            "aggregate",
            "seed",
            "store_id",
            "channel",
            "shape",
            "spacing",
            "brick",
            "view",
            "sampling",
            "step",
            "digits",
            "components",
            "level",
            "base_shape",
            "exponent",
            "metadata",
        }
        if not isinstance(d, dict) or set(d) != fields:
            raise bad(
                "version",
                f"an object with exactly {sorted(fields)} (version 2; a frame verified before "
                "hevr bound the store's metadata: render it again)",
            )
        if d["version"] != 2 or type(d["version"]) is not int:
            raise bad("version", "2")
        agg = d["aggregate"]
        if not (isinstance(agg, str) and agg.isdigit() and len(agg) <= 2 * len(str(n)) and 0 < int(agg) < n * n):
            raise bad("aggregate", "a decimal string of a ciphertext in (0, n²)")
        seed = d["seed"]
        if not (isinstance(seed, str) and len(seed) == 64 and all(c in "0123456789abcdef" for c in seed)):
            raise bad("seed", "64 lower-case hex digits")
        if not (isinstance(d["store_id"], str) and len(d["store_id"]) == 16):
            raise bad("store_id", "a store id of 16 hex digits")
        if d["channel"] not in ("scalar", "vector", "gradient"):
            raise bad("channel", "'scalar', 'vector' or 'gradient'")
        for name, kind in (("shape", int), ("brick", int), ("spacing", float), ("base_shape", int)):
            v = d[name]
            if not (
                isinstance(v, list)
                and len(v) == 3
                and all(type(x) is kind or (kind is float and type(x) is int) for x in v)
                and all(x > 0 for x in v)
            ):
                raise bad(name, f"three positive {kind.__name__}s")
        if d["sampling"] not in ("nearest", "trilinear"):
            raise bad("sampling", "'nearest' or 'trilinear'")
        if not (type(d["step"]) in (int, float) and 0 < d["step"] < float("inf")):
            raise bad("step", "a positive number")
        for name, lo, hi in (("digits", 0, 12), ("components", 0, 64), ("level", 0, MAX_LEVELS), ("exponent", -64, 64)):
            if type(d[name]) is not int or not lo <= d[name] <= hi:
                raise bad(name, f"an integer in [{lo}, {hi}]")
        try:
            view = view_from_dict(d["view"])
        except HevrError as exc:
            raise bad("view", f"a camera or plane ({exc})") from None
        try:
            meta = VolumeMetadata.from_dict(d["metadata"], where=f"{where}: verification.metadata")
        except HevrError as exc:
            raise bad("metadata", f"a verifiable store's metadata ({exc})") from None
        if not meta.tags or meta.store_id != d["store_id"] or int(meta.n) != int(n):
            raise bad("metadata", "the metadata of the verifiable store the record names, under the image's key")
        if tuple(d["base_shape"]) != meta.shape:
            raise bad("base_shape", f"the store's shape {list(meta.shape)}")
        if d["level"] > len(meta.levels) and d["level"]:
            raise bad("level", f"a level of the store's pyramid (0 to {len(meta.levels)})")
        lm = meta.level_meta(d["level"]) if d["level"] else meta
        if tuple(d["shape"]) != tuple(lm.shape) or tuple(d["brick"]) != tuple(lm.brick):
            raise bad(
                "shape", f"the shape {list(lm.shape)} and brick {list(lm.brick)} of level {d['level']} of the store"
            )
        return cls(
            aggregate=int(agg),
            seed=bytes.fromhex(seed),
            store_id=d["store_id"],
            channel=d["channel"],
            shape=tuple(d["shape"]),
            spacing=tuple(float(x) for x in d["spacing"]),
            brick=tuple(d["brick"]),
            camera=view,
            sampling=d["sampling"],
            step=float(d["step"]),
            digits=d["digits"],
            components=d["components"],
            n=int(n),
            level=d["level"],
            base_shape=tuple(d["base_shape"]),
            exponent=d["exponent"],
            meta=meta,
        )

    def beta_sum(self, private_key: Any, rays: RaySet | None = None) -> int:
        """Σ_{r,k} ρ_{r,k}·B_{r,k} mod n from the public geometry and the PRF (module docstring):
        brick by brick, on a thread per core (the geometry's numpy work releases the GIL)."""
        key = tag_key_of(private_key)
        rays = rays if rays is not None else cast_rays(self.camera, self.shape, self.spacing, self.step)
        cache: dict = {}  # β blocks shared by neighbouring bricks (a race only recomputes a block)
        # the bricks whose footprint holds a hit pixel (O(bricks + pixels), as the render graph picks its
        # map tasks): a superset of the touched ones, whose extra bricks add nothing (empty weights)
        hit = np.asarray(rays.n_samples) > 0
        prints = brick_footprints(
            self.camera, self.shape, self.spacing, self.brick, hit, max(self.camera.width, self.camera.height)
        )
        with ThreadPoolExecutor(max_workers=max(1, min(os.cpu_count() or 1, 8))) as pool:
            parts = list(
                pool.map(
                    lambda item: self._brick_beta_sum(key, _footprint_rays(rays, item[1].rect, hit), item[0], cache),
                    prints.items(),
                )
            )
        return sum(parts) % self.n

    def _brick_beta_sum(self, key: Any, rays: RaySet, index: tuple, cache: dict) -> int:
        K = self.components
        bw = brick_weights(rays, self.shape, self.spacing, self.brick, index, self.sampling, self.step, self.digits)
        if not bw.rays.size:
            return 0
        _, ny, nx = self.shape
        (z0, z1), (y0, y1), (x0, x1) = brick_bounds(self.shape, self.brick, index)
        zz, yy, xx = np.meshgrid(np.arange(z0, z1), np.arange(y0, y1), np.arange(x0, x1), indexing="ij")
        used, local = np.unique(bw.voxels, return_inverse=True)  # β of the voxels the rays reach only
        glob = ((zz * ny + yy) * nx + xx).reshape(-1)[used]
        rho = coefficients_at(self.seed, (bw.rays[:, None] * K + np.arange(K)).reshape(-1)).reshape(-1, K)
        total = 0
        for k in range(K):
            beta = level_betas(key, self.store_id, self.channel, k, self.level, glob, self.base_shape, cache)
            total += weighted_beta_total(beta, bw.indptr, local.reshape(-1), bw.weights, rho[:, k])
        return total

    def check_metadata(self, private_key: Any, image: Any) -> None:
        """Raise :class:`hevr.VerificationError` unless the store's metadata this render used carries
        the owner's MAC (:mod:`hevr.store.authenticity`) and the record's geometry, channel and key
        are the ones it gives at the record's level."""
        m = self.meta
        if m is None or not check_metadata_mac(private_key, authenticated_fields(m.to_dict()), m.auth):
            raise VerificationError(
                "store metadata: expected the owner's MAC over the shape, spacing, brick, channels, exponents, digits, "
                f"value range and store id, got {'none' if m is None or not m.auth else 'a MAC that does not match'}: "
                "the store's public metadata was altered (or is not this key's); no image is returned"
            )
        lm = m.level_meta(self.level) if self.level else m
        want = (
            m.store_id,
            int(m.n),
            m.fingerprint,
            tuple(lm.shape),
            tuple(float(x) for x in lm.spacing),
            tuple(lm.brick),
            tuple(m.shape),
            lm.components(self.channel),
        )
        got = (
            self.store_id,
            int(self.n),
            image.fingerprint,
            tuple(self.shape),
            tuple(float(x) for x in self.spacing),
            tuple(self.brick),
            tuple(self.base_shape),
            self.components,
        )
        if want != got or getattr(lm, self.channel) is None:
            raise VerificationError(
                "image: its store id, key, shape, spacing, brick or channel are not those of the "
                "store's authenticated metadata; no image is returned"
            )

    def check(self, private_key: Any, image: Any, ray_ids: np.ndarray, sums: list[int]) -> None:
        """Raise :class:`hevr.VerificationError` unless the ``image``'s public fields are those of
        this view (shape, channel, exponent, components, sample counts, hit mask) and D(A) = α·Σρ·S' + Σρ·B
        (mod n); ``sums`` are its decrypted ray sums S' (offset removed), ``K`` per ray of
        ``ray_ids``."""
        t0 = time.perf_counter()
        self.check_metadata(private_key, image)
        K = self.components
        rays = cast_rays(self.camera, self.shape, self.spacing, self.step)
        H, W = self.camera.height, self.camera.width
        samples = np.asarray(rays.n_samples).reshape(H, W)
        same = (
            tuple(image.shape[:2]) == (H, W)
            and image.finish == "client"
            and image.channel == self.channel
            and int(image.exponent) == self.exponent
            and int(image.components or 0) == K
            and image.samples is not None
            and image.hits is not None
            and np.array_equal(np.asarray(image.samples).reshape(H, W), samples)
            and np.array_equal(np.asarray(image.hits, bool), samples > 0)
        )
        if not same:
            raise VerificationError(
                "image: its shape, channel, exponent, components, sample counts or hit mask are "
                f"not those of the verified view ({W}x{H}, channel {self.channel!r}); no image is "
                "returned"
            )
        ids = (np.asarray(ray_ids, np.int64)[:, None] * K + np.arange(K)).reshape(-1)
        if ids.size != len(sums):
            raise VerificationError(
                f"image: expected {ids.size} ray sums for its hit pixels, got {len(sums)}; no image is returned"
            )
        rho = coefficients_at(self.seed, ids).tolist()
        s_sum = sum(int(r) * int(s) for r, s in zip(rho, sums))
        holds = aggregate_holds(private_key, s_sum, self.beta_sum(private_key, rays), self.aggregate)
        log.info("verification: %.3f s on the client", time.perf_counter() - t0)
        if not holds:
            raise VerificationError(
                "image: the render does not verify: its ray sums are not the ones the store's tags certify (an "
                "altered, substituted or replayed image or store, or a server that did not render as asked); "
                "no image is returned"
            )
        record_verified(self, private_key)  # proven: the store under its name is the one the key holder knows
