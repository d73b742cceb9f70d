"""Locate a GPU-only wrong result in the key holder's kernels (owner.cuh) against Python references.

Run on the GPU machine (``bash benchmarks/gpu-proof.sh diagnose``). Per key (unbalanced 33/95-bit
primes, 60/68, 512, 2048 bits), each step checked against plain Python integers, never against
another kernel:

* ``tables``  — the fixed-base tables converted to Montgomery form by the device (``k_mont_convert``)
  against ``e·R mod P``;
* ``owner``   — owner encryption on the device, with tables converted in Python, decrypted by ``cpu``;
* ``owner+devtables`` — the same with the device's own tables (what a user runs);
* ``repeat``  — the same launch twice (a race would differ);
* ``public``  — public-key encryption on the device, decrypted by ``cpu``;
* ``decrypt`` — CRT decryption on the device of ``cpu`` ciphertexts.

and each variant of the module's compilation: as shipped, without ``__restrict__``, with ``-G``
(no device optimisation). Prints one line per (variant, key, step): wrong / total and the first
wrong indices. Exit status 0 always: it is a diagnosis, the tests are the verdict.
"""

from __future__ import annotations

import os
import sys
import time
import warnings

import gmpy2
import numpy as np

import hevr
from hevr.backends import CpuBackend
from hevr.backends.cuda import device as device_module
from hevr.backends.cuda import owner as owner_module
from hevr.backends.cuda.device import CupyLauncher
from hevr.backends.cuda.host import from_limbs, to_limbs

CPU = CpuBackend()
_REF: dict = {}


class PyConvert:
    """mont_convert in Python integers (the tables' reference)."""

    def mont_convert(self, limbs, b, M):
        R_inv = pow(1 << (32 * M.nl), -1, M.n)
        bb = from_limbs(np.asarray(b).reshape(1, -1))[0]
        return to_limbs([v * bb * R_inv % M.n for v in from_limbs(limbs)], M.nl)


def _key(pbits: int, qbits: int):
    if pbits == qbits:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
            return hevr.generate_keypair(2 * pbits)
    p, q = int(gmpy2.next_prime(2 ** (pbits - 1) + 12345)), int(gmpy2.next_prime(2 ** (qbits - 1) + 987654))
    pub = hevr.PublicKey(p * q)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        return pub, hevr.PrivateKey(pub, p, q)


def _report(variant: str, label: str, step: str, got: list[int], want: list[int], extra: str = "") -> None:
    bad = [i for i, (g, w) in enumerate(zip(got, want)) if g != w]
    print(f"{variant:10s} {label:8s} {step:16s} wrong {len(bad):5d}/{len(want):5d} first {bad[:6]} {extra}", flush=True)


