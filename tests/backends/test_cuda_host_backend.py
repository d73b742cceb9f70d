"""The ``cuda-host`` backend (the CUDA kernels of hevr/backends/cuda/render.cuh compiled for the host)
against the ``cpu`` reference, operation by operation: bit-identical results and identical
operation counts, on random operands and the edge cases (1, n²−1, values whose top limbs are zero,
weights up to 2^64 − 1, exponents wider than 64 bits), for keys of 64 to 2048 bits. Whole renders
are in test_cuda_host_renders.py.

On a GPU machine ``HEVR_TEST_KERNELS=cuda`` runs every test here against the ``cuda`` backend (the
same kernels on the device through CuPy) instead: ``hevr bench --gpu`` and
tests/backends/test_cuda_device.py say how."""

from __future__ import annotations

import os
import pickle
import secrets
import shutil
import subprocess

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hevr import MissingDependencyError, ParameterError
from hevr.backends import (
    CpuBackend,
    CudaHostBackend,
    OpCounter,
    ProductPlan,
    get_backend,
)
from hevr.backends.base import HORNER, ONES, SHARED, SINGLE
from hevr.backends.cuda import build_host, kernel_cache
from hevr.backends.cuda import host as host_module
from hevr.backends.cuda import launch as launch_module
from hevr.backends.cuda import residues as residues_module
from hevr.backends.cuda.launch import HostLauncher
from hevr.backends.cuda.residues import LimbBatch, exponent_words
from hevr.crypto.records import record_width
from hevr.rendering.pipeline.kernel import plan_products

KERNELS = os.environ.get("HEVR_TEST_KERNELS", "cuda-host")  # "cuda" on a GPU machine
CPU, GPU = CpuBackend(), get_backend(KERNELS)
BITS = [64, 96, 128, 256, 512, 1024]  # n; n² has twice as many bits (96: a short top limb)


@pytest.fixture(autouse=True)
def _every_operation_in_the_kernels(monkeypatch):
    """This suite checks the kernels op by op, however small the batch: on a device, batches of fewer
    than ``min_items`` items would go to gmpy2 (test_cuda_device.py checks that rule)."""
    monkeypatch.setattr(type(GPU._launch), "min_items", 0)


def _modulus(bits: int) -> int:
    """An odd n of exactly ``bits`` bits (primality does not matter to the arithmetic)."""
    return secrets.randbits(bits) | 1 | (3 << (bits - 2))


