"""Verified packed frames: the tags' aggregate on the server and the key holder's check.

A verifiable packed store holds beside every packed ciphertext Enc(P[A]) its tag
t_A = Enc(α·P[A] + β_A mod n), β_A the PRF value of the pack's flat index in the packed array
(:mod:`hevr.crypto.tags`, :mod:`hevr.store.packed_brick`). A frame's combined value of block B
and row j is a public linear function of the packs,

    V[j, B] = Σ_c 2^(K·c) · Σ_{(A, w) ∈ acc[j, B, c]} w·P[A]        (:mod:`.plan`),

so the same map, merge and combine on the tags give Enc(α·V[j, B] + β[j, B]) with
β[j, B] = Σ_c 2^(K·c) Σ w·β_A (all mod n). After the image's values are fixed (computed and in the
key holder's hands) the key holder draws a fresh seed (:func:`secrets.token_bytes`), and the server
returns one aggregate over the tag render, with ρ[j, B] the 62-bit coefficient of the value's
global index j·N_B + (B − B_lo) (:func:`hevr.crypto.tags.coefficients_at`):

    A = Π_{j,B} T[j, B]^ρ[j, B] = Π_c ( Π_{j,B} acc_tag[j, B, c]^ρ[j, B] )^(2^(K·c))   (mod n²),

computed per tile as one multi-exponentiation per class and one Horner step over the classes
(:func:`aggregate_tile`: the tags' K·O squarings once per tile, not per value). The key holder
decrypts A once and checks, before any pixel is formed (:meth:`PackedVerification.check`),

    D(A) ≡ α·Σ ρ[j, B]·V'[j, B] + Σ_c 2^(K·c) Σ_A β_A · Σ_{pairs (j, B, c, A, w)} ρ[j, B]·w   (mod n),

with V' the values it decrypted from the image and the right-hand sum recomputed from the public
plan (:meth:`~.plan.SlicePlan.brick_pairs`, brick by brick) and the PRF. The soundness argument is
the per-voxel one (:mod:`hevr.crypto.tags`): whatever the server returns is a linear combination of
ciphertexts with coefficients it fixed before it knew ρ; a wrong value passes with probability
about 2^-62 per frame. The key holder's cost: the plan's pairs (numpy), the β of every pack the
frame reads (SHAKE-256), exact weighted sums of 16-bit pieces in numpy, and one decryption.
"""

from __future__ import annotations

import logging
import os
import secrets
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gmpy2
import numpy as np
from dask.delayed import delayed

from ...backends import get_backend
from ...crypto.tags import aggregate_holds, betas, coefficients_at, tag_channel, tag_key_of
from ...errors import ParameterError, VerificationError
from ...runtime.scheduler import compute as run_tasks
from ...store.authenticity import authenticated_fields, check_metadata_mac
from ...store.known import record_verified
from ...store.layout import array_slices
from ..pipeline.kernel import plan_products
from .graph import map_graph, merge_parts
from .plan import SlicePlan

if TYPE_CHECKING:
    from .planes import PlanePlan

log = logging.getLogger(__name__)

__all__ = ["PackedVerification", "aggregate_for", "aggregate_tile", "class_beta_total", "tag_aggregate"]

WORKERS = max(1, min(os.cpu_count() or 1, 8))  # the key holder's threads for the check


def aggregate_tile(
    plan: SlicePlan, t: int, n: int, width: int, backend: str, seed: bytes, first: int, *parts: Any
) -> tuple[np.ndarray | None, dict]:
    """One server task: tile ``t``'s tag accumulators merged per key, then
    Π_c (Π acc[j, B, c]^ρ[j, B])^(2^(K·c)) mod n² as one ``(W,)`` record (None: the tile has no
    product), and the operations spent; ``first``: the coefficients' index of the component's value
    0 (component j of a k-component frame: j·``plan.n_values``; 0 for one component)."""
    be = get_backend(backend)
    uniq, merged, merged_ops = merge_parts(be, n, parts)
    if not len(uniq):
        return None, {"verify_merge": 0}
    C = plan.classes
    ids, cls = plan.key_values(uniq)
    rho = coefficients_at(seed, ids + int(first))
    order = np.argsort(cls, kind="stable")
    indptr = np.searchsorted(cls[order], np.arange(C + 1)).astype(np.int64)
    pp = plan_products(indptr, order.astype(np.int64), rho[order], len(uniq))
    (per_class,) = be.ray_products(pp, [merged], n * n)
    (out,) = be.to_bytes(be.pack(per_class, [1] * C, plan.packing.slot_bits, C, 0, n), width)
    return out, {"verify_merge": merged_ops, "verify_values": int(len(uniq))}


