"""What a packed store's frame may ask, checked where the request enters (``hevr.render``).

A packed store serves X-ray frames (``mode="xray"``; with the vector channel also ``"tf"`` and
``"emphasize"``, :mod:`hevr.rendering.packed.colour`) of parallel cameras whose principal axis is
not its packing axis, sampled once per slice (``sampling="nearest"``, or ``"trilinear"``: bilinear
within the slice), finished on the client, streamed from the store or resident. Everything else is
refused before any work, with a :class:`hevr.ParameterError` that names the option and the way to
get it (a per-voxel store). ``verify`` is resolved as for a per-voxel store
(:func:`hevr.rendering.verify.resolve_verify`): a verifiable packed store's frames are verified by
default (:mod:`hevr.rendering.packed.verified`), a store id pins the store.
"""

from __future__ import annotations

import logging
from typing import Any

from ...core.validate import check_int
from ...errors import ParameterError
from ...runtime.scheduler import active_client
from ..planning.planner import check_render_size
from ..planning.request import at_level
from ..verify import resolve_verify
from .colour import PackedColourImage
from .colour_render import render_packed_colour_request
from .graph import render_packed
from .image import PackedImage
from .verified import tag_aggregate

log = logging.getLogger(__name__)

__all__ = ["render_packed_request"]

_OTHER = "encrypt a per-voxel store (encrypt_volume(..., layout='voxel')) for it"


def render_packed_request(
    ev: Any,
    camera: Any,
    mode: Any,
    sampling: Any,
    step: Any,
    density: Any,
    nodes: Any,
    *,
    tile: Any,
    client: Any,
    progress: bool,
    backend: Any,
    compute: Any,
    keep_sums: Any,
    level: Any,
    gradient: Any,
    finish: Any,
    verify: Any,
    weight_bits: Any,
) -> PackedImage | PackedColourImage:
    """Check a render request against what a packed store serves, then render it."""
    if mode != "xray" and ev.meta.vector is None:
        raise ParameterError(
            f"mode: expected 'xray' on a packed store without the vector channel, got "
            f"{mode!r}; encrypt it again with vector_dims=k (packed too), or {_OTHER} with vector_dims"
        )
    if mode == "xray" and (density is not None or nodes is not None):
        raise ParameterError("density/nodes: expected None for an X-ray of a packed store, got a colouring")
    if type(step) not in (int, float) or float(step) != 1.0:
        raise ParameterError(
            f"step: expected 1.0 on a packed store (one sample per slice of the view's principal axis), got {step!r}"
        )
    asked = camera  # level 0's frame: what a request to hevr serve names (with the level)
    ev, camera = at_level(ev, camera, level)  # a level the owner encrypted packed (hevr.store.packed_levels)
    if gradient and (mode == "xray" or ev.meta.gradient is None):
        what = "an X-ray" if mode == "xray" else "a packed store without the gradient channel"
        raise ParameterError(
            f"gradient: expected False on {what} (the gradient channel modulates emphasis and "
            "transfer functions; encrypt with gradient=True for it)"
        )
    if finish != "client":
        raise ParameterError(
            f"finish: expected 'client' on a packed store (the key holder decodes the slots and "
            f"warps the image), got {finish!r}"
        )
    if keep_sums is not None:
        raise ParameterError("keep_sums: expected None on a packed store (its ray sums are not saved yet)")
    if compute is not True:
        raise ParameterError(f"compute: expected True on a packed store, got {compute!r}")
    if weight_bits is not None:
        weight_bits = check_int("weight_bits", weight_bits, 0, 16)
    check_render_size(camera, ev.shape, ev.spacing, 1.0)  # the size limits, before anything per pixel
    if mode != "xray":  # transfer function / emphasis: the vector channel's sums, coloured by the key holder
        return render_packed_colour_request(
            ev,
            camera,
            mode,
            density,
            nodes,
            sampling,
            verify=verify,
            tile=tile,
            client=client,
            progress=progress,
            backend=backend,
            weight_bits=weight_bits,
            channel="gradient" if gradient else "vector",
        )
    verified = resolve_verify(verify, ev, "client", level=ev.level, compute=True, stream=False)
    if getattr(ev, "remote", None) is not None:  # a store on hevr serve: the request goes there (remote/packed.py)
        return ev.render_packed_request(
            camera,
            sampling,
            tile=tile,
            weight_bits=weight_bits,
            backend=backend,
            client=client,
            verify=verified,
            asked=asked,
        )
    image = render_packed(
        ev, camera, sampling, tile=tile, client=client, progress=progress, backend=backend, weight_bits=weight_bits
    )
    if verified:  # the second round: the values are fixed in this process before the seed is drawn
        image.verification = tag_aggregate(ev, image.plan, image.stats["backend"], active_client(client), progress)
        image.stats["verify"] = {"server_s": image.verification.server_s, "ops": image.verification.ops}
    return image
