"""The paper's render case: 100³ phantom, 150² image, 2048-bit key, 2-worker LocalCluster.

Run after ``python benchmarks/encrypt.py --keep DIR`` (which leaves DIR/scalar.zarr,
DIR/4.zarr and DIR/key.json):  python benchmarks/render.py --stores DIR [--quick]
Measures nearest / trilinear X-ray, the 4-dim transfer function with 1–4 colours, the
re-colouring cost on cached ray sums, the client's decryption with and without packing
(one core), and the speed-up of 2 workers over 1. Appends to benchmarks/history.md.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from _machine import append, machine  # noqa: E402

import hevr  # noqa: E402
from hevr.paper import TF_NODES  # noqa: E402

PAPER_RENDER = {
    ("xray", "nearest"): 94.30,
    ("xray", "trilinear"): 1182.48,
    ("tf1", "nearest"): 2292.48,
    ("tf2", "nearest"): 3234.38,
    ("tf3", "nearest"): 4251.69,
    ("tf4", "nearest"): 5217.38,
}
PAPER_DECRYPT_RGB = 190.49


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stores", type=Path, required=True)
    ap.add_argument("--image", type=int, default=150)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-unpacked-rgb", action="store_true", help="skip the ~3 min unpacked RGB decryption")
    args = ap.parse_args(argv)
    from distributed import Client, LocalCluster

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        priv = hevr.load_key(args.stores / "key.json")
    sc = hevr.open_volume(args.stores / "scalar.zarr")
    vec = hevr.open_volume(args.stores / "4.zarr")
    vol = hevr.phantom(sc.shape[0])
    W = args.image
    cam = hevr.Camera.orbit(sc, azimuth=30, elevation=20, width=W, height=W)
    rays = hevr.rendering.geometry.rays.cast_rays(cam, sc.shape, sc.spacing, 1.0)
    hits = int((rays.n_samples > 0).sum())
    samples = int(rays.n_samples.sum())
    rows, images = [], {}
    paper_case = sc.shape == (100, 100, 100) and W == 150 and sc.public_key.bits == 2048
    if not paper_case:
        PAPER_RENDER.clear()  # the paper's numbers only apply to its own case
    with (
        LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cl,
        Client(cl) as client,
    ):
        client.run(lambda: __import__("hevr"))  # warm the workers' imports
        for sampling in ("nearest", "trilinear"):
            img, s = timed(partial(hevr.render, sc, cam, sampling=sampling, cache=False, client=client, progress=False))
            err = float(np.abs(img.decrypt(priv) - hevr.render_plain(vol, cam, sampling=sampling)).max())
            rows.append((f"X-ray {sampling}", s, PAPER_RENDER[("xray", sampling)], err))
            images[("xray", sampling)] = img
            print(rows[-1], flush=True)
        for sampling in ("nearest", "trilinear"):
            for k in range(1, 5):
                nodes = TF_NODES[:k]
                img, s = timed(
                    partial(
                        hevr.render,
                        vec,
                        cam,
                        mode="tf",
                        nodes=nodes,
                        sampling=sampling,
                        cache=False,
                        client=client,
                        progress=False,
                    )
                )
                ref = hevr.render_plain(vol, cam, mode="tf", nodes=nodes, sampling=sampling, vector_dims=4)
                err = float(np.abs(img.decrypt(priv) - ref).max())
                rows.append(
                    (
                        f"TF 4-dim, {k} colour{'s' if k > 1 else ''}, {sampling}",
                        s,
                        PAPER_RENDER.get((f"tf{k}", sampling)),
                        err,
                    )
                )
                images[("tf", sampling, k)] = img
                print(rows[-1], flush=True)
        hevr.render(vec, cam, mode="tf", nodes=TF_NODES, client=client, progress=False)  # fills the cache
        _, recolour = timed(lambda: hevr.render(vec, cam, mode="tf", nodes=TF_NODES[:2], client=client, progress=False))
    # the client: one core, no cluster
    rgb = images[("tf", "nearest", 4)]
    p_rgb = f"{PAPER_DECRYPT_RGB}" if paper_case else "–"
    p_grey = "185.94" if paper_case else "–"
    _, dec_packed = timed(lambda: rgb.decrypt(priv))
    unpacked = hevr.render(vec, cam, mode="tf", nodes=TF_NODES, pack=False, progress=False)
    grey_unpacked = hevr.render(sc, cam, pack=False, progress=False)
    _, dec_grey_unpacked = timed(lambda: grey_unpacked.decrypt(priv))
    dec_unpacked = None if args.skip_unpacked_rgb else timed(lambda: unpacked.decrypt(priv))[1]
    # scaling: the same render on 1 and on 2 workers
    scale = {}
    for nw in (1, 2):
        with (
            LocalCluster(n_workers=nw, threads_per_worker=1, processes=True, dashboard_address=":0") as cl,
            Client(cl) as client,
        ):
            client.run(lambda: __import__("hevr"))
            _, scale[nw] = timed(
                lambda: hevr.render(sc, cam, sampling="trilinear", cache=False, client=client, progress=False)
            )
    lines = [
        f"## render.py — {sc.shape[0]}³ phantom, {W}² image, {sc.public_key.bits}-bit key, "
        f"{args.workers}-worker LocalCluster (1 thread each)\n",
        f"Machine: {machine()}\n",
        f"Camera: `Camera.orbit(ev, azimuth=30, elevation=20, width={W}, height={W})` (default framing), "
        f"{hits:,} of {W * W:,} rays hit the volume, {samples:,} samples (step 1). Every render from "
        "scratch (`cache=False`), timed end to end (graph, map, reduce, finishing, packing).\n",
        "| render | hevr s | paper s (Table 1/3) | speed-up | max abs error vs render_plain |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, s, paper, err in rows:
        lines.append(
            f"| {name} | {s:,.1f} | {paper:,.0f} | {paper / s:,.0f}× | {err:.2e} |"
            if paper
            else f"| {name} | {s:,.1f} | – | – | {err:.2e} |"
        )
    lines += [
        f"\nRe-colouring the cached 4-dim ray sums with a new 2-node transfer function: {recolour:.2f} s.\n",
        "| client decryption (1 core) | ciphertexts | seconds | paper s |",
        "|---|---:|---:|---:|",
        f"| {W}² RGB, packed ({rgb.per_pack} values per ciphertext) | {rgb.n_ciphertexts:,} | {dec_packed:.2f} "
        f"| {p_rgb} |",
        f"| {W}² grey, unpacked | {grey_unpacked.n_ciphertexts:,} | {dec_grey_unpacked:.2f} | {p_grey} |",
    ]
    if dec_unpacked is not None:
        lines.append(f"| {W}² RGB, unpacked | {unpacked.n_ciphertexts:,} | {dec_unpacked:.2f} | {p_rgb} |")
    lines.append(
        f"\nScaling, trilinear X-ray: 1 worker {scale[1]:.1f} s, 2 workers {scale[2]:.1f} s, "
        f"speed-up {scale[1] / scale[2]:.2f}×."
    )
    text = "\n".join(lines)
    print(text)
    append(text)


if __name__ == "__main__":
    main()
