"""Per-brick homomorphic ray products: ``P_r = prod_v c_v^(w_rv) mod n^2``.

For one brick the renderer has, per ray ``r``, plaintext weights ``w_rv >= 0`` in CSR form
(``indptr``, ``voxels``, ``weights``). The product of the Paillier ciphertexts raised to
those weights is the encryption of the weighted sum. The cost is big-integer modular
multiplication, so the kernel minimises their number and keeps Python work per
(voxel, weight) pair to a few bytecodes.

Cost model (unit: one ``a * b % n2``; a modular squaring costs ``S ~= 0.85``, a
``gmpy2.powmod`` with a ``b``-bit exponent ``~= 1.3 b + 0.5``; measured with gmpy2 2.3 at
n^2 of 4096 bits). Zero weights are dropped first; ``n`` is the number of remaining
pairs of a row.

* Identical rows (same ``(voxel, weight)`` list, compared on the raw bytes through a
  dict) are computed once: cost 0 for every repeat.
* ``n == 1``: ``c^e`` by left-to-right binary (``e < 16``) or ``powmod``.
* All weights 1: running product, ``n - 1``.
* Otherwise a bucket (Pippenger-style) multi-exponentiation in radix ``2^w`` with
  ``J = ceil(bits(max weight) / w)`` windows. Window ``j`` puts ``c_v`` into bucket
  ``d = digit_j(w_rv)`` (the first entry of a bucket is free) and combines the buckets
  with the running-product trick ``prod_d B_d^d = prod_j (prod_{d >= j} B_d)``. With
  ``n_j`` non-zero digits and largest digit ``D_j`` a window costs exactly
  ``n_j + D_j - 2``; windows are joined by Horner, ``(J - 1)(w S + 1)``. ``J = 1`` is
  the plain bucket-per-weight method (nearest sampling: ``n + max_w - 2``). ``w`` is
  chosen per row by evaluating this exact cost for every ``w`` with numpy.
* Shared buckets: with per-voxel powers ``c_v^(2^(w j))`` (``(J_v - 1) w`` squarings per
  voxel and brick, amortised over all rays through the voxel) all windows share one set
  of buckets: ``sum_j n_j + max_j D_j - 2`` per row and no Horner. Chosen per brick only
  when the saving over all rows exceeds the precomputation.

For 10-bit trilinear weights and ~128 pairs per row this is ``w = 5`` Horner,
``~312`` multiplications, ``~2.45`` per pair; for nearest sampling (weights 1-3) it is
below one per pair.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import gmpy2
import numpy as np
from gmpy2 import mpz

from .errors import ParameterError

__all__ = ["OpCounter", "brick_ray_products", "brick_ray_products_multi"]

_SQR = 0.85  # cost of a modular squaring relative to a modular multiplication
_POW_BIT = 1.3  # powmod cost per exponent bit (Montgomery setup included below)
_POW_BASE = 0.5
_MAX_W = 16  # radix bits tried; 2^16 buckets is already far beyond any optimum
_ONES, _SINGLE, _HORNER, _SHARED = range(4)


@dataclass
class OpCounter:
    """Counts of the modular operations done by the kernel (accumulates over calls).

    Attributes
    ----------
    mulmod : int
        Modular multiplications of two operands (``a * b % n2``).
    squarings : int
        Modular squarings (Horner steps and per-voxel precomputed powers).
    powmod : int
        ``gmpy2.powmod`` calls; ``powmod_bits`` sums their exponent bit lengths.
    pairs, rows : int
        CSR entries and rows processed (counted once per component).
    duplicate_rows : int
        Non-empty rows served from an identical earlier row (per component).
    precomputed : int
        Per-voxel powers ``c^(2^(w j))``, ``j >= 1``, computed for shared buckets.

    Examples
    --------
    >>> c = OpCounter()
    >>> c.mulmod += 3; c.squarings += 2
    >>> c.modmuls
    5
    """

    mulmod: int = 0
    squarings: int = 0
    powmod: int = 0
    powmod_bits: int = 0
    pairs: int = 0
    rows: int = 0
    duplicate_rows: int = 0
    precomputed: int = 0

    @property
    def modmuls(self) -> int:
        """Multiplications plus squarings (``powmod`` calls excluded)."""
        return self.mulmod + self.squarings

    def add(self, other: OpCounter) -> None:
        """Add the counts of ``other`` into this counter."""
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))


@dataclass
class _Plan:
    """Weight analysis of one brick, shared by all components."""

    n_rows: int
    n_pairs: int
    rep: list[int]  # per row: index into tasks, -1 for an empty row
    tasks: list[tuple[int, int, int, int, int]]  # (kind, start, stop, w, J)
    vl: list[int]
    wl: list[int]
    shared_w: int = 0
    pre: list[tuple[int, int]] | None = None  # (voxel, J_v) for shared buckets


def brick_ray_products(
    ciphertexts: Sequence[mpz],
    indptr: np.ndarray,
    voxels: np.ndarray,
    weights: np.ndarray,
    nsquare,
    counter: OpCounter | None = None,
) -> list[mpz]:
    """Compute ``prod_v c_v^(w_rv) mod n^2`` for every CSR row of one brick.

    Parameters
    ----------
    ciphertexts : sequence of gmpy2.mpz
        Ciphertext of every local voxel, each in ``[0, nsquare)``.
    indptr : numpy.ndarray
        Integer array of length ``R + 1``; row ``r`` is ``indptr[r]:indptr[r + 1]``.
    voxels : numpy.ndarray
        Local voxel index (``0 <= v < len(ciphertexts)``) of every pair.
    weights : numpy.ndarray
        Non-negative integer weight of every pair (zeros are ignored).
    nsquare : int or gmpy2.mpz
        The modulus ``n^2``.
    counter : OpCounter, optional
        Incremented with the operations done.

    Returns
    -------
    list of gmpy2.mpz
        One product per row; an empty (or all-zero-weight) row gives ``mpz(1)``.

    Examples
    --------
    >>> import numpy as np
    >>> from gmpy2 import mpz
    >>> brick_ray_products([mpz(2), mpz(3)], np.array([0, 2, 2]), np.array([0, 1]),
    ...                    np.array([3, 1]), 1000)
    [mpz(24), mpz(1)]
    """
    return brick_ray_products_multi([ciphertexts], indptr, voxels, weights, nsquare, counter)[0]


def brick_ray_products_multi(
    components: Sequence[Sequence[mpz]],
    indptr: np.ndarray,
    voxels: np.ndarray,
    weights: np.ndarray,
    nsquare,
    counter: OpCounter | None = None,
) -> list[list[mpz]]:
    """Like :func:`brick_ray_products` for ``k`` ciphertext lists sharing the weights.

    Vector-encoded volumes hold ``k`` ciphertexts per voxel; the duplicate detection,
    the method and window choice are done once and reused for every component.

    Parameters
    ----------
    components : sequence of sequences of gmpy2.mpz
        ``k`` lists, each with one ciphertext per local voxel (all the same length).
    indptr, voxels, weights, nsquare, counter
        As in :func:`brick_ray_products`.

    Returns
    -------
    list of list of gmpy2.mpz
        ``k`` lists of ``R`` products, in the order of ``components``.

    Examples
    --------
    >>> import numpy as np
    >>> from gmpy2 import mpz
    >>> brick_ray_products_multi([[mpz(2)], [mpz(5)]], np.array([0, 1]), np.array([0]),
    ...                          np.array([2]), 1000)
    [[mpz(4)], [mpz(25)]]
    """
    try:
        n2 = mpz(nsquare)
    except (TypeError, ValueError):
        raise ParameterError(f"nsquare: expected an integer, got {type(nsquare).__name__}") from None
    if n2 < 2:
        raise ParameterError("nsquare: expected an integer >= 2")
    if len(components) == 0:
        return []
    n_vox = len(components[0])
    for i, comp in enumerate(components):
        if len(comp) != n_vox:
            raise ParameterError(
                f"components[{i}]: expected {n_vox} ciphertexts like components[0], got {len(comp)}"
            )
    plan = _plan(indptr, voxels, weights, n_vox)
    return [_execute(plan, comp, n2, counter) for comp in components]


def _as_int_array(name: str, a) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim != 1 or (arr.size and arr.dtype.kind not in "iu"):
        raise ParameterError(f"{name}: expected a 1-D integer array, got {arr.dtype} {arr.shape}")
    return arr


def _bit_length(a: np.ndarray) -> np.ndarray:
    """Exact bit length of non-negative integers (frexp may round up near 2^53+)."""
    a = a.astype(np.uint64)
    bits = np.frexp(a.astype(np.float64))[1].astype(np.int64)
    too_big = (bits > 0) & ((a >> np.maximum(bits - 1, 0).astype(np.uint64)) == 0)
    return bits - too_big


def _plan(indptr, voxels, weights, n_vox: int) -> _Plan:
    """Validate the CSR arrays, find duplicate rows and choose a method per row."""
    ip = _as_int_array("indptr", indptr).astype(np.int64)
    vox = _as_int_array("voxels", voxels)
    wt = _as_int_array("weights", weights)
    if ip.size == 0 or ip[0] != 0 or np.any(np.diff(ip) < 0) or ip[-1] != vox.size:
        raise ParameterError("indptr: expected non-decreasing offsets from 0 to len(voxels)")
    if wt.size != vox.size:
        raise ParameterError(f"weights: expected {vox.size} entries like voxels, got {wt.size}")
    if vox.size and (vox.min() < 0 or vox.max() >= n_vox):
        raise ParameterError(f"voxels: expected indices in [0, {n_vox}), got {vox.min()}..{vox.max()}")
    if wt.size and wt.dtype.kind == "i" and wt.min() < 0:
        raise ParameterError("weights: expected non-negative integers, got a negative one")
    n_rows, n_pairs = ip.size - 1, int(vox.size)
    vox, wt = vox.astype(np.uint64), wt.astype(np.uint64)
    if n_pairs and not wt.all():  # drop zero weights: they contribute c^0 = 1
        keep = wt != 0
        rowid = np.repeat(np.arange(n_rows), np.diff(ip))
        ip = np.concatenate([[0], np.cumsum(np.bincount(rowid[keep], minlength=n_rows))])
        vox, wt = vox[keep], wt[keep]
    # Duplicate rows: the dict compares the exact bytes of the (voxel, weight) records.
    blob = np.stack([vox, wt], axis=1).tobytes()
    ipl = ip.tolist()
    rep = [-1] * n_rows
    first: dict[bytes, int] = {}
    uniq: list[int] = []
    for r in range(n_rows):
        s, e = ipl[r], ipl[r + 1]
        if s != e:
            u = first.setdefault(blob[16 * s : 16 * e], len(uniq))
            if u == len(uniq):
                uniq.append(r)
            rep[r] = u
    plan = _Plan(n_rows, n_pairs, rep, [], vox.tolist(), wt.tolist())
    if not uniq:
        return plan
    u_rows = np.asarray(uniq)
    nonempty = np.flatnonzero(np.diff(ip))
    row_max = np.zeros(n_rows, np.uint64)
    row_max[nonempty] = np.maximum.reduceat(wt, ip[nonempty])
    u_s, u_e, u_max = ip[u_rows], ip[u_rows + 1], row_max[u_rows]
    u_n = u_e - u_s
    kinds = np.where(u_n == 1, _SINGLE, np.where(u_max == 1, _ONES, _HORNER))
    w_r = np.zeros(len(uniq), np.int64)
    gen = np.flatnonzero(kinds == _HORNER)
    if gen.size:
        w_r[gen], shared = _choose_windows(plan, vox, wt, u_s[gen], u_e[gen], u_max[gen])
        if shared is not None:
            use, plan.shared_w, plan.pre = shared
            kinds[gen[use]] = _SHARED
    bits = _bit_length(u_max)
    jw = np.where(w_r > 0, -(-bits // np.maximum(w_r, 1)), 0)
    plan.tasks = list(zip(kinds.tolist(), u_s.tolist(), u_e.tolist(), w_r.tolist(), jw.tolist()))
    return plan


def _choose_windows(plan: _Plan, vox, wt, starts, stops, rmax):
    """Per-row radix bits minimising the exact Horner cost; decide on shared buckets.

    Rows are contiguous in ``wt`` only row by row, so the rows are gathered first.
    """
    lens = stops - starts
    offs = np.cumsum(lens) - lens
    idx = np.repeat(starts - offs, lens) + np.arange(int(lens.sum()))
    g_wt, g_vox = wt[idx], vox[idx]
    bits = _bit_length(rmax)
    b_max = int(bits.max())
    n = lens.astype(np.float64)
    best = n + rmax.astype(np.float64) - 2  # single window (J = 1, w = bits)
    best_w = bits.copy()
    # Shared-bucket costs need per-voxel precomputation: only worth it with reuse.
    vmax = np.zeros(len(plan.vl) and int(vox.max()) + 1, np.uint64)
    np.maximum.at(vmax, g_vox.astype(np.int64), g_wt)
    v_bits = _bit_length(vmax)
    w_top = min(b_max - 1, _MAX_W, int(lens.max()).bit_length() + 2)
    sh_best = None  # (total cost, w, per-row cost)
    for w in range(1, w_top + 1):
        mask = np.uint64((1 << w) - 1)
        n_j = -(-bits // w)
        horner = (n_j - 1) * w * _SQR
        digits = np.zeros(len(starts))
        dmax = np.zeros(len(starts))
        for j in range(-(-b_max // w)):
            d = (g_wt >> np.uint64(w * j)) & mask
            nz = np.add.reduceat(d != 0, offs).astype(np.float64)
            dj = np.maximum.reduceat(d, offs).astype(np.float64)
            horner = horner + np.where(nz > 0, nz + dj - 2, 0) + ((nz > 0) & (j < n_j - 1))
            digits += nz
            dmax = np.maximum(dmax, dj)
        better = horner < best
        best = np.where(better, horner, best)
        best_w = np.where(better, w, best_w)
        pre = float(((-(-v_bits // w) - 1).clip(0) * w).sum()) * _SQR
        sh_row = digits + dmax - 2
        if sh_best is None or pre + sh_row.sum() < sh_best[0]:
            sh_best = (pre + sh_row.sum(), w, sh_row)
    shared = None
    if sh_best is not None:
        _, w, sh_row = sh_best
        use = sh_row < best
        saving = float((best - sh_row)[use].sum())
        need = np.zeros_like(vmax)
        sel = np.repeat(use, lens)
        np.maximum.at(need, g_vox[sel].astype(np.int64), g_wt[sel])
        j_v = -(-_bit_length(need) // w)
        cost = float(((j_v - 1).clip(0) * w).sum()) * _SQR
        if use.any() and saving > cost:
            v_need = np.flatnonzero(j_v > 1)
            shared = (use, w, list(zip(v_need.tolist(), j_v[v_need].tolist())))
    return best_w, shared


def _execute(plan: _Plan, cts: Sequence[mpz], n2: mpz, counter: OpCounter | None) -> list[mpz]:
    """Run the plan on one component (one ciphertext list)."""
    vl, wl = plan.vl, plan.wl
    mul = sq = n_pow = pow_bits = 0
    pw: list | None = None
    if plan.pre:
        pw, sq = _precompute(cts, plan.pre, plan.shared_w, n2)
    vals: list[mpz] = []
    for kind, s, e, w, n_win in plan.tasks:
        if kind == _ONES:  # the nearest-sampling hot path: one multiplication per pair
            acc = cts[vl[s]]
            for v in vl[s + 1 : e]:
                acc = acc * cts[v] % n2
            mul += e - s - 1
        elif kind == _SINGLE:
            c, x = cts[vl[s]], wl[s]
            if x < 16:
                acc, m, q = _small_pow(c, x, n2)
                mul += m
                sq += q
            else:
                acc = gmpy2.powmod(c, x, n2)
                n_pow += 1
                pow_bits += x.bit_length()
        elif kind == _HORNER:
            acc, m, q = _horner(cts, vl, wl, s, e, w, n_win, n2)
            mul += m
            sq += q
        else:
            acc, m = _shared(pw, vl, wl, s, e, plan.shared_w, n2)
            mul += m
        vals.append(acc)
    one = mpz(1)
    out = [one if u < 0 else vals[u] for u in plan.rep]
    if counter is not None:
        counter.mulmod += mul
        counter.squarings += sq
        counter.powmod += n_pow
        counter.powmod_bits += pow_bits
        counter.pairs += plan.n_pairs
        counter.rows += plan.n_rows
        counter.duplicate_rows += sum(1 for u in plan.rep if u >= 0) - len(plan.tasks)
        counter.precomputed += sum(j - 1 for _, j in plan.pre or ())
    return out


def _small_pow(c: mpz, x: int, n2: mpz) -> tuple[mpz, int, int]:
    """Left-to-right binary power; cheaper than powmod's Montgomery setup for x < 16."""
    acc, mul, sq = c, 0, 0
    for bit in bin(x)[3:]:
        acc = acc * acc % n2
        sq += 1
        if bit == "1":
            acc = acc * c % n2
            mul += 1
    return acc, mul, sq


