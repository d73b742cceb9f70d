"""``hevr slice``: an encrypted slice (axial, coronal, sagittal or oblique) of an encrypted volume.

The server-side twin of ``hevr render`` for multi-planar reformatting
(:func:`hevr.rendering.slices.render_slice`): never needs the secret key, writes a ``.hevr``
frame that ``hevr decrypt`` opens. Errors follow the CLI's rule (:mod:`hevr.cli.exits`): a bad
plane, size or slab is exit 2 with a message that starts with the option.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from ..paper import PAPER_TF1
from ..rendering.plane import Plane
from ..rendering.planner import check_render_size
from ..rendering.slices import render_slice
from .commands import open_for_mode, resolve_mode
from .finish import report_finish
from .scan import resolve_tf
from .storage import output_file, save_frame, size_of, storage_options
from .util import (
    Timer,
    UsageError,
    dask_client,
    describe_client,
    format_tf,
    human_bytes,
    show_progress,
    wh,
    xyz,
)

__all__ = ["SLICE_EPILOG", "cmd_slice", "oblique_type"]

SLICE_EPILOG = """\
examples:
  hevr slice vol.zarr --out axial.hevr --axial 50                 # layer 50 as it is stored (x across, y down)
  hevr slice vol.zarr --out cor.hevr --coronal 40 --size 150x150 --sampling trilinear
  hevr slice vol.zarr --out obl.hevr --oblique 50,50,50:1,1,0 --pixel-spacing 0.5 --size 200x200
  hevr slice vol.zarr --out slab.hevr --axial 50 --slab 5 --slab-step 1   # mean of 5 planes (no MIP: see README)
  hevr slice vol.zarr --out tf.hevr --sagittal 30 --tf '0.279:blue,0.797:red'

Rows and columns follow the array: --axial K is vol[K] (x across, y down), --coronal J is
vol[:, J, :] (x across, z down), --sagittal I is vol[:, :, I] (y across, z down). Without
--size or --pixel-spacing the image is the volume's own grid; --size alone fits the volume
into it with square pixels; --oblique CX,CY,CZ:NX,NY,NZ centres the image on the world point C
(':NX,NY,NZ': the volume's centre) with normal N. Pixels outside the volume are 0.
--mode defaults to emphasize with --density, tf with --tf, else xray; with --finish client (the
default) the density or transfer function is applied at 'hevr decrypt' (the command is printed).
"""


def oblique_type(text: str) -> tuple[tuple[float, float, float] | None, tuple[float, float, float]]:
    """``--oblique CX,CY,CZ:NX,NY,NZ`` (or ``:NX,NY,NZ`` for the volume's centre) -> (centre, normal).

    >>> oblique_type("1,2,3:0,0,1"), oblique_type(":1,1,0")
    (((1.0, 2.0, 3.0), (0.0, 0.0, 1.0)), (None, (1.0, 1.0, 0.0)))
    """
    expected = "CX,CY,CZ:NX,NY,NZ (a world point and a non-zero normal; ':NX,NY,NZ' for the volume's centre)"
    centre_text, sep, normal_text = text.partition(":")
    try:
        centre = tuple(float(p) for p in centre_text.split(",")) if centre_text.strip() else None
        normal = tuple(float(p) for p in normal_text.split(","))
    except ValueError:
        centre, normal = (), ()
    ok = (sep and len(normal) == 3 and (centre is None or len(centre) == 3)
          and all(math.isfinite(v) for v in (centre or ()) + normal) and any(v != 0 for v in normal))
    if not ok:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return centre, normal  # type: ignore[return-value]


def _plane(args: Any, ev: Any) -> tuple[Plane, str]:
    """The plane the options ask for, and its description."""
    w, h = args.size if args.size is not None else (None, None)
    kw = dict(width=w, height=h, pixel_spacing=args.pixel_spacing, slab=args.slab, slab_step=args.slab_step)
    if args.axial is not None:
        return Plane.axial(ev, args.axial, **kw), f"axial, k = {args.axial:g} (z = {args.axial * ev.spacing[2]:g})"
    if args.coronal is not None:
        return Plane.coronal(ev, args.coronal, **kw), f"coronal, j = {args.coronal:g} (y = {args.coronal * ev.spacing[1]:g})"
    if args.sagittal is not None:
        return Plane.sagittal(ev, args.sagittal, **kw), f"sagittal, i = {args.sagittal:g} (x = {args.sagittal * ev.spacing[0]:g})"
    centre, normal = args.oblique
    plane = Plane.oblique(ev, centre, normal, **kw)
    u, v, _ = plane.basis()
    c = (plane.origin + (plane.width - 1) / 2 * plane.pixel_spacing[0] * u
         + (plane.height - 1) / 2 * plane.pixel_spacing[1] * v)
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
    ev = open_for_mode(args.store, mode, "slice", so)
    nodes = resolve_tf(nodes, ev.value_range)  # a --tf preset: in the store's value range
    plane, where = _plane(args, ev)
    finish = {"finish": args.finish}
    check_render_size(plane, ev.shape, ev.spacing, plane.slab_step)  # refuse before a cluster starts
    what = {"xray": "value", "emphasize": f"emphasis of density {args.density}",
            "tf": f"transfer function {format_tf(nodes) if nodes else ''}"}[mode]
    du, dv = plane.pixel_spacing
    spacing = f"{du:g}" if du == dv else f"{du:g} × {dv:g}"
    slab = f", slab of {plane.slab} planes {plane.slab_step:g} apart (their mean)" if plane.slab > 1 else ""
    print(f"store:   {args.store}, {xyz(ev.shape)} voxels, key {ev.meta.fingerprint[:16]}…")
    print(f"slice:   {where}, {wh(plane.width, plane.height)} px of {spacing} world units, {what}, "
          f"{args.sampling} sampling{slab}")
    with dask_client(args.scheduler, args.workers) as client:
        print(f"compute: {describe_client(client)}")
        with Timer() as t:
            img = render_slice(ev, plane, mode=mode, sampling=args.sampling, density=args.density, nodes=nodes,
                               precision=args.precision, pack=not args.no_pack, client=client,
                               progress=show_progress(args), gradient=args.gradient, **finish)
    save_frame(img, out, force=args.force, so=so)
    inside = int(img.hits.sum())
    print(f"wrote {out}: {img.n_ciphertexts} ciphertexts ({img.per_pack} values each), "
          f"{human_bytes(size_of(out, so))}, {inside} of {plane.width * plane.height} pixels inside the volume, "
          f"rendered in {t.seconds:.2f} s")
    report_finish(img, out, mode, args.density, nodes)
    return 0
