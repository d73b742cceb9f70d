"""Launchers: how the kernels of ``render.cuh`` are run on a batch.

One small interface (:class:`Launcher`): each method runs one kernel over all its items and
returns new arrays. The backend above it (:mod:`hevr.backends.cuda.backend`: batching, plan
tables, Montgomery bookkeeping) is shared by every launcher.

* :class:`HostLauncher` — the source compiled for the host with the C compiler
  (:func:`hevr.backends.cuda.host.build_library`, ``-O3``, cached by the source hash) and
  called through ctypes on numpy buffers; each ``*_host`` entry point is a loop over the items
  of the same per-item function the CUDA kernel runs per thread.
* a CuPy launcher (NVRTC, device arrays, the ``k_*`` kernels) — later, on a GPU machine.

The library is built on the first kernel call, not when a launcher is made: registering and
creating the backend compiles nothing.

>>> import numpy as np
>>> from hevr.backends.cuda.residues import Modulus
>>> L, M = HostLauncher(), Modulus(1_000_003)
>>> L.records_to_limbs(np.array([[1, 2]], np.uint8), 1)[0].tolist()
[[258]]
>>> L.mont_convert(L.mont_convert(np.array([[12345]], np.uint32), M.r2, M), M.unit, M).tolist()
[[12345]]
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np

from ...errors import ParameterError
from .host import SOURCE as MONT_SOURCE
from .host import build_library, check_defines
from .residues import FOLD, Modulus, PlanTables

__all__ = ["OWNER_SOURCE", "RENDER_SOURCE", "HostLauncher", "Launcher"]

RENDER_SOURCE = Path(__file__).with_name("render.cuh")
OWNER_SOURCE = Path(__file__).with_name("owner.cuh")

_P, _I, _LL, _U32 = ctypes.c_void_p, ctypes.c_int, ctypes.c_longlong, ctypes.c_uint32
_Args: TypeAlias = "list[type[ctypes._SimpleCData[Any]]]"  # a C function's argtypes
_MOD: _Args = [_P, _P, _U32, _I]  # n, one, ninv, nl
_SIGNATURES: dict[str, _Args] = {
    "hevr_records_to_limbs_host": [_P, _I, _I, _LL, _P, _P],
    "hevr_limbs_to_records_host": [_P, _I, _I, _LL, _P, _P],
    "hevr_out_of_range_host": [_P, _P, _I, _LL, _P],
    "hevr_mont_convert_host": [_P, _P, _P, _U32, _I, _LL, _P],
    "hevr_ray_powers_host": [_P, _P, _P, _P, _I, _LL, _P, *_MOD],
    "hevr_ray_tasks_host": [_P, _LL, _LL, _P, _P, _P, _P, _P, _P, _I, _P, _P, _P, _LL, _P, _P, *_MOD],
    "hevr_segments_host": [_P, _P, _I, _LL, _P, *_MOD],
    "hevr_combine_host": [_P, _I, _I, _P, _I, _LL, _LL, _P, _P, *_MOD],
    "hevr_pack_host": [_P, _P, _I, _LL, _I, _I, _P, _LL, _P, *_MOD],
}
_HALF: _Args = [_P, _I, _I, _P, _P, _U32, _I, _P]  # T, rows, w, P, one, ninv, nl, NR
# x, a, ka, b, kb, p half, R2p, q half, INV, NL, count, out
_OWNER_SIGNATURE: _Args = [_P, _P, _I, _P, _I, *_HALF, _P, *_HALF, _P, _I, _LL, _P]
# P2, one2, R2, ninv2, nl2, E, ew, P, PINV, HR, ninv, k
_DHALF: _Args = [_P, _P, _P, _U32, _I, _P, _I, _P, _P, _P, _U32, _I]
_DECRYPT_SIGNATURE: _Args = [_P, _I, *_DHALF, *_DHALF, _P, _P, _I, _LL, _P]  # ..., R2Q, PIQ, nlo, count, out
# x, r, n, k, N, one, R2, ninv, NL, count, out
_PUBLIC_SIGNATURE: _Args = [_P, _P, _P, _I, _P, _P, _P, _U32, _I, _LL, _P]


def decrypt_args(c: Any, tables: Any, pointer: Any, i32: Any, u32: Any, i64: Any) -> list:
    """The arguments of ``k_decrypt`` / ``hevr_decrypt_host`` in order, each through the launcher's
    own marshalling (``pointer`` for arrays, ``i32``/``u32``/``i64`` for scalars)."""
    args = [pointer(c), i32(tables.NL)]
    for h in (tables.p, tables.q):
        args += [
            pointer(h.P2.limbs),
            pointer(h.P2.one),
            pointer(h.P2.r2),
            u32(h.P2.ninv),
            i32(h.P2.nl),
            pointer(h.E),
            i32(h.E.size),
            pointer(h.P.limbs),
            pointer(h.PINV),
            pointer(h.HR),
            u32(h.P.ninv),
            i32(h.P.nl),
        ]
    return args + [pointer(tables.q.P.r2), pointer(tables.PIQ), i32(tables.nlo), i64(c.shape[0])]


def _p(arr: np.ndarray | None) -> int | None:
    """The address of a C-contiguous array (None: a NULL pointer)."""
    if arr is None:
        return None
    if not arr.flags.c_contiguous:  # pragma: no cover - every caller passes contiguous arrays
        raise ParameterError("kernel argument: expected a C-contiguous array")
    return arr.ctypes.data


def _mod(M: Modulus) -> tuple:
    return _p(M.limbs), _p(M.one), M.ninv, M.nl


class Launcher:
    """The kernels of ``render.cuh`` over whole batches (arrays in, new arrays out).

    Limb arrays are ``(m, nl)`` uint32, C-contiguous; every Montgomery operand is in
    ``[0, M.n)`` and every result is too. See the source's header for what each item computes.

    ``keyholder``: whether the backend sends the key holder's work (encryption, decryption) to this
    launcher's ``owner.cuh`` kernels; where False it goes the CPU way, byte for byte the same.
    """

    keyholder = True
    # Where this launcher's limb arrays live: "host" (numpy) or "device" (its own arrays, which
    # stay there between operations: a resident brick in Montgomery form is uploaded once).
    residence = "host"
    # Operations of fewer independent items than this run on gmpy2 (KernelBackend._few); the host
    # build always runs its kernels (the CI's check of them).
    min_items = 0

    # -- where arrays live: every operation takes numpy or this launcher's arrays and returns its own
    # (flags, counts, records and decrypted residues come back as numpy: the host reads them)
    def host(self, limbs: Any) -> np.ndarray:
        """A numpy array of one of this launcher's arrays (a download on a device)."""
        return np.asarray(limbs)

    def join(self, arrays: list, nl: int) -> Any:
        """The rows of ``arrays`` in order, each zero-extended to ``nl`` limbs (each at most ``nl``).

        >>> HostLauncher().join([np.ones((1, 1), np.uint32), np.full((1, 2), 2, np.uint32)], 2).tolist()
        [[1, 0], [2, 2]]
        """
        out = np.zeros((sum(int(a.shape[0]) for a in arrays), nl), np.uint32)
        r = 0
        for a in arrays:
            out[r : r + a.shape[0], : a.shape[1]] = self.host(a)
            r += a.shape[0]
        return out

    def take(self, limbs: Any, index: np.ndarray) -> Any:
        """Rows ``index`` (int64, in range) of ``limbs``, as a new array."""
        return np.ascontiguousarray(np.asarray(limbs)[index])

    def rows(self, vals: Any, rep: np.ndarray, fill: np.ndarray) -> Any:
        """Row ``i`` is ``vals[rep[i]]``, or ``fill`` where ``rep[i] < 0`` (a plan's empty rows).

        >>> vals, fill = np.array([[7], [8]], np.uint32), np.array([1], np.uint32)
        >>> HostLauncher().rows(vals, np.array([1, -1, 0]), fill).tolist()
        [[8], [1], [7]]
        """
        out = np.empty((rep.size, vals.shape[1]), np.uint32)  # one allocation, one gather (the hot path)
        empty = rep < 0
        out[~empty] = vals[rep[~empty]]
        out[empty] = fill
        return out

    def memory(self) -> tuple[int, int] | None:
        """(free, total) bytes of the device memory residues live in; None on the host."""
        return None

    def frame_bytes(self, resident: int) -> int:
        """Device bytes a frame needs beside ``resident`` bytes of resident residues (0 on the host)."""
        return 0

    def with_defines(self, defines: tuple[str, ...]) -> Launcher:
        """A launcher of the same kind whose modules are compiled with ``defines`` (``-D``)."""
        raise NotImplementedError

    def device_tables(self, t: PlanTables) -> PlanTables:
        """``t`` with the arrays the kernels read already where they run (uploaded once: the
        benchmark's kernels-alone timing); on the host, ``t`` itself."""
        return t

    def records_to_limbs(self, records: np.ndarray, nl: int) -> tuple[np.ndarray, np.ndarray]:
        """(limbs, overflow flags) of (m, W) big-endian uint8 records."""
        raise NotImplementedError

    def limbs_to_records(self, limbs: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
        """((m, width) uint8 records, overflow flags) of normal-form limbs."""
        raise NotImplementedError

    def out_of_range(self, limbs: np.ndarray, upper: np.ndarray | None) -> np.ndarray:
        """Per value 1 unless ``0 < x < upper`` (``upper`` None: unless ``x != 0``)."""
        raise NotImplementedError

    def mont_convert(self, limbs: np.ndarray, b: np.ndarray, M: Modulus) -> np.ndarray:
        """``x·b·R^-1 mod N`` per value: to Montgomery form with ``b = M.r2``, back with ``M.unit``."""
        raise NotImplementedError

    def ray_products(self, t: PlanTables, cts: np.ndarray, shared_w: int, M: Modulus) -> tuple[np.ndarray, np.ndarray]:
        """(per task its product, per task (products, squarings, powmod bits)) for one component."""
        raise NotImplementedError

    def segments(self, vals: np.ndarray, indptr: np.ndarray, k: int, M: Modulus) -> np.ndarray:
        """Per segment and component the product of the segment's rows of ``k`` values."""
        raise NotImplementedError

    def combine(self, vals: np.ndarray, k: int, E: np.ndarray, M: Modulus) -> np.ndarray:
        """Per row of ``k`` values and channel ``ch``: ``Π_i v_i^E[ch, i]`` (E: (C, k, ew) words)."""
        raise NotImplementedError

    def pack(
        self, terms: np.ndarray, R: np.ndarray, per_pack: int, bits: int, offs: np.ndarray | None, M: Modulus
    ) -> np.ndarray:
        """Per group of ``per_pack`` terms the Horner packing; ``offs``: the offset factors of a full
        group and of a shorter last one (Montgomery), or None."""
        raise NotImplementedError

    def owner_encrypt(self, x: np.ndarray, a: np.ndarray, b: np.ndarray, tables: Any) -> np.ndarray:
        """``(m, NL)`` normal-form ciphertexts of the int64 mantissas ``x`` with exponents ``a``, ``b``
        (``owner.cuh``; ``tables``: :class:`~hevr.backends.cuda.owner.OwnerTables`)."""
        raise NotImplementedError

    def public_encrypt(self, x: np.ndarray, r: np.ndarray, n: np.ndarray, M: Modulus) -> np.ndarray:
        """``(m, M.nl)`` normal-form ciphertexts ``(1 + x·n)·r^n mod n²`` (``M`` the modulus n², ``n``
        and each row of ``r`` as ``n``'s limbs; ``owner.cuh``)."""
        raise NotImplementedError

    def decrypt(self, c: np.ndarray, tables: Any) -> np.ndarray:
        """``(m, nlo)`` limbs of the residues in ``[0, n)`` of normal-form ciphertexts ``c`` ``(m, NL)``
        (``owner.cuh``; ``tables``: :class:`~hevr.backends.cuda.owner.DecryptTables`)."""
        raise NotImplementedError


class HostLauncher(Launcher):
    """The kernels compiled for the host and called through ctypes (see the module docstring)."""

    def __init__(self, compiler: str | None = None, defines: tuple[str, ...] = ()) -> None:
        self._compiler, self._defines = compiler, check_defines(defines)
        self._dll: ctypes.CDLL | None = None
        self._owner_dll: ctypes.CDLL | None = None

    def __reduce__(self):
        return (HostLauncher, (self._compiler, self._defines))

    def with_defines(self, defines):
        return HostLauncher(self._compiler, defines)

    @property
    def lib(self) -> ctypes.CDLL:
        """The host build (compiled on first use; MissingDependencyError without a C compiler)."""
        if self._dll is None:
            dll = build_library(RENDER_SOURCE, (MONT_SOURCE,), self._compiler, self._defines)
            for name, args in _SIGNATURES.items():
                fn = getattr(dll, name)
                fn.argtypes, fn.restype = args, ctypes.c_int
            self._dll = dll
        return self._dll

    def _call(self, name: str, *args) -> None:
        if getattr(self.lib, name)(*args) != 0:  # pragma: no cover - Modulus bounds nl
            raise ParameterError(f"nl: the kernel {name} refused the limb count")

    @property
    def owner_lib(self) -> ctypes.CDLL:
        """The host build of ``owner.cuh`` (compiled on first use)."""
        if self._owner_dll is None:
            dll = build_library(OWNER_SOURCE, (MONT_SOURCE,), self._compiler, self._defines)
            dll.hevr_owner_encrypt_host.argtypes, dll.hevr_owner_encrypt_host.restype = _OWNER_SIGNATURE, ctypes.c_int
            dll.hevr_decrypt_host.argtypes, dll.hevr_decrypt_host.restype = _DECRYPT_SIGNATURE, ctypes.c_int
            dll.hevr_public_encrypt_host.argtypes = _PUBLIC_SIGNATURE
            dll.hevr_public_encrypt_host.restype = ctypes.c_int
            self._owner_dll = dll
        return self._owner_dll

    def decrypt(self, c, tables):
        c = np.ascontiguousarray(c, dtype=np.uint32)
        out = np.empty((c.shape[0], tables.nlo), np.uint32)
        ident = int  # ctypes converts Python ints by the declared argtypes
        args = decrypt_args(c, tables, _p, ident, ident, ident)
        if self.owner_lib.hevr_decrypt_host(*args, _p(out)) != 0:  # pragma: no cover - limbs bounded by Modulus
            raise ParameterError("nl: the decryption kernel refused the limb counts")
        return out

    def public_encrypt(self, x, r, n, M):
        x, r = np.ascontiguousarray(x, dtype=np.int64), np.ascontiguousarray(r, dtype=np.uint32)
        n = np.ascontiguousarray(n, dtype=np.uint32)
        out = np.empty((x.size, M.nl), np.uint32)
        if (
            self.owner_lib.hevr_public_encrypt_host(
                _p(x), _p(r), _p(n), n.size, _p(M.limbs), _p(M.one), _p(M.r2), M.ninv, M.nl, x.size, _p(out)
            )
            != 0
        ):
            raise ParameterError("nl: the encryption kernel refused the limb counts")  # pragma: no cover
        return out

    def owner_encrypt(self, x, a, b, tables):
        x = np.ascontiguousarray(x, dtype=np.int64)
        a, b = np.ascontiguousarray(a, dtype=np.uint32), np.ascontiguousarray(b, dtype=np.uint32)
        out = np.empty((x.size, tables.NL), np.uint32)
        halves = [
            [_p(h.T), h.rows, h.w, _p(h.P.limbs), _p(h.P.one), h.P.ninv, h.P.nl, _p(h.NR)] for h in (tables.p, tables.q)
        ]
        if (
            self.owner_lib.hevr_owner_encrypt_host(
                _p(x),
                _p(a),
                a.shape[1],
                _p(b),
                b.shape[1],
                *halves[0],
                _p(tables.p.P.r2),
                *halves[1],
                _p(tables.INV),
                tables.NL,
                x.size,
                _p(out),
            )
            != 0
        ):
            raise ParameterError("nl: the owner kernel refused the limb counts")  # pragma: no cover
        return out

    def records_to_limbs(self, records, nl):
        rec = np.ascontiguousarray(records, dtype=np.uint8)
        m, width = rec.shape
        x, over = np.empty((m, nl), np.uint32), np.empty(m, np.uint8)
        self._call("hevr_records_to_limbs_host", _p(rec), width, nl, m, _p(x), _p(over))
        return x, over

    def limbs_to_records(self, limbs, width):
        x = np.ascontiguousarray(limbs, dtype=np.uint32)
        m, nl = x.shape
        rec, over = np.empty((m, width), np.uint8), np.empty(m, np.uint8)
        self._call("hevr_limbs_to_records_host", _p(x), nl, width, m, _p(rec), _p(over))
        return rec, over

    def out_of_range(self, limbs, upper):
        x = np.ascontiguousarray(limbs, dtype=np.uint32)
        bad = np.empty(x.shape[0], np.uint8)
        self._call("hevr_out_of_range_host", _p(x), _p(upper), x.shape[1], x.shape[0], _p(bad))
        return bad

    def mont_convert(self, limbs, b, M):
        x = np.ascontiguousarray(limbs, dtype=np.uint32)
        out = np.empty_like(x)
        self._call("hevr_mont_convert_host", _p(x), _p(b), _p(M.limbs), M.ninv, M.nl, x.shape[0], _p(out))
        return out

    def ray_products(self, t, cts, shared_w, M):
        nl = M.nl
        pw = np.empty((max(1, t.pw_rows), nl), np.uint32)
        if t.pre_v.size:
            self._call(
                "hevr_ray_powers_host",
                _p(cts),
                _p(t.pre_v),
                _p(t.pre_j),
                _p(t.pre_start),
                shared_w,
                t.pre_v.size,
                _p(pw),
                *_mod(M),
            )
        T = t.tasks.shape[0]
        vals, counts = np.empty((T, nl), np.uint32), np.zeros((T, 3), np.int64)
        buckets, used = np.empty((t.slot, nl), np.uint32), np.empty(t.slot, np.uint8)
        self._call(
            "hevr_ray_tasks_host",
            _p(t.tasks),
            0,
            T,
            _p(cts),
            _p(pw),
            _p(t.pw_off),
            _p(t.pw_n),
            _p(t.vl),
            _p(t.wl),
            shared_w,
            _p(FOLD),
            _p(buckets),
            _p(used),
            t.slot,
            _p(vals),
            _p(counts),
            *_mod(M),
        )
        return vals, counts

    def segments(self, vals, indptr, k, M):
        ip = np.ascontiguousarray(indptr, dtype=np.int64)
        count = (ip.size - 1) * k
        out = np.empty((count, M.nl), np.uint32)
        self._call("hevr_segments_host", _p(vals), _p(ip), k, count, _p(out), *_mod(M))
        return out

    def combine(self, vals, k, E, M):
        C, _, ew = E.shape
        rows = vals.shape[0] // k
        sub = np.empty(((1 << k) if k <= 8 else 1, M.nl), np.uint32)
        out = np.empty((rows * C, M.nl), np.uint32)
        self._call("hevr_combine_host", _p(vals), k, C, _p(E), ew, 0, rows, _p(sub), _p(out), *_mod(M))
        return out

    def pack(self, terms, R, per_pack, bits, offs, M):
        m, ew = R.shape
        groups = -(-m // per_pack)
        out = np.empty((groups, M.nl), np.uint32)
        self._call("hevr_pack_host", _p(terms), _p(R), ew, m, per_pack, bits, _p(offs), groups, _p(out), *_mod(M))
        return out
