"""The host build of the CUDA kernel source ``mont.cuh``: compiled with the C compiler, called
through ctypes, checked against gmpy2 by the tests.

Montgomery form (the source's comment has the algorithm). For an odd modulus N of ``NL = ceil(bits/32)``
limbs and R = 2^(32·NL):

* ``mont_mul(a, b) = a·b·R^-1 mod N`` (CIOS), for a, b < N;
* ``to_mont(x) = mont_mul(x, R² mod N) = x·R mod N`` and ``from_mont(y) = mont_mul(y, 1)``;
* so ``from_mont(mont_mul(to_mont(a), to_mont(b))) = a·b mod N``: a chain of products stays in
  Montgomery form and converts once at each end — how a GPU backend keeps residues on the device.

>>> m = HostMontgomery(1_000_003)          # an odd modulus
>>> m.modmul([123456, 0, 1_000_002], [654321, 5, 1_000_002])
[611039, 0, 1]
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import platform
import shutil
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...errors import MissingDependencyError, ParameterError
from . import kernel_cache

log = logging.getLogger(__name__)

__all__ = [
    "HostMontgomery",
    "build_host",
    "build_library",
    "check_defines",
    "from_limbs",
    "montgomery_params",
    "source",
    "to_limbs",
]

SOURCE = Path(__file__).with_name("mont.cuh")
MAX_LIMBS = 128  # HEVR_MAX_LIMBS in the source: 4096-bit moduli (n² of a 2048-bit key)
FLAGS = ("-O3", "-shared", "-fPIC", "-x", "c", "-std=c99")  # portable: no -march, so a cached build runs anywhere
_LIB: dict[str, ctypes.CDLL] = {}
_BUILD = threading.Lock()  # the threads of one worker build once


def source() -> str:
    """The kernel source (CUDA C; host-compilable)."""
    return SOURCE.read_text(encoding="utf-8")


def build_library(
    main: Path, headers: Sequence[Path] = (), compiler: str | None = None, defines: Sequence[str] = ()
) -> ctypes.CDLL:
    """Compile a kernel source for the host once per process and load it through ctypes.

    The shared library is cached on disk (a private folder in the temporary directory) under the
    hash of the source, the headers it includes and the compiler flags, so an edited source is
    rebuilt and an unchanged one is compiled once per machine; a cached library is checked
    against its digest before it is loaded, and the compiler has a time limit
    (:mod:`hevr.backends.cuda.kernel_cache`).

    Parameters
    ----------
    main : pathlib.Path
        The source to compile (its quoted ``#include`` lines resolve beside it).
    headers : sequence of pathlib.Path
        The files it includes: part of the hash.
    compiler : str, optional
        The C compiler; default ``$CC``, else ``cc`` or ``gcc`` on PATH.
    defines : sequence of str
        Preprocessor names to define (``-D``), e.g. ``("HEVR_CIOS_REG",)``: part of the hash.

    Raises
    ------
    MissingDependencyError
        No C compiler (``cc``/``gcc``, or ``$CC``) on this machine, or it cannot build the source
        (fails, writes no loadable library, or runs past ``hevr.limits.compile-seconds``).
    """
    texts = [main.read_text(encoding="utf-8")] + [h.read_text(encoding="utf-8") for h in headers]
    cc = compiler or os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or ""
    # the machine and the compiler too: a cache folder seen by other hosts or compilers never serves a foreign build
    flags = (*FLAGS, *(f"-D{d}" for d in check_defines(defines)))
    digest = hashlib.sha256(
        "\0".join(texts + list(flags) + [platform.machine(), platform.system(), cc]).encode()
    ).hexdigest()[:16]
    key = f"{main.stem}-{digest}"
    with _BUILD:
        if key not in _LIB:
            _LIB[key] = _compile(main, key, compiler, flags)
        return _LIB[key]


def check_defines(defines: Sequence[str]) -> tuple[str, ...]:
    """Preprocessor names for ``-D`` (letters, digits, underscores; no value), as a tuple.

    >>> check_defines(["HEVR_CIOS_REG"])
    ('HEVR_CIOS_REG',)
    """
    if isinstance(defines, (str, bytes)):  # one name would otherwise become one define per letter
        raise ParameterError(f"defines: expected a sequence of preprocessor names, got the string {defines!r}")
    out = tuple(defines)
    for name in out:
        if not isinstance(name, str) or not name.isidentifier() or not name.isascii():
            raise ParameterError(f"defines: expected preprocessor names like 'HEVR_CIOS_REG', got {name!r}")
    return out


def _compile(main: Path, key: str, compiler: str | None, flags: Sequence[str] = FLAGS) -> ctypes.CDLL:
    cc = compiler or os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        raise MissingDependencyError(
            "compiler: expected a C compiler (cc, gcc or $CC) to build the kernel source for the host, got none on PATH"
        )
    return kernel_cache.load(main, key, cc, flags)


def build_host(compiler: str | None = None) -> ctypes.CDLL:
    """The host build of ``mont.cuh`` (:func:`build_library`), its batch product declared.

    Raises
    ------
    MissingDependencyError
        No C compiler (``cc``/``gcc``, or ``$CC``) on this machine.
    """
    dll = build_library(SOURCE, (), compiler)
    u32p = ctypes.POINTER(ctypes.c_uint32)
    dll.hevr_mont_mul_batch.argtypes = [u32p, u32p, u32p, ctypes.c_uint32, ctypes.c_int, ctypes.c_longlong, u32p]
    dll.hevr_mont_mul_batch.restype = ctypes.c_int
    return dll


def montgomery_params(n: int) -> tuple[int, int, int]:
    """``(NL, ninv, R² mod n)`` of an odd modulus: limbs, ``−n^-1 mod 2^32`` and the conversion constant.

    >>> montgomery_params(2**61 - 1)
    (2, 1, 64)
    """
    n = int(n)
    if n < 3 or n % 2 == 0:
        raise ParameterError(f"n: expected an odd modulus >= 3, got {'an even number' if n > 0 else n}")
    nl = -(-n.bit_length() // 32)
    if nl > MAX_LIMBS:
        raise ParameterError(f"n: expected at most {32 * MAX_LIMBS} bits, got {n.bit_length()}")
    ninv = (-pow(n, -1, 1 << 32)) % (1 << 32)
    return nl, ninv, pow(1 << (32 * nl), 2, n)


def to_limbs(values: Sequence[int], nl: int) -> np.ndarray:
    """Integers in ``[0, 2^(32·nl))`` as a (count, nl) uint32 array, little-endian limbs.

    >>> to_limbs([2**32 + 5], 2).tolist()
    [[5, 1]]
    """
    raw = b"".join(int(v).to_bytes(4 * nl, "little") for v in values)
    return np.frombuffer(raw, dtype="<u4").reshape(len(values), nl).astype(np.uint32)


def from_limbs(arr: np.ndarray) -> list[int]:
    """The inverse of :func:`to_limbs`."""
    arr = np.ascontiguousarray(arr, dtype="<u4")
    return [int.from_bytes(row.tobytes(), "little") for row in arr]


class HostMontgomery:
    """Montgomery arithmetic modulo ``n`` with the host build of the kernel source (for tests)."""

    def __init__(self, n: int) -> None:
        self.n = int(n)
        self.nl, self.ninv, self.r2 = montgomery_params(self.n)
        self._lib = build_host()
        self._n = to_limbs([self.n], self.nl)[0]

    def mont_mul(self, a: Sequence[int], b: Sequence[int]) -> list[int]:
        """``a_k·b_k·R^-1 mod n`` for every k (each operand in [0, n))."""
        if len(a) != len(b):
            raise ParameterError(f"b: expected {len(a)} operands like a, got {len(b)}")
        for name, vals in (("a", a), ("b", b)):
            bad = next((v for v in vals if not 0 <= int(v) < self.n), None)
            if bad is not None:
                raise ParameterError(f"{name}: expected operands in [0, n), got one of {int(bad).bit_length()} bits")
        A, B = to_limbs(a, self.nl), to_limbs(b, self.nl)
        out = np.zeros_like(A)
        p = ctypes.POINTER(ctypes.c_uint32)
        rc = self._lib.hevr_mont_mul_batch(
            A.ctypes.data_as(p),
            B.ctypes.data_as(p),
            self._n.ctypes.data_as(p),
            self.ninv,
            self.nl,
            len(a),
            out.ctypes.data_as(p),
        )
        if rc != 0:  # pragma: no cover - montgomery_params bounds nl
            raise ParameterError(f"n: the kernel refused {self.nl} limbs")
        return from_limbs(out)

    def to_mont(self, x: Sequence[int]) -> list[int]:
        return self.mont_mul(x, [self.r2] * len(x))

    def from_mont(self, y: Sequence[int]) -> list[int]:
        return self.mont_mul(y, [1] * len(y))

    def modmul(self, a: Sequence[int], b: Sequence[int]) -> list[int]:
        """``a_k·b_k mod n`` through Montgomery form (three conversions, one product)."""
        return self.from_mont(self.mont_mul(self.to_mont(a), self.to_mont(b)))
