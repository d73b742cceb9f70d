"""Issue 13 A/B: the render pipeline before (a checkout of the previous commit) and after, on one
store, in alternating fresh processes (each with its own 2-worker LocalCluster).

Usage::

    python benchmarks/pipeline_ab.py OLD_CHECKOUT STORE ROUNDS [MODE SAMPLING]

Prints one JSON line per run: version, wall seconds of a streamed frame (cache off) and of a
second one, and the decrypted image's checksum (both versions must agree).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

CHILD = r"""
import hashlib, json, sys, time, warnings
warnings.simplefilter("ignore")
import hevr
from distributed import Client, LocalCluster
if __name__ == "__main__":
    store, mode, sampling, key = sys.argv[1:5]
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c, Client(c) as cl:
        ev = hevr.open_volume(store)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20)
        kw = {"nodes": hevr.paper.TF_NODES} if mode == "tf" else {}
        walls = []
        for _ in range(2):
            t = time.perf_counter()
            img = hevr.render(ev, cam, mode=mode, sampling=sampling, cache=False, progress=False, **kw)
            walls.append(time.perf_counter() - t)
        arr = img.decrypt(hevr.load_key(key))
        print(json.dumps({"walls": walls, "sha": hashlib.sha256(arr.tobytes()).hexdigest()[:16]}))
"""


def run(root: str, args: list[str]) -> dict:
    env = dict(os.environ, PYTHONPATH=root)
    out = subprocess.run(
        [sys.executable, "-c", CHILD, *args], env=env, cwd=root, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    old, store, rounds = sys.argv[1], sys.argv[2], int(sys.argv[3])
    mode, sampling = (sys.argv[4], sys.argv[5]) if len(sys.argv) > 5 else ("xray", "nearest")
    key = sys.argv[6] if len(sys.argv) > 6 else "/tmp/hevr-integrity/key.json"
    new = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for r in range(rounds):
        for name, root in (("before", old), ("after", new)) if r % 2 == 0 else (("after", new), ("before", old)):
            res = run(root, [store, mode, sampling, key])
            print(json.dumps({"version": name, "round": r, "mode": mode, "sampling": sampling} | res), flush=True)


if __name__ == "__main__":
    main()
