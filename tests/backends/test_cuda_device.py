"""The ``cuda`` backend (hevr.backends.cuda.device: the kernels on a GPU through CuPy).

Without a GPU, the launcher itself still runs end to end against ``_fake_cupy.FakeCupy``: CuPy's
arrays and launches played by the host build of the same kernels, every argument's C type and
the grid checked at each launch — operations, owner encryption, a render and ``hevr bench --gpu``.

Everywhere: the device source compiles with NVRTC for Hopper (compute_90) without a GPU — the
NVRTC wheel is in the test extra, so under CI a missing library fails rather than skips — and
without CuPy or a device the backend says what is missing. On a GPU machine (marked ``gpu``,
skipped without one): every operation and a whole render bit-identical to ``cpu``. The full
operation-by-operation suite runs there with ``HEVR_TEST_KERNELS=cuda python -m pytest
tests/backends/test_cuda_host_backend.py tests/backends/test_cuda_host_renders.py``.
"""

from __future__ import annotations

import json
import os
import pickle
import secrets
import subprocess
import sys

import dask
import numpy as np
import pytest
from _fake_cupy import FakeArray, FakeCupy
from dask.sizeof import sizeof

import hevr
from hevr import MissingDependencyError, backends
from hevr.backends import (
    CpuBackend,
    CudaBackend,
    CudaHostBackend,
    ProductPlan,
    get_backend,
)
from hevr.backends.cuda import device as device_module
from hevr.backends.cuda.device import KERNELS, CupyLauncher, device_source, owner_source
from hevr.backends.cuda.nvrtc import find_nvrtc, ptx
from hevr.bench.gpu_operations import EXPERIMENTS
from hevr.cli.main import main
from hevr.rendering.pipeline.kernel import plan_products
from hevr.store import resident as resident_module

CPU = CpuBackend()


def _cuda_or_skip() -> CudaBackend:
    be = get_backend("cuda")
    try:
        be.check()
    except MissingDependencyError as exc:
        pytest.skip(f"no CUDA device here: {exc}")
    return be


def test_device_source_compiles_with_nvrtc_for_hopper():
    try:
        find_nvrtc()
    except MissingDependencyError as exc:
        if os.environ.get("CI"):
            pytest.fail(f"{exc} (the test extra installs nvidia-cuda-nvrtc-cu12)")
        pytest.skip(str(exc))
    code = ptx(device_source(), "compute_90")
    for kernel in KERNELS:
        assert f".entry {kernel}(" in code, kernel
    with pytest.raises(RuntimeError, match="NVRTC could not compile"):
        ptx(device_source() + "\nint broken(\n", "compute_90")
    owner_ptx = ptx(owner_source(), "compute_90")
    assert all(f".entry {k}(" in owner_ptx for k in ("k_owner_encrypt", "k_public_encrypt", "k_decrypt"))
    # the kernel source's experiments (hevr bench --gpu times them on a device) compile too
    for name in EXPERIMENTS:
        code = ptx(device_source(), "compute_90", ("--std=c++11", f"-D{name}"))
        assert all(f".entry {kernel}(" in code for kernel in KERNELS), name


def test_without_cupy_or_device_the_first_operation_says_what_is_missing(monkeypatch):
    be = CudaBackend()  # creating it touches nothing
    assert be.name == "cuda" and pickle.loads(pickle.dumps(be)).name == "cuda"
    assert "cuda" in hevr.backends.available_backends()

    class NoDevice:
        class cuda:
            class runtime:
                @staticmethod
                def getDeviceCount():
                    raise RuntimeError("cudaErrorNoDevice: no CUDA-capable device is detected")

    for fake, match in (
        (None, "CuPy is not installed: pip install 'hevr\\[gpu\\]'"),
        (NoDevice, "needs an NVIDIA GPU; CuPy sees none"),
    ):
        launcher = CupyLauncher()
        if fake is None:
            monkeypatch.setitem(sys.modules, "cupy", None)  # import cupy -> ImportError
        else:
            monkeypatch.setitem(sys.modules, "cupy", fake)
        with pytest.raises(MissingDependencyError, match=match):
            launcher.records_to_limbs(np.zeros((1, 4), np.uint8), 1)
        with pytest.raises(MissingDependencyError, match=match):
            CudaBackend().check()


