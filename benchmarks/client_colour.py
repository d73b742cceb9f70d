"""Issue 25: colour on the client against the paper's server-side finishing, side by side.

Usage::

    python benchmarks/client_colour.py STORE KEY OUT.json [ROUNDS]

STORE: the 100³ phantom with the scalar channel and the 4-dim vector encoding, brick 25,
2048-bit key (owner path). Everything runs on one 2-worker LocalCluster (1 thread each), same
volume and camera (``Camera.orbit(ev, azimuth=30, elevation=20, width=150, height=150)``), every
render from scratch (``cache=False``); the two arms alternate within each round.

End to end = request → decrypted float image on the client (one core): for the server arm
``render(finish="server")`` then ``decrypt``; for the client arm ``render_frame`` (units
decrypted as they complete) then colouring. Finishing multiplications are counted from the
plans (:mod:`hevr.bench.finish_count`). Writes raw numbers to OUT.json.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
import warnings
from functools import partial

import numpy as np
from distributed import Client, LocalCluster, get_task_stream

import hevr
from hevr.bench.finish_count import finishing_modmuls
from hevr.bench.measure import machine
from hevr.paper import PAPER_DENSITIES, PAPER_TF1, TF_NODES
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.planning.modes import combination_matrix, make_spec
from hevr.rendering.planning.planner import plan_render

warnings.simplefilter("ignore")


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def count(ev, cam, mode, sampling, finish, **kw) -> int:
    spec = make_spec(mode, sampling, 1.0, kw.get("density"), kw.get("nodes"), ev.vector_dims, ev.has_scalar)
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    comb = combination_matrix(spec, ev.vector_dims) if spec.needs_vector and finish == "server" else None
    plan = plan_render(
        n=int(ev.public_key.n),
        spec=spec,
        meta=ev.meta,
        n_samples=rays.n_samples,
        digits=3 if sampling == "trilinear" else 0,
        precision=4,
        comb_digits=4,
        pack=True,
        combination=comb,
        finish=finish,
    )
    return finishing_modmuls(plan, rays.n_samples.tolist())


def main(store: str, key: str, out: str, rounds: int = 2) -> None:
    priv = hevr.load_key(key)
    ev = hevr.open_volume(store)
    vol = hevr.phantom(size=ev.shape[0])
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=150, height=150)
    res: dict = {"machine": machine(), "store": store, "bits": ev.public_key.bits, "rounds": rounds, "cases": {}}

    def save():
        with open(out, "w") as f:
            json.dump(res, f, indent=1, sort_keys=True)

    cases = {"tf4-nearest": ("tf", {"nodes": TF_NODES}), "xray-nearest": ("xray", {})}
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as lc, Client(lc) as cl:
        for name, (mode, kw) in cases.items():
            ref = hevr.render_plain(vol, cam, mode=mode, vector_dims=4, **kw)
            cell: dict = {
                "server": [],
                "client": [],
                "finish_modmuls": {f: count(ev, cam, mode, "nearest", f, **kw) for f in ("server", "client")},
            }
            for r in range(rounds):
                for arm in ("server", "client") if r % 2 == 0 else ("client", "server"):
                    t0 = time.perf_counter()
                    if arm == "server":
                        img = hevr.render(
                            ev, cam, mode=mode, client=cl, cache=False, progress=False, finish="server", **kw
                        )
                        rendered = time.perf_counter() - t0
                        arr, dec = timed(partial(img.decrypt, priv))
                        total = time.perf_counter() - t0
                        row = {
                            "render_s": rendered,
                            "decrypt_s": dec,
                            "end_to_end_s": total,
                            "ciphertexts": img.n_ciphertexts,
                            "per_pack": img.per_pack,
                            "pack_bits": img.pack_bits,
                        }
                    else:
                        frame = hevr.render_frame(
                            ev, cam, priv, mode=mode, client=cl, cache=False, progress=False, **kw
                        )
                        arr = frame.image
                        total = time.perf_counter() - t0
                        row = {
                            "end_to_end_s": total,
                            "frame_seconds": frame.stats["seconds"],
                            "decrypt_s": frame.stats["decrypt_s"],
                            "ciphertexts": frame.stats["ciphertexts"],
                        }
                    bound = hevr.error_bound(ev, cam, mode, finish=arm, **kw)
                    err = np.abs(arr - ref)
                    row.update(
                        max_abs_err=float(err.max()),
                        within_bound=bool((err <= bound).all()),
                        bound_max=float(bound.max()),
                    )
                    cell[arm].append(row)
                    print(
                        name, arm, {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}, flush=True
                    )
                    save()
                    if name == "tf4-nearest" and arm == "client" and r == 0:
                        res["recolour"] = recolour_case(frame, cl, ref_args=(vol, cam))
                        save()
            res["cases"][name] = cell
            save()
        res["accuracy"] = accuracy(ev, vol, cam, priv, cl)
        save()


def recolour_case(frame, cl, ref_args) -> dict:
    """Re-colour a decrypted TF frame: time (median of 20), tasks on the cluster meanwhile, accuracy."""
    vol, cam = ref_args
    others = [("tf", {"nodes": PAPER_TF1}), ("emphasize", {"density": PAPER_DENSITIES[1]}), ("tf", {"nodes": TF_NODES})]
    times = []
    with get_task_stream(client=cl) as ts:
        for _ in range(20):
            for mode, kw in others:
                _, s = timed(partial(frame.recolour, mode, **kw))
                times.append(s)
    errs = {}
    for mode, kw in others:
        ref = hevr.render_plain(vol, cam, mode=mode, vector_dims=4, **kw)
        errs[f"{mode}:{kw}"] = float(np.abs(frame.recolour(mode, **kw) - ref).max())
    return {
        "median_s": statistics.median(times),
        "max_s": max(times),
        "cluster_tasks": len(ts.data),
        "max_abs_err": errs,
    }


def accuracy(ev, vol, cam, priv, cl) -> dict:
    """Max error against render_plain for every mode, both ways (nearest; the server arm's
    emphasis re-finishes the cached TF sums, the client arm re-colours its frame)."""
    out = {}
    frame = hevr.render_frame(ev, cam, priv, mode="tf", nodes=TF_NODES, client=cl, progress=False)
    hevr.render(ev, cam, mode="tf", nodes=TF_NODES, client=cl, progress=False, finish="server")  # caches the sums
    for mode, kw in (("emphasize", {"density": PAPER_DENSITIES[1]}), ("tf", {"nodes": PAPER_TF1})):
        ref = hevr.render_plain(vol, cam, mode=mode, vector_dims=4, **kw)
        server = hevr.render(ev, cam, mode=mode, client=cl, progress=False, finish="server", **kw).decrypt(priv)
        out[mode] = {
            "server": float(np.abs(server - ref).max()),
            "client": float(np.abs(frame.recolour(mode, **kw) - ref).max()),
            "bound_server": float(hevr.error_bound(ev, cam, mode, finish="server", **kw).max()),
            "bound_client": float(hevr.error_bound(ev, cam, mode, finish="client", **kw).max()),
        }
    return out


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]) if len(sys.argv) > 4 else 2)
