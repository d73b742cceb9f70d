"""`hevr serve` against in-process renders on one Dask cluster (the remote path's overhead, then
its throughput with several key holders).

Usage::

    python benchmarks/serve.py --quick          # 512-bit key, 32³, 48² px: a smoke check, < 1 min
    python benchmarks/serve.py                  # 2048-bit key, 100³ phantom, 150² px (the full run)

One 2-worker LocalCluster (processes, one thread each); the phantom, scalar channel, brick 32,
encrypted on the owner's path with ``verifiable=True`` and cached in ``--store-dir`` with its key
pair (reused while the key matches). The bricks are resident (``ev.persist``); the server runs in
this process, in a background thread (:func:`hevr.serve.run.serve`, uvicorn on 127.0.0.1, port 0)
on the same Dask client, and the key holder talks to it with :func:`hevr.remote.connect`.

1. **Frame**: X-ray, nearest, ``verify=False``; ``--frames`` remote and in-process
   (``cache=False``) frames, and in-process ``cache=True`` ones (what the server runs: it keeps
   the ray sums), taken in turn, each on a camera of its own (azimuth 30° + 0.5°·i: the
   server keeps the ray sums of recent views, so a repeated camera would time a cache hit).
   Median and min of each, ratio and difference; the issue's goal is remote ≤ 1.05 × in-process +
   30 ms (medians). One verified frame each way, and one camera rendered both ways and decrypted
   (the images must be identical).
2. **Throughput**: 1, 2 and 4 concurrent key holders (threads, each with its own ``connect``),
   each rendering new cameras for ``--seconds``; total frames/s and per-frame latency.

Writes ``benchmarks/results-serve[-quick].json``, prints the tables, appends them to
``benchmarks/history.md`` (not with ``--no-history``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import shutil
import statistics
import sys
import threading
import time
import warnings
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from _machine import append, machine  # noqa: E402

import hevr  # noqa: E402

FULL = {"bits": 2048, "size": 100, "image": 150, "brick": 32, "frames": 7, "seconds": 60.0}
QUICK = {"bits": 512, "size": 32, "image": 48, "brick": 16, "frames": 5, "seconds": 4.0}
CAMERAS = itertools.count()  # every frame of the run gets a camera of its own


def camera(ev, W: int) -> hevr.Camera:
    i = next(CAMERAS)
    return hevr.Camera.orbit(ev, azimuth=(30 + 0.5 * i) % 360, elevation=20 + (i // 720), width=W, height=W)


def store(cfg: dict, root: Path, client) -> tuple:
    """(private key, opened store, seconds spent encrypting or None when reused)."""
    d = root / f"phantom{cfg['size']}-{cfg['bits']}bit-brick{cfg['brick']}"
    key_path, path = d / "key.json", d / "scalar.zarr"
    if key_path.exists() and path.exists():
        try:
            priv = hevr.load_key(key_path)
            ev = hevr.open_volume(path)
            if isinstance(priv, hevr.PrivateKey) and ev.public_key == priv.public_key and ev.meta.tags:
                return priv, ev, None
        except hevr.HevrError as exc:
            print(f"store in {d} not reusable ({exc}); encrypting again", flush=True)
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    pub, priv = hevr.generate_keypair(cfg["bits"])
    priv.save(key_path)
    pub.save(d / "pub.json")
    print(f"encrypting {cfg['size']}³ at {cfg['bits']} bits into {path} ...", flush=True)
    t = time.perf_counter()
    ev = hevr.encrypt_volume(
        hevr.phantom(cfg["size"]), path, priv, brick=cfg["brick"], progress=False, client=client, verifiable=True
    )
    return priv, ev, time.perf_counter() - t


def start_server(stores: dict, client) -> str:
    """Run ``hevr serve``'s :func:`serve` in a daemon thread; its URL once it listens."""
    from hevr.serve.run import serve

    ready: list = []
    t = threading.Thread(
        target=serve,
        args=(stores,),
        daemon=True,
        name="hevr-serve",
        kwargs={"host": "127.0.0.1", "port": 0, "client": client, "on_ready": ready.append},
    )
    t.start()
    deadline = time.monotonic() + 30
    while not ready:
        if not t.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("the server did not start")
        time.sleep(0.02)
    return ready[0]


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def summary(xs: list) -> dict:
    return {"n": len(xs), "median": statistics.median(xs), "min": min(xs), "max": max(xs)}


