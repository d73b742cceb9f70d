"""A stand-in for CuPy that runs the CUDA launcher's kernel launches on the host build.

:class:`~hevr.backends.cuda.device.CupyLauncher` marshals numpy operands into CuPy arrays and typed
scalars and launches the ``k_*`` kernels. On a machine without a GPU this module plays CuPy: arrays
are numpy arrays behind the few CuPy methods the launcher uses, and a launch of ``k_name`` calls the
host build's ``hevr_name_host`` — the same per-item function over the same arguments in the same
order (render.cuh and owner.cuh declare both with one parameter list). Every argument is checked
against the C type the kernel declares, as CuPy would pack it by its dtype: a pointer must be an
array or the zero uint64 that stands for NULL, an ``int`` an int32, a ``long long`` an int64, a
``hevr_u32`` a uint32 — so a wrong type or order in the launcher fails here, not first on a GPU.
The grid must cover the item count. Only the launcher's plumbing is under test; the arithmetic is
the host build's, checked against gmpy2 elsewhere.
"""

from __future__ import annotations

import ctypes

import numpy as np

from hevr.backends.cuda import launch
from hevr.backends.cuda.host import SOURCE as MONT_SOURCE
from hevr.backends.cuda.host import build_library

_C = {launch._P: "pointer", launch._I: np.int32, launch._LL: np.int64, launch._U32: np.uint32}
_SIGS = {
    **launch._SIGNATURES,
    "hevr_owner_encrypt_host": launch._OWNER_SIGNATURE,
    "hevr_decrypt_host": launch._DECRYPT_SIGNATURE,
    "hevr_public_encrypt_host": launch._PUBLIC_SIGNATURE,
}
# the position of each kernel's item count (what one thread per item covers)
_COUNT = {
    "records_to_limbs": 3,
    "limbs_to_records": 3,
    "out_of_range": 3,
    "mont_convert": 5,
    "ray_powers": 5,
    "ray_tasks": 2,
    "segments": 3,
    "combine": 6,
    "pack": 7,
    "owner_encrypt": 24,
    "decrypt": 29,
    "public_encrypt": 9,
}


class FakeArray:
    """A numpy array behind the CuPy array methods the launcher calls. Like a CuPy array it refuses
    to become a numpy array implicitly (``np.asarray``): the launcher must download with ``get()``."""

    def __init__(self, a: np.ndarray) -> None:
        self.a = a

    shape = property(lambda self: self.a.shape)
    dtype = property(lambda self: self.a.dtype)
    size = property(lambda self: self.a.size)
    flags = property(lambda self: self.a.flags)

    def __array__(self, *args, **kwargs):
        raise TypeError("Implicit conversion to a NumPy array is not allowed. Please use `.get()`")

    def __len__(self) -> int:
        return len(self.a)

    def __getitem__(self, key):
        return FakeArray(self.a[key])

    def __setitem__(self, key, value) -> None:
        assert isinstance(value, FakeArray), "device arrays take device values"
        self.a[key] = value.a

    def astype(self, dtype) -> FakeArray:
        return FakeArray(self.a.astype(dtype))

    def get(self) -> np.ndarray:
        FakeCupy.downloaded += self.a.nbytes
        return self.a.copy()


class _Function:
    def __init__(self, module: FakeModule, name: str) -> None:
        self.module, self.name = module, name
        self.host = "hevr_" + name[2:] + "_host"
        self.calls = 0
        # ptxas's stack frames at sm_90 (2026-11-28): owner.cuh's kernels over the default limit
        frame = {"k_decrypt": 2576, "k_owner_encrypt": 2576, "k_public_encrypt": 2064}.get(name, 520)
        self.attributes = {"local_size_bytes": frame, "num_regs": 64}

    def __call__(self, grid, block, args) -> None:
        sig = _SIGS[self.host]
        assert len(args) == len(sig), f"{self.name}: {len(args)} arguments, the kernel takes {len(sig)}"
        c_args = []
        for i, (arg, ctype) in enumerate(zip(args, sig)):
            want = _C[ctype]
            if want == "pointer":
                if isinstance(arg, FakeArray):
                    assert arg.a.flags.c_contiguous, f"{self.name} argument {i}: not contiguous"
                    c_args.append(arg.a.ctypes.data)
                else:
                    assert type(arg) is np.uint64 and int(arg) == 0, f"{self.name} argument {i}: {arg!r} is no pointer"
                    c_args.append(None)
            else:
                assert type(arg) is want, (
                    f"{self.name} argument {i}: {type(arg).__name__}, the kernel takes {want.__name__}"
                )
                c_args.append(int(arg))
        count = int(args[_COUNT[self.name[2:]]])
        assert self.attributes["local_size_bytes"] <= FakeCupy.stack, f"{self.name}: stack limit under its frame"
        assert grid[0] * block[0] >= count and (grid[0] - 1) * block[0] < max(count, 1), (
            f"{self.name}: grid {grid} x block {block} for {count} items"
        )
        fn = getattr(self.module.lib, self.host)
        fn.argtypes, fn.restype = sig, ctypes.c_int
        assert fn(*c_args) == 0
        self.calls += 1


