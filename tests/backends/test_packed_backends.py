"""Packed frames (hevr.rendering.packed) on every backend: the kernel backends' frames are the
``cpu`` frames, ciphertext for ciphertext.

For a multi-brick packed store at 256 bits (S = 4) and at 512 bits (S = 10, a partly filled last
pack, up to 7 slot classes): nearest and bilinear (``trilinear``) frames of a view orbiting the
packing axis (one class, no combine) and of general views (several classes, the Horner combine),
streamed and resident (``persist(backend=...)``), rendered with ``backend=KERNELS`` give the
identical ciphertexts, decrypted slot sums and image as ``backend="cpu"`` — the sums the exact
integers of the plan on the plaintext, the image within ``error_bound`` of the float64 slice
reference. The kernels do the work (their operations are spied on; no silent gmpy2 fallback on
``cuda-host``). A verified frame (the store's default): the kernels' tag render and aggregate
(62-bit coefficients) pass the key holder's check, and for one seed their aggregate is cpu's. The
operations a packed frame adds — ``pack`` with up to ~40 classes of up to 38-bit digits,
``segment_products`` over ragged segments — are checked at 2048 bits.

``KERNELS`` is ``cuda-host`` (the CUDA kernels compiled for the host: runs in CI); on a GPU machine
``HEVR_TEST_KERNELS=cuda`` runs the same tests on the device. The ``cuda`` launcher also runs here
over ``_fake_cupy.FakeCupy`` (its small-launch CPU path and its kernel path), and on a real GPU in
the ``gpu``-marked test (skipped without one).
"""

from __future__ import annotations

import os
import secrets
import sys

import dask
import numpy as np
import pytest
from _fake_cupy import FakeCupy
from gmpy2 import mpz

import hevr
from hevr import MissingDependencyError, backends
from hevr.backends import CpuBackend, CudaBackend, get_backend
from hevr.backends.cuda.backend import KernelBackend
from hevr.rendering.packed import PackedImage
from hevr.rendering.packed.verified import aggregate_for

KERNELS = os.environ.get("HEVR_TEST_KERNELS", "cuda-host")  # "cuda" on a GPU machine
CPU = CpuBackend()
SPACING = (1.0, 0.9, 1.2)
ORBIT, GENERAL = (90, 20), [(60, 10), (250, 30)]  # azimuth 90 looks along x: no shift along z, one class
SAMPLINGS = ("nearest", "trilinear")
STORES = {256: ((13, 9, 11), 4), 512: ((23, 9, 10), (4, 4, 5))}  # shape, brick (z rounded up to S)


@pytest.fixture(scope="module")
def stores(tmp_path_factory, keypair256, keypair512):
    """One packed store per key size (encrypted on cpu: the backends are compared on the frames)."""
    out = {}
    for bits, kp in ((256, keypair256), (512, keypair512)):
        shape, brick = STORES[bits]
        vol = np.random.default_rng(bits).integers(0, 256, shape).astype(np.uint8)
        path = tmp_path_factory.mktemp(f"packed-{bits}") / "p.zarr"
        with dask.config.set(scheduler="sync"):
            ev = hevr.encrypt_volume(vol, path, kp[1], brick=brick, spacing=SPACING, layout="packed", progress=False)
        out[bits] = (ev, vol, kp[1])
    return out


@pytest.fixture
def calls(monkeypatch):
    """Counts the kernel backend's operations and its gmpy2 fallbacks (so a test sees who did the work)."""
    seen: dict[str, int] = {}

    def counting(op: str):
        fn = getattr(KernelBackend, op)

        def spy(self, *a, **kw):
            seen[op] = seen.get(op, 0) + 1
            return fn(self, *a, **kw)

        return spy

    for op in ("ray_products", "segment_products", "pack", "concat", "_fallback"):
        monkeypatch.setattr(KernelBackend, op, counting(op))
    return seen


def _camera(ev, view, w=14, h=11):
    return hevr.Camera.orbit(ev, azimuth=view[0], elevation=view[1], width=w, height=h, parallel=True)


def _render(ev, cam, sampling, backend):
    with dask.config.set(scheduler="sync"):
        return hevr.render(ev, cam, sampling=sampling, backend=backend, progress=False, verify=False)


def _same(a: PackedImage, b: PackedImage) -> None:
    assert len(a.ciphertexts) == len(b.ciphertexts) and a.stats["ops"] == b.stats["ops"]
    for x, y in zip(a.ciphertexts, b.ciphertexts):
        np.testing.assert_array_equal(x, y)


