"""The key holder's kernels on a CUDA device: owner encryption, public-key encryption, CRT decryption.

The ``owner.cuh`` kernels' launches for :class:`~hevr.backends.cuda.device.CupyLauncher`, which
compiles the module and hands each function here its kernel, CuPy and its upload (``dev``: an
array as a contiguous device array of a dtype). The tables a key needs (CRT constants, fixed-base
tables) are uploaded once per key, process and device, kept in the tables' own ``device`` dict,
so they are freed with them. On a device these kernels are used only with the launcher's
``keyholder`` set (:mod:`hevr.backends.cuda.device` says why).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .device_build import BLOCK
from .launch import decrypt_args
from .residues import Modulus

__all__ = ["decrypt", "owner_encrypt", "public_encrypt"]

Upload = Callable[[Any, Any], Any]


def _i32(x: int) -> np.int32:
    return np.int32(x)


def _i64(x: int) -> np.int64:
    return np.int64(x)


def _grid(m: int) -> tuple[int]:
    return ((m + BLOCK - 1) // BLOCK,)


def public_encrypt(cp: Any, fn: Any, dev: Upload, x: Any, r: Any, n: Any, M: Modulus) -> Any:
    """``k_public_encrypt``: ``(m, M.nl)`` normal-form ciphertexts ``(1 + x·n)·r^n mod n²`` on the device."""
    m = int(np.asarray(x).size)
    out = cp.empty((max(m, 1), M.nl), cp.uint32)
    if m:
        nd = dev(n, np.uint32)
        fn(
            _grid(m),
            (BLOCK,),
            (
                dev(x, np.int64),
                dev(r, np.uint32),
                nd,
                _i32(nd.shape[0]),
                dev(M.limbs, np.uint32),
                dev(M.one, np.uint32),
                dev(M.r2, np.uint32),
                np.uint32(M.ninv),
                _i32(M.nl),
                _i64(m),
                out,
            ),
        )
    return out[:m]


def decrypt(cp: Any, fn: Any, dev: Upload, c: Any, tables: Any) -> np.ndarray:
    """``k_decrypt``: ``(m, nlo)`` limbs of the residues in ``[0, n)``, downloaded to the host."""
    where = f"cupy-{cp.cuda.Device().id}"  # copies per device
    on = tables.device.get(where)
    if on is None:  # the CRT constants once per key, process and device
        on = tables.device[where] = {
            id(a): dev(a, np.uint32)
            for h in (tables.p, tables.q)
            for a in (h.P2.limbs, h.P2.one, h.P2.r2, h.E, h.P.limbs, h.PINV, h.HR, h.P.r2)
        } | {id(tables.PIQ): dev(tables.PIQ, np.uint32)}
    m = int(c.shape[0])
    out = cp.empty((max(m, 1), tables.nlo), cp.uint32)
    if m:
        cd = dev(c, np.uint32)
        args = decrypt_args(cd, tables, lambda a: cd if a is cd else on[id(a)], _i32, np.uint32, _i64)
        fn(_grid(m), (BLOCK,), (*args, out))
    result: np.ndarray = out[:m].get()
    return result


def owner_encrypt(cp: Any, fn: Any, dev: Upload, x: Any, a: Any, b: Any, tables: Any) -> Any:
    """``k_owner_encrypt``: ``(m, NL)`` normal-form ciphertexts of the int64 mantissas ``x`` with the
    exponents ``a``, ``b`` (``tables``: :class:`~hevr.backends.cuda.owner.OwnerTables`)."""
    where = f"cupy-{cp.cuda.Device().id}"  # copies per device
    on = tables.device.get(where)
    if on is None:  # the tables once per key, process and device (secret-derived: freed with the tables)
        on = tables.device[where] = {
            name: dev(arr, np.uint32)
            for name, arr in (
                ("Tp", tables.p.T),
                ("Pp", tables.p.P.limbs),
                ("op", tables.p.P.one),
                ("NRp", tables.p.NR),
                ("R2p", tables.p.P.r2),
                ("Tq", tables.q.T),
                ("Pq", tables.q.P.limbs),
                ("oq", tables.q.P.one),
                ("NRq", tables.q.NR),
                ("INV", tables.INV),
            )
        }
    m = int(np.asarray(x).size)
    out = cp.empty((max(m, 1), tables.NL), cp.uint32)
    ad, bd = dev(a, np.uint32), dev(b, np.uint32)
    if m:
        p, q = tables.p, tables.q
        fn(
            _grid(m),
            (BLOCK,),
            (
                dev(x, np.int64),
                ad,
                _i32(ad.shape[1]),
                bd,
                _i32(bd.shape[1]),
                on["Tp"],
                _i32(p.rows),
                _i32(p.w),
                on["Pp"],
                on["op"],
                np.uint32(p.P.ninv),
                _i32(p.P.nl),
                on["NRp"],
                on["R2p"],
                on["Tq"],
                _i32(q.rows),
                _i32(q.w),
                on["Pq"],
                on["oq"],
                np.uint32(q.P.ninv),
                _i32(q.P.nl),
                on["NRq"],
                on["INV"],
                _i32(tables.NL),
                _i64(m),
                out,
            ),
        )
    return out[:m]
