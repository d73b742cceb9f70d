"""Packed stores and their frames on the command line: what ``hevr render`` may ask of a packed
store, the camera it renders, and the lines ``render``, ``decrypt`` and ``info`` print about a
packed frame (:class:`hevr.PackedImage`, its file: :mod:`hevr.rendering.packed.files`).

A packed store (``hevr encrypt --layout packed``) serves X-ray frames of parallel cameras whose
principal axis is not its packing axis, one sample per slice, finished on the client. So ``hevr
render`` on one renders a parallel camera whatever ``--parallel`` says; with no ``--view`` and no
``--azimuth`` it takes an anatomical view the store serves (:func:`default_packed_view`); every
option it cannot serve is refused before any work, with one line naming the option (exit 2).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ..errors import ParameterError
from ..rendering.geometry.camera import Camera
from ..rendering.packed.shear import ShearGeometry
from ..rendering.planning.planner import check_render_size
from .storage import png_name
from .util import UsageError, plural, warn_line, wh, xyz
from .verifying import recorded_proof, verified_row

__all__ = [
    "check_packed_decrypt",
    "check_packed_render",
    "default_packed_view",
    "packed_camera",
    "packed_done",
    "packed_encrypt_lines",
    "packed_info_rows",
    "packed_start",
    "packed_verified_line",
]

# the array axis each anatomical view looks along
_VIEW_AXES = {"anterior": 1, "posterior": 1, "left": 2, "right": 2, "superior": 0, "inferior": 0}
_PER_VOXEL = "render a per-voxel store for it (hevr encrypt without --layout packed)"


def default_packed_view(ev: Any) -> str:
    """The anatomical view ``hevr render`` takes on a packed store when none is given: ``anterior``
    (looking along y), or ``left`` (along x) for a store packed along y, whose anterior view would
    look along its packing axis.

    >>> from types import SimpleNamespace as NS
    >>> default_packed_view(NS(packing=NS(axis=0))), default_packed_view(NS(packing=NS(axis=1)))
    ('anterior', 'left')
    """
    return "left" if int(ev.packing.axis) == 1 else "anterior"


def check_packed_render(args: Any, mode: str, ev: Any = None) -> None:
    """Refuse (:class:`UsageError`, exit 2) an option of ``hevr render`` that a packed store cannot
    serve, naming it; before the store is read further or a cluster starts. Emphasis and transfer
    functions need the vector channel (``--gradient``: the gradient channel) in the store."""

    def has(channel: str) -> bool:
        return ev is not None and getattr(ev.meta, channel) is not None

    if mode != "xray" and not has("vector"):
        opt = f"--mode {mode}" if args.mode else "--tf" if args.tf is not None else "--density"
        raise UsageError(
            f"{opt}: expected an X-ray of this packed store, which has no vector channel (encrypt it "
            f"with --layout packed --vector-dims 4 for emphasis and transfer functions); or "
            f"{_PER_VOXEL} with --vector-dims 4"
        )
    refused = [
        (
            args.step is not None and args.step != 1.0,
            "--step",
            "a packed store samples once per slice of the view's principal axis (step 1)",
        ),
        (
            args.finish == "server",
            "--finish server",
            "a packed frame is finished on the client (the key holder decodes the slots and warps the image)",
        ),
        (
            args.view_angle is not None,
            "--view-angle",
            "a packed store renders parallel cameras only (the view angle is a perspective camera's)",
        ),
        (args.keep_sums is not None, "--keep-sums", "a packed frame's ray sums are not saved apart from it"),
        (args.no_pack, "--no-pack", "a packed frame's values are packed by the store's slots"),
        (
            args.gradient and (mode == "xray" or not has("gradient")),
            "--gradient",
            "gradient modulation needs --mode emphasize/tf and a store encrypted with --gradient",
        ),
    ]
    for bad, opt, why in refused:
        if bad:
            raise UsageError(f"{opt}: not for a packed store ({why}); leave it out, or {_PER_VOXEL}")


def packed_camera(args: Any, ev: Any) -> tuple[Camera, str]:
    """The parallel camera of ``hevr render`` on the packed store ``ev`` and the view's name (the
    default view when neither ``--view`` nor ``--azimuth`` is given); a view the store cannot serve
    (along its packing axis) is a :class:`UsageError` naming the options that set it."""
    view = args.view or (default_packed_view(ev) if args.azimuth is None else None)
    w, h = args.size
    cam = Camera.orbit(
        ev, azimuth=args.azimuth or 0.0, elevation=args.elevation or 0.0, width=w, height=h, parallel=True, view=view
    )
    try:
        ShearGeometry.of(cam, ev.shape, ev.spacing, axis=ev.packing.axis)
    except ParameterError:
        opts = (
            "/".join(
                o
                for o, v in (("--view", args.view), ("--azimuth", args.azimuth), ("--elevation", args.elevation))
                if v is not None
            )
            or "--view"
        )
        a = int(ev.packing.axis)
        around = ", ".join(v for v, ax in _VIEW_AXES.items() if ax != a)
        raise UsageError(
            f"{opts}: expected a view within 45° of the plane across the packing axis {'zyx'[a]} of this "
            f"packed store, got one closer to {'zyx'[a]}: it serves views around {'zyx'[a]} (--view "
            f"{around}, turned by --azimuth, tilted by --elevation under 45°); for this view encrypt a "
            "store packed along another axis (--pack-axis) or a per-voxel store"
        ) from None
    return cam, view or ""


def packed_encrypt_lines(ev: Any, out: str) -> None:
    """``hevr encrypt``'s lines about the packed store it wrote: its slots, how to render it, its tags."""
    p = ev.packing
    print(
        f"packed:  {p.slots} voxels per ciphertext along {'zyx'[p.axis]} ({p.slot_bits}-bit slots): X-ray frames of "
        f"parallel cameras around that axis (hevr render {out} --out FRAME.hevr --key KEY: --view "
        f"{default_packed_view(ev)} unless you give a view)"
    )
    if ev.meta.tags:
        print(
            f"verifiable: store id {ev.meta.store_id}; one tag per packed ciphertext: frames rendered with --key "
            f"KEY are verified (--verify {ev.meta.store_id} refuses any other store)"
        )
    else:
        print(
            "not verifiable: no tags (--no-verifiable, or a public --key: only the owner's private key makes them); "
            "packed frames of this store cannot be checked against a lying server"
        )