def _check_frames(ev, vol, priv, backend: str, views, resident=None) -> list[int]:
    """Every view × sampling on ``backend`` (and on ``resident``, a persisted copy, if given) against
    cpu: identical ciphertexts, sums and image; exact sums; within the bound. Returns the classes seen."""
    seen = []
    for view in views:
        cam = _camera(ev, view)
        for sampling in SAMPLINGS:
            ref = _render(ev, cam, sampling, "cpu")
            sums = ref.decrypt_sums(priv)
            assert (sums == ref.plan.plain_sums(vol.astype(np.int64) - ev.packing.offset)).all()
            arr = ref.decrypt(priv)
            plain = hevr.render_plain(vol, cam, sampling=sampling, spacing=SPACING, slices=True)
            assert (np.abs(arr - plain) <= hevr.error_bound(ev, cam, sampling=sampling)).all() and plain.max() > 10
            for volume in (ev,) if resident is None else (ev, resident, resident):  # resident: twice (converted once)
                img = _render(volume, cam, sampling, backend)
                assert img.stats["backend"] == backend and img.stats["resident"] == (volume is resident)
                _same(ref, img)
                assert np.array_equal(img.decrypt_sums(priv), sums)
                assert np.array_equal(img.decrypt_sums(priv, backend=backend), sums)  # decrypted by the backend too
                assert np.array_equal(img.decrypt(priv), arr)
            seen.append(ref.plan.classes)
    return seen


@pytest.mark.parametrize("bits", [256, 512])
def test_kernel_frames_are_the_cpu_frames(stores, calls, bits):
    """Streamed frames, an orbit (one class) and general views (several): identical to cpu."""
    ev, vol, priv = stores[bits]
    assert len(ev.brick_indices()) >= 9 and ev.packing.slots == {256: 4, 512: 10}[bits]
    classes = _check_frames(ev, vol, priv, KERNELS, [ORBIT, *GENERAL])
    assert classes[:2] == [1, 1] and min(classes[2:]) > 1  # the orbit needs no combine; the others do
    if bits == 512:
        assert max(classes) >= 4  # several classes combined (5–6 with this plan)
    assert calls["ray_products"] >= 6 and calls["segment_products"] >= 1 and calls["pack"] >= 6
    if KERNELS == "cuda-host":  # min_items 0: every operation in the kernels, none on gmpy2
        assert "_fallback" not in calls


def test_resident_kernel_frames_are_the_cpu_frames(stores, calls):
    """persist(backend=KERNELS): the bricks stay in the backend's form (Montgomery after the first
    frame) and a column's bricks are joined with the backend's concat; identical to cpu."""
    ev, vol, priv = stores[512]
    with dask.config.set(scheduler="sync"):
        res = ev.persist(backend=KERNELS)
    assert res.resident.backend == KERNELS
    _check_frames(ev, vol, priv, KERNELS, [ORBIT, GENERAL[0]], resident=res)
    assert calls["concat"] >= 1  # the 512-bit store's columns hold several bricks along x
    brick = next(iter(res.resident.bricks.values())).channel("scalar")
    assert brick.modulus is not None  # converted once, kept in Montgomery form mod n²


@pytest.mark.parametrize("sampling", SAMPLINGS)
def test_verified_kernel_frames(stores, calls, sampling):
    """A verifiable packed store's default (verified) frame on KERNELS: cpu's ciphertexts, and its tag
    render and aggregate, on the kernels with 62-bit coefficients, pass the key holder's check; for one
    seed the kernels' aggregate is cpu's, exactly."""
    ev, vol, priv = stores[512]
    assert ev.meta.tags  # verifiable by default (encrypted with the private key)
    cam = _camera(ev, GENERAL[0])
    with dask.config.set(scheduler="sync"):
        ref = hevr.render(ev, cam, sampling=sampling, backend="cpu", progress=False)
        img = hevr.render(ev, cam, sampling=sampling, backend=KERNELS, progress=False)
    assert img.verified and ref.verified and img.stats["backend"] == KERNELS
    _same(ref, img)
    assert np.array_equal(img.decrypt(priv, require_verified=True), ref.decrypt(priv, require_verified=True))
    seed = secrets.token_bytes(32)
    with dask.config.set(scheduler="sync"):
        a_cpu, ops_cpu = aggregate_for(ev, img.plan, "cpu", None, False, seed)
        a_kern, ops_kern = aggregate_for(ev, img.plan, KERNELS, None, False, seed)
    assert a_cpu == a_kern and ops_cpu == ops_kern and 1 < a_kern < int(ev.public_key.nsquare)
    assert calls["ray_products"] >= 2 and calls["pack"] >= 2


