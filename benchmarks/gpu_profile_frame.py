"""Where a frame's time goes on the GPU machine: cProfile of one resident 2048-bit X-ray frame per backend.

On an H200 (2026-11-26) a 24³ 2048-bit nearest X-ray frame of 48² took 4.5 s with ``cuda``, resident
or not, and 13.8 s with ``cpu`` on 16 workers — against 0.25 s (``cpu``) on a 2-core machine here.
This prints, per backend, a nearest and a trilinear frame's wall time and the 25 functions with the most own time, on
Dask's synchronous scheduler in this process (no cluster), so the answer is the frame's own work.

    python benchmarks/gpu_profile_frame.py [size] [backend ...]     # default 24 cuda cpu
    python benchmarks/gpu_profile_frame.py --fake 24 cuda             # no GPU: CuPy played by the host build

After each profile it prints the frame's phases (``hevr.runtime.stats``: seconds and counts per map,
merge and finish phase) and, for ``cuda``, its launches per kernel with their threads: a GPU
thread runs a chain of 4096-bit products about 20x slower than a CPU core, so a frame of few,
small launches is slow however fast the device is in bulk.
"""

from __future__ import annotations

import cProfile
import io
import os
import pstats
import sys
import tempfile
import time
import warnings

import dask

import hevr
from hevr.runtime import stats as _stats
from hevr.volume.phantom import phantom


def main(argv: list[str]) -> None:
    if "--fake" in argv:  # the tests' FakeCupy: the launcher's path and launch counts on the host build
        argv = [a for a in argv if a != "--fake"]
        sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "backends"))
        from _fake_cupy import FakeCupy

        sys.modules["cupy"] = FakeCupy
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
            for sampling in ("nearest", "trilinear"):
                _profile(resident, cam, be, sampling)


def _profile(resident, cam, be: str, sampling: str) -> None:
    """One warm resident X-ray frame under cProfile: its top functions, phases and launches."""
    with dask.config.set(scheduler="sync"):
        hevr.render(resident, cam, "xray", sampling, backend=be, progress=False, cache=False)  # warm
        prof = cProfile.Profile()
        _stats.take()
        t0 = time.perf_counter()
        prof.enable()
        img = hevr.render(resident, cam, "xray", sampling, backend=be, progress=False, cache=False)
        prof.disable()
        dt = time.perf_counter() - t0
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(25)
    phases = _stats.take()
    print(f"== {be}: resident xray {sampling} frame {dt:.3f} s (stats: {img.stats})\n{out.getvalue()}", flush=True)
    print(
        f"-- {be} {sampling} phases (s, count): "
        + "; ".join(
            f"{k} {v:.3f} ({phases['counts'].get(k, 0)})"
            for k, v in sorted(phases["seconds"].items())
            if not k.startswith(("launch ", "threads "))
        ),
        flush=True,
    )
    launches = {k[7:]: c for k, c in phases["counts"].items() if k.startswith("launch ")}
    if launches:
        print(
            f"-- {be} {sampling} launches: "
            + "; ".join(
                f"{k} {c} x {phases['counts'].get('threads ' + k, 0) / c:.0f} threads"
                for k, c in sorted(launches.items())
            ),
            flush=True,
        )


if __name__ == "__main__":
    main(sys.argv[1:])
