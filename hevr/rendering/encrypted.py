"""``hevr.render``: encrypted ray casting as one Dask graph, and re-colouring from cached ray sums.

Two ways to finish a frame (``finish=``). ``"client"`` (the default): the server merges and
packs the per-component ray sums only, and the client divides by the public sample counts and
colours them after decryption (:mod:`hevr.colour`): the density, transfer function and colours
never leave the client process — not in the task graph, the scheduler, a worker, a store, a
``.hevr`` file or a log. ``"server"``: the paper's way, the server combines, normalises and
packs the finished pixels (bit for bit the images of earlier releases).

The error bound of a decrypted pixel against :func:`hevr.render_plain` is
:mod:`hevr.rendering.planning.bounds` (:func:`error_bound`); a request is checked once, where it enters
(:mod:`hevr.rendering.planning.request`). The render of a per-voxel store's view is
:mod:`hevr.rendering.view`, its cache of ray sums :mod:`hevr.rendering.pipeline.cache`; a packed store's frames
are :mod:`hevr.rendering.packed`'s.
"""

from __future__ import annotations

import os
from typing import Any

from dask.delayed import Delayed

from ..errors import ParameterError
from ..image.encrypted import EncryptedImage
from ..store.reader import EncryptedVolume
from .geometry.camera import Camera
from .geometry.plane import Plane
from .packed.colour import PackedColourImage
from .packed.image import PackedImage
from .packed.request import render_packed_request
from .pipeline.cache import clear_cache
from .pipeline.sums import RaySums
from .planning.bounds import error_bound
from .view import render_view

__all__ = ["render", "RaySums", "clear_cache", "error_bound"]


