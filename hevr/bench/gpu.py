"""``hevr bench --gpu``: prove the GPU backend on the machine at hand, then measure it.

One command for whoever next has a GPU (issue 26). In order, each step's result written as
soon as it is known (``gpu.json`` and ``gpu.md`` in the output folder, naming the card):

1. **device** — the card (CuPy's device properties), the backend's module compiled by NVRTC;
2. **identity** — every render operation of the backend against ``cpu`` (gmpy2) on random
   residues and the edge cases (1, n²−1, n²−2), at 64-, 256-, 1024- and 2048-bit keys:
   records ↔ residues, the range check, ``ray_products`` for nearest-like (weights 1–2),
   trilinear-like (10-bit) and 64-bit weights, ``segment_products``, ``combine`` and ``pack``;
3. **render** — a ``size``³ phantom (64, or 16 with ``quick``) encrypted under a
   ``render_bits`` key (on a LocalCluster of up to 16 processes: owner encryption is CPU work),
   rendered X-ray nearest, X-ray trilinear and TF 4-dim nearest with the
   backend (streamed, then three resident frames: ``persist(backend=...)``) and with ``cpu``: the
   packed images must be byte-identical, and within ``error_bound`` of ``render_plain``;
4. **throughput** — at 2048-bit keys (4096-bit products mod n²): independent running products
   (``ONES`` rows of 64 factors: products/s) and multi-exponentiation rows of 64 pairs with
   10-bit weights (pairs/s), each through ``Backend.ray_products`` end to end (host ↔ device
   copies included), beside ``cpu`` on one core of this machine; on a kernel backend also split
   into its stages (``KernelBackend.stage_times``: the plan's arrays on the host, the launcher with
   them on the host, the kernels alone with them already on the device).
5. **experiments** — each of the kernel source's experiments (:data:`EXPERIMENTS`, e.g.
   ``HEVR_CIOS_REG`` in ``mont.cuh``) compiled in: step 2's checks and step 4's kernel rates, so
   a GPU session decides from one run whether an experiment becomes the default;
6. **encryption** — the owner path in a kernel (``owner.cuh``): 64³ int64 mantissas under a
   2048-bit key, values/s beside ``cpu`` on one core, the projected time of a 100³ volume (goal
   3 s), and a sample decrypted exactly;

Any mismatch makes the command exit 1 after writing what it found. ``backend`` may be
``cuda-host`` (the same kernels on the CPU), which is how the test suite runs this command on a
machine without a GPU; the issue's goals (≥ 1.0·10⁸ 4096-bit products/s, ≥ 2·10⁷ pairs/s on one
H100) are printed beside the figures, never asserted.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import secrets
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import dask
import numpy as np
from distributed import Client, LocalCluster

from ..backends import CpuBackend, get_backend
from ..crypto.keys import generate_keypair
from ..crypto.records import record_width
from ..errors import InsecureKeyWarning, IntegrityError
from ..paper import TF_NODES
from ..rendering.encrypted import error_bound, render
from ..rendering.geometry.camera import Camera
from ..rendering.pipeline.kernel import plan_products
from ..rendering.reference.plain import render_plain
from ..store.writer import encrypt_volume
from ..volume.phantom import phantom
from .measure import machine

log = logging.getLogger(__name__)

__all__ = ["run_gpu_bench"]

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
    """Every render operation of ``be`` against ``cpu`` (module docstring, step 2)."""
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


def render_identity(
    be_name: str, size: int, bits: int, work: Path | None, workers: int = 0, log_line: Callable[[str], None] = log.info
) -> list[dict]:
    """The ``size``³ phantom's renders with ``be_name`` and ``cpu``: identical bytes, within the bound.

    With ``workers`` the encryption and the ``cpu`` renders run on a LocalCluster of that many
    processes (a 64³ 2048-bit store is ~15 CPU-minutes of owner encryption); the ``be_name``
    renders run in this process (the GPU is this process's), on Dask's synchronous scheduler."""
    with warnings.catch_warnings():  # --quick's 256-bit key: insecure on purpose
        warnings.simplefilter("ignore", InsecureKeyWarning)
        _, priv = generate_keypair(bits)
    vol = phantom(size)
    with contextlib.ExitStack() as stack:
        # a fresh scratch folder (never over an earlier run's store), removed afterwards
        folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="hevr-gpu-bench-", dir=work)))
        client = None
        if workers:
            cluster = stack.enter_context(LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None))
            client = stack.enter_context(Client(cluster, set_as_default=False))
        with dask.config.set(scheduler="sync"):
            ev = encrypt_volume(
                vol,
                folder / f"phantom{size}.zarr",
                priv,
                brick=max(8, size // 4),
                vector_dims=4,
                progress=False,
                client=client,
            )
        log_line(f"  {size}^3 store encrypted ({bits} bits)")
        cam = Camera.orbit(ev, azimuth=30, elevation=20, width=2 * size, height=2 * size)
        with dask.config.set(scheduler="sync"):  # resident in the backend's form, in this process
            resident = ev.persist(backend=be_name)
        out = []
        for mode, sampling, kw in (
            ("xray", "nearest", {}),
            ("xray", "trilinear", {}),
            ("tf", "nearest", {"nodes": TF_NODES}),
        ):
            t0 = time.perf_counter()
            with dask.config.set(scheduler="sync"):
                a = render(ev, cam, mode, sampling, backend=be_name, progress=False, cache=False, verify=False, **kw)
            t1 = time.perf_counter()
            frames = []
            for _ in range(3):  # resident frames: no store reads, bricks already in the backend's form
                f0 = time.perf_counter()
                with dask.config.set(scheduler="sync"):
                    r = render(
                        resident, cam, mode, sampling, backend=be_name, progress=False, cache=False, verify=False, **kw
                    )
                frames.append(time.perf_counter() - f0)
            same_resident = all(np.array_equal(x, y) for x, y in zip(a.ciphertexts, r.ciphertexts))
            c0 = time.perf_counter()  # the cpu render alone (the H200 run of 2026-11-26 timed the resident frames too)
            with dask.config.set(scheduler="sync"):
                b = render(
                    ev,
                    cam,
                    mode,
                    sampling,
                    backend="cpu",
                    progress=False,
                    cache=False,
                    client=client,
                    verify=False,
                    **kw,
                )
            t2 = time.perf_counter()
            same = len(a.ciphertexts) == len(b.ciphertexts) and all(
                np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts)
            )
            row = {
                "case": f"{mode} {sampling}",
                "size": size,
                "bits": bits,
                "identical": bool(same and same_resident),
                "within_bound": False,
                "seconds": t1 - t0,
                "resident_seconds": sorted(frames)[1],
                "cpu_seconds": t2 - c0,
                "cpu_workers": workers or 1,
            }
            try:  # a wrong backend's image may not even decrypt: the client's checks refuse it
                err = np.abs(a.decrypt(priv) - render_plain(vol, cam, mode, sampling, **kw))
                row["within_bound"] = bool(np.all(err <= error_bound(ev, cam, mode, sampling, **kw)))
            except IntegrityError as exc:
                row["error"] = str(exc)
            out.append(row)
            log_line(
                f"  {row['case']}: {row['seconds']:.2f} s streamed, {row['resident_seconds']:.2f} s resident, "
                f"cpu {row['cpu_seconds']:.2f} s on {row['cpu_workers']} ({'identical' if row['identical'] else 'MISMATCH'})"
            )
    return out


def throughput(be: Any, quick: bool) -> dict:
    """Products/s and multi-exponentiation pairs/s at 2048-bit keys (module docstring, step 4)."""
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


def _markdown(res: dict) -> str:
    m = res["machine"]
    head = f"Backend `{res['backend']}`; {m['date']}, commit {m.get('commit')}, {m['cpu']} ({m['cores']} cores)."
    lines = [f"# hevr bench --gpu: {res['device']}", "", head, ""]
    if "identity" in res:
        lines += [
            "## Operations against cpu (bit-identical?)",
            "",
            "| bits | " + " | ".join(k for k in res["identity"][0] if k not in ("bits", "values")) + " |",
            "|---|" + "---|" * (len(res["identity"][0]) - 2),
        ]
        for row in res["identity"]:
            lines.append(
                f"| {row['bits']} | "
                + " | ".join("yes" if v else "**NO**" for k, v in row.items() if k not in ("bits", "values"))
                + " |"
            )
        lines.append("")
    if "render" in res:
        lines += [
            "## Renders against cpu (streamed; resident: median of 3 frames, this process)",
            "",
            "| case | size | key bits | identical | within bound | s | resident s | cpu s (workers) |",
            "|---|---:|---:|---|---|---:|---:|---:|",
        ]
        lines += [
            f"| {r['case']} | {r['size']}³ | {r['bits']} | {'yes' if r['identical'] else '**NO**'} | "
            f"{'yes' if r['within_bound'] else '**NO**'} | {r['seconds']:.2f} | {r['resident_seconds']:.3f} | "
            f"{r['cpu_seconds']:.2f} ({r['cpu_workers']}) |"
            for r in res["render"]
        ]
        lines.append("")
    if "throughput" in res:
        lines += [
            "## Throughput at 2048-bit keys (4096-bit products), end to end through ray_products",
            "",
            "| what | rows × 64 | per s | cpu, one core, per s | × one core | goal per s |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for label, r in res["throughput"].items():
            unit = "products_per_s" if label == "products" else "pairs_per_s"
            lines.append(
                f"| {label} | {r['rows']} | {r[unit]:.3g} | {r['cpu_' + unit]:.3g} | "
                f"{r['speedup_vs_one_core']:.3g} | {r['goal']:.1g} |"
            )
        lines.append("")
        staged = {k: r for k, r in res["throughput"].items() if "stages_s" in r}
        if staged:
            lines += [
                (
                    "Where one call's time goes (seconds; a quick run times an eighth of the rows): the plan's "
                    "arrays on the host, the launcher with them on the host (uploads, kernels, counts back), the "
                    "kernels with them on the device:"
                ),
                "",
                "| what | end to end | plan | launch | kernels | kernels alone, per s |",
                "|---|---:|---:|---:|---:|---:|",
            ]
            for label, r in staged.items():
                st, unit = r["stages_s"], "products_per_s" if label == "products" else "pairs_per_s"
                rate = r.get("kernels_" + unit)
                lines.append(
                    f"| {label} | {r['seconds']:.3g} | {st['plan']:.3g} | {st['launch']:.3g} | "
                    f"{st['kernels']:.3g} | {f'{rate:.3g}' if rate else '-'} |"
                )
            lines.append("")
    if res.get("experiments"):
        lines += [
            "## Experiments in the kernel source (compiled in with -D), kernels alone",
            "",
            "| experiment | identical to cpu | products per s | pairs per s |",
            "|---|---|---:|---:|",
        ]
        base = {
            u: r.get("kernels_" + u)
            for r, u in (
                (res.get("throughput", {}).get("products", {}), "products_per_s"),
                (res.get("throughput", {}).get("pairs", {}), "pairs_per_s"),
            )
        }
        lines.append(f"| (default) | yes | {base['products_per_s'] or 0:.3g} | {base['pairs_per_s'] or 0:.3g} |")
        for name, r in res["experiments"].items():
            lines.append(
                f"| {name} | {'yes' if r['identical'] else '**NO**'} | {r['products_per_s'] or 0:.3g} | "
                f"{r['pairs_per_s'] or 0:.3g} |"
            )
        lines.append("")
    if "encryption" in res:
        e = res["encryption"]
        lines += [
            "## Owner-side encryption (owner.cuh)",
            "",
            "| key bits | values | per s | cpu, one core, per s | × one core | 100³ at this rate | goal | exact |",
            "|---:|---:|---:|---:|---:|---:|---:|---|",
            (
                f"| {e['bits']} | {e['values']} | {e['values_per_s']:.3g} | {e['cpu_values_per_s']:.3g} | "
                f"{e['speedup_vs_one_core']:.3g} | {e['volume_100_s']:.3g} s | {e['goal_volume_100_s']:g} s | "
                f"{'yes' if e['exact'] else '**NO**'} |"
            ),
            "",
        ]
    if "encryption_skipped" in res:
        lines += ["## Owner-side encryption (owner.cuh)", "", f"Skipped: {res['encryption_skipped']}.", ""]
    lines.append(
        f"Result: **{'all identical' if res.get('ok') else 'MISMATCH' if res.get('ok') is False else 'incomplete'}**."
    )
    return "\n".join(lines) + "\n"


def run_gpu_bench(
    out: Path,
    *,
    backend: str = "cuda",
    quick: bool = False,
    work: Path | None = None,
    render_bits: int = 2048,
    render_size: int | None = None,
    log_line: Callable[[str], None] = log.info,
) -> tuple[Path, bool]:
    """Run the steps of the module docstring; returns (the markdown's path, every check passed)."""
    out.mkdir(parents=True, exist_ok=True)
    be = get_backend(backend)
    be.check() if hasattr(be, "check") else None  # CuPy, a device and the module, or a clear error now
    launcher = getattr(be, "_launch", None)
    device = launcher.device_name() if hasattr(launcher, "device_name") else f"the host CPU ({backend})"
    res: dict = {"machine": machine(), "backend": backend, "device": device, "quick": quick}
    md, js = out / "gpu.md", out / "gpu.json"

    def save() -> None:
        js.write_text(json.dumps(res, indent=1, default=str))
        md.write_text(_markdown(res))

    log_line(f"device: {device}")
    t0 = time.perf_counter()
    res["identity"] = identity(be, quick)
    ok = all(v for row in res["identity"] for k, v in row.items() if k not in ("bits", "values"))
    log_line(f"operations against cpu: {'identical' if ok else 'MISMATCH'} ({time.perf_counter() - t0:.1f} s)")
    save()
    t0 = time.perf_counter()
    size = render_size or (16 if quick else 64)
    res["render"] = render_identity(
        backend, size, 256 if quick else render_bits, work, 0 if quick else min(16, os.cpu_count() or 1), log_line
    )
    rok = all(r["identical"] and r["within_bound"] for r in res["render"])
    log_line(f"renders against cpu: {'identical' if rok else 'MISMATCH'} ({time.perf_counter() - t0:.1f} s)")
    save()
    res["throughput"] = throughput(be, quick)
    for label, r in res["throughput"].items():
        unit = "products_per_s" if label == "products" else "pairs_per_s"
        log_line(
            f"{label}: {r[unit]:.3g}/s ({r['speedup_vs_one_core']:.3g}x one core; goal {r['goal']:.1g}/s)"
            + (" stages " + ", ".join(f"{k} {v:.3g} s" for k, v in r["stages_s"].items()) if "stages_s" in r else "")
        )
    save()
    if hasattr(be, "with_defines"):
        res["experiments"] = experiments(be, quick)
        for name, r in res["experiments"].items():
            log_line(
                f"experiment {name}: {'identical' if r['identical'] else 'MISMATCH (not for use)'}; kernels "
                + ", ".join(f"{k} {r[k]:.3g}/s" for k in ("products_per_s", "pairs_per_s") if r.get(k))
            )
        save()
    if not getattr(launcher, "keyholder", True):  # owner.cuh is off on a device (device.py): nothing to time
        res["encryption_skipped"] = (
            "the key holder's kernels are off on a device until they pass there "
            "(hevr/backends/cuda/device.py); benchmarks/gpu_diagnose.py checks them"
        )
        log_line(f"encryption: skipped: {res['encryption_skipped']}")
        res["ok"] = ok and rok
        save()
        return md, bool(res["ok"])
    res["encryption"] = enc = encryption(be, quick)
    log_line(
        f"encryption: {enc['values_per_s']:.3g} values/s at {enc['bits']} bits ({enc['volume_100_s']:.3g} s for "
        f"100^3; {'exact' if enc['exact'] else 'WRONG'})"
    )
    res["ok"] = ok and rok and enc["exact"]
    save()
    return md, bool(res["ok"])
