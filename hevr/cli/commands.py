"""Implementations of ``hevr encrypt | render | recolour | decrypt | info | upgrade-store`` (see
:mod:`hevr.cli.main`; the key commands are in :mod:`hevr.cli.keys`, re-exported here for dispatch).

Each ``cmd_*`` takes the parsed argparse namespace, prints its report on stdout and
returns the exit code; errors are raised and turned into one line and an exit status by
:func:`hevr.cli.main.main` (:mod:`hevr.cli.exits`). What only the command line can check is
checked here first, in its words (``UsageError("--out: …")``), before anything is computed.
Every size printed goes through :func:`~hevr.cli.util.xyz` / :func:`~hevr.cli.util.wh`.
"""

from __future__ import annotations

import json
import logging
import stat
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..crypto.keys import SECURE_BITS, PrivateKey
from ..crypto.phe_keys import is_phe_dict
from .._files import check_regular
from ..errors import MissingFileError, StoreError
from ..image import MAGIC, load_image
from ..paper import PAPER_DENSITIES, PAPER_TF1
from ..rendering.camera import Camera
from ..rendering.encrypted import render
from ..rendering.planner import check_render_size
from ..rendering.sums import MAGIC as SUMS_MAGIC
from ..rendering.sums import load_sums, recolour
from ..store.metadata import VolumeMetadata
from ..store.paths import normalise, zarr_store
from ..store.layout import check_document
from ..store.reader import open_volume
from ..store.upgrade import upgrade_store
from ..store.writer import encrypt_volume
from . import storage as st
from .keys import cmd_convert_key, cmd_keygen
from .pyramid import level_rows
from .scan import encrypt_input, resolve_tf, scan_rows
from .verify import verify_store, warn_leftovers
from .util import (
    Timer,
    UsageError,
    check_frame_path,
    check_new_file,
    check_store_path,
    check_writable_dir,
    dask_client,
    describe_client,
    disk_usage,
    format_tf,
    human_bytes,
    key_label,
    read_key,
    show_progress,
    warn_line,
    wh,
    xyz,
)

log = logging.getLogger("hevr.cli.main")


# -- encrypt -------------------------------------------------------------------------------
def cmd_encrypt(args: Any) -> int:

    if args.resume and args.overwrite:
        raise UsageError("--resume, --overwrite: expected one of them, got both (they exclude each other)")
    if args.gradient and not args.vector_dims:
        raise UsageError("--gradient: expected --vector-dims K as well (the gradient channel scales the K-dim "
                         "density encoding)")
    if args.no_scalar and not args.vector_dims:
        raise UsageError("--no-scalar: expected --vector-dims K as well (a store needs at least one channel)")
    so = st.storage_options(args)
    store = st.encrypt_target(args, so)
    key = read_key(args.key)
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    if private and args.scheduler and not args.trust_scheduler:
        raise UsageError(
            f"--key: {args.key} is a private key and --scheduler is set: the owner-side fast path would send "
            "p and q to the cluster's workers; encrypt with the public key (.pub.json) or pass --trust-scheduler")
    scan, value_range = encrypt_input(args)  # prints input, scan and value-range lines
    print(f"key:     {key_label(pub)}")
    print("path:    " + ("owner-side fast path (private key: p, q speed up encryption; "
                          "the store still holds only the public key)" if private
                          else "public-key path (g^m r^n mod n^2; slower than encrypting with the private key)"))
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = encrypt_volume(scan, store, key, brick=args.brick, scalar=not args.no_scalar,
                                vector_dims=args.vector_dims, value_range=value_range, digits=args.digits,
                                overwrite=args.overwrite, resume=args.resume, gradient=args.gradient,
                                storage_options=so,
                                progress=show_progress(args))
    n_ct = int(np.prod(ev.shape)) * sum(ev.meta.components(ch) for ch in ev.meta.channel_names)
    chans = _channels(ev.meta)
    print(f"wrote {args.out}: {ev.meta.n_bricks} bricks of {xyz(ev.brick)}, channels {chans}, "
          f"{n_ct} ciphertexts, {human_bytes(st.size_of(ev.path, so))}, in {t.seconds:.2f} s "
          f"({n_ct / max(t.seconds, 1e-9):.0f} ciphertexts/s)")
    if not ev.vector_dims:
        print("note: scalar channel only (X-ray); add --vector-dims 4 to allow --mode emphasize/tf")
    return 0


