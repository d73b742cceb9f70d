"""Issue 13: resident frames with and without tile-row map pieces (``BAND_BITS``), alternating
in one 2-worker cluster, traced (tail = graph time after the last map task).

Usage::

    python benchmarks/bands_ab.py SCALAR_STORE VECTOR_STORE ROUNDS OUT.json
"""

from __future__ import annotations

import json
import sys
import warnings

from distributed import Client, LocalCluster

import hevr
from hevr.bench.measure import machine
from hevr.bench.pipeline import trace_frame
from hevr.paper import TF_NODES
from hevr.rendering import view as render_mod

warnings.simplefilter("ignore")


def main(scalar: str, vector: str, rounds: int, out: str) -> None:
    res = {"machine": machine(), "runs": []}
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c, Client(c) as cl:
        for name, path, kw in (
            ("xray-nearest", scalar, {}),
            ("tf4-nearest", vector, {"mode": "tf", "nodes": TF_NODES}),
        ):
            ev = hevr.open_volume(path).persist()
            ev.resident.wait()
            cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20)
            trace_frame(cl, ev, cam, **kw)  # warm
            for r in range(rounds if name == "xray-nearest" else max(1, rounds // 2)):
                for arm in ("pieces", "whole") if r % 2 == 0 else ("whole", "pieces"):
                    render_mod.BAND_BITS = 1024 if arm == "pieces" else 1 << 30
                    tr = trace_frame(cl, ev, cam, **kw)
                    row = {
                        "case": name,
                        "arm": arm,
                        "round": r,
                        "wall": tr["wall"],
                        "tail": tr["tail"],
                        "busy": tr["busy"],
                        "map_tasks": tr["kinds"]["map"]["n"],
                    }
                    res["runs"].append(row)
                    print(json.dumps(row), flush=True)
            ev.resident.release()
    render_mod.BAND_BITS = 1024
    with open(out, "w") as f:
        json.dump(res, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4])