def _residues(n2: int, m: int) -> list[int]:
    """Edge cases first, then random residues in (0, n²)."""
    nl = -(-n2.bit_length() // 32)
    edges = [1, 2, n2 - 1, n2 - 2, n2 // 2, (1 << 32) - 1, 1 << 32, (1 << (32 * (nl - 1))) - 1, 3]
    return (edges + [secrets.randbelow(n2 - 1) + 1 for _ in range(max(0, m - len(edges)))])[:m]


def _records(values: list[int], width: int) -> np.ndarray:
    return CPU.to_bytes(values, width)


def _same(a, b, width: int) -> None:
    np.testing.assert_array_equal(CPU.to_bytes(a, width), GPU.to_bytes(b, width))


def _both(values: list[int], width: int):
    rec = _records(values, width)
    return CPU.from_bytes(rec), GPU.from_bytes(rec)


# -- conversion and the range check -------------------------------------------------------------
@pytest.mark.parametrize("bits", BITS + [2048])
def test_records_round_trip_and_montgomery_form(bits):
    n = _modulus(bits)
    n2, W = n * n, record_width(n)
    vals = _residues(n2, 40)
    rec = _records(vals, W)
    b = GPU.from_bytes(rec)
    assert len(b) == 40 and b.modulus is None
    np.testing.assert_array_equal(GPU.to_bytes(b, W), rec)
    one_rows = GPU.segment_products(b, np.arange(41), 1, n2)  # one-row segments: Montgomery form and back
    assert b.modulus == n2 and one_rows.modulus == n2  # converted in place, once
    np.testing.assert_array_equal(GPU.to_bytes(one_rows, W), rec)
    np.testing.assert_array_equal(GPU.to_bytes(b, W), rec)
    np.testing.assert_array_equal(GPU.to_bytes(b, W + 3), CPU.to_bytes(CPU.from_bytes(rec), W + 3))
    assert GPU.residue_bytes(W) == 4 * -(-W // 4)


def test_conversion_errors_match_the_cpu_backend():
    for bad in ([[1, 2]], np.zeros((2, 3), np.int16), np.zeros((2, 0), np.uint8)):
        with pytest.raises(ParameterError, match="arr: expected"):
            GPU.from_bytes(bad)
    b = GPU.from_bytes(np.array([[1, 0, 0], [0, 0, 7]], np.uint8))
    with pytest.raises(ParameterError, match=r"values\[0\]: value of 17 bits does not fit in 2 bytes"):
        GPU.to_bytes(b, 2)
    with pytest.raises(ParameterError, match="width: expected an integer >= 1"):
        GPU.to_bytes(b, 0)
    assert GPU.to_bytes(b, 5).tolist() == [[0, 0, 1, 0, 0], [0, 0, 0, 0, 7]]
    assert GPU.from_bytes(np.zeros((2, 3, 5), np.uint8)).limbs.shape == (6, 2)  # leading axes flattened
    with pytest.raises(ParameterError, match=r"at most 512 bytes .*keys of up to 2048 bits\), got 768-byte"):
        GPU.from_bytes(np.zeros((1, 768), np.uint8))  # a 3072-bit key


@pytest.mark.parametrize("bits", [64, 96, 512, 2048])
def test_first_out_of_range(bits):
    n = _modulus(bits)
    n2, W = n * n, record_width(n)
    good = _residues(n2, 12)
    for bad_value in (0, n2, n2 + 1, (1 << (8 * W)) - 1):
        for pos in (0, 5, 11):
            vals = list(good)
            vals[pos] = bad_value
            c, g = _both(vals, W)
            assert GPU.first_out_of_range(g, n2) == CPU.first_out_of_range(c, n2) == pos
    c, g = _both(good, W)
    assert GPU.first_out_of_range(g, n2) is CPU.first_out_of_range(c, n2) is None
    GPU.segment_products(g, np.arange(13), 1, n2)  # now in Montgomery form mod n²
    assert GPU.first_out_of_range(g, n2) is None
    assert GPU.first_out_of_range(g, n2 - 1) == CPU.first_out_of_range(c, n2 - 1) == 2  # n² − 1 itself
    assert GPU.first_out_of_range(g, 1 << (8 * W + 40)) is None and GPU.first_out_of_range(g, 1) == 0
    assert GPU.first_out_of_range(GPU.from_bytes(np.zeros((0, W), np.uint8)), n2) is None


# -- the per-brick products ---------------------------------------------------------------------
def _u64(count: int) -> np.ndarray:
    return np.frombuffer(secrets.token_bytes(8 * count), np.uint64).copy()


def _csr(rows: int, n_vox: int, max_len: int, weights: str):
    lens = _u64(rows) % np.uint64(max_len + 1)
    ip = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
    P = int(ip[-1])
    vox = (_u64(P) % np.uint64(n_vox)).astype(np.int64)
    w = _u64(P)
    w = {
        "nearest": w % np.uint64(2) + np.uint64(1),
        "trilinear": w % np.uint64(1024),
        "wide": w % np.uint64(70000) + np.uint64(1),
        "u64": w | np.uint64(1 << 63),
        "mixed": w >> (w % np.uint64(64)),
        "shared": (w % np.uint64(4096)) | np.uint64(1),
    }[weights]
    if weights == "shared":
        vox %= 6  # few voxels under many rays: the planner picks shared buckets
    if rows > 3:  # row 3 repeats row 1 (a duplicate row), row 2 is empty
        parts = [(vox[ip[r] : ip[r + 1]], w[ip[r] : ip[r + 1]]) for r in range(rows)]
        parts[3], parts[2] = parts[1], (vox[:0], w[:0])
        ip = np.concatenate([[0], np.cumsum([len(p[0]) for p in parts])]).astype(np.int64)
        vox, w = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    return ip, vox, w


def _check_rays(plan: ProductPlan, n2: int, W: int, n_vox: int, k: int = 2) -> None:
    comps = [_residues(n2, n_vox) for _ in range(k)]
    comps[-1] = comps[-1][::-1]
    a_cnt, b_cnt = OpCounter(), OpCounter()
    a = CPU.ray_products(plan, [CPU.from_bytes(_records(c, W)) for c in comps], n2, a_cnt)
    b = GPU.ray_products(plan, [GPU.from_bytes(_records(c, W)) for c in comps], n2, b_cnt)
    assert len(a) == len(b) == k
    for x, y in zip(a, b):
        _same(x, y, W)
    assert a_cnt == b_cnt


@pytest.mark.parametrize("weights", ["nearest", "trilinear", "wide", "u64", "mixed", "shared"])
@pytest.mark.parametrize("bits", BITS)
def test_ray_products_identical_with_identical_counts(bits, weights):
    n = _modulus(bits)
    n_vox = 40
    ip, vox, w = _csr(30, n_vox, 24, weights)
    plan = plan_products(ip, vox, w, n_vox)
    if weights == "shared":
        assert plan.pre is not None and len(plan.pre) and any(t[0] == SHARED for t in plan.tasks)
    _check_rays(plan, n * n, record_width(n), n_vox)


@pytest.mark.parametrize("weights", ["trilinear", "shared", "u64"])
def test_ray_products_at_2048_bits(weights):
    n = _modulus(2048)
    ip, vox, w = _csr(8, 12, 10, weights)
    _check_rays(plan_products(ip, vox, w, 12), n * n, record_width(n), 12, k=1)


def test_every_task_kind_and_the_fold():
    """Hand-made plans: each kind alone, a HORNER fold (top digit near 2^w), J > 2 windows, empty rows."""
    n = _modulus(128)
    n2, W = n * n, record_width(n)
    vl, wl = [0, 1, 2, 3, 0, 1, 2, 3, 0], [1, 1, 1, 1, 31, 30, 2**40 + 5, 1, 2**64 - 1]
    tasks = [
        (ONES, 0, 4, 0, 0),
        (HORNER, 4, 8, 5, 9),
        (HORNER, 4, 6, 1, 5),
        (SINGLE, 8, 9, 0, 0),
        (HORNER, 6, 7, 3, 14),
        (HORNER, 8, 9, 16, 4),
    ]
    plan = ProductPlan(8, 9, [0, 1, -1, 2, 3, 4, 5, 1], vl, wl, tasks)
    _check_rays(plan, n2, W, 4)
    shared = ProductPlan(
        2,
        3,
        [0, 1],
        [0, 1, 2],
        [5, 2**20 + 7, 63],
        [(SHARED, 0, 2, 0, 0), (SHARED, 2, 3, 0, 0)],
        shared_w=3,
        pre=[(0, 1), (1, 7), (2, 2)],
    )
    _check_rays(shared, n2, W, 3)
    _check_rays(ProductPlan(3, 0, [-1, -1, -1], [], [], []), n2, W, 4)  # no pairs: every row is 1
    assert GPU.ray_products(plan, [], n2) == []


def test_malformed_plans_are_refused_not_run():
    n2 = _modulus(64) ** 2
    cts = GPU.from_bytes(_records([5, 7], 16))
    too_wide = ProductPlan(1, 1, [0], [0], [2**20], [(HORNER, 0, 1, 4, 2)])  # 21 bits in 2 windows of 4
    with pytest.raises(ParameterError, match="task 0 has a weight with more digits"):
        GPU.ray_products(too_wide, [cts], n2)
    no_powers = ProductPlan(1, 1, [0], [1], [9], [(SHARED, 0, 1, 0, 0)], shared_w=2, pre=[(0, 2)])
    with pytest.raises(ParameterError, match="task 0 has a weight with more digits"):
        GPU.ray_products(no_powers, [cts], n2)
    for bad, match in [
        (ProductPlan(1, 1, [0], [5], [1], [(ONES, 0, 1, 0, 0)]), "voxels in"),
        (ProductPlan(1, 1, [1], [0], [1], [(ONES, 0, 1, 0, 0)]), "row tasks"),
        (ProductPlan(1, 1, [0], [0], [1], [(ONES, 0, 2, 0, 0)]), "start < stop <= pairs"),
        (ProductPlan(1, 1, [0], [0], [1], [(HORNER, 0, 1, 0, 1)]), "w >= 1"),
        (ProductPlan(1, 1, [0], [0], [1], [(HORNER, 0, 1, 20, 2**40)]), "J <= 64"),
        (ProductPlan(1, 1, [0], [0], [1], [(SHARED, 0, 1, 0, 0)], 2, [(0, 65)]), "J <= 64"),
    ]:
        with pytest.raises(ParameterError, match=match):
            GPU.ray_products(bad, [cts], n2)


def test_plans_beyond_the_kernels_and_even_moduli_run_on_gmpy2(monkeypatch):
    n = _modulus(64)
    monkeypatch.setattr(residues_module, "MAX_BUCKETS", 16)
    big = ProductPlan(1, 2, [0], [0, 1], [3, 2**9 + 1], [(HORNER, 0, 2, 5, 2)])  # 66 buckets
    _check_rays(big, n * n, record_width(n), 2)
    x = GPU.from_bytes(np.array([[0, 2], [0, 3]], np.uint8))
    assert GPU.to_bytes(GPU.segment_products(x, np.array([0, 2]), 1, 1000), 2).tolist() == [[0, 6]]
    assert GPU.to_bytes(GPU.combine(x, [[3], [1]], 1000), 2).tolist() == [[0, 24]]
    assert (
        GPU.to_bytes(GPU.pack(x, [1, 2], 4, 2, 1, 10), 2).tolist()
        == CPU.to_bytes(CPU.pack(CPU.from_bytes(np.array([[0, 2], [0, 3]], np.uint8)), [1, 2], 4, 2, 1, 10), 2).tolist()
    )


def test_stage_times_refuses_what_the_kernels_cannot_take(monkeypatch):
    """stage_times times the kernels only: an even modulus, or a plan beyond the kernels' buckets,
    is a ParameterError naming it (it was an AttributeError on None)."""
    n = _modulus(64)
    x = GPU.from_bytes(np.array([[0, 2], [0, 3]], np.uint8))
    plan = ProductPlan(1, 2, [0], [0, 1], [1, 1], [(ONES, 0, 2, 0, 0)])
    with pytest.raises(ParameterError, match="nsquare"):
        GPU.stage_times(plan, x, 1000)
    monkeypatch.setattr(residues_module, "MAX_BUCKETS", 16)
    big = ProductPlan(1, 2, [0], [0, 1], [3, 2**9 + 1], [(HORNER, 0, 2, 5, 2)])  # 66 buckets
    with pytest.raises(ParameterError, match="buckets"):
        GPU.stage_times(big, x, n * n)


@settings(max_examples=30, deadline=None)
@given(
    data=st.data(),
    bits=st.sampled_from([64, 128, 256]),
    n_vox=st.integers(1, 8),
    rows=st.integers(1, 6),
    wmax=st.sampled_from([1, 2, 5, 1023, 70000, 2**64 - 1]),
)
def test_ray_products_property(data, bits, n_vox, rows, wmax):
    n = _modulus(bits)
    lens = data.draw(st.lists(st.integers(0, 10), min_size=rows, max_size=rows))
    ip = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
    P = int(ip[-1])
    vox = np.array(data.draw(st.lists(st.integers(0, n_vox - 1), min_size=P, max_size=P)), np.int64)
    w = np.array(data.draw(st.lists(st.integers(0, wmax), min_size=P, max_size=P)), np.uint64)
    _check_rays(plan_products(ip, vox, w, n_vox), n * n, record_width(n), n_vox)


# -- merging, combining, packing ------------------------------------------------------------------
@pytest.mark.parametrize("bits", BITS + [2048])
@pytest.mark.parametrize("k", [1, 3])
def test_segment_products(bits, k):
    n = _modulus(bits)
    n2, W = n * n, record_width(n)
    rows = 9
    c, g = _both(_residues(n2, rows * k), W)
    indptr = np.array([0, 1, 4, 5, 9])
    _same(CPU.segment_products(c, indptr, k, n2), GPU.segment_products(g, indptr, k, n2), W)
    with pytest.raises(ParameterError, match="indptr"):
        GPU.segment_products(g, np.array([0, 3, 3, 9]), k, n2)


@pytest.mark.parametrize("bits", BITS + [2048])
def test_combine(bits):
    n = _modulus(bits)
    n2, W = n * n, record_width(n)
    for k, C, top in [(1, 1, 125), (3, 3, 10**4), (4, 2, 2**70 + 3), (9, 2, 300)]:
        pixels = 3
        c, g = _both(_residues(n2, k * pixels), W)
        comb = [[secrets.randbelow(top) if (i + ch) % 3 else 0 for ch in range(C)] for i in range(k)]
        comb[0][C - 1] = top
        if C > 1:
            for row in comb:
                row[0] = 0  # an all-zero channel gives 1
        _same(CPU.combine(c, comb, n2), GPU.combine(g, comb, n2), W)
    with pytest.raises(ParameterError, match="rows of 2 values"):
        GPU.combine(GPU.from_bytes(_records([1, 2, 3], W)), [[1], [1]], n2)


@pytest.mark.parametrize("bits", BITS + [2048])
def test_pack(bits):
    n = _modulus(bits)
    n2, W = n * n, record_width(n)
    m = 11
    for b, J, offset, exps in [
        (12, 3, 0, [secrets.randbelow(1 << 12) for _ in range(m)]),
        (9, 4, 7, [0, 1, 511, 3, 2**9 + 5, 0, 7, 100, 2**70 + 1, 8, 1]),  # R wider than b; wider than 64 bits
        (20, 1, 12345, [secrets.randbelow(1 << 20) for _ in range(m)]),
        (6, 11, 2**40, [63] * m),
        (5, 2, 1, [31] * (m - 1) + [0]),
    ]:
        c, g = _both(_residues(n2, m), W)
        got = GPU.pack(g, exps, b, J, offset, n)
        assert len(got) == -(-m // J)
        _same(CPU.pack(c, exps, b, J, offset, n), got, W)
    with pytest.raises(ParameterError, match="exps: expected non-negative"):
        GPU.pack(g, [-1] * m, 5, 2, 0, n)
    with pytest.raises(ParameterError, match="exps: expected 11 exponents"):
        GPU.pack(g, [1] * 3, 5, 2, 0, n)


@settings(max_examples=25, deadline=None)
@given(
    data=st.data(),
    per_pack=st.integers(1, 5),
    b=st.integers(1, 24),
    offset=st.integers(0, 99),
    bits=st.sampled_from([64, 160, 256]),
)
def test_pack_and_combine_property(data, per_pack, b, offset, bits):
    n = data.draw(st.integers(1 << (bits - 1), (1 << bits) - 1)) | 1
    n2, W = n * n, record_width(n)
    m = data.draw(st.integers(1, 9))
    terms = data.draw(st.lists(st.integers(1, n2 - 1), min_size=m, max_size=m))
    exps = data.draw(st.lists(st.integers(0, (1 << b) - 1), min_size=m, max_size=m))
    c, g = _both(terms, W)
    _same(CPU.pack(c, exps, b, per_pack, offset, n), GPU.pack(g, exps, b, per_pack, offset, n), W)
    k = data.draw(st.integers(1, 3))
    comb = data.draw(st.lists(st.lists(st.integers(0, 5000), min_size=2, max_size=2), min_size=k, max_size=k))
    c, g = _both(terms[: m - m % k] or terms[:1] * k, W)
    _same(CPU.combine(c, comb, n2), GPU.combine(g, comb, n2), W)


# -- encryption, decryption, the backend's life cycle -----------------------------------------------
def test_encrypt_and_decrypt_through_the_cpu_backend(keypair256):
    pub, priv = keypair256
    m = np.array([0, 1, -1, 12345, -(2**40)], np.int64)
    W = record_width(pub.n)
    for key in (pub, priv):
        cts = GPU.encrypt(key, m)
        assert isinstance(cts, LimbBatch) and len(cts) == 5
        assert GPU.first_out_of_range(cts, pub.nsquare) is None
        want = [int(v) % pub.n for v in m.tolist()]
        assert GPU.decrypt(priv, cts) == CPU.decrypt(priv, CPU.from_bytes(GPU.to_bytes(cts, W))) == want
    mont = GPU.segment_products(GPU.from_bytes(GPU.to_bytes(cts, W)), np.arange(6), 1, pub.nsquare)
    assert mont.modulus == pub.nsquare and GPU.decrypt(priv, mont) == want  # from Montgomery form


def test_registration_pickling_and_lazy_build(monkeypatch, tmp_path):
    be = get_backend("cuda-host")
    assert isinstance(be, CudaHostBackend) and be.name == "cuda-host"
    assert pickle.loads(pickle.dumps(be)).name == "cuda-host"
    b = GPU.from_bytes(np.array([[0, 9], [1, 0]], np.uint8))
    again = pickle.loads(pickle.dumps(b))
    assert again.limbs.tolist() == [[9], [256]] and again.modulus is None and "2 values" in repr(again)
    assert HostLauncher()._dll is None  # nothing compiled until a kernel runs
    monkeypatch.setattr(launch_module, "RENDER_SOURCE", tmp_path / "render.cuh")
    (tmp_path / "render.cuh").write_text("int hevr_nothing(void) { return 0; }\n")
    fresh = HostLauncher(compiler=str(tmp_path / "no-such-cc"))
    with pytest.raises(MissingDependencyError, match="compiler"):
        fresh.records_to_limbs(np.zeros((1, 4), np.uint8), 1)
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(host_module.shutil, "which", lambda name: None)
    with pytest.raises(MissingDependencyError, match="expected a C compiler"):
        HostLauncher().lib  # noqa: B018


def test_exponent_words():
    assert exponent_words([0, 2**64 - 1]).tolist() == [[0, 0], [2**32 - 1, 2**32 - 1]]
    assert exponent_words(np.array([7], np.uint8)).tolist() == [[7, 0]]
    assert exponent_words([2**95]).tolist() == [[0, 0, 2**31]]
    with pytest.raises(ParameterError, match="expected non-negative"):
        exponent_words(np.array([-1]))


@pytest.mark.skipif(shutil.which("nvcc") is None, reason="nvcc (CUDA toolkit) is not installed: device compile check")
def test_render_kernels_compile_for_the_device(tmp_path):
    """render.cuh (with mont.cuh) builds as CUDA device code, PTX for sm_90 (Hopper): no GPU needed."""
    out = tmp_path / "render.ptx"
    run = subprocess.run(
        ["nvcc", "-ptx", "-arch=sm_90", "-x", "cu", str(launch_module.RENDER_SOURCE), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    ptx = out.read_text()
    for kernel in (
        "k_records_to_limbs",
        "k_limbs_to_records",
        "k_out_of_range",
        "k_mont_convert",
        "k_ray_powers",
        "k_ray_tasks",
        "k_segments",
        "k_combine",
        "k_pack",
        "k_mont_mul",
    ):
        assert f".entry {kernel}(" in ptx, kernel
    run = subprocess.run(
        ["nvcc", "-ptx", "-arch=sm_90", "-x", "cu", str(launch_module.OWNER_SOURCE), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert all(f".entry {k}(" in out.read_text() for k in ("k_owner_encrypt", "k_public_encrypt", "k_decrypt"))


def test_concat_keeps_one_form():
    """Batches of several bricks are concatenated (a map task over a worker's bricks): any mix of
    forms gives the values in order, in Montgomery form where one part is."""
    n = _modulus(96)
    n2, W = n * n, record_width(n)
    a, b, c = _residues(n2, 4), _residues(n2, 3)[::-1], [7]
    parts = [GPU.from_bytes(_records(v, W)) for v in (a, b, c)]
    plain = GPU.concat(parts)
    assert plain.modulus is None and len(plain) == 8 and plain.parts is not None and "3 parts" in repr(plain)
    np.testing.assert_array_equal(GPU.to_bytes(plain, W), _records(a + b + c, W))
    assert pickle.loads(pickle.dumps(plain)).limbs.tolist() == plain.limbs.tolist()
    rows = GPU.segment_products(plain, np.arange(9), 1, n2)  # joined now: the parts converted in place
    assert plain.parts is None and all(p.modulus == n2 for p in parts)
    np.testing.assert_array_equal(GPU.to_bytes(rows, W), _records(a + b + c, W))
    parts = [GPU.from_bytes(_records(v, W)) for v in (a, b, c)]
    GPU.segment_products(parts[1], np.arange(4), 1, n2)  # one part in Montgomery form
    mixed = GPU.concat(parts)
    assert mixed.modulus == n2 == parts[0].modulus
    np.testing.assert_array_equal(GPU.to_bytes(mixed, W), _records(a + b + c, W))
    narrow = GPU.concat([GPU.from_bytes(np.array([[0, 5]], np.uint8)), GPU.from_bytes(_records(a, W))])
    np.testing.assert_array_equal(GPU.to_bytes(narrow, W), _records([5] + a, W))
    assert len(GPU.concat([])) == 0


@pytest.mark.skipif(not hasattr(os, "getuid"), reason="POSIX owners and modes")
def test_a_kernel_folder_others_can_write_is_not_used(monkeypatch, tmp_path):
    """The compiled library is loaded only from a folder this user alone can write."""
    monkeypatch.setattr(host_module, "_LIB", {})
    monkeypatch.setattr(kernel_cache.tempfile, "gettempdir", lambda: str(tmp_path))
    open_folder = tmp_path / f"hevr-kernels-{os.getuid()}"
    open_folder.mkdir()
    open_folder.chmod(0o777)
    build_host()
    assert not any(open_folder.iterdir())
