"""Issue 15 — slices, the pyramid and the gradient channel, on the paper's phantom at 2048 bits.

Usage::

    python benchmarks/beyond.py WORKDIR OUT.json [--reuse]

On a 2-worker LocalCluster (processes, one thread each), in one run:

1. encrypt the 100³ phantom, scalar channel, 2048-bit key, owner path, 25³ bricks (the paper's
   case; ``--reuse`` takes WORKDIR/key.json + scalar.zarr from an earlier run and does not time
   the encryption again);
2. build pyramid levels 1 and 2 (``hevr.build_pyramid``), timed per level;
3. X-ray frames, nearest and trilinear, at levels 0, 1 and 2 — with the same 150² camera and
   with a preview camera of 150/2^L pixels per axis — seconds (streamed, no cache) and
   ray-voxel pairs (nearest: samples; trilinear: 8 per sample; a level samples every 2^L);
4. a 150² axial slice through the middle, nearest and trilinear, streamed and resident
   (``persist``), each with its client decryption, end to end;
5. the gradient channel's cost: 32³ phantom, 4-dim encoding, encrypted without and with
   ``gradient=True``, and one 4-node TF frame (64², nearest) on each.

Every encrypted image is compared with its plaintext reference within ``error_bound``.
"""

from __future__ import annotations

import inspect
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr.bench.measure import machine
from hevr.paper import TF_NODES
from hevr.rendering.geometry.rays import cast_rays

warnings.simplefilter("ignore")

SIZE, IMAGE, BITS, BRICK = 100, 150, 2048, 25


def timed(fn, *a, **kw):
    t = time.perf_counter()
    out = fn(*a, **kw)
    return out, time.perf_counter() - t


def check(arr, ref, bound, what):
    err = float(np.abs(arr - ref).max())
    assert (np.abs(arr - ref) <= bound).all(), f"{what}: error {err} above the bound"
    return err


def frames(ev, vol, priv, res):
    """X-ray frames at levels 0-2: the same 150² camera, and a preview camera of 150/2^L pixels."""
    rows = []
    for level in (0, 1, 2):
        lv = ev.at_level(level)
        for size in sorted({IMAGE, IMAGE >> level}, reverse=True):
            cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=size, height=size)
            moved = (
                cam
                if not level
                else hevr.Camera(
                    **{
                        **cam.to_dict(),
                        "position": tuple(np.subtract(cam.position, lv.origin)),
                        "focal_point": tuple(np.subtract(cam.focal_point, lv.origin)),
                    }
                )
            )
            samples = int(cast_rays(moved, lv.shape, lv.spacing, 2.0**level).n_samples.sum())
            for sampling in ("nearest", "trilinear"):
                hevr.clear_cache()
                img, sec = timed(hevr.render, ev, cam, sampling=sampling, level=level, cache=False, progress=False)
                arr, dsec = timed(img.decrypt, priv)
                ref = hevr.render_plain(vol, cam, sampling=sampling, level=level)
                err = check(arr, ref, hevr.error_bound(ev, cam, sampling=sampling, level=level), f"level {level}")
                rows.append(
                    {
                        "level": level,
                        "image": size,
                        "sampling": sampling,
                        "shape": list(lv.shape),
                        "brick": list(lv.brick),
                        "seconds": sec,
                        "decrypt_s": dsec,
                        "pairs": samples * (8 if sampling == "trilinear" else 1),
                        "map_tasks": img.stats["map_tasks"],
                        "max_error": err,
                    }
                )
                print(rows[-1], flush=True)
    res["frames"] = rows


def slices(ev, vol, priv, res, client):
    plane = hevr.Plane.axial(ev, SIZE // 2, width=IMAGE, height=IMAGE)
    rows = []
    for resident in (False, True):
        src = ev.persist(client=client) if resident else ev
        if resident:
            src.resident.wait()
        for sampling in ("nearest", "trilinear"):
            for rep in range(2):
                hevr.clear_cache()
                t = time.perf_counter()
                img = hevr.render_slice(src, plane, sampling=sampling, cache=False, progress=False)
                rsec = time.perf_counter() - t
                arr = img.decrypt(priv)
                total = time.perf_counter() - t
                ref = hevr.render_slice_plain(vol, plane, sampling=sampling)
                err = check(arr, ref, hevr.error_bound(ev, plane, sampling=sampling), "slice")
                rows.append(
                    {
                        "sampling": sampling,
                        "resident": resident,
                        "repeat": rep,
                        "render_s": rsec,
                        "end_to_end_s": total,
                        "ciphertexts": img.n_ciphertexts,
                        "max_error": err,
                    }
                )
                print(rows[-1], flush=True)
        if resident:
            src.resident.release()
    res["slices"] = rows


def gradient(work, res):
    if "gradient" not in inspect.signature(hevr.encrypt_volume).parameters:
        res["gradient"] = None
        return
    pub, priv = hevr.generate_keypair(BITS)
    vol = hevr.phantom(32)
    rows = []
    for grad in (False, True):
        ev, sec = timed(
            hevr.encrypt_volume,
            vol,
            work / f"g{int(grad)}.zarr",
            priv,
            brick=16,
            vector_dims=4,
            gradient=grad,
            overwrite=True,
            progress=False,
        )
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=64, height=64)
        hevr.clear_cache()
        img, rsec = timed(hevr.render, ev, cam, mode="tf", nodes=TF_NODES, gradient=grad, cache=False, progress=False)
        ref = hevr.render_plain(vol, cam, mode="tf", nodes=TF_NODES, vector_dims=4, gradient=grad)
        err = check(
            img.decrypt(priv), ref, hevr.error_bound(ev, cam, mode="tf", nodes=TF_NODES, gradient=grad), "gradient"
        )
        rows.append(
            {
                "gradient": grad,
                "encrypt_s": sec,
                "ciphertexts_per_voxel": 1 + 4 * (2 if grad else 1),
                "tf_render_s": rsec,
                "max_error": err,
            }
        )
        print(rows[-1], flush=True)
    res["gradient"] = rows


def main(work: str, out: str, reuse: bool) -> None:
    work_p = Path(work)
    work_p.mkdir(parents=True, exist_ok=True)
    res: dict = {"machine": machine(), "case": f"{SIZE}^3 phantom, {BITS}-bit key, {IMAGE}^2 image, brick {BRICK}"}
    vol = hevr.phantom(SIZE)
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c, Client(c) as client:
        if reuse:
            priv = hevr.load_key(work_p / "key.json")
            ev = hevr.open_volume(work_p / "scalar.zarr")
            res["encrypt_s"] = None
        else:
            pub, priv = hevr.generate_keypair(BITS)
            priv.save(work_p / "key.json", overwrite=True)
            ev, res["encrypt_s"] = timed(
                hevr.encrypt_volume, vol, work_p / "scalar.zarr", priv, brick=BRICK, overwrite=True, progress=False
            )
            print("encrypt", res["encrypt_s"], flush=True)
        res["pyramid_s"] = {}
        for level in (1, 2):
            if ev.levels < level:
                ev, res["pyramid_s"][level] = timed(hevr.build_pyramid, ev, level, progress=False)
                print("pyramid", level, res["pyramid_s"][level], flush=True)
        frames(ev, vol, priv, res)
        slices(ev, vol, priv, res, client)
        gradient(work_p, res)
    Path(out).write_text(json.dumps(res, indent=1, default=str) + "\n")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2], "--reuse" in sys.argv[3:])
