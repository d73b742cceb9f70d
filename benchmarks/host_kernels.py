"""The host build of the CUDA kernels (backend ``cuda-host``) against gmpy2 (``cpu``), one run.

Usage::

    python benchmarks/host_kernels.py [--bits 64] [--repeat 3] [--quick] [--no-append]

Measured in one process, both backends interleaved, CPU time of this process (best of
``--repeat``; the machine is shared, so only the ratios of one run are compared):

* ``brick``: one brick's :meth:`~hevr.backends.base.Backend.ray_products` — the paper case's
  busiest brick (100³ volume, brick 25, 150² image, azimuth 30°, elevation 20°) for nearest and
  trilinear sampling, at 64, 256, 1024 and 2048-bit keys; the batch is already in the backend's
  form (Montgomery form for cuda-host), as for a resident brick.
* ``frame map``: the map step of the whole ``--bits`` paper-case frame, every brick as a map task
  does it after the geometry: records -> batch (``from_bytes``; cuda-host then converts to
  Montgomery form inside its first operation), ``ray_products`` for K components (1: scalar
  X-ray; 4: the 4-dim vector channel of TF 4-dim), records of the products (``to_bytes``). The
  geometry and the product plans are made once, outside the timing, and reported beside it.

The ciphertexts are random residues below n² with n of the stated size (the cost of the
arithmetic does not depend on them being encryptions). Results: ``results-host-kernels.json``
and a section appended to ``history.md`` (neither with ``--no-append``).
"""

from __future__ import annotations

import argparse
import json
import secrets
import sys
import time
from pathlib import Path

import numpy as np

from hevr.backends import CpuBackend, CudaHostBackend
from hevr.bench.measure import machine
from hevr.crypto.records import record_width
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.geometry.weights import brick_weights
from hevr.rendering.pipeline.kernel import plan_products

HERE = Path(__file__).resolve().parent
SIZE, IMAGE, BRICK = 100, 150, 25
BACKENDS = (CpuBackend(), CudaHostBackend())


