"""Arithmetic backends: where hevr's bulk big-integer work runs.

Every bulk modular operation — owner-side masks, the per-brick multi-exponentiation,
merging partial sums, finishing and packing, batch decryption — goes through one
:class:`~hevr.backends.base.Backend` (interface and operation counts per render mode in
:mod:`hevr.backends.base`). ``cpu`` (gmpy2, :mod:`hevr.backends.cpu`) is the default and the
reference. ``cuda-host`` (:mod:`hevr.backends.cuda.backend`) runs the CUDA backend's kernels,
compiled for the host with the C compiler on first use, on the CPU: bit-identical to ``cpu``, for
tests and for checking a machine (encryption and decryption still delegate to ``cpu``).

Choosing a backend is explicit: the ``backend=`` parameter of :func:`hevr.render`,
:func:`hevr.encrypt_volume` and :meth:`hevr.EncryptedImage.decrypt`, else the Dask config key
``hevr.backend`` (``dask.config.set({"hevr.backend": "cpu"})``, or
``DASK_HEVR__BACKEND`` in the environment), else ``"cpu"``. The client
resolves the name once and puts only the *name* into the task graph; each worker builds its
own backend instance from it.

>>> get_backend().name
'cpu'
>>> import dask
>>> with dask.config.set({"hevr.backend": "cpu"}):
...     resolve_backend_name(None)
'cpu'
>>> resolve_backend_name("abacus")
Traceback (most recent call last):
...
hevr.errors.ParameterError: backend: expected one of 'cpu', 'cuda-host', got 'abacus'
"""

from __future__ import annotations

import re
from collections.abc import Callable

import dask

from ..errors import ParameterError
from .base import Backend, OpCounter, ProductPlan
from .cpu import CpuBackend
from .cuda.backend import CudaHostBackend

__all__ = [
    "CONFIG_KEY",
    "Backend",
    "CpuBackend",
    "CudaHostBackend",
    "OpCounter",
    "ProductPlan",
    "available_backends",
    "get_backend",
    "register_backend",
    "resolve_backend_name",
]

CONFIG_KEY = "hevr.backend"
DEFAULT = "cpu"

_FACTORIES: dict[str, Callable[[], Backend]] = {"cpu": CpuBackend, "cuda-host": CudaHostBackend}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*")
_INSTANCES: dict[str, Backend] = {}


def register_backend(name: str, factory: Callable[[], Backend]) -> None:
    """Make ``factory`` (called once per process, lazily) available as backend ``name``."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ParameterError(f"name: expected a backend name (letters, digits, '_' and '-'), got {name!r}")
    _FACTORIES[name] = factory
    _INSTANCES.pop(name, None)


def available_backends() -> tuple[str, ...]:
    """Names of the registered backends."""
    return tuple(_FACTORIES)


def resolve_backend_name(backend: str | Backend | None) -> str:
    """The backend name to use: ``backend``, else the Dask config ``hevr.backend``, else ``'cpu'``."""
    if isinstance(backend, Backend):
        backend = backend.name
    name = dask.config.get(CONFIG_KEY, DEFAULT) if backend is None else backend
    if not isinstance(name, str) or name not in _FACTORIES:
        raise ParameterError(f"backend: expected one of {', '.join(repr(k) for k in _FACTORIES)}, got {name!r}")
    return name


def get_backend(backend: str | Backend | None = None) -> Backend:
    """The backend instance of this process for ``backend`` (see :func:`resolve_backend_name`)."""
    if isinstance(backend, Backend):
        return backend
    name = resolve_backend_name(backend)
    inst = _INSTANCES.get(name)
    if inst is None:
        inst = _INSTANCES[name] = _FACTORIES[name]()
    return inst
