"""Issue 48's measurement: a frame through ``hevr serve`` against the same frame in process, in one
run, and the service's own overhead per frame in milliseconds.

Usage::

    python benchmarks/serve_ratio.py            # 2048-bit key: 32³ scalar, 24³ TF store, 3 frames a case
    python benchmarks/serve_ratio.py --quick    # 512-bit key, 16³ / 12³: a smoke check, < 1 min

One LocalCluster (``--workers`` processes, one thread each); the phantom encrypted with the owner's key
(tags: the key's policy) and cached in ``--store-dir``; the bricks resident (``persist``). The server runs in
this process (:func:`hevr.serve.run.serve` in a thread, 127.0.0.1, port 0, no tokens) on the same Dask
client; the key holder uses :func:`hevr.connect`. Cases: X-ray nearest at 100², X-ray trilinear and TF
trilinear (4-dim vector store) at 64², each ``verify=False`` and ``verify=True``. For each case the two
arms alternate (remote first in odd rounds), every frame on a camera of its own (the server and the
in-process arm keep ray sums of recent views: ``cache=True`` both ways, so neither reuses sums). A frame is
``hevr.render`` to its encrypted image (decryption is the key holder's, not the service's: timed apart,
once per case). The overhead per frame is the paired difference remote − in-process of one round, whose
median the table shows in ms, beside the ratio of the medians.

Writes ``benchmarks/results-serve-ratio[-quick].json``, prints the table and appends it to
``benchmarks/history.md`` (not with ``--no-history``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import statistics
import sys
import time
import warnings
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _machine import append, machine  # noqa: E402
from serve import start_server, timed  # noqa: E402

import hevr  # noqa: E402
from hevr.paper import TF_NODES  # noqa: E402

FULL = {"bits": 2048, "size": 32, "tf_size": 24, "frames": 3, "nearest": 100, "image": 64}
QUICK = {"bits": 512, "size": 16, "tf_size": 12, "frames": 2, "nearest": 32, "image": 24}
CASES = (("xray", "nearest", "scalar"), ("xray", "trilinear", "scalar"), ("tf", "trilinear", "tf"))
CAMERAS = itertools.count()


def camera(ev, W: int) -> hevr.Camera:
    i = next(CAMERAS)
    return hevr.Camera.orbit(ev, azimuth=(30 + 0.5 * i) % 360, elevation=20 + (i // 720), width=W, height=W)


def stores(cfg: dict, root: Path, client) -> tuple:
    """(private key, {kind: opened store}, seconds encrypting or None when reused)."""
    d = root / f"ratio-{cfg['size']}-{cfg['tf_size']}-{cfg['bits']}bit"
    key_path = d / "key.json"
    paths = {"scalar": d / "scalar.zarr", "tf": d / "tf.zarr"}
    if key_path.exists() and all(p.exists() for p in paths.values()):
        try:
            priv = hevr.load_key(key_path)
            evs = {k: hevr.open_volume(p) for k, p in paths.items()}
            if all(ev.public_key == priv.public_key and ev.meta.tags for ev in evs.values()):
                return priv, evs, None
        except hevr.HevrError as exc:
            print(f"stores in {d} not reusable ({exc}); encrypting again", flush=True)
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    _, priv = hevr.generate_keypair(cfg["bits"])
    priv.save(key_path)
    t = time.perf_counter()
    evs = {
        "scalar": hevr.encrypt_volume(
            hevr.phantom(cfg["size"]),
            paths["scalar"],
            priv,
            brick=max(4, cfg["size"] // 2),
            progress=False,
            client=client,
        ),
        "tf": hevr.encrypt_volume(
            hevr.phantom(cfg["tf_size"]),
            paths["tf"],
            priv,
            brick=max(4, cfg["tf_size"] // 2),
            vector_dims=4,
            progress=False,
            client=client,
        ),
    }
    return priv, evs, time.perf_counter() - t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--store-dir", type=Path, default=Path("/tmp/hevr-bench-serve"))
    ap.add_argument("--frames", type=int)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--no-history", action="store_true")
    args = ap.parse_args(argv)
    cfg = dict(QUICK if args.quick else FULL)
    if args.frames:
        cfg["frames"] = args.frames
    warnings.simplefilter("ignore")  # small keys in --quick
    from distributed import Client, LocalCluster

    t_run = time.perf_counter()
    out: dict = {
        "config": cfg,
        "machine": machine(),
        "workers": args.workers,
        "load_average_start": os.getloadavg(),
        "cases": [],
    }
    with (
        LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cl,
        Client(cl) as client,
    ):
        client.run(lambda: __import__("hevr"))
        priv, evs, enc_s = stores(cfg, args.store_dir, client)
        hevr.trust_store(evs["scalar"], priv)  # the key holder's own stores, recorded as verifiable
        hevr.trust_store(evs["tf"], priv)
        out["encrypt_s"] = enc_s
        res = {k: ev.persist(client=client) for k, ev in evs.items()}
        for r in res.values():
            r.resident.wait()
        url = start_server({k: r for k, r in res.items()}, client)
        server = hevr.connect(url, timeout=900)
        remote = {k: server.open(k) for k in res}
        for mode, sampling, kind in CASES:
            W = cfg["nearest"] if sampling == "nearest" else cfg["image"]
            kw = {"nodes": TF_NODES} if mode == "tf" else {}
            for verify in (False, True):
                common = dict(mode=mode, sampling=sampling, progress=False, verify=verify, **kw)
                arms = {
                    "remote": partial(hevr.render, remote[kind], **common),
                    "in-process": partial(hevr.render, res[kind], client=client, cache=True, **common),
                }
                for fn in arms.values():  # warm-up: imports, the server's first request, the plan caches
                    fn(camera(evs[kind], W))
                times: dict = {a: [] for a in arms}
                server_s: list = []
                for r in range(cfg["frames"]):
                    for a in list(arms) if r % 2 == 0 else list(arms)[::-1]:
                        img, s = timed(lambda: arms[a](camera(evs[kind], W)))  # noqa: B023 - timed() calls it at once, in this iteration
                        times[a].append(s)
                        if a == "remote" and img.stats.get("server_seconds") is not None:
                            server_s.append(img.stats["server_seconds"])
                _, dec_s = timed(partial(img.decrypt, priv))
                med = {a: statistics.median(v) for a, v in times.items()}
                diffs = [x - y for x, y in zip(times["remote"], times["in-process"])]
                row = {
                    "mode": mode,
                    "sampling": sampling,
                    "image": W,
                    "verify": verify,
                    "times": times,
                    "median": med,
                    "ratio": med["remote"] / med["in-process"],
                    "overhead_ms": 1000 * statistics.median(diffs),
                    "server_s": server_s,
                    "decrypt_s": dec_s,
                }
                out["cases"].append(row)
                print(
                    f"{mode} {sampling} {W}² verify={verify}: remote {med['remote']:.3f} s, in-process "
                    f"{med['in-process']:.3f} s, ratio {row['ratio']:.3f}, overhead {row['overhead_ms']:+.0f} ms",
                    flush=True,
                )
        server.close()
    out["wall_s"] = time.perf_counter() - t_run
    out["load_average"] = os.getloadavg()
    dest = args.json or Path(__file__).parent / f"results-serve-ratio{'-quick' if args.quick else ''}.json"
    dest.write_text(json.dumps(out, indent=1) + "\n")
    text = report(out, args)
    print(text)
    if not args.no_history:
        append(text)


def report(out: dict, args) -> str:
    cfg = out["config"]
    la = " → ".join(", ".join(f"{x:.2f}" for x in out[k]) for k in ("load_average_start", "load_average"))
    lines = [
        f"## serve_ratio.py — a frame through `hevr serve` / in process, {cfg['bits']}-bit key, "
        f"{cfg['size']}³ scalar and {cfg['tf_size']}³ TF phantom, {out['workers']}-worker LocalCluster"
        f"{' (quick)' if args.quick else ''}\n",
        f"Machine: {out['machine']}\n",
        f"Command: `python benchmarks/serve_ratio.py{' --quick' if args.quick else ''}` · wall {out['wall_s']:.0f} s "
        f"· load average (1, 5, 15 min) start → end {la}. {cfg['frames']} frames an arm, alternating, each on a "
        "camera of its own; overhead = median of the paired differences remote − in-process.\n",
        "| frame | verified | in-process s | remote s | remote / in-process | service overhead ms | "
        "decrypt s (apart) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in out["cases"]:
        lines.append(
            f"| {r['mode']} {r['sampling']} {r['image']}² | {'yes' if r['verify'] else 'no'} | "
            f"{r['median']['in-process']:.3f} | {r['median']['remote']:.3f} | {r['ratio']:.3f} | "
            f"{r['overhead_ms']:+.0f} | {r['decrypt_s']:.3f} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
