"""Transfer-function and emphasis frames of packed stores: the vector channel's k ray sums per
intermediate ray, coloured by the key holder (:mod:`hevr.colour`).

A packed store encrypted with ``vector_dims=k`` (:mod:`hevr.store.packed_brick`) holds, beside the
scalar packs, the k components of the density encoding e(d) packed alike: the same S slots of K
bits along the same axis, slot value = the component's mantissa rint(e(d)_c·10^digits) (offset 0).
A frame's weights depend on the view only, never on the channel, so the scalar frame's plan
(:class:`~hevr.rendering.packed.plan.SlicePlan`) serves all k components:

* **map** (one task per column of bricks, :func:`map_components`): the column's pairs and one
  product plan (:func:`~hevr.rendering.pipeline.kernel.plan_products`), run on the k components'
  batches at once (``ray_products`` takes k components for one plan);
* **merge and combine** (one task per tile, :func:`merge_components`): the scalar frame's
  :func:`~hevr.rendering.packed.graph.merge_tile`, once per component;
* **the key holder** (:class:`PackedColourImage`): each component's values decoded and checked as
  an X-ray frame's (:class:`~hevr.rendering.packed.image.PackedImage`: integrity margin, every slot
  at most 10^digits·W of its ray), divided by the public sample count and weight unit — the ray's
  mean x_c of component c — warped to the camera's pixels, then coloured exactly as a per-voxel
  client-finished frame is (:func:`hevr.colour.colour`: emphasis x·e(density), transfer function
  (1/N)·x·Σ_i e(d_i)·c_i^T). The warp is linear, so warping the means and colouring commute.

The colouring never leaves the key holder's process (not pickled, never sent). Its reference is
``hevr.render_plain(vol, cam, mode=..., vector_dims=k, slices=True)`` and its bound
:func:`hevr.error_bound` (:mod:`hevr.rendering.packed.sliced`). A verifiable store's colour frame is
verified by default as an X-ray is (:func:`colour_aggregate`): one seed drawn after the values, the
vector tags' k components through the same plan, one aggregate for all k (component j's coefficients
from j·n_values), all components' values checked against it before any mean is formed. Not yet:
frame files.
"""

from __future__ import annotations

import logging
import secrets
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import gmpy2
import numpy as np
from dask.delayed import delayed

from ...backends import get_backend
from ...backends.base import OpCounter
from ...colour import Colouring, Frame, colour, colouring_spec
from ...crypto.tags import data_channel, tag_channel
from ...errors import ParameterError
from ...image.provenance import check_provenance
from ...runtime.scheduler import active_client
from ...runtime.scheduler import compute as run_tasks
from ...store.packing import mantissa_range
from ..pipeline.kernel import plan_products
from ..verify import resolve_verify
from . import files
from .graph import column_pairs, map_graph, merge_tile, render_context, resident_bricks
from .image import PackedImage, decode
from .plan import SlicePlan
from .verified import PackedVerification, aggregate_tile

log = logging.getLogger(__name__)

__all__ = [
    "PackedColourImage",
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
) -> tuple[list[np.ndarray], dict]:
    """Tile ``t`` of each component: :func:`~hevr.rendering.packed.graph.merge_tile` on the
    component's partial accumulators (``parts``: per map task a list of k (keys, records))."""
    out, ops = [], {}
    for c in range(k):
        recs, counts = merge_tile(plan, t, n, width, backend, *[p[c] for p in parts])
        out.append(recs)
        for name, v in counts.items():
            ops[name] = ops.get(name, 0) + v
    return out, ops


