"""Implementations of ``hevr keygen | encrypt | render | decrypt | info`` (see :mod:`hevr.cli.main`).

Each ``cmd_*`` takes the parsed argparse namespace, prints its report on stdout and
returns the exit code; errors are raised and turned into one line by :func:`hevr.cli.main.main`.
"""

from __future__ import annotations

import json
import logging
import stat
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..crypto.keys import SECURE_BITS, PrivateKey, generate_keypair
from ..errors import InsecureKeyWarning, MissingFileError, ParameterError, StoreError
from ..image import MAGIC, load_image, save_png
from ..paper import PAPER_DENSITIES, PAPER_TF1
from ..rendering.camera import Camera
from ..rendering.encrypted import render
from ..rendering.planner import check_render_size
from ..store.metadata import VolumeMetadata
from ..store.reader import open_volume
from ..store.upgrade import upgrade_store
from ..store.writer import encrypt_volume
from .util import (
    Timer,
    UsageError,
    check_writable_dir,
    dask_client,
    describe_client,
    disk_usage,
    format_tf,
    human_bytes,
    key_label,
    load_input,
    public_key_path,
    read_key,
    show_progress,
    warn_line,
)

log = logging.getLogger("hevr.cli.main")


# -- keygen --------------------------------------------------------------------------------
def cmd_keygen(args: Any) -> int:

    out = Path(args.out).expanduser()
    pub_out = public_key_path(out)
    check_writable_dir(out)
    for p in (out, pub_out):
        if p.exists() and not args.force:
            raise FileExistsError(17, "refusing to overwrite an existing key (pass --force to replace it)", str(p))
    if args.bits < SECURE_BITS:
        warn_line(f"a {args.bits}-bit key is NOT secure; use --bits {SECURE_BITS} or more for real data")
    with Timer() as t, warnings.catch_warnings():
        warnings.simplefilter("ignore", InsecureKeyWarning)
        pub, priv = generate_keypair(args.bits)
    priv.save(out, overwrite=args.force)
    pub.save(pub_out, overwrite=args.force)
    print(f"generated a {args.bits}-bit Paillier key pair in {t.seconds:.2f} s")
    print(f"  private key: {out}  (mode 0600 - keep it secret, it decrypts every image)")
    print(f"  public key:  {pub_out}  (give this one to whoever encrypts)")
    print(f"  fingerprint: {pub.fingerprint}")
    return 0


