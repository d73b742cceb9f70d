"""The key holder's frame commands: ``hevr recolour`` (kept ray sums finished again with another
colouring, no map step) and ``hevr decrypt`` (a frame file decrypted, verified and coloured here).

Each ``cmd_*`` takes the parsed argparse namespace, prints its report on stdout and returns the
exit code; errors are raised and turned into one line and an exit status by
:func:`hevr.cli.main.main` (:mod:`hevr.cli.exits`). What only the command line can check is checked
first, in its words (``UsageError("--out: …")``), before anything is computed. Every size printed
goes through :func:`~hevr.cli.util.xyz` / :func:`~hevr.cli.util.wh`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.files import check_regular
from ..image import load_image
from ..image.display import default_window
from ..image.orient import describe_layout
from ..image.proof import Expect
from ..paper import PAPER_TF1
from ..rendering.packed.colour import PackedColourImage
from ..rendering.packed.image import PackedImage
from ..rendering.pipeline.sums import load_sums, recolour
from ..rendering.pipeline.sums_file import MAGIC as SUMS_MAGIC
from ..store.paths import normalise
from . import storage as st
from .cluster import dask_client, describe_client
from .finish import report_finish
from .keys import read_key
from .packed import (
    check_packed_decrypt,
    packed_verified_line,
)
from .render import resolve_mode
from .render_options import format_tf
from .scan import resolve_tf
from .util import (
    Timer,
    UsageError,
    check_frame_path,
    check_new_file,
    human_bytes,
    plural,
    show_progress,
    wh,
)
from .verifying import recorded_proof, verified_line


# -- recolour ------------------------------------------------------------------------------
def _spelled(name: str) -> str:
    """A file's one spelling: a URL normalised, a local path absolute."""
    return normalise(name) if st.is_url(name) else str(st.local_path(name).absolute())


def cmd_recolour(args: Any) -> int:
    so = st.storage_options(args)
    path = normalise(args.sums) if st.is_url(args.sums) else st.local_path(args.sums)
    if _spelled(args.sums) == _spelled(args.out):
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
    colouring: tuple[str, float | None, Any] | None = None
    if isinstance(img, PackedImage):
        check_packed_decrypt(args)  # decrypted as it is: no colouring option
    else:
        colouring = decrypt_colouring(args, img)
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
        proof = recorded_proof(img)
        if proof.moved and need is None:
            print(
                f"NOT verified for {frame}: the key holder saved this frame as {proof.saved_as}; it proves only "
                f"that it is {proof.what} (name what you expect: --expect-store "
                f"{proof.store_id} --expect-view {proof.view_key})"
            )
        else:
            line = packed_verified_line(img) if packed else verified_line(img)
            print(f"{line} (the file carries the key holder's stamp)\nproof:   {proof.describe()}")
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


__all__ = ["cmd_recolour", "cmd_decrypt", "decrypt_colouring", "expected"]