def _channels(meta: Any) -> str:
    ch = []
    if meta.scalar is not None:
        ch.append("scalar" + (f" ({meta.scalar.digits} digits)" if meta.scalar.digits is not None else " (exact)"))
    if meta.vector is not None:
        ch.append(f"vector[{meta.vector.dims}] ({meta.vector.digits} digits)")
    if getattr(meta, "gradient", None) is not None:
        ch.append(f"gradient[{meta.gradient.dims}] ({meta.gradient.digits} digits)")
    return " + ".join(ch) or "none"


# -- render --------------------------------------------------------------------------------
def resolve_mode(args: Any) -> str:
    """The render mode: explicit --mode, else inferred from --density / --tf, else xray."""
    mode = args.mode or ("tf" if args.tf is not None else "emphasize" if args.density is not None else "xray")
    if mode == "emphasize" and args.density is None:
        raise UsageError(f"--mode emphasize: expected --density D as well (a normalised density in [0, 1], "
                         f"e.g. {PAPER_DENSITIES[1]})")
    if mode != "emphasize" and args.density is not None:
        raise UsageError(f"--density: only applies to --mode emphasize, got --mode {mode}")
    if mode != "tf" and args.tf is not None:
        raise UsageError(f"--tf: only applies to --mode tf, got --mode {mode}")
    return mode


def open_for_mode(store: str, mode: str, verb: str, so: dict | None = None) -> Any:
    """Open STORE (a folder or a URL, with storage options ``so``) and check that it has the channel
    ``mode`` reads (``verb``: the command, for the hint)."""
    ev = st.open_store(store, "STORE", so)
    if mode != "xray" and not ev.vector_dims:
        raise UsageError(f"--mode {mode}: expected a store with the vector channel, got {store} without one; "
                         f"encrypt it with --vector-dims 4 (or {verb} --mode xray)")
    if mode == "xray" and not ev.has_scalar:
        raise UsageError(f"--mode xray: expected a store with the scalar channel, got {store} without one "
                         f"(encrypted with --no-scalar); {verb} --mode emphasize or --mode tf")
    return ev


