"""The render of one view of a per-voxel store: the Dask graph of one frame or slice, run and finished.

:func:`render_view` is :func:`hevr.render`'s work for a :class:`~hevr.rendering.geometry.camera.Camera`
and :func:`hevr.render_slice`'s for a :class:`~hevr.rendering.geometry.plane.Plane` (a packed store's
frames are :mod:`hevr.rendering.packed`'s): the request checked once
(:mod:`hevr.rendering.planning.request`), the plan, one graph map -> tree merge -> finish
(:mod:`hevr.rendering.pipeline`), the ray sums kept for re-colouring (:mod:`hevr.rendering.pipeline.cache`, a
``.hevrsums`` file) and, for a verifiable store, the tags' aggregate (:mod:`hevr.rendering.verify`).
"""

from __future__ import annotations

import logging
import os
import time
import uuid
from typing import TYPE_CHECKING, Any, cast

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
from .pipeline import cache as render_cache
from .pipeline.graph import FinishGraph, build_sums_graph
from .pipeline.maps import resident_groups
from .pipeline.reduce import BlockedReduce
from .pipeline.sums import RaySums, image_fields, with_colouring
from .pipeline.sums_file import check_sums_path, save_sums
from .planning.modes import combination_matrix
from .planning.planner import check_render_size, plan_render
from .planning.request import at_level, check_request, level_step
from .verify import resolve_verify, tag_aggregate

if TYPE_CHECKING:
    from ..remote.volume import RemoteVolume

log = logging.getLogger(__name__)

__all__ = ["BAND_BITS", "RESIDENT_BATCH_KEY", "render_view"]


def _gathered_bytes(packed: list[Any], sums: RaySums, client: Any, reused: bool) -> int:
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


def render_view(
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
    keep_sums: str | os.PathLike[str] | None,
    views: tuple[type, ...] = (Camera,),
    level: int | None = None,
    gradient: bool = False,
    overwrite: bool = False,
    finish: str = "client",
    stream: Any = None,
    verify: bool | str | None = None,
) -> EncryptedImage | Delayed:
    """:func:`hevr.render`'s work for a view of the kinds ``views``; a plane's ``step`` is its ``slab_step``.

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
        return cast("RemoteVolume", ev).render_request(
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
    comb = None
    if spec.needs_vector and finish == "server":
        assert ev.vector_dims is not None  # check_request: a store with the vector channel
        comb = combination_matrix(spec, ev.vector_dims)
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
    sums = render_cache.cached(key, cl) if cache else None
    reused = sums is not None
    finishing = FinishGraph.plan_units(plan, layout, rays.n_samples, int(ev.public_key.n), backend)

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
        stream.start(finishing, fields)
        on_unit = stream.unit
    if sums is None:
        # One graph: map -> tree merge -> finish, so merged sums never travel through the client.
        # When they are cached they stay where they are: futures on a cluster (re-colouring
        # then runs next to them), values on a single machine.
        batch = resident is not None and _batch(int(ev.public_key.n).bit_length(), backend)
        groups = resident_groups(resident, cl, backend) if resident is not None and batch else None
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
            red = BlockedReduce(graph, finishing, len(groups))
            fin, kept, on_result = red.unit_tasks(), red.block_tasks() if keep else [], red.on_block(on_unit)
        else:
            red, fin, on_result = None, finishing.tasks({t: graph.delayed(t) for t in graph.merged}), on_unit
            live = [t for t, d in graph.merged.items() if d is not None] if keep else []
            kept = [graph.delayed(t) for t in live]
        map_tasks = graph.map_tasks
        if not compute:
            return _deferred(
                fin,
                finishing,
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
        packed = finishing.assemble(units)
        sums = RaySums(key, dict.fromkeys(range(n_tiles)), map_tasks, cl, backend=backend)
        if plan.finish == "client":  # copies: the image's arrays are the caller's to change
            sums.packed[plan] = [u.copy() for u in units]
        if red is not None:
            sums.tiles.update(red.sums(results[len(fin) :], cl) if kept else {})
        else:
            sums.tiles.update(dict(zip(live, results[len(fin) :])))
        if cache:
            render_cache.keep(key, sums)
    elif compute and plan in sums.packed:  # finished on the client: the same packed sums for any colouring
        fin = []
        units = [u.copy() for u in sums.packed[plan]]
        for i, unit in enumerate(units):
            if on_unit is not None:
                on_unit(i, unit)
        packed = finishing.assemble(units)
    else:
        fin = finishing.tasks(sums.tiles)
        if not compute:
            return _deferred(
                fin,
                finishing,
                fields,
                {"map_tasks": 0, "reused_ray_sums": True, "backend": backend, "resident": resident is not None},
            )
        units = run_tasks(fin, client=cl, progress=False, desc="finish", on_result=on_unit)
        packed = finishing.assemble(units)
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


def _image_from(
    parts: list[Any], finish: FinishGraph, fields: dict[str, Any], stats: dict[str, Any], nested: bool = False
) -> EncryptedImage:
    """The last task of a deferred render (``compute=False``): the finished units as an image
    (``nested``: ``parts`` are reduce blocks' lists of units)."""
    packed = finish.assemble([p for block in parts for p in block] if nested else parts)
    stats = dict(stats, finish_tasks=len(parts), gathered_bytes=sum(int(p.nbytes) for p in packed), seconds=None)
    return EncryptedImage(ciphertexts=list(packed), stats=stats, **fields)


def _deferred(
    fin: list[Delayed], finish: FinishGraph, fields: dict[str, Any], stats: dict[str, Any], nested: bool = False
) -> Delayed:
    """A ``Delayed`` of the image: one more task over the finishing tasks (tile-sized outputs)."""
    return delayed(_image_from, pure=True)(
        fin, finish, fields, stats, nested, dask_key_name=f"hevr-image-{uuid.uuid4().hex}"
    )
