"""What ``hevr info PATH [--verify]`` prints about a store, frame, sums file, key or volume file,
in public facts only (never a secret), and its checks (see :mod:`hevr.cli.main`).

:func:`describe` tells what PATH is and describes it. ``hevr info`` starts in
:mod:`hevr.cli.info`, which describes a local key file without importing this module (Zarr,
Dask, the readers) and hands everything else to :func:`describe`.

A store gets its quick check (metadata checksum, documents, completeness, chunk sizes) and,
with ``--verify``, every brick read back (:mod:`hevr.cli.verify`); temporaries left beside it
by an interrupted write are named on stderr. A FIFO or device named as PATH is refused before
it is opened (it would block). Returns 1 when a check failed; the table is printed either way.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import zarr

from ..core.files import check_regular
from ..crypto.keys import SECURE_BITS
from ..crypto.phe_keys import is_phe_dict
from ..errors import MissingFileError, StoreError
from ..image.files import load_image
from ..image.header import MAGIC
from ..rendering.packed.colour import PackedColourImage
from ..rendering.packed.image import PackedImage
from ..rendering.pipeline.sums import load_sums
from ..rendering.pipeline.sums_file import MAGIC as SUMS_MAGIC
from ..store.layout import check_document
from ..store.metadata import VolumeMetadata
from ..store.paths import normalise, zarr_store
from ..store.reader import open_volume
from . import storage as st
from .exits import cli_phrases
from .keys import info_key
from .packed import packed_info_rows
from .pyramid import level_rows
from .render_options import format_tf
from .scan import scan_rows
from .util import (
    UsageError,
    check_frame_path,
    check_store_path,
    human_bytes,
    plural,
    print_rows,
    wh,
    xyz,
)
from .verify import verify_store, warn_leftovers
from .verifying import verified_row

__all__ = ["channels", "describe"]


def channels(meta: Any) -> str:
    """The stored channels in words, e.g. ``scalar (exact) + vector[4] (3 digits)``."""
    ch = []
    if meta.scalar is not None:
        ch.append("scalar" + (f" ({meta.scalar.digits} digits)" if meta.scalar.digits is not None else " (exact)"))
    if meta.vector is not None:
        ch.append(f"vector[{meta.vector.dims}] ({meta.vector.digits} digits)")
    if getattr(meta, "gradient", None) is not None:
        ch.append(f"gradient[{meta.gradient.dims}] ({meta.gradient.digits} digits)")
    tags = f", each with its tag channel (verifiable, store id {meta.store_id})" if getattr(meta, "tags", False) else ""
    return (" + ".join(ch) or "none") + tags


def describe(args: Any) -> int:
    """Print what PATH holds (module docstring); 1 if a check failed."""
    if st.is_url(args.path):  # a store, frame or sums file on object storage
        url, so = normalise(args.path), st.storage_options(args)
        kind = st.url_kind(url, so)
        return (
            _info_store(url, so, args) if kind == "store" else {"frame": _info_image, "sums": _info_sums}[kind](url, so)
        )
    path = st.local_path(args.path)
    if str(args.path).startswith("sample:") and not path.exists():  # a real scan a package ships
        return _info_volume(path, args, spec=str(args.path))
    if not path.exists():
        raise MissingFileError("PATH", "a key, store, frame or volume file", args.path)
    if path.is_dir():
        if (path / "zarr.json").exists():
            return _info_store(check_store_path(path, "PATH"), None, args)
        return _info_volume(path, args)
    check_regular(path, "PATH", "a key, store, frame or volume file")  # a FIFO would block the read below
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC))
    if head[:-1] == MAGIC[:-1] or path.suffix == ".hevr":  # any version: load_image names an unsupported one
        return _info_image(check_frame_path(path, "PATH"))
    if head == SUMS_MAGIC[: len(MAGIC)] or path.suffix == ".hevrsums":
        return _info_sums(path)
    if head.lstrip()[:1] == b"{":
        try:
            doc = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError):
            doc = None
        if isinstance(doc, dict) and (doc.get("format") == "hevr-key" or is_phe_dict(doc)):
            return info_key(path, "python-paillier (pheutil)" if is_phe_dict(doc) else "hevr")
        if isinstance(doc, dict) and doc.get("zarr_format") is not None:
            return _info_store(check_store_path(path.parent, "PATH"), None, args)
        raise UsageError(
            f"PATH: expected a key, store, frame or volume file, got a JSON file that is not an hevr key ({args.path})"
        )
    return _info_volume(path, args)


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
        check, failed = f"FAILED: {cli_phrases(str(exc), 'info')}", True
    verify: str | None = None
    damaged: list[str] = []
    if getattr(args, "verify", False):
        verify, damaged, bad = verify_store(str(path), so, args)
        failed = failed or bad
    bits = int(meta.n).bit_length()
    print_rows(
        [
            ("path", path),
            ("kind", "encrypted volume store"),
            ("format", f"{meta.format} version {meta.version}"),
            ("shape", f"{xyz(meta.shape)} voxels"),
            ("dtype", meta.dtype),
            ("spacing", xyz(tuple(meta.spacing)[::-1], sep=", ")),
            (
                "frame",
                f"RAS+, voxel (0, 0, 0) at {', '.join(f'{v:g}' for v in meta.patient['origin'])} mm"
                if meta.patient
                else "none recorded (axes as the input stored them)",
            ),
            ("brick", f"{xyz(meta.brick)} voxels"),
            ("grid", f"{xyz(meta.grid)} = {plural(meta.n_bricks, 'brick')}"),
            ("channels", channels(meta)),
            (
                "layout",
                "one ciphertext per voxel"
                if meta.packing is None
                else f"packed: {meta.packing.slots} voxels per ciphertext along {'zyx'[meta.packing.axis]} "
                f"({meta.packing.slot_bits}-bit slots, {meta.packing.weight_bits}-bit in-slice weights)",
            ),
            ("value range", meta.value_range),
            ("key", f"{bits}-bit public key" + (" (NOT secure: < 2048 bits)" if bits < SECURE_BITS else "")),
            ("fingerprint", meta.fingerprint),
            ("ciphertext", f"{meta.ciphertext_bytes} bytes each"),
            ("complete", meta.complete),
            *level_rows(meta),
            ("check", check),
            *([("verify", verify)] if verify else []),
            ("on disk", human_bytes(st.size_of(path, so))),
        ]
    )
    for line in damaged:
        print(line)
    warn_leftovers(path)
    return 1 if failed else 0  # the table is printed either way; a failed check is not a success


def _info_image(path: Path | str, so: dict | None = None) -> int:
    img = load_image(path, storage_options=so)
    if isinstance(img, (PackedImage, PackedColourImage)):  # a packed store's frame (hevr.rendering.packed.files)
        print_rows([("path", path), *packed_info_rows(img), ("on disk", human_bytes(st.size_of(path, so)))])
        return 0
    info = img.info or {}
    cam = info.get("camera") or {}
    bits = int(img.n).bit_length()
    packing = f"{img.per_pack} values per ciphertext (base 2^{img.pack_bits})" if img.per_pack > 1 else "unpacked"
    client = img.finish == "client"
    view = f"{info.get('sampling', '?')} sampling, step {info.get('step', '?')}"
    rows = [
        ("path", path),
        ("kind", "encrypted image (.hevr frame)"),
        ("shape", f"{wh(img.shape[1], img.shape[0])} px{', rgb' if len(img.shape) == 3 and not client else ''}"),
    ]
    if client:
        colour = (
            "an X-ray: decrypted as it is"
            if img.channel == "scalar"
            else "coloured at decryption: hevr decrypt --tf NODES | --density D (the frame holds neither)"
        )
        rows += [
            ("finish", f"client: the ray sums of the {img.channel} channel, {colour}"),
            (
                "components",
                f"{img.values_per_pixel} per pixel the ray hits (each sum / its samples = the "
                f"mean of a stored component)",
            ),
            ("rendered", f"{img.channel} channel, {view}"),
        ]
        if img.samples is not None and img.hits is not None and img.hits.any():
            rows.append(
                ("samples", f"{int(img.samples[img.hits].min())} .. {int(img.samples.max())} per ray (public geometry)")
            )
    else:
        rows += [
            ("finish", "server: finished pixels (the paper's way: colouring applied on the cluster)"),
            ("components", f"{img.values_per_pixel} per pixel the ray hits"),
            ("mode", f"{info.get('mode', '?')}, {view}"),
        ]
    if info.get("density") is not None:
        rows.append(("density", info["density"]))
    if info.get("nodes"):
        rows.append(("transfer fn", format_tf(info["nodes"])))
    if cam.get("kind") == "plane":  # a slice (hevr slice / hevr.render_slice)
        org = tuple(round(float(v), 3) for v in cam.get("origin", ()))
        rows.append(
            (
                "plane",
                f"pixel (0, 0) at {xyz(org[::-1], sep=', ') if len(org) == 3 else '?'}, "
                f"slab {cam.get('slab')} x {cam.get('slab_step')}",
            )
        )
    elif cam:
        pos = tuple(round(float(v), 3) for v in cam.get("position", ()))
        where = xyz(pos[::-1], sep=", ") if len(pos) == 3 else "?"
        rows.append(("camera", f"position {where}, view angle {cam.get('view_angle')}, parallel {cam.get('parallel')}"))
    rows += [
        ("exponent", f"{img.exponent} ({'ray sum' if client else 'pixel'} = (m - offset) * 10^{img.exponent})"),
        ("packing", packing),
        ("bound", f"every value + offset in [0, {img.bound}] (checked at decryption)"),
        ("ciphertexts", f"{img.n_ciphertexts} in {plural(len(img.ciphertexts), 'tile')} of {img.tile}x{img.tile} px"),
        ("verified", verified_row(img)),
        ("checksum", "ok (SHA-256 over the whole file)"),
        ("key", f"{bits}-bit"),
        ("fingerprint", img.fingerprint),
        ("on disk", human_bytes(st.size_of(path, so))),
    ]
    print_rows(rows)
    return 0


def _info_sums(path: Path | str, so: dict | None = None) -> int:
    saved = load_sums(path, storage_options=so)
    cam = saved.camera
    kept = sum(1 for v in saved.tiles.values() if v is not None)
    print_rows(
        [
            ("path", path),
            (
                "kind",
                f"encrypted ray sums ({saved.channel} channel: "
                f"{'X-ray' if saved.channel == 'scalar' else 'emphasis / transfer function'})",
            ),
            ("store", saved.store or "-"),
            ("volume", f"{xyz(saved.meta.shape)} voxels"),
            ("view", f"{wh(cam.width, cam.height)} px, {saved.sampling} sampling, step {saved.step:g}"),
            ("tiles", f"{kept} of {len(saved.tiles)} with sums (tile {saved.tile})"),
            ("key", f"{int(saved.meta.n).bit_length()}-bit, fingerprint {saved.meta.fingerprint}"),
            ("checks", "passed (checksum, header, ciphertext ranges)"),
        ]
    )
    return 0


def _info_volume(path: Path, args: Any, spec: str | None = None) -> int:
    read = {k: getattr(args, k, None) for k in ("series", "volume", "allow_uneven", "oblique")}
    print_rows(
        scan_rows(path, spec=spec, **read)
    )  # a DICOM folder: its series; a scan: frame, modality, default value range
    return 0
