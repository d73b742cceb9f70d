"""The GPU proof's renders: a phantom's frames on the backend and on ``cpu``, byte for byte.

Step 3 of ``hevr bench --gpu`` (:mod:`hevr.bench.gpu`): a ``size``³ phantom encrypted, rendered
streamed and resident with the backend and with ``cpu``; the packed images must be identical and
within ``error_bound`` of ``render_plain``.
"""

from __future__ import annotations

import contextlib
import logging
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import dask
import numpy as np
from distributed import Client, LocalCluster

from ..crypto.keys import generate_keypair
from ..errors import InsecureKeyWarning, IntegrityError
from ..paper import TF_NODES
from ..rendering.encrypted import error_bound, render
from ..rendering.geometry.camera import Camera
from ..rendering.reference.plain import render_plain
from ..store.writer import encrypt_volume
from ..volume.phantom import phantom

log = logging.getLogger(__name__)


def render_identity(
    be_name: str, size: int, bits: int, work: Path | None, workers: int = 0, log_line: Callable[[str], None] = log.info
) -> list[dict]:
    """The ``size``³ phantom's renders with ``be_name`` and ``cpu``: identical bytes, within the bound.

    With ``workers`` the encryption and the ``cpu`` renders run on a LocalCluster of that many
    processes (a 64³ 2048-bit store is ~15 CPU-minutes of owner encryption); the ``be_name``
    renders run in this process (the GPU is this process's), on Dask's synchronous scheduler."""
    with warnings.catch_warnings():  # --quick's 256-bit key: insecure on purpose
        warnings.simplefilter("ignore", InsecureKeyWarning)
        _, priv = generate_keypair(bits)
    vol = phantom(size)
    with contextlib.ExitStack() as stack:
        # a fresh scratch folder (never over an earlier run's store), removed afterwards
        folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="hevr-gpu-bench-", dir=work)))
        client = None
        if workers:
            cluster = stack.enter_context(LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None))
            client = stack.enter_context(Client(cluster, set_as_default=False))
        with dask.config.set(scheduler="sync"):
            ev = encrypt_volume(
                vol,
                folder / f"phantom{size}.zarr",
                priv,
                brick=max(8, size // 4),
                vector_dims=4,
                progress=False,
                client=client,
            )
        log_line(f"  {size}^3 store encrypted ({bits} bits)")
        cam = Camera.orbit(ev, azimuth=30, elevation=20, width=2 * size, height=2 * size)
        with dask.config.set(scheduler="sync"):  # resident in the backend's form, in this process
            resident = ev.persist(backend=be_name)
        out = []
        cases: tuple[tuple[str, str, dict[str, Any]], ...] = (
            ("xray", "nearest", {}),
            ("xray", "trilinear", {}),
            ("tf", "nearest", {"nodes": TF_NODES}),
        )
        for mode, sampling, kw in cases:
            t0 = time.perf_counter()
            with dask.config.set(scheduler="sync"):
                a = render(ev, cam, mode, sampling, backend=be_name, progress=False, cache=False, verify=False, **kw)
            t1 = time.perf_counter()
            frames = []
            for _ in range(3):  # resident frames: no store reads, bricks already in the backend's form
                f0 = time.perf_counter()
                with dask.config.set(scheduler="sync"):
                    r = render(
                        resident, cam, mode, sampling, backend=be_name, progress=False, cache=False, verify=False, **kw
                    )
                frames.append(time.perf_counter() - f0)
            same_resident = all(np.array_equal(x, y) for x, y in zip(a.ciphertexts, r.ciphertexts))
            c0 = time.perf_counter()  # the cpu render alone (the H200 run of 2026-11-26 timed the resident frames too)
            with dask.config.set(scheduler="sync"):
                b = render(
                    ev,
                    cam,
                    mode,
                    sampling,
                    backend="cpu",
                    progress=False,
                    cache=False,
                    client=client,
                    verify=False,
                    **kw,
                )
            t2 = time.perf_counter()
            same = len(a.ciphertexts) == len(b.ciphertexts) and all(
                np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts)
            )
            row = {
                "case": f"{mode} {sampling}",
                "size": size,
                "bits": bits,
                "identical": bool(same and same_resident),
                "within_bound": False,
                "seconds": t1 - t0,
                "resident_seconds": sorted(frames)[1],
                "cpu_seconds": t2 - c0,
                "cpu_workers": workers or 1,
            }
            try:  # a wrong backend's image may not even decrypt: the client's checks refuse it
                err = np.abs(a.decrypt(priv) - render_plain(vol, cam, mode, sampling, **kw))
                row["within_bound"] = bool(np.all(err <= error_bound(ev, cam, mode, sampling, **kw)))
            except IntegrityError as exc:
                row["error"] = str(exc)
            out.append(row)
            log_line(
                f"  {row['case']}: {row['seconds']:.2f} s streamed, {row['resident_seconds']:.2f} s resident, "
                f"cpu {row['cpu_seconds']:.2f} s on {row['cpu_workers']} "
                f"({'identical' if row['identical'] else 'MISMATCH'})"
            )
    return out
