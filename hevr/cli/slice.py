"""``hevr slice``: an encrypted slice (axial, coronal, sagittal or oblique) of an encrypted volume.

The server-side twin of ``hevr render`` for multi-planar reformatting
(:func:`hevr.rendering.slices.render_slice`): never needs the secret key, writes a ``.hevr``
frame that ``hevr decrypt`` opens. Errors follow the CLI's rule (:mod:`hevr.cli.exits`): a bad
plane, size or slab is exit 2 with a message that starts with the option.

A packed store (``hevr encrypt --layout packed``) has no ``.hevr`` frame file for its slices yet:
with ``--key`` the slice is rendered and decrypted in this process and ``--out`` is the PNG (or
``.npy`` values) to write; planes perpendicular to the packing axis or containing its direction,
``--mode xray``, nearest or trilinear, any slab (:mod:`hevr.rendering.packed.planes`); a verifiable
store's slice is checked against its tags before the file is written (``--verify [ID]`` pins the store,
``--no-verify`` skips the check).
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from ..core.files import write_file
from ..errors import ParameterError
from ..image.encrypted import EncryptedImage
from ..image.orient import describe_layout
from ..paper import PAPER_TF1
from ..rendering.geometry.plane import Plane
from ..rendering.packed.plane_image import PackedSlice
from ..rendering.packed.planes import plane_kind
from ..rendering.planning.planner import check_render_size
from ..rendering.slices import render_slice
from .finish import report_finish
from .render import compute_context, open_for_mode, resolve_mode
from .render_options import format_tf
from .scan import resolve_tf
from .storage import output_file, save_decrypted, save_frame, size_of, storage_options
from .util import (
    Timer,
    UsageError,
    human_bytes,
    plural,
    show_progress,
    wh,
    xyz,
)
from .verifying import key_holder, verified_line, warn_unverified

__all__ = ["cmd_slice"]


def _at(ev: Any, axis: int, index: float) -> str:
    """Where layer ``index`` along world ``axis`` (0 x, 1 y, 2 z) lies: from voxel 0, and in the
    scan's patient frame when the input recorded its origin."""
    name = "xyz"[axis]
    offset = index * ev.spacing[axis]
    origin = getattr(ev, "patient_origin", None)
    if not origin:
        return f"{name} = {offset:g}"
    return f"{name} = {offset:g} from voxel 0, {name} = {origin[axis] + offset:g} mm in the scan's RAS+ frame"


def _plane(args: Any, ev: Any) -> tuple[Plane, str]:
    """The plane the options ask for, and its description."""
    w, h = args.size if args.size is not None else (None, None)
    kw = dict(width=w, height=h, pixel_spacing=args.pixel_spacing, slab=args.slab, slab_step=args.slab_step)
    if args.axial is not None:
        return Plane.axial(ev, args.axial, **kw), f"axial, k = {args.axial:g} ({_at(ev, 2, args.axial)})"
    if args.coronal is not None:
        return Plane.coronal(ev, args.coronal, **kw), f"coronal, j = {args.coronal:g} ({_at(ev, 1, args.coronal)})"
    if args.sagittal is not None:
        return Plane.sagittal(ev, args.sagittal, **kw), f"sagittal, i = {args.sagittal:g} ({_at(ev, 0, args.sagittal)})"
    centre, normal = args.oblique
    plane = Plane.oblique(ev, centre, normal, **kw)
    u, v, _ = plane.basis()
    c = (
        plane.origin
        + (plane.width - 1) / 2 * plane.pixel_spacing[0] * u
        + (plane.height - 1) / 2 * plane.pixel_spacing[1] * v
    )
    where = xyz(tuple(round(float(x), 3) for x in c)[::-1], sep=", ")
    n = tuple(round(float(x), 4) for x in plane.normal)
    return plane, f"oblique through {where}, normal {xyz(n[::-1], sep=', ')}"


