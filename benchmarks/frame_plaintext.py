"""Issue 27: the plaintext side of a frame — rays, weights, plans and task overhead.

Usage::

    python benchmarks/frame_plaintext.py WORKDIR OUT.json [--frames 6] [--big STORE KEY]

WORKDIR holds (or gets) the 64-bit paper-case store: the 100³ phantom, brick 25, scalar and
the 4-dim vector channel, under a 64-bit key, so the arithmetic is nearly free and what is left
is the plaintext work and the task graph. Measured, in one run on one machine:

* ``plain``: :func:`hevr.render_plain` of the same view (the reference the issue compares with),
  in a fresh process (``plain_fresh_s``) and in this one after :func:`hevr.runtime.malloc.tune`
  (``plain_nearest_s``, the faster: the ratios are taken against it);
* ``geometry``: the plaintext work of one frame in one process, all bricks — casting the rays,
  the brick weights and the product plans — as the tasks do it (CPU seconds);
* ``frame``: the resident 64-bit frames (150², from scratch, ``cache=False``) on a fresh 2-worker
  LocalCluster (processes, one thread each), for each arm — per-brick map tasks (``cpu``), one
  map task per worker and frame (``cpu``, ``cuda-host``) and the defaults (backend ``"auto"``) —
  frames alternating between the arms; with ``--malloc-ab`` the default arm also on a second
  cluster started with ``hevr.malloc-tuning: false`` (Dask's worker allocator settings);
* ``--big STORE KEY``: the same frames of a 2048-bit store (nearest and trilinear X-ray, TF
  4-dim nearest) for both arms, to check that they are no slower.

Every frame is decrypted and compared with ``render_plain`` (within ``error_bound``), and the
two arms' packed images must be identical.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import pickle
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

import dask
import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr.bench.measure import machine
from hevr.paper import TF_NODES
from hevr.rendering.geometry.footprint import brick_footprints
from hevr.rendering.geometry.group_weights import nearest_group_rows
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.geometry.weights import brick_weights
from hevr.rendering.pipeline.kernel import plan_products
from hevr.runtime import malloc as _malloc

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
    """CPU seconds of the per-brick path's plaintext work of one frame, all bricks, in this process."""
    t0 = time.process_time()
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    t1 = time.process_time()
    prints = brick_footprints(cam, ev.shape, ev.spacing, ev.brick, rays.n_samples > 0, 32)
    weights = [
        brick_weights(rays, ev.shape, ev.spacing, ev.brick, idx, sampling, 1.0, 3)
        for idx, fp in prints.items()
        if fp.tiles
    ]
    t2 = time.process_time()
    n_vox = int(np.prod(ev.brick))
    for bw in weights:
        plan_products(bw.indptr, bw.voxels, bw.weights, n_vox)
    t3 = time.process_time()
    return {
        "rays_s": t1 - t0,
        "weights_s": t2 - t1,
        "plans_s": t3 - t2,
        "total_s": t3 - t0,
        "bricks": len(weights),
        "pairs": int(sum(bw.n_pairs for bw in weights)),
    }


def frames(vols: dict, cam, priv, cases, arms, n: int, client) -> dict:
    """``n`` rounds; in each, one frame per (case, arm), the arms' order alternating.

    ``arms``: ``(label, batch, backend[, client])`` (backend None: the default, ``"auto"``);
    ``vols``: backend (or label) -> the resident volume in its form. Every frame is checked
    against ``render_plain``; all arms' packed images must be identical.
    """
    out: dict = {}
    for r in range(n):
        for name, mode, sampling, kw in cases:
            any_ev = next(iter(vols.values()))
            ref = hevr.render_plain(hevr.phantom(100), cam, mode, sampling, **kw)
            bound = hevr.error_bound(any_ev, cam, mode, sampling, **kw)
            images = {}
            for label, batch, backend, *own in arms if r % 2 == 0 else arms[::-1]:
                with dask.config.set({BATCH_KEY: batch}):
                    t = time.perf_counter()
                    img = hevr.render(
                        vols[label if own or backend is None else backend],
                        cam,
                        mode,
                        sampling,
                        cache=False,
                        progress=False,
                        client=own[0] if own else client,
                        backend=backend,
                        **kw,
                    )
                    dt = time.perf_counter() - t
                diff = np.abs(img.decrypt(priv) - ref)
                assert np.all(diff <= bound), (name, label, float(diff.max()))
                images[label] = b"".join(c.tobytes() for c in img.ciphertexts)
                rec = out.setdefault(name, {}).setdefault(label, {"s": [], "err": 0.0})
                rec["s"].append(dt)
                rec["err"] = max(rec["err"], float(diff.max()))
                rec["map_tasks"] = img.stats["map_tasks"]
                rec["backend"] = img.stats["backend"]
            assert len(set(images.values())) == 1, f"{name}: the arms' packed images differ"
    for rec in out.values():
        for arm in rec.values():
            arm["median_s"] = statistics.median(arm["s"])
    return out


