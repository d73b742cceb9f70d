"""Compile the device source to PTX with NVRTC through ctypes — no GPU, no CuPy needed.

NVRTC is a library (``libnvrtc.so``: the ``nvidia-cuda-nvrtc-cu12`` wheel, or a CUDA toolkit),
and it compiles for any architecture without a device. This is how CI checks that every
``k_*`` kernel of :func:`~hevr.backends.cuda.device.device_source` — exactly what
:class:`~hevr.backends.cuda.device.CupyLauncher` hands NVRTC on a GPU machine — compiles for
Hopper (``compute_90``), on machines that have neither a GPU nor ``nvcc``.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys
from pathlib import Path

from ...errors import MissingDependencyError

__all__ = ["find_nvrtc", "ptx"]


def find_nvrtc() -> Path:
    """The NVRTC library: from the ``nvidia-cuda-nvrtc`` wheel in this environment, else a CUDA
    toolkit (``$CUDA_HOME``, else the usual install folder). :class:`MissingDependencyError` if none."""
    roots = [Path(p) / "nvidia" for p in sys.path if p and Path(p, "nvidia").is_dir()]
    roots += [Path(os.environ.get("CUDA_HOME", "/usr/local/cuda"))]
    for root in roots:
        for pattern in (
            "cuda_nvrtc/lib/libnvrtc.so*",
            "cu*/lib/libnvrtc.so*",
            "lib64/libnvrtc.so*",
            "lib/libnvrtc.so*",
        ):
            found = sorted(
                p
                for p in glob.glob(str(root / pattern))
                if "alt" not in Path(p).name and "builtins" not in Path(p).name
            )
            if found:
                return Path(found[0])
    raise MissingDependencyError(
        "nvrtc: expected the NVRTC library (pip install nvidia-cuda-nvrtc-cu12, or a CUDA toolkit), got none"
    )


def ptx(
    source: str, arch: str = "compute_90", options: tuple[str, ...] = ("--std=c++11",), name: str = "render.cu"
) -> str:
    """PTX of ``source`` for ``arch``; :class:`RuntimeError` with NVRTC's log if it does not compile."""
    lib = ctypes.CDLL(str(find_nvrtc()))
    prog = ctypes.c_void_p()
    _check(lib, lib.nvrtcCreateProgram(ctypes.byref(prog), source.encode(), name.encode(), 0, None, None), "create")
    try:
        opts = [f"--gpu-architecture={arch}".encode(), *(o.encode() for o in options)]
        arr = (ctypes.c_char_p * len(opts))(*opts)
        status = lib.nvrtcCompileProgram(prog, len(opts), arr)
        if status != 0:
            size = ctypes.c_size_t()
            lib.nvrtcGetProgramLogSize(prog, ctypes.byref(size))
            log = ctypes.create_string_buffer(size.value)
            lib.nvrtcGetProgramLog(prog, log)
            raise RuntimeError(f"NVRTC could not compile {name} for {arch}:\n{log.value.decode(errors='replace')}")
        size = ctypes.c_size_t()
        _check(lib, lib.nvrtcGetPTXSize(prog, ctypes.byref(size)), "PTX size")
        out = ctypes.create_string_buffer(size.value)
        _check(lib, lib.nvrtcGetPTX(prog, out), "PTX")
        return out.value.decode()
    finally:
        lib.nvrtcDestroyProgram(ctypes.byref(prog))


def _check(lib: ctypes.CDLL, status: int, what: str) -> None:
    if status != 0:
        lib.nvrtcGetErrorString.restype = ctypes.c_char_p
        raise RuntimeError(f"NVRTC {what}: {lib.nvrtcGetErrorString(status).decode()}")
