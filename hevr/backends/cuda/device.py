"""The CuPy launcher: the kernels of ``render.cuh`` on an NVIDIA GPU (backend ``"cuda"``).

The same source as the host build (:class:`~hevr.backends.cuda.launch.HostLauncher`), compiled
once per process by NVRTC through CuPy's ``RawModule`` for the current device's architecture —
no jitify (it hung for minutes here) and no ``<stdint.h>`` (``mont.cuh`` typedefs its limb types
under ``__CUDACC_RTC__``); ``mont.cuh`` is pasted in place of its ``#include`` so no include path
is needed (:mod:`~hevr.backends.cuda.device_build`: the sources, the kernels' names, the stack they
need; :mod:`~hevr.backends.cuda.device_owner`: the key holder's launches). Each method mirrors
the host launcher's: numpy arrays in, one launch of the ``k_*`` kernel over all items (``BLOCK``
threads per block), numpy arrays out. Kernel arguments are typed
as the kernels declare them (``int`` → int32, ``long long`` → int64, ``hevr_u32`` → uint32); a
NULL pointer is passed as a zero uint64 (CuPy turns ``None`` into 0xffffffff, cupy#9046).

Scratch. ``k_ray_tasks`` and ``k_combine`` give every thread its own slice of one bucket buffer,
``slot`` residues of ``nl`` limbs each; tasks are launched in chunks whose scratch stays under
``SCRATCH_BYTES`` (256 MiB), at least 32k threads a launch where that fits.

The key holder's kernels are off on a device (``keyholder = False``). On an NVIDIA H200
(2026-11-26, ``benchmarks/results-gpu-h200-2026-11-26.md``) every render operation and whole
2048-bit renders were byte-identical to ``cpu``, but ``owner.cuh`` was not: CRT decryption at a
2048-bit key returned wrong residues in one run and faulted (illegal address) in another, owner
encryption of 262,144 values faulted while 64 were exact, and one public-key ciphertext of a
33/95-bit key was wrong; the host build of the same source passes every test, also under
AddressSanitizer and UBSan. Until a device run passes ``tests/backends/test_cuda_owner.py``
(``benchmarks/gpu-proof.sh``), :class:`~hevr.backends.cuda.registered.CudaBackend` encrypts and
decrypts the CPU way on a device; the kernels stay reachable for that proof (set ``keyholder``).
The second run (2026-11-28, ``benchmarks/results-gpu-h200-2026-11-28.md``) found them exact with the
device's stack limit raised before any launch and wrong or faulting in some runs without:
:func:`reserve_stack` now does so when a module loads; ``keyholder`` stays off until a device run passes.

Residence. Results stay on the device (``residence = "device"``): an operation returns CuPy
arrays, and an operand that already is one is used where it is, so a chain of operations moves
only what the host reads — records at the end (``limbs_to_records``), flags, operation counts and
decrypted residues — plus each call's plan arrays. A resident volume (``persist(backend="cuda")``)
keeps every brick on the GPU in Montgomery form from its first frame on; a frame uploads none of
the bricks' ciphertexts, only its plan and the ray sums that map tasks hand to merges and finishing
as records (``tests/backends/test_cuda_device.py`` counts the bytes on FakeCupy). The modulus
constants are uploaded once per modulus. Owner encryption, public-key encryption and CRT
decryption have their kernels here (:meth:`CupyLauncher.owner_encrypt`, tables uploaded once per
key), used only with ``keyholder`` set (above). The launcher is exercised on a GPU only by the
``gpu``-marked tests; everywhere else it runs on ``tests/backends/_fake_cupy.py`` (CuPy played by
the host build); without CuPy or a device :class:`hevr.MissingDependencyError` says what is missing.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ...errors import MissingDependencyError
from ...runtime import stats
from . import device_owner
from .device_build import BLOCK, KERNELS, device_source, owner_source, reserve_stack
from .host import check_defines
from .launch import Launcher
from .residues import FOLD, Modulus, PlanTables

__all__ = ["BLOCK", "KERNELS", "CupyLauncher", "device_source", "owner_source", "reserve_stack"]

SCRATCH_BYTES = 256 << 20
MIN_THREADS = 32768
# Fewer independent items than this (segments, rows to combine, packed ciphertexts) go to gmpy2: a GPU
# thread's chain of 4096-bit products runs tens of times slower than a CPU core's (backend.py). Estimated
# from the H200's 24³ frame (benchmarks/results-gpu-h200-2026-11-26.md): ~0.5-0.8 ms a product on one
# thread against ~5 µs on a core with gmpy2, so a launch beats one core from ~100 items. Not yet measured.
MIN_ITEMS = 128
_NULL = np.uint64(0)


def _i32(x: int) -> np.int32:
    return np.int32(x)


def _i64(x: int) -> np.int64:
    return np.int64(x)


class CupyLauncher(Launcher):
    """The kernels on the current CUDA device through CuPy (module docstring).

    Parameters
    ----------
    device : int, optional
        The CUDA device to use (default: CuPy's current device, i.e. ``CUDA_VISIBLE_DEVICES``'s first).
    defines : tuple of str
        Preprocessor names the modules are compiled with (``-D``): the source's experiments, such as
        ``HEVR_CIOS_REG`` (``mont.cuh``), which ``hevr bench --gpu`` measures against the default.
    """

    keyholder = False  # owner.cuh wrong on an H200 (module docstring): the CPU way until proven
    residence = "device"
    min_items = MIN_ITEMS

    def __init__(self, device: int | None = None, defines: tuple[str, ...] = ()) -> None:
        self._device = device
        self._defines = check_defines(defines)
        self._options = ("--std=c++11", *(f"-D{d}" for d in self._defines))
        self._cp: Any = None
        self._fns: dict[str, Any] = {}
        self._owner_fn: Any = None
        self._decrypt_fn: Any = None
        self._public_fn: Any = None
        self._moduli: dict[int, tuple] = {}

    def __reduce__(self):
        return (CupyLauncher, (self._device, self._defines))

    def with_defines(self, defines):
        return CupyLauncher(self._device, defines)

    # -- CuPy, the device and the module -----------------------------------------------------
    @property
    def cp(self) -> Any:
        """The ``cupy`` module, with a device present (MissingDependencyError otherwise)."""
        if self._cp is None:
            try:
                import cupy
            except ImportError as exc:
                raise MissingDependencyError(
                    "backend: 'cuda' needs CuPy and an NVIDIA GPU; CuPy is not installed: pip install 'hevr[gpu]' "
                    "(cupy-cuda12x or cupy-cuda13x, matching the driver), or use backend='cpu'"
                ) from exc
            try:
                count = cupy.cuda.runtime.getDeviceCount()
            except Exception as exc:  # noqa: BLE001 - CUDARuntimeError without a driver, and its kin
                raise MissingDependencyError(f"backend: 'cuda' needs an NVIDIA GPU; CuPy sees none ({exc})") from None
            if count < 1:
                raise MissingDependencyError("backend: 'cuda' needs an NVIDIA GPU; CuPy sees none")
            self._cp = cupy
        if self._device is not None:  # the current device is per thread: each of a worker's threads sets it
            self._cp.cuda.Device(self._device).use()
        return self._cp

    def device_name(self) -> str:
        """The GPU's name (as the benchmark records it)."""
        cp = self.cp
        props = cp.cuda.runtime.getDeviceProperties(cp.cuda.Device().id)
        name = props["name"]
        return name.decode() if isinstance(name, bytes) else str(name)

    def load(self) -> bool:
        """Compile the module now (CuPy caches NVRTC's output on disk): True, or
        :class:`MissingDependencyError` without CuPy or a device."""
        return self._fn(KERNELS[0]) is not None

    def _fn(self, name: str) -> Any:
        if not self._fns:
            mod = self.cp.RawModule(code=device_source(), options=self._options, backend="nvrtc")
            fns = {k: mod.get_function(k) for k in KERNELS}
            reserve_stack(self.cp, fns.values())
            self._fns = fns
        return self._fns[name]

    def _launch(self, name: str, count: int, *args: Any) -> None:
        if count > 0:
            self._fn(name)(((count + BLOCK - 1) // BLOCK,), (BLOCK,), args)
            stats.add(f"launch {name}", 0.0, 1)  # how many launches of how many threads a frame makes
            stats.add(f"threads {name}", 0.0, count)

    def _dev(self, arr: Any, dtype: Any) -> Any:
        """A contiguous device array of ``dtype``: a device array as it is (no copy where it already
        is one), a numpy array uploaded; None as the NULL pointer."""
        if arr is None:
            return _NULL
        cp = self.cp
        if isinstance(arr, cp.ndarray):
            if arr.dtype == dtype and arr.flags.c_contiguous:
                return arr
            return cp.ascontiguousarray(arr.astype(dtype))
        return cp.asarray(np.ascontiguousarray(arr, dtype=dtype))

    # -- where arrays live (Launcher): results stay on the device ----------------------------------
    def host(self, limbs):
        return limbs.get() if isinstance(limbs, self.cp.ndarray) else np.asarray(limbs)

    def join(self, arrays, nl):
        cp = self.cp
        out = cp.zeros((sum(int(a.shape[0]) for a in arrays), nl), cp.uint32)
        r = 0
        for a in arrays:
            m, k = int(a.shape[0]), int(a.shape[1])
            if m:
                out[r : r + m, :k] = self._dev(a, np.uint32)
            r += m
        return out

    def take(self, limbs, index):
        return self.cp.take(self._dev(limbs, np.uint32), self._dev(index, np.int64), axis=0)

    def rows(self, vals, rep, fill):
        # on the device one gather from vals with the fill row appended (no boolean-mask assignment)
        idx = np.where(rep < 0, vals.shape[0], rep).astype(np.int64)
        return self.take(self.join([vals, fill.reshape(1, -1)], int(vals.shape[1])), idx)

    def memory(self):
        cp = self.cp
        free, total = cp.cuda.runtime.memGetInfo()
        return int(free) + int(cp.get_default_memory_pool().free_bytes()), int(total)  # the pool's cache is free too

    def frame_bytes(self, resident):
        # a worker's resident bricks are joined into one array for its map task (KernelBackend.concat),
        # and each launch takes up to SCRATCH_BYTES of buckets
        return int(resident) + SCRATCH_BYTES

    def device_tables(self, t):
        dev = {
            f: self._dev(getattr(t, f), dt)
            for f, dt in (
                ("vl", np.int64),
                ("wl", np.uint64),
                ("tasks", np.int64),
                ("pre_v", np.int64),
                ("pre_j", np.int64),
                ("pre_start", np.int64),
                ("pw_off", np.int64),
                ("pw_n", np.int64),
            )
        }
        return dataclasses.replace(t, **dev)

    def _mod(self, M: Modulus) -> tuple:
        """The kernels' modulus arguments, its arrays uploaded once per modulus (the last few kept)."""
        got = self._moduli.get(M.n)
        if got is None:
            if len(self._moduli) >= 8:
                self._moduli.clear()
            got = self._moduli[M.n] = (
                self._dev(M.limbs, np.uint32),
                self._dev(M.one, np.uint32),
                np.uint32(M.ninv),
                _i32(M.nl),
            )
        return got

    # -- the operations --------------------------------------------------------------------
    def records_to_limbs(self, records, nl):
        cp = self.cp
        rec = self._dev(records, np.uint8)
        m, width = rec.shape
        x, over = cp.empty((m, nl), cp.uint32), cp.empty(m, cp.uint8)
        self._launch("k_records_to_limbs", m, rec, _i32(width), _i32(nl), _i64(m), x, over)
        return x, over.get()

    def limbs_to_records(self, limbs, width):
        cp = self.cp
        x = self._dev(limbs, np.uint32)
        m, nl = x.shape
        rec, over = cp.empty((m, width), cp.uint8), cp.empty(m, cp.uint8)
        self._launch("k_limbs_to_records", m, x, _i32(nl), _i32(width), _i64(m), rec, over)
        return rec.get(), over.get()

    def out_of_range(self, limbs, upper):
        x = self._dev(limbs, np.uint32)
        bad = self.cp.empty(x.shape[0], self.cp.uint8)
        self._launch(
            "k_out_of_range", x.shape[0], x, self._dev(upper, np.uint32), _i32(x.shape[1]), _i64(x.shape[0]), bad
        )
        return bad.get()

    def mont_convert(self, limbs, b, M):
        x = self._dev(limbs, np.uint32)
        out = self.cp.empty_like(x)
        n, _, ninv, nl = self._mod(M)
        self._launch("k_mont_convert", x.shape[0], x, self._dev(b, np.uint32), n, ninv, nl, _i64(x.shape[0]), out)
        return out

    def ray_products(self, t: PlanTables, cts, shared_w, M):
        cp, nl = self.cp, M.nl
        mod = self._mod(M)
        c = self._dev(cts, np.uint32)
        pw = cp.empty((max(1, t.pw_rows), nl), cp.uint32)
        if t.pre_v.size:
            self._launch(
                "k_ray_powers",
                t.pre_v.size,
                c,
                self._dev(t.pre_v, np.int64),
                self._dev(t.pre_j, np.int64),
                self._dev(t.pre_start, np.int64),
                _i32(shared_w),
                _i64(t.pre_v.size),
                pw,
                *mod,
            )
        T = t.tasks.shape[0]
        vals, counts = cp.empty((max(T, 1), nl), cp.uint32), cp.zeros((max(T, 1), 3), cp.int64)
        per_thread = max(1, t.slot) * (nl * 4 + 1)
        chunk = int(min(max(T, 1), max(SCRATCH_BYTES // per_thread, min(MIN_THREADS, T) or 1)))
        buckets = cp.empty((chunk * max(1, t.slot), nl), cp.uint32)
        used = cp.empty(chunk * max(1, t.slot), cp.uint8)
        args = (self._dev(t.tasks, np.int64),)
        tables = (
            c,
            pw,
            self._dev(t.pw_off, np.int64),
            self._dev(t.pw_n, np.int64),
            self._dev(t.vl, np.int64),
            self._dev(t.wl, np.uint64),
            _i32(shared_w),
            self._dev(FOLD, np.int64),
            buckets,
            used,
            _i64(t.slot),
            vals,
            counts,
            *mod,
        )
        for first in range(0, T, chunk):
            count = min(chunk, T - first)
            self._launch("k_ray_tasks", count, *args, _i64(first), _i64(count), *tables)
        return vals[:T], counts[:T].get()

    def segments(self, vals, indptr, k, M):
        ip = np.ascontiguousarray(indptr, dtype=np.int64)
        count = (ip.size - 1) * k
        out = self.cp.empty((max(count, 1), M.nl), self.cp.uint32)
        self._launch(
            "k_segments",
            count,
            self._dev(vals, np.uint32),
            self._dev(ip, np.int64),
            _i32(k),
            _i64(count),
            out,
            *self._mod(M),
        )
        return out[:count]

    def combine(self, vals, k, E, M):
        cp = self.cp
        C, _, ew = E.shape
        rows = vals.shape[0] // k
        slot = (1 << k) if k <= 8 else 0
        out = cp.empty((max(rows * C, 1), M.nl), cp.uint32)
        chunk = int(min(max(rows, 1), max(SCRATCH_BYTES // (max(slot, 1) * M.nl * 4), 1)))
        sub = cp.empty((chunk * max(slot, 1), M.nl), cp.uint32)
        v, e, mod = self._dev(vals, np.uint32), self._dev(E, np.uint32), self._mod(M)
        for first in range(0, rows, chunk):
            count = min(chunk, rows - first)
            self._launch("k_combine", count, v, _i32(k), _i32(C), e, _i32(ew), _i64(first), _i64(count), sub, out, *mod)
        return out[: rows * C]

    def pack(self, terms, R, per_pack, bits, offs, M):
        m, ew = R.shape
        groups = -(-m // per_pack)
        out = self.cp.empty((max(groups, 1), M.nl), self.cp.uint32)
        self._launch(
            "k_pack",
            groups,
            self._dev(terms, np.uint32),
            self._dev(R, np.uint32),
            _i32(ew),
            _i64(m),
            _i32(per_pack),
            _i32(bits),
            self._dev(offs, np.uint32),
            _i64(groups),
            out,
            *self._mod(M),
        )
        return out[:groups]

    def _owner_module(self) -> None:
        if self._owner_fn is None:
            mod = self.cp.RawModule(code=owner_source(), options=self._options, backend="nvrtc")
            fns = [mod.get_function(k) for k in ("k_decrypt", "k_public_encrypt", "k_owner_encrypt")]
            reserve_stack(self.cp, fns)
            self._decrypt_fn, self._public_fn, self._owner_fn = fns  # _owner_fn, tested first, set last

    # -- the key holder's kernels (owner.cuh; device_owner.py launches them) ---------------------
    def public_encrypt(self, x, r, n, M):
        self._owner_module()
        return device_owner.public_encrypt(self.cp, self._public_fn, self._dev, x, r, n, M)

    def decrypt(self, c, tables):
        self._owner_module()
        return device_owner.decrypt(self.cp, self._decrypt_fn, self._dev, c, tables)

    def owner_encrypt(self, x, a, b, tables):
        self._owner_module()
        return device_owner.owner_encrypt(self.cp, self._owner_fn, self._dev, x, a, b, tables)