def packed_start(args: Any, ev: Any) -> Camera:
    """``hevr render`` on a packed store up to the render: the camera (:func:`packed_camera`), the
    level and size checks, and the ``store:`` / ``render:`` lines."""
    if args.view and ev.frame is None:
        warn_line(
            f"--view {args.view}: {args.store} records no patient frame (its input had no orientation); "
            "the view takes the stored axes as RAS+ (x right, y anterior, z superior)"
        )
    cam, view = packed_camera(args, ev)
    if args.level > ev.levels:
        raise UsageError(
            f"--level {args.level}: expected a level of the store's pyramid (0 to {ev.levels}), got "
            f"{args.level}; encrypt the packed store with --levels {args.level}"
        )
    check_render_size(cam, ev.shape, ev.spacing, 1.0)  # refuse before a cluster starts
    p = ev.packing
    print(
        f"store:   {args.store}, {xyz(ev.shape)} voxels, key {ev.meta.fingerprint[:16]}…, packed along "
        f"{'zyx'[p.axis]} ({p.slots} voxels per ciphertext)"
    )
    lvl = f", pyramid level {args.level} ({xyz(ev.meta.levels[args.level - 1].shape)})" if args.level else ""
    default = " (the packed store's default)" if view and not args.view else ""
    mode = args.mode or ("tf" if args.tf is not None else "emphasize" if args.density is not None else "xray")
    what = {"xray": "X-ray", "emphasize": "emphasis", "tf": "transfer function"}[mode]
    what += " (coloured at decryption)" if mode != "xray" else ""
    print(
        f"render:  {what}{', gradient-modulated' if args.gradient else ''}, {args.sampling} sampling"
        f"{' (bilinear in each slice)' if args.sampling == 'trilinear' else ''}"
        f", {wh(cam.width, cam.height)} px, {f'{view} view{default}, ' if view else ''}azimuth "
        f"{args.azimuth or 0.0:g}, elevation {args.elevation or 0.0:g}, parallel, one sample per slice{lvl}"
    )
    return cam