def test_null_pointers_are_passed_as_zero_not_none():
    """CuPy turns None into 0xffffffff (cupy#9046): optional pointers go as a zero uint64."""
    launcher = CupyLauncher()
    null = launcher._dev(None, np.uint32)
    assert isinstance(null, np.uint64) and int(null) == 0
    assert device_module.BLOCK % 32 == 0


@pytest.fixture
def fake_cuda(monkeypatch):
    """The cuda backend on FakeCupy (a fresh instance, registered for the test's renders)."""
    monkeypatch.setitem(sys.modules, "cupy", FakeCupy)
    monkeypatch.setattr(FakeCupy, "stack", 1024)  # the driver's default per-thread stack, not yet raised
    monkeypatch.setattr(FakeCupy, "synchronized", False)
    be = CudaBackend()
    monkeypatch.setitem(backends._INSTANCES, "cuda", be)
    return be


def test_the_stack_is_raised_for_the_deepest_kernel_before_any_launch(fake_cuda, keypair512):
    """owner.cuh's kernels take 2,576 bytes of stack frame (over the default 1,024): the launcher raises
    the device's limit when the module loads, with the device idle, not at a launch (device.py's
    reserve_stack: on an H200, exact with the limit raised first, wrong or faulting in some runs
    without). The fake refuses a launch whose frame is over the limit."""
    pub, priv = keypair512
    launched = fake_cuda._launch
    launched.keyholder = True
    x = np.array([0, 1, -1, 12345], np.int64)
    assert fake_cuda.decrypt(priv, fake_cuda.encrypt(priv, x)) == [int(v) % int(pub.n) for v in x.tolist()]
    assert FakeCupy.synchronized and FakeCupy.stack == 3072  # 2,576 rounded up to whole KiB
    # a limit already high enough is left as it is
    assert device_module.reserve_stack(FakeCupy, [launched._decrypt_fn]) == 3072


def test_a_kernel_over_the_stack_limit_is_refused_by_the_fake(fake_cuda, keypair512, monkeypatch):
    """The fake's check is real: without reserve_stack, the first owner launch trips it."""
    monkeypatch.setattr(device_module, "reserve_stack", lambda cp, fns: 1024)
    fake_cuda._launch.keyholder = True
    with pytest.raises(AssertionError, match="stack limit under its frame"):
        fake_cuda.encrypt(keypair512[1], np.array([1, 2], np.int64))


@pytest.mark.parametrize("bits", [64, 512, 2048])
def test_the_launcher_on_fake_cupy_matches_cpu(fake_cuda, bits):
    _check_operations(fake_cuda, bits)
    fns = fake_cuda._launch._fns
    assert fns and all(f.calls > 0 for name, f in fns.items() if name not in ("k_combine", "k_pack"))


def test_an_experiment_compiles_in_through_the_launchers_options(fake_cuda):
    """``CudaBackend(defines=...)`` / ``with_defines``: NVRTC gets ``-D``; the experiment's module
    (here the host build FakeCupy makes with the same -D) is bit-identical to cpu at 2048 bits."""
    fake_cuda.check()  # the default module, for comparison
    var = fake_cuda.with_defines(("HEVR_CIOS_REG",))
    _check_operations(var, 2048)
    module = next(iter(var._launch._fns.values())).module
    default = next(iter(fake_cuda._launch._fns.values())).module
    assert "-DHEVR_CIOS_REG" in module.options and "-DHEVR_CIOS_REG" not in default.options
    assert hasattr(module.lib, "hevr_experiment_cios_reg") and not hasattr(default.lib, "hevr_experiment_cios_reg")
    assert pickle.loads(pickle.dumps(CudaBackend(defines=("HEVR_CIOS_REG",))))._launch._options[-1] == "-DHEVR_CIOS_REG"
    with pytest.raises(hevr.ParameterError, match="defines: expected preprocessor names"):
        CudaBackend(defines=("A B",))
    with pytest.raises(hevr.ParameterError, match="defines: expected a sequence of preprocessor names, got the string"):
        CudaBackend(defines="HEVR_CIOS_REG")  # not one define per letter