def _combine(B: list, lo: int, hi: int, n2: mpz) -> tuple[mpz | None, int]:
    """``prod_d B[lo + d]^d`` for ``d`` in ``1..hi-lo`` by running products."""
    run = tot = None
    mul = 0
    for i in range(hi, lo, -1):
        b = B[i]
        if b is not None:
            if run is None:
                run = b
            else:
                run = run * b % n2
                mul += 1
        if run is not None:
            if tot is None:
                tot = run
            else:
                tot = tot * run % n2
                mul += 1
    return tot, mul


def _horner(cts, vl, wl, s: int, e: int, w: int, n_win: int, n2: mpz) -> tuple[mpz, int, int]:
    """Bucket multi-exponentiation, ``n_win`` windows of ``w`` bits joined by Horner."""
    size = 1 << w
    mask = size - 1
    B: list = [None] * (size * n_win)
    mul = 0
    if n_win == 1:  # bucket index is the weight itself
        for i in range(s, e):
            c = cts[vl[i]]
            x = wl[i]
            b = B[x]
            if b is None:
                B[x] = c
            else:
                B[x] = b * c % n2
                mul += 1
    else:
        for i in range(s, e):
            c = cts[vl[i]]
            x = wl[i]
            base = 0
            while x:
                d = x & mask
                if d:
                    b = B[base + d]
                    if b is None:
                        B[base + d] = c
                    else:
                        B[base + d] = b * c % n2
                        mul += 1
                x >>= w
                base += size
    acc = None
    sq = 0
    for j in range(n_win - 1, -1, -1):
        if acc is not None:
            for _ in range(w):
                acc = acc * acc % n2
            sq += w
        t, m = _combine(B, j * size, j * size + mask, n2)
        mul += m
        if t is not None:
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


def _shared(pw, vl, wl, s: int, e: int, w: int, n2: mpz) -> tuple[mpz, int]:
    """All windows share one bucket set thanks to the precomputed ``c^(2^(w j))``."""
    size = 1 << w
    mask = size - 1
    B: list = [None] * size
    mul = 0
    for i in range(s, e):
        powers = pw[vl[i]]
        x = wl[i]
        j = 0
        while x:
            d = x & mask
            if d:
                c = powers[j]
                b = B[d]
                if b is None:
                    B[d] = c
                else:
                    B[d] = b * c % n2
                    mul += 1
            x >>= w
            j += 1
    t, m = _combine(B, 0, mask, n2)
    return t, mul + m