class FakeModule:
    """``cupy.RawModule``: the source must hold the kernel; the host build runs it."""

    def __init__(self, code: str, options=(), backend: str = "nvrtc") -> None:
        assert backend == "nvrtc" and '#include "mont.cuh"' not in code
        self.code, self.options = code, tuple(options)
        owner = "k_owner_encrypt" in code
        defines = tuple(o[2:] for o in options if o.startswith("-D"))  # NVRTC's -D, the host build's too
        self.lib = build_library(
            launch.OWNER_SOURCE if owner else launch.RENDER_SOURCE, (MONT_SOURCE,), defines=defines
        )
        self.functions: dict[str, _Function] = {}

    def get_function(self, name: str) -> _Function:
        assert f"void {name}(" in self.code, name
        return self.functions.setdefault(name, _Function(self, name))


class FakeCupy:
    """The module attributes of ``cupy`` the launcher uses."""

    uint8, uint32, int64 = np.uint8, np.uint32, np.int64
    RawModule = FakeModule
    ndarray = FakeArray  # dask and array-api-compat look for it when cupy is importable

    class cuda:
        class runtime:
            @staticmethod
            def getDeviceCount() -> int:
                return 1

            @staticmethod
            def getDeviceProperties(i: int) -> dict:
                return {"name": b"FakeCupy on the host build"}

            @staticmethod
            def memGetInfo() -> tuple[int, int]:
                return FakeCupy.memory

            @staticmethod
            def deviceGetLimit(what: int) -> int:
                assert what == 0, "only cudaLimitStackSize"
                return FakeCupy.stack

            @staticmethod
            def deviceSetLimit(what: int, value: int) -> None:
                assert what == 0 and FakeCupy.synchronized, "the stack re-sized with the device idle"
                FakeCupy.stack = value

        class Device:
            def __init__(self, i: int = 0) -> None:
                self.id = i

            def use(self) -> None:
                pass

            def synchronize(self) -> None:
                FakeCupy.synchronized = True

    memory = (60 << 30, 80 << 30)  # (free, total) device bytes
    stack, synchronized = 1024, False  # the per-thread stack limit (the driver's default) and a sync seen
    uploaded = downloaded = 0  # bytes through asarray / get(): what a frame moves over PCIe

    @staticmethod
    def asarray(a) -> FakeArray:
        if isinstance(a, FakeArray):
            return a
        assert isinstance(a, np.ndarray), f"asarray of a {type(a).__name__}"
        FakeCupy.uploaded += a.nbytes
        return FakeArray(np.ascontiguousarray(a).copy())

    class _Pool:
        @staticmethod
        def free_bytes() -> int:
            return 0

    @staticmethod
    def get_default_memory_pool():
        return FakeCupy._Pool

    @staticmethod
    def ascontiguousarray(a: FakeArray) -> FakeArray:
        assert isinstance(a, FakeArray)
        return FakeArray(np.ascontiguousarray(a.a))

    @staticmethod
    def take(a: FakeArray, index: FakeArray, axis: int) -> FakeArray:
        assert isinstance(a, FakeArray) and isinstance(index, FakeArray)
        return FakeArray(np.take(a.a, index.a, axis=axis))

    @staticmethod
    def empty(shape, dtype) -> FakeArray:
        return FakeArray(np.full(shape, 0xA5, dtype=dtype))  # garbage, as device memory is

    @staticmethod
    def zeros(shape, dtype) -> FakeArray:
        return FakeArray(np.zeros(shape, dtype=dtype))

    @staticmethod
    def empty_like(x: FakeArray) -> FakeArray:
        return FakeArray(np.full_like(x.a, 0xA5))
