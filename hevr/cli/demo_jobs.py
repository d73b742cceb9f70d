"""The demo's figure set (:mod:`hevr.cli.demo`): the paper's images as :class:`Job` s, each rendered,
decrypted and compared with :func:`hevr.render_plain` (:func:`run_jobs`); the packed store's verified
parallel X-ray beside the per-voxel store's frame of the same camera (:func:`run_packed`); every name
the demo writes, and the tables of its report.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import MemoryLimitError
from ..image.display import default_window, save_png
from ..image.encrypted import EncryptedImage
from ..paper import (
    PAPER_DENSITIES,
    PAPER_TF1,
    PAPER_TF2,
    tf_text,
)
from ..rendering.encrypted import error_bound, render
from ..rendering.geometry.camera import Camera
from ..rendering.packed.image import PackedImage
from ..rendering.reference.plain import render_plain
from ..store.writer import encrypt_volume
from .outdir import OutputFolder
from .packed import default_packed_view
from .util import (
    Timer,
    disk_usage,
    human_bytes,
    show_progress,
    table,
)

__all__ = [
    "Job",
    "jobs_table",
    "output_names",
    "packed_job",
    "packed_table",
    "paper_jobs",
    "run_jobs",
    "run_packed",
    "stages_table",
    "write_files",
]


@dataclass
class Job:
    """One image of the figure set."""

    name: str
    title: str
    mode: str
    sampling: str
    density: float | None = None
    nodes: Any = None
    result: dict = field(default_factory=dict)


def paper_jobs() -> list[Job]:
    """The paper's figure set (X-ray, emphasis at three densities, two transfer functions)."""
    jobs = [
        Job("xray-nearest", "X-ray, nearest", "xray", "nearest"),
        Job("xray-trilinear", "X-ray, trilinear", "xray", "trilinear"),
    ]
    for d in PAPER_DENSITIES:
        jobs.append(Job(f"emphasize-{d}", f"emphasis of density {d}, trilinear", "emphasize", "trilinear", density=d))
    for i, tf in enumerate((PAPER_TF1, PAPER_TF2), 1):
        jobs.append(Job(f"tf{i}", f"transfer function {tf_text(tf)}", "tf", "trilinear", nodes=list(tf)))
    return jobs


def _window(ref: np.ndarray) -> tuple[float, float]:
    """The default PNG window of :func:`hevr.image.display.to_uint8`, taken from the reference."""
    return default_window(ref)


def write_files(
    folder: OutputFolder,
    name: str,
    img: Any,
    arr: np.ndarray,
    ref: np.ndarray,
    window: tuple[float, float],
    **save: Any,
) -> None:
    """An image's three files in ``folder``: the encrypted frame ``NAME.hevr`` (``save``: keyword
    arguments of its ``save``), the decrypted ``NAME.png`` and the reference ``NAME.ref.png`` in one
    ``window``; each replaces only what :class:`hevr.cli.outdir.OutputFolder` allows."""
    frame = f"{name}.hevr"
    img.save(folder.path / frame, overwrite=folder.overwrite(frame), **save)
    folder.wrote(frame)
    for png, values in ((f"{name}.png", arr), (f"{name}.ref.png", ref)):
        save_png(values, folder.path / png, window=window, overwrite=folder.overwrite(png))
        folder.wrote(png)


def packed_job() -> Job:
    """The packed store's frame (:func:`run_packed`)."""
    return Job("xray-packed", "packed store: verified parallel X-ray, bilinear in each slice", "xray", "trilinear")


def output_names(jobs: list[Job], packed: bool = True) -> list[str]:
    """Every name the demo writes into its folder (``packed``: the packed store's too)."""
    frames = [
        f"{j.name}{ext}" for j in jobs + ([packed_job()] if packed else []) for ext in (".hevr", ".png", ".ref.png")
    ]
    return [
        "demo-key.json",
        "demo-key.pub.json",
        "volume.zarr",
        *(["volume-packed.zarr"] if packed else []),
        *frames,
        "contact-sheet.png",
        "summary.json",
        "report.md",
    ]


