"""Where a frame's time goes on the GPU machine: cProfile of one resident 2048-bit X-ray frame per backend.

On an H200 (2026-11-26) a 24³ 2048-bit nearest X-ray frame of 48² took 4.5 s with ``cuda``, resident
or not, and 13.8 s with ``cpu`` on 16 workers — against 0.25 s (``cpu``) on a 2-core machine here.
This prints, per backend, the frame's wall time and the 25 functions with the most own time, on
Dask's synchronous scheduler in this process (no cluster), so the answer is the frame's own work.

    python benchmarks/gpu_profile_frame.py [size] [backend ...]     # default 24 cuda cpu
"""

from __future__ import annotations

import cProfile
import io
import pstats
import sys
import tempfile
import time
import warnings

import dask

import hevr
from hevr._bench.gpu import phantom


def main(argv: list[str]) -> None:
    size = int(argv[0]) if argv else 24
    backends = argv[1:] or ["cuda", "cpu"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        _, priv = hevr.generate_keypair(2048)
    with tempfile.TemporaryDirectory(prefix="hevr-profile-") as folder:
        t0 = time.perf_counter()
        with dask.config.set(scheduler="threads"):
            ev = hevr.encrypt_volume(phantom(size), f"{folder}/p.zarr", priv, brick=8, progress=False)
        print(f"encrypted {size}^3 at 2048 bits in {time.perf_counter() - t0:.1f} s", flush=True)
        t0 = time.perf_counter()  # the store's reads alone (a slow /tmp would explain slow frames everywhere)
        grid = [(z, y, x) for z in range(ev.grid[0]) for y in range(ev.grid[1]) for x in range(ev.grid[2])]
        for index in grid:
            ev.read_brick(index, "scalar", backend="cpu")
        print(f"read {len(grid)} bricks in {time.perf_counter() - t0:.3f} s ({folder})", flush=True)
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=2 * size, height=2 * size)
        for be in backends:
            with dask.config.set(scheduler="sync"):
                resident = ev.persist(backend=be)
                hevr.render(resident, cam, "xray", "nearest", backend=be, progress=False, cache=False)  # warm
                prof = cProfile.Profile()
                t0 = time.perf_counter()
                prof.enable()
                img = hevr.render(resident, cam, "xray", "nearest", backend=be, progress=False, cache=False)
                prof.disable()
                dt = time.perf_counter() - t0
            out = io.StringIO()
            pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(25)
            print(f"== {be}: resident frame {dt:.3f} s (stats: {img.stats})\n{out.getvalue()}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
