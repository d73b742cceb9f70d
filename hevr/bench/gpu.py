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
5. **experiments** — each of the kernel source's experiments
   (:data:`~hevr.bench.gpu_operations.EXPERIMENTS`, e.g. ``HEVR_CIOS_REG`` in ``mont.cuh``) compiled
   in: step 2's checks and step 4's kernel rates, so a GPU session decides from one run whether an
   experiment becomes the default;
6. **encryption** — the owner path in a kernel (``owner.cuh``): 64³ int64 mantissas under a
   2048-bit key, values/s beside ``cpu`` on one core, the projected time of a 100³ volume (goal
   3 s), and a sample decrypted exactly;

Any mismatch makes the command exit 1 after writing what it found. ``backend`` may be
``cuda-host`` (the same kernels on the CPU), which is how the test suite runs this command on a
machine without a GPU; the issue's goals (≥ 1.0·10⁸ 4096-bit products/s, ≥ 2·10⁷ pairs/s on one
H100) are printed beside the figures, never asserted.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

from ..backends import get_backend
from .gpu_operations import encryption, experiments, identity, throughput
from .gpu_renders import render_identity
from .gpu_report import markdown
from .measure import machine

log = logging.getLogger(__name__)

__all__ = ["run_gpu_bench"]


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
    device_name = getattr(launcher, "device_name", None)
    device = device_name() if device_name is not None else f"the host CPU ({backend})"
    res: dict = {"machine": machine(), "backend": backend, "device": device, "quick": quick}
    md, js = out / "gpu.md", out / "gpu.json"

    def save() -> None:
        js.write_text(json.dumps(res, indent=1, default=str))
        md.write_text(markdown(res))

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
