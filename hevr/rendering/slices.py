"""``hevr.render_slice``: encrypted slices (multi-planar reformatting) through the render pipeline.

A slice pixel is a short ray along the plane's normal whose samples are the slab's planes
(:mod:`hevr.rendering.geometry.plane`), so a slice is one more kind of view for the ray renderer: the
same weights, kernel, Dask graph, planner, finishing, packing, ray-sum cache and
:func:`hevr.error_bound`. Its value is the mean over the pixel's slab samples inside the volume
(one sample: the sampled value itself, exactly ``vol[k]`` for a nearest axial slice through
layer k); a pixel with none inside has no value (0, ``hits`` False).

Why a thick slab is a mean and never a maximum (no MIP): Paillier is additively homomorphic.
The server can multiply ciphertexts (adding the plaintexts) and raise them to public powers
(multiplying by public constants); every output is therefore a *linear* function of the voxels.
``max`` is not linear, and deciding which of two ciphertexts holds the larger value needs the
secret key — or an interactive protocol with the key holder that reveals the order of the
values, which is what the encryption hides. A mean over the slab (average-intensity projection)
is linear and exact up to the fixed-point error bound.
"""

from __future__ import annotations

import logging
import os
from typing import TYPE_CHECKING, Any, cast

from dask.delayed import Delayed

from ..errors import ParameterError
from ..image.encrypted import EncryptedImage
from ..runtime.scheduler import active_client
from ..store.reader import EncryptedVolume
from .geometry.plane import Plane
from .packed.plane_image import PackedSlice, render_packed_slice, slice_verification
from .verify import resolve_verify
from .view import render_view

if TYPE_CHECKING:
    from ..remote.volume import RemoteVolume

__all__ = ["DEFAULT_PRECISION", "render_slice"]

log = logging.getLogger(__name__)

# Decimal digits of the normalisation when a slice needs one (a slab, or K > 1 transfer-function nodes).
DEFAULT_PRECISION = 4


