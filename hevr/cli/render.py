"""``hevr render``: an encrypted frame of a store, rendered locally on Dask or by a ``hevr serve``,
and what the render commands share: the mode from ``--mode / --density / --tf``, the store opened
and checked for the channel that mode reads, the compute context (:mod:`hevr.cli.slice` and
:mod:`hevr.cli.decrypt` use them).

Each ``cmd_*`` takes the parsed argparse namespace, prints its report on stdout and returns the
exit code; errors are raised and turned into one line and an exit status by
:func:`hevr.cli.main.main` (:mod:`hevr.cli.exits`). What only the command line can check is checked
first, in its words (``UsageError("--out: …")``), before anything is computed. Every size printed
goes through :func:`~hevr.cli.util.xyz` / :func:`~hevr.cli.util.wh`.
"""

from __future__ import annotations

import contextlib
from typing import Any

from ..image.encrypted import EncryptedImage
from ..paper import PAPER_DENSITIES, PAPER_TF1
from ..rendering.encrypted import render
from ..rendering.geometry.camera import Camera
from ..rendering.planning.planner import check_render_size
from . import storage as st
from .cluster import dask_client, describe_client
from .finish import colour_options, report_finish
from .packed import (
    check_packed_render,
    packed_done,
    packed_start,
)
from .remote import open_remote
from .render_options import format_tf
from .scan import resolve_tf
from .util import (
    Timer,
    UsageError,
    human_bytes,
    plural,
    show_progress,
    warn_line,
    wh,
    xyz,
)
from .verifying import key_holder, verified_line, warn_unverified


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
    assert isinstance(img, EncryptedImage)  # a per-voxel store's frame, computed (here or on hevr serve)
    st.save_frame(img, out, force=args.force, so=so, private_key=args.private_key)
    line = verified_line(img)
    if line:
        print(f"{line} (stamped with the key holder's MAC)")
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


__all__ = ["cmd_render", "compute_context", "open_for_mode", "resolve_mode"]