def run_jobs(
    ev: Any,
    vol: np.ndarray,
    priv: Any,
    jobs: list[Job],
    cam: Any,
    *,
    progress: bool,
    outdir: OutputFolder | None = None,
    log: Any = print,
) -> None:
    """Render, decrypt and compare every job (results in ``job.result``); optionally write files
    into ``outdir`` (what it may replace: :class:`hevr.cli.outdir.OutputFolder`)."""

    for job in jobs:
        kw = dict(mode=job.mode, sampling=job.sampling, step=1.0, density=job.density, nodes=job.nodes)
        with Timer() as tr:  # the store has no tags: said once by the caller, not at every frame
            img = render(ev, cam, progress=progress, verify=False, **kw)
        assert isinstance(img, EncryptedImage)  # the per-voxel store's frame
        with Timer() as td:
            arr = img.decrypt(priv)
        with Timer() as tp:
            ref = render_plain(
                vol, cam, spacing=ev.spacing, value_range=ev.value_range, vector_dims=ev.vector_dims, **kw
            )
        err = np.abs(arr - ref)
        bound = error_bound(ev, cam, **kw)
        scale = float(np.abs(ref).max()) or 1.0
        job.result = {
            "render_s": tr.seconds,
            "decrypt_s": td.seconds,
            "frame_s": tr.seconds + td.seconds,
            "reference_s": tp.seconds,
            "finish": img.finish,
            "max_abs_error": float(err.max()),
            "max_rel_error": float(err.max()) / scale,
            "within_bound": bool((err <= bound).all()),
            "ciphertexts": img.n_ciphertexts,
            "reused_ray_sums": bool(img.stats.get("reused_ray_sums")),
            "resident": bool(img.stats.get("resident")),
        }
        if outdir is not None:
            win = _window(ref)
            write_files(outdir, job.name, img, arr, ref, win)
            job.result["window"] = list(win)
        log(
            f"  {job.name:<16} frame {tr.seconds + td.seconds:6.2f} s (render {tr.seconds:.2f} + decrypt "
            f"{td.seconds:.2f})  "
            f"max|err| {err.max():.2e}{'' if job.result['within_bound'] else '  (ABOVE the error bound!)'}"
        )


def jobs_table(jobs: list[Job]) -> str:
    rows = [
        [
            j.name,
            f"{j.result['max_abs_error']:.2e}",
            f"{j.result['max_rel_error']:.1e}",
            "yes" if j.result["within_bound"] else "NO",
            f"{j.result['frame_s']:.2f}",
            f"{j.result['render_s']:.2f}",
            f"{j.result['decrypt_s']:.3f}",
            j.result["ciphertexts"],
            "yes" if j.result["reused_ray_sums"] else "no",
        ]
        for j in jobs
    ]
    return table(
        rows,
        [
            "image",
            "max|err|",
            "rel.err",
            "in bound",
            "frame s (request → image)",
            "render s",
            "decrypt s",
            "ciphertexts",
            "cached sums",
        ],
    )


def stages_table(stages: dict) -> str:
    total = sum(stages.values())
    rows = [[k, f"{v:.2f}", f"{100 * v / total:.0f}%" if total else "-"] for k, v in stages.items()]
    rows.append(["total", f"{total:.2f}", "100%"])
    return table(rows, ["stage", "seconds", "share"])