@dataclass
class PackedColourImage:
    """An encrypted transfer-function or emphasis frame of a packed store (``hevr.render(ev, cam,
    mode="tf", nodes=...)`` or ``mode="emphasize", density=...`` on a store with the vector channel).

    Attributes
    ----------
    components : list of PackedImage
        Per component c of e(d), its frame of ray sums (the plan, decoding and checks of an X-ray
        frame; values are the component's means, in [0, 1]).
    colouring : Colouring or None
        The render's colouring: kept in this process only (never pickled, saved or sent);
        :meth:`decrypt` applies it unless given another.
    stats : dict
        ``ops`` (map, merge, combine over all components), ``components``, ``ciphertexts``, …
    """

    components: list = field(repr=False)
    colouring: Any = field(default=None, repr=False, compare=False)
    stats: dict = field(default_factory=dict, repr=False)
    verification: Any = field(default=None, repr=False, compare=False)  # one PackedVerification, all k components
    channel: str = "vector"  # or "gradient": g·e(d), the gradient-modulated encoding
    stamp: Any = field(default=None, repr=False, compare=False)  # a file's (stamp, message, saved as, read as)

    def __getstate__(self) -> dict:
        return dict(self.__dict__, colouring=None)

    @property
    def plan(self) -> SlicePlan:
        return self.components[0].plan

    @property
    def meta(self) -> Any:
        """The store's metadata (level 0's; colour frames have no level)."""
        return self.components[0].meta

    level = 0
    finish = "client"  # coloured by the key holder, as a per-voxel client-finished frame

    @property
    def ciphertexts(self) -> list:
        """Every component's tiles, component-major (the frame file's order)."""
        return [t for c in self.components for t in c.ciphertexts]

    @property
    def camera(self) -> Any:
        return self.components[0].camera

    @property
    def fingerprint(self) -> str:
        return self.components[0].fingerprint

    @property
    def store_id(self) -> str:
        return self.components[0].store_id

    @property
    def n(self) -> int:
        return self.components[0].n

    @property
    def shape(self) -> tuple[int, int]:
        return self.components[0].shape

    @property
    def n_ciphertexts(self) -> int:
        return int(sum(c.n_ciphertexts for c in self.components))

    @property
    def verified(self) -> bool:
        """Whether the frame carries a check of all k components against the vector channel's tags
        (drawn in this process), which its decryption runs before any mean is formed."""
        return self.verification is not None

    def decrypt_sums(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """The exact integer ray sums Σ w·q_c of every component c and intermediate ray, (k, N_i, N_j)
        int64: every component's values checked as an X-ray frame's, and a verified frame's all k
        against the tags at once (one aggregate), before any sum is returned."""
        first = self.components[0]
        key = first._key(private_key)
        check_provenance(
            key, self, require_verified, "a store encrypted with verifiable=False, or a render with verify=False"
        )
        if self.verification is not None:  # the metadata first: it says what every number means
            self.verification.check_metadata(key, self.plan, self.fingerprint)
        tiles = [c._decrypted_tiles(key, backend) for c in self.components]
        sums = np.stack([decode(self.plan, t, c.span) for t, c in zip(tiles, self.components)])
        if self.verification is not None:
            t0 = time.perf_counter()
            self.verification.check(key, self.plan, tiles, self.fingerprint)
            self.stats["check_s"] = time.perf_counter() - t0
        return sums

    def decrypt_means(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> np.ndarray:
        """Per pixel the mean of each component over its ray's samples, warped to the camera: (H, W, k) float64."""
        geo = self.plan.geometry
        coords = geo.pixel_coords(self.camera)
        sums = self.decrypt_sums(private_key, backend, require_verified=require_verified)
        return np.stack(
            [geo.warp(c._values(s), coords).reshape(self.shape) for c, s in zip(self.components, sums)], axis=-1
        )

    def decrypt_frame(
        self, private_key: Any, backend: str | None = None, *, require_verified: bool | str | None = None
    ) -> Frame:
        """A :class:`hevr.Frame` of the warped means, to colour (and re-colour) on this machine, checked
        as :meth:`decrypt` checks; its ``n_samples`` are the intermediate rays' sample counts warped to
        the pixels, rounded."""
        t0 = time.perf_counter()
        means = self.decrypt_means(private_key, backend, require_verified=require_verified)
        plan = self.plan
        geo = plan.geometry
        counts = geo.warp(geo.sample_counts(plan.sampling).astype(np.float64), geo.pixel_coords(self.camera))
        stats = dict(self.stats, decrypt_s=time.perf_counter() - t0, ciphertexts=self.n_ciphertexts)
        return Frame(
            means=means,
            n_samples=np.rint(counts).astype(np.int64).reshape(self.shape),
            channel=self.channel,
            colouring=self.colouring,
            stats=stats,
        )

    def decrypt(
        self,
        private_key: Any,
        backend: str | None = None,
        *,
        mode: str | None = None,
        density: float | None = None,
        nodes: Any = None,
        require_verified: bool | str | None = None,
    ) -> np.ndarray:
        """The coloured (H, W) (emphasize) or (H, W, 3) (tf) float64 image: with ``mode`` /
        ``density`` / ``nodes`` when given, else the render's own colouring (:func:`hevr.colour.colour`).
        A verified frame's components are each checked against the vector channel's tags first;
        ``require_verified`` (True or a store id) refuses a frame without those checks."""
        spec = colouring_spec(self.channel, len(self.components), mode, density, nodes, self.colouring)
        return colour(self.decrypt_means(private_key, backend, require_verified=require_verified), spec)

    def save(
        self, path: Any, *, overwrite: bool = False, storage_options: dict | None = None, private_key: Any = None
    ) -> None:
        """Write the frame file (a packed frame file with the ``channel`` field: the k components'
        tiles, component-major; ``docs/format.md``), as :meth:`PackedImage.save` does; the colouring
        is not saved (``hevr decrypt --tf / --density`` colours at decryption)."""
        files.save_packed(self, path, overwrite=overwrite, storage_options=storage_options, private_key=private_key)

    def to_bytes(self, private_key: Any = None) -> bytes:
        """The frame file as bytes (:meth:`save`'s rules)."""
        return files.packed_bytes(self, private_key)

    def __repr__(self) -> str:
        return (
            f"PackedColourImage(shape={self.shape}, components={len(self.components)}, "
            f"sampling={self.plan.sampling!r}, ciphertexts={self.n_ciphertexts}, key={self.fingerprint[:16]}…)"
        )


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
