"""Issue 13: the render pipeline at cluster scale, measured on existing paper-case stores.

Usage::

    python benchmarks/pipeline.py SCALAR_STORE VECTOR_STORE KEY SMALL_STORE OUT.json

SCALAR_STORE: 100³ phantom, scalar, brick 25, 2048-bit key (owner-encrypted, masked);
VECTOR_STORE: the same volume with the 4-dim vector encoding only; SMALL_STORE: the same
volume under a 64-bit key. Every case runs on a fresh LocalCluster of N processes × 1
thread; each render is from scratch (``cache=False``) unless it measures re-colouring.
Writes raw numbers to OUT.json; ``benchmarks/history.md`` has the table made from them.
"""

from __future__ import annotations

import json
import os
import sys
import time
import warnings
from functools import partial

import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr.bench.measure import machine
from hevr.bench.pipeline import predict, trace_frame
from hevr.paper import TF_NODES

warnings.simplefilter("ignore")


def cluster(n: int) -> tuple[LocalCluster, Client]:
    c = LocalCluster(n_workers=n, threads_per_worker=1, dashboard_address=None)
    return c, Client(c)


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def slim(trace: dict) -> dict:
    return {k: v for k, v in trace.items() if k not in ("durations", "deps")}


def main(scalar: str, vector: str, key: str, small: str, out: str) -> None:
    priv = hevr.load_key(key)
    cores = os.cpu_count() or 1
    res: dict = {"machine": machine(), "cores": cores, "cases": {}}

    def save():
        with open(out, "w") as f:
            json.dump(res, f, indent=1, sort_keys=True)

    # 1. The paper case on 2 workers, streamed and resident; the model from the traced frames.
    c, cl = cluster(2)
    with c, cl:
        for name, path, mode, sampling in (
            ("xray-nearest", scalar, "xray", "nearest"),
            ("xray-trilinear", scalar, "xray", "trilinear"),
            ("tf4-nearest", vector, "tf", "nearest"),
        ):
            ev = hevr.open_volume(path)
            cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20)
            kw = {"mode": mode, "sampling": sampling} | ({"nodes": TF_NODES} if mode == "tf" else {})
            streamed = trace_frame(cl, ev, cam, **kw)
            rv, persist_s = timed(ev.persist)
            (_, wait_s) = timed(rv.resident.wait)
            first = trace_frame(cl, rv, cam, **kw)
            second = trace_frame(cl, rv, cam, **kw)
            cell = {
                "streamed": slim(streamed),
                "resident_first": slim(first),
                "resident_second": slim(second),
                "persist_s": persist_s + wait_s,
                "resident_bytes": dict(rv.resident.worker_bytes),
                "model": predict(second, [1, 2, 4, 8, 16, 32, 64]),
                "model_streamed": predict(streamed, [1, 2, 4, 8, 16, 32, 64]),
            }
            if mode == "tf":  # re-colouring: the sums stay on the workers
                hevr.clear_cache()
                img = hevr.render(rv, cam, client=cl, progress=False, **kw)
                ref = img.decrypt(priv)
                again, t_re = timed(
                    partial(hevr.render, rv, cam, mode="tf", nodes=TF_NODES[:2], client=cl, progress=False)
                )
                cell["recolour"] = {"seconds": t_re, "stats": {k: v for k, v in again.stats.items()}}
                cell["recolour"]["ok"] = bool(np.isfinite(again.decrypt(priv)).all() and np.isfinite(ref).all())
                hevr.clear_cache()
            img = hevr.render(rv, cam, client=cl, progress=False, cache=False, **kw)
            img2 = hevr.render(ev, cam, client=cl, progress=False, cache=False, **kw)
            cell["identical"] = bool(np.array_equal(img.decrypt(priv), img2.decrypt(priv)))
            rv.resident.release()
            res["cases"][name] = cell
            print(
                name,
                {k: round(cell[k]["wall"], 2) for k in ("streamed", "resident_first", "resident_second")},
                "tail",
                round(cell["resident_second"]["tail"], 2),
                flush=True,
            )
            save()
    # 2. Measured frame time against N (N > cores marked oversubscribed), resident X-ray nearest.
    res["workers"] = {}
    for n in sorted({1, 2, cores, cores + 1, 2 * cores}):
        c, cl = cluster(n)
        with c, cl:
            ev = hevr.open_volume(scalar).persist()
            ev.resident.wait()
            cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20)
            trace_frame(cl, ev, cam)  # warm
            tr = trace_frame(cl, ev, cam)
            res["workers"][str(n)] = {
                "trace": slim(tr),
                "oversubscribed": n > cores,
                "model_from_this": predict(tr, [1, 2, 4, 8, 16, 64]),
            }
            print("workers", n, round(tr["wall"], 2), flush=True)
            save()
    # 3. Small frames: 64-bit key, 150² nearest, streamed and resident.
    c, cl = cluster(2)
    with c, cl:
        ev = hevr.open_volume(small)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20)
        walls = {"streamed": [], "resident": []}
        for _ in range(3):
            walls["streamed"].append(timed(lambda: hevr.render(ev, cam, client=cl, progress=False, cache=False))[1])
        rv = ev.persist()
        rv.resident.wait()
        for _ in range(5):
            walls["resident"].append(timed(lambda: hevr.render(rv, cam, client=cl, progress=False, cache=False))[1])
        res["small"] = {"bits": ev.public_key.bits, "walls": walls, "trace": slim(trace_frame(cl, rv, cam))}
        print("small", walls, flush=True)
        save()


if __name__ == "__main__":
    main(*sys.argv[1:6])