def test_a_render_and_owner_encryption_on_fake_cupy(fake_cuda, tmp_path, keypair512):
    _check_render(tmp_path, keypair512)
    pub, priv = keypair512
    x = np.array([0, 1, -1, 2**62, -(2**63), 2**63 - 1, 12345, -999], np.int64)
    launched = fake_cuda._launch
    # on a device the key holder's work goes the CPU way (owner.cuh unproven there: device.py's docstring)
    assert launched.keyholder is False
    assert fake_cuda.decrypt(priv, fake_cuda.encrypt(priv, x)) == [int(v) % int(pub.n) for v in x.tolist()]
    assert launched._owner_fn is None and launched._decrypt_fn is None
    launched.keyholder = True  # what the device proof sets: the kernels (this test's fresh backend only)
    assert fake_cuda.decrypt(priv, fake_cuda.encrypt(priv, x)) == [int(v) % int(pub.n) for v in x.tolist()]
    assert fake_cuda.decrypt(priv, fake_cuda.encrypt(pub, x)) == [int(v) % int(pub.n) for v in x.tolist()]
    assert launched._owner_fn.calls == launched._public_fn.calls == 1 and launched._decrypt_fn.calls == 2
    launched = {n for n, f in fake_cuda._launch._fns.items() if f.calls}
    # a frame's few packed ciphertexts (2 per tile here) are the CPU's work: fewer than MIN_ITEMS
    assert launched >= {"k_combine", "k_ray_tasks"} and "k_pack" not in launched


def test_few_long_chains_go_to_the_cpu(fake_cuda):
    """pack / combine / segment_products of fewer than ``min_items`` independent items run on gmpy2
    (same bytes); from ``min_items`` on, the kernels."""
    n = secrets.randbits(512) | 1 | (3 << 510)
    n2, W = n * n, (n * n).bit_length() // 8 + 1
    vals = [secrets.randbelow(n2 - 1) + 1 for _ in range(3 * device_module.MIN_ITEMS)]
    rows = CPU.from_bytes(CPU.to_bytes(vals, W))
    fake_cuda.check()  # the module, so that its kernels' launch counts exist
    fns = fake_cuda._launch._fns
    for m in (3 * (device_module.MIN_ITEMS - 1), 3 * device_module.MIN_ITEMS):  # groups of 3: 127, then 128
        exps = [secrets.randbelow(1 << 40) + 1 for _ in range(m)]
        before = fns["k_pack"].calls
        got = fake_cuda.pack(fake_cuda.from_bytes(CPU.to_bytes(rows[:m], W)), exps, 20, 3, 7, n)
        np.testing.assert_array_equal(
            fake_cuda.to_bytes(got, W), CPU.to_bytes(CPU.pack(rows[:m], exps, 20, 3, 7, n), W)
        )
        assert fns["k_pack"].calls - before == (m // 3 >= device_module.MIN_ITEMS)
    comb = [[3, 0], [17, 2], [0, 1000]]  # rows of 3 values into 2 channels
    for items in (device_module.MIN_ITEMS - 1, device_module.MIN_ITEMS):
        seg = np.arange(items + 1)  # one-row segments
        before = fns["k_segments"].calls, fns["k_combine"].calls
        g = fake_cuda.from_bytes(CPU.to_bytes(rows[: 3 * items], W))
        np.testing.assert_array_equal(
            fake_cuda.to_bytes(fake_cuda.segment_products(g, seg, 1, n2), W),
            CPU.to_bytes(CPU.segment_products(rows[:items], seg, 1, n2), W),
        )
        np.testing.assert_array_equal(
            fake_cuda.to_bytes(fake_cuda.combine(g, comb, n2), W),
            CPU.to_bytes(CPU.combine(rows[: 3 * items], comb, n2), W),
        )
        kernels = items >= device_module.MIN_ITEMS
        assert (fns["k_segments"].calls - before[0], fns["k_combine"].calls - before[1]) == (kernels, kernels)
        # a value >= n² (never from a store) comes back reduced either way, as the kernels reduce it
        big = fake_cuda.from_bytes(CPU.to_bytes([n2 + 5] * items, W))
        assert (
            fake_cuda.to_bytes(fake_cuda.segment_products(big, seg, 1, n2), W).tolist()
            == CPU.to_bytes([5] * items, W).tolist()
        )
    assert CudaHostBackend()._launch.min_items == 0  # the host build always runs its kernels (CI checks them)


@pytest.mark.slow  # heavy end to end: .ci/run's -m slow, not the README's command (issue 49)
def test_the_kernel_suites_pass_on_fake_cupy():
    """The three kernel suites (operations, the key holder's kernels, renders) on the ``cuda``
    backend over FakeCupy, in a fresh interpreter (``tests/conftest.py``): what a GPU run
    of ``gpu-proof.sh`` runs, so a launcher that hands a device array where numpy is read fails here."""
    here = os.path.dirname(__file__)
    env = {**os.environ, "HEVR_TEST_FAKE_CUPY": "1"}
    env.pop("HEVR_TEST_KERNELS", None)
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-o",
            "addopts=",
            "-x",
            *(
                os.path.join(here, f)
                for f in ("test_cuda_owner.py", "test_cuda_host_backend.py", "test_cuda_host_renders.py")
            ),
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=os.path.dirname(os.path.dirname(here)),
        timeout=600,
        check=False,
    )
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert " passed" in run.stdout and " skipped" not in run.stdout.splitlines()[-1], run.stdout[-500:]


