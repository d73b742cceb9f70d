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

import numpy as np
from gmpy2 import mpz

from ..backends import get_backend
from ..backends.base import HORNER as _HORNER
from ..backends.base import ONES as _ONES
from ..backends.base import SHARED as _SHARED
from ..backends.base import SINGLE as _SINGLE
from ..backends.base import SQR_COST as _SQR
from ..backends.base import Backend, OpCounter, ProductPlan
from ..errors import ParameterError

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


def _as_int_array(name: str, a) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim != 1 or (arr.size and arr.dtype.kind not in "iu"):
        raise ParameterError(f"{name}: expected a 1-D integer array, got {arr.dtype} {arr.shape}")
    return arr


def _popcount(a: np.ndarray) -> np.ndarray:
    """Set bits of each uint64 (SWAR; ``np.bitwise_count`` needs numpy 2).

    >>> _popcount(np.array([0, 1, 6, 2**64 - 1], np.uint64)).tolist()
    [0, 1, 2, 64]
    """
    x = a.astype(np.uint64)
    with np.errstate(over="ignore"):
        x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
        x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
        x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
        return ((x * np.uint64(0x0101010101010101)) >> np.uint64(56)).astype(np.int64)


def _bit_length(a: np.ndarray) -> np.ndarray:
    """Exact bit lengths of non-negative integers (frexp rounds up just below 2^k, k > 53)."""
    a = a.astype(np.uint64)
    bits = np.minimum(np.frexp(a.astype(np.float64))[1], 64).astype(np.int64)
    if a.size == 0 or a.max() < 2**53:
        return bits
    return bits - ((bits > 0) & ((a >> np.maximum(bits - 1, 0).astype(np.uint64)) == 0))