def run_packed(
    ev: Any,
    vol: np.ndarray,
    priv: Any,
    args: Any,
    client: Any,
    folder: OutputFolder,
    stages: dict,
    job: Job,
    brick: Any,
) -> dict:
    """The packed store of the same volume (verifiable: the private key; ``brick`` as the per-voxel
    one's), persisted as that one is, and one verified parallel X-ray of it beside the per-voxel
    store's frame of the same camera; files into ``folder``, results in ``job.result`` and returned
    for the summary."""
    out, progress = folder.path, show_progress(args)
    with Timer() as t:
        pev = encrypt_volume(
            vol,
            out / "volume-packed.zarr",
            priv,
            spacing=ev.spacing,
            brick=brick,
            value_range=ev.value_range,
            layout="packed",
            overwrite=folder.overwrite("volume-packed.zarr"),
            progress=progress,
        )
        folder.wrote("volume-packed.zarr")
    stages["encrypt packed"] = t.seconds
    info = pev.packing
    size, size_voxel = disk_usage(pev.path), disk_usage(ev.path)
    print(
        f"[packed]  {t.seconds:.2f} s: {info.slots} voxels per ciphertext along {'zyx'[info.axis]}, with tags "
        f"(verifiable), {human_bytes(size)} (the per-voxel store: {human_bytes(size_voxel)})"
    )
    try:
        pev = pev.persist(client=client)
        assert pev.resident is not None  # persist() returns a handle with it set
        pev.resident.wait()
    except MemoryLimitError:
        pass  # streamed from the store, as the per-voxel one would be
    el = args.elevation if abs(args.elevation) < 40 else 0.0  # a packed store serves views around its axis
    w, h = args.image
    cam = Camera.orbit(
        pev, view=default_packed_view(pev), azimuth=args.azimuth, elevation=el, width=w, height=h, parallel=True
    )
    with Timer() as tr:
        img = render(pev, cam, sampling=job.sampling, progress=progress)
    assert isinstance(img, PackedImage)  # a packed store's frame (hevr.rendering.packed)
    with Timer() as td:
        arr = img.decrypt(priv, require_verified=pev.meta.store_id)  # checked against the tags before any pixel
    ref = render_plain(vol, cam, spacing=pev.spacing, value_range=pev.value_range, sampling=job.sampling, slices=True)
    err = np.abs(arr - ref)
    bound = error_bound(pev, cam, sampling=job.sampling)
    with Timer() as tv:  # the per-voxel store's frame of the same camera, for comparison
        vimg = render(ev, cam, mode="xray", sampling=job.sampling, progress=progress, verify=False)
        vimg.decrypt(priv)
    win = _window(ref)
    job.result = {
        "render_s": tr.seconds,
        "decrypt_s": td.seconds,
        "frame_s": tr.seconds + td.seconds,
        "finish": "client",
        "max_abs_error": float(err.max()),
        "max_rel_error": float(err.max()) / (float(np.abs(ref).max()) or 1.0),
        "within_bound": bool((err <= bound).all()),
        "ciphertexts": img.n_ciphertexts,
        "reused_ray_sums": False,
        "resident": bool(img.stats.get("resident")),
        "verified": img.verified,
        "window": list(win),
    }
    write_files(folder, "xray-packed", img, arr, ref, win, private_key=priv)
    stages["render packed"], stages["decrypt packed"] = tr.seconds, td.seconds
    print(
        f"  {job.name:<16} frame {tr.seconds + td.seconds:6.2f} s (render {tr.seconds:.2f} + decrypt and verify "
        f"{td.seconds:.2f}), verified; max|err| {err.max():.2e}"
        f"{'' if job.result['within_bound'] else '  (ABOVE the error bound!)'}; the per-voxel store's frame of the "
        f"same camera: {tv.seconds:.2f} s, not verified"
    )
    return {
        "store": "volume-packed.zarr",
        "axis": "zyx"[info.axis],
        "slots": info.slots,
        "slot_bits": info.slot_bits,
        "store_bytes": size,
        "voxel_store_bytes": size_voxel,
        "encrypt_s": t.seconds,
        "camera": cam.to_dict(),
        "voxel_frame_s": tv.seconds,
        "frame": "xray-packed.hevr",
        "png": "xray-packed.png",
        "reference_png": "xray-packed.ref.png",
        **job.result,
    }


def packed_table(r: dict) -> str:
    rows = [
        ["per-voxel (scalar + vector[4])", human_bytes(r["voxel_store_bytes"]), f"{r['voxel_frame_s']:.2f}", "no", "-"],
        [
            f"packed ({r['slots']} voxels/ciphertext along {r['axis']}, tags)",
            human_bytes(r["store_bytes"]),
            f"{r['frame_s']:.2f}",
            "yes" if r["verified"] else "no",
            f"{r['max_abs_error']:.2e}",
        ],
    ]
    return table(rows, ["store", "size", "parallel X-ray frame s", "verified", "max|err| (slice reference)"])