def render_slice(
    ev: EncryptedVolume,
    plane: Plane,
    mode: str = "xray",
    sampling: str = "nearest",
    density: float | None = None,
    nodes: Any = None,
    *,
    digits: int = 3,
    precision: int | None = None,
    comb_digits: int = 4,
    pack: bool = True,
    tile: int = 32,
    cache: bool = True,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
    compute: bool = True,
    keep_sums: str | os.PathLike[str] | None = None,
    gradient: bool = False,
    overwrite: bool = False,
    finish: str = "client",
    verify: bool | str | None = None,
) -> EncryptedImage | PackedSlice | Delayed:
    """Render a slice of an encrypted volume to an :class:`EncryptedImage` (no key needed).

    Parameters
    ----------
    ev : EncryptedVolume
    plane : Plane
        The slice (:meth:`Plane.axial`, :meth:`Plane.coronal`, :meth:`Plane.sagittal`,
        :meth:`Plane.oblique`, or any :class:`Plane`); its ``slab`` planes, ``slab_step``
        apart, are averaged per pixel.
    mode : {"xray", "emphasize", "tf"}
        ``xray``: the (mean) value; ``emphasize`` / ``tf``: the paper's density emphasis and
        transfer function applied to the sampled density encoding, as for :func:`hevr.render`.
    sampling : {"nearest", "trilinear"}
    density, nodes :
        As for :func:`hevr.render`.
    verify : bool or str, optional
        As for :func:`hevr.render`: checked against a verifiable store's tags (the default there);
        a store id pins the store.
    precision : int, optional
        Decimal digits of the normalisation, as for :func:`hevr.render`. Default: 0 when it is
        exact without any — one plane (``slab=1``) in mode ``xray`` or ``emphasize``, where every
        pixel divides by n·K = 1 — else 4. Fewer digits mean smaller packed values: the
        finishing does ``bits(value)`` squarings per pixel, so a nearest X-ray slice of 8-bit
        data packs 8 bits per pixel instead of 22.
    digits, comb_digits, pack, tile, cache, client, progress, backend, compute, keep_sums, gradient, overwrite, finish :
        As for :func:`hevr.render` (the plane's ``slab_step`` is the sample step; ``gradient``:
        the gradient channel g·e(d), emphasize / tf only).

    Returns
    -------
    EncryptedImage, PackedSlice or dask.delayed.Delayed
        Shape (height, width) (``tf``: (height, width, 3)); ``hits`` marks the pixels with a
        value. :func:`hevr.error_bound` with the plane bounds its error against
        :func:`hevr.render_slice_plain`. A packed store (``layout="packed"``) gives a
        :class:`~hevr.rendering.packed.plane_image.PackedSlice` (:mod:`hevr.rendering.packed.planes`):
        planes perpendicular to its packing axis or containing its direction, ``mode="xray"``,
        nearest or trilinear, any slab; the per-voxel options (digits, precision, comb_digits,
        pack, tile, cache, overwrite) do not apply there, and the slice is not verified yet.

    Raises
    ------
    ParameterError
        ``plane`` is not a :class:`Plane` (bad planes are refused when they are built).
    RenderPlanError
        As for :func:`hevr.render` (too many pixels or samples, or a possible overflow).

    Examples
    --------
    ``img = hevr.render_slice(ev, hevr.Plane.axial(ev, 50))`` then
    ``img.decrypt(priv)`` is layer 50 of the volume, as a (ny, nx) float64 image.
    """
    if not isinstance(plane, Plane):
        raise ParameterError(
            f"plane: expected a hevr.Plane (Plane.axial, Plane.oblique, ...), got {type(plane).__name__}"
        )
    if getattr(ev, "packing", None) is not None:  # a packed store: its own plan (hevr.rendering.packed.planes)
        return _packed_slice(
            ev,
            plane,
            mode,
            sampling,
            density,
            nodes,
            client=client,
            progress=progress,
            backend=backend,
            compute=compute,
            keep_sums=keep_sums,
            gradient=gradient,
            finish=finish,
            verify=verify,
        )
    if precision is None:
        precision = 0 if plane.slab == 1 and mode in ("xray", "emphasize") else DEFAULT_PRECISION
    return render_view(
        ev,
        plane,
        mode,
        sampling,
        plane.slab_step,
        density,
        nodes,
        digits=digits,
        precision=precision,
        comb_digits=comb_digits,
        pack=pack,
        tile=tile,
        cache=cache,
        client=client,
        progress=progress,
        backend=backend,
        compute=compute,
        keep_sums=keep_sums,
        views=(Plane,),
        gradient=gradient,
        overwrite=overwrite,
        finish=finish,
        verify=verify,
    )


def _packed_slice(
    ev: EncryptedVolume,
    plane: Plane,
    mode: str,
    sampling: str,
    density: Any,
    nodes: Any,
    *,
    client: Any,
    progress: bool,
    backend: str | None,
    compute: Any,
    keep_sums: Any,
    gradient: Any,
    finish: Any,
    verify: Any,
) -> PackedSlice:
    """A packed store's slice: what it serves is checked before any work, then rendered."""
    other = "a per-voxel store (encrypt_volume(..., layout='voxel')) serves it"
    if mode != "xray":
        raise ParameterError(
            f"mode: expected 'xray' on a packed store (it holds the scalar channel only), got {mode!r}; {other}"
        )
    if density is not None or nodes is not None or gradient:
        raise ParameterError(
            "density/nodes/gradient: expected None, None and False for a slice of a packed store, "
            f"got a colouring; {other}"
        )
    if finish != "client":
        raise ParameterError(
            f"finish: expected 'client' on a packed store (the key holder finishes the pixels), got {finish!r}"
        )
    if keep_sums is not None or compute is not True:
        raise ParameterError(
            f"keep_sums/compute: expected None and True on a packed store, got {keep_sums!r} and {compute!r}"
        )
    verified = resolve_verify(verify, ev, "client", level=0, compute=True, stream=False)
    if getattr(ev, "remote", None) is not None:  # a store on hevr serve: planned here, rendered there
        remote = cast("RemoteVolume", ev)
        served: PackedSlice = remote.render_packed_slice_request(
            plane, sampling, backend=backend, client=client, verify=verified
        )
        return served
    img = render_packed_slice(ev, plane, sampling, client=client, progress=progress, backend=backend)
    if verified:  # the values are fixed in this process: only now the seed (hevr.rendering.packed.verified)
        img.verification = slice_verification(ev, img.plan, img.stats["backend"], active_client(client), progress)
    return img
