"""Server-side pixel finishing: per-pixel combination, Eq. 1 normalisation, offset, packing.

Every function here works on one image tile and only on public integers plus
ciphertexts; the secret key is never needed.
"""

from __future__ import annotations

from typing import Sequence

import gmpy2
import numpy as np
from gmpy2 import mpz

from .planner import RenderPlan

__all__ = ["finish_tile", "merge_partials", "pack_values"]


def _to_mpz(arr: np.ndarray) -> list[mpz]:
    from ._mpzbytes import bytes_to_mpz

    return bytes_to_mpz(arr)


def _to_bytes(values: Sequence[mpz], width: int) -> np.ndarray:
    from ._mpzbytes import mpz_to_bytes

    return mpz_to_bytes(values, width)


def merge_partials(parts: Sequence[tuple[np.ndarray, np.ndarray]], nsquare: int) -> tuple[np.ndarray, np.ndarray]:
    """fpAdd of partial ray sums that share one exponent: ⊕ per ray, i.e. a product mod n².

    ``parts`` are ``(rays (R,), records (R, C, W))``; the result has sorted unique rays.
    Rays present in one part only are passed through without any arithmetic.
    """
    parts = [p for p in parts if p[0].size]
    if not parts:
        return np.zeros(0, np.int64), np.zeros((0, 0, 0), np.uint8)
    if len(parts) == 1:
        return parts[0]
    rays = np.concatenate([p[0] for p in parts])
    recs = np.concatenate([p[1] for p in parts])
    order = np.argsort(rays, kind="stable")
    rays, recs = rays[order], recs[order]
    uniq, start, counts = np.unique(rays, return_index=True, return_counts=True)
    out = recs[start].copy()
    multi = np.nonzero(counts > 1)[0]
    if multi.size:
        n2 = mpz(nsquare)
        _, C, W = recs.shape
        for u in multi.tolist():
            s, e = int(start[u]), int(start[u] + counts[u])
            vals = _to_mpz(recs[s:e].reshape(-1, W))  # (e - s)·C values, ray-major
            acc = vals[:C]
            for i in range(1, e - s):
                acc = [a * b % n2 for a, b in zip(acc, vals[i * C:(i + 1) * C])]
            out[u] = _to_bytes(acc, W)
    return uniq, out


def _subset_products(bases: Sequence[mpz], n2: mpz) -> list[mpz]:
    """sub[mask] = Π_{i in mask} bases[i] mod n²: 2^k − 1 − k multiplications, shared by all channels."""
    sub = [mpz(1)] * (1 << len(bases))
    for i, b in enumerate(bases):
        bit = 1 << i
        sub[bit] = b
        for m in range(1, bit):
            sub[bit | m] = sub[m] * b % n2
    return sub


def _straus(sub: list[mpz], exps: Sequence[int], n2: mpz) -> mpz:
    """Π b_i^e_i from subset products: one squaring and at most one multiplication per bit."""
    top = max(exps).bit_length()
    acc = mpz(1)
    for bit in range(top - 1, -1, -1):
        acc = acc * acc % n2
        m = 0
        for i, e in enumerate(exps):
            if e >> bit & 1:
                m |= 1 << i
        if m:
            acc = acc * sub[m] % n2
    return acc


def finish_tile(plan: RenderPlan, sums: dict[int, list[mpz]], pixels: np.ndarray, n_samples: np.ndarray,
                n: int, counter: dict | None = None) -> list[mpz]:
    """Finished, offset ciphertexts of one tile in (pixel, channel) order.

    For each pixel: combine the k component sums with the quantised matrix (emphasize /
    tf), multiply by the rounded reciprocal R = round(10^G / (n·K)) (Eq. 1), add the public
    offset. A pixel whose ray misses gets the trivial encryption of the offset: which
    rays miss is fixed by the public camera and volume shape, so nothing is revealed.
    """
    n = mpz(n)
    n2 = n * n
    nude_offset = (1 + plan.offset * n) % n2
    recips = plan.reciprocal(n_samples)
    C = plan.channels_out
    out: list[mpz] = []
    ops = 0
    for pix, R in zip(pixels.tolist(), recips):
        s = sums.get(pix)
        if s is None or R == 0:
            out.extend([nude_offset] * C)
            continue
        if plan.comb is None:
            values = [gmpy2.powmod(s[0], R, n2)]
            ops += R.bit_length()
        else:
            # Σ_k Q[k,ch]·S_k by Straus over small exponents (subset products shared by the
            # channels), then one reciprocal exponentiation per channel.
            sub = _subset_products(s, n2) if len(s) <= 8 else None
            values = []
            for ch in range(C):
                exps = [row[ch] for row in plan.comb]
                if not any(exps):
                    values.append(mpz(1))
                    continue
                if sub is not None:
                    t = _straus(sub, exps, n2)
                else:
                    t = mpz(1)
                    for b, e in zip(s, exps):
                        if e:
                            t = t * gmpy2.powmod(b, e, n2) % n2
                values.append(gmpy2.powmod(t, R, n2))
                ops += 2 * max(exps).bit_length() + R.bit_length()
        if plan.offset:
            values = [v * nude_offset % n2 for v in values]
        out.extend(values)
    if counter is not None:
        counter["finish_ops"] = counter.get("finish_ops", 0) + ops
    return out


def pack_values(values: Sequence[mpz], plan: RenderPlan, n: int) -> list[mpz]:
    """Horner packing c = Π_j c_j^(B^j), B = 2^pack_bits, ``per_pack`` values per ciphertext.

    Valid because every value lies in [0, bound] with bound < B and per_pack·pack_bits <=
    bits(n) - 2, so the packed plaintext Σ m_j·B^j stays below n/2 and no digit carries.
    """
    if plan.per_pack <= 1:
        return list(values)
    n2 = mpz(n) * mpz(n)
    B = mpz(1) << plan.pack_bits
    J = plan.per_pack
    out = []
    for start in range(0, len(values), J):
        group = values[start:start + J]
        acc = group[-1]
        for v in reversed(group[:-1]):
            acc = gmpy2.powmod(acc, B, n2) * v % n2
        out.append(acc)
    return out