def plan_products(indptr, voxels, weights, n_vox: int) -> ProductPlan:
    """Validate the CSR arrays, find duplicate rows and choose a method per row.

    Examples
    --------
    >>> p = plan_products(np.array([0, 2, 4, 4]), np.array([0, 1, 0, 1]), np.array([1, 1, 1, 1]), 2)
    >>> p.rep.tolist(), len(p.tasks)          # row 1 repeats row 0; row 2 is empty
    ([0, 0, -1], 1)
    """
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
    if n_pairs and not wt.all():  # zero weights contribute c^0 = 1: drop them
        keep = wt != 0
        rowid = np.repeat(np.arange(n_rows), np.diff(ip))
        ip = np.concatenate([[0], np.cumsum(np.bincount(rowid[keep], minlength=n_rows))])
        vox, wt = vox[keep], wt[keep]
    rep_a, u_rows = _duplicate_rows(ip, vox, wt)
    plan = ProductPlan(n_rows, n_pairs, rep_a, vox.astype(np.int64), wt, np.zeros((0, 5), np.int64))
    if not u_rows.size:
        return plan
    nonempty = np.flatnonzero(np.diff(ip))
    row_max = np.zeros(n_rows, np.uint64)
    row_max[nonempty] = np.maximum.reduceat(wt, ip[nonempty])
    u_s, u_e, u_max = ip[u_rows], ip[u_rows + 1], row_max[u_rows]
    kinds = np.where(u_e - u_s == 1, _SINGLE, np.where(u_max == 1, _ONES, _HORNER))
    w_r = np.zeros(u_rows.size, np.int64)
    gen = np.flatnonzero(kinds == _HORNER)
    # One pair: binary powering is Horner with w = 1, (b - 1) S + popcount - 1; else powmod.
    single = kinds == _SINGLE
    b = _bit_length(u_max)
    binary = single & ((b - 1) * _SQR + _popcount(u_max) - 1 <= _POW_BIT * b + _POW_BASE)
    kinds[binary], w_r[binary] = _HORNER, 1
    if gen.size:
        w_r[gen], shared = _choose_windows(vox, wt, u_s[gen], u_e[gen], u_max[gen])
        if shared is not None:
            use, plan.shared_w, plan.pre = shared
            kinds[gen[use]] = _SHARED
    n_win = np.where(w_r > 0, -(-_bit_length(u_max) // np.maximum(w_r, 1)), 0)
    plan.tasks = np.stack([kinds, u_s, u_e, w_r, n_win], axis=1).astype(np.int64)
    return plan


_MIX = tuple(np.uint64(k) for k in (0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0xBF58476D1CE4E5B9))


def _duplicate_rows(ip: np.ndarray, vox: np.ndarray, wt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    n_rows = ip.size - 1
    lens = np.diff(ip)
    rows = np.flatnonzero(lens)
    rep = np.full(n_rows, -1, np.int64)
    if not rows.size:
        return rep, rows
    k0, k1, k2, k3 = _MIX
    pos = np.arange(vox.size, dtype=np.uint64) - np.repeat(ip[:-1], lens).astype(np.uint64)
    with np.errstate(over="ignore"):
        h = (vox * k0) ^ ((wt + k1) * k2) ^ ((pos + np.uint64(1)) * k3)
        h ^= h >> np.uint64(31)
        h *= k1
        h ^= h >> np.uint64(29)
        key = np.add.reduceat(h, ip[rows]) ^ (lens[rows].astype(np.uint64) * k2)
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    head = rows[first[inverse.reshape(-1)]]  # per non-empty row: the first row of its group
    other = head != rows
    if other.any():  # check every pair against the group's first row
        r, g = rows[other], head[other]
        n = lens[r]
        if np.any(n != lens[g]):  # a hash collision across lengths
            return _duplicate_rows_exact(ip, vox, wt)
        start = np.repeat(ip[r], n)
        at = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        a, b = start + at, np.repeat(ip[g], n) + at
        differ = np.add.reduceat(((vox[a] != vox[b]) | (wt[a] != wt[b])).astype(np.int64), np.cumsum(n) - n)
        if differ.any():  # a hash collision: group these rows by their exact bytes instead
            return _duplicate_rows_exact(ip, vox, wt)
    uniq = np.unique(head)
    rep[rows] = np.searchsorted(uniq, head)
    return rep, uniq


def _duplicate_rows_exact(ip: np.ndarray, vox: np.ndarray, wt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_duplicate_rows` by the exact bytes of every row (a dict): the collision fallback."""
    blob = np.stack([vox, wt], axis=1).tobytes()
    ipl = ip.tolist()
    rep, uniq, first = [-1] * (ip.size - 1), [], {}
    for r in range(ip.size - 1):
        s, e = ipl[r], ipl[r + 1]
        if s != e:
            rep[r] = u = first.setdefault(blob[16 * s : 16 * e], len(uniq))
            if u == len(uniq):
                uniq.append(r)
    return np.asarray(rep, np.int64), np.asarray(uniq, np.int64)


def _choose_windows(vox, wt, starts, stops, rmax):
    """Per-row radix bits minimising the exact Horner cost; decide on shared buckets."""
    lens = stops - starts
    offs = np.cumsum(lens) - lens  # the rows are gathered so that reduceat can segment them
    idx = np.repeat(starts - offs, lens) + np.arange(int(lens.sum()))
    g_wt, g_vox = wt[idx], vox[idx]
    bits = _bit_length(rmax)
    b_max = int(bits.max())
    best = lens + rmax.astype(np.float64) - 2  # J = 1: one bucket per weight value
    best_w = bits.copy()
    # With weights <= 3 shared buckets save at most one squaring per row for one per
    # voxel: not worth evaluating.
    try_shared = b_max > 2
    if try_shared:
        n_vox = int(g_vox.max()) + 1
        vmax = np.zeros(n_vox, np.uint64)
        np.maximum.at(vmax, g_vox.astype(np.int64), g_wt)
        hist = np.bincount(_bit_length(vmax), minlength=b_max + 1)  # of per-voxel bits
        bit_vals = np.arange(hist.size)
    sh_best = None  # (total cost, w, per-row cost)
    for w in range(1, min(b_max - 1, _MAX_W, int(lens.max()).bit_length() + 2) + 1):
        mask = np.uint64((1 << w) - 1)
        n_j = -(-bits // w)
        horner = digits = dmax = 0
        for j in range(-(-b_max // w)):
            d = (g_wt >> np.uint64(w * j)) & mask
            nz = np.add.reduceat(d != 0, offs).astype(np.float64)
            dj = np.maximum.reduceat(d, offs).astype(np.float64)
            join = np.where(nz > 0, np.minimum(w * _SQR + 1, 2**w - dj + 1), w * _SQR)
            horner = horner + np.where(nz > 0, nz + dj - 2, 0) + np.where(j < n_j - 1, join, 0)
            digits, dmax = digits + nz, np.maximum(dmax, dj)
        better = horner < best
        best, best_w = np.where(better, horner, best), np.where(better, w, best_w)
        if try_shared:
            pre = float((hist * ((-(-bit_vals // w) - 1).clip(0) * w)).sum()) * _SQR
            sh_row = digits + dmax - 2
            if sh_best is None or pre + sh_row.sum() < sh_best[0]:
                sh_best = (pre + sh_row.sum(), w, sh_row)
    if sh_best is None:
        return best_w, None
    _, w, sh_row = sh_best
    use = sh_row < best  # re-price the precomputation for the rows that would use it
    need = np.zeros(n_vox, np.uint64)
    sel = np.repeat(use, lens)
    np.maximum.at(need, g_vox[sel].astype(np.int64), g_wt[sel])
    j_v = -(-_bit_length(need) // w)
    if not use.any() or (best - sh_row)[use].sum() <= ((j_v - 1).clip(0) * w).sum() * _SQR:
        return best_w, None
    v_need = np.flatnonzero(j_v >= 1)  # J_v == 1 entries are just [c]
    return best_w, (use, w, np.stack([v_need, j_v[v_need]], axis=1).astype(np.int64))
