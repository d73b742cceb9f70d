"""Issue 27: the plaintext side of a frame — rays, weights, plans and task overhead.

Usage::

    python benchmarks/frame_plaintext.py WORKDIR OUT.json [--frames 6] [--big STORE KEY]

WORKDIR holds (or gets) the 64-bit paper-case store: the 100³ phantom, brick 25, scalar and
the 4-dim vector channel, under a 64-bit key, so the arithmetic is nearly free and what is left
is the plaintext work and the task graph. Measured, in one run on one machine:

* ``plain``: :func:`hevr.render_plain` of the same view (the reference the issue compares with);
* ``geometry``: the plaintext work of one frame in one process, all bricks — casting the rays,
  the brick weights and the product plans — as the tasks do it (CPU seconds);
* ``frame``: the resident 64-bit X-ray nearest frame (150², from scratch, ``cache=False``) on a
  fresh 2-worker LocalCluster (processes, one thread each), for each arm of
  ``hevr.render.resident-batch`` (per-brick map tasks against one map task per worker and
  frame), frames alternating between the arms;
* ``--big STORE KEY``: the same frames of a 2048-bit store (nearest and trilinear X-ray, TF
  4-dim nearest) for both arms, to check that they are no slower.

Every frame is decrypted and compared with ``render_plain`` (within ``error_bound``), and the
two arms' packed images must be identical.
"""

from __future__ import annotations

import argparse
import json
import pickle
import statistics
import sys
import time
import warnings
from pathlib import Path

import dask
import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr._bench.measure import machine
from hevr.paper import TF_NODES
from hevr.rendering.footprint import brick_footprints
from hevr.rendering.kernel import plan_products
from hevr.rendering.rays import cast_rays
from hevr.rendering.weights import brick_weights

warnings.simplefilter("ignore")
BATCH_KEY = "hevr.render.resident-batch"


def small_store(work: Path):
    work.mkdir(parents=True, exist_ok=True)
    store, key = work / "paper64.zarr", work / "paper64.key.pkl"
    if not store.exists():
        pub, priv = hevr.generate_keypair(64)
        hevr.encrypt_volume(hevr.phantom(100), store, priv, brick=25, vector_dims=4, progress=False)
        key.write_bytes(pickle.dumps(priv))
    return store, pickle.loads(key.read_bytes())


def geometry_seconds(ev, cam, sampling: str) -> dict:
    """CPU seconds of the plaintext side of one frame, all bricks, in this process."""
    t0 = time.process_time()
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    t1 = time.process_time()
    prints = brick_footprints(cam, ev.shape, ev.spacing, ev.brick, rays.n_samples > 0, 32)
    weights = [brick_weights(rays, ev.shape, ev.spacing, ev.brick, idx, sampling, 1.0, 3)
               for idx, fp in prints.items() if fp.tiles]
    t2 = time.process_time()
    n_vox = int(np.prod(ev.brick))
    for bw in weights:
        plan_products(bw.indptr, bw.voxels, bw.weights, n_vox)
    t3 = time.process_time()
    return {"rays_s": t1 - t0, "weights_s": t2 - t1, "plans_s": t3 - t2, "total_s": t3 - t0,
            "bricks": len(weights), "pairs": int(sum(bw.n_pairs for bw in weights))}


def frames(ev, cam, priv, cases, n: int, client) -> dict:
    """``n`` rounds; in each, one frame per (case, arm), arms alternating."""
    out: dict = {}
    for r in range(n):
        for name, mode, sampling, kw in cases:
            ref = hevr.render_plain(hevr.phantom(100), cam, mode, sampling, **kw)
            bound = hevr.error_bound(ev, cam, mode, sampling, **kw)
            images = {}
            for arm in ((False, True) if r % 2 == 0 else (True, False)):
                with dask.config.set({BATCH_KEY: arm}):
                    t = time.perf_counter()
                    img = hevr.render(ev, cam, mode, sampling, cache=False, progress=False, client=client, **kw)
                    dt = time.perf_counter() - t
                diff = np.abs(img.decrypt(priv) - ref)
                assert np.all(diff <= bound), (name, arm, float(diff.max()))
                err = float(diff.max())
                images[arm] = b"".join(c.tobytes() for c in img.ciphertexts)
                rec = out.setdefault(name, {}).setdefault("batched" if arm else "per-brick", {"s": [], "err": 0.0})
                rec["s"].append(dt)
                rec["err"] = max(rec["err"], err)
                rec["map_tasks"] = img.stats["map_tasks"]
            assert images[True] == images[False], f"{name}: the arms' packed images differ"
    for rec in out.values():
        for arm in rec.values():
            arm["median_s"] = statistics.median(arm["s"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("work", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--big", nargs=2, metavar=("STORE", "KEY"))
    a = ap.parse_args()
    res: dict = {"machine": machine(), "argv": sys.argv[1:]}
    store, priv = small_store(a.work)
    ev = hevr.open_volume(store)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=150, height=150)  # the bench paper case
    vol = hevr.phantom(100)
    t = []
    for _ in range(5):
        t0 = time.perf_counter()
        hevr.render_plain(vol, cam, "xray", "nearest")
        t.append(time.perf_counter() - t0)
    res["plain_nearest_s"] = statistics.median(t)
    res["geometry"] = {s: min((geometry_seconds(ev, cam, s) for _ in range(3)), key=lambda d: d["total_s"])
                       for s in ("nearest", "trilinear")}
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c, Client(c) as cl:
        ev = hevr.open_volume(store).persist(client=cl)
        ev.resident.wait()
        res["small"] = frames(ev, cam, priv, [("xray-nearest-64", "xray", "nearest", {}),
                                              ("xray-trilinear-64", "xray", "trilinear", {})], a.frames, cl)
        if a.big:
            big = hevr.open_volume(a.big[0]).persist(client=cl)
            big.resident.wait()
            bpriv = hevr.load_key(a.big[1])
            res["big"] = frames(big, cam, bpriv, [("xray-nearest-2048", "xray", "nearest", {}),
                                                  ("xray-trilinear-2048", "xray", "trilinear", {}),
                                                  ("tf4-nearest-2048", "tf", "nearest",
                                                   {"nodes": TF_NODES})],
                                max(2, a.frames // 3), cl)
    a.out.write_text(json.dumps(res, indent=1, sort_keys=True))
    small = res["small"]["xray-nearest-64"]
    print(f"plain {res['plain_nearest_s']:.3f} s; geometry nearest {res['geometry']['nearest']['total_s']:.3f} s; "
          f"frame per-brick {small['per-brick']['median_s']:.3f} s, batched {small['batched']['median_s']:.3f} s")


if __name__ == "__main__":
    main()
