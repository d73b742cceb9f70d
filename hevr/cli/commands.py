"""Implementations of ``hevr encrypt | render | recolour | decrypt | upgrade-store`` (see
:mod:`hevr.cli.main`; the key commands are in :mod:`hevr.cli.keys`, ``info`` in
:mod:`hevr.cli.info`; :data:`hevr.cli.parser.COMMANDS` names each command's function).

Each ``cmd_*`` takes the parsed argparse namespace, prints its report on stdout and
returns the exit code; errors are raised and turned into one line and an exit status by
:func:`hevr.cli.main.main` (:mod:`hevr.cli.exits`). What only the command line can check is
checked here first, in its words (``UsageError("--out: …")``), before anything is computed.
Every size printed goes through :func:`~hevr.cli.util.xyz` / :func:`~hevr.cli.util.wh`.
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.files import check_regular
from ..crypto.keys import PrivateKey
from ..image import load_image
from ..image.display import default_window
from ..image.orient import describe_layout
from ..image.proof import Expect, proof_of
from ..paper import PAPER_DENSITIES, PAPER_TF1
from ..rendering.encrypted import render
from ..rendering.geometry.camera import Camera
from ..rendering.packed.colour import PackedColourImage
from ..rendering.packed.image import PackedImage
from ..rendering.pipeline.sums import MAGIC as SUMS_MAGIC
from ..rendering.pipeline.sums import load_sums, recolour
from ..rendering.planning.planner import check_render_size
from ..runtime.scheduler import declared_own
from ..store.paths import normalise
from ..store.upgrade import upgrade_store
from ..store.writer import encrypt_volume
from . import storage as st
from .cluster import dask_client, describe_client
from .describe import channels
from .finish import colour_options, report_finish
from .keys import key_label, read_key
from .packed import (
    check_packed_decrypt,
    check_packed_render,
    packed_done,
    packed_encrypt_lines,
    packed_start,
    packed_verified_line,
)
from .pyramid import level_rows
from .remote import open_remote
from .render_options import format_tf
from .scan import encrypt_input, resolve_tf
from .util import (
    Timer,
    UsageError,
    check_frame_path,
    check_new_file,
    check_store_path,
    check_writable_dir,
    disk_usage,
    human_bytes,
    plural,
    show_progress,
    warn_line,
    wh,
    xyz,
)
from .verifying import key_holder, verified_line, warn_unverified  # hevr.cli.slice takes them from here too

log = logging.getLogger("hevr.cli.main")


# -- encrypt -------------------------------------------------------------------------------
def cmd_encrypt(args: Any) -> int:

    if args.resume and args.overwrite:
        raise UsageError("--resume, --overwrite: expected one of them, got both (they exclude each other)")
    if args.gradient and not args.vector_dims:
        raise UsageError(
            "--gradient: expected --vector-dims K as well (the gradient channel scales the K-dim density encoding)"
        )
    if args.no_scalar and not args.vector_dims:
        raise UsageError("--no-scalar: expected --vector-dims K as well (a store needs at least one channel)")
    so = st.storage_options(args)
    store = st.encrypt_target(args, so)
    key = read_key(args.key)
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    own = args.own_cluster or (bool(args.scheduler) and args.trust_scheduler)  # --trust-scheduler: its old name
    if private and args.scheduler and not (own or declared_own(args.scheduler)):
        raise UsageError(
            f"--key: {args.key} is a private key and --scheduler is set: the owner-side fast path would send "
            "p and q to the cluster's workers, and Dask lets that cluster run code in this process; encrypt with "
            "the public key (.pub.json), or pass --own-cluster if the cluster is yours"
        )
    scan, value_range = encrypt_input(args)  # prints input, scan and value-range lines
    print(f"key:     {key_label(pub)}")
    print(
        "path:    "
        + (
            "owner-side fast path (private key: p, q speed up encryption; the store still holds only the public key)"
            if private
            else "public-key path ((1 + m·n)·h^s mod n², fixed base and short exponents after "
            "Damgård–Jurik–Nielsen; slower than encrypting with the private key)"
        )
    )
    with dask_client(args.scheduler, args.workers, own=own) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = encrypt_volume(
                scan,
                store,
                key,
                brick=args.brick,
                scalar=not args.no_scalar,
                vector_dims=args.vector_dims,
                value_range=value_range,
                digits=args.digits,
                overwrite=args.overwrite,
                resume=args.resume,
                gradient=args.gradient,
                storage_options=so,
                verifiable=args.verifiable,
                layout=args.layout,
                pack_axis=args.pack_axis,
                levels=args.levels,
                progress=show_progress(args, lines=True),
            )
    records = int(np.prod(ev.packing.array_shape(ev.shape))) if ev.packing is not None else int(np.prod(ev.shape))
    n_ct = records * sum(ev.meta.components(ch) for ch in ev.meta.channel_names)
    chans = channels(ev.meta)
    now = getattr(ev, "written_now", {"bricks": ev.meta.n_bricks, "ciphertexts": n_ct})
    bricks = plural(ev.meta.n_bricks, "brick")
    size = human_bytes(st.size_of(ev.path, so))
    if now["bricks"] == 0:
        print(
            f"{args.out}: already complete ({bricks} of {xyz(ev.brick)}, channels {chans}, {n_ct:,} ciphertexts, "
            f"{size}); nothing was left to encrypt"
        )
    else:
        part = (
            f"; resumed: {plural(now['bricks'], 'brick')} ({now['ciphertexts']:,} ciphertexts) encrypted now"
            if now["bricks"] < ev.meta.n_bricks
            else ""
        )
        print(
            f"wrote {args.out}: {bricks} of {xyz(ev.brick)}, channels {chans}, {n_ct:,} ciphertexts, {size}{part}, "
            f"in {t.seconds:.2f} s ({now['ciphertexts'] / max(t.seconds, 1e-9):,.0f} ciphertexts/s)"
        )
    if ev.packing is not None:
        packed_encrypt_lines(ev, args.out)
    elif not ev.vector_dims:
        print("note: scalar channel only (X-ray); add --vector-dims 4 to allow --mode emphasize/tf")
    for name, text in level_rows(ev.meta):
        print(f"{name}: {text}")
    if ev.meta.tags and ev.packing is None:  # a packed store's: packed_encrypt_lines
        print(
            f"verifiable: store id {ev.meta.store_id}; keep it, and render with --key KEY --verify "
            f"{ev.meta.store_id} to refuse any other store a server might answer with (recorded in your known "
            "stores)"
        )
    return 0


# -- render --------------------------------------------------------------------------------
def resolve_mode(args: Any) -> str:
    """The render mode: explicit --mode, else inferred from --density / --tf, else xray."""
    mode = args.mode or ("tf" if args.tf is not None else "emphasize" if args.density is not None else "xray")
    if mode == "emphasize" and args.density is None:
        raise UsageError(
            f"--mode emphasize: expected --density D as well (a normalised density in [0, 1], "
            f"e.g. {PAPER_DENSITIES[1]})"
        )
    if mode != "emphasize" and args.density is not None:
        raise UsageError(f"--density: only applies to --mode emphasize, got --mode {mode}")
    if mode != "tf" and args.tf is not None:
        raise UsageError(f"--tf: only applies to --mode tf, got --mode {mode}")
    return mode


def open_for_mode(
    store: str, mode: str, verb: str, so: dict | None = None, args: Any = None, packed: bool = False
) -> Any:
    """Open STORE (a folder or a URL, with storage options ``so``; with ``args.server``, the store id
    on that ``hevr serve``: :func:`open_remote`) and check that it has the channel ``mode`` reads
    (``verb``: the command, for the hint). A packed store only where the command serves one
    (``packed``; its options are checked by the command: :mod:`hevr.cli.packed`)."""
    ev = open_remote(args) if getattr(args, "server", None) else st.open_store(store, "STORE", so)
    if getattr(ev, "packing", None) is not None:
        if not packed:
            raise UsageError(
                f"STORE: expected a per-voxel store for 'hevr {verb}', got the packed store {store}: a "
                "packed store serves X-ray frames ('hevr render'); encrypt a per-voxel store for it"
            )
        return ev
    if mode != "xray" and not ev.vector_dims:
        raise UsageError(
            f"--mode {mode}: expected a store with the vector channel, got {store} without one; "
            f"encrypt it with --vector-dims 4 (or {verb} --mode xray)"
        )
    if mode == "xray" and not ev.has_scalar:
        raise UsageError(
            f"--mode xray: expected a store with the scalar channel, got {store} without one "
            f"(encrypted with --no-scalar); {verb} --mode emphasize or --mode tf"
        )
    return ev


def compute_context(args: Any, ev: Any) -> Any:
    """The Dask client of a local render (:func:`dask_client`), or none for a remote one."""
    if getattr(ev, "remote", None) is not None:
        print(f"compute: hevr serve at {ev.remote.url} (this process holds no Dask client)")
        return contextlib.nullcontext(None)
    return _local_client(args)


@contextlib.contextmanager
def _local_client(args: Any) -> Any:
    with dask_client(args.scheduler, args.workers, own=getattr(args, "own_cluster", False)) as client:
        print(f"compute: {describe_client(client)}")
        yield client


def cmd_render(args: Any) -> int:
    mode = resolve_mode(args)
    nodes = (args.tf if args.tf is not None else list(PAPER_TF1)) if mode == "tf" else None
    so = st.storage_options(args)
    out = st.output_file(args.out, force=args.force, so=so)
    sums = (
        st.output_file(args.keep_sums, "--keep-sums", force=args.force, so=so) if args.keep_sums is not None else None
    )
    if sums is not None and str(sums) == str(out):
        raise UsageError(f"--keep-sums: expected another file than --out, got {args.keep_sums} for both")
    ev = open_for_mode(args.store, mode, "render", so, args, packed=True)
    if getattr(ev, "packing", None) is not None:
        return _render_packed(args, ev, mode, out, so)
    nodes = resolve_tf(nodes, ev.value_range)  # a --tf preset: in the store's value range
    verify = key_holder(args, ev)
    if args.view and ev.frame is None:
        warn_line(
            f"--view {args.view}: {args.store} records no patient frame (its input had no orientation); "
            "the view takes the stored axes as RAS+ (x right, y anterior, z superior)"
        )
    w, h = args.size
    step = 1.0 if args.step is None else args.step
    azimuth, elevation = args.azimuth or 0.0, args.elevation or 0.0
    cam = Camera.orbit(
        ev,
        azimuth=azimuth,
        elevation=elevation,
        width=w,
        height=h,
        parallel=args.parallel,
        view_angle=30.0 if args.view_angle is None else args.view_angle,
        view=args.view,
    )
    if args.level > ev.levels:
        raise UsageError(
            f"--level {args.level}: expected a level of the store's pyramid (0 to {ev.levels}), got "
            f"{args.level}; build it with: hevr pyramid {args.store} --levels {args.level}"
        )
    check_render_size(cam, ev.shape, ev.spacing, step)  # refuse before a cluster starts
    what = {
        "xray": "X-ray",
        "emphasize": f"emphasis of density {args.density}",
        "tf": f"transfer function {format_tf(nodes) if nodes else ''}",
    }[mode]
    print(f"store:   {args.store}, {xyz(ev.shape)} voxels, key {ev.meta.fingerprint[:16]}…")
    lvl = f", pyramid level {args.level} ({xyz(ev.meta.levels[args.level - 1].shape)})" if args.level else ""
    print(
        f"render:  {what}, {args.sampling} sampling, {wh(w, h)} px, "
        f"{f'{args.view} view, ' if args.view else ''}azimuth {azimuth:g}, "
        f"elevation {elevation:g}, step {step:g}{lvl}"
    )
    with compute_context(args, ev):
        with Timer() as t:
            img = render(
                ev,
                cam,
                mode=mode,
                sampling=args.sampling,
                step=step,
                density=args.density,
                nodes=nodes,
                precision=args.precision,
                pack=not args.no_pack,
                progress=show_progress(args),
                keep_sums=sums,
                level=args.level or None,
                gradient=args.gradient,
                overwrite=args.force,
                finish=args.finish,
                verify=verify,
            )
    st.save_frame(img, out, force=args.force, so=so, private_key=args.private_key)
    if verified_line(img):
        print(verified_line(img) + " (stamped with the key holder's MAC)")
    warn_unverified(args, ev, img)
    print(
        f"wrote {out}: {plural(img.n_ciphertexts, 'ciphertext')} ({img.per_pack} values each), "
        f"{human_bytes(st.size_of(out, so))}, rendered in {t.seconds:.2f} s"
    )
    if sums is not None:
        again = (
            " (X-ray sums: other --precision / --no-pack)"
            if mode == "xray"
            else " --tf NODES | --density D"
            if args.finish == "server"
            else " --finish server --tf NODES | --density D (a client frame is "
            "re-coloured at decryption: hevr decrypt --tf | --density)"
        )
        print(
            f"wrote {sums}: the view's encrypted ray sums, {human_bytes(st.size_of(sums, so))}; "
            f"finish again with: hevr recolour {sums} --out FRAME.hevr{again}"
        )
    report_finish(img, out, mode, args.density, nodes)
    return 0


def _render_packed(args: Any, ev: Any, mode: str, out: Any, so: dict | None) -> int:
    """``hevr render`` on a packed store (:mod:`hevr.cli.packed`): a parallel X-ray, its file stamped
    with ``--key``."""
    check_packed_render(args, mode, ev)
    verify = key_holder(args, ev)
    cam = packed_start(args, ev)  # the camera, its checks and the store / render lines
    colour = (
        {}
        if mode == "xray"
        else {
            "mode": mode,
            "density": args.density,
            "gradient": bool(args.gradient),
            "nodes": resolve_tf(
                (args.tf if args.tf is not None else list(PAPER_TF1)) if mode == "tf" else None, ev.value_range
            ),
        }
    )
    with compute_context(args, ev):
        with Timer() as t:
            img = render(
                ev,
                cam,
                sampling=args.sampling,
                progress=show_progress(args),
                level=args.level or None,
                verify=verify,
                **colour,
            )
    st.save_frame(img, out, force=args.force, so=so, private_key=args.private_key)
    opts = colour_options(mode, args.density, colour.get("nodes")) if colour else ""
    packed_done(img, out, human_bytes(st.size_of(out, so)), t.seconds, lambda: warn_unverified(args, ev, img), opts)
    return 0


# -- recolour ------------------------------------------------------------------------------
def cmd_recolour(args: Any) -> int:
    so = st.storage_options(args)
    path = normalise(args.sums) if st.is_url(args.sums) else st.local_path(args.sums)
    out = normalise(args.out) if st.is_url(args.out) else st.local_path(args.out)
    if str(path if st.is_url(args.sums) else path.absolute()) == str(out if st.is_url(args.out) else out.absolute()):
        raise UsageError(f"--out: expected another file than SUMS, got {args.out} for both (it would replace the sums)")
    out = st.output_file(args.out, force=args.force, so=so)  # after the check above: SUMS exists
    if not st.is_url(args.sums):  # missing, or a folder, FIFO, device (never opened: it could block)
        check_regular(args.sums, "SUMS", "a ray-sums file (hevr render --keep-sums)")
    if st.head_of(args.sums, len(SUMS_MAGIC) - 1, "SUMS", "a ray-sums file", so) != SUMS_MAGIC[:-1]:
        raise UsageError(f"SUMS: expected a ray-sums file (hevr render --keep-sums), got {args.sums}, which is not one")
    saved = load_sums(path, storage_options=so)
    if args.mode is None and args.tf is None and args.density is None:
        args.mode = "xray" if saved.channel == "scalar" else "tf"
    mode = resolve_mode(args)
    nodes = (args.tf if args.tf is not None else list(PAPER_TF1)) if mode == "tf" else None
    if (saved.channel == "scalar") != (mode == "xray"):
        raise UsageError(
            f"--mode {mode}: expected {'X-ray' if mode == 'xray' else 'emphasis/TF'} ray sums, got "
            f"{args.sums} with the {saved.channel} channel's; render them again with --keep-sums "
            f"and {'--mode xray' if mode == 'xray' else '--density or --tf'}"
        )
    nodes = resolve_tf(nodes, saved.meta.value_range)
    cam = saved.camera
    print(
        f"sums:    {args.sums}, {saved.sampling} sampling, {wh(cam.width, cam.height)} px, key "
        f"{saved.meta.fingerprint[:16]}… (from {saved.store or 'an unnamed store'})"
    )
    with dask_client(args.scheduler, args.workers, own=getattr(args, "own_cluster", False)) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            img = recolour(
                saved,
                mode=mode,
                density=args.density,
                nodes=nodes,
                precision=args.precision,
                pack=not args.no_pack,
                client=client,
                progress=show_progress(args),
                gradient=args.gradient,
                finish=args.finish,
            )
    st.save_frame(img, out, force=args.force, so=so)
    done = "re-coloured" if img.finish == "server" else "packed for colouring at decryption"
    print(
        f"wrote {out}: {plural(img.n_ciphertexts, 'ciphertext')}, {human_bytes(st.size_of(out, so))}, {done} in "
        f"{t.seconds:.2f} s (no map step)"
    )
    report_finish(img, out, mode, args.density, nodes)
    return 0


# -- decrypt -------------------------------------------------------------------------------
def decrypt_colouring(args: Any, img: Any) -> tuple[str, float | None, Any] | None:
    """(mode, density, nodes) that colour the client-finished frame ``img`` (``--mode``,
    ``--density``, ``--tf``, ``--value-range`` for a preset); None for a frame the server
    finished, which takes none of them. Every mistake is a :class:`UsageError` naming the option."""
    given = [
        opt
        for opt, v in (
            ("--mode", args.mode),
            ("--density", args.density),
            ("--tf", args.tf),
            ("--value-range", args.value_range),
        )
        if v is not None
    ]
    if img.finish != "client":
        if given:
            raise UsageError(
                f"{', '.join(given)}: only for a frame finished on the client, got {args.frame}, which "
                "the server finished (its colouring was applied there); render it with --finish client "
                "to colour at decryption"
            )
        return None
    channel = str(img.channel)
    if args.mode is None and args.density is None and args.tf is None:
        if channel != "scalar":
            raise UsageError(
                f"--tf, --density: expected one of them to colour {args.frame}: it holds the {channel} "
                "channel's ray sums, finished on the client, and not the render's transfer function or "
                "density (hevr render printed the decrypt command with them)"
            )
        if args.value_range is not None:
            raise UsageError("--value-range: only applies to a --tf preset, got no --tf")
        return "xray", None, None
    mode = resolve_mode(args)
    if channel == "scalar" and mode != "xray":
        opt = f"--mode {mode}" if args.mode else "--tf" if args.tf is not None else "--density"
        raise UsageError(
            f"{opt}: expected no colouring for {args.frame}, an X-ray (the scalar channel's ray sums); "
            "emphasis and transfer functions colour a frame of the vector channel (hevr render "
            "--density / --tf)"
        )
    if channel != "scalar" and mode == "xray":
        raise UsageError(
            f"--mode xray: expected --mode emphasize or tf for {args.frame}, a frame of the {channel} "
            "channel's ray sums (an X-ray reads the scalar channel: hevr render --mode xray)"
        )
    nodes = (args.tf if args.tf is not None else list(PAPER_TF1)) if mode == "tf" else None
    if args.value_range is not None and not isinstance(nodes, str):
        raise UsageError(
            f"--value-range: only applies to a --tf preset, got "
            f"{'--tf DENSITY:COLOR,...' if args.tf is not None else 'no --tf'}"
        )
    if isinstance(nodes, str):
        if args.value_range is None:
            raise UsageError(
                f"--tf {nodes}: a preset needs the store's value range and a frame does not record it; "
                "give --value-range=LO,HI (hevr info STORE shows it) or the nodes as DENSITY:COLOR,..."
            )
        nodes = resolve_tf(nodes, args.value_range)
    return mode, args.density, nodes


def expected(args: Any) -> Any:
    """``hevr decrypt``'s ``require_verified``: None (the key's policy), False (``--unverified``), True,
    a store id, or an :class:`hevr.Expect` of ``--expect-store / --expect-view / --max-age / --moved``."""
    if args.unverified:
        if args.require_verified or args.expect_store or args.expect_view or args.max_age or args.moved:
            raise UsageError("--unverified: expected alone, got it with --require-verified or an --expect option")
        return False
    if not (args.expect_store or args.expect_view or args.max_age or args.moved):
        return args.require_verified
    store = args.expect_store
    if isinstance(args.require_verified, str):
        if store is not None and store != args.require_verified:
            raise UsageError(
                f"--expect-store {store}: expected the store --require-verified names, got "
                f"{args.require_verified} there"
            )
        store = args.require_verified
    return Expect(store=store, view=args.expect_view, max_age=args.max_age, moved=args.moved)


def cmd_decrypt(args: Any) -> int:
    so = st.storage_options(args)
    frame = normalise(args.frame) if st.is_url(args.frame) else check_frame_path(st.local_path(args.frame), "FRAME")
    out = Path(args.out).expanduser() if args.out else Path(st.png_name(frame))
    check_new_file(out, "--out", suffix=".png", force=args.force)
    npy = Path(args.npy).expanduser() if args.npy else None
    if npy is not None:
        check_new_file(npy, "--npy", force=args.force)
        if npy.absolute() == out.absolute():
            raise UsageError(f"--npy: expected another file than --out, got {args.npy} for both")
    key = read_key(args.key, private=True)
    img = load_image(frame, storage_options=so)
    packed = isinstance(img, (PackedImage, PackedColourImage))
    colouring = check_packed_decrypt(args) if isinstance(img, PackedImage) else decrypt_colouring(args, img)
    need = expected(args)
    with Timer() as t:
        decrypted = (
            img.decrypt_frame(key, require_verified=need)
            if colouring is not None
            else img.decrypt(key, require_verified=need)
        )
    coloured = ""
    if colouring is not None:
        mode, density, nodes = colouring
        with Timer() as tc:
            arr = decrypted.recolour(mode, density, nodes)
        what = (
            "X-ray"
            if mode == "xray"
            else f"emphasis of density {density:g}"
            if mode == "emphasize"
            else f"transfer function {format_tf(nodes)}"
        )
        coloured = f"; coloured on this machine in {1000 * tc.seconds:.1f} ms ({what})"
    else:
        arr = decrypted
    cam = {} if packed else (img.info or {}).get("camera") or {}
    plane = cam if cam.get("kind") == "plane" else None
    hits = None if packed else img.hits if img.hits is not None and img.hits.shape == arr.shape[:2] else None
    window = args.window if args.window is not None else default_window(arr, hits)
    st.save_decrypted(arr, out, npy, window, force=args.force, plane=plane, hits=hits)
    rgb = ", rgb" if arr.ndim == 3 else ""
    print(
        f"decrypted {plural(img.n_ciphertexts, 'ciphertext')} in {t.seconds:.3f} s: {wh(arr.shape[1], arr.shape[0])} px"
        f"{rgb}, values {float(arr.min()):.6g} .. {float(arr.max()):.6g}{coloured}"
    )
    if img.verification is not None:
        proof = proof_of(img)
        if proof.moved and need is None:
            print(
                f"NOT verified for {frame}: the key holder saved this frame as {proof.saved_as}; it proves only "
                f"that it is {proof.what} (name what you expect: --expect-store "
                f"{proof.store_id} --expect-view {proof.view_key})"
            )
        else:
            print(
                (packed_verified_line(img) if packed else verified_line(img)) + " (the file carries the key "
                f"holder's stamp)\nproof:   {proof.describe()}"
            )
    else:
        print(
            "not verified: the frame carries no check against a store's tags (a store encrypted without "
            "--verifiable, rendered without --key or with --no-verify or --finish server); --require-verified "
            "refuses such a frame"
        )
    if args.window is None and arr.ndim == 2:
        how = (
            "the value range (0.1th .. 99.9th percentile), as the image has negative values"
            if window[0] < 0
            else "0 .. the 99.9th percentile"
        )
        print(f"window:  {window[0]:.6g} .. {window[1]:.6g} ({how}; --window LO,HI sets another)")
    if plane is not None:
        print(f"shown:   {describe_layout(plane)}")
    print(f"wrote {out}")
    if npy is not None:
        order = ", in the plane's pixel order, not turned like the PNG" if plane else ""
        print(f"wrote {npy} (float64 values{order})")
    return 0


# -- upgrade-store ---------------------------------------------------------------------------
def cmd_upgrade_store(args: Any) -> int:
    check_store_path(Path(args.src).expanduser(), "OLD")
    dst = Path(args.dst).expanduser()
    if dst.exists():
        raise UsageError(f"NEW: {args.dst} already exists; choose a new path for the upgraded store")
    check_writable_dir(dst, "NEW")
    with dask_client(args.scheduler, args.workers, own=getattr(args, "own_cluster", False)) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = upgrade_store(args.src, args.dst, client=client, progress=show_progress(args))
    print(
        f"wrote {args.dst}: format {ev.meta.version}, {plural(ev.meta.n_bricks, 'brick')} with digests, "
        f"{human_bytes(disk_usage(ev.path))}, in {t.seconds:.2f} s; {args.src} is unchanged"
    )
    return 0


__all__ = [
    "cmd_encrypt",
    "cmd_render",
    "cmd_recolour",
    "cmd_decrypt",
    "cmd_upgrade_store",
    "decrypt_colouring",
    "open_for_mode",
    "resolve_mode",
]
