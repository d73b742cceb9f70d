"""The CPU backend: gmpy2 big integers, one Python list of ``mpz`` per batch.

This is the reference implementation of :class:`hevr.backends.base.Backend`; every other
backend must give bit-identical results. Its hot loops keep the Python work per modular
multiplication to a few bytecodes (``a * b % n2`` on ``mpz``); the per-brick products run
the bucket plans of :mod:`hevr.rendering.pipeline.kernel` exactly as costed there.

>>> import numpy as np
>>> from gmpy2 import mpz
>>> be = CpuBackend()
>>> be.to_bytes(be.segment_products([mpz(2), mpz(3), mpz(5)], np.array([0, 2, 3]), 1, 1000), 2).tolist()
[[0, 6], [0, 5]]
>>> be.combine([mpz(2), mpz(3)], [[1, 0], [2, 1]], 1000)  # rows of k=2 -> 2 channels
[mpz(18), mpz(3)]
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import gmpy2
import numpy as np
from gmpy2 import mpz

from ..crypto.records import bytes_to_mpz, mpz_to_bytes
from .base import HORNER, ONES, SHARED, SQR_COST, Backend, OpCounter, ProductPlan

__all__ = ["CpuBackend"]


class CpuBackend(Backend):
    """gmpy2 on the host: the default backend (``hevr.backend: cpu``)."""

    name = "cpu"

    def __reduce__(self):
        return (CpuBackend, ())

    # -- conversion -----------------------------------------------------------------------
    def from_bytes(self, records: np.ndarray) -> list[mpz]:
        return bytes_to_mpz(records)

    def to_bytes(self, values: Sequence[mpz], width: int) -> np.ndarray:
        return mpz_to_bytes(values, width)

    def residue_bytes(self, width: int) -> int:
        """Memory of one resident value: an ``mpz`` object header (40 bytes, CPython 3.11,
        64-bit), its 64-bit limbs and its list slot. A formula: ``sys.getsizeof`` of a
        recycled mpz reports its earlier allocation.

        >>> CpuBackend().residue_bytes(512), CpuBackend().residue_bytes(16)
        (560, 64)
        """
        return 40 + 8 * -(-int(width) // 8) + 8

    def first_out_of_range(self, values: Sequence[mpz], upper: int) -> int | None:
        u = mpz(upper)
        for i, c in enumerate(values):
            if not 0 < c < u:
                return i
        return None

    # -- encryption and decryption ----------------------------------------------------------
    def encrypt(self, key: Any, mantissas, *, unsafe_no_obfuscation: bool = False) -> list[mpz]:
        return key.encrypt_array(mantissas, unsafe_no_obfuscation=unsafe_no_obfuscation)

    def decrypt(self, private_key: Any, values: Sequence[mpz]) -> list[int]:
        return private_key.decrypt_array(values, signed=False)

    # -- rendering -------------------------------------------------------------------------
    def ray_products(
        self, plan: ProductPlan, components, nsquare: int, counter: OpCounter | None = None
    ) -> list[list[mpz]]:
        n2 = mpz(nsquare)
        listed = _ListedPlan.of(plan)  # once for all components
        return [_execute(listed, comp, n2, counter) for comp in components]

    def segment_products(self, values: Sequence[mpz], indptr: np.ndarray, k: int, nsquare: int) -> list[mpz]:
        n2 = mpz(nsquare)
        out: list[mpz] = []
        ip = np.asarray(indptr).tolist()
        for s, e in zip(ip[:-1], ip[1:]):
            acc = list(values[s * k : (s + 1) * k])
            for i in range(s + 1, e):
                acc = [a * b % n2 for a, b in zip(acc, values[i * k : (i + 1) * k])]
            out.extend(acc)
        return out

    def combine(self, values: Sequence[mpz], comb: Sequence[Sequence[int]], nsquare: int) -> list[mpz]:
        n2 = mpz(nsquare)
        k, C = len(comb), len(comb[0])
        cols = [[row[ch] for row in comb] for ch in range(C)]
        one = mpz(1)
        out: list[mpz] = []
        for start in range(0, len(values), k):
            s = values[start : start + k]
            sub = _subset_products(s, n2) if k <= 8 else None
            for exps in cols:
                if not any(exps):
                    out.append(one)
                elif sub is not None:
                    out.append(_straus(sub, exps, n2))
                else:
                    t = one
                    for b, e in zip(s, exps):
                        if e:
                            t = t * gmpy2.powmod(b, e, n2) % n2
                    out.append(t)
        return out

    def pack(
        self, terms: Sequence[mpz], exps: Sequence[int], pack_bits: int, per_pack: int, offset: int, n: int
    ) -> list[mpz]:
        """Horner from the highest digit, acc ← acc^B · T_j^R_j, with the b squarings of
        acc^B and the square-and-multiply of T_j^R_j interleaved (Shamir): a value costs b
        squarings plus popcount(R_j) multiplications; the offset is one product per
        ciphertext, g^(O·Σ_j B^j) = 1 + O·Σ_j B^j·n."""
        n = mpz(n)
        n2 = n * n
        b = pack_bits
        J = max(1, per_pack)
        out: list[mpz] = []
        powmod = gmpy2.powmod
        for start in range(0, len(terms), J):
            group_t, group_r = terms[start : start + J], exps[start : start + J]
            acc = _small_pow(group_t[-1], group_r[-1], n2)
            for T, R in zip(reversed(group_t[:-1]), reversed(group_r[:-1])):
                r = R.bit_length()
                if r > b:  # not reachable under the planner's bounds; kept exact anyway
                    acc = powmod(acc, mpz(1) << b, n2) * powmod(T, R, n2) % n2
                    continue
                for _ in range(b - r):  # acc^(2^(b-r)): plain squarings beat powmod's set-up (~10 µs)
                    acc = acc * acc % n2
                for i in range(r - 1, -1, -1):
                    acc = acc * acc % n2
                    if R >> i & 1:
                        acc = acc * T % n2
            if offset:
                digits = sum(mpz(1) << (b * j) for j in range(len(group_t))) if J > 1 else 1
                acc = acc * ((1 + offset * digits * n) % n2) % n2
            out.append(acc)
        return out


# -- finishing helpers ---------------------------------------------------------------------
def _small_pow(T: mpz, R: int, n2: mpz) -> mpz:
    """``T^R mod n²``: square-and-multiply for exponents of a few bits (powmod's set-up costs
    about three products), gmpy2's windowed powmod beyond.

    >>> _small_pow(mpz(3), 5, mpz(1000)), _small_pow(mpz(3), 1, mpz(1000)), _small_pow(mpz(3), 300, mpz(1000))
    (mpz(243), mpz(3), mpz(1))
    """
    r = int(R).bit_length()
    if r > 6:
        return gmpy2.powmod(T, R, n2)
    if r == 0:
        return mpz(1)
    acc = T % n2
    for i in range(r - 2, -1, -1):
        acc = acc * acc % n2
        if R >> i & 1:
            acc = acc * T % n2
    return acc


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


# -- the per-brick kernel: executing a ProductPlan ------------------------------------------
class _ListedPlan(NamedTuple):
    """A plan's arrays as lists of Python ints (the loops below index lists of ints fastest),
    made once per :meth:`CpuBackend.ray_products` call, whatever the number of components."""

    plan: ProductPlan
    vl: list
    wl: list
    tasks: list
    rep: list
    pre: list

    @classmethod
    def of(cls, plan: ProductPlan) -> _ListedPlan:
        vl, wl, tasks, rep = (_listed(a) for a in (plan.vl, plan.wl, plan.tasks, plan.rep))
        return cls(plan, vl, wl, tasks, rep, _listed(plan.pre) if plan.pre is not None else [])


def _execute(listed: _ListedPlan, cts: Sequence[mpz], n2: mpz, counter: OpCounter | None) -> list[mpz]:
    """Run the plan on one component (one ciphertext list)."""
    plan, vl, wl, tasks, rep, pre = listed
    mul = n_pow = pow_bits = 0
    pw, sq = _precompute(cts, pre, plan.shared_w, n2) if pre else (None, 0)
    vals: list[mpz] = []
    for kind, s, e, w, n_win in tasks:
        if kind == ONES:  # the nearest-sampling hot path: one multiplication per pair
            acc = cts[vl[s]]
            for v in vl[s + 1 : e]:
                acc = acc * cts[v] % n2
            m, q = e - s - 1, 0
        elif kind == HORNER:
            acc, m, q = _horner(cts, vl, wl, s, e, w, n_win, n2)
        elif kind == SHARED:
            acc, m, q = _shared(pw, vl, wl, s, e, plan.shared_w, n2)
        else:  # SINGLE: one pair with a weight large enough for powmod's Montgomery set-up
            acc, m, q = gmpy2.powmod(cts[vl[s]], wl[s], n2), 0, 0
            n_pow += 1
            pow_bits += wl[s].bit_length()
        mul += m
        sq += q
        vals.append(acc)
    one = mpz(1)
    out = [one if u < 0 else vals[u] for u in rep]
    if counter is not None:
        counter.add(
            OpCounter(
                mulmod=mul,
                squarings=sq,
                powmod=n_pow,
                powmod_bits=pow_bits,
                pairs=plan.n_pairs,
                rows=plan.n_rows,
                duplicate_rows=sum(1 for u in rep if u >= 0) - len(tasks),
                precomputed=sum(j - 1 for _, j in pre),
            )
        )
    return out


def _listed(a: Any) -> list:
    """A plan's array as Python ints (the loops below index lists of ints fastest).

    >>> _listed(np.array([[1, 2]], np.uint64)), _listed([3])
    ([[1, 2]], [3])
    """
    return a.tolist() if isinstance(a, np.ndarray) else list(a)


def _combine(B: list, lo: int, hi: int, n2: mpz) -> tuple[mpz | None, int]:
    """``prod_d B[lo + d]^d``, ``d = 1..hi-lo``, by running products, and the top digit.

    Costs ``(m - 1) + (top - 1)`` for ``m`` non-empty buckets: the first one is free.
    """
    run = tot = None
    top = 0
    for i in range(hi, lo, -1):
        b = B[i]
        if b is not None:
            if run is None:
                run, top = b, i - lo
            else:
                run = run * b % n2
        if run is not None:
            tot = run if tot is None else tot * run % n2
    return tot, top


def _horner(cts, vl, wl, s: int, e: int, w: int, n_win: int, n2: mpz) -> tuple[mpz, int, int]:
    """Bucket multi-exponentiation, ``n_win`` windows of ``w`` bits joined by Horner."""
    size = 1 << w
    mask = size - 1
    stride = size + 1  # bucket d of window j at j * stride + d; d = size is for folding
    B: list = [None] * (stride * n_win)
    k = 0  # digits inserted; all but the first of each bucket cost a multiplication
    if n_win <= 2:  # unrolled for nearest (w = 1) and 10-bit trilinear (w = 5) rows
        for v, x in zip(vl[s:e], wl[s:e]):
            c = cts[v]
            d = x & mask
            if d:
                b = B[d]
                B[d] = c if b is None else b * c % n2
                k += 1
            d = x >> w
            if d:
                d += stride
                b = B[d]
                B[d] = c if b is None else b * c % n2
                k += 1
    else:
        for v, x in zip(vl[s:e], wl[s:e]):
            c = cts[v]
            base = 0
            while x:
                d = x & mask
                if d:
                    b = B[base + d]
                    B[base + d] = c if b is None else b * c % n2
                    k += 1
                x >>= w
                base += stride
    acc = None
    mul, sq = k, 0
    fold = size - w * SQR_COST  # see the kernel's _choose_windows: fold when the top digit exceeds this
    for j in range(n_win - 1, -1, -1):
        lo = j * stride
        if acc is not None:
            top = mask
            while top and B[lo + top] is None:
                top -= 1
            if top > fold:  # acc^(2^w) T_j as bucket 2^w: size - top + 1 < w S + 1
                B[lo + size] = acc
                acc = _combine(B, lo, lo + size, n2)[0]
                mul += size - 1  # n_j + 2^w - 1 for the window and the join
                continue
            for _ in range(w):
                acc = acc * acc % n2
            sq += w
        t, top = _combine(B, lo, lo + mask, n2)
        if t is not None:
            mul += top - 2  # window cost n_j + top_j - 2, the n_j are in k
            if acc is None:
                acc = t
            else:
                acc = acc * t % n2
                mul += 1
    return acc, mul, sq


def _precompute(cts, pre: list[tuple[int, int]], w: int, n2: mpz) -> tuple[list, int]:
    """Per-voxel powers ``[c, c^(2^w), c^(2^(2w)), ...]`` for the shared-bucket rows."""
    pw: list = [None] * len(cts)
    sq = 0
    for v, n_win in pre:
        c = cts[v]
        row = [c]
        for _ in range(n_win - 1):
            for _ in range(w):
                c = c * c % n2
            row.append(c)
        sq += (n_win - 1) * w
        pw[v] = row
    return pw, sq


def _shared(pw, vl, wl, s: int, e: int, w: int, n2: mpz) -> tuple[mpz, int, int]:
    """All windows share one bucket set thanks to the precomputed ``c^(2^(w j))``."""
    mask = (1 << w) - 1
    B: list = [None] * (mask + 1)
    k = 0
    for v, x in zip(vl[s:e], wl[s:e]):
        powers = pw[v]
        j = 0
        while x:
            d = x & mask
            if d:
                b = B[d]
                B[d] = powers[j] if b is None else b * powers[j] % n2
                k += 1
            x >>= w
            j += 1
    t, top = _combine(B, 0, mask, n2)
    return t, k + top - 2, 0