def test_resident_bricks_stay_on_the_device_between_frames(fake_cuda, tmp_path, keypair512, monkeypatch):
    """persist(backend="cuda") keeps each brick as a device array in Montgomery form: a resident
    frame uploads none of the bricks' ciphertexts (a streamed frame uploads all of them), maps all
    the bricks in one task (the process's one device), and gives the cpu image; residency is
    planned against device memory."""
    vol = np.random.default_rng(4).integers(0, 256, (16, 16, 16)).astype(np.uint8)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair512[1], brick=8, progress=False)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=24, height=20)
        want = hevr.render(ev, cam, backend="cpu", progress=False, cache=False)

        def frame(volume):
            before = FakeCupy.uploaded
            img = hevr.render(volume, cam, backend="cuda", progress=False, cache=False)
            assert img.stats["backend"] == "cuda"
            for x, y in zip(want.ciphertexts, img.ciphertexts):
                np.testing.assert_array_equal(x, y)
            return FakeCupy.uploaded - before, img.stats

        streamed, _ = frame(ev)
        # 400 MiB free: half of it holds the 512 KiB of bricks, not also their joined copy and the kernels' scratch
        monkeypatch.setattr(FakeCupy, "memory", (400 << 20, 80 << 30))
        with pytest.raises(
            hevr.MemoryLimitError,
            match=r"device memory \(200.0 MiB\), got 0.5 MiB.* 256.5 MiB a frame needs beside them",
        ):
            ev.persist(backend="cuda")
        monkeypatch.setattr(FakeCupy, "memory", (60 << 30, 80 << 30))
        rv = ev.persist(backend="cuda")
        first, _ = frame(rv)
        second, stats = frame(rv)
    bricks = 16**3 * 128  # the ciphertexts' bytes (512-bit key: 128-byte records)
    assert streamed >= bricks and second <= streamed - bricks and second <= first, (streamed, first, second)
    assert stats["resident"] and stats["map_tasks"] == 1  # one launch over all rays, not a task per brick or thread
    for brick in rv.resident.bricks.values():
        limbs, modulus = brick.channel("scalar").state
        assert isinstance(limbs, FakeArray) and modulus == int(keypair512[0].nsquare)
        # device memory in nbytes, but not in Dask's managed (host) memory, which would spill it
        assert brick.device and brick.nbytes == 8**3 * 128 and sizeof(brick) < 8**3 * 128 // 4
    assert rv.resident.nbytes == bricks
    batch = next(iter(rv.resident.bricks.values())).channel("scalar")
    assert isinstance(pickle.loads(pickle.dumps(batch)).state[0], np.ndarray)  # pickles carry numpy limbs


