"""Encrypted ray sums that outlive a render: the in-memory cache entry, the ``.hevrsums`` file,
and re-colouring from either.

The map and merge steps of a render produce, per image tile, the merged encrypted ray sums of
every stored component (scalar: one per ray; vector: k per ray). Everything after them — the
combination matrix of an emphasis density or a transfer function, Eq. 1's normalisation, the
offset and packing (:mod:`hevr.rendering.pipeline.finishing`) — depends only on these sums and public
numbers. So another density or transfer function on the same view needs no map step: the
sums are kept in memory (:class:`RaySums`, the render cache) or in a file
(``hevr.render(..., keep_sums=PATH)``, ``hevr render --keep-sums``), and :func:`recolour`
redoes only the finishing. The result is bit for bit the image a full render with the new
parameters gives.

The file (``.hevrsums``) is :mod:`hevr.rendering.pipeline.sums_file`.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...backends import resolve_backend_name
from ...colour import Colouring
from ...core.files import read_regular
from ...core.validate import check_choice, check_int
from ...errors import (
    CorruptStoreError,
    MissingFileError,
    ParameterError,
)
from ...image.checks import FINISHES
from ...image.encrypted import EncryptedImage
from ...image.tiles import TileLayout
from ...runtime.scheduler import active_client
from ...runtime.scheduler import compute as run_tasks
from ...store.metadata import VolumeMetadata
from ...store.paths import (
    check_storage_options,
    is_local,
    normalise,
    read_bytes,
)
from ..geometry.camera import Camera
from ..geometry.plane import Plane
from ..geometry.rays import cast_rays
from ..planning.modes import RenderSpec, combination_matrix, make_spec
from ..planning.planner import RenderPlan, check_render_size, plan_render
from .graph import BlockSums, FinishGraph, block_sums
from .sums_file import read_sums

log = logging.getLogger(__name__)

__all__ = ["RaySums", "SavedSums", "image_fields", "load_sums", "recolour", "with_colouring"]


@dataclass
class RaySums:
    """Merged encrypted per-component ray sums of one view, per tile (reusable).

    On a distributed client ``tiles`` holds futures: the sums stay on the workers that
    merged them, and re-colouring runs its finishing tasks there (no sums cross the
    network); on a single machine it holds the values. ``packed`` keeps, per client-finished
    plan, the finishing units' outputs: the packed sums are the same for every colouring, so
    another density or transfer function on this view needs no task at all.
    """

    key: tuple[Any, ...]
    tiles: dict[int, Any]  # tile id -> (rays, records (R, C, W)), a future of it, or None
    map_tasks: int
    client: Any = None
    packed: dict[RenderPlan, list[np.ndarray]] = field(
        default_factory=dict
    )  # client-finished RenderPlan -> its units' (P, W) outputs
    backend: str = "cpu"  # the backend that computed them

    def usable(self, client: Any) -> bool:
        """Whether these sums can serve a render on ``client`` (futures are bound to theirs)."""
        return client is self.client and (client is None or client.status == "running")

    def values(self) -> dict[int, Any]:
        """Tile id -> ``(rays, records)`` or None, gathered from the workers if they hold them
        (a tile's future, or the future of the reduce block holding it: :class:`BlockSums`)."""
        live = {t: v for t, v in self.tiles.items() if v is not None}
        if self.client is not None and live:
            futures = {t: v.block if isinstance(v, BlockSums) else v for t, v in live.items()}
            unique = list({f.key: f for f in futures.values()}.values())
            got = dict(zip((f.key for f in unique), self.client.gather(unique)))
            live = {
                t: block_sums(got[futures[t].key], v.tile) if isinstance(v, BlockSums) else got[futures[t].key]
                for t, v in live.items()
            }
        return {t: live.get(t) for t in self.tiles}


@dataclass(frozen=True)
class SavedSums:
    """The ray sums of one view as read from a ``.hevrsums`` file, checked.

    ``tiles`` maps every tile id to ``(rays (R,) int64, records (R, K, width) uint8)``, or to
    None for a tile no brick touches.
    """

    meta: VolumeMetadata
    camera: Camera | Plane
    sampling: str
    step: float
    weight_digits: int
    channel: str
    tile: int
    tiles: dict[int, tuple[np.ndarray, np.ndarray] | None]
    store: str
    level: int
    path: str


def image_fields(
    spec: RenderSpec,
    plan: RenderPlan,
    camera: Camera | Plane,
    n_samples: np.ndarray,
    meta: VolumeMetadata,
    tile: int,
    level: int = 0,
) -> dict[str, Any]:
    """Everything of an :class:`EncryptedImage` but its ciphertexts and stats (render and recolour).

    A client-finished plan (``plan.finish == "client"``) gives fields without the mode, the density
    and the nodes (they stay with the caller: :func:`with_colouring`), the pixel grid (H, W) as the
    shape, and the public sample counts the client divides by."""
    H, W = camera.height, camera.width
    client = plan.finish == "client"
    colouring = (
        {"channel": plan.channel}
        if client
        else {
            "mode": spec.mode,
            "density": spec.density,
            "nodes": [[d, list(c)] for d, c in spec.nodes] if spec.nodes else None,
        }
    )
    counts = np.asarray(n_samples).reshape(H, W)
    return dict(
        shape=(H, W) if client else spec.image_shape(H, W),
        exponent=plan.exponent,
        offset=plan.offset,
        fingerprint=meta.fingerprint,
        n=int(meta.n),
        tile=tile,
        pack_bits=plan.pack_bits,
        per_pack=plan.per_pack,
        hits=counts > 0,
        bound=plan.bound,
        finish=plan.finish,
        channel=plan.channel,
        components=plan.channels_out,
        samples=counts.astype(np.int64) if client else None,
        info={
            "sampling": spec.sampling,
            "step": spec.step,
            **colouring,
            "store": meta.store_id,
            "tags": bool(meta.tags),
            "camera": camera.to_dict(),
            "plan": plan.to_dict(),
            "finish": plan.finish,
            **({"gradient": True} if spec.gradient else {}),
            **({"level": level} if level else {}),
        },
    )  # a level's camera is in the level's frame


def with_colouring(fields: dict[str, Any], spec: RenderSpec) -> dict[str, Any]:
    """The fields of the image returned in this process: a client-finished one gets the request's
    :class:`~hevr.colour.Colouring` and the shape it colours to ((H, W, 3) for a transfer
    function); neither is ever in a task, a file or a log."""
    if fields["finish"] != "client":
        return dict(fields, colouring=None)
    return dict(fields, colouring=Colouring.of(spec), shape=spec.image_shape(*fields["shape"][:2]))


def load_sums(path: str | os.PathLike[str], *, storage_options: dict[str, Any] | None = None) -> SavedSums:
    """Read and check a ``.hevrsums`` file (module docstring: checksum, header, sizes, ranges);
    ``path`` may be an fsspec URL, read with ``storage_options``."""
    what = "a ray-sums file (hevr.render(..., keep_sums=PATH))"
    path = normalise(path) if "://" in str(path) else path
    if not is_local(str(path)):
        where = str(path)
        try:
            blob = read_bytes(where, check_storage_options(storage_options))
        except FileNotFoundError:
            raise MissingFileError("sums", what, where) from None
        return SavedSums(**read_sums(blob, where))
    if Path(path).is_dir():
        raise ParameterError(
            f"sums: expected a ray-sums file (hevr.render(..., keep_sums=PATH)), got a folder ({path})"
        )
    # never blocks: a FIFO or a device is a NotRegularFileError before a byte is read
    return SavedSums(**read_sums(read_regular(path, "sums", what), str(path)))


def recolour(
    sums: SavedSums | str | os.PathLike[str],
    mode: str = "tf",
    density: float | None = None,
    nodes: Any = None,
    *,
    precision: int = 4,
    comb_digits: int = 4,
    pack: bool = True,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
    gradient: bool = False,
    finish: str = "client",
) -> EncryptedImage:
    """Finish saved ray sums with another density or transfer function: only the per-pixel step.

    Parameters
    ----------
    sums : SavedSums or path
        From :func:`load_sums`, or the path of a ``.hevrsums`` file.
    mode, density, nodes, precision, comb_digits, pack
        As for :func:`hevr.render`; the camera, sampling, step and weight digits are the sums'.
        ``emphasize`` and ``tf`` need sums of the vector channel, ``xray`` of the scalar one.
    client, progress, backend
        As for :func:`hevr.render`.
    gradient : bool
        ``emphasize`` / ``tf`` of sums of the gradient channel (a render with ``gradient=True``);
        sums of the vector channel need ``gradient=False``, and the other way round.
    finish : {"client", "server"}
        As for :func:`hevr.render`: ``"client"`` packs the saved sums for colouring at
        decryption (the density / nodes stay here); ``"server"`` finishes them on the workers.

    Returns
    -------
    EncryptedImage
        Bit for bit the image ``hevr.render`` gives for the same view and parameters.
    """
    if not isinstance(sums, SavedSums):
        sums = load_sums(sums)
    t0 = time.perf_counter()
    meta, camera = sums.meta, sums.camera
    spec = make_spec(
        mode,
        sums.sampling,
        sums.step,
        density,
        nodes,
        meta.vector.dims if meta.vector else None,
        meta.scalar is not None,
        gradient,
        meta.gradient is not None,
    )
    if spec.channel != sums.channel and {spec.channel, sums.channel} == {"vector", "gradient"}:
        raise ParameterError(
            f"gradient: expected sums of the {spec.channel} channel for gradient={spec.gradient}, got "
            f"the {sums.channel} channel's (rendered with gradient={not spec.gradient}; {sums.path}); "
            f"recolour them with gradient={not spec.gradient}"
        )
    if spec.channel != sums.channel:
        need = "an X-ray render" if spec.channel == "scalar" else "a render in mode 'emphasize' or 'tf'"
        raise ParameterError(
            f"sums: expected the {spec.channel} channel's sums ({need}) for mode {spec.mode!r}, "
            f"got the {sums.channel} channel's ({sums.path})"
        )
    precision = check_int("precision", precision, 0, 30)
    comb_digits = check_int("comb_digits", comb_digits, 1, 12)
    check_choice("finish", finish, FINISHES)
    backend = resolve_backend_name(backend, int(meta.n).bit_length(), client=active_client(client))
    checked = check_render_size(camera, meta.shape, meta.spacing, spec.step)
    rays = checked if checked is not None else cast_rays(camera, meta.shape, meta.spacing, spec.step)
    comb = None
    if spec.needs_vector and finish == "server":
        dims = meta.vector.dims if meta.vector is not None else None
        assert dims is not None  # make_spec: emphasis and transfer functions need the vector channel
        comb = combination_matrix(spec, dims)
    plan = plan_render(
        n=int(meta.n),
        spec=spec,
        meta=meta,
        n_samples=rays.n_samples,
        digits=sums.weight_digits if spec.sampling == "trilinear" else 0,
        precision=precision,
        comb_digits=comb_digits,
        pack=pack,
        combination=comb,
        finish=finish,
    )
    if plan.weight_digits != sums.weight_digits:  # the planner keeps the digits it is given; a guard
        raise CorruptStoreError(
            f"{sums.path}: expected weights of {plan.weight_digits} digits, got {sums.weight_digits}"
        )
    layout = TileLayout(camera.width, camera.height, sums.tile)
    finishing = FinishGraph.plan_units(plan, layout, rays.n_samples, int(meta.n), backend)
    fin = finishing.tasks(sums.tiles)
    packed = finishing.assemble(run_tasks(fin, client=active_client(client), progress=progress, desc="recolour"))
    stats = {
        "map_tasks": 0,
        "finish_tasks": len(fin),
        "reused_ray_sums": True,
        "resident": False,
        "gathered_bytes": sum(int(p.nbytes) for p in packed),
        "seconds": time.perf_counter() - t0,
    }
    fields = image_fields(spec, plan, camera, rays.n_samples, meta, sums.tile, level=sums.level)
    return EncryptedImage(ciphertexts=list(packed), stats=stats, **with_colouring(fields, spec))