def render(
    ev: EncryptedVolume,
    camera: Camera,
    mode: str = "xray",
    sampling: str = "nearest",
    step: float = 1.0,
    density: float | None = None,
    nodes: Any = None,
    *,
    digits: int = 3,
    precision: int = 4,
    comb_digits: int = 4,
    pack: bool = True,
    tile: int = 32,
    cache: bool = True,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
    compute: bool = True,
    keep_sums: str | os.PathLike[str] | None = None,
    level: int | None = None,
    gradient: bool = False,
    overwrite: bool = False,
    finish: str = "client",
    verify: bool | str | None = None,
    weight_bits: int | None = None,
) -> EncryptedImage | PackedImage | PackedColourImage | Delayed:
    """Render an encrypted volume to an :class:`EncryptedImage` on the active Dask scheduler.

    Parameters
    ----------
    ev : EncryptedVolume
    camera : Camera
    mode : {"xray", "emphasize", "tf"}
    sampling : {"nearest", "trilinear"}
    step : float
        Sample spacing along each ray, world units.
    density : float
        Emphasised normalised density (``mode="emphasize"``).
    nodes : list of (density, colour)
        Transfer-function nodes (``mode="tf"``); colours as (r, g, b) in [0, 1], '#rrggbb' or names.
    digits : int
        Decimal digits of the trilinear weights.
    precision : int
        Decimal digits of the reciprocal normalisation (relative error <= 0.5·10^-precision).
    comb_digits : int
        Decimal digits of the emphasis / transfer-function combination matrix.
    pack : bool
        Pack many pixels per ciphertext (the client decrypts far fewer ciphertexts).
    tile : int
        Image tile edge (pixels) of the reduce.
    cache : bool
        Keep the per-component ray sums of this view so that another density or transfer
        function on the same camera only redoes the per-pixel step. On a distributed client the
        sums stay on the workers (futures) and re-colouring runs there: no sums travel.
    client : distributed.Client, optional
        Defaults to the active client, else Dask's default scheduler.
    progress : bool
        Progress bar on stderr.
    backend : str, optional
        Arithmetic backend of the workers (:mod:`hevr.backends`); default: the Dask config
        key ``hevr.backend``, else ``"auto"``: the resident volume's backend, else the compiled
        host kernels (``cuda-host``) for keys under 256 bits where they build, else ``cpu``.
        Every backend gives the identical image.
    compute : bool
        False: build the graph and return it unevaluated, as a ``dask.delayed`` object whose
        result is the :class:`EncryptedImage` (``client.compute(d)`` gives a future,
        ``dask.compute(d)`` or ``d.compute()`` the image) — for notebooks and services that
        must not block. Its ray sums are not cached (cached sums are still used). When the
        graph refers to data held by a client that is not the default one (cached sums or a
        persisted volume), compute it with that client: ``client.compute(d)``. The image's
        ``stats["seconds"]`` is None (the caller times the compute).
    keep_sums : path, optional
        Also write this view's merged encrypted ray sums to a ``.hevrsums`` file (ciphertexts
        and public geometry only: safe on the server), from which :func:`hevr.recolour`
        finishes another density or transfer function without the map step
        (:mod:`hevr.rendering.pipeline.sums`). The sums travel to this process to be written. An
        existing file there is refused before any work (:class:`hevr.ExistingFileError`)
        unless ``overwrite=True``.
    level : int, optional
        Render pyramid level ``level`` of the store (:func:`hevr.build_pyramid`; 0 = the full
        volume) with the same camera, sampled in the level's voxels (``step·2^level`` world
        units): 2^level times fewer samples per ray, 8^level times fewer voxels; a camera of
        half the width and height per level (a preview) makes it ~8^level times fewer
        ray-voxel pairs. It shows the 2×2×2 means (for emphasis and transfer functions: the
        means of the encoded density vectors, :mod:`hevr.volume.pyramid`). Default: the
        volume as given (a view from :meth:`hevr.EncryptedVolume.at_level` renders its level).
    gradient : bool
        ``emphasize`` / ``tf`` only: read the gradient channel g·e(d) (a store encrypted with
        ``gradient=True``, :mod:`hevr.volume.gradient`) instead of e(d), so each sample is weighted
        by its voxel's normalised gradient magnitude: boundaries stand out, homogeneous regions
        fade. Same kernel and cost per sample as without.
    overwrite : bool
        Replace an existing ``keep_sums`` file (the only file a render writes).
    finish : {"client", "server"}
        ``"client"`` (default): the server packs only the ray sums of the stored components;
        ``density`` / ``nodes`` stay in this process (the returned image holds them in memory,
        never in its file) and :meth:`~hevr.EncryptedImage.decrypt` colours on the client —
        or :meth:`~hevr.EncryptedImage.decrypt_frame` keeps the sums to re-colour in
        milliseconds (:mod:`hevr.colour`). ``"server"``: the paper's way, the server
        combines, normalises and packs finished pixels (the colouring is sent to the workers).
        With ``compute=False`` a client-finished image carries no colouring: pass it to ``decrypt``.
    verify : bool or str, optional
        Check the render against the store's tags (a store encrypted with ``verifiable=True``):
        after the image, the server sums the tag channel with the same plan and returns one
        aggregate ciphertext for coefficients drawn here; decryption then raises
        :class:`hevr.VerificationError` instead of returning an image that is not the render of
        this store and camera (:mod:`hevr.rendering.verify`). Default: on for a verifiable store
        where the request can be verified (client finishing, ``compute=True``); ``True``
        where it cannot is a :class:`hevr.ParameterError`. Against a server that may lie, pass the
        store id the owner recorded (``ev.meta.store_id`` from :func:`hevr.encrypt_volume`): the
        render is verified, and refused for any other store (a server could otherwise serve another
        verifiable store of the same key, or one without tags). About twice the server's work.
    weight_bits : int, optional
        Packed stores only: bits per axis of the in-slice bilinear weights (default: the store's,
        which its slots were sized for; more is refused when a sum could carry into the next slot).

    A packed store (``encrypt_volume(..., layout="packed")``, :mod:`hevr.store.packing`) renders
    X-ray frames of parallel cameras slice by slice (:mod:`hevr.rendering.packed`): ``sampling``
    ``"nearest"`` or ``"trilinear"`` (bilinear within each slice), ``step`` 1 (one sample per
    slice), client finishing; it returns a :class:`hevr.rendering.packed.PackedImage`, which
    ``decrypt`` s like an :class:`EncryptedImage`, compared with ``render_plain(..., slices=True)``.

    Returns
    -------
    EncryptedImage, PackedImage, PackedColourImage or dask.delayed.Delayed
        Never touches the secret key. ``stats`` reports ``map_tasks``, ``finish_tasks``,
        ``reused_ray_sums``, ``resident`` (bricks taken from a persisted volume,
        :meth:`hevr.EncryptedVolume.persist`), ``backend`` (the one that ran: ``backend="auto"``
        resolved) and ``gathered_bytes`` (what reached the client).

    Raises
    ------
    RenderPlanError
        The render could overflow the key's plaintext space, or is bigger than the size
        limits ``hevr.limits.max-pixels`` / ``hevr.limits.max-samples``
        (:func:`hevr.rendering.planning.planner.check_render_size`): refused before any work.
    """
    if isinstance(camera, Plane):
        raise ParameterError("camera: expected a hevr.Camera, got a hevr.Plane (render slices with hevr.render_slice)")
    if getattr(getattr(ev, "meta", None), "packing", None) is not None:  # a packed store's frame plan
        if not isinstance(camera, Camera):
            raise ParameterError(f"camera: expected a hevr.Camera, got {type(camera).__name__}")
        return render_packed_request(
            ev,
            camera,
            mode,
            sampling,
            step,
            density,
            nodes,
            tile=tile,
            client=client,
            progress=progress,
            backend=backend,
            compute=compute,
            keep_sums=keep_sums,
            level=level,
            gradient=gradient,
            finish=finish,
            verify=verify,
            weight_bits=weight_bits,
        )
    if weight_bits is not None:
        raise ParameterError(
            f"weight_bits: expected None for a per-voxel store (its trilinear weights have "
            f"'digits'), got {weight_bits!r}"
        )
    return render_view(
        ev,
        camera,
        mode,
        sampling,
        step,
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
        level=level,
        gradient=gradient,
        overwrite=overwrite,
        finish=finish,
        verify=verify,
    )
