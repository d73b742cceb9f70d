"""Per-brick homomorphic ray products: ``P_r = prod_v c_v^(w_rv) mod n^2``.

For one brick the renderer has, per ray ``r``, plaintext weights ``w_rv >= 0`` in CSR form
(``indptr``, ``voxels``, ``weights``); the product of the Paillier ciphertexts raised to
them encrypts the weighted sum. The cost is big-integer modular multiplication, so the
kernel minimises their number. This module is the plaintext half: it plans, from the
public weights alone, which products to form (:func:`plan_products` ->
:class:`~hevr.backends.base.ProductPlan`); a backend (:mod:`hevr.backends`) executes the
plan on the ciphertexts (the CPU backend keeps the Python work per pair to a few bytecodes).

Cost model (unit: one ``a * b % n2``; a modular squaring ``S ~= 0.85``; ``powmod`` with
a ``b``-bit exponent ``~= 1.3 b + 0.5``; gmpy2 2.3, n^2 of 4096 bits). Zero weights are
dropped first; ``n`` is the number of remaining pairs of a row.

* Identical rows (same ``(voxel, weight)`` list; the raw bytes are dict keys) are
  computed once: a repeat costs nothing.
* ``n == 1``: binary powering (Horner below with ``w = 1``: ``(b - 1) S + popcount - 1``)
  or ``powmod``, whichever the model says is cheaper.
* All weights 1: running product, ``n - 1``.
* Otherwise a bucket (Pippenger-style) multi-exponentiation in radix ``2^w`` with
  ``J = ceil(bits(max weight) / w)`` windows. Window ``j`` multiplies ``c_v`` into bucket
  ``digit_j(w_rv)`` (the first entry of a bucket is free) and combines its buckets with
  running products, ``prod_d B_d^d = prod_k (prod_{d >= k} B_d)``: with ``n_j`` non-zero
  digits and top digit ``D_j`` a window costs exactly ``n_j + D_j - 2``. Windows are
  joined by Horner, ``w S + 1`` each, or, when ``2^w - D_j < w S``, by putting the
  accumulator into an extra bucket ``2^w`` (``2^w - D_j + 1``). ``J = 1`` is one bucket
  per weight value (``n + max_w - 2``). The exact cost is evaluated with numpy for
  every ``w`` and each row takes its cheapest.
* Shared buckets: with per-voxel powers ``c_v^(2^(w j))`` (``(J_v - 1) w`` squarings per
  voxel, once per brick, amortised over all rays through the voxel) the windows share one
  bucket set: ``sum_j n_j + max_j D_j - 2`` per row, no Horner. Used for a brick only
  when the rows' saving exceeds the precomputation (high voxel reuse).

10-bit trilinear rows of ~128 pairs take ``w = 5``, ``J = 2`` with a folded join:
``(124 + 29) + (124 + 31) = 308`` operations, ~2.4 per pair. Nearest rows (weights 1-2)
take ``w = 1``: ``n - 1`` plus one squaring when a 2 is present.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from array_api_compat import array_namespace, is_numpy_namespace
from gmpy2 import mpz

from ...backends import get_backend
from ...backends.base import HORNER, ONES, SHARED, SINGLE, Backend, OpCounter, ProductPlan
from ...backends.base import SQR_COST as _SQR
from ...errors import ParameterError
from ._segments import (
    bit_length,
    partition_max,
    partition_sum,
    place,
    popcount,
    segment_max,
    segment_sum,
    to_host,
)

__all__ = ["OpCounter", "brick_ray_products", "brick_ray_products_multi", "plan_products"]

_POW_BIT, _POW_BASE = 1.3, 0.5  # powmod cost per exponent bit, plus Montgomery set-up
_MAX_W = 16  # radix bits tried; 2^16 buckets is far beyond any optimum


def brick_ray_products(
    ciphertexts: Sequence[mpz],
    indptr: np.ndarray,
    voxels: np.ndarray,
    weights: np.ndarray,
    nsquare,
    counter: OpCounter | None = None,
    backend: str | Backend | None = None,
) -> list[mpz]:
    """Compute ``prod_v c_v^(w_rv) mod n^2`` for every CSR row of one brick.

    Parameters
    ----------
    ciphertexts : sequence of gmpy2.mpz
        Ciphertext of every local voxel, each in ``[0, nsquare)``.
    indptr : numpy.ndarray
        Integer offsets of length ``R + 1``; row ``r`` is ``indptr[r]:indptr[r + 1]``.
    voxels : numpy.ndarray
        Local voxel index (``0 <= v < len(ciphertexts)``) of every pair.
    weights : numpy.ndarray
        Non-negative integer weight of every pair (zeros are ignored).
    nsquare : int or gmpy2.mpz
        The modulus ``n^2``.
    counter : OpCounter, optional
        Incremented with the operations done.
    backend : str or Backend, optional
        The arithmetic backend (default: :func:`hevr.backends.get_backend`'s choice);
        ``ciphertexts`` is a batch of that backend (a list of mpz for ``cpu``).

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
    return brick_ray_products_multi([ciphertexts], indptr, voxels, weights, nsquare, counter, backend)[0]


def brick_ray_products_multi(
    components: Sequence[Sequence[mpz]],
    indptr: np.ndarray,
    voxels: np.ndarray,
    weights: np.ndarray,
    nsquare,
    counter: OpCounter | None = None,
    backend: str | Backend | None = None,
) -> list[list[mpz]]:
    """Like :func:`brick_ray_products` for ``k`` ciphertext lists sharing the weights.

    Vector-encoded volumes hold ``k`` ciphertexts per voxel; duplicate detection and the
    choice of method and window are done once and reused for every component.

    Parameters
    ----------
    components : sequence of sequences of gmpy2.mpz
        ``k`` lists, each with one ciphertext per local voxel (all the same length).
    indptr, voxels, weights, nsquare, counter, backend
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
            raise ParameterError(f"components[{i}]: expected {n_vox} ciphertexts, got {len(comp)}")
    plan = plan_products(indptr, voxels, weights, n_vox)
    return get_backend(backend).ray_products(plan, components, n2, counter)


def _as_int_array(name: str, a: Any) -> Any:
    """``a`` as a 1-D integer array of its own namespace (numpy for lists)."""
    try:
        xp = array_namespace(a)
    except TypeError:
        a = np.asarray(a)
        xp = array_namespace(a)
    if a.ndim != 1 or (a.shape[0] and not xp.isdtype(a.dtype, "integral")):
        raise ParameterError(f"{name}: expected a 1-D integer array, got {a.dtype} {a.shape}")
    return a


def plan_products(indptr: Any, voxels: Any, weights: Any, n_vox: int) -> ProductPlan:
    """Validate the CSR arrays, find duplicate rows and choose a method per row.

    Written against the array API (:mod:`hevr.rendering.pipeline._segments` has the segmented
    reductions): the plan's arrays are in the namespace of ``voxels`` — numpy, or CuPy on a GPU
    worker — and equal, bit for bit, whatever the namespace.

    Examples
    --------
    >>> p = plan_products(np.array([0, 2, 4, 4]), np.array([0, 1, 0, 1]), np.array([1, 1, 1, 1]), 2)
    >>> p.rep.tolist(), len(p.tasks)          # row 1 repeats row 0; row 2 is empty
    ([0, 0, -1], 1)
    """
    ip = _as_int_array("indptr", indptr)
    vox = _as_int_array("voxels", voxels)
    wt = _as_int_array("weights", weights)
    xp = array_namespace(vox, wt, ip)
    ip = xp.astype(ip, xp.int64)
    n_rows, n_pairs = ip.shape[0] - 1, int(vox.shape[0])
    if n_rows < 0 or int(ip[0]) != 0 or bool(xp.any(ip[1:] < ip[:-1])) or int(ip[-1]) != n_pairs:
        raise ParameterError("indptr: expected non-decreasing offsets from 0 to len(voxels)")
    if wt.shape[0] != n_pairs:
        raise ParameterError(f"weights: expected {n_pairs} entries like voxels, got {wt.shape[0]}")
    if n_pairs and (int(xp.min(vox)) < 0 or int(xp.max(vox)) >= n_vox):
        raise ParameterError(f"voxels: expected indices in [0, {n_vox}), got {int(xp.min(vox))}..{int(xp.max(vox))}")
    if n_pairs and xp.isdtype(wt.dtype, "signed integer") and int(xp.min(wt)) < 0:
        raise ParameterError("weights: expected non-negative integers, got a negative one")
    vox, wt = xp.astype(vox, xp.uint64), xp.astype(wt, xp.uint64)
    if n_pairs and not bool(xp.all(wt != 0)):  # zero weights contribute c^0 = 1: drop them
        keep = wt != 0
        counts = segment_sum(xp.astype(keep, xp.int64), ip[:-1], ip[1:])
        ip = xp.concat([xp.zeros(1, dtype=xp.int64), xp.cumulative_sum(counts)])
        vox, wt = vox[keep], wt[keep]
    rep_a, u_rows = _duplicate_rows(ip, vox, wt)
    plan = ProductPlan(n_rows, n_pairs, rep_a, xp.astype(vox, xp.int64), wt, xp.zeros((0, 5), dtype=xp.int64))
    if not u_rows.shape[0]:
        return plan
    u_s, u_e = xp.take(ip, u_rows), xp.take(ip, u_rows + 1)
    u_max = segment_max(wt, u_s, u_e)
    kinds = xp.full(u_rows.shape, HORNER, dtype=xp.int64)
    kinds = xp.where(u_e - u_s == 1, SINGLE, xp.where(u_max == 1, ONES, kinds))
    gen = xp.nonzero(kinds == HORNER)[0]
    # One pair: binary powering is Horner with w = 1, (b - 1) S + popcount - 1; else powmod.
    b = bit_length(u_max)
    bf = xp.astype(b, xp.float64)
    binary = (kinds == SINGLE) & (
        (bf - 1) * _SQR + xp.astype(popcount(u_max) - 1, xp.float64) <= _POW_BIT * bf + _POW_BASE
    )
    kinds = xp.where(binary, HORNER, kinds)
    w_r = xp.astype(binary, xp.int64)
    if gen.shape[0]:
        w_gen, shared = _choose_windows(vox, wt, xp.take(u_s, gen), xp.take(u_e, gen), xp.take(u_max, gen))
        w_r = place(w_r, gen, w_gen)
        if shared is not None:
            use, plan.shared_w, plan.pre = shared
            kinds = place(kinds, gen[use], xp.full(int(xp.sum(xp.astype(use, xp.int64))), SHARED, dtype=kinds.dtype))
    n_win = xp.where(w_r > 0, -(-b // xp.maximum(w_r, 1)), 0)
    plan.tasks = xp.astype(xp.stack([kinds, u_s, u_e, w_r, n_win], axis=1), xp.int64)
    return plan


_MIX = (0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0xBF58476D1CE4E5B9)


def _duplicate_rows(ip: Any, vox: Any, wt: Any) -> tuple[Any, Any]:
    """Identical rows, found with array operations: ``(rep, uniq)``.

    ``uniq`` holds the first row of every distinct non-empty ``(voxel, weight)`` list, in row
    order; ``rep[r]`` is the position in ``uniq`` of row ``r``'s list (-1: an empty row). Rows
    are grouped by length and a 64-bit hash of their pairs and positions, then every row is
    compared pair by pair with its group's first row, so a hash collision cannot merge two
    different rows (on one, the rows are grouped again by their exact bytes).

    >>> r, u = _duplicate_rows(np.array([0, 2, 2, 4, 5]), np.array([1, 2, 1, 2, 1], np.uint64),
    ...                        np.array([1, 1, 1, 1, 1], np.uint64))
    >>> r.tolist(), u.tolist()
    ([0, -1, 0, 1], [0, 3])
    """
    xp = array_namespace(ip, vox, wt)
    n_rows = ip.shape[0] - 1
    lens = ip[1:] - ip[:-1]
    rows = xp.nonzero(lens)[0]
    rep = xp.full(n_rows, -1, dtype=xp.int64)
    if not rows.shape[0]:
        return rep, rows
    k0, k1, k2, k3 = _MIX
    pos = xp.astype(xp.arange(vox.shape[0], dtype=xp.int64) - xp.repeat(ip[:-1], lens), xp.uint64)
    with np.errstate(over="ignore"):
        h = (vox * k0) ^ ((wt + k1) * k2) ^ ((pos + 1) * k3)
        h = h ^ (h >> 31)
        h = h * k1
        h = h ^ (h >> 29)
        r_s, r_l = xp.take(ip, rows), xp.take(lens, rows)
        key = partition_sum(h, r_s) ^ (xp.astype(r_l, xp.uint64) * k2)  # the non-empty rows cover the pairs
    u = xp.unique_all(key)
    head = xp.take(rows, xp.take(u.indices, xp.reshape(u.inverse_indices, (-1,))))  # each row's group's first row
    other = xp.nonzero(head != rows)[0]
    if other.shape[0]:  # check every pair against the group's first row
        r, g = xp.take(rows, other), xp.take(head, other)
        n = xp.take(lens, r)
        if bool(xp.any(n != xp.take(lens, g))):  # a hash collision across lengths
            return _duplicate_rows_exact(ip, vox, wt)
        off = xp.cumulative_sum(n) - n
        at = xp.arange(int(xp.sum(n)), dtype=xp.int64) - xp.repeat(off, n)
        a, b = xp.repeat(xp.take(ip, r), n) + at, xp.repeat(xp.take(ip, g), n) + at
        bad = xp.astype((xp.take(vox, a) != xp.take(vox, b)) | (xp.take(wt, a) != xp.take(wt, b)), xp.int64)
        if bool(xp.any(segment_sum(bad, off, off + n) > 0)):  # a hash collision: compare exact bytes instead
            return _duplicate_rows_exact(ip, vox, wt)
    uniq = xp.sort(xp.take(rows, u.indices))
    return place(rep, rows, xp.searchsorted(uniq, head)), uniq


def _duplicate_rows_exact(ip: Any, vox: Any, wt: Any) -> tuple[Any, Any]:
    """:func:`_duplicate_rows` by the exact bytes of every row (a dict, on the host): the
    collision fallback; the result in the namespace of the inputs."""
    xp = array_namespace(ip, vox, wt)
    ipl, v, w = (to_host(a) for a in (ip, vox, wt))
    blob = np.stack([v.astype(np.uint64), w.astype(np.uint64)], axis=1).tobytes()
    ipl = ipl.tolist()
    rep = [-1] * (len(ipl) - 1)
    uniq: list[int] = []  # the first row of each distinct content
    first: dict[bytes, int] = {}  # a row's bytes -> its index in uniq
    for r in range(len(ipl) - 1):
        s, e = ipl[r], ipl[r + 1]
        if s != e:
            rep[r] = u = first.setdefault(blob[16 * s : 16 * e], len(uniq))
            if u == len(uniq):
                uniq.append(r)
    return xp.asarray(np.asarray(rep, np.int64)), xp.asarray(np.asarray(uniq, np.int64))


def _choose_windows(vox: Any, wt: Any, starts: Any, stops: Any, rmax: Any) -> tuple[Any, Any]:
    """Per-row radix bits minimising the exact Horner cost; decide on shared buckets.

    The per-row costs are elementwise (the same bits in every namespace); the few sums that
    decide between alternatives are taken on the host, so their order of addition is numpy's
    whatever the namespace.
    """
    xp = array_namespace(vox, wt, starts)
    lens = stops - starts
    offs = xp.cumulative_sum(lens) - lens  # the rows are gathered so that they are segments
    idx = xp.repeat(starts - offs, lens) + xp.arange(int(xp.sum(lens)), dtype=xp.int64)
    g_wt, g_vox = xp.take(wt, idx), xp.take(vox, idx)
    bits = bit_length(rmax)
    b_max = int(xp.max(bits))
    best = xp.astype(lens, xp.float64) + xp.astype(rmax, xp.float64) - 2  # J = 1: one bucket per weight value
    best_w = bits
    zero = xp.zeros(lens.shape[0], dtype=xp.float64)
    # With weights <= 3 shared buckets save at most one squaring per row for one per
    # voxel: not worth evaluating.
    try_shared = b_max > 2
    if try_shared:  # per-voxel bits of the largest weight (voxels no row reaches count for nothing)
        hist = np.bincount(to_host(bit_length(_per_voxel_max(g_vox, g_wt)[1])), minlength=b_max + 1)
        bit_vals = np.arange(hist.size)
    sh_best = None  # (total cost, w, per-row cost)
    for w in range(1, min(b_max - 1, _MAX_W, int(xp.max(lens)).bit_length() + 2) + 1):
        mask = (1 << w) - 1
        last = -(-bits // w) - 1
        horner, digits, dmax = zero, zero, zero
        for j in range(-(-b_max // w)):
            d = (g_wt >> (w * j)) & mask
            nz = xp.astype(partition_sum(xp.astype(d != 0, xp.int64), offs), xp.float64)
            dj = xp.astype(partition_max(d, offs), xp.float64)
            join = xp.where(nz > 0, xp.minimum(xp.full_like(dj, w * _SQR + 1), 2**w - dj + 1), w * _SQR)
            horner = horner + xp.where(nz > 0, nz + dj - 2, 0.0) + xp.where(last > j, join, 0.0)
            digits, dmax = digits + nz, xp.maximum(dmax, dj)
        better = horner < best
        best, best_w = xp.where(better, horner, best), xp.where(better, w, best_w)
        if try_shared:
            pre = float((hist * ((-(-bit_vals // w) - 1).clip(0) * w)).sum()) * _SQR
            sh_row = digits + dmax - 2
            cost = pre + to_host(sh_row).sum()
            if sh_best is None or cost < sh_best[0]:
                sh_best = (cost, w, sh_row)
    if sh_best is None:
        return best_w, None
    _, w, sh_row = sh_best
    use = sh_row < best  # re-price the precomputation for the rows that would use it
    sel = xp.repeat(use, lens)
    v_need, need = _per_voxel_max(g_vox[sel], g_wt[sel])  # voxels ascending, J_v >= 1 each
    j_v = -(-bit_length(need) // w)
    gain = to_host(best - sh_row)[to_host(use)].sum()
    if not bool(xp.any(use)) or gain <= int(to_host((j_v - 1) * w).sum()) * _SQR:
        return best_w, None
    return best_w, (use, w, xp.astype(xp.stack([xp.astype(v_need, xp.int64), j_v], axis=1), xp.int64))


def _per_voxel_max(vox: Any, wt: Any) -> tuple[Any, Any]:
    """The distinct voxels of ``vox`` (ascending) and the largest weight each has.

    >>> v, m = _per_voxel_max(np.array([4, 1, 4], np.uint64), np.array([2, 3, 5], np.uint64))
    >>> v.tolist(), m.tolist()
    ([1, 4], [3, 5])
    """
    xp = array_namespace(vox, wt)
    if is_numpy_namespace(xp) and vox.size:  # numpy's scattered maximum: the same values, faster
        top = np.zeros(int(vox.max()) + 1, np.uint64)
        np.maximum.at(top, vox.astype(np.int64), wt)
        v = np.flatnonzero(top)  # weights are positive: exactly the voxels present
        return v.astype(vox.dtype), top[v]
    order = xp.argsort(vox, stable=True)
    sv, sw = xp.take(vox, order), xp.take(wt, order)
    n = int(sv.shape[0])
    starts = xp.nonzero(xp.concat([xp.ones(min(n, 1), dtype=xp.bool), sv[1:] != sv[:-1]]))[0]
    ends = xp.concat([starts[1:], xp.asarray([n], dtype=starts.dtype)])
    return xp.take(sv, starts), segment_max(sw, starts, ends)
