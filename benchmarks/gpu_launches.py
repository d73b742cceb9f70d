"""The launch structure of a resident 2048-bit frame on the ``cuda`` backend, without a GPU.

A GPU thread runs a chain of 4096-bit products tens of times slower than a CPU core, so a frame
is fast on a device only when its launches are few and wide. This counts, per kernel, the
launches and their threads of one warm resident frame of the ``size``³ phantom (2048-bit key,
brick 8, image 2·size square), with CuPy played by the host build (``tests/backends/_fake_cupy``):
under the rules before issue 26's second CPU session (commit aa61989: per-brick map tasks at 2048
bits, every operation in the kernels; residues already on the device here, which only moves
bytes) and now (one map task for the device's bricks, trilinear rows of every brick in one plan,
fewer than ``MIN_ITEMS`` items to gmpy2). Counts, not times: the host build's
seconds say nothing about a GPU's.

    python benchmarks/gpu_launches.py [size] > benchmarks/results-gpu-launches.md
"""

from __future__ import annotations

import os
import platform
import sys
import tempfile
import warnings

import dask

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "backends"))
from _fake_cupy import FakeCupy  # noqa: E402 - from tests/backends, on the path above

sys.modules["cupy"] = FakeCupy  # before hevr imports: CuPy is the host build's fake

import hevr  # noqa: E402
from hevr.backends.cuda import device  # noqa: E402
from hevr.rendering.pipeline import maps  # noqa: E402
from hevr.runtime import stats  # noqa: E402
from hevr.volume.phantom import phantom  # noqa: E402


def launches(rv, cam, sampling: str) -> str:
    with dask.config.set(scheduler="sync"):
        hevr.render(rv, cam, "xray", sampling, backend="cuda", progress=False, cache=False)  # warm
        stats.take()
        img = hevr.render(rv, cam, "xray", sampling, backend="cuda", progress=False, cache=False)
    c = stats.take()["counts"]
    runs = {k[7:]: n for k, n in c.items() if k.startswith("launch ")}
    text = ", ".join(f"{k[2:]} {n}×{c['threads ' + k] / n:.0f}" for k, n in sorted(runs.items()))
    return f"{img.stats['map_tasks']} | {sum(runs.values())} | {text}"


def main(size: int) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        _, priv = hevr.generate_keypair(2048)
    print(f"# Launches of one resident 2048-bit frame on `cuda` ({size}³ phantom, brick 8, {2 * size}² image)\n")
    print(
        f"Counted with FakeCupy on {platform.processor() or platform.machine()}, {os.cpu_count()} cores "
        f"(`python benchmarks/gpu_launches.py {size}`); a cell lists kernel launches×threads per launch.\n"
    )
    print("| rules | sampling | map tasks | launches | kernel launches × threads |\n|---|---|---:|---:|---|")
    with tempfile.TemporaryDirectory() as folder:
        with dask.config.set(scheduler="threads"):
            ev = hevr.encrypt_volume(phantom(size), f"{folder}/p.zarr", priv, brick=8, progress=False)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=2 * size, height=2 * size)
        for rules in ("before", "now"):
            old = rules == "before"
            device.CupyLauncher.min_items = 0 if old else device.MIN_ITEMS
            fused = maps._fused_bricks
            if old:  # per-brick trilinear maps: the host path
                maps._fused_bricks = lambda ev, camera, items, s, st, d, ch, tile, be, data: [
                    maps.map_brick(ev, camera, idx, s, st, d, ch, fp, tile, be, b) for (idx, fp), b in zip(items, data)
                ]
            with dask.config.set({"hevr.render.resident-batch": not old}):
                with dask.config.set(scheduler="sync"):
                    rv = ev.persist(backend="cuda")
                for sampling in ("nearest", "trilinear"):
                    print(f"| {rules} | {sampling} | {launches(rv, cam, sampling)} |", flush=True)
            maps._fused_bricks = fused
    device.CupyLauncher.min_items = device.MIN_ITEMS


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 24)