def test_device_residency_behind_a_scheduler(fake_cuda, tmp_path, keypair256, cluster, monkeypatch):
    """Two GPU workers behind one scheduler (in-process workers sharing FakeCupy): persist plans
    against each worker's device memory (asked on the workers), holds each worker's bricks on
    its device, maps them in one task per worker, and the frames are the cpu image."""
    monkeypatch.setattr(resident_module, "BATCH_BITS", 64)  # as at 2048 bits: host residues map per brick
    vol = np.random.default_rng(5).integers(0, 256, (16, 16, 16)).astype(np.uint8)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[1], brick=8, vector_dims=3, progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=24, height=20)
    want = {
        s: hevr.render(
            ev, cam, "tf", s, nodes=[(0.3, "red"), (0.8, "blue")], backend="cpu", progress=False, cache=False
        )
        for s in ("nearest", "trilinear")
    }
    monkeypatch.setattr(FakeCupy, "memory", (80 << 30, 256 << 20))  # 256 MiB a GPU: half of it < the scratch
    with pytest.raises(hevr.MemoryLimitError, match="device memory"):
        ev.persist(backend="cuda", client=cluster)
    monkeypatch.setattr(FakeCupy, "memory", (60 << 30, 80 << 30))
    rv = ev.persist(backend="cuda", client=cluster)
    rv.resident.wait()
    assert len(rv.resident.worker_bytes) == 2 and all(rv.resident.worker_bytes.values())
    for s, a in want.items():
        for _ in range(2):
            b = hevr.render(
                rv,
                cam,
                "tf",
                s,
                nodes=[(0.3, "red"), (0.8, "blue")],
                backend="cuda",
                progress=False,
                cache=False,
                client=cluster,
            )
            assert b.stats["resident"] and b.stats["map_tasks"] == 2  # one task per worker (GPU)
            for x, y in zip(a.ciphertexts, b.ciphertexts):
                np.testing.assert_array_equal(x, y)
    limbs = [f.result().channel("vector")[0].state[0] for f in rv.resident.bricks.values()]
    assert all(isinstance(x, FakeArray) for x in limbs)  # on the devices, in Montgomery form
    host = ev.persist(backend="cpu", client=cluster)  # the host rule at this key size: a task per brick
    assert hevr.render(host, cam, backend="cpu", progress=False, cache=False, client=cluster).stats["map_tasks"] == 8


@pytest.mark.slow  # heavy end to end: .ci/run's -m slow, not the README's command (issue 49)
def test_gpu_bench_on_fake_cupy(fake_cuda, tmp_path):
    assert main(["bench", "--gpu", "--quick", "--out", str(tmp_path)]) == 0
    md = (tmp_path / "gpu.md").read_text()
    assert "# hevr bench --gpu: FakeCupy on the host build" in md
    assert "| HEVR_CIOS_REG | yes |" in md and "Where one call's time goes" in md  # experiments, stages
    js = json.loads((tmp_path / "gpu.json").read_text())
    assert js["experiments"]["HEVR_CIOS_REG"]["products_per_s"] > 0
    assert set(js["throughput"]["pairs"]["stages_s"]) == {"plan", "launch", "kernels"}