def throughput(url: str, sid: str, ev, W: int, clients: int, seconds: float) -> dict:
    """``clients`` key holders, each its own connection, rendering new cameras until ``seconds`` pass."""
    conns = [hevr.remote.connect(url, timeout=600) for _ in range(clients)]
    rvs = [c.open(sid) for c in conns]
    records, busy, errors = [], [0], []
    lock, barrier = threading.Lock(), threading.Barrier(clients + 1)

    def holder(rv) -> None:
        barrier.wait()
        while time.perf_counter() < t_end:
            cam = camera(ev, W)
            t = time.perf_counter()
            try:
                img = hevr.render(rv, cam, progress=False, verify=False)
            except hevr.errors.RemoteError as exc:
                with lock:
                    (busy.__setitem__(0, busy[0] + 1) if exc.status == 429 else errors.append(str(exc)[:300]))
                time.sleep(0.2)
                continue
            end = time.perf_counter()
            with lock:
                records.append((t, end, end - t, bool(img.stats.get("reused_ray_sums"))))

    threads = [threading.Thread(target=holder, args=(rv,)) for rv in rvs]
    for th in threads:
        th.start()
    t0 = time.perf_counter()
    t_end = t0 + seconds
    barrier.wait()
    for th in threads:
        th.join()
    for c in conns:
        c.close()
    wall = max(r[1] for r in records) - t0 if records else float("nan")
    lat = [r[2] for r in records]
    return {
        "clients": clients,
        "frames": len(records),
        "wall_s": wall,
        "fps": len(records) / wall,
        "latency": summary(lat) if lat else None,
        "reused": sum(r[3] for r in records),
        "busy_429": busy[0],
        "errors": errors,
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="512-bit key, 32³, 48² px: a smoke check")
    ap.add_argument("--store-dir", type=Path, default=Path("/tmp/hevr-bench-serve"))
    ap.add_argument("--frames", type=int, help="timed frames per path (default 7, quick 5)")
    ap.add_argument("--seconds", type=float, help="throughput: seconds per client count (default 60, quick 4)")
    ap.add_argument("--clients", default="1,2,4")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-verified", action="store_true", help="skip the verified frames")
    ap.add_argument("--json", type=Path, help="default benchmarks/results-serve[-quick].json")
    ap.add_argument("--no-history", action="store_true")
    args = ap.parse_args(argv)
    cfg = dict(QUICK if args.quick else FULL)
    cfg.update({k: v for k, v in (("frames", args.frames), ("seconds", args.seconds)) if v is not None})
    W = cfg["image"]
    warnings.simplefilter("ignore")  # 512-bit keys, key file permissions
    import dask
    from distributed import Client, LocalCluster

    t_run = time.perf_counter()
    out: dict = {
        "config": cfg,
        "machine": machine(),
        "hevr": hevr.__version__,
        "dask": dask.__version__,
        "python": platform.python_version(),
        "cores": os.cpu_count(),
        "workers": args.workers,
        "load_average_start": os.getloadavg(),
    }
    with (
        LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cl,
        Client(cl) as client,
    ):
        client.run(lambda: __import__("hevr"))
        priv, ev, enc_s = store(cfg, args.store_dir, client)
        out["store"] = {"path": str(ev.path), "id": ev.meta.store_id, "encrypt_s": enc_s, "reused": enc_s is None}
        print(f"store {ev.meta.store_id}: {'reused' if enc_s is None else f'encrypted in {enc_s:.1f} s'}", flush=True)
        res, persist_s = timed(lambda: ev.persist(client=client))
        _, wait_s = timed(res.resident.wait)
        out["persist_s"] = persist_s + wait_s
        sid = ev.meta.store_id
        url = start_server({sid: res}, client)
        server = hevr.remote.connect(url, timeout=600)
        rv = server.open(sid)
        local = lambda cam, **kw: hevr.render(res, cam, client=client, cache=False, progress=False, **kw)  # noqa: E731
        remote = lambda cam, **kw: hevr.render(rv, cam, progress=False, **kw)  # noqa: E731

        # warm-up and check: one camera both ways, decrypted; the images must be the same
        cam = camera(ev, W)
        (a, ta), (b, tb) = timed(lambda: local(cam, verify=False)), timed(lambda: remote(cam, verify=False))
        pa, pb = a.decrypt(priv), b.decrypt(priv)
        ref = hevr.render_plain(hevr.phantom(cfg["size"]), cam)
        out["check"] = {
            "local_s": ta,
            "remote_s": tb,
            "same_image": bool(np.array_equal(pa, pb)),
            "same_ciphertexts": len(a.ciphertexts) == len(b.ciphertexts)
            and all(np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts)),
            "max_abs_error": float(np.abs(pa - ref).max()),
            "ciphertexts": a.n_ciphertexts,
        }
        print("check", out["check"], flush=True)

        # 1. remote against in-process, alternating, a new camera each frame
        arms = {
            "remote": remote,
            "local": local,
            "local_cached": lambda cam, **kw: hevr.render(res, cam, client=client, cache=True, progress=False, **kw),
        }  # the server's own call keeps the sums
        rec: dict = {p: [] for p in arms}
        for r in range(cfg["frames"]):
            for path in list(arms)[r % 3 :] + list(arms)[: r % 3]:
                img, s = timed(lambda: arms[path](camera(ev, W), verify=False))  # noqa: B023 - timed() calls it at once, in this iteration
                st = img.stats
                rec[path].append(
                    {
                        "s": s,
                        "reused": bool(st.get("reused_ray_sums")),
                        "map_tasks": st.get("map_tasks"),
                        "server_s": st.get("server_seconds"),
                        "bytes": st.get("gathered_bytes"),
                    }
                )
                print(path, f"{s:.3f} s", rec[path][-1], flush=True)
        sm = {p: summary([x["s"] for x in v]) for p, v in rec.items()}
        sm["remote_server"] = summary([x["server_s"] for x in rec["remote"] if x["server_s"] is not None] or [0.0])
        sm["paired_diff"] = summary([r["s"] - q["s"] for r, q in zip(rec["remote"], rec["local"])])  # same round
        sm["client_http"] = summary(
            [x["s"] - x["server_s"] for x in rec["remote"] if x["server_s"] is not None] or [0.0]
        )  # the key holder's rays, plan and checks, HTTP, parsing
        lm, rm = sm["local"]["median"], sm["remote"]["median"]
        out["frame"] = {
            "records": rec,
            "summary": sm,
            "ratio": rm / lm,
            "diff_s": rm - lm,
            "goal_s": 1.05 * lm + 0.030,
            "ok": rm <= 1.05 * lm + 0.030,
            "reused_any": any(x["reused"] for v in rec.values() for x in v),
        }
        if not args.no_verified:
            ver = {}
            for path, fn in (("local", local), ("remote", remote)):
                img, s = timed(lambda: fn(camera(ev, W), verify=True))  # noqa: B023 - timed() calls it at once, in this iteration
                _, ds = timed(partial(img.decrypt, priv))  # checks the verification first
                ver[path] = {"s": s, "verify_s": img.stats.get("verify_s"), "decrypt_s": ds}
                print("verified", path, ver[path], flush=True)
            out["verified"] = ver

        # 2. throughput with 1, 2, 4 key holders
        out["throughput"] = []
        for k in (int(x) for x in args.clients.split(",")):
            out["throughput"].append(throughput(url, sid, ev, W, k, cfg["seconds"]))
            print(out["throughput"][-1], flush=True)
        server.close()
    out["wall_s"] = time.perf_counter() - t_run
    out["load_average"] = os.getloadavg()
    dest = args.json or Path(__file__).parent / f"results-serve{'-quick' if args.quick else ''}.json"
    dest.write_text(json.dumps(out, indent=1) + "\n")
    text = report(out, args)
    print(text)
    if not args.no_history:
        append(text)