# -- encrypt -------------------------------------------------------------------------------
def cmd_encrypt(args: Any) -> int:

    if args.resume and args.overwrite:
        raise UsageError("--resume and --overwrite exclude each other")
    store = Path(args.out).expanduser().absolute()
    if store.exists() and not (args.resume or args.overwrite):
        raise FileExistsError(17, "already exists; pass --overwrite to replace it or --resume to finish an "
                                  "interrupted run", args.out)
    if not store.exists() and args.resume:
        raise MissingFileError("--out", "a store to --resume", args.out)
    check_writable_dir(store)
    key = read_key(args.key)
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    if private and args.scheduler and not args.trust_scheduler:
        raise UsageError(
            f"--key {args.key} is a private key and --scheduler is set: the owner-side fast path would send "
            "p and q to the cluster's workers; encrypt with the public key (.pub.json) or pass --trust-scheduler")
    vol, spacing, what = load_input(args.input, args.spacing)
    print(f"input:   {what}, spacing {tuple(float(s) for s in spacing)}")
    print(f"key:     {key_label(pub)}")
    print("path:    " + ("owner-side fast path (private key: p, q speed up encryption; "
                          "the store still holds only the public key)" if private
                          else "public-key path (g^m r^n mod n^2; slower than encrypting with the private key)"))
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = encrypt_volume(vol, store, key, spacing=spacing, brick=args.brick, scalar=not args.no_scalar,
                                vector_dims=args.vector_dims, value_range=args.value_range, digits=args.digits,
                                overwrite=args.overwrite, resume=args.resume,
                                progress=show_progress(args))
    n_ct = int(np.prod(ev.shape)) * ((1 if ev.has_scalar else 0) + (ev.vector_dims or 0))
    chans = _channels(ev.meta)
    print(f"wrote {args.out}: {ev.meta.n_bricks} bricks of {ev.brick}, channels {chans}, "
          f"{n_ct} ciphertexts, {human_bytes(disk_usage(ev.path))}, in {t.seconds:.2f} s "
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
    return " + ".join(ch) or "none"


# -- render --------------------------------------------------------------------------------
def resolve_mode(args: Any) -> str:
    """The render mode: explicit --mode, else inferred from --density / --tf, else xray."""
    mode = args.mode or ("tf" if args.tf is not None else "emphasize" if args.density is not None else "xray")
    if mode == "emphasize" and args.density is None:
        raise UsageError(f"--mode emphasize needs --density D (a normalised density in [0, 1], e.g. {PAPER_DENSITIES[1]})")
    if mode != "emphasize" and args.density is not None:
        raise UsageError(f"--density only applies to --mode emphasize, got --mode {mode}")
    if mode != "tf" and args.tf is not None:
        raise UsageError(f"--tf only applies to --mode tf, got --mode {mode}")
    return mode


def cmd_render(args: Any) -> int:


    mode = resolve_mode(args)
    nodes = (args.tf if args.tf is not None else list(PAPER_TF1)) if mode == "tf" else None
    out = Path(args.out).expanduser()
    check_writable_dir(out)
    store = Path(args.store).expanduser().absolute()
    if not store.exists():
        raise MissingFileError("--store", "an encrypted volume store (make one with 'hevr encrypt')", args.store)
    ev = open_volume(store)
    w, h = args.size
    cam = Camera.orbit(ev, azimuth=args.azimuth, elevation=args.elevation, width=w, height=h,
                       view_angle=args.view_angle, parallel=args.parallel)
    check_render_size(cam, ev.shape, ev.spacing, args.step)  # refuse before a cluster starts
    what = {"xray": "X-ray", "emphasize": f"emphasis of density {args.density}",
            "tf": f"transfer function {format_tf(nodes) if nodes else ''}"}[mode]
    print(f"store:   {args.store} {ev.shape[::-1]} (x, y, z), key {ev.meta.fingerprint[:16]}…")
    print(f"render:  {what}, {args.sampling} sampling, {w}x{h} px, azimuth {args.azimuth:g}, "
          f"elevation {args.elevation:g}, step {args.step:g}")
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            img = render(ev, cam, mode=mode, sampling=args.sampling, step=args.step, density=args.density,
                         nodes=nodes, precision=args.precision, pack=not args.no_pack,
                         progress=show_progress(args))
    img.save(out)
    print(f"wrote {out}: {img.n_ciphertexts} ciphertexts ({img.per_pack} values each), "
          f"{human_bytes(out.stat().st_size)}, rendered in {t.seconds:.2f} s")
    print(f"decrypt it with: hevr decrypt {out} --key KEY.json --out {out.with_suffix('.png')}")
    return 0


# -- decrypt -------------------------------------------------------------------------------
def cmd_decrypt(args: Any) -> int:

    key = read_key(args.key)
    if not isinstance(key, PrivateKey):
        raise ParameterError(f"--key {args.key} is a public key; decrypting needs the private key file")
    img = load_image(Path(args.frame).expanduser())
    with Timer() as t:
        arr = img.decrypt(key)
    out = Path(args.out).expanduser() if args.out else Path(args.frame).expanduser().with_suffix(".png")
    check_writable_dir(out)
    save_png(arr, out, window=args.window)
    print(f"decrypted {img.n_ciphertexts} ciphertexts in {t.seconds:.3f} s: shape {arr.shape}, "
          f"values {float(arr.min()):.6g} .. {float(arr.max()):.6g}")
    print(f"wrote {out}")
    if args.npy:
        npy = Path(args.npy).expanduser()
        check_writable_dir(npy)
        np.save(npy, arr)
        print(f"wrote {npy} (float64 values)")
    return 0


# -- upgrade-store ---------------------------------------------------------------------------
def cmd_upgrade_store(args: Any) -> int:
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            ev = upgrade_store(args.src, args.dst, client=client, progress=show_progress(args))
    print(f"wrote {args.dst}: format {ev.meta.version}, {ev.meta.n_bricks} bricks with digests, "
          f"{human_bytes(disk_usage(ev.path))}, in {t.seconds:.2f} s; {args.src} is unchanged")
    return 0


# -- info ----------------------------------------------------------------------------------
def cmd_info(args: Any) -> int:

    path = Path(args.path).expanduser()
    if not path.exists():
        raise MissingFileError("path", "a key, store or image file", path)
    if path.is_dir():
        if (path / "zarr.json").exists():
            return _info_store(path)
        return _info_volume(path)
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC))
    if head[:-1] == MAGIC[:-1]:  # any version: load_image names an unsupported one
        return _info_image(path)
    if head.lstrip()[:1] == b"{":
        try:
            doc = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError):
            doc = None
        if isinstance(doc, dict) and doc.get("format") == "hevr-key":
            return _info_key(path)
        if isinstance(doc, dict) and doc.get("zarr_format") is not None:
            return _info_store(path.parent)
        raise ParameterError(f"{path}: a JSON file but not an hevr key file")
    return _info_volume(path)


def _rows(rows: list[tuple[str, Any]]) -> None:
    w = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k + ':':<{w + 1}} {v}")