def cmd_slice(args: Any) -> int:
    mode = resolve_mode(args)
    nodes = (args.tf if args.tf is not None else list(PAPER_TF1)) if mode == "tf" else None
    if args.slab_step is not None and args.slab == 1:
        raise UsageError(f"--slab-step: only applies to a thick slab (--slab N > 1), got --slab {args.slab}")
    so = storage_options(args)
    out = output_file(args.out, force=args.force, so=so)
    # a packed store (here or on hevr serve): rendered, then decrypted in this process (_packed_slice)
    ev = open_for_mode(args.store, mode, "slice", so, args, packed=True)
    if ev.packing is not None:
        return _packed_slice(args, ev, mode, out)
    nodes = resolve_tf(nodes, ev.value_range)  # a --tf preset: in the store's value range
    verify = key_holder(args, ev)
    plane, where = _plane(args, ev)
    finish = {"finish": args.finish}
    check_render_size(plane, ev.shape, ev.spacing, plane.slab_step)  # refuse before a cluster starts
    what = {
        "xray": "value",
        "emphasize": f"emphasis of density {args.density}",
        "tf": f"transfer function {format_tf(nodes) if nodes else ''}",
    }[mode]
    du, dv = plane.pixel_spacing
    spacing = f"{du:g}" if du == dv else f"{du:g} × {dv:g}"
    slab = f", slab of {plane.slab} planes {plane.slab_step:g} apart (their mean)" if plane.slab > 1 else ""
    print(f"store:   {args.store}, {xyz(ev.shape)} voxels, key {ev.meta.fingerprint[:16]}…")
    print(
        f"slice:   {where}, {wh(plane.width, plane.height)} px of {spacing} world units, {what}, "
        f"{args.sampling} sampling{slab}"
    )
    print(f"shown:   {describe_layout(plane)} (in hevr decrypt's PNG)")
    with compute_context(args, ev) as client:
        with Timer() as t:
            img = render_slice(
                ev,
                plane,
                mode=mode,
                sampling=args.sampling,
                density=args.density,
                nodes=nodes,
                precision=args.precision,
                pack=not args.no_pack,
                client=client,
                progress=show_progress(args),
                gradient=args.gradient,
                verify=verify,
                **finish,
            )
    assert isinstance(img, EncryptedImage)  # a per-voxel store's slice, computed (here or on hevr serve)
    save_frame(img, out, force=args.force, so=so, private_key=args.private_key)
    line = verified_line(img)
    if line:
        print(f"{line} (stamped with the key holder's MAC)")
    warn_unverified(args, ev, img)
    inside = 0 if img.hits is None else int(img.hits.sum())
    print(
        f"wrote {out}: {plural(img.n_ciphertexts, 'ciphertext')} ({img.per_pack} values each), "
        f"{human_bytes(size_of(out, so))}, {inside:,} of {plane.width * plane.height:,} pixels inside the volume, "
        f"rendered in {t.seconds:.2f} s"
    )
    report_finish(img, out, mode, args.density, nodes)
    return 0


def _packed_slice(args: Any, ev: Any, mode: str, out: Any) -> int:
    """``hevr slice`` on a packed store: checked before any work, rendered, decrypted with ``--key``
    in this process, written as ``--out`` (``.png``, or ``.npy`` for the float64 values)."""
    option = next(f"--{o}" for o in ("axial", "coronal", "sagittal", "oblique") if getattr(args, o) is not None)
    store = args.store
    if mode != "xray":
        raise UsageError(
            f"--mode {mode}: expected xray on the packed store {store} (it holds the scalar channel "
            "only); encrypt a per-voxel store (--layout voxel --vector-dims 4) for it"
        )
    for flag, given in (
        ("--gradient", args.gradient),
        ("--no-pack", args.no_pack),
        ("--precision", args.precision is not None),
        ("--finish server", args.finish != "client"),
    ):
        if given:
            raise UsageError(
                f"{flag}: does not apply to a slice of the packed store {store} (decrypted in this "
                "process from its X-ray values)"
            )
    if not args.key:
        raise UsageError(
            f"--key: expected the private key KEY.json for a slice of the packed store {store}: packed "
            "slices have no .hevr frame file yet, so the slice is decrypted in this process and --out "
            "is the PNG (or .npy) to write"
        )
    suffix = str(out).lower().rsplit(".", 1)[-1]
    if suffix not in ("png", "npy"):
        raise UsageError(
            f"--out: expected a .png or .npy file for a slice of the packed store {store} (decrypted "
            f"here with --key; no .hevr frame file for packed slices yet), got {args.out}"
        )
    verify = key_holder(args, ev)  # reads --key, which must be the store's; --verify [ID] / --no-verify
    plane, where = _plane(args, ev)
    try:
        kind = plane_kind(plane, ev.packing.axis)
    except ParameterError as exc:
        raise UsageError(f"{option}: {str(exc).split(': ', 1)[1]}") from None
    check_render_size(plane, ev.shape, ev.spacing, plane.slab_step)
    slab = f", slab of {plane.slab} planes {plane.slab_step:g} apart (their mean)" if plane.slab > 1 else ""
    axis = "zyx"[ev.packing.axis]
    print(
        f"store:   {store}, {xyz(ev.shape)} voxels, packed ({ev.packing.slots} voxels per ciphertext along {axis}), "
        f"key {ev.meta.fingerprint[:16]}…"
    )
    print(
        f"slice:   {where}, {wh(plane.width, plane.height)} px, value, {args.sampling} sampling{slab}; "
        f"{'perpendicular to' if kind == 'perpendicular' else 'containing'} the packing axis {axis}"
    )
    with compute_context(args, ev) as client:
        with Timer() as t:
            img = render_slice(
                ev, plane, sampling=args.sampling, client=client, progress=show_progress(args), verify=verify
            )
    assert isinstance(img, PackedSlice)  # a packed store's slice (here or on hevr serve)
    arr = img.decrypt(args.private_key)
    if suffix == "npy":
        buf = io.BytesIO()
        np.save(buf, arr)
        write_file(out, [buf.getbuffer()], overwrite=args.force, name="--out", doing="writing the pixel values")
    else:
        save_decrypted(arr, out, None, None, force=args.force, plane=plane, hits=img.hits)
    if img.verified:
        print(f"verified: the slice's values are the store {ev.meta.store_id}'s (checked against its tags)")
    else:
        warn_unverified(args, ev, img)
    print(
        f"wrote {out}: decrypted here from {plural(img.n_ciphertexts, 'ciphertext')} ({img.plan.n_footprints:,} "
        f"footprints, up to {ev.packing.slots} layers each), {int(img.hits.sum()):,} of "
        f"{plane.width * plane.height:,} pixels inside the volume, rendered in {t.seconds:.2f} s"
    )
    return 0
