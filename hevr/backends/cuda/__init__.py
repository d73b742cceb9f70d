"""CUDA kernel sources of the GPU backend, and their host build (backend ``"cuda-host"``).

* ``mont.cuh`` — batched Montgomery multiplication on 32-bit limbs (CIOS);
  :mod:`hevr.backends.cuda.host` compiles it with the machine's C compiler and checks it against
  gmpy2 (issue 14: GPU arithmetic tested where no GPU is).
* ``render.cuh`` — the render path's backend operations as kernels, one independent item per
  thread: records ↔ limbs, the range check, Montgomery conversion, the per-brick
  multi-exponentiation of a :class:`~hevr.backends.base.ProductPlan` (every task kind), merging,
  combining and packing (issue 26, items 1–3, for a render).
* :mod:`~hevr.backends.cuda.residues` (limb batches, Montgomery constants, plan tables) and
  :mod:`~hevr.backends.cuda.backend` (the orchestration) are shared by every launcher
  (:mod:`~hevr.backends.cuda.registered`: ``cuda-host`` and ``cuda``);
  :mod:`~hevr.backends.cuda.launch` holds the launchers' interface and the host build through
  ctypes; :mod:`~hevr.backends.cuda.device` the CuPy launcher (NVRTC, ``k_*`` kernels) on a GPU,
  with :mod:`~hevr.backends.cuda.device_build` (what it compiles and loads) and
  :mod:`~hevr.backends.cuda.device_owner` (the key holder's kernels there).
"""

from __future__ import annotations

from .backend import KernelBackend
from .host import (
    HostMontgomery,
    build_host,
    build_library,
    from_limbs,
    montgomery_params,
    source,
    to_limbs,
)
from .launch import HostLauncher, Launcher
from .registered import CudaHostBackend
from .residues import LimbBatch

__all__ = [
    "CudaHostBackend",
    "HostLauncher",
    "HostMontgomery",
    "KernelBackend",
    "Launcher",
    "LimbBatch",
    "build_host",
    "build_library",
    "from_limbs",
    "montgomery_params",
    "source",
    "to_limbs",
]
