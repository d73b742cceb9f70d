"""CUDA kernel sources of the (future) GPU backend, and their host build for testing.

:mod:`hevr.backends.cuda.host` compiles ``mont.cuh`` — batched Montgomery multiplication on
32-bit limbs — with the machine's C compiler and checks it against gmpy2 in the normal test
suite, so the GPU arithmetic is tested where no GPU is (issue 14: the GPU backend itself, its
CuPy/NVRTC build and its benchmarks need a GPU machine).
"""

from __future__ import annotations

from .host import (
    HostMontgomery,
    build_host,
    from_limbs,
    montgomery_params,
    source,
    to_limbs,
)

__all__ = ["HostMontgomery", "build_host", "from_limbs", "montgomery_params", "source", "to_limbs"]
