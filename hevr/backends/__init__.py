"""Arithmetic backends: where hevr's bulk big-integer work runs.

Every bulk modular operation — owner-side masks, the per-brick multi-exponentiation,
merging partial sums, finishing and packing, batch decryption — goes through one
:class:`~hevr.backends.base.Backend` (interface and operation counts per render mode in
:mod:`hevr.backends.base`). ``cpu`` (gmpy2, :mod:`hevr.backends.cpu`) is the reference, and the
default's choice (``"auto"``, below) for keys of 256 bits and more. ``cuda-host``
(:mod:`hevr.backends.cuda.registered`) runs the CUDA backend's kernels, compiled for the host with
the C compiler on first use, on the CPU: bit-identical to ``cpu``, for tests and for checking a
machine (encryption and decryption included: ``owner.cuh``). ``cuda`` runs the same kernels on an
NVIDIA GPU through CuPy (:mod:`hevr.backends.cuda.device`; ``pip install
'hevr[gpu]'``), bit-identical too; without CuPy or a device its first operation raises
:class:`hevr.MissingDependencyError`.

Choosing a backend: the ``backend=`` parameter of :func:`hevr.render`,
:meth:`hevr.EncryptedVolume.persist`, :func:`hevr.encrypt_volume` and
:meth:`hevr.EncryptedImage.decrypt`, else the Dask config key ``hevr.backend``
(``dask.config.set({"hevr.backend": "cpu"})``, or ``DASK_HEVR__BACKEND`` in the environment),
else ``"auto"``. The client resolves the name once and puts only the resolved *name* into the
task graph; each worker builds its own backend instance from it.

``"auto"`` (the default) picks by key size, where the caller knows it (renders, residency,
pyramids, re-colouring): keys below :data:`COMPILED_BELOW_BITS` (256) bits take ``cuda-host``
when this machine — and, on a cluster, every worker (asked once per scheduler) — can build its
kernels with a C compiler — there a per-product Python loop is the cost and the
compiled kernels are 2.2–6.5× faster (``benchmarks/host_kernels.py``: 64 and 128 bits) —
and everything else ``cpu``, whose gmpy2 is as fast from 256 bits and faster above 1024. A
render of a resident volume under ``"auto"`` takes the residency's own backend, so a volume
persisted with an explicit backend is never streamed for want of one. Both give the same bytes
(every backend gives the identical image), so ``"auto"`` changes speed, never results.

>>> get_backend().name
'cpu'
>>> resolve_backend_name(None, bits=2048)
'cpu'
>>> import dask
>>> with dask.config.set({"hevr.backend": "cpu"}):
...     resolve_backend_name(None, bits=64)
'cpu'
>>> resolve_backend_name("abacus")
Traceback (most recent call last):
...
hevr.errors.ParameterError: backend: expected 'auto' or one of 'cpu', 'cuda-host', 'cuda', got 'abacus'
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from typing import Any

import dask

from ..errors import MissingDependencyError, ParameterError
from .base import Backend, OpCounter, ProductPlan
from .cpu import CpuBackend
from .cuda.registered import CudaBackend, CudaHostBackend

__all__ = [
    "AUTO",
    "COMPILED_BELOW_BITS",
    "CONFIG_KEY",
    "Backend",
    "CpuBackend",
    "CudaBackend",
    "CudaHostBackend",
    "OpCounter",
    "ProductPlan",
    "available_backends",
    "check_backend",
    "get_backend",
    "register_backend",
    "resolve_backend_name",
]

log = logging.getLogger(__name__)

CONFIG_KEY = "hevr.backend"
AUTO = "auto"
DEFAULT = AUTO
COMPILED = "cuda-host"  # the compiled host kernels
COMPILED_BELOW_BITS = 256

_FACTORIES: dict[str, Callable[[], Backend]] = {"cpu": CpuBackend, "cuda-host": CudaHostBackend, "cuda": CudaBackend}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*")
_INSTANCES: dict[str, Backend] = {}
_COMPILED_OK: list[bool] = []  # whether this process built the compiled kernels (checked once)
_WORKERS_OK: dict[str, bool] = {}  # scheduler address -> whether every worker built them


def register_backend(name: str, factory: Callable[[], Backend]) -> None:
    """Make ``factory`` (called once per process, lazily) available as backend ``name``."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ParameterError(f"name: expected a backend name (letters, digits, '_' and '-'), got {name!r}")
    _FACTORIES[name] = factory
    _INSTANCES.pop(name, None)


