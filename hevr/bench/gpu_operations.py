"""The GPU proof's operations on random operands: each against ``cpu``, and their rates.

Steps 2, 4, 5 and 6 of ``hevr bench --gpu`` (:mod:`hevr.bench.gpu`): :func:`identity` checks every
render operation of a backend against ``cpu`` (gmpy2) bit for bit, :func:`throughput` times running
products and multi-exponentiation pairs at 2048-bit keys, :func:`experiments` does both for each
experiment of the kernel source, :func:`encryption` times the owner path. Operands come from
:mod:`secrets` and :func:`os.urandom`.
"""

from __future__ import annotations

import os
import secrets
import time
import warnings
from typing import Any

import numpy as np

from ..backends import CpuBackend
from ..crypto.keys import generate_keypair
from ..crypto.records import record_width
from ..errors import InsecureKeyWarning
from ..rendering.pipeline.kernel import plan_products

IDENTITY_BITS = (64, 256, 1024, 2048)
GOALS = {"products_per_s": 1.0e8, "pairs_per_s": 2.0e7}
# the kernel source's experiments (preprocessor names), each checked and timed beside the default
EXPERIMENTS = ("HEVR_CIOS_REG",)
CPU = CpuBackend()


def _modulus(bits: int) -> int:
    return secrets.randbits(bits) | 1 | (3 << (bits - 2))


def _uniform(count: int, high: int) -> np.ndarray:
    """``count`` integers in ``[0, high)`` from :func:`os.urandom` (the project draws no other
    randomness; the modulo bias, below 2^-40 for these sizes, does not matter to a benchmark's operands).

    >>> x = _uniform(1000, 7)
    >>> x.dtype, bool(x.min() >= 0 and x.max() < 7)
    (dtype('uint64'), True)
    """
    return np.frombuffer(os.urandom(8 * count), "<u8") % np.uint64(high)


def _plan(rows: int, per_row: int, pool: int, wbits: int):
    """A product plan of ``rows`` rows of ``per_row`` distinct voxels of ``pool`` (a random start and
    a random stride coprime to ``pool`` per row: no Python loop per row), weights of ``wbits`` bits
    (1: all ones, the ONES task kind)."""
    start = _uniform(rows, pool).astype(np.int64)
    stride = 1 + _uniform(rows, pool - 1).astype(np.int64)
    bad = np.gcd(stride, pool) != 1
    while bad.any():  # redraw the strides that share a factor with pool
        stride[bad] = 1 + _uniform(int(bad.sum()), pool - 1).astype(np.int64)
        bad = np.gcd(stride, pool) != 1
    vox = ((start[:, None] + stride[:, None] * np.arange(per_row)) % pool).reshape(-1)
    if wbits == 1:
        w = np.ones(vox.size, np.uint64)
    elif wbits >= 64:
        w = np.frombuffer(os.urandom(8 * vox.size), "<u8") | np.uint64(1)  # full 64-bit, never 0
    else:
        w = 1 + _uniform(vox.size, (1 << wbits) - 1)
    return plan_products(np.arange(rows + 1) * per_row, vox, w, pool)


