"""Benchmark of :mod:`hevr.rendering.pipeline.kernel` on realistic per-brick CSR workloads.

Usage::

    python benchmarks/kernel.py [--bits 2048] [--quick] [--no-append]

(also run by ``hevr bench``, which puts the ratios beside the render benchmarks).

Every time is divided by the time of one bare ``a * b % n2`` on numbers of the same size
measured in the same run, so the ratios are comparable across machines. Workloads:

* ``nearest``: 32^3 brick, 2025 orthographic rays (pixels 0.7 voxel, almost
  axis-aligned), nearest sampling at step 0.95 voxel: 32 pairs per ray, weights mostly 1
  and a few 2; ~20% of the rows repeat an earlier row.
* ``nearest-nodup`` (extra): same with a more oblique view, so no row repeats (worst
  case for nearest sampling).
* ``trilinear``: 26^3 brick, 784 oblique rays at 0.8-voxel pixel spacing, trilinear
  footprints at step 0.5 voxel (114-124 distinct voxels per ray for 90% of the rays,
  each voxel used by ~6 rays); weights drawn uniformly in 1..1023 (10 bits).
* ``trilinear-real`` (extra): same geometry with the real trilinear weights summed per
  voxel and quantised to 10 bits (many small weights, some zeros dropped).

The ciphertexts are random residues modulo a random odd n^2 with n of ``--bits`` bits:
the cost of modular arithmetic does not depend on them being real encryptions.
Run alone, a markdown section is appended to ``benchmarks/history.md``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import secrets
import time
import timeit
from functools import partial
from typing import Any

import gmpy2
import numpy as np
from gmpy2 import mpz

from ..crypto.records import bytes_to_mpz, mpz_to_bytes, record_width
from ..rendering.pipeline.kernel import OpCounter, brick_ray_products
from .measure import cpu_model

# CPU time of this process: other jobs on the machine do not count against the kernel.
CLOCK = time.process_time
GOALS = {"nearest": 1.3, "nearest-nodup": 1.3, "trilinear": 3.0}


def _to_csr(rows: list[dict[int, float]]):
    indptr = np.zeros(len(rows) + 1, np.int64)
    indptr[1:] = np.cumsum([len(r) for r in rows])
    voxels = np.fromiter((v for r in rows for v in r), np.int64, int(indptr[-1]))
    weights = np.fromiter((w for r in rows for w in r.values()), np.float64, int(indptr[-1]))
    return indptr, voxels, weights


def _rays(n_side: int, pixel: float, direction, size: int):
    d = np.asarray(direction, np.float64)
    d /= np.linalg.norm(d)
    span = (n_side - 1) * pixel
    lo = (size - 1 - span) / 2
    xs = lo + pixel * np.arange(n_side)
    return [(np.array([x, y, -0.5]), d) for y in xs for x in xs]


def nearest_workload(size=32, n_side=45, pixel=0.7, step=0.95, direction=(0.01, 0.006, 1.0)):
    rows = []
    for o, d in _rays(n_side, pixel, direction, size):
        row: dict[int, float] = {}
        t = 0.5 * step
        while True:
            p = o + t * d
            if p[2] > size - 0.5:
                break
            v = np.rint(p).astype(np.int64)
            if (v >= 0).all() and (v < size).all():
                key = int((v[2] * size + v[1]) * size + v[0])
                row[key] = row.get(key, 0) + 1
            t += step
        rows.append(row)
    ip, vx, wt = _to_csr(rows)
    return ip, vx, wt.astype(np.int64), size**3


class _Rng:
    """The few draws the workloads need, from os.urandom like everything random in hevr
    (the workloads are statistically the same every run, not bit-identical)."""

    @staticmethod
    def integers(lo: int, hi: int, size, dtype=np.int64) -> np.ndarray:
        n = int(np.prod(size))
        u = np.frombuffer(os.urandom(8 * n), dtype=np.uint64)
        return (lo + u % np.uint64(hi - lo)).astype(dtype).reshape(size)

    @staticmethod
    def choice(n: int, size: int, replace: bool = False) -> np.ndarray:
        return np.array(secrets.SystemRandom().sample(range(n), size))


def trilinear_workload(rng, size=26, n_side=28, pixel=0.8, step=0.5, direction=(0.1, 0.06, 1.0), uniform=True):
    rows = []
    for o, d in _rays(n_side, pixel, direction, size):
        row: dict[int, float] = {}
        t = 0.5 * step
        while True:
            p = o + t * d
            if p[2] > size - 1:
                break
            base = np.floor(p).astype(np.int64)
            f = p - base
            for dz in (0, 1):
                for dy in (0, 1):
                    for dx in (0, 1):
                        v = base + (dx, dy, dz)
                        if (v >= 0).all() and (v < size).all():
                            w = (f[0] if dx else 1 - f[0]) * (f[1] if dy else 1 - f[1]) * (f[2] if dz else 1 - f[2])
                            key = int((v[2] * size + v[1]) * size + v[0])
                            row[key] = row.get(key, 0.0) + w
            t += step
        rows.append(row)
    ip, vx, wt = _to_csr(rows)
    if uniform:
        wt = rng.integers(1, 1024, wt.size)
    else:
        wt = np.rint(np.minimum(wt, 1.0) * 1023).astype(np.int64)
    return ip, vx, wt.astype(np.int64), size**3


def best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = CLOCK()
        fn()
        best = min(best, CLOCK() - t0)
    return best


def naive(cts, ip, vx, wt, n2, rows):
    ipl, vl, wl = ip.tolist(), vx.tolist(), wt.tolist()
    powmod = gmpy2.powmod
    out = []
    for r in rows:
        acc = mpz(1)
        for i in range(ipl[r], ipl[r + 1]):
            acc = acc * powmod(cts[vl[i]], wl[i], n2) % n2
        out.append(acc)
    return out


def kernel_micro(bits: int = 2048, quick: bool = False) -> dict:
    """Run the four workloads; ``{"mulmod_s": ..., "workloads": [{name, ratio, ...}]}``."""
    args = argparse.Namespace(bits=bits, quick=quick)
    rng = _Rng()
    # Two top bits set: n^2 has exactly 2 * bits bits, like a real Paillier modulus.
    n = mpz(secrets.randbits(args.bits)) | 1 | (mpz(3) << (args.bits - 2))
    n2 = n * n
    width = record_width(n)
    repeat = 2 if args.quick else 3

    a, b = mpz(secrets.randbelow(int(n2))), mpz(secrets.randbelow(int(n2)))
    number = 2000 if args.quick else 10000

    def time_mulmod(rep: int) -> float:
        return min(timeit.repeat(lambda: a * b % n2, number=number, repeat=rep, timer=CLOCK)) / number

    # Other processes may share the CPU: times are CPU times of this process, the
    # baseline is re-measured between kernel runs and minima are used throughout.
    t_mul = time_mulmod(7)

    workloads = {
        "nearest": nearest_workload(**({"n_side": 30} if args.quick else {})),
        "nearest-nodup": nearest_workload(direction=(0.02, 0.012, 1.0), **({"n_side": 30} if args.quick else {})),
        "trilinear": trilinear_workload(rng, **({"n_side": 12} if args.quick else {})),
        "trilinear-real": trilinear_workload(rng, uniform=False, **({"n_side": 12} if args.quick else {})),
    }
    results: list[dict[str, Any]] = []
    measured = []
    for name, (ip, vx, wt, n_vox) in workloads.items():
        raw = rng.integers(0, 256, (n_vox, width), dtype=np.uint8)
        raw[:, 0] = 0  # keep every value below 2^(8 width - 8) < n2
        t0 = CLOCK()
        cts = bytes_to_mpz(raw)
        t_conv = (CLOCK() - t0) / n_vox
        assert mpz_to_bytes(cts[:10], width).shape == (10, width)
        n_rows, n_pairs = len(ip) - 1, int(ip[-1])
        counter = OpCounter()
        brick_ray_products(cts, ip, vx, wt, n2, counter)
        t_kernel = float("inf")
        for _ in range(repeat):
            t_mul = min(t_mul, time_mulmod(3))
            t_kernel = min(t_kernel, best_time(partial(brick_ray_products, cts, ip, vx, wt, n2), 1))
        sub = rng.choice(n_rows, size=min(n_rows, 40 if args.quick else 150), replace=False)
        sub_pairs = int(sum(ip[r + 1] - ip[r] for r in sub))
        res = brick_ray_products(cts, ip, vx, wt, n2)
        ref = naive(cts, ip, vx, wt, n2, sub)
        assert all(res[r] == x for r, x in zip(sub, ref)), f"{name}: kernel != naive"
        t_naive = best_time(partial(naive, cts, ip, vx, wt, n2, sub), 1)
        nz = wt[wt > 0]
        measured.append((t_kernel, t_naive, t_conv, sub_pairs))
        results.append(
            {
                "name": name,
                "rows": n_rows,
                "pairs": n_pairs,
                "pairs_per_row": n_pairs / max(n_rows, 1),
                "weights": f"{nz.min()}..{nz.max()}, {np.mean(nz == 1):.0%} ones",
                "dup": counter.duplicate_rows / max(n_rows, 1),
                "ops": counter.modmuls / n_pairs,
                "pre": counter.precomputed,
            }
        )
    t_mul = min(t_mul, time_mulmod(7))
    for r, (t_kernel, t_naive, t_conv, sub_pairs) in zip(results, measured):
        r["ratio"] = t_kernel / r["pairs"] / t_mul
        r["naive"] = t_naive / sub_pairs / t_mul
        r["conv"] = t_conv / t_mul
    return {
        "bits": bits,
        "quick": quick,
        "mulmod_s": t_mul,
        "goals": GOALS,
        "workloads": [
            {k: (float(v) if isinstance(v, (np.floating, np.integer)) else v) for k, v in r.items()} for r in results
        ],
    }


def report(res: dict) -> str:
    args = argparse.Namespace(bits=res["bits"], quick=res["quick"])
    results, t_mul = res["workloads"], res["mulmod_s"]
    when = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    machine = (
        f"{platform.platform()}; CPU {cpu_model()} ({platform.machine()}); "
        f"Python {platform.python_version()}; gmpy2 {gmpy2.version()}; numpy {np.__version__}; "
        f"{os.cpu_count()} logical CPUs, load average {os.getloadavg()[0]:.2f} at the end"
    )
    lines = [
        f"## kernel: brick_ray_products ({when})",
        "",
        f"- machine: {machine}",
        f"- n: {args.bits} bits (n^2 {2 * args.bits} bits); one `a * b % n2` = "
        f"{t_mul * 1e6:.2f} µs; {'quick' if args.quick else 'full'} run",
        "- ratio = kernel time per (ray, voxel) pair / time of one `a * b % n2`; "
        "naive = `powmod` per pair; ops = counted mulmod + squarings per pair; "
        "dup = fraction of rows identical to an earlier row; pre = per-voxel powers",
        "",
        "| workload | rows | pairs/row | weights | dup | ops/pair | pre | ratio | goal | naive ratio |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        goal = GOALS.get(r["name"])
        verdict = "-" if goal is None else f"≤ {goal} {'ok' if r['ratio'] <= goal else 'MISSED'}"
        lines.append(
            f"| {r['name']} | {r['rows']} | {r['pairs_per_row']:.1f} | {r['weights']} | "
            f"{r['dup']:.1%} | {r['ops']:.3f} | {r['pre']} | **{r['ratio']:.3f}** | {verdict} | "
            f"{r['naive']:.2f} |"
        )
    lines += ["", f"- bytes_to_mpz: {results[0]['conv']:.3f} `a * b % n2` per ciphertext (once per brick)", ""]
    return "\n".join(lines)