def group_geometry_seconds(ev, cam, workers: int = 2) -> dict:
    """CPU seconds of the batched nearest path's plaintext work, all bricks, in this process:
    the rays, each worker slab's rows (one pass) and its one product plan."""
    idx = ev.brick_indices()
    t0 = time.process_time()
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    t1 = time.process_time()
    groups = [idx[i * len(idx) // workers : (i + 1) * len(idx) // workers] for i in range(workers)]
    rows = [nearest_group_rows(rays, ev.shape, ev.spacing, ev.brick, g, 1.0) for g in groups]
    t2 = time.process_time()
    for g, rw in zip(groups, rows):
        sizes = [int(np.prod(ev.brick_shape(i))) for i in g]
        plan_products(rw.indptr, rw.voxels(sizes), rw.weights, sum(sizes))
    t3 = time.process_time()
    return {
        "rays_s": t1 - t0,
        "weights_s": t2 - t1,
        "plans_s": t3 - t2,
        "total_s": t3 - t0,
        "groups": workers,
        "pairs": int(sum(int(rw.indptr[-1]) for rw in rows)),
    }


def plain_fresh(cam) -> float:
    """``render_plain`` of the view ``cam`` in a fresh process (its allocator untouched)."""
    code = (
        "import json, statistics, sys, time, hevr\n"
        "vol = hevr.phantom(100)\n"
        "cam = hevr.Camera.from_dict(json.loads(sys.argv[1]))\n"
        "t = []\n"
        "for _ in range(5):\n"
        "    t0 = time.perf_counter(); hevr.render_plain(vol, cam, 'xray', 'nearest'); "
        "t.append(time.perf_counter() - t0)\n"
        "print(statistics.median(t))\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, json.dumps(cam.to_dict())], capture_output=True, text=True, check=True
    )
    return float(run.stdout)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("work", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--big", nargs=2, metavar=("STORE", "KEY"))
    ap.add_argument("--malloc-ab", action="store_true")
    a = ap.parse_args()
    res: dict = {"machine": machine(), "argv": sys.argv[1:]}
    store, priv = small_store(a.work)
    ev = hevr.open_volume(store)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=150, height=150)  # the bench paper case
    vol = hevr.phantom(100)
    res["plain_fresh_s"] = plain_fresh(cam)
    _malloc.tune()
    t = []
    for _ in range(5):
        t0 = time.perf_counter()
        hevr.render_plain(vol, cam, "xray", "nearest")
        t.append(time.perf_counter() - t0)
    res["plain_nearest_s"] = statistics.median(t)
    res["geometry"] = {
        s: min((geometry_seconds(ev, cam, s) for _ in range(3)), key=lambda d: d["total_s"])
        for s in ("nearest", "trilinear")
    }
    res["geometry_batched"] = min((group_geometry_seconds(ev, cam) for _ in range(5)), key=lambda d: d["total_s"])
    arms = [
        ("per-brick cpu", False, "cpu"),
        ("batched cpu", True, "cpu"),
        ("batched cuda-host", True, "cuda-host"),
        ("default", "auto", None),
    ]
    with contextlib.ExitStack() as stack:
        c = stack.enter_context(LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None))
        cl = stack.enter_context(Client(c))
        vols = {b: hevr.open_volume(store).persist(client=cl, backend=b) for b in ("cpu", "cuda-host")}
        vols["default"] = hevr.open_volume(store).persist(client=cl)
        if a.malloc_ab:  # a second cluster whose workers keep Dask's allocator settings
            with dask.config.set({"hevr.malloc-tuning": False}):
                c2 = stack.enter_context(LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None))
            cl2 = stack.enter_context(Client(c2, set_as_default=False))
            vols["default, malloc untuned"] = hevr.open_volume(store).persist(client=cl2)
            arms.append(("default, malloc untuned", "auto", None, cl2))
        for v in vols.values():
            v.resident.wait()
        res["small"] = frames(
            vols,
            cam,
            priv,
            [
                ("xray-nearest-64", "xray", "nearest", {}),
                ("xray-trilinear-64", "xray", "trilinear", {}),
                ("tf4-nearest-64", "tf", "nearest", {"nodes": TF_NODES}),
            ],
            arms,
            a.frames,
            cl,
        )
        for v in vols.values():
            v.resident.release()
        if a.big:
            big = hevr.open_volume(a.big[0]).persist(client=cl)
            big.resident.wait()
            bpriv = hevr.load_key(a.big[1])
            res["big"] = frames(
                {"cpu": big},
                cam,
                bpriv,
                [
                    ("xray-nearest-2048", "xray", "nearest", {}),
                    ("xray-trilinear-2048", "xray", "trilinear", {}),
                    ("tf4-nearest-2048", "tf", "nearest", {"nodes": TF_NODES}),
                ],
                arms[:2],
                max(2, a.frames // 2),
                cl,
            )
    a.out.write_text(json.dumps(res, indent=1, sort_keys=True))
    for name, rec in res["small"].items():
        print(name, "  ".join(f"{k}: {v['median_s']:.3f} s ({v['map_tasks']} maps)" for k, v in rec.items()))
    print(
        f"plain {res['plain_nearest_s']:.3f} s (fresh process {res['plain_fresh_s']:.3f} s); "
        f"geometry per-brick {res['geometry']['nearest']['total_s']:.3f} s, "
        f"batched {res['geometry_batched']['total_s']:.3f} s"
    )


if __name__ == "__main__":
    main()