def geometry(sampling: str, quick: bool) -> tuple[list, float]:
    """Per brick with pairs: (indptr, voxels, weights, plan); and the CPU seconds of plans."""
    shape, sp, brick = (SIZE,) * 3, (1.0,) * 3, (BRICK,) * 3
    image = 60 if quick else IMAGE
    cam = Camera.orbit(shape, azimuth=30, elevation=20, width=image, height=image)
    rays = cast_rays(cam, shape, sp, 1.0)
    out, plans_s = [], 0.0
    nb = -(-SIZE // BRICK)
    for idx in np.ndindex(nb, nb, nb):
        bw = brick_weights(rays, shape, sp, brick, idx, sampling, 1.0, 3)
        if bw.indptr[-1] == 0:
            continue
        t0 = time.process_time()
        plan = plan_products(bw.indptr, bw.voxels, bw.weights, BRICK**3)
        plans_s += time.process_time() - t0
        out.append(plan)
    return out, plans_s


def residues(bits: int, count: int) -> tuple[int, int, np.ndarray]:
    n = secrets.randbits(bits) | 1 | (3 << (bits - 2))
    width = record_width(n)
    raw = np.frombuffer(secrets.token_bytes(count * width), np.uint8).reshape(count, width).copy()
    raw[:, 0] = 0  # below 2^(8W - 8) < n²
    return n * n, width, raw


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def brick_case(plans: list, bits: int, repeat: int) -> dict:
    plan = max(plans, key=lambda p: p.n_pairs)
    n2, _, raw = residues(bits, BRICK**3)
    row = {"bits": bits, "pairs": plan.n_pairs, "rows": plan.n_rows}
    for be in BACKENDS:
        batch = be.from_bytes(raw)
        be.ray_products(plan, [batch], n2)  # warm: the library is built, the batch converted
        row[be.name] = best(lambda be=be, batch=batch: be.ray_products(plan, [batch], n2), repeat)
    row["ratio"] = row["cpu"] / row["cuda-host"]
    return row


def frame_case(plans: list, bits: int, K: int, repeat: int) -> dict:
    n2, width, raw = residues(bits, BRICK**3 * K)
    recs = raw.reshape(K, BRICK**3, width)
    row = {"bits": bits, "K": K, "bricks": len(plans), "pairs": sum(p.n_pairs for p in plans)}

    def run(be):
        for plan in plans:
            comps = [be.from_bytes(recs[k]) for k in range(K)]
            prods = be.ray_products(plan, comps, n2)
            np.stack([be.to_bytes(p, width) for p in prods], axis=1)

    run(BACKENDS[1])  # cuda-host's library is built outside the timing
    times = {be.name: [] for be in BACKENDS}
    for _ in range(repeat):  # interleaved: a burst of load hits both arms alike
        for be in BACKENDS:
            times[be.name].append(best(lambda be=be: run(be), 1))
    row.update({name: min(t) for name, t in times.items()})
    row["ratio"] = row["cpu"] / row["cuda-host"]
    return row


def report(res: dict) -> str:
    m = res["machine"]
    head = (
        f"Machine: {m['cpu']} · {m['cores']} cores · {m['os']} · Python {m['versions']['python']} · gmpy2 "
        f"{m['versions']['gmpy2']} · {m['date']} · commit {m['commit']} · load average "
        f"{m['load_average_start']:.2f}. CPU seconds of this process, best of {res['repeat']}, both backends in "
        "one run (ratio = cpu / cuda-host: > 1 means cuda-host is faster)."
    )
    lines = [
        "## host_kernels.py — the CUDA kernels' host build (cuda-host) against gmpy2 (cpu)",
        "",
        head,
        "",
        "| case | bits | pairs | cpu ms | cuda-host ms | ratio |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in res["brick"]:
        lines.append(
            f"| one brick, {r['sampling']} | {r['bits']} | {r['pairs']:,} | {1e3 * r['cpu']:.1f} | "
            f"{1e3 * r['cuda-host']:.1f} | **{r['ratio']:.2f}** |"
        )
    for r in res["frame"]:
        lines.append(
            f"| frame map, {r['sampling']}, K={r['K']} ({r['bricks']} bricks) | {r['bits']} | "
            f"{r['pairs']:,} | {1e3 * r['cpu']:.0f} | {1e3 * r['cuda-host']:.0f} | **{r['ratio']:.2f}** |"
        )
    lines += [
        "",
        "Plans (shared by both backends, not in the frame times): "
        + ", ".join(f"{s} {1e3 * t:.0f} ms" for s, t in res["plans_s"].items())
        + ".",
    ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bits", type=int, default=64, help="key bits of the frame-map case")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="a 60² image, brick cases at 64 and 256 bits only")
    ap.add_argument(
        "--no-append", action="store_true", help="only print: write neither history.md nor results-host-kernels.json"
    )
    args = ap.parse_args(argv)
    res: dict = {
        "machine": machine(),
        "repeat": args.repeat,
        "case": f"{SIZE}^3, brick {BRICK}, image {IMAGE}^2",
        "brick": [],
        "frame": [],
        "plans_s": {},
    }
    for sampling in ("nearest", "trilinear"):
        plans, res["plans_s"][sampling] = geometry(sampling, args.quick)
        for bits in (64, 256) if args.quick else (64, 256, 1024, 2048):
            res["brick"].append({"sampling": sampling, **brick_case(plans, bits, args.repeat)})
            print(res["brick"][-1], file=sys.stderr)
        for K in (1, 4):
            res["frame"].append({"sampling": sampling, **frame_case(plans, args.bits, K, args.repeat)})
            print(res["frame"][-1], file=sys.stderr)
    text = report(res)
    print(text)
    if not args.no_append:
        (HERE / "results-host-kernels.json").write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
        with (HERE / "history.md").open("a", encoding="utf-8") as fh:
            fh.write("\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
