"""Tests of hevr.rendering.pipeline.kernel: products against a naive prod-of-powmod, and operation counts."""

from __future__ import annotations

import gmpy2
import numpy as np
import pytest
from gmpy2 import mpz
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hevr.errors import ParameterError
from hevr.rendering.pipeline.kernel import (
    OpCounter,
    brick_ray_products,
    brick_ray_products_multi,
    plan_products,
)


def _modulus(rng: np.random.Generator, bits: int) -> mpz:
    n = mpz(int.from_bytes(rng.bytes(bits // 8), "big")) | 1 | (mpz(1) << (bits - 1))
    return n * n


def _values(rng: np.random.Generator, count: int, n2: mpz) -> list[mpz]:
    width = (gmpy2.bit_length(n2) + 7) // 8 + 8
    return [mpz(int.from_bytes(rng.bytes(width), "big")) % n2 for _ in range(count)]


def _naive(cts, indptr, voxels, weights, n2) -> list[mpz]:
    out = []
    for r in range(len(indptr) - 1):
        acc = mpz(1)
        for i in range(int(indptr[r]), int(indptr[r + 1])):
            acc = acc * gmpy2.powmod(cts[int(voxels[i])], int(weights[i]), n2) % n2
        out.append(acc)
    return out


def _csr(rows):
    """rows: list of lists of (voxel, weight) -> (indptr, voxels, weights)."""
    indptr = np.zeros(len(rows) + 1, np.int64)
    indptr[1:] = np.cumsum([len(r) for r in rows])
    voxels = np.array([v for r in rows for v, _ in r], np.int64)
    weights = np.array([w for r in rows for _, w in r], np.int64)
    return indptr, voxels, weights


@pytest.fixture(scope="module")
def ring():
    rng = np.random.default_rng(12345)
    n2 = _modulus(rng, 384)
    return rng, n2, _values(rng, 400, n2)


def _check(cts, rows, n2, counter=None):
    ip, vx, wt = _csr(rows)
    got = brick_ray_products(cts, ip, vx, wt, n2, counter)
    assert got == _naive(cts, ip, vx, wt, n2)
    assert all(isinstance(x, type(mpz(0))) for x in got)
    return got


def test_empty_csr_and_empty_rows(ring):
    _, n2, cts = ring
    c = OpCounter()
    assert brick_ray_products(cts, np.array([0]), np.array([], np.int64), np.array([], np.int64), n2, c) == []
    got = _check(cts, [[], [(3, 0), (4, 0)], [], [(5, 0)]], n2, c)
    assert got == [mpz(1)] * 4
    assert (c.mulmod, c.squarings, c.powmod, c.rows, c.pairs) == (0, 0, 0, 4, 3)


def test_single_pairs(ring):
    _, n2, cts = ring
    weights = list(range(0, 40)) + [255, 256, 1000, 1023, 4097, 5000, 2**20 + 7, 2**40 - 1]
    c = OpCounter()
    _check(cts, [[(i % len(cts), w)] for i, w in enumerate(weights)], n2, c)
    assert c.powmod >= 1  # the large exponents go to powmod


def test_weight_one_single_pair_is_free(ring):
    _, n2, cts = ring
    c = OpCounter()
    assert _check(cts, [[(7, 1)]], n2, c) == [cts[7]]
    assert c.modmuls == 0 and c.powmod == 0


@pytest.mark.parametrize("length", [2, 3, 17, 64])
def test_all_ones_cost_length_minus_one(ring, length):
    rng, n2, cts = ring
    rows = [[(int(v), 1) for v in rng.integers(0, len(cts), length)] for _ in range(5)]
    c = OpCounter()
    _check(cts, rows, n2, c)
    assert (c.mulmod, c.squarings, c.powmod) == (5 * (length - 1), 0, 0)


def test_zero_weights_are_skipped(ring):
    _, n2, cts = ring
    c = OpCounter()
    _check(cts, [[(1, 1), (2, 0), (3, 1), (4, 0)]], n2, c)
    assert c.mulmod == 1


def test_all_twos_uses_one_squaring(ring):
    _, n2, cts = ring
    c = OpCounter()
    _check(cts, [[(v, 2) for v in range(10)]], n2, c)
    assert (c.mulmod, c.squarings) == (9, 1)


def test_duplicate_rows_not_recomputed(ring):
    rng, n2, cts = ring
    row = [(int(v), int(w)) for v, w in zip(rng.integers(0, 400, 30), rng.integers(1, 4, 30))]
    other = [(v, w + 1) for v, w in row]  # same voxels, other weights: not a duplicate
    separate = OpCounter()
    for r in (row, other, row[::-1]):
        _check(cts, [r], n2, separate)
    c = OpCounter()
    got = _check(cts, [row, [], row, other, row[::-1], row, other], n2, c)
    assert got[0] == got[2] == got[5] == got[4] and got[3] == got[6]
    assert c.duplicate_rows == 3
    assert c.modmuls <= separate.modmuls  # only row, other and the reversed row computed


def test_weights_up_to_5000(ring):
    rng, n2, cts = ring
    rows = []
    for length in [0, 1, 2, 5, 40, 120]:
        vox = rng.integers(0, len(cts), length)
        rows.append([(int(v), int(w)) for v, w in zip(vox, rng.integers(0, 5001, length))])
    c = OpCounter()
    _check(cts, rows, n2, c)
    pairs = sum(len(r) for r in rows)
    assert c.modmuls + 20 * c.powmod_bits < 6 * pairs  # naive powmod costs ~16 per pair


def test_trilinear_cost_per_pair(ring):
    rng, n2, cts = ring
    # Distinct voxels per row and little reuse: the per-row Horner bucket method.
    rows = [
        [(int(v), int(w)) for v, w in zip(rng.permutation(len(cts))[:128], rng.integers(1, 1024, 128))]
        for _ in range(4)
    ]
    c = OpCounter()
    _check(cts, rows, n2, c)
    assert c.precomputed == 0 and c.powmod == 0
    assert c.modmuls / c.pairs < 2.6  # model: ~312 / 128 = 2.44


def test_nearest_cost_per_pair(ring):
    rng, n2, cts = ring
    rows = [[(int(v), 2 if rng.random() < 0.08 else 1) for v in rng.integers(0, 400, 32)] for _ in range(20)]
    c = OpCounter()
    _check(cts, rows, n2, c)
    assert c.mulmod + c.squarings <= c.pairs - 20 + sum(any(w == 2 for _, w in r) for r in rows)


def test_shared_buckets_with_high_reuse(ring):
    rng, n2, cts = ring
    rows = [[(int(v), int(w)) for v, w in zip(rng.permutation(16), rng.integers(1, 1024, 16))] for _ in range(200)]
    c = OpCounter()
    _check(cts, rows, n2, c)
    assert 0 < c.precomputed <= 16 * 9  # at most J_v - 1 <= 9 powers per voxel
    alone = OpCounter()  # one row per call: no reuse, so per-row Horner
    for r in rows[:50]:
        brick_ray_products(cts, *_csr([r]), n2, alone)
    assert alone.precomputed == 0
    assert c.modmuls / 200 < 0.9 * alone.modmuls / 50


def test_large_uint64_weights(ring):
    rng, n2, cts = ring
    ip = np.array([0, 3, 4])
    vx = np.array([1, 2, 3, 4])
    wt = np.array([2**64 - 1, 2**63 + 5, 12345, 2**53 + 1], np.uint64)
    got = brick_ray_products(cts, ip, vx, wt, n2)
    assert got == _naive(cts, ip, vx, [int(x) for x in wt], n2)


@pytest.mark.parametrize("k", [1, 3])
def test_components_share_plan(ring, k):
    rng, n2, cts = ring
    comps = [_values(rng, 50, n2) for _ in range(k)]
    rows = [
        [(int(v), int(w)) for v, w in zip(rng.integers(0, 50, n), rng.integers(0, 1100, n))]
        for n in [0, 1, 3, 30, 30, 70]
    ]
    rows.append(rows[3])
    ip, vx, wt = _csr(rows)
    c = OpCounter()
    got = brick_ray_products_multi(comps, ip, vx, wt, n2, c)
    assert len(got) == k
    one = OpCounter()
    for comp, res in zip(comps, got):
        assert res == _naive(comp, ip, vx, wt, n2)
    brick_ray_products(comps[0], ip, vx, wt, n2, one)
    assert c.modmuls == k * one.modmuls and c.duplicate_rows == k
    assert brick_ray_products_multi([], ip, vx, wt, n2) == []


def test_plain_sequences_and_int_modulus(ring):
    _, n2, cts = ring
    got = brick_ray_products(cts, [0, 2, 3], [5, 6, 5], [3, 1, 2], int(n2))
    assert got == _naive(cts, [0, 2, 3], [5, 6, 5], [3, 1, 2], n2)


def test_counter_add():
    a, b = OpCounter(mulmod=1, pairs=2), OpCounter(mulmod=3, squarings=4)
    a.add(b)
    assert (a.mulmod, a.squarings, a.pairs, a.modmuls) == (4, 4, 2, 8)


@pytest.mark.parametrize(
    "indptr, voxels, weights, match",
    [
        ([1, 2], [0, 1], [1, 1], "indptr"),
        ([0, 2, 1], [0, 1], [1, 1], "indptr"),
        ([0, 3], [0, 1], [1, 1], "indptr"),
        ([], [], [], "indptr"),
        ([0, 2], [0, 1], [1], "weights"),
        ([0, 2], [0, 10], [1, 1], "voxels"),
        ([0, 2], [-1, 0], [1, 1], "voxels"),
        ([0, 2], [0, 1], [1, -1], "weights"),
        ([0, 2], [0, 1], [1.0, 2.0], "weights"),
        ([0, 2], [[0, 1]], [1, 1], "voxels"),
    ],
)
def test_invalid_csr(ring, indptr, voxels, weights, match):
    _, n2, cts = ring
    with pytest.raises(ParameterError, match=match):
        brick_ray_products(cts[:10], np.array(indptr), np.array(voxels), np.array(weights), n2)


def test_invalid_modulus_and_components(ring):
    _, n2, cts = ring
    args = (np.array([0, 1]), np.array([0]), np.array([1]))
    with pytest.raises(ParameterError, match="nsquare"):
        brick_ray_products(cts, *args, 1)
    with pytest.raises(ValueError, match="nsquare"):
        brick_ray_products(cts, *args, "x")
    with pytest.raises(ParameterError, match="components"):
        brick_ray_products_multi([cts[:3], cts[:4]], *args, n2)


_weight = st.one_of(
    st.integers(0, 3), st.integers(0, 1100), st.integers(0, 2**24), st.sampled_from([2**31 - 1, 2**32 + 1])
)


@st.composite
def _random_csr(draw):
    n_vox = draw(st.integers(1, 12))
    rows = draw(st.lists(st.lists(st.tuples(st.integers(0, n_vox - 1), _weight), max_size=14), max_size=10))
    if rows and draw(st.booleans()):  # duplicated rows, as nearest sampling makes them
        rows = rows + [rows[draw(st.integers(0, len(rows) - 1))]]
    dtype = draw(st.sampled_from([np.int64, np.uint64, np.int32]))
    return n_vox, rows, dtype


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=_random_csr(), bits=st.sampled_from([256, 512]), k=st.integers(1, 2), seed=st.integers(0, 2**32 - 1))
def test_random_csr_matches_naive(case, bits, k, seed):
    n_vox, rows, dtype = case
    rng = np.random.default_rng(seed)
    n2 = _modulus(rng, bits)
    comps = [_values(rng, n_vox, n2) for _ in range(k)]
    ip, vx, wt = _csr(rows)
    wt = (wt % 2**31 if dtype is np.int32 else wt).astype(dtype)
    c = OpCounter()
    got = brick_ray_products_multi(comps, ip, vx.astype(dtype), wt, n2, c)
    for comp, res in zip(comps, got):
        assert res == _naive(comp, ip, vx, wt, n2)
    assert c.rows == k * len(rows) and c.pairs == k * len(vx)


# -- duplicate rows found with array operations (issue 27, item 1) ---------------------------------------
def _csr_with_repeats(rng: np.random.Generator, n_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows drawn from a few distinct (voxel, weight) lists, with empty rows and near-misses
    (same voxels, one weight changed; same pairs in another order)."""
    base = [
        (rng.integers(0, 30, size=n, dtype=np.uint64), rng.integers(1, 4, size=n, dtype=np.uint64))
        for n in rng.integers(1, 6, size=6)
    ]
    rows = []
    for _ in range(n_rows):
        v, w = base[int(rng.integers(0, len(base)))]
        kind = int(rng.integers(0, 5))
        if kind == 0:
            v, w = v[:0], w[:0]
        elif kind == 1 and v.size:
            w = w.copy()
            w[-1] += 1
        elif kind == 2 and v.size > 1:
            v, w = v[::-1], w[::-1]
        rows.append((v, w))
    ip = np.concatenate([[0], np.cumsum([v.size for v, _ in rows])]).astype(np.int64)
    vox = np.concatenate([v for v, _ in rows]).astype(np.uint64)
    wt = np.concatenate([w for _, w in rows]).astype(np.uint64)
    return ip, vox, wt


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 80))
def test_duplicate_rows_match_the_exact_byte_comparison(seed, n_rows):
    from hevr.rendering.pipeline.kernel import _duplicate_rows, _duplicate_rows_exact

    ip, vox, wt = _csr_with_repeats(np.random.default_rng(seed), n_rows)
    rep, uniq = _duplicate_rows(ip, vox, wt)
    rep_x, uniq_x = _duplicate_rows_exact(ip, vox, wt)
    assert rep.tolist() == rep_x.tolist() and uniq.tolist() == uniq_x.tolist()


def test_duplicate_rows_survive_hash_collisions(monkeypatch):
    """With every hash equal, rows of one length collide: the exact comparison still decides."""
    import hevr.rendering.pipeline.kernel as kernel

    ip, vox, wt = _csr_with_repeats(np.random.default_rng(7), 50)
    expected = kernel._duplicate_rows_exact(ip, vox, wt)
    monkeypatch.setattr(kernel, "_MIX", tuple(np.uint64(0) for _ in range(4)))
    rep, uniq = kernel._duplicate_rows(ip, vox, wt)
    assert rep.tolist() == expected[0].tolist() and uniq.tolist() == expected[1].tolist()
    assert len(set(expected[0].tolist())) > 3  # several distinct rows, so a merge would show


# -- the plan under a second array namespace (issue 27, item 2) ----------------------------------------
def _plans_equal(a, b) -> None:
    def to_np(x):
        return x if isinstance(x, np.ndarray) else np.from_dlpack(x)

    assert (a.n_rows, a.n_pairs, a.shared_w) == (b.n_rows, b.n_pairs, b.shared_w)
    for name in ("rep", "vl", "wl", "tasks"):
        x, y = to_np(getattr(a, name)), to_np(getattr(b, name))
        assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert (a.pre is None) == (b.pre is None)
    if a.pre is not None:
        assert np.array_equal(to_np(a.pre), to_np(b.pre))


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_plan_is_bit_identical_under_array_api_strict(sampling):
    """Real weights of a render (every brick of a small volume, trilinear rows with shared
    buckets among them) planned from numpy arrays and from ``array_api_strict`` arrays: the
    same plan, array for array (the plan code runs on any array-API namespace, CuPy included)."""
    xps = pytest.importorskip("array_api_strict")
    from hevr.rendering.geometry.camera import Camera
    from hevr.rendering.geometry.rays import cast_rays
    from hevr.rendering.geometry.weights import brick_grid, brick_weights

    shape, brick = (10, 9, 11), (4, 5, 4)  # many rays per voxel: shared buckets pay off for trilinear rows
    cam = Camera.orbit(shape, 25, 15, width=48, height=44)
    rays = cast_rays(cam, shape, (1, 1, 1), 0.7)
    shared = 0
    for idx in np.ndindex(*brick_grid(shape, brick)):
        bw = brick_weights(rays, shape, (1, 1, 1), brick, idx, sampling, 0.7, 3)
        ref = plan_products(bw.indptr, bw.voxels, bw.weights, 4 * 5 * 4)
        got = plan_products(xps.asarray(bw.indptr), xps.asarray(bw.voxels), xps.asarray(bw.weights), 4 * 5 * 4)
        assert not isinstance(got.tasks, np.ndarray)
        _plans_equal(ref, got)
        shared += ref.pre is not None
    if sampling == "trilinear":
        assert shared  # the shared-bucket branch was taken and compared


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 60))
def test_plan_of_random_rows_under_array_api_strict(seed, n_rows):
    """Random rows (repeats, zero weights, one-pair rows, wide weights up to 2^40)."""
    xps = pytest.importorskip("array_api_strict")
    rng = np.random.default_rng(seed)
    ip, vox, wt = _csr_with_repeats(rng, n_rows)
    wt = wt * rng.choice(np.array([0, 1, 3, 1000, 2**40], np.uint64), size=wt.size)
    ref = plan_products(ip, vox, wt, 30)
    _plans_equal(ref, plan_products(xps.asarray(ip), xps.asarray(vox), xps.asarray(wt), 30))
