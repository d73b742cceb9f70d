"""``hevr.render``: encrypted ray casting as one Dask graph, and re-colouring from cached ray sums.

Two ways to finish a frame (``finish=``). ``"client"`` (the default): the server merges and
packs the per-component ray sums only, and the client divides by the public sample counts and
colours them after decryption (:mod:`hevr.colour`): the density, transfer function and colours
never leave the client process — not in the task graph, the scheduler, a worker, a store, a
``.hevr`` file or a log. ``"server"``: the paper's way, the server combines, normalises and
packs the finished pixels (bit for bit the images of earlier releases).

The error bound of a decrypted pixel against :func:`hevr.render_plain` is
:mod:`hevr.rendering.planning.bounds` (:func:`error_bound`); a request is checked once, where it enters
(:mod:`hevr.rendering.planning.request`).
"""

from __future__ import annotations

import logging
import os
import threading
import time
import uuid
from collections import OrderedDict
from typing import Any

import dask
from dask.delayed import Delayed, delayed

from ..backends import resolve_backend_name
from ..core.validate import check_bool, check_int
from ..errors import ParameterError
from ..image.encrypted import EncryptedImage
from ..image.tiles import TileLayout
from ..runtime import malloc
from ..runtime.scheduler import active_client, warn_if_remote
from ..runtime.scheduler import compute as run_tasks
from ..store.paths import check_reachable
from ..store.reader import EncryptedVolume
from ..store.resident import batched
from .geometry.camera import Camera
from .geometry.plane import Plane
from .geometry.rays import cast_rays
from .packed.request import render_packed_request
from .pipeline.graph import FinishGraph, build_sums_graph
from .pipeline.maps import resident_groups
from .pipeline.reduce import BlockedReduce
from .pipeline.sums import RaySums, check_sums_path, image_fields, save_sums, with_colouring
from .planning.bounds import error_bound
from .planning.modes import combination_matrix
from .planning.planner import check_render_size, plan_render
from .planning.request import at_level, check_request, level_step
from .verify import resolve_verify, tag_aggregate

log = logging.getLogger(__name__)

__all__ = ["render", "RaySums", "clear_cache", "error_bound"]


def _gathered_bytes(packed: list, sums: RaySums, client: Any, reused: bool) -> int:
    """Bytes the client received: the packed tiles, plus the ray sums it holds itself (single machine)."""
    total = sum(int(p.nbytes) for p in packed)
    if client is None and not reused:
        total += sum(int(r.nbytes) + int(c.nbytes) for v in sums.tiles.values() if v is not None for r, c in [v])
    return total


# Resident bricks get one map task per tile row of their footprint (graph.build_sums_graph) from
# this key size on, where a piece's arithmetic outweighs a task's fixed cost (~2 ms); nearest
# sampling only: trilinear rows share per-voxel powers across a brick's rays (kernel.py), which
# pieces would compute once per piece (measured: +8 % map time at 2048 bits).
BAND_BITS = 1024
# Dask config: resident bricks mapped in one task per worker (True), one task per brick (False) or
# "auto": one per worker below BATCH_BITS (1024), where a task's fixed cost outweighs a brick's arithmetic
# (64-bit paper case, 2 workers: 0.45 -> 0.35 s); from BATCH_BITS on per brick, whose pipelining of
# merges and finishing with the maps the batched task would lose (2048 bits: trilinear 18.3 ->
# 24.8 s, TF 9.4 -> 10.7 s; benchmarks/frame_plaintext.py); and always per worker where the backend
# keeps residues on a GPU (a few large launches, not one small launch per brick).
RESIDENT_BATCH_KEY = "hevr.render.resident-batch"


def _batch(bits: int, backend: str = "cpu") -> bool:
    """Whether resident bricks are mapped one task per worker (see RESIDENT_BATCH_KEY; "auto":
    :func:`hevr.store.resident.batched`).

    >>> _batch(64), _batch(2048), _batch(2048, "cuda")
    (True, False, True)
    """
    value = dask.config.get(RESIDENT_BATCH_KEY, "auto")
    if isinstance(value, str) and value.strip().lower() in ("true", "false"):  # from the environment
        value = value.strip().lower() == "true"
    if value == "auto":
        return batched(bits, backend)
    if not isinstance(value, bool):
        raise ParameterError(f"{RESIDENT_BATCH_KEY}: expected true, false or 'auto', got {value!r}")
    return value


