"""What a CUDA device compiles and loads: the kernels' sources for NVRTC and the stack they need.

:func:`device_source` and :func:`owner_source` are ``render.cuh`` and ``owner.cuh`` with
``mont.cuh`` pasted in place of its ``#include`` (NVRTC then needs no include path);
:data:`KERNELS` names the ``k_*`` kernels of the first, launched ``BLOCK`` threads a block;
:func:`reserve_stack` raises the device's per-thread stack limit for a module's deepest kernel
before any of them runs. The launcher that uses them is :class:`~hevr.backends.cuda.device.CupyLauncher`.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from .host import SOURCE as MONT_SOURCE
from .launch import OWNER_SOURCE, RENDER_SOURCE

__all__ = ["BLOCK", "KERNELS", "device_source", "owner_source", "reserve_stack"]

BLOCK = 128
KERNELS = (
    "k_records_to_limbs",
    "k_limbs_to_records",
    "k_out_of_range",
    "k_mont_convert",
    "k_ray_powers",
    "k_ray_tasks",
    "k_segments",
    "k_combine",
    "k_pack",
)


def reserve_stack(cp: Any, fns: Iterable[Any]) -> int:
    """Raise the device's per-thread stack limit to the deepest frame of ``fns`` before any of them
    runs, with the device idle; the limit after. ``owner.cuh``'s kernels take 2,576 bytes of stack
    frame at sm_90 (ptxas), over the default limit of 1,024: on an H200 (2026-11-28) they were exact
    in every run with the limit raised before any launch and wrong or faulting (illegal address,
    ``cudaErrorInvalidAddressSpace``) in some runs without, exact under ``compute-sanitizer``, which
    serialises launches; so the driver's own growing of the stack at a launch is not relied on."""
    rt = cp.cuda.runtime
    need = max((int(f.attributes["local_size_bytes"]) for f in fns), default=0)
    have = int(rt.deviceGetLimit(0))  # cudaLimitStackSize
    if need > have:
        cp.cuda.Device().synchronize()  # no kernel in flight while the driver re-sizes local memory
        rt.deviceSetLimit(0, -(-need // 1024) * 1024)
        have = int(rt.deviceGetLimit(0))
    return have


def device_source() -> str:
    """``render.cuh`` with ``mont.cuh`` pasted in place of its include (what NVRTC compiles).

    >>> src = device_source()
    >>> '#include "mont.cuh"' in src, "k_ray_tasks" in src, "hevr_mont_mul" in src
    (False, True, True)
    """
    render = RENDER_SOURCE.read_text(encoding="utf-8")
    if '#include "mont.cuh"' not in render:  # pragma: no cover - the source's own include
        raise RuntimeError('render.cuh: expected #include "mont.cuh"')
    return render.replace('#include "mont.cuh"', MONT_SOURCE.read_text(encoding="utf-8"), 1)


def owner_source() -> str:
    """``owner.cuh`` with ``mont.cuh`` pasted in (the owner-encryption module NVRTC compiles).

    >>> "k_owner_encrypt" in owner_source() and '#include "mont.cuh"' not in owner_source()
    True
    """
    return OWNER_SOURCE.read_text(encoding="utf-8").replace(
        '#include "mont.cuh"', MONT_SOURCE.read_text(encoding="utf-8"), 1
    )