def report(out: dict, args) -> str:
    cfg, f, sm = out["config"], out["frame"], out["frame"]["summary"]
    enc = out["store"]["encrypt_s"]
    cmd = " ".join(["python benchmarks/serve.py"] + [a for a in sys.argv[1:] if a != "--no-history"])
    la = " → ".join(", ".join(f"{x:.2f}" for x in out[k]) for k in ("load_average_start", "load_average"))
    lines = [
        f"## serve.py — `hevr serve` vs in-process, {cfg['size']}³ phantom, {cfg['image']}² px, {cfg['bits']}-bit "
        f"key, {out['workers']}-worker LocalCluster (1 thread each){' (quick)' if args.quick else ''}\n",
        f"Machine: {out['machine']} · hevr {out['hevr']} · dask {out['dask']}\n",
        f"Command: `{cmd}` · wall {out['wall_s']:.0f} s · load average (1, 5, 15 min) start → end {la} · store "
        f"(scalar, brick {cfg['brick']}, verifiable) {'reused' if enc is None else f'encrypted in {enc:.0f} s'}, "
        f"bricks resident ({out['persist_s']:.1f} s to load). Server in-process (uvicorn thread, 127.0.0.1), "
        "same Dask client. X-ray nearest, `verify=False`; a new camera for every frame, the three arms "
        f"taken in turn. Check frame: images identical "
        f"{out['check']['same_image']}, ciphertexts identical {out['check']['same_ciphertexts']}, max abs "
        f"error vs render_plain {out['check']['max_abs_error']:.2e}.\n",
        "| path | frames | median s | min s | max s |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, key in (
        ("in-process (`cache=False`)", "local"),
        ("remote", "remote"),
        ("remote: the server's render (X-Hevr-Stats seconds)", "remote_server"),
        ("in-process, `cache=True` (as the server renders)", "local_cached"),
    ):
        s = sm[key]
        lines.append(f"| {name} | {s['n']} | {s['median']:.3f} | {s['min']:.3f} | {s['max']:.3f} |")
    for name, key in (
        ("remote − in-process, same round (paired)", "paired_diff"),
        ("remote − the server's render (key holder + HTTP)", "client_http"),
    ):
        s = sm[key]
        lines.append(f"| {name} | {s['n']} | {s['median']:+.3f} | {s['min']:+.3f} | {s['max']:+.3f} |")
    lines.append(
        f"\nRemote / in-process (medians) {f['ratio']:.3f}×, difference {1000 * f['diff_s']:+.0f} ms; goal "
        f"≤ 1.05× + 30 ms = {f['goal_s']:.3f} s: **{'ok' if f['ok'] else 'missed'}**"
        f"{'' if not f['reused_any'] else ' (WARNING: some frame reused cached ray sums)'}."
    )
    if "verified" in out:
        v = out["verified"]
        lines.append(
            "Verified frame (one each, `verify=True`): "
            + "; ".join(
                f"{p} {v[p]['s']:.2f} s (of it the tag round {v[p]['verify_s'] or 0:.2f} s), decrypt with check "
                f"{v[p]['decrypt_s']:.2f} s"
                for p in ("local", "remote")
            )
            + "."
        )
    lines += [
        "\n| key holders | frames | wall s | frames/s | latency median s | latency min / max s | 429s |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for t in out["throughput"]:
        la_ = t["latency"] or {"median": float("nan"), "min": float("nan"), "max": float("nan")}
        lines.append(
            f"| {t['clients']} | {t['frames']} | {t['wall_s']:.1f} | {t['fps']:.3f} | {la_['median']:.3f} | "
            f"{la_['min']:.3f} / {la_['max']:.3f} | {t['busy_429']} |"
        )
    lines.append(
        f"\nThroughput: each key holder a thread with its own `connect`, new cameras for "
        f"{cfg['seconds']:g} s (the frame running then finishes; wall = until the last one ends); "
        "server default `max_concurrent` 4, no tokens."
    )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