def aggregate_for(ev: Any, plan: SlicePlan, backend: str, client: Any, progress: bool, seed: bytes) -> tuple[int, dict]:
    """The server's half of the round for the coefficients of ``seed``: A = Π_t A_t mod n² over the
    tag channel's map with the frame's plan (``hevr serve`` runs it for the seed the key holder sent
    after it held the values), and the operations spent."""
    meta = ev.meta
    if not meta.tags:
        raise ParameterError(f"verify: expected a verifiable store, got the packed store {meta.store_id} without tags")
    n, width = int(ev.public_key.n), meta.ciphertext_bytes
    tag = f"{meta.store_id}-{uuid.uuid4().hex}"
    per_tile, maps = map_graph(ev._plain(), plan, backend, None, tag_channel("scalar"), tag)  # tags: streamed
    tasks = [
        delayed(aggregate_tile, pure=True, nout=2)(
            plan, t, n, width, backend, seed, 0, *per_tile[t], dask_key_name=f"hevr-packed-verify-{tag}-{t}"
        )
        for t in range(plan.n_tiles)
        if per_tile[t]
    ]
    results = run_tasks(tasks + maps, client=client, progress=progress, desc="verify") if tasks else []
    A = gmpy2.mpz(1)
    n2 = gmpy2.mpz(n) * n
    for rec, _ in results[: len(tasks)]:
        if rec is not None:
            A = A * gmpy2.mpz(int.from_bytes(np.asarray(rec, np.uint8).tobytes(), "big")) % n2
    ops = {"map": sum(m["map"] for m in results[len(tasks) :])}
    for _, r in results[: len(tasks)]:
        for k, v in r.items():
            ops[k] = ops.get(k, 0) + v
    return int(A), ops


def tag_aggregate(ev: Any, plan: SlicePlan, backend: str, client: Any, progress: bool) -> PackedVerification:
    """The second round of a verified frame, after its values are in the key holder's hands: a
    fresh seed drawn here, then :func:`aggregate_for`; the :class:`PackedVerification` to keep."""
    seed = secrets.token_bytes(32)
    t0 = time.perf_counter()
    A, ops = aggregate_for(ev, plan, backend, client, progress, seed)
    level = int(getattr(ev, "level", 0) or 0)
    return PackedVerification(
        aggregate=A,
        seed=seed,
        meta=ev.base if level else ev.meta,
        level=level,
        ops=ops,
        server_s=time.perf_counter() - t0,
        drawn_here=True,
        drawn_at=time.time(),
        known_name=str(ev.path),
    )