def packed_done(img: Any, out: Any, size: str, seconds: float, warn: Callable[[], None], opts: str = "") -> None:
    """``hevr render``'s closing lines about the packed frame file it wrote (``warn``: the
    command's one line when the frame is not verified; ``opts``: a colour frame's decrypt options)."""
    line = packed_verified_line(img)
    if line:
        print(line + " (stamped with the key holder's MAC)")
    warn()
    p = img.plan.packing
    print(
        f"wrote {out}: {plural(img.n_ciphertexts, 'ciphertext')} (up to {p.slots + img.plan.classes - 1} ray sums "
        f"of {p.slot_bits} bits each), {size}, rendered in {seconds:.2f} s"
    )
    if hasattr(img, "components"):
        print(
            f"colour:  applied at decryption: {out} holds the {img.channel} channel's {len(img.components)} "
            "components' ray sums, not the colouring (neither sent to the server nor written)"
        )
    print(f"decrypt it with: hevr decrypt {out} --key KEY.json --out {png_name(out)}{opts}")


def check_packed_decrypt(args: Any) -> None:
    """``hevr decrypt`` of a packed X-ray: no colouring option (decrypted as it is; a packed colour
    frame takes them as a per-voxel client-finished frame does: ``decrypt_colouring``)."""
    given = [
        o
        for o, v in (
            ("--mode", args.mode),
            ("--density", args.density),
            ("--tf", args.tf),
            ("--value-range", args.value_range),
        )
        if v is not None and (o != "--mode" or v != "xray")
    ]
    if given:
        raise UsageError(
            f"{', '.join(given)}: expected no colouring for {args.frame}, a packed store's X-ray (it is "
            "decrypted as it is)"
        )


def packed_verified_line(img: Any) -> str | None:
    """What a verified packed frame proves (None: not verified)."""
    v = img.verification
    if v is None:
        return None
    c = img.camera
    kind = (
        "X-ray" if getattr(v, "channel", "scalar") == "scalar" else f"{v.channel} channel's {v.components} components"
    )
    return (
        f"verified: the frame is the packed {kind} of store {v.store_id} ({img.plan.sampling} sampling, level "
        f"{img.level}) and its view, parallel camera at ({', '.join(f'{x:g}' for x in c.position)}) looking at "
        f"({', '.join(f'{x:g}' for x in c.focal_point)}), {c.width}x{c.height} px (view key "
        f"{recorded_proof(img).view_key}); checked against the store's tags and its owner-authenticated metadata"
    )


def packed_info_rows(img: Any) -> list[tuple[str, Any]]:
    """``hevr info``'s rows about a packed frame file (public facts only)."""
    plan, c = img.plan, img.camera
    p = plan.packing
    where = ", ".join(f"{x:g}" for x in c.position)
    verified = verified_row(img)
    return [
        (
            "kind",
            "encrypted packed frame (.hevr: "
            + (
                "an X-ray of a packed store"
                if not hasattr(img, "components")
                else f"the {img.channel} channel's {len(img.components)} components of a packed store, coloured at "
                "decryption with --tf / --density"
            )
            + ", finished on the client)",
        ),
        ("shape", f"{wh(c.width, c.height)} px"),
        (
            "rendered",
            f"{'X-ray' if not hasattr(img, 'components') else img.channel + ' channel'}, "
            f"{plan.sampling} sampling ("
            f"{'bilinear in each slice' if plan.sampling == 'trilinear' else 'one voxel per slice'}), "
            f"{plan.weight_bits}-bit weights, level {img.level}",
        ),
        ("camera", f"parallel, position {where}, scale {c.parallel_scale:g}"),
        (
            "store",
            f"{img.store_id}, packed along {'zyx'[p.axis]}: {p.slots} voxels per ciphertext ({p.slot_bits}-bit slots)",
        ),
        (
            "ciphertexts",
            f"{img.n_ciphertexts} in {plural(len(img.ciphertexts), 'tile')} (one per block of {p.slots} rays and row)",
        ),
        ("verified", verified),
        ("checksum", "ok (SHA-256 over the whole file; every field checked, the frame's plan rebuilt)"),
        ("key", f"{int(img.n).bit_length()}-bit"),
        ("fingerprint", img.fingerprint),
    ]