def identity(be: Any, quick: bool) -> list[dict]:
    """Every render operation of ``be`` against ``cpu`` (:mod:`hevr.bench.gpu`, step 2)."""
    out = []
    for bits in IDENTITY_BITS:
        n = _modulus(bits)
        n2 = n * n
        W = record_width(n)
        m = 200 if quick else 2000
        vals = [1, n2 - 1, n2 - 2] + [secrets.randbelow(n2 - 1) + 1 for _ in range(m - 3)]
        rec = CPU.to_bytes(vals, W)
        c, g = CPU.from_bytes(rec), be.from_bytes(rec)
        checks: dict[str, bool] = {
            "records": bool(np.array_equal(be.to_bytes(be.from_bytes(rec), W), rec)),
            "range": be.first_out_of_range(g, n2) is None and be.first_out_of_range(g, n2 - 1) == 1,
        }
        for label, wbits in (("nearest", 2), ("trilinear", 10), ("u64", 64)):
            plan = _plan(60 if quick else 400, 16, m, wbits)
            checks[f"ray_products {label}"] = bool(
                np.array_equal(
                    CPU.to_bytes(CPU.ray_products(plan, [c], n2)[0], W),
                    be.to_bytes(be.ray_products(plan, [g], n2)[0], W),
                )
            )
        seg = np.arange(0, m + 1, 5)
        checks["segment_products"] = bool(
            np.array_equal(
                CPU.to_bytes(CPU.segment_products(c, seg, 1, n2), W), be.to_bytes(be.segment_products(g, seg, 1, n2), W)
            )
        )
        k = 4
        comb = _uniform(2 * k, 10**4).reshape(k, 2).tolist()  # K = 4 components, C = 2
        rows = c[: (m // k) * k]
        grow = be.from_bytes(CPU.to_bytes(rows, W))
        checks["combine"] = bool(
            np.array_equal(CPU.to_bytes(CPU.combine(rows, comb, n2), W), be.to_bytes(be.combine(grow, comb, n2), W))
        )
        exps = [secrets.randbelow(1 << 40) + 1 for _ in range(len(rows))]
        cpu_pack = CPU.pack(rows, exps, 20, 3, 7, n)
        dev_pack = be.pack(be.from_bytes(CPU.to_bytes(rows, W)), exps, 20, 3, 7, n)
        checks["pack"] = bool(np.array_equal(CPU.to_bytes(cpu_pack, W), be.to_bytes(dev_pack, W)))
        out.append({"bits": bits, "values": m, **checks})
    return out


def throughput(be: Any, quick: bool) -> dict:
    """Products/s and multi-exponentiation pairs/s at 2048-bit keys (:mod:`hevr.bench.gpu`, step 4)."""
    n = _modulus(2048)
    n2 = n * n
    W = record_width(n)
    pool = 512 if quick else 4096  # quick: the command's check (the test suite), not a measurement
    rec = CPU.to_bytes([secrets.randbelow(n2 - 1) + 1 for _ in range(pool)], W)
    rows = 256 if quick else 131072
    res: dict = {}
    for label, wbits, unit in (("products", 1, "products_per_s"), ("pairs", 10, "pairs_per_s")):
        plan = _plan(rows, 64, pool, wbits)
        g = be.from_bytes(rec)
        be.ray_products(plan, [g], n2)  # warm: module, Montgomery form, caches
        t0 = time.perf_counter()
        be.ray_products(plan, [g], n2)
        dt = time.perf_counter() - t0
        count = rows * (63 if wbits == 1 else 64)
        sub = _plan(max(8, rows // 512), 64, pool, wbits)  # cpu: a slice, one core
        c = CPU.from_bytes(rec)
        t0 = time.perf_counter()
        CPU.ray_products(sub, [c], n2)
        cdt = time.perf_counter() - t0
        ccount = sub.n_rows * (63 if wbits == 1 else 64)
        res[label] = {
            "rows": rows,
            "per_row": 64,
            "seconds": dt,
            unit: count / dt,
            f"cpu_{unit}": ccount / cdt,
            "goal": GOALS[unit],
            "speedup_vs_one_core": (count / dt) / (ccount / cdt),
        }
        if hasattr(be, "stage_times"):  # where the end-to-end time goes: host plan, uploads, kernels
            st = be.stage_times(plan if not quick else _plan(rows // 8, 64, pool, wbits), g, n2)
            res[label]["stages_s"] = st
            res[label][f"kernels_{unit}"] = (
                count / (1 if not quick else 8) / st["kernels"] if st["kernels"] > 0 else None
            )
    return res


def experiments(be: Any, quick: bool) -> dict:
    """Each of the kernel source's experiments (:data:`EXPERIMENTS`, compiled in with ``-D``) on
    ``be``'s kind of launcher: identical to ``cpu`` on every operation (step 2's checks) and its
    kernels' rates (step 4's plans, the plan already on the device), beside the default's. An
    experiment that is not identical is reported, never used."""
    out = {}
    n = _modulus(2048)
    n2 = n * n
    pool, rows = (512, 64) if quick else (4096, 131072)
    rec = CPU.to_bytes([secrets.randbelow(n2 - 1) + 1 for _ in range(pool)], record_width(n))
    for name in EXPERIMENTS:
        var = be.with_defines((name,))
        checks = identity(var, True)
        r: dict = {"identical": all(v for row in checks for k, v in row.items() if k not in ("bits", "values"))}
        for label, wbits in (("products_per_s", 1), ("pairs_per_s", 10)):
            plan = _plan(rows, 64, pool, wbits)
            st = var.stage_times(plan, var.from_bytes(rec), n2)
            r[label] = rows * (63 if wbits == 1 else 64) / st["kernels"] if st["kernels"] > 0 else None
        out[name] = r
    return out


def encryption(be: Any, quick: bool, bits: int = 2048) -> dict:
    """Owner-side encryption of int64 mantissas at ``bits`` (``owner.cuh``): values/s beside ``cpu``
    on one core, the time a 100³ scalar volume would take at that rate, and an exact decryption
    of a sample."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        pub, priv = generate_keypair(256 if quick else bits)
    count = 4096 if quick else 262144
    x = _uniform(count, 2**13).astype(np.int64) - 2**12
    be.encrypt(priv, x[:64])  # warm: the tables (once per key and process), the module
    t0 = time.perf_counter()
    cts = be.encrypt(priv, x)
    dt = time.perf_counter() - t0
    sample = min(count, 200)
    exact = be.decrypt(priv, be.from_bytes(be.to_bytes(cts, record_width(pub.n))[:sample])) == [
        int(v) % int(pub.n) for v in x[:sample].tolist()
    ]
    t0 = time.perf_counter()
    CPU.encrypt(priv, x[:2000])
    cdt = time.perf_counter() - t0
    rate, crate = count / dt, 2000 / cdt
    return {
        "bits": int(pub.n).bit_length(),
        "values": count,
        "seconds": dt,
        "values_per_s": rate,
        "cpu_values_per_s": crate,
        "speedup_vs_one_core": rate / crate,
        "volume_100_s": 1e6 / rate,
        "goal_volume_100_s": 3.0,
        "exact": bool(exact),
    }
