"""Issue 27: resident paper-case frames of whichever hevr is first on the path (before/after).

Usage (one process per arm; alternate the arms and give the old checkout with PYTHONPATH)::

    PYTHONPATH=/path/to/old/checkout python benchmarks/frame_before_after.py LABEL OUT.jsonl STORE \
        [--cases xray-nearest,xray-trilinear,tf4-nearest] [--frames 2] [--backend cuda-host]

Each process starts a 2-worker LocalCluster (processes, one thread each), persists STORE, and
renders every case ``--frames`` times from scratch (``cache=False``), appending one JSON line:
the label, the seconds of each frame, and the SHA-256 of the last frame's packed ciphertexts (the
same hash in every arm: the images are identical). Results of the issue-27 session:
``results-frame-before-after.jsonl``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
import warnings

from distributed import Client, LocalCluster

import hevr
from hevr.paper import TF_NODES

warnings.simplefilter("ignore")
CASES = {
    "xray-nearest": ("xray", "nearest", {}),
    "xray-trilinear": ("xray", "trilinear", {}),
    "tf4-nearest": ("tf", "nearest", {"nodes": TF_NODES}),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("label")
    ap.add_argument("out")
    ap.add_argument("store")
    ap.add_argument("--cases", default="xray-nearest,xray-trilinear,tf4-nearest")
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--backend")
    a = ap.parse_args()
    kw = {"backend": a.backend} if a.backend else {}
    res: dict = {"label": a.label, "hevr": hevr.__file__, "store": a.store, **kw}
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c, Client(c) as cl:
        ev = hevr.open_volume(a.store).persist(client=cl, **kw)
        ev.resident.wait()
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=150, height=150)  # the bench paper case
        for name in a.cases.split(","):
            mode, sampling, extra = CASES[name]
            ts = []
            for _ in range(a.frames):
                t = time.perf_counter()
                img = hevr.render(ev, cam, mode, sampling, cache=False, progress=False, client=cl, **kw, **extra)
                ts.append(time.perf_counter() - t)
            res[name] = {
                "s": ts,
                "image_sha": hashlib.sha256(b"".join(x.tobytes() for x in img.ciphertexts)).hexdigest(),
            }
    with open(a.out, "a") as f:
        f.write(json.dumps(res) + "\n")


if __name__ == "__main__":
    main()
