"""Server-side pixel finishing: per-pixel combination, Eq. 1 normalisation, offset, packing.

Every function here works on one image tile and only on public integers plus
ciphertexts; the secret key is never needed.
"""

from __future__ import annotations

from typing import Sequence

import gmpy2
import numpy as np
from gmpy2 import mpz

from ..crypto.records import bytes_to_mpz, mpz_to_bytes
from .planner import RenderPlan

__all__ = ["finish_tile", "merge_partials", "pack_terms"]


def _to_mpz(arr: np.ndarray) -> list[mpz]:

    return bytes_to_mpz(arr)


def _to_bytes(values: Sequence[mpz], width: int) -> np.ndarray:

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
                n: int) -> list[tuple[mpz, int]]:
    """Per-pixel terms (T, R) of one tile, for the pixels whose rays hit, in (pixel, channel) order.

    T is the pixel's combined ciphertext (xray: the ray sum; emphasize / tf: Σ_k Q[k,ch]·S_k,
    computed by Straus with subset products shared by the channels) and R = round(10^G/(n·K))
    the rounded reciprocal of Eq. 1; the finished value is T^R (⊗ R), which :func:`pack_terms`
    raises while packing. Pixels whose rays miss are skipped: which rays miss follows from the
    public camera and volume shape, and the image records them in a public mask.
    """
    n2 = mpz(n) * mpz(n)
    recips = plan.reciprocal(n_samples)
    C = plan.channels_out
    out: list[tuple[mpz, int]] = []
    one = mpz(1)
    for pix, R in zip(pixels.tolist(), recips):
        if R == 0:
            continue
        s = sums.get(pix)
        if s is None:  # every weight of this ray rounded to 0
            out.extend([(one, R)] * C)
            continue
        if plan.comb is None:
            out.append((s[0], R))
            continue
        sub = _subset_products(s, n2) if len(s) <= 8 else None
        for ch in range(C):
            exps = [row[ch] for row in plan.comb]
            if not any(exps):
                out.append((one, R))
            elif sub is not None:
                out.append((_straus(sub, exps, n2), R))
            else:
                t = one
                for b, e in zip(s, exps):
                    if e:
                        t = t * gmpy2.powmod(b, e, n2) % n2
                out.append((t, R))
    return out


def pack_terms(terms: Sequence[tuple[mpz, int]], plan: RenderPlan, n: int) -> list[mpz]:
    """Finish and pack: c = Π_j (T_j^R_j · g^O)^(B^j), B = 2^pack_bits, ``per_pack`` values each.

    Horner from the highest digit, acc ← acc^B · T_j^R_j, with the b squarings of acc^B and
    the square-and-multiply of T_j^R_j interleaved (Shamir), so a value costs b squarings
    plus popcount(R_j) multiplications. The public offset O is added once per ciphertext,
    as g^(O·Σ_j B^j). Valid because every value M_j + O lies in [0, bound], bound < B, and
    per_pack·pack_bits <= bits(n) − 2: no digit carries and the plaintext stays below n/2.
    With ``per_pack == 1`` each value is one ciphertext T^R · g^O.
    """
    n = mpz(n)
    n2 = n * n
    b = plan.pack_bits
    J = max(1, plan.per_pack)
    out: list[mpz] = []
    powmod = gmpy2.powmod
    for start in range(0, len(terms), J):
        group = terms[start:start + J]
        T, R = group[-1]
        acc = powmod(T, R, n2)
        for T, R in reversed(group[:-1]):
            r = R.bit_length()
            if r > b:  # not reachable under the planner's bounds; kept exact anyway
                acc = powmod(acc, mpz(1) << b, n2) * powmod(T, R, n2) % n2
                continue
            if b > r:
                acc = powmod(acc, mpz(1) << (b - r), n2)
            for i in range(r - 1, -1, -1):
                acc = acc * acc % n2
                if R >> i & 1:
                    acc = acc * T % n2
        if plan.offset:
            digits = sum(mpz(1) << (b * j) for j in range(len(group))) if J > 1 else 1
            acc = acc * ((1 + plan.offset * digits * n) % n2) % n2
        out.append(acc)
    return out
