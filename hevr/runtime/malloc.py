"""The C allocator of a render process: keep the frame's temporary arrays out of ``mmap``.

A frame's plaintext work (rays, samples, weights, plans) allocates and frees many numpy arrays
of 0.1–30 MB. glibc serves a block above ``M_MMAP_THRESHOLD`` with a fresh ``mmap`` and returns
it with ``munmap`` on free, so every such temporary is page-faulted in again (about 0.25 ms per
MB); by default glibc raises the threshold as it sees large blocks freed, but setting any
``MALLOC_*`` tunable fixes it at 128 KiB — and Dask's nanny starts every worker with
``MALLOC_TRIM_THRESHOLD_=65536`` (``distributed.nanny.pre-spawn-environ``), which also trims
the heap's top after each large free. Measured on the 64-bit paper case (2-core EPYC,
``benchmarks/frame_plaintext.py``): a worker's geometry of one frame took 0.070 s in a Dask
worker against 0.038 s in a plain process, and 0.026 s with the thresholds below.

:func:`tune` sets ``M_MMAP_THRESHOLD`` to 32 MiB and ``M_TRIM_THRESHOLD`` to 64 MiB with
``mallopt`` — once per process, on Linux with glibc, when the render tasks first run there
(and in the client's render) — so a process keeps at most 64 MiB of freed heap for reuse
instead of returning it at once. Dask config ``hevr.malloc-tuning: false``
(``DASK_HEVR__MALLOC_TUNING=false``) leaves the allocator alone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import sys
import threading

import dask

from ..errors import ParameterError

log = logging.getLogger(__name__)

CONFIG_KEY = "hevr.malloc-tuning"
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters
MMAP_THRESHOLD = 32 << 20
TRIM_THRESHOLD = 64 << 20

_DONE: list[bool] = []
_LOCK = threading.Lock()


def tune() -> bool:
    """Set this process's allocator thresholds (module docstring) once; True if they are set.

    >>> tune() in (True, False)
    True
    """
    if _DONE:
        return _DONE[0]
    value = _setting(dask.config.get(CONFIG_KEY, True))
    if not value:  # asked again next time: the setting may change
        return False
    with _LOCK:
        if not _DONE:
            _DONE.append(_set())
    return _DONE[0]


def _setting(value: object) -> bool:
    """The config value as a bool: true/false, or the strings an environment variable gives.

    >>> _setting("Off"), _setting(True), _setting("1")
    (False, True, True)
    >>> _setting("flase")
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: hevr.malloc-tuning: expected true or false, got 'flase'
    """
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().lower() in ("true", "1", "yes", "on", "false", "0", "no", "off"):
        return value.strip().lower() in ("true", "1", "yes", "on")
    raise ParameterError(f"{CONFIG_KEY}: expected true or false, got {value!r}")


def _set() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    log.debug(
        "malloc thresholds: mmap %d, trim %d bytes (%s)", MMAP_THRESHOLD, TRIM_THRESHOLD, "set" if ok else "refused"
    )
    return ok