@pytest.mark.parametrize("classes, bits_per_slot", [(41, 24), (40, 32), (27, 38), (2, 22), (1, 24)])
def test_horner_combine_of_many_classes_at_2048_bits(keypair2048, classes, bits_per_slot):
    """The combine of merge_tile: groups of C classes, exponents 1, base 2^K — with the 'one'
    records of the accumulators no pair reached, and a short last group."""
    n = int(keypair2048[0].n)
    n2, W = n * n, (2 * n.bit_length() + 7) // 8
    m = 3 * classes - (classes > 1)
    vals = [mpz(1) if secrets.randbelow(4) == 0 else mpz(secrets.randbelow(n2 - 1) + 1) for _ in range(m)]
    recs = CPU.to_bytes(vals, W)
    be = get_backend(KERNELS)
    want = CPU.to_bytes(CPU.pack(CPU.from_bytes(recs), [1] * m, bits_per_slot, classes, 0, n), W)
    got = be.to_bytes(be.pack(be.from_bytes(recs), [1] * m, bits_per_slot, classes, 0, n), W)
    np.testing.assert_array_equal(want, got)
    assert len(got) == -(-m // classes)


def test_merge_of_ragged_partials_at_2048_bits(keypair2048):
    """segment_products as merge_tile calls it: sorted partials, segments of 1 to 5 rows."""
    n2 = int(keypair2048[0].nsquare)
    W = (n2.bit_length() + 7) // 8
    lens = [1, 3, 1, 5, 2, 1, 4]
    ip = np.r_[0, np.cumsum(lens)].astype(np.int64)
    recs = CPU.to_bytes([mpz(secrets.randbelow(n2 - 1) + 1) for _ in range(int(ip[-1]))], W)
    be = get_backend(KERNELS)
    want = CPU.to_bytes([int(v) % n2 for v in CPU.segment_products(CPU.from_bytes(recs), ip, 1, n2)], W)
    np.testing.assert_array_equal(want, be.to_bytes(be.segment_products(be.from_bytes(recs), ip, 1, n2), W))


@pytest.fixture
def fake_cuda(monkeypatch):
    """The cuda backend on FakeCupy (a fresh instance, registered for the test's renders)."""
    monkeypatch.setitem(sys.modules, "cupy", FakeCupy)
    be = CudaBackend()
    monkeypatch.setitem(backends._INSTANCES, "cuda", be)
    return be


@pytest.mark.parametrize("min_items", [None, 0])
def test_the_cuda_launcher_on_fake_cupy(stores, fake_cuda, calls, monkeypatch, min_items):
    """backend="cuda" over FakeCupy, streamed and resident: its device arrays, its few-items path
    (a tile's combine of a few blocks on gmpy2) and, with ``min_items`` 0, every launch in its kernels."""
    if min_items is not None:
        monkeypatch.setattr(fake_cuda._launch, "min_items", min_items)
    ev, vol, priv = stores[512]
    with dask.config.set(scheduler="sync"):
        res = ev.persist(backend="cuda")
    _check_frames(ev, vol, priv, "cuda", [GENERAL[1]], resident=res)
    if min_items == 0:
        assert "_fallback" not in calls
    else:
        assert calls.get("_fallback", 0) >= 1  # the combine's few long Horner chains: the CPU's work
    limbs, modulus = next(iter(res.resident.bricks.values())).channel("scalar").state
    assert not isinstance(limbs, np.ndarray) and modulus is not None  # a device array, in Montgomery form


@pytest.mark.gpu
def test_packed_frames_on_the_device(stores):
    """On an NVIDIA GPU: streamed and resident packed frames identical to cpu (skipped without one)."""
    be = get_backend("cuda")
    try:
        be.check()
    except MissingDependencyError as exc:
        pytest.skip(f"no CUDA device here: {exc}")
    ev, vol, priv = stores[512]  # S = 10, up to 7 classes; two views, so the device's few seconds suffice
    with dask.config.set(scheduler="sync"):
        res = ev.persist(backend="cuda")
    _check_frames(ev, vol, priv, "cuda", [ORBIT, GENERAL[0]], resident=res)
    cam = _camera(ev, GENERAL[0])
    with dask.config.set(scheduler="sync"):
        img = hevr.render(ev, cam, sampling="trilinear", backend="cuda", progress=False)  # verified (default)
        ref = hevr.render(ev, cam, sampling="trilinear", backend="cpu", progress=False, verify=False)
    _same(ref, img)
    assert img.verified and np.array_equal(img.decrypt(priv, require_verified=True), ref.decrypt(priv))
