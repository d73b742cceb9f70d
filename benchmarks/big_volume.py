"""Issue 13: a 256³ volume (512-bit key, 256² image) on the 2-core machine — client memory and
graph-build work grow with the work, not with bricks × pixels.

Usage::

    python benchmarks/big_volume.py WORKDIR OUT.json [--no-mask]

Encrypts a 256³ phantom (brick 32: 512 bricks) with the owner path (``--no-mask``: without the
random mask — the client-side numbers do not depend on it, render times do), then on a
2-worker LocalCluster measures: the client's graph build (seconds, tracemalloc peak, task and
edge counts) for 64², 128² and 256² images, the same for a 128³ crop, and one X-ray nearest
frame at 256², streamed, compared with render_plain within error_bound.
"""

from __future__ import annotations

import json
import sys
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr.bench.measure import machine
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.pipeline.graph import build_sums_graph

warnings.simplefilter("ignore")


def graph_cost(ev, size: int) -> dict:
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=size, height=size)
    tracemalloc.start()
    t = time.perf_counter()
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    g = build_sums_graph(ev, cam, rays, "nearest", 1.0, 0, "scalar", 32, (-(-size // 32)) ** 2)
    dt = time.perf_counter() - t
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        "pixels": size * size,
        "bricks": int(np.prod(ev.grid)),
        "map_tasks": g.map_tasks,
        "edges": g.edges,
        "tasks": len(dict(g.dsk)),
        "seconds": dt,
        "peak_bytes": peak,
        "samples": int(rays.n_samples.sum()),
    }


def main(work: str, out: str, mask: bool) -> None:
    work_p = Path(work)
    work_p.mkdir(parents=True, exist_ok=True)
    res: dict = {"machine": machine(), "masked": mask}
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c, Client(c) as cl:
        vol = hevr.phantom(256)
        if (work_p / "key.json").exists():  # a second run on the same stores: measure, do not re-encrypt
            priv = hevr.load_key(work_p / "key.json")
            ev, small = hevr.open_volume(work_p / "big.zarr"), hevr.open_volume(work_p / "crop.zarr")
            res["encrypt_s"] = None
        else:
            pub, priv = hevr.generate_keypair(512)
            t = time.perf_counter()
            ev = hevr.encrypt_volume(
                vol, work_p / "big.zarr", priv, brick=32, overwrite=True, progress=False, unsafe_no_obfuscation=not mask
            )
            res["encrypt_s"] = time.perf_counter() - t
            small = hevr.encrypt_volume(
                vol[:128, :128, :128],
                work_p / "crop.zarr",
                priv,
                brick=32,
                overwrite=True,
                progress=False,
                unsafe_no_obfuscation=not mask,
            )
            priv.save(work_p / "key.json")
        res["graph"] = [graph_cost(ev, s) for s in (64, 128, 256)] + [graph_cost(small, s) for s in (64, 128, 256)]
        for g in res["graph"]:
            print(g, flush=True)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=256, height=256)
        tracemalloc.start()
        t = time.perf_counter()
        img = hevr.render(ev, cam, client=cl, progress=False, cache=False)
        res["render_s"] = time.perf_counter() - t
        res["render_client_peak_bytes"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        arr = img.decrypt(priv)
        ref = hevr.render_plain(vol, cam)
        res["within_bound"] = bool(np.all(np.abs(arr - ref) <= hevr.error_bound(ev, cam)))
        res["stats"] = {k: v for k, v in img.stats.items()}
        print(res["render_s"], res["within_bound"], flush=True)
    Path(out).write_text(json.dumps(res, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], "--no-mask" not in sys.argv)
