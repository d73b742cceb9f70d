"""Locate a GPU-only wrong result in the key holder's kernels (``owner.cuh``) against Python integers.

Run on the GPU machine (``bash benchmarks/gpu-proof.sh run`` calls it). Each step is checked against
plain Python integers, never against another kernel:

* ``tables``  — the fixed-base tables converted to Montgomery form by the device (``k_mont_convert``)
  against ``e·R mod P``;
* ``owner``   — owner encryption with tables converted in Python, decrypted by ``cpu``; ``repeat``
  (the same launch twice: a race would differ); ``owner+devtables`` (the device's own tables);
  ``owner single`` (one value per launch against the batch's);
* ``public``  — public-key encryption, decrypted by ``cpu``;
* ``decrypt`` — CRT decryption of ``cpu`` ciphertexts;

for keys of unbalanced 33/95-bit primes (with known factors of p − 1, so the owner path runs), 60/68,
512, 1024 and 2048 bits, at several batch sizes. An illegal address poisons a CUDA context for good,
so every variant of the module's compilation runs in its own process: as shipped, without
``__restrict__``, without the unrolled limb counts (every product through the generic loop), the
products inlined instead of called, 32 and 1 threads a block, and ``-G`` (no device optimisation).
One line per (variant, key, step, batch): wrong / total and the first wrong indices.

    python benchmarks/gpu_diagnose.py                      # every variant, each in a subprocess
    python benchmarks/gpu_diagnose.py --variant shipped --keys 2048 --steps decrypt --counts 64
    python benchmarks/gpu_diagnose.py --fake ...           # without a GPU: the host build (FakeCupy)

Exit status 0: it is a diagnosis; the tests are the verdict.
"""

from __future__ import annotations

import argparse
import os
import subprocess
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
from hevr.crypto.primes import random_prime_with_factors

CPU = CpuBackend()
_REF: dict = {}
KEYS = {"33/95": (33, 95), "60/68": (60, 68), "512": (256, 256), "1024": (512, 512), "2048": (1024, 1024)}
VARIANTS = {
    "shipped": {},
    "norestrict": {"replace": ("#define HEVR_RESTRICT __restrict__", "#define HEVR_RESTRICT")},
    "nounroll": {"replace": ("switch (nl) {", "switch (-1) {")},
    "inline": {
        "replace": ("#define HEVR_CALL __device__ __noinline__", "#define HEVR_CALL __device__ __forceinline__")
    },
    "block32": {"block": 32},
    "block1": {"block": 1},
    "-G": {"options": ("-G",)},
    # the per-thread stack raised to 16 KiB before any launch: owner.cuh's kernels take 2,576 bytes of
    # stack frame (ptxas, sm_90, 2026-11-28) against at most 1,552 for render.cuh's, which pass
    "stack16k": {"stack": 16384},
    # the launcher before reserve_stack (device.py): the stack left at the driver's 1,024 bytes, grown by
    # the driver at a launch; wrong or faulting in some runs on an H200 (2026-11-28)
    "noreserve": {"reserve": False},
}
# CUfunction_attribute numbers (cuda.h): what each kernel takes per thread, as the driver sees it
ATTRIBUTES = {
    "max_threads_per_block": 0,
    "shared_size_bytes": 1,
    "const_size_bytes": 2,
    "local_size_bytes": 3,
    "num_regs": 4,
}


class PyConvert:
    """mont_convert in Python integers (the tables' reference)."""

    keyholder = True

    def host(self, limbs):
        return np.asarray(limbs)

    def mont_convert(self, limbs, b, M):
        N = gmpy2.mpz(M.n)
        f = gmpy2.mpz(from_limbs(np.asarray(b).reshape(1, -1))[0]) * pow(gmpy2.mpz(1 << (32 * M.nl)), -1, N) % N
        return to_limbs([int(gmpy2.mpz(v) * f % N) for v in from_limbs(limbs)], M.nl)