def _records(limbs: np.ndarray, n: int):
    return CPU.from_bytes(CPU.to_bytes(from_limbs(limbs), 2 * ((n.bit_length() + 7) // 8)))


def check(launcher: CupyLauncher, variant: str, label: str, pub, priv, count: int) -> None:
    n = int(pub.n)
    x = (np.arange(count, dtype=np.int64) - count // 2) * 7919
    x[:4] = [0, 1, -1, -2]
    want = [int(v) % n for v in x.tolist()]
    if n not in _REF:  # the Python reference tables once per key (seconds at 2048 bits)
        owner_module._CACHE.clear()
        _REF[n] = owner_module.owner_tables(priv, PyConvert())
    ref = _REF[n]
    owner_module._CACHE.clear()
    dev = owner_module.owner_tables(priv, launcher)
    owner_module._CACHE.clear()
    for half in ("p", "q") if ref is not None else ():
        a_, b_ = getattr(ref, half).T, getattr(dev, half).T
        bad = np.flatnonzero((a_ != b_).any(axis=1))
        print(f"{variant:10s} {label:8s} tables {half:9s} wrong {bad.size:5d}/{a_.shape[0]:5d} first {bad[:6].tolist()} "
              f"(w={getattr(ref, half).w}, rows={getattr(ref, half).rows}, nl={getattr(ref, half).P.nl})", flush=True)
    if ref is None:
        print(f"{variant:10s} {label:8s} owner: no tables for this key (the cpu path)", flush=True)
    for step in ("owner", "public", "decrypt"):
        if step == "owner" and ref is None:
            continue
        try:
            STEPS[step](launcher, variant, label, pub, priv, x, want, ref, dev)
        except Exception as exc:  # noqa: BLE001 - a diagnosis goes on
            print(f"{variant:10s} {label:8s} {step} FAILED {type(exc).__name__}: {str(exc)[:300]}", flush=True)


def _owner(launcher, variant, label, pub, priv, x, want, ref, dev) -> None:
    n, count = int(pub.n), x.size
    a = owner_module.random_below(ref.p.bound, count)
    b = owner_module.random_below(ref.q.bound, count)
    c1 = launcher.owner_encrypt(x, a, b, ref)
    _report(variant, label, "owner", CPU.decrypt(priv, _records(c1, n)), want)
    c2 = launcher.owner_encrypt(x, a, b, ref)
    _report(variant, label, "repeat", [int(v) for v in (c1 != c2).any(axis=1)], [0] * count)
    c3 = launcher.owner_encrypt(x, a, b, dev)
    _report(variant, label, "owner+devtables", CPU.decrypt(priv, _records(c3, n)), want)
    ones = [i for i in range(min(count, 8))]  # one value per launch: a per-item fault or a launch-wide one
    single = [from_limbs(launcher.owner_encrypt(x[i:i + 1], a[i:i + 1], b[i:i + 1], ref))[0] for i in ones]
    _report(variant, label, "owner single", [int(s == from_limbs(c1[i:i + 1])[0]) for i, s in zip(ones, single)],
            [1] * len(ones))


def _public(launcher, variant, label, pub, priv, x, want, ref, dev) -> None:
    n = int(pub.n)
    c4 = owner_module.public_limbs(launcher, pub, x)
    _report(variant, label, "public", CPU.decrypt(priv, _records(c4, n)), want)


def _decrypt(launcher, variant, label, pub, priv, x, want, ref, dev) -> None:
    n = int(pub.n)
    cts = CPU.encrypt(priv, x)
    limbs = np.asarray(to_limbs([int(v) for v in cts], -(-(n * n).bit_length() // 32)))
    _report(variant, label, "decrypt", owner_module.decrypt_limbs(launcher, priv, limbs), want)


STEPS = {"owner": _owner, "public": _public, "decrypt": _decrypt}


class _Block:
    """A kernel launched with ``block`` threads per block (the same threads in all)."""

    def __init__(self, fn, block: int) -> None:
        self.fn, self.block = fn, block

    def __call__(self, grid, block, args):
        total = int(args[-2])  # every kernel here ends (..., count, out)
        return self.fn(((total + self.block - 1) // self.block,), (self.block,), args)


class Variant(CupyLauncher):
    def __init__(self, replace: tuple[str, str] | None = None, options: tuple[str, ...] = (), block: int = 0):
        super().__init__()
        self._replace, self._options, self._block = replace, options, block

    def _owner_module(self):
        if self._owner_fn is None:
            src = device_module.owner_source()
            if self._replace:
                src = src.replace(*self._replace)
            mod = self.cp.RawModule(code=src, options=("--std=c++11", *self._options), backend="nvrtc")
            fns = [mod.get_function(k) for k in ("k_decrypt", "k_public_encrypt", "k_owner_encrypt")]
            if self._block:
                fns = [_Block(f, self._block) for f in fns]
            self._decrypt_fn, self._public_fn, self._owner_fn = fns


def main() -> None:
    keys = [("33/95", _key(33, 95), 512), ("60/68", _key(60, 68), 512), ("512", _key(256, 256), 256),
            ("2048", _key(1024, 1024), 64)]
    variants = [("shipped", Variant()), ("norestrict", Variant(("#define HEVR_RESTRICT __restrict__", "#define HEVR_RESTRICT"))),
                ("block32", Variant(block=32)), ("block1", Variant(block=1)),
                ("inline", Variant(("#define HEVR_CALL __device__ __noinline__", "#define HEVR_CALL __device__ __forceinline__"))),
                ("-G", Variant(options=("-G",)))]
    wanted = os.environ.get("HEVR_DIAG_KEYS")
    keys = [k for k in keys if not wanted or k[0] in wanted.split(",")]
    only = [a for a in sys.argv[1:] if a != "--fake"]
    if "--fake" in sys.argv:  # on a machine without a GPU: the launcher over the host build (tests' FakeCupy)
        sys.path.insert(0, "tests/backends")
        from _fake_cupy import FakeCupy
        for _, launcher in variants:
            launcher._cp = FakeCupy()
    for vname, launcher in variants:
        if only and vname not in only:
            continue
        for label, (pub, priv), count in keys:
            t0 = time.perf_counter()
            try:
                check(launcher, vname, label, pub, priv, count)
            except Exception as exc:  # noqa: BLE001 - a diagnosis goes on
                print(f"{vname:10s} {label:8s} FAILED {type(exc).__name__}: {str(exc)[:300]}", flush=True)
            print(f"{vname:10s} {label:8s} ({time.perf_counter() - t0:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