def available_backends() -> tuple[str, ...]:
    """Names of the registered backends."""
    return tuple(_FACTORIES)


def resolve_backend_name(
    backend: str | Backend | None, bits: int | None = None, resident: str | None = None, client: Any = None
) -> str:
    """The backend name to use: ``backend``, else the Dask config ``hevr.backend``, else ``'auto'``.

    ``'auto'`` (module docstring) resolves to ``resident`` — the backend of the volume's
    residency, when a render has one — else to ``'cuda-host'`` for a key of fewer than
    :data:`COMPILED_BELOW_BITS` ``bits`` when the compiled kernels build here and on every
    worker of ``client`` (a distributed client, or None), else ``'cpu'`` (also when ``bits`` is
    not known).
    """
    if isinstance(backend, Backend):
        backend = backend.name
    name = dask.config.get(CONFIG_KEY, DEFAULT) if backend is None else backend
    if name == AUTO:
        if resident in _FACTORIES:
            return resident
        small = bits is not None and bits < COMPILED_BELOW_BITS
        return COMPILED if small and _compiled_ok() and (client is None or _workers_ok(client)) else "cpu"
    if not isinstance(name, str) or name not in _FACTORIES:
        raise ParameterError(
            f"backend: expected {AUTO!r} or one of {', '.join(repr(k) for k in _FACTORIES)}, got {name!r}"
        )
    return name


def _compiled_ok() -> bool:
    """Whether the compiled host kernels build and load in this process (tried once)."""
    if not _COMPILED_OK:
        try:
            be = get_backend(COMPILED)
            if hasattr(be, "check"):
                be.check()  # compiled once per machine, cached on disk
            _COMPILED_OK.append(True)
        except (MissingDependencyError, OSError) as exc:  # no compiler; a temp folder mounted noexec, ...
            log.info("backend auto: %s; small keys use the cpu backend", exc)
            _COMPILED_OK.append(False)
    return _COMPILED_OK[0]


def _workers_ok(client: Any) -> bool:
    """Whether every worker of ``client`` builds the compiled kernels (asked once per scheduler:
    a worker without a C compiler would fail every task of a ``cuda-host`` render)."""
    key = str(getattr(getattr(client, "scheduler", None), "address", None) or id(client))
    if key not in _WORKERS_OK:
        try:
            got = client.run(_compiled_ok)
            ok = bool(got) and all(got.values())
        except Exception as exc:  # noqa: BLE001 - a worker that cannot answer: the safe choice
            log.info("backend auto: could not ask the workers (%s); small keys use the cpu backend", exc)
            ok = False
        if not ok:
            log.info("backend auto: not every worker builds the compiled kernels; small keys use the cpu backend")
        _WORKERS_OK[key] = ok
    return _WORKERS_OK[key]


def get_backend(backend: str | Backend | None = None) -> Backend:
    """The backend instance of this process for ``backend`` (see :func:`resolve_backend_name`)."""
    if isinstance(backend, Backend):
        return backend
    name = resolve_backend_name(backend)
    inst = _INSTANCES.get(name)
    if inst is None:
        inst = _INSTANCES[name] = _FACTORIES[name]()
    return inst


def check_backend(name: str, client: Any = None) -> None:
    """Make sure backend ``name`` works in this process before any work is written, when the work
    runs here (``client`` is None; a cluster's workers answer for themselves): CuPy and a device
    for ``cuda``, a C compiler for ``cuda-host``.

    Raises
    ------
    MissingDependencyError
        What the backend needs and this machine lacks.
    """
    if client is None:
        be = get_backend(name)
        if hasattr(be, "check"):
            be.check()
