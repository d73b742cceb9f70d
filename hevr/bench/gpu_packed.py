"""Issue 46's packed frame in the GPU proof: a packed store's frames on the backend and on ``cpu``.

``python -m hevr.bench.gpu_goals packed`` (``benchmarks/gpu-proof.sh goals`` or ``packed``) runs
:func:`packed_step`:

1. the ``size``³ phantom (uint8) encrypted as a packed store (``layout="packed"``, S voxels of a
   z column per ciphertext, :mod:`hevr.store.packing`) under its own key at ``bits`` (owner path, on
   a LocalCluster of ``workers`` processes, or in this process for one);
2. for two parallel views — *general* (azimuth 60, elevation 10: the shift along the packing axis
   spans the slot classes, so every block's classes are combined) and *orbit* (azimuth 90,
   elevation 20: one class, no combine) — and nearest and bilinear (``trilinear``) sampling: the
   frame on the backend from its resident copy (``persist(backend=...)``, this process, Dask's
   synchronous scheduler) and on ``cpu`` from its resident copy (the LocalCluster), each a first
   frame then the median of ``repeats``;
3. the identity rule checked, not assumed: both frames' ciphertexts byte for byte (their SHA-256
   kept), the decrypted slot sums and images equal, and the image within
   :func:`~hevr.rendering.encrypted.error_bound` of the float64 slice reference
   (``render_plain(..., slices=True)``);
4. last, the general bilinear frame *verified* (the store's default: the tags rendered through the
   same plan and aggregated on the backend, :mod:`hevr.rendering.packed.verified`), the key
   holder's check passed (``decrypt(..., require_verified=True)``) and its seconds kept.

One row per (view, sampling) is appended to ``OUT/goals.jsonl`` as soon as it is measured: both
backends' seconds, the frame's modular operations (map products, ray-pack pairs, merge products,
the combine's squarings and products), its tasks, rays and output ciphertexts, the packing (S, K)
and the classes; :func:`table_lines` puts them in ``goals.md``. Frame seconds are render only (the
key holder's decryption is timed apart, once).

Sizes: at 2048 bits the 128³ store is 65,536 ciphertexts (S = 40, K = 25: 32 MiB), encrypted in
12.9 s on this project's 2-core machine; its four frames took 0.9–3.5 s there on 2 workers
(``benchmarks/RESULTS-packed.md``) — about a minute in all on a 16-core GPU machine.
"""

from __future__ import annotations

import contextlib
import logging
import statistics
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import dask
import numpy as np

from ..errors import HevrError
from ..rendering.encrypted import error_bound, render
from ..rendering.geometry.camera import Camera
from ..rendering.reference.plain import render_plain
from ..store.writer import encrypt_volume
from ..volume.phantom import phantom
from .gpu_common import append_row, bench_key, image_digest, local_cluster
from .measure import dir_bytes

log = logging.getLogger(__name__)

__all__ = ["CASES", "VIEWS", "packed_step", "table_lines"]

VIEWS = {"general": (60.0, 10.0), "orbit": (90.0, 20.0)}
SAMPLINGS = ("nearest", "trilinear")
# (view, sampling, verified): the combine's cases first, the verified frame (a second round) last
CASES = [(v, s, False) for v in VIEWS for s in SAMPLINGS] + [("general", "trilinear", True)]


@contextlib.contextmanager
def _cpu_side(workers: int) -> Iterator[Any]:
    """Where ``cpu`` works: a LocalCluster of ``workers`` single-threaded processes, or None (this
    process, Dask's synchronous scheduler) for one."""
    if workers <= 1:
        yield None
        return
    with local_cluster(workers) as client:
        yield client


def _frames(
    volume: Any, cam: Camera, sampling: str, backend: str, client: Any, repeats: int, verify: bool = False
) -> tuple[list[float], Any]:
    """A first frame, then ``repeats`` timed ones: (their seconds, the last image)."""

    def one() -> Any:
        with dask.config.set(scheduler="sync") if client is None else contextlib.nullcontext():
            return render(
                volume,
                cam,
                "xray",
                sampling,
                backend=backend,
                client=client,
                progress=False,
                cache=False,
                verify=verify,
            )

    img = one()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        img = one()
        times.append(time.perf_counter() - t0)
    return times, img


