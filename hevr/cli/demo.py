"""``hevr demo``: the whole pipeline end to end, with timings.

The demo generates the paper's phantom (or reads ``--input``), makes a key pair, encrypts
the scalar and the 4-dim vector channel on the owner-side fast path, starts a local
2-worker Dask cluster, renders the paper's figure set — X-ray (nearest and trilinear),
emphasis of the densities 0.331, 0.653 and 0.781, and two transfer functions (all from
:mod:`hevr.paper`) — decrypts each image, compares it with :func:`hevr.render_plain` and
writes PNGs, a contact sheet, ``report.md`` and ``summary.json``.

Beside it (``--no-packed`` leaves it out) the same volume is encrypted as a packed store
(:mod:`hevr.store.packing`, with the private key: verifiable) and one verified parallel X-ray
of it is rendered, decrypted and compared with its slice reference; the report shows both
stores' sizes and that frame's time beside the per-voxel store's frame of the same camera. The
per-voxel store has no tags (they would double its five ciphertexts per voxel and the demo's
encryption time), which the demo says once instead of warning at every frame.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import write_atomic
from ..crypto.keys import SECURE_BITS, generate_keypair
from ..errors import InsecureKeyWarning, MemoryLimitError
from ..rendering.geometry.camera import Camera
from ..store.writer import encrypt_volume
from .cluster import dask_client, describe_client
from .demo_jobs import (
    Job,
    jobs_table,
    output_names,
    packed_job,
    packed_table,
    paper_jobs,
    run_jobs,
    run_packed,
    stages_table,
)
from .keys import key_label
from .outdir import OutputFolder
from .render_options import format_tf
from .scan import load_input
from .sheet import contact_sheet
from .util import (
    Timer,
    UsageError,
    disk_usage,
    human_bytes,
    plural,
    show_progress,
    warn_line,
    wh,
    xyz,
)

__all__ = ["Job", "paper_jobs", "cmd_demo"]


def _keypair(bits: int) -> tuple[Any, Any]:

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        return generate_keypair(bits)


def _demo_volume(args: Any) -> tuple[np.ndarray, tuple, tuple | None, str]:
    """(volume, spacing, value_range, description); a user volume is normalised by its data range."""
    if args.input:
        vol, spacing, what = load_input(args.input)
        vol = np.asarray(vol)
        lo, hi = float(vol.min()), float(vol.max())
        return vol, spacing, (lo, hi if hi > lo else lo + 1.0), what
    vol, spacing, what = load_input(f"phantom:{args.size}")
    return vol, spacing, None, what


def _auto_brick(shape: tuple) -> int:
    """About 3 bricks per axis: enough tasks to keep a few workers busy, few enough to be cheap."""
    return max(4, math.ceil(max(shape) / 3))


def cmd_demo(args: Any) -> int:

    t_start = time.perf_counter()
    out = Path(args.out).expanduser()
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: expected a folder, got a file ({args.out})")
    packed = getattr(args, "packed", True)
    folder = OutputFolder(out, "demo", output_names(paper_jobs(), packed), force=args.force)
    folder.check()  # before any work: a file the demo did not write is never replaced without --force
    workers = 2 if args.workers is None else args.workers
    progress = show_progress(args)
    stages: dict[str, float] = {}
    vol, spacing, value_range, what = _demo_volume(args)
    w, h = args.image
    print(f"hevr demo: {what}, {w}x{h} px images, {args.bits}-bit key -> {out}/")
    if args.bits < SECURE_BITS:
        warn_line(f"the demo's {args.bits}-bit key is NOT secure (use --bits 2048 for real data)")
    with Timer() as t:
        pub, priv = _keypair(args.bits)
    stages["keygen"] = t.seconds
    # The demo's folder holds its own run: a new key, with the volume and images encrypted
    # under it, replaces the previous run's key only (the folder's record, hevr.cli.outdir).
    for name, key in (("demo-key.json", priv), ("demo-key.pub.json", pub)):
        key.save(out / name, overwrite=folder.overwrite(name))  # the private key: mode 0600
        folder.wrote(name)
    print(f"[keygen]  {t.seconds:.2f} s: {key_label(pub)}")
    brick = args.brick or _auto_brick(vol.shape)
    with contextlib.ExitStack() as stack:
        client = None
        if not args.scheduler:  # the private key (owner-side fast path) stays on this machine
            with Timer() as t:
                client = stack.enter_context(dask_client(None, workers))
            stages["start cluster"] = t.seconds
            print(f"[cluster] {t.seconds:.2f} s: {describe_client(client)}")
        with Timer() as t:
            ev = encrypt_volume(
                vol,
                out / "volume.zarr",
                priv,
                spacing=spacing,
                brick=brick,
                vector_dims=4,
                value_range=value_range,
                overwrite=folder.overwrite("volume.zarr"),
                progress=progress,
            )
            folder.wrote("volume.zarr")
        stages["encrypt"] = t.seconds
        n_ct = int(np.prod(vol.shape)) * 5
        print(
            f"[encrypt] {t.seconds:.2f} s: {n_ct} ciphertexts (scalar + 4-dim vector, owner-side fast path), "
            f"{plural(ev.meta.n_bricks, 'brick')} of {xyz(ev.brick)}, {human_bytes(disk_usage(ev.path))}"
        )
        if args.scheduler:
            with Timer() as t:
                client = stack.enter_context(dask_client(args.scheduler, None, own=getattr(args, "own_cluster", False)))
            stages["connect"] = t.seconds
            print(f"[cluster] {t.seconds:.2f} s: {describe_client(client)}")
        with Timer() as t:  # open once, render many: the jobs below read no brick from the store
            try:
                ev = ev.persist(client=client)
                assert ev.resident is not None  # persist() returns a handle with it set
                ev.resident.wait()
                resident = f"{human_bytes(ev.resident.nbytes)} of decoded bricks in worker memory"
            except MemoryLimitError as exc:
                resident = f"not resident ({exc}); rendering streams the bricks"
        stages["persist"] = t.seconds
        print(f"[persist] {t.seconds:.2f} s: {resident}")
        cam = Camera.orbit(ev, azimuth=args.azimuth, elevation=args.elevation, width=w, height=h)
        jobs = paper_jobs()
        print(
            f"[render]  {len(jobs)} images on {describe_client(client)}; decrypt and compare with render_plain "
            "(not verified: the per-voxel demo store has no tags; the packed store's frame is verified):"
        )
        run_jobs(ev, vol, priv, jobs, cam, progress=progress, outdir=folder)
        pjob = packed_job()
        packed_result = run_packed(ev, vol, priv, args, client, folder, stages, pjob, brick) if packed else None
    for j in jobs:
        stages[f"render {j.name}"] = j.result["render_s"]
    stages["decrypt (all)"] = sum(j.result["decrypt_s"] for j in jobs)
    stages["reference (all)"] = sum(j.result["reference_s"] for j in jobs)
    with Timer() as t:
        caption = f"hevr demo: {what}, {args.bits}-bit key, {w}x{h} px; left decrypted, right plaintext reference"
        sheet = jobs + ([pjob] if packed_result is not None else [])
        contact_sheet(out, sheet, caption, out / "contact-sheet.png", overwrite=folder.overwrite("contact-sheet.png"))
        folder.wrote("contact-sheet.png")
    stages["write images"] = t.seconds
    total = time.perf_counter() - t_start
    summary = {
        "input": what,
        "shape": list(vol.shape),
        "spacing": list(ev.spacing),
        "value_range": list(ev.value_range),
        "bits": args.bits,
        "fingerprint": pub.fingerprint,
        "image": [w, h],
        "brick": list(ev.brick),
        "camera": cam.to_dict(),
        "compute": describe_client(None) if client is None else "distributed",
        "workers": None if args.scheduler else workers,
        "stages_s": stages,
        "total_s": total,
        "images": [
            {
                "name": j.name,
                "title": j.title,
                "mode": j.mode,
                "sampling": j.sampling,
                "density": j.density,
                "tf": format_tf(j.nodes) if j.nodes else None,
                "png": f"{j.name}.png",
                "reference_png": f"{j.name}.ref.png",
                "frame": f"{j.name}.hevr",
                **j.result,
            }
            for j in jobs
        ],
    }
    if packed_result is not None:
        summary["packed"] = packed_result
    jt, st = jobs_table(jobs), stages_table(stages)
    pt = packed_table(packed_result) if packed_result is not None else None
    for name, text in (
        ("summary.json", json.dumps(summary, indent=1) + "\n"),
        ("report.md", _report(summary, jt, st, pt)),
    ):
        write_atomic(out / name, text, overwrite=folder.overwrite(name), name="--out", doing="writing the demo's")
        folder.wrote(name)
    print()
    print(jt)
    print()
    print(st)
    if pt is not None:
        print()
        print(pt)
    print(f"\nwrote {out}/contact-sheet.png, report.md, summary.json and {3 * len(sheet)} image files in {total:.1f} s")
    bad = [j.name for j in sheet if not j.result["within_bound"]]
    if bad:
        warn_line(f"decrypted images above the error bound: {', '.join(bad)}")
        return 1
    return 0


def _report(summary: dict, jobs_table: str, stages_table: str, packed_table: str | None = None) -> str:
    lines = [
        "# hevr demo",
        "",
        f"Input: {summary['input']}, spacing {xyz(summary['spacing'][::-1], sep=', ')}, value range "
        f"{tuple(summary['value_range'])}.  ",
        f"Key: {summary['bits']} bits, fingerprint `{summary['fingerprint']}`.  ",
        f"Images: {wh(*summary['image'])} px; bricks {xyz(summary['brick'])}; "
        f"workers: {summary['workers'] if summary['workers'] is not None else 'external scheduler'}.",
        "",
        "![contact sheet](contact-sheet.png)",
        "",
        "Each encrypted render was decrypted and compared with `hevr.render_plain` on the plaintext volume "
        "(same camera, mode and sampling). *in bound*: every pixel is within `hevr.rendering.encrypted.error_bound`.",
        "",
        "```",
        jobs_table,
        "```",
        "",
        "Time per stage:",
        "",
        "```",
        stages_table,
        "```",
        "",
    ]
    if packed_table is not None:
        lines += [
            "The same volume as a packed store (S voxels per ciphertext, verifiable) and one parallel X-ray "
            "(bilinear in each slice; compared with `render_plain(..., slices=True)`), beside the per-voxel "
            "store's frame of the same camera (frame: render, decrypt and, for the packed one, the check "
            "against the store's tags):",
            "",
            "```",
            packed_table,
            "```",
            "",
        ]
    return "\n".join(lines)