def class_beta_total(
    beta_limbs: np.ndarray, packs: np.ndarray, classes: np.ndarray, rho: np.ndarray, weights: np.ndarray, slot_bits: int
) -> int:
    """Σ_pairs 2^(K·c)·ρ·w·β_pack exactly, in numpy (``packs`` index the rows of ``beta_limbs``):
    per (pack, class) the coefficient Σ ρ·w in 16-bit pieces of ρ (float64 sums stay below 2^53:
    pieces below 2^16, weights at most 2^16, fewer than 2^21 pairs per pack and class), then per
    class one matrix product of the packs' 16-bit β pieces with the coefficients cut small enough
    that every dot product stays an exact float64 integer (below 2^53).

    >>> bl = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], np.uint32)      # β = 1 and 2^32
    >>> rho, w = np.array([2**61 + 5, 3, 7]), np.array([3, 2, 1])
    >>> got = class_beta_total(bl, np.array([0, 1, 1]), np.array([0, 0, 2]), rho, w, 10)
    >>> got == (2**61 + 5) * 3 + 3 * 2 * 2**32 + (7 * 2**32 << 20)
    True
    """
    w = np.asarray(weights, np.int64)
    if not w.size:
        return 0
    if w.min() < 0 or w.max() > 1 << 16:  # 2^16: a whole sample at weight_bits 16 (ρ pieces·w < 2^32)
        raise ParameterError("weights: expected integers in [0, 2^16], got others")
    U = beta_limbs.shape[0]
    pair_key = np.asarray(classes, np.int64) * U + np.asarray(packs, np.int64)
    uk, inv = np.unique(pair_key, return_inverse=True)  # (class, pack), class-major
    if np.bincount(inv).max() >= 1 << 21:
        raise ParameterError("pairs: expected fewer than 2^21 per pack and class")
    r = np.asarray(rho, np.uint64)
    wf = w.astype(np.float64)
    coef = [
        np.bincount(
            inv, weights=((r >> np.uint64(16 * i)) & np.uint64(0xFFFF)).astype(np.float64) * wf, minlength=uk.size
        ).astype(np.uint64)
        for i in range(4)
    ]  # exact: < 2^53
    pieces = np.ascontiguousarray(beta_limbs, dtype="<u4").view("<u2").astype(np.float64)  # (U, P) 16-bit
    cls, pk = uk // U, uk % U
    bounds = np.searchsorted(cls, np.arange(int(cls.max()) + 2))
    total = 0
    for c in range(int(cls.max()) + 1):
        a, b = int(bounds[c]), int(bounds[c + 1])
        if a == b:
            continue
        h = 53 - 16 - int(b - a).bit_length()  # bits of a coefficient piece: 16 + h + log2(rows) ≤ 53
        cols, shifts = [], []
        for i in range(4):
            for j in range(-(-53 // h)):
                cols.append(((coef[i][a:b] >> np.uint64(h * j)) & np.uint64((1 << h) - 1)).astype(np.float64))
                shifts.append(16 * i + h * j)
        S = (pieces[pk[a:b]].T @ np.stack(cols, axis=1)).astype(np.uint64)  # (P, columns): exact integers
        part = sum(int(S[p, q]) << (16 * p + shifts[q]) for p in range(S.shape[0]) for q in range(S.shape[1]))
        total += part << (int(slot_bits) * c)
    return total


@dataclass(frozen=True, repr=False)
class PackedVerification:
    """What the key holder keeps of a verified packed frame: the aggregate A (a ciphertext), the
    seed of the coefficients and the store's metadata the frame was planned with (no secret)."""

    aggregate: int
    seed: bytes
    meta: Any  # the store's (level 0's) VolumeMetadata: its owner's MAC is checked
    level: int = 0  # the pyramid level the frame was rendered at (its own packing: meta.level_meta(level))
    channel: str = "scalar"  # the channel whose tags certify the values
    components: int = 1  # its components, checked together (component j's coefficients from j·n_values)
    ops: Any = None
    server_s: float = 0.0
    drawn_here: bool = False
    drawn_at: float = 0.0  # when the seed was drawn here (seconds since the epoch)
    known_name: str = field(default="", compare=False)  # rendered under (known stores; not in files)

    def __repr__(self) -> str:
        return f"PackedVerification(store {self.meta.store_id}, seed …)"

    @property
    def store_id(self) -> str:
        return self.meta.store_id

    @property
    def level_meta(self) -> Any:
        """The metadata of the frame's level (level 0's own at level 0)."""
        return self.meta.level_meta(self.level) if self.level else self.meta

    def check_metadata(self, private_key: Any, plan: SlicePlan | PlanePlan, fingerprint: str) -> None:
        """Raise :class:`hevr.VerificationError` unless the metadata carries the owner's MAC and the
        frame's plan is the one its shape, spacing, brick and packing give."""
        m = self.meta
        if m is None or not check_metadata_mac(private_key, authenticated_fields(m.to_dict()), m.auth):
            raise VerificationError(
                "store metadata: expected the owner's MAC over the shape, spacing, brick, layout, value range and "
                "store "
                f"id, got {'none' if m is None or not m.auth else 'a MAC that does not match'}: the store's public "
                "metadata was altered (or is not this key's); no image is returned"
            )
        lm = self.level_meta
        if isinstance(plan, SlicePlan):  # a frame's shear geometry
            g = plan.geometry
            grid = tuple(g.shape) == tuple(lm.shape) and tuple(float(s) for s in g.spacing) == tuple(lm.spacing)
        else:  # a slice's plan holds the shape itself
            grid = tuple(plan.shape) == tuple(lm.shape)
        same = (
            grid
            and tuple(plan.brick) == tuple(lm.brick)
            and plan.packing == lm.packing
            and m.tags
            and fingerprint == m.fingerprint
            and int(private_key.public_key.n) == int(m.n)
        )
        if not same:
            raise VerificationError(
                "image: its shape, spacing, brick, packing or key are not those of the store's "
                "authenticated metadata; no image is returned"
            )

    def beta_sum(self, private_key: Any, plan: SlicePlan | PlanePlan) -> int:
        """Σ_c 2^(K·c) Σ_A β_A·Σ ρ·w over every product of the frame's plan, mod n (module docstring)."""
        key = tag_key_of(private_key)
        m = self.level_meta
        sid = self.meta.store_id
        info = m.packing
        ashape = info.array_shape(m.shape)
        K = info.slot_bits
        grid = tuple(-(-s // b) for s, b in zip(m.shape, m.brick))
        cache: dict = {}  # β blocks shared by neighbouring bricks (a race only recomputes a block)

        def pairs(idx: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            keys, local, w = plan.brick_pairs(idx)
            sl = array_slices(m, idx)
            coords = np.unravel_index(local, tuple(s.stop - s.start for s in sl))
            return np.ravel_multi_index(tuple(c + s.start for c, s in zip(coords, sl)), ashape), keys, w

        def part(bricks: list) -> int:  # a run of neighbouring bricks: their packs' β in one go
            got = [p for p in map(pairs, bricks) if len(p[1])]
            if not got:
                return 0
            packs, keys, w = (np.concatenate([g[i] for g in got]) for i in range(3))
            lo = int(packs.min())
            span = np.zeros(int(packs.max()) - lo + 1, bool)
            span[packs - lo] = True
            where = np.cumsum(span) - 1
            ids, cls = plan.key_values(keys)
            total = 0
            for j in range(self.components):  # the same products, each component's β and coefficients
                beta = betas(key, sid, self.channel, self.level, j, np.flatnonzero(span) + lo, cache)
                rho = coefficients_at(self.seed, ids + j * plan.n_values)
                total += class_beta_total(beta, where[packs - lo], cls, rho, w, K)
            return total

        bricks = list(np.ndindex(*grid))
        runs = max(1, min(len(bricks), 4 * WORKERS))
        chunks = [bricks[i * len(bricks) // runs : (i + 1) * len(bricks) // runs] for i in range(runs)]
        with ThreadPoolExecutor(max_workers=WORKERS) as pool:  # numpy's sorts and products release the GIL
            total = sum(pool.map(part, chunks))
        return total % int(self.meta.n)

    def check(
        self, private_key: Any, plan: SlicePlan | PlanePlan, values: list[list[list[int]]], fingerprint: str
    ) -> None:
        """Raise :class:`hevr.VerificationError` unless D(A) = α·Σρ·V' + Σρ·β (mod n) for the
        frame's decrypted values ``values`` (per component, per tile, in the tile's order)."""
        t0 = time.perf_counter()
        self.check_metadata(private_key, plan, fingerprint)
        if len(values) != self.components or any(len(v) != plan.n_tiles for v in values):
            raise VerificationError(
                f"image: expected {self.components} component(s) of {plan.n_tiles} tiles; no image is returned"
            )
        s_sum = 0
        for j, tiles in enumerate(values):
            for t, vals in enumerate(tiles):
                ids = plan.value_ids(t)
                if len(vals) != ids.size:
                    raise VerificationError(
                        f"image: tile {t} holds {len(vals)} values, expected {ids.size}; no image is returned"
                    )
                rho = coefficients_at(self.seed, ids + j * plan.n_values).tolist()
                s_sum += sum(int(r) * int(v) for r, v in zip(rho, vals))
        holds = aggregate_holds(private_key, s_sum, self.beta_sum(private_key, plan), self.aggregate)
        log.info("verification of a packed frame: %.3f s on the key holder's side", time.perf_counter() - t0)
        if not holds:
            raise VerificationError(
                "image: the packed frame does not verify: its values are not the ones the store's tags certify (an "
                "altered, substituted or replayed image or store, or a server that did not render as asked); no "
                "image is returned"
            )
        record_verified(self, private_key)  # proven: the store under its name is the one the key holder knows
