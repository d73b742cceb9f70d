"""The kernel backends hevr registers: ``cuda-host`` (the host build) and ``cuda`` (a GPU through CuPy).

Both are :class:`~hevr.backends.cuda.backend.KernelBackend` — the same orchestration over the same
kernels — with a different launcher: :class:`CudaHostBackend` the kernels compiled for the host
with the C compiler and called through ctypes (:class:`~hevr.backends.cuda.launch.HostLauncher`),
:class:`CudaBackend` the kernels on an NVIDIA GPU (:class:`~hevr.backends.cuda.device.CupyLauncher`).
"""

from __future__ import annotations

from .backend import KernelBackend
from .device import CupyLauncher
from .host import check_defines
from .launch import HostLauncher

__all__ = ["CudaBackend", "CudaHostBackend"]


class CudaHostBackend(KernelBackend):
    """The kernels of the CUDA backend compiled for the host: backend ``"cuda-host"``.

    For tests and for checking a machine: the same kernels and orchestration as the GPU
    backend, on the CPU; bit-identical to ``cpu``. The C source is compiled on first use
    (:class:`MissingDependencyError` without a C compiler).
    """

    name = "cuda-host"

    def __init__(self) -> None:
        self._host = HostLauncher()
        super().__init__(self._host)

    def __reduce__(self) -> tuple[type[CudaHostBackend], tuple[()]]:
        return (CudaHostBackend, ())

    def check(self) -> bool:
        """Build (or load the cached build of) the kernels now: True, or
        :class:`MissingDependencyError` where no C compiler here builds them."""
        return self._host.lib is not None  # the property builds or loads the library


class CudaBackend(KernelBackend):
    """The kernels on an NVIDIA GPU through CuPy: backend ``"cuda"``
    (:class:`~hevr.backends.cuda.device.CupyLauncher`).

    Bit-identical to ``cpu`` and ``cuda-host`` (the same kernels and orchestration). Creating it
    touches no GPU; the first operation compiles the module with NVRTC and raises
    :class:`MissingDependencyError` on a machine without CuPy or a device.
    """

    name = "cuda"

    def __init__(self, device: int | None = None, defines: tuple[str, ...] = ()) -> None:
        self._cupy = CupyLauncher(device, defines)
        super().__init__(self._cupy)
        self._device, self._defines = device, check_defines(defines)

    def __reduce__(self) -> tuple[type[CudaBackend], tuple[int | None, tuple[str, ...]]]:
        return (CudaBackend, (self._device, self._defines))

    def check(self) -> bool:
        """CuPy and a device are there, and the module compiles: True, else
        :class:`MissingDependencyError` saying what is missing."""
        return self._cupy.load()