def cmd_render(args: Any) -> int:


    mode = resolve_mode(args)
    nodes = (args.tf if args.tf is not None else list(PAPER_TF1)) if mode == "tf" else None
    so = st.storage_options(args)
    out = st.output_file(args.out, force=args.force, so=so)
    sums = st.output_file(args.keep_sums, "--keep-sums", force=args.force, so=so) if args.keep_sums is not None else None
    if sums is not None and str(sums) == str(out):
        raise UsageError(f"--keep-sums: expected another file than --out, got {args.keep_sums} for both")
    ev = open_for_mode(args.store, mode, "render", so)
    nodes = resolve_tf(nodes, ev.value_range)  # a --tf preset: in the store's value range
    if args.view and ev.frame is None:
        warn_line(f"--view {args.view}: {args.store} records no patient frame (its input had no orientation); "
                  "the view takes the stored axes as RAS+ (x right, y anterior, z superior)")
    w, h = args.size
    cam = Camera.orbit(ev, azimuth=args.azimuth, elevation=args.elevation, width=w, height=h,
                       view_angle=args.view_angle, parallel=args.parallel, view=args.view)
    if args.level > ev.levels:
        raise UsageError(f"--level {args.level}: expected a level of the store's pyramid (0 to {ev.levels}), got "
                         f"{args.level}; build it with: hevr pyramid {args.store} --levels {args.level}")
    check_render_size(cam, ev.shape, ev.spacing, args.step)  # refuse before a cluster starts
    what = {"xray": "X-ray", "emphasize": f"emphasis of density {args.density}",
            "tf": f"transfer function {format_tf(nodes) if nodes else ''}"}[mode]
    print(f"store:   {args.store}, {xyz(ev.shape)} voxels, key {ev.meta.fingerprint[:16]}…")
    lvl = f", pyramid level {args.level} ({xyz(ev.meta.levels[args.level - 1].shape)})" if args.level else ""
    print(f"render:  {what}, {args.sampling} sampling, {wh(w, h)} px, "
          f"{f'{args.view} view, ' if args.view else ''}azimuth {args.azimuth:g}, "
          f"elevation {args.elevation:g}, step {args.step:g}{lvl}")
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            img = render(ev, cam, mode=mode, sampling=args.sampling, step=args.step, density=args.density,
                         nodes=nodes, precision=args.precision, pack=not args.no_pack,
                         progress=show_progress(args), keep_sums=sums, level=args.level or None,
                         gradient=args.gradient, overwrite=args.force)
    st.save_frame(img, out, force=args.force, so=so)
    print(f"wrote {out}: {img.n_ciphertexts} ciphertexts ({img.per_pack} values each), "
          f"{human_bytes(st.size_of(out, so))}, rendered in {t.seconds:.2f} s")
    if sums is not None:
        again = " --tf NODES | --density D" if mode != "xray" else " (X-ray sums: other --precision / --no-pack)"
        print(f"wrote {sums}: the view's encrypted ray sums, {human_bytes(st.size_of(sums, so))}; "
              f"finish again with: hevr recolour {sums} --out FRAME.hevr{again}")
    print(f"decrypt it with: hevr decrypt {out} --key KEY.json --out {st.png_name(out)}")
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
        raise UsageError(f"--mode {mode}: expected {'X-ray' if mode == 'xray' else 'emphasis/TF'} ray sums, got "
                         f"{args.sums} with the {saved.channel} channel's; render them again with --keep-sums "
                         f"and {'--mode xray' if mode == 'xray' else '--density or --tf'}")
    nodes = resolve_tf(nodes, saved.meta.value_range)
    cam = saved.camera
    print(f"sums:    {args.sums}, {saved.sampling} sampling, {wh(cam.width, cam.height)} px, key "
          f"{saved.meta.fingerprint[:16]}… (from {saved.store or 'an unnamed store'})")
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            img = recolour(saved, mode=mode, density=args.density, nodes=nodes, precision=args.precision,
                           pack=not args.no_pack, client=client, progress=show_progress(args), gradient=args.gradient)
    st.save_frame(img, out, force=args.force, so=so)
    print(f"wrote {out}: {img.n_ciphertexts} ciphertexts, {human_bytes(st.size_of(out, so))}, re-coloured in "
          f"{t.seconds:.2f} s (no map step)")
    return 0


# -- decrypt -------------------------------------------------------------------------------
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
    with Timer() as t:
        arr = img.decrypt(key)
    st.save_decrypted(arr, out, npy, args.window, force=args.force)
    rgb = ", rgb" if arr.ndim == 3 else ""
    print(f"decrypted {img.n_ciphertexts} ciphertexts in {t.seconds:.3f} s: {wh(arr.shape[1], arr.shape[0])} px"
          f"{rgb}, values {float(arr.min()):.6g} .. {float(arr.max()):.6g}")
    print(f"wrote {out}")
    if npy is not None:
        print(f"wrote {npy} (float64 values)")
    return 0


# -- upgrade-store ---------------------------------------------------------------------------
def cmd_upgrade_store(args: Any) -> int:
    check_store_path(Path(args.src).expanduser(), "OLD")
    dst = Path(args.dst).expanduser()
    if dst.exists():
        raise UsageError(f"NEW: {args.dst} already exists; choose a new path for the upgraded store")
    check_writable_dir(dst, "NEW")
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = upgrade_store(args.src, args.dst, client=client, progress=show_progress(args))
    print(f"wrote {args.dst}: format {ev.meta.version}, {ev.meta.n_bricks} bricks with digests, "
          f"{human_bytes(disk_usage(ev.path))}, in {t.seconds:.2f} s; {args.src} is unchanged")
    return 0