def _same(a: Any, b: Any) -> bool:
    """Whether two packed images hold the same ciphertexts, record for record."""
    return len(a.ciphertexts) == len(b.ciphertexts) and all(
        x.shape == y.shape and bool((x == y).all()) for x, y in zip(a.ciphertexts, b.ciphertexts)
    )


def packed_step(
    out: Path, work: Path, backend: str, size: int, image: int, bits: int, repeats: int, workers: int
) -> bool:
    """The module docstring's steps; rows go to ``out/goals.jsonl`` (step ``"packed"``) as measured.
    Returns whether every frame was identical to cpu's and within the bound."""
    (work / "packed").mkdir(parents=True, exist_ok=True)
    priv = bench_key(work / "packed", bits)  # its own key: the other steps' key may be of another size
    vol = phantom(size)
    path = work / "packed" / "packed.zarr"
    brick = max(4, size // 4)
    with _cpu_side(workers) as client:
        t0 = time.perf_counter()
        with dask.config.set(scheduler="sync") if client is None else contextlib.nullcontext():
            ev = encrypt_volume(
                vol,
                path,
                priv,
                brick=brick,
                layout="packed",
                client=client,
                backend="cpu",
                progress=False,
                overwrite=True,
            )
        enc_s = time.perf_counter() - t0
        pk = ev.packing
        records = int(np.prod(pk.array_shape(ev.shape)))
        how = "cpu, " + (f"LocalCluster of {workers} processes" if client else "one process")
        append_row(
            out,
            {
                "step": "packed",
                "what": "encrypt packed",
                "size": size,
                "bits": bits,
                "seconds": enc_s,
                "ciphertexts": records,
                "voxels": size**3,
                "slots": pk.slots,
                "slot_bits": pk.slot_bits,
                "bytes": dir_bytes(path),
                "how": how,
            },
        )
        log.info(
            "packed %d^3 at %d bits: S=%d K=%d, %d ciphertexts, encrypted in %.2f s",
            size,
            bits,
            pk.slots,
            pk.slot_bits,
            records,
            enc_s,
        )
        with dask.config.set(scheduler="sync"):
            t0 = time.perf_counter()
            on_backend = ev.persist(backend=backend)
            persist_s = time.perf_counter() - t0
        if client is None:
            with dask.config.set(scheduler="sync"):
                on_cpu = ev.persist(backend="cpu")
        else:
            on_cpu = ev.persist(client=client, backend="cpu")
            assert on_cpu.resident is not None  # persist() returns a handle with it set
            on_cpu.resident.wait()
        ok = True
        for view, sampling, verify in CASES:
            az, el = VIEWS[view]
            cam = Camera.orbit(ev, azimuth=az, elevation=el, width=image, height=image, parallel=True)
            be_s, img = _frames(on_backend, cam, sampling, backend, None, repeats, verify)
            cpu_s, ref = _frames(on_cpu, cam, sampling, "cpu", client, repeats, verify)
            st = img.stats
            row = {
                "step": "packed",
                "what": f"packed {view} {sampling}{' verified' if verify else ''}",
                "backend": backend,
                "size": size,
                "image": image,
                "bits": bits,
                "slots": pk.slots,
                "slot_bits": pk.slot_bits,
                "classes": img.plan.classes,
                "seconds": statistics.median(be_s),
                "all_s": be_s,
                "cpu_seconds": statistics.median(cpu_s),
                "cpu_all_s": cpu_s,
                "cpu_workers": workers,
                "persist_s": persist_s,
                "identical": _same(img, ref),
                "within_bound": False,
                "sha256": image_digest(img),
                "cpu_sha256": image_digest(ref),
                "ops": st["ops"],
                "cpu_ops": ref.stats["ops"],
                "map_tasks": st["map_tasks"],
                "finish_tasks": st["finish_tasks"],
                "rays": st["rays"],
                "ciphertexts": st["ciphertexts"],
            }
            if verify:
                v = img.verification
                row.update(
                    {
                        "verified": False,
                        "verify_ops": getattr(v, "ops", None),
                        "verify_server_s": getattr(v, "server_s", None),
                    }
                )
            row.update(_check(img, ref, ev, cam, sampling, vol, priv, verify))
            row["identical"] = bool(row["identical"] and row.pop("decrypted_equal"))
            ok = ok and row["identical"] and row["within_bound"] and row.get("verified", True)
            append_row(out, row)
            log.info(
                "%s: %s %.3f s, cpu %.3f s, identical %s, within bound %s, ops %s",
                row["what"],
                backend,
                row["seconds"],
                row["cpu_seconds"],
                row["identical"],
                row["within_bound"],
                st["ops"],
            )
    return ok


def _check(
    img: Any, ref: Any, ev: Any, cam: Camera, sampling: str, vol: np.ndarray, priv: Any, verify: bool = False
) -> dict:
    """The key holder's side of one case: the backend's image decrypted (timed; a verified frame's
    check included), its slot sums and image equal to cpu's, within the bound of the slice
    reference; an image the key holder's checks refuse (a wrong backend's) is recorded as such."""
    try:
        t0 = time.perf_counter()
        arr = img.decrypt(priv, require_verified=True) if verify else img.decrypt(priv)
        dec_s = time.perf_counter() - t0
        equal = np.array_equal(img.decrypt_sums(priv), ref.decrypt_sums(priv)) and np.array_equal(
            arr, ref.decrypt(priv)
        )
        want = render_plain(vol, cam, "xray", sampling, slices=True)
        within = bool(np.all(np.abs(arr - want) <= error_bound(ev, cam, "xray", sampling)))
    except HevrError as exc:
        return {"decrypted_equal": False, "within_bound": False, "error": f"{type(exc).__name__}: {exc}"}
    return {
        "decrypted_equal": bool(equal),
        "within_bound": within,
        "decrypt_s": dec_s,
        **({"verified": True} if verify else {}),
    }


def table_lines(rows: list[dict]) -> list[str]:
    """``goals.md``'s packed section from the rows of :func:`packed_step` (none: no lines)."""
    enc = next((r for r in rows if r.get("step") == "packed" and r.get("what") == "encrypt packed"), None)
    frames = [r for r in rows if r.get("step") == "packed" and r.get("what", "").startswith("packed ")]
    if not enc and not frames:
        return []
    lines = ["", "Packed store (issue 46): frames from resident copies, render only (median s)", ""]
    if enc:
        lines += [
            f"{enc['size']}³ phantom at {enc['bits']} bits: S = {enc['slots']}, K = {enc['slot_bits']}, "
            f"{enc['ciphertexts']:,} ciphertexts ({enc['bytes'] / 2**20:.1f} MiB), encrypted in "
            f"{enc['seconds']:.3g} s ({enc['how']}).",
            "",
        ]
    if frames:
        lines += [
            "| frame | classes | backend s | cpu s (workers) | map / merge / combine products | identical | "
            "within bound |",
            "|---|---:|---:|---:|---:|---|---|",
        ]
        for r in frames:
            o = r["ops"]
            comb = o.get("combine", 0) + o.get("combine_squarings", 0)
            lines.append(
                f"| {r['what'][7:]} ({r['backend']}, {r['image']}²) | {r['classes']} | {r['seconds']:.3g} | "
                f"{r['cpu_seconds']:.3g} ({r['cpu_workers']}) | {o.get('map', 0):,} / {o.get('merge', 0):,} / "
                f"{comb:,} | {'yes' if r['identical'] else 'NO'} | {'yes' if r['within_bound'] else 'NO'} |"
            )
    return lines