class _Block:
    """A kernel launched with ``block`` threads per block (the same threads in all)."""

    def __init__(self, fn, block: int) -> None:
        self.fn, self.block = fn, block

    def __call__(self, grid, block, args):
        total = int(args[-2])  # every kernel here ends (..., count, out)
        return self.fn(((total + self.block - 1) // self.block,), (self.block,), args)


class Variant(CupyLauncher):
    """The device launcher with the owner module compiled or launched another way."""

    keyholder = True

    def __init__(
        self,
        replace: tuple[str, str] | None = None,
        options: tuple[str, ...] = (),
        block: int = 0,
        stack: int = 0,
        reserve: bool = True,
    ):
        super().__init__()
        self._replace, self._options, self._block, self._stack = replace, options, block, stack
        self._reserve = reserve

    def _owner_module(self):
        if self._owner_fn is None:
            src = device_module.owner_source()
            if self._replace:
                if self._replace[0] not in src:
                    raise RuntimeError(f"variant: {self._replace[0]!r} not in the source")
                src = src.replace(*self._replace)
            mod = self.cp.RawModule(code=src, options=("--std=c++11", *self._options), backend="nvrtc")
            fns = [mod.get_function(k) for k in ("k_decrypt", "k_public_encrypt", "k_owner_encrypt")]
            _attributes(self.cp, fns, self._stack)
            if self._reserve and not self._stack:  # as the shipped launcher does (device.reserve_stack)
                print(f"stack limit after reserve_stack: {device_module.reserve_stack(self.cp, fns)} bytes", flush=True)
            if self._block:
                fns = [_Block(f, self._block) for f in fns]
            self._decrypt_fn, self._public_fn, self._owner_fn = fns


def _attributes(cp, fns, stack: int) -> None:
    """Print each kernel's registers, local memory and limits as the driver reports them, and the
    device's per-thread stack limit (after raising it to ``stack`` bytes where asked)."""
    rt = cp.cuda.runtime
    try:
        if stack:
            rt.deviceSetLimit(0, stack)  # cudaLimitStackSize
        print(f"stack limit per thread: {rt.deviceGetLimit(0)} bytes", flush=True)
    except Exception as exc:  # noqa: BLE001 - a diagnosis goes on (FakeCupy has no limits)
        print(f"stack limit: not read ({type(exc).__name__}: {exc})", flush=True)
    for fn in fns:
        name = getattr(fn, "name", None) or getattr(fn, "_name", None) or repr(fn)[:40]
        try:  # CuPy's RawKernel.attributes (a RawKernel has no .ptr under cupy-cuda13x, 2026-11-28)
            attrs = fn.attributes
            got = {k: attrs[k] for k in ATTRIBUTES}
        except Exception as exc:  # noqa: BLE001
            got = {"error": f"{type(exc).__name__}: {exc}"}
        print(f"kernel {name}: " + ", ".join(f"{k}={v}" for k, v in got.items()), flush=True)


def _key(pbits: int, qbits: int):
    if pbits == qbits:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
            return hevr.generate_keypair(2 * pbits)
    p, q = (int(random_prime_with_factors(b)[0]) for b in (pbits, qbits))  # p − 1's factors: owner tables
    pub = hevr.PublicKey(p * q)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        return pub, hevr.PrivateKey(pub, p, q)


def _line(variant: str, label: str, step: str, count: int, text: str) -> None:
    print(f"{variant:10s} {label:6s} {step:16s} m={count:<7d} {text}", flush=True)


def _report(variant: str, label: str, step: str, got: list, want: list) -> None:
    bad = [i for i, (g, w) in enumerate(zip(got, want)) if g != w]
    _line(variant, label, step, len(want), f"wrong {len(bad)}/{len(want)} first {bad[:6]}")


def _records(limbs: np.ndarray, n: int):
    return CPU.from_bytes(CPU.to_bytes(from_limbs(limbs), 2 * ((n.bit_length() + 7) // 8)))


def _values(count: int, n: int) -> np.ndarray:
    x = (np.arange(count, dtype=np.int64) - count // 2) * 7919
    x[: min(count, 4)] = [0, 1, -1, -2][: min(count, 4)]
    return np.clip(x, -(n // 3 - 1), n // 3 - 1)


def _tables(launcher, variant, label, pub, priv) -> tuple:
    n = int(pub.n)
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
        h = getattr(ref, half)
        _line(
            variant,
            label,
            f"tables {half}",
            a_.shape[0],
            f"wrong {bad.size}/{a_.shape[0]} first {bad[:6].tolist()} (w={h.w}, rows={h.rows}, nl={h.P.nl})",
        )
    return ref, dev


def _owner(launcher, variant, label, pub, priv, count, tables) -> None:
    ref, dev = tables
    if ref is None:
        _line(variant, label, "owner", count, "no tables for this key (the cpu path)")
        return
    n = int(pub.n)
    x = _values(count, n)
    want = [int(v) % n for v in x.tolist()]
    a, b = owner_module.random_below(ref.p.bound, count), owner_module.random_below(ref.q.bound, count)
    c1 = launcher.host(launcher.owner_encrypt(x, a, b, ref))  # the launcher's arrays: numpy here
    sample = slice(0, min(count, 512))  # cpu decryption of a sample: seconds at 2048 bits otherwise
    _report(variant, label, "owner", CPU.decrypt(priv, _records(c1[sample], n)), want[sample])
    c2 = launcher.host(launcher.owner_encrypt(x, a, b, ref))
    _report(variant, label, "repeat", [int(v) for v in (c1 != c2).any(axis=1)], [0] * count)
    c3 = launcher.host(launcher.owner_encrypt(x[sample], a[sample], b[sample], dev))
    _report(variant, label, "owner+devtables", CPU.decrypt(priv, _records(c3, n)), want[sample])
    ones = range(min(count, 4))
    single = [
        from_limbs(launcher.host(launcher.owner_encrypt(x[i : i + 1], a[i : i + 1], b[i : i + 1], ref)))[0]
        for i in ones
    ]
    _report(
        variant,
        label,
        "owner single",
        [int(s == from_limbs(c1[i : i + 1])[0]) for i, s in zip(ones, single)],
        [1] * len(ones),
    )


def _public(launcher, variant, label, pub, priv, count, tables) -> None:
    n = int(pub.n)
    x = _values(min(count, 1024), n)  # cpu decrypts them all
    c = launcher.host(owner_module.public_limbs(launcher, pub, x))
    _report(variant, label, "public", CPU.decrypt(priv, _records(c, n)), [int(v) % n for v in x.tolist()])


def _decrypt(launcher, variant, label, pub, priv, count, tables) -> None:
    n = int(pub.n)
    x = _values(min(count, 1024), n)  # cpu encrypts them all
    cts = CPU.encrypt(priv, x)
    limbs = np.asarray(to_limbs([int(v) for v in cts], -(-(n * n).bit_length() // 32)))
    _report(
        variant, label, "decrypt", owner_module.decrypt_limbs(launcher, priv, limbs), [int(v) % n for v in x.tolist()]
    )


STEPS = {"owner": _owner, "public": _public, "decrypt": _decrypt}


def run_variant(name: str, keys: list[str], steps: list[str], counts: list[int], fake: bool) -> None:
    launcher = Variant(**VARIANTS[name])
    if fake:  # on a machine without a GPU: the launcher over the host build (the tests' FakeCupy)
        sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "backends"))
        from _fake_cupy import FakeCupy

        launcher._cp = FakeCupy()
    for label in keys:
        pub, priv = _key(*KEYS[label])
        t0 = time.perf_counter()
        try:
            tables = _tables(launcher, name, label, pub, priv) if "owner" in steps else (None, None)
        except Exception as exc:  # noqa: BLE001 - a diagnosis goes on
            _line(name, label, "tables", 0, f"FAILED {type(exc).__name__}: {str(exc)[:200]}")
            return
        for step in steps:
            for count in counts:
                try:
                    STEPS[step](launcher, name, label, pub, priv, count, tables)
                except Exception as exc:  # noqa: BLE001 - an illegal address ends this process's checks
                    _line(name, label, step, count, f"FAILED {type(exc).__name__}: {str(exc)[:200]}")
                    if "illegal" in str(exc).lower() or "CUDA" in type(exc).__name__:
                        return
        _line(name, label, "done", 0, f"({time.perf_counter() - t0:.1f} s)")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", choices=sorted(VARIANTS), help="run one variant here (default: each in a subprocess)")
    ap.add_argument("--keys", default=",".join(KEYS))
    ap.add_argument("--steps", default="decrypt,public,owner")
    ap.add_argument("--counts", default="64,4096")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per variant's subprocess")
    ap.add_argument("--fake", action="store_true")
    args = ap.parse_args(argv)
    keys, steps = args.keys.split(","), args.steps.split(",")
    counts = [int(c) for c in args.counts.split(",")]
    if args.variant:
        run_variant(args.variant, keys, steps, counts, args.fake)
        return
    for name in VARIANTS:
        cmd = [
            sys.executable,
            __file__,
            f"--variant={name}",
            "--keys",
            args.keys,
            "--steps",
            args.steps,
            "--counts",
            args.counts,
        ] + (["--fake"] if args.fake else [])
        try:
            subprocess.run(cmd, timeout=args.timeout, check=False)
        except subprocess.TimeoutExpired:
            print(f"{name:10s} timed out after {args.timeout:.0f} s", flush=True)


if __name__ == "__main__":
    main()