def _check_operations(be, bits: int) -> None:
    n = secrets.randbits(bits) | 1 | (3 << (bits - 2))
    n2 = n * n
    W = (n2.bit_length() + 7) // 8
    vals = [1, 2, n2 - 1] + [secrets.randbelow(n2 - 1) + 1 for _ in range(997)]
    rec = CPU.to_bytes(vals, W)
    c, g = CPU.from_bytes(rec), be.from_bytes(rec)
    np.testing.assert_array_equal(be.to_bytes(g, W), rec)
    assert be.first_out_of_range(g, n2) is None and be.first_out_of_range(g, n2 - 1) == 2
    rng = np.random.default_rng(bits)
    rows = [
        (np.sort(rng.choice(len(vals), size=rng.integers(1, 40), replace=False)), rng.integers(1, 1 << 12, size=40))
        for _ in range(300)
    ]
    indptr = np.cumsum([0] + [r.size for r, _ in rows])
    vox = np.concatenate([r for r, _ in rows])
    w = np.concatenate([x[: r.size] for r, x in rows]).astype(np.uint64)
    plan = plan_products(indptr, vox, w, len(vals))
    assert isinstance(plan, ProductPlan)
    np.testing.assert_array_equal(
        CPU.to_bytes(CPU.ray_products(plan, [c], n2)[0], W), be.to_bytes(be.ray_products(plan, [g], n2)[0], W)
    )
    seg = np.arange(0, 1001, 7)
    np.testing.assert_array_equal(
        CPU.to_bytes(CPU.segment_products(c, seg, 1, n2), W), be.to_bytes(be.segment_products(g, seg, 1, n2), W)
    )
    comb = [[3, 0], [17, 2], [0, 1000]]
    rows = c[:999]
    np.testing.assert_array_equal(
        CPU.to_bytes(CPU.combine(rows, comb, n2), W),
        be.to_bytes(be.combine(be.from_bytes(CPU.to_bytes(rows, W)), comb, n2), W),
    )
    exps = [secrets.randbelow(1 << 40) + 1 for _ in range(len(rows))]
    np.testing.assert_array_equal(
        CPU.to_bytes(CPU.pack(rows, exps, 20, 3, 7, n), W),
        be.to_bytes(be.pack(be.from_bytes(CPU.to_bytes(rows, W)), exps, 20, 3, 7, n), W),
    )


@pytest.mark.gpu
@pytest.mark.parametrize("bits", [64, 512, 2048])
def test_every_operation_identical_on_the_device(bits):
    _check_operations(_cuda_or_skip(), bits)


@pytest.mark.gpu
def test_a_render_on_the_device_is_the_cpu_render(tmp_path, keypair512):
    _cuda_or_skip()
    _check_render(tmp_path, keypair512)


def _check_render(tmp_path, keypair512) -> None:
    vol = np.random.default_rng(9).integers(0, 256, (16, 16, 16)).astype(np.uint8)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair512[1], brick=8, vector_dims=3, progress=False)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=24, height=20)
        nodes = [(0.3, "red"), (0.8, "blue")]
        rv = ev.persist(backend="cuda")  # every brick on the device, in Montgomery form after the first frame
        for mode, sampling, kw in (
            ("xray", "nearest", {}),
            ("tf", "trilinear", {"nodes": nodes}),
            ("tf", "nearest", {"nodes": nodes, "finish": "server"}),
        ):  # combine on the server
            a = hevr.render(ev, cam, mode, sampling, backend="cpu", progress=False, cache=False, **kw)
            for volume in (ev, rv, rv):  # streamed, then two resident frames
                b = hevr.render(volume, cam, mode, sampling, backend="cuda", progress=False, cache=False, **kw)
                assert b.stats["backend"] == "cuda" and len(a.ciphertexts) == len(b.ciphertexts)
                assert b.stats["resident"] == (volume is rv)
                for x, y in zip(a.ciphertexts, b.ciphertexts):
                    np.testing.assert_array_equal(x, y)
    limbs, modulus = next(iter(rv.resident.bricks.values())).channel("scalar").state
    assert not isinstance(limbs, np.ndarray) and modulus is not None  # a device array (CuPy's, or FakeCupy's)


@pytest.mark.gpu
def test_owner_encryption_on_the_device_decrypts_exactly(keypair2048, monkeypatch):
    be = _cuda_or_skip()
    monkeypatch.setattr(be._launch, "keyholder", True)  # the kernels themselves (off by default on a device)
    pub, priv = keypair2048
    x = np.array([0, 1, -1, 2**62, -(2**63), 2**63 - 1, 12345, -999], np.int64)
    assert be.decrypt(priv, be.encrypt(priv, x)) == [int(v) % int(pub.n) for v in x.tolist()]