_CACHE: OrderedDict[tuple, RaySums] = OrderedDict()
CACHE_SIZE = 2
_CACHE_LOCK = threading.Lock()  # renders run on several threads at once (hevr serve, a notebook's threads)


def clear_cache() -> None:
    """Forget every cached set of ray sums."""
    with _CACHE_LOCK:
        _CACHE.clear()


def _cached(key: tuple, client: Any) -> RaySums | None:
    """The cached ray sums of ``key`` usable on ``client`` (now the most recent), else None; sums
    whose futures belong to another (or a closed) client are dropped. One step under the lock: a
    render on another thread cannot evict them between the look-up and the use."""
    with _CACHE_LOCK:
        sums = _CACHE.get(key)
        if sums is not None and not sums.usable(client):
            del _CACHE[key]
            sums = None
        if sums is not None:
            _CACHE.move_to_end(key)
        return sums


def _keep(key: tuple, sums: RaySums) -> None:
    """Cache ``sums`` under ``key``, dropping the least recently used beyond :data:`CACHE_SIZE`."""
    with _CACHE_LOCK:
        _CACHE[key] = sums
        _CACHE.move_to_end(key)
        while len(_CACHE) > CACHE_SIZE:
            _CACHE.popitem(last=False)


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
    keep_sums: str | os.PathLike | None = None,
    level: int | None = None,
    gradient: bool = False,
    overwrite: bool = False,
    finish: str = "client",
    verify: bool | str | None = None,
    weight_bits: int | None = None,
) -> EncryptedImage | Delayed:
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
    EncryptedImage, PackedImage or dask.delayed.Delayed
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
    return _render(
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


# -- the render of one view (a Camera, or a Plane: hevr.render_slice) ----------------------------
def _render(
    ev: EncryptedVolume,
    camera: Camera | Plane,
    mode: str,
    sampling: str,
    step: float,
    density: float | None,
    nodes: Any,
    *,
    digits: int,
    precision: int,
    comb_digits: int,
    pack: bool,
    tile: int,
    cache: bool,
    client: Any,
    progress: bool,
    backend: str | None,
    compute: bool,
    keep_sums: str | os.PathLike | None,
    views: tuple[type, ...] = (Camera,),
    level: int | None = None,
    gradient: bool = False,
    overwrite: bool = False,
    finish: str = "client",
    stream: Any = None,
    verify: bool | str | None = None,
) -> EncryptedImage | Delayed:
    """:func:`render`'s work for a view of the kinds ``views``; a plane's ``step`` is its ``slab_step``.

    With ``finish="client"`` nothing below this function sees ``spec``'s density or nodes: the
    plan (:func:`~hevr.rendering.planning.planner.plan_sums`), the graph and the image fields are built
    from the channel, the sampling and the step; the spec joins the image here, at the end.

    ``stream`` (:class:`hevr.rendering.pipeline.stream.StreamDecryptor`): told the plan before the graph
    runs and handed every finishing unit's ciphertexts as it completes."""
    if getattr(getattr(ev, "meta", None), "packing", None) is not None:
        raise ParameterError(
            f"ev: expected a per-voxel store for a {'slice' if Plane in views else 'frame'} of this kind, "
            f"got the packed store {ev.meta.store_id}: a packed store renders X-ray frames of parallel "
            "cameras (hevr.render); slices, streamed frames and the rest need a per-voxel store "
            "(encrypt_volume(..., layout='voxel'))"
        )
    spec, digits, precision, comb_digits = check_request(
        ev, camera, mode, sampling, step, density, nodes, digits, precision, comb_digits, views, gradient, finish
    )
    if getattr(ev, "remote", None) is not None:  # a store on hevr serve: the request goes there (remote/render.py)
        return ev.render_request(
            camera,
            spec,
            level=level,
            digits=digits,
            pack=pack,
            tile=tile,
            client=client,
            compute=compute,
            keep_sums=keep_sums,
            finish=finish,
            stream=stream,
            verify=verify,
            backend=backend,
            progress=progress,
        )
    ev, camera = at_level(ev, camera, level)
    spec = level_step(spec, ev, camera)
    verified = resolve_verify(verify, ev, finish, level=ev.level, compute=compute, stream=stream is not None)
    tile = check_int("tile", tile, 1, 4096)
    if keep_sums is not None and not compute:
        raise ParameterError(
            "keep_sums: expected None with compute=False (the sums are written after the "
            f"render runs), got {str(keep_sums)!r}"
        )
    overwrite = check_bool("overwrite", overwrite)
    if keep_sums is not None:
        keep_sums = check_sums_path(keep_sums, overwrite=overwrite)
    cl = active_client(client)
    warn_if_remote(cl)  # the key holder joined another party's cluster? (hevr.connect is the safe way)
    check_reachable(ev.path, cl)  # memory:// stores only where the tasks run in this process
    backend = resolve_backend_name(
        backend,
        int(ev.public_key.n).bit_length(),  # auto: the residency's, else by key
        resident=ev.resident.backend if ev.resident is not None and ev.resident.bricks else None,
        client=cl,
    )
    checked = check_render_size(camera, ev.shape, ev.spacing, spec.step)  # before anything per pixel or sample
    malloc.tune()  # the client's rays and plan too
    t0 = time.perf_counter()
    rays = checked if checked is not None else cast_rays(camera, ev.shape, ev.spacing, spec.step)
    if not rays.n_samples.any():  # public geometry: say so rather than hand back a black frame
        log.warning(
            "render: no ray of this %dx%d %s hits the volume (%s voxels, spacing %s): the image is empty; "
            "aim it at the volume (hevr.Camera.orbit looks at its centre)",
            camera.width,
            camera.height,
            "plane" if isinstance(camera, Plane) else "camera",
            "x".join(map(str, ev.shape[::-1])),
            ", ".join(f"{s:g}" for s in ev.spacing),
        )
    comb = combination_matrix(spec, ev.vector_dims) if spec.needs_vector and finish == "server" else None
    plan = plan_render(
        n=int(ev.public_key.n),
        spec=spec,
        meta=ev.meta,
        n_samples=rays.n_samples,
        digits=digits if spec.sampling == "trilinear" else 0,
        precision=precision,
        comb_digits=comb_digits,
        pack=pack,
        combination=comb,
        finish=finish,
    )
    H, W = camera.height, camera.width
    layout = TileLayout(W, H, tile)
    n_tiles = layout.n_tiles
    # the metadata's own MAC too: a store written again at the same path (hevr serve reopens it) misses
    key = (
        ev.path,
        ev.meta.store_id,
        ev.meta.auth,
        ev.meta.fingerprint,
        ev.level,
        camera.key(),
        spec.sampling,
        spec.step,
        plan.weight_digits,
        plan.channel,
        tile,
    )
    sums = _cached(key, cl) if cache else None
    reused = sums is not None
    finish = FinishGraph.plan_units(plan, layout, rays.n_samples, int(ev.public_key.n), backend)

    resident = None
    if ev.resident is not None and ev.resident.bricks:  # a released residency just streams
        if ev.resident.usable(plan.channel, backend, cl):
            resident = ev.resident.bricks
        else:
            log.warning(
                "render: the resident bricks (%s, backend %s) cannot serve this render (channel %s, backend "
                "%s, %s client); streaming from the store",
                "+".join(ev.resident.channels),
                ev.resident.backend,
                plan.channel,
                backend,
                "another" if cl is not ev.resident.client else "a",
            )
    fields = image_fields(spec, plan, camera, rays.n_samples, ev.meta, tile, level=ev.level)
    on_unit = None
    if stream is not None:
        stream.start(finish, fields)
        on_unit = stream.unit
    if sums is None:
        # One graph: map -> tree merge -> finish, so merged sums never travel through the client.
        # When they are cached they stay where they are: futures on a cluster (re-colouring
        # then runs next to them), values on a single machine.
        batch = resident is not None and _batch(int(ev.public_key.n).bit_length(), backend)
        groups = resident_groups(resident, cl, backend) if batch else None
        graph = build_sums_graph(
            ev,
            camera,
            rays,
            spec.sampling,
            spec.step,
            plan.weight_digits,
            plan.channel,
            tile,
            n_tiles,
            backend,
            resident,
            bands=resident is not None
            and spec.sampling == "nearest"
            and int(ev.public_key.n).bit_length() >= BAND_BITS,
            groups=groups,
            fuse=groups is not None,
        )
        keep = cache or keep_sums is not None
        if groups is not None:  # G map tasks: merge and finish in G blocks of tiles (reduce.py)
            red = BlockedReduce(graph, finish, len(groups))
            fin, kept, on_result = red.unit_tasks(), red.block_tasks() if keep else [], red.on_block(on_unit)
        else:
            red, fin, on_result = None, finish.tasks({t: graph.delayed(t) for t in graph.merged}), on_unit
            live = [t for t, d in graph.merged.items() if d is not None] if keep else []
            kept = [graph.delayed(t) for t in live]
        map_tasks = graph.map_tasks
        if not compute:
            return _deferred(
                fin,
                finish,
                fields,
                {
                    "map_tasks": map_tasks,
                    "reused_ray_sums": False,
                    "backend": backend,
                    "resident": resident is not None,
                },
                nested=red is not None,
            )
        results = run_tasks(
            fin + kept, client=cl, progress=progress, desc="render", keep=len(kept), on_result=on_result
        )
        units = results[: len(fin)] if red is None else red.units(results[: len(fin)])
        packed = finish.assemble(units)
        sums = RaySums(key, dict.fromkeys(range(n_tiles)), map_tasks, cl, backend=backend)
        if plan.finish == "client":  # copies: the image's arrays are the caller's to change
            sums.packed[plan] = [u.copy() for u in units]
        if red is not None:
            sums.tiles.update(red.sums(results[len(fin) :], cl) if kept else {})
        else:
            sums.tiles.update(dict(zip(live, results[len(fin) :])))
        if cache:
            _keep(key, sums)
    elif compute and plan in sums.packed:  # finished on the client: the same packed sums for any colouring
        fin = []
        units = [u.copy() for u in sums.packed[plan]]
        for i, unit in enumerate(units):
            if on_unit is not None:
                on_unit(i, unit)
        packed = finish.assemble(units)
    else:
        fin = finish.tasks(sums.tiles)
        if not compute:
            return _deferred(
                fin,
                finish,
                fields,
                {"map_tasks": 0, "reused_ray_sums": True, "backend": backend, "resident": resident is not None},
            )
        units = run_tasks(fin, client=cl, progress=False, desc="finish", on_result=on_unit)
        packed = finish.assemble(units)
        if plan.finish == "client":
            sums.packed[plan] = [u.copy() for u in units]
    if keep_sums is not None:
        save_sums(
            keep_sums,
            sums,
            meta=ev.meta,
            camera=camera,
            sampling=spec.sampling,
            step=spec.step,
            weight_digits=plan.weight_digits,
            channel=plan.channel,
            tile=tile,
            store=str(ev.path),
            level=ev.level,
            storage_options=ev.storage_options,  # a URL: written with the store's options
            overwrite=overwrite,
            name="keep_sums",
        )
    stats = {
        "map_tasks": 0 if reused else sums.map_tasks,
        "finish_tasks": len(fin),
        "reused_ray_sums": reused,
        "resident": resident is not None,
        "backend": backend if fin else sums.backend,  # no task: the sums' own
        "gathered_bytes": _gathered_bytes(packed, sums, cl, reused) if fin else 0,
        "seconds": time.perf_counter() - t0,
    }
    verification = None
    if verified:  # the image is fixed: now the coefficients, then the tags' aggregate (verify.py)
        verification = tag_aggregate(
            ev,
            camera,
            rays,
            spec.sampling,
            spec.step,
            plan.weight_digits,
            plan.channel,
            tile,
            n_tiles,
            backend,
            cl,
            progress,
            exponent=plan.exponent,
        )
        stats["verify_s"] = verification.server_s
        stats["seconds"] = time.perf_counter() - t0
    log.info("render %s/%s %dx%d: %s", spec.mode, spec.sampling, W, H, stats)
    return EncryptedImage(
        ciphertexts=list(packed), stats=stats, verification=verification, **with_colouring(fields, spec)
    )


def _image_from(parts: list, finish: FinishGraph, fields: dict, stats: dict, nested: bool = False) -> EncryptedImage:
    """The last task of a deferred render (``compute=False``): the finished units as an image
    (``nested``: ``parts`` are reduce blocks' lists of units)."""
    packed = finish.assemble([p for block in parts for p in block] if nested else parts)
    stats = dict(stats, finish_tasks=len(parts), gathered_bytes=sum(int(p.nbytes) for p in packed), seconds=None)
    return EncryptedImage(ciphertexts=list(packed), stats=stats, **fields)


def _deferred(fin: list, finish: FinishGraph, fields: dict, stats: dict, nested: bool = False) -> Delayed:
    """A ``Delayed`` of the image: one more task over the finishing tasks (tile-sized outputs)."""
    return delayed(_image_from, pure=True)(
        fin, finish, fields, stats, nested, dask_key_name=f"hevr-image-{uuid.uuid4().hex}"
    )
