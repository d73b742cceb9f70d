"""Issue 28: what verification costs — storage, encryption, render and the client's check.

Usage::

    python benchmarks/verify_cost.py WORKDIR OUT.json [--size 100] [--encrypt-size 50] [--bits 2048] [--rounds 3]

On a 2-worker LocalCluster (processes, one thread each), the phantom (brick 25, scalar) under one
``bits``-bit key:

* ``encrypt``: the ``encrypt-size``³ store written without and with ``verifiable=True`` (seconds,
  bytes on disk), one after the other;
* ``render``: 150² X-ray frames of the ``size``³ verifiable store from scratch (``cache=False``), verified and
  not (``verify=False``), alternating, ``rounds`` of each, nearest and trilinear; every image is
  decrypted, the verified ones with their check, and compared with ``render_plain``;
* ``client``: the decryption of a verified frame against the same without the check, and the check's
  own parts (the geometry and PRF sums Σρ·B, one decryption).

Ratios are taken within this one run on this one machine.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr.bench.measure import machine

warnings.simplefilter("ignore")


def _bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--size", type=int, default=100)
    ap.add_argument("--encrypt-size", type=int, default=50)
    ap.add_argument("--bits", type=int, default=2048)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    res: dict = {
        "machine": machine(),
        "size": args.size,
        "encrypt_size": args.encrypt_size,
        "bits": args.bits,
        "rounds": args.rounds,
    }
    _, priv = hevr.generate_keypair(args.bits)
    vol = hevr.phantom(args.size)
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc,
        Client(lc) as client,
    ):
        client.run(lambda: __import__("hevr"))
        stores = {}
        for label, verifiable in (("plain", False), ("verifiable", True)):
            path = args.work / f"{label}.zarr"
            if path.exists():
                shutil.rmtree(path)
            t0 = time.perf_counter()
            stores[label] = hevr.encrypt_volume(
                hevr.phantom(args.encrypt_size),
                path,
                priv,
                brick=25,
                progress=False,
                client=client,
                verifiable=verifiable,
            )
            res.setdefault("encrypt", {})[label] = {"seconds": time.perf_counter() - t0, "bytes": _bytes(path)}
            print(label, res["encrypt"][label], flush=True)
        ev = stores["verifiable"]
        if args.size != args.encrypt_size:
            path = args.work / "render.zarr"
            if path.exists():
                shutil.rmtree(path)
            t0 = time.perf_counter()
            ev = hevr.encrypt_volume(vol, path, priv, brick=25, progress=False, client=client, verifiable=True)
            res["encrypt"]["render_store_s"] = time.perf_counter() - t0
            print("render store", res["encrypt"]["render_store_s"], flush=True)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=150, height=150)
        for sampling in ("nearest", "trilinear"):
            ref = hevr.render_plain(vol, cam, "xray", sampling)
            bound = hevr.error_bound(ev, cam, "xray", sampling)
            times: dict = {"verified": [], "unverified": []}
            client_s: dict = {"verified": [], "unverified": []}
            for r in range(args.rounds):
                for arm in ("verified", "unverified") if r % 2 == 0 else ("unverified", "verified"):
                    t0 = time.perf_counter()
                    img = hevr.render(
                        ev, cam, "xray", sampling, client=client, progress=False, cache=False, verify=arm == "verified"
                    )
                    times[arm].append(time.perf_counter() - t0)
                    t0 = time.perf_counter()
                    got = img.decrypt(priv)
                    client_s[arm].append(time.perf_counter() - t0)
                    if arm == "verified":
                        last = img
                    if not np.all(np.abs(got - ref) <= bound):
                        raise SystemExit(f"{sampling} {arm}: outside the error bound")
                    print(
                        sampling, arm, f"{times[arm][-1]:.2f} s render, {client_s[arm][-1]:.3f} s decrypt", flush=True
                    )
            t0 = time.perf_counter()
            last.verification.beta_sum(priv)
            beta_s = time.perf_counter() - t0
            med = {k: statistics.median(v) for k, v in times.items()}
            cmed = {k: statistics.median(v) for k, v in client_s.items()}
            res.setdefault("render", {})[sampling] = {
                "render_s": times,
                "decrypt_s": client_s,
                "median_render_s": med,
                "median_decrypt_s": cmed,
                "render_ratio": med["verified"] / med["unverified"],
                "check_s": cmed["verified"] - cmed["unverified"],
                "beta_sum_s": beta_s,
            }
            print(sampling, res["render"][sampling]["render_ratio"], res["render"][sampling]["check_s"], flush=True)
    res["storage_ratio"] = res["encrypt"]["verifiable"]["bytes"] / res["encrypt"]["plain"]["bytes"]
    res["encrypt_ratio"] = res["encrypt"]["verifiable"]["seconds"] / res["encrypt"]["plain"]["seconds"]
    args.out.write_text(json.dumps(res, indent=1))
    print(json.dumps({k: v for k, v in res.items() if k.endswith("ratio")}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