def _info_store(path: Path) -> int:


    try:
        group = zarr.open_group(str(path), mode="r")
        attrs = dict(group.attrs)
    except Exception as exc:
        raise StoreError(f"{path}: not a readable Zarr store ({type(exc).__name__})") from None
    meta = VolumeMetadata.from_dict(attrs.get("hevr"), where=str(path), accept_v1=True)
    failed = False
    try:
        open_volume(path)
        check = "ok (metadata checksum and documents, completeness, chunk sizes; digests are checked on every read)"
    except StoreError as exc:
        check, failed = f"FAILED: {exc}", True
    bits = int(meta.n).bit_length()
    _rows([
        ("path", path),
        ("kind", "encrypted volume store"),
        ("format", f"{meta.format} version {meta.version}"),
        ("shape", f"{meta.shape} (nz, ny, nx) = {meta.shape[2]}x{meta.shape[1]}x{meta.shape[0]} voxels"),
        ("dtype", meta.dtype),
        ("spacing", f"{meta.spacing} (sx, sy, sz)"),
        ("brick", f"{meta.brick} (bz, by, bx)"),
        ("grid", f"{meta.grid} = {meta.n_bricks} bricks"),
        ("channels", _channels(meta)),
        ("value range", meta.value_range),
        ("key", f"{bits}-bit public key" + (" (NOT secure: < 2048 bits)" if bits < SECURE_BITS else "")),
        ("fingerprint", meta.fingerprint),
        ("ciphertext", f"{meta.ciphertext_bytes} bytes each"),
        ("complete", meta.complete),
        ("check", check),
        ("on disk", human_bytes(disk_usage(path))),
    ])
    return 1 if failed else 0  # the table is printed either way; a failed check is not a success


def _info_image(path: Path) -> int:

    img = load_image(path)
    info = img.info or {}
    cam = info.get("camera") or {}
    bits = int(img.n).bit_length()
    packing = f"{img.per_pack} values per ciphertext (base 2^{img.pack_bits})" if img.per_pack > 1 else "unpacked"
    rows = [
        ("path", path),
        ("kind", "encrypted image (.hevr frame)"),
        ("shape", f"{tuple(img.shape)} (height, width{', rgb' if len(img.shape) == 3 else ''})"),
        ("mode", f"{info.get('mode', '?')}, {info.get('sampling', '?')} sampling, step {info.get('step', '?')}"),
    ]
    if info.get("density") is not None:
        rows.append(("density", info["density"]))
    if info.get("nodes"):
        rows.append(("transfer fn", format_tf(info["nodes"])))
    if cam:
        rows.append(("camera", f"position {tuple(round(x, 3) for x in cam.get('position', ()))}, "
                               f"view angle {cam.get('view_angle')}, parallel {cam.get('parallel')}"))
    rows += [
        ("exponent", f"{img.exponent} (pixel = (m - offset) * 10^{img.exponent})"),
        ("packing", packing),
        ("bound", f"every value + offset in [0, {img.bound}] (checked at decryption)"),
        ("ciphertexts", f"{img.n_ciphertexts} in {len(img.ciphertexts)} tiles of {img.tile}x{img.tile} px"),
        ("checksum", "ok (SHA-256 over the whole file)"),
        ("key", f"{bits}-bit"),
        ("fingerprint", img.fingerprint),
        ("on disk", human_bytes(path.stat().st_size)),
    ]
    _rows(rows)
    return 0


def _info_key(path: Path) -> int:
    key = read_key(str(path))
    private = isinstance(key, PrivateKey)
    pub = key.public_key if private else key
    rows = [("path", path), ("kind", "private key (holds the secret primes; not shown)" if private else "public key"),
            ("bits", f"{pub.bits}" + (" (NOT secure: < 2048 bits)" if pub.bits < SECURE_BITS else "")),
            ("fingerprint", pub.fingerprint)]
    mode = stat.S_IMODE(path.stat().st_mode)
    rows.append(("file mode", f"{mode:04o}"))
    _rows(rows)
    if private and mode & 0o077:
        warn_line(f"{path} is readable by other users (mode {mode:04o}); run: chmod 600 {path}")
    return 0


def _info_volume(path: Path) -> int:
    vol, spacing, what = load_input(str(path))
    _rows([
        ("path", path),
        ("kind", "plaintext volume"),
        ("shape", f"{vol.shape} (nz, ny, nx)"),
        ("dtype", vol.dtype),
        ("spacing", f"{spacing} (sx, sy, sz)"),
        ("values", f"{vol.min()} .. {vol.max()}"),
    ])
    return 0


__all__ = ["cmd_keygen", "cmd_encrypt", "cmd_render", "cmd_decrypt", "cmd_info", "resolve_mode"]