# -- info ----------------------------------------------------------------------------------
def cmd_info(args: Any) -> int:

    if st.is_url(args.path):  # a store, frame or sums file on object storage
        url, so = normalise(args.path), st.storage_options(args)
        kind = st.url_kind(url, so)
        return _info_store(url, so, args) if kind == "store" else {"frame": _info_image, "sums": _info_sums}[kind](url, so)
    path = st.local_path(args.path)
    if not path.exists():
        raise MissingFileError("PATH", "a key, store, frame or volume file", args.path)
    if path.is_dir():
        if (path / "zarr.json").exists():
            return _info_store(check_store_path(path, "PATH"), None, args)
        return _info_volume(path)
    check_regular(path, "PATH", "a key, store, frame or volume file")  # a FIFO would block the read below
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC))
    if head[:-1] == MAGIC[:-1] or path.suffix == ".hevr":  # any version: load_image names an unsupported one
        return _info_image(check_frame_path(path, "PATH"))
    if head == SUMS_MAGIC[:len(MAGIC)] or path.suffix == ".hevrsums":
        return _info_sums(path)
    if head.lstrip()[:1] == b"{":
        try:
            doc = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError):
            doc = None
        if isinstance(doc, dict) and (doc.get("format") == "hevr-key" or is_phe_dict(doc)):
            return _info_key(path, "python-paillier (pheutil)" if is_phe_dict(doc) else "hevr")
        if isinstance(doc, dict) and doc.get("zarr_format") is not None:
            return _info_store(check_store_path(path.parent, "PATH"), None, args)
        raise UsageError(f"PATH: expected a key, store, frame or volume file, got a JSON file that is not an "
                         f"hevr key ({args.path})")
    return _info_volume(path)


def _rows(rows: list[tuple[str, Any]]) -> None:
    w = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k + ':':<{w + 1}} {v}")


def _info_store(path: Path | str, so: dict | None = None, args: Any = None) -> int:
    """The store's public metadata and its quick check; with ``--verify`` every brick read back
    (:mod:`hevr.cli.verify`); a warning names temporaries left beside it. 1 if a check failed."""
    check_document(str(path), "")  # a FIFO in place of zarr.json: CorruptStoreError, never a blocked open
    try:
        group = zarr.open_group(zarr_store(str(path), so, read_only=True), mode="r")
        attrs = dict(group.attrs)
    except Exception as exc:
        raise StoreError(f"{path}: not a readable Zarr store ({type(exc).__name__})") from None
    meta = VolumeMetadata.from_dict(attrs.get("hevr"), where=str(path), accept_v1=True)
    failed = False
    try:
        open_volume(path, storage_options=so)
        check = "ok (metadata checksum and documents, completeness, chunk sizes; digests are checked on every read)"
    except StoreError as exc:
        check, failed = f"FAILED: {exc}", True
    verify, damaged = None, []
    if getattr(args, "verify", False):
        verify, damaged, bad = verify_store(str(path), so, args)
        failed = failed or bad
    bits = int(meta.n).bit_length()
    _rows([
        ("path", path),
        ("kind", "encrypted volume store"),
        ("format", f"{meta.format} version {meta.version}"),
        ("shape", f"{xyz(meta.shape)} voxels"),
        ("dtype", meta.dtype),
        ("spacing", xyz(tuple(meta.spacing)[::-1], sep=", ")),
        ("frame", f"RAS+, voxel (0, 0, 0) at {', '.join(f'{v:g}' for v in meta.patient['origin'])} mm"
         if meta.patient else "none recorded (axes as the input stored them)"),
        ("brick", f"{xyz(meta.brick)} voxels"),
        ("grid", f"{xyz(meta.grid)} = {meta.n_bricks} bricks"),
        ("channels", _channels(meta)),
        ("value range", meta.value_range),
        ("key", f"{bits}-bit public key" + (" (NOT secure: < 2048 bits)" if bits < SECURE_BITS else "")),
        ("fingerprint", meta.fingerprint),
        ("ciphertext", f"{meta.ciphertext_bytes} bytes each"),
        ("complete", meta.complete),
        *level_rows(meta),
        ("check", check),
        *([("verify", verify)] if verify else []),
        ("on disk", human_bytes(st.size_of(path, so))),
    ])
    for line in damaged:
        print(line)
    warn_leftovers(path)
    return 1 if failed else 0  # the table is printed either way; a failed check is not a success


def _info_image(path: Path | str, so: dict | None = None) -> int:

    img = load_image(path, storage_options=so)
    info = img.info or {}
    cam = info.get("camera") or {}
    bits = int(img.n).bit_length()
    packing = f"{img.per_pack} values per ciphertext (base 2^{img.pack_bits})" if img.per_pack > 1 else "unpacked"
    rows = [
        ("path", path),
        ("kind", "encrypted image (.hevr frame)"),
        ("shape", f"{wh(img.shape[1], img.shape[0])} px{', rgb' if len(img.shape) == 3 else ''}"),
        ("mode", f"{info.get('mode', '?')}, {info.get('sampling', '?')} sampling, step {info.get('step', '?')}"),
    ]
    if info.get("density") is not None:
        rows.append(("density", info["density"]))
    if info.get("nodes"):
        rows.append(("transfer fn", format_tf(info["nodes"])))
    if cam.get("kind") == "plane":  # a slice (hevr slice / hevr.render_slice)
        org = tuple(round(float(v), 3) for v in cam.get("origin", ()))
        rows.append(("plane", f"pixel (0, 0) at {xyz(org[::-1], sep=', ') if len(org) == 3 else '?'}, "
                              f"slab {cam.get('slab')} x {cam.get('slab_step')}"))
    elif cam:
        pos = tuple(round(float(v), 3) for v in cam.get("position", ()))
        where = xyz(pos[::-1], sep=", ") if len(pos) == 3 else "?"
        rows.append(("camera", f"position {where}, "
                               f"view angle {cam.get('view_angle')}, parallel {cam.get('parallel')}"))
    rows += [
        ("exponent", f"{img.exponent} (pixel = (m - offset) * 10^{img.exponent})"),
        ("packing", packing),
        ("bound", f"every value + offset in [0, {img.bound}] (checked at decryption)"),
        ("ciphertexts", f"{img.n_ciphertexts} in {len(img.ciphertexts)} tiles of {img.tile}x{img.tile} px"),
        ("checksum", "ok (SHA-256 over the whole file)"),
        ("key", f"{bits}-bit"),
        ("fingerprint", img.fingerprint),
        ("on disk", human_bytes(st.size_of(path, so))),
    ]
    _rows(rows)
    return 0


def _info_sums(path: Path | str, so: dict | None = None) -> int:
    saved = load_sums(path, storage_options=so)
    cam = saved.camera
    kept = sum(1 for v in saved.tiles.values() if v is not None)
    _rows([("path", path), ("kind", f"encrypted ray sums ({saved.channel} channel: "
                                    f"{'X-ray' if saved.channel == 'scalar' else 'emphasis / transfer function'})"),
           ("store", saved.store or "-"), ("volume", f"{xyz(saved.meta.shape)} voxels"),
           ("view", f"{wh(cam.width, cam.height)} px, {saved.sampling} sampling, step {saved.step:g}"),
           ("tiles", f"{kept} of {len(saved.tiles)} with sums (tile {saved.tile})"),
           ("key", f"{int(saved.meta.n).bit_length()}-bit, fingerprint {saved.meta.fingerprint}"),
           ("checks", "passed (checksum, header, ciphertext ranges)")])
    return 0


def _info_key(path: Path, fmt: str = "hevr") -> int:
    key = read_key(str(path))
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    rows = [("path", path), ("kind", "private key (holds the secret primes; not shown)" if private else "public key"),
            ("format", fmt),
            ("bits", f"{pub.bits}" + (" (NOT secure: < 2048 bits)" if pub.bits < SECURE_BITS else "")),
            ("fingerprint", pub.fingerprint)]
    mode = stat.S_IMODE(path.stat().st_mode)
    rows.append(("file mode", f"{mode:04o}"))
    _rows(rows)
    if private and mode & 0o077:
        warn_line(f"{path} is readable by other users (mode {mode:04o}); run: chmod 600 {path}")
    return 0


def _info_volume(path: Path) -> int:
    _rows(scan_rows(path))  # a DICOM folder: its series; a scan: frame, modality, default value range
    return 0


__all__ = ["cmd_keygen", "cmd_convert_key", "cmd_encrypt", "cmd_render", "cmd_recolour", "cmd_decrypt", "cmd_info",
           "cmd_upgrade_store", "open_for_mode", "resolve_mode"]
