"""The encrypted multi-resolution pyramid, computed by the server from the store alone (no key).

A voxel of level L+1 is the average of its 2×2×2 children of level L, edges clamped
(:mod:`hevr.volume.pyramid` has the definition and the geometry). On ciphertexts, with
``c_1 … c_8`` the children (a clamped child counted twice),

    C = (c_1 · c_2 ⋯ c_8)^125  mod n²   decrypts to   125 · Σ m_i = mean · 10^3,

so the level's channels keep exact fixed point with exponent ``e − 3`` per level (no rounding,
no key, no new randomness: a level ciphertext is a public function of public ciphertexts and
reveals nothing new). Cost per coarse voxel and stored component: 7 products for the ⊕ and
about 11 for ⊗ 125 (6 squarings, 5 multiplications); a level has 1/8 of the voxels of the
level below, so a whole pyramid costs at most 18/7 ≈ 2.6 products per voxel and component of
level 0 — a few percent of encryption, which costs two fixed-base exponentiations per value.

Layout (docs/format.md, "Pyramid levels"): level L's arrays are ``levels/L/scalar``,
``levels/L/vector``, ``levels/L/gradient`` (every channel of the store) and ``levels/L/done``
with the bricks, codecs and digest markers of level 0 (:func:`hevr.volume.pyramid.level_brick`
says why the bricks do not shrink) (digests over the channel name ``levels/L/<channel>``, so no
brick can pass for one of another level); the checksummed ``hevr`` attribute lists each level (shape, completeness,
array-document digests) and the group's ``ome`` attribute mirrors it as OME-Zarr
``multiscales``. :func:`build_pyramid` is one Dask task per brick of a level, level after
level, and resumable: bricks whose digest marker exists are not recomputed. Each task reads
the child bricks one at a time (every read checks its digest), multiplies each coarse voxel's
children inside the child brick, then merges those partial products: memory stays a few bricks.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import dask
import numpy as np
import zarr

from ..backends import get_backend, resolve_backend_name
from ..crypto.tags import data_channel
from ..errors import ParameterError, StoreError
from ..runtime.scheduler import active_client, compute
from ..volume.pyramid import MAX_LEVELS, level_brick, level_shape
from .digests import brick_digest, marker, written
from .layout import compressors, store_array
from .metadata import LevelInfo, VolumeMetadata, ome_attribute
from .paths import check_reachable, document_digest, zarr_store
from .reader import EncryptedVolume, array_layout, brick_slices, open_volume

log = logging.getLogger(__name__)

__all__ = ["build_pyramid", "LEVEL_FACTOR", "level_arrays_ok", "write_meta"]

LEVEL_FACTOR = 125  # 10^3 / 8: the ⊗ that turns a sum of 8 children into their mean at exponent e − 3
_MAX_DIGITS = 30  # hevr.core.validate.MAX_STORE_DIGITS: the most decimal digits a channel's metadata holds


def _children(shape_below: tuple[int, ...], coarse: tuple[slice, slice, slice]) -> np.ndarray:
    """Level-below voxel coordinates (M, 8, 3) of the children of every coarse voxel of the slices
    (C order), clamped at the last voxel of each axis.

    >>> _children((3, 1, 1), (slice(1, 2), slice(0, 1), slice(0, 1)))[0, :, 0].tolist()
    [2, 2, 2, 2, 2, 2, 2, 2]
    """
    axes = np.meshgrid(*[np.arange(s.start, s.stop) for s in coarse], indexing="ij")
    base = np.stack([a.ravel() for a in axes], axis=1) * 2  # (M, 3)
    offs = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)])  # (8, 3): z, y, x bits
    out: np.ndarray = np.minimum(base[:, None, :] + offs[None, :, :], np.asarray(shape_below) - 1)
    return out


def _level_brick(
    below: EncryptedVolume, path: str, level: int, index: tuple[int, int, int], meta: VolumeMetadata, backend: str
) -> tuple[int, int, int]:
    """One task: the brick ``index`` of ``level`` from the level below, written with its marker."""
    be = get_backend(backend)
    n2 = int(below.public_key.nsquare)
    width = meta.ciphertext_bytes
    sl = brick_slices(meta, index)
    bshape = tuple(s.stop - s.start for s in sl)
    kids = _children(below.shape, sl).reshape(-1, 3)  # (8M, 3)
    owner = np.repeat(np.arange(kids.shape[0] // 8), 8)  # coarse voxel of each child entry
    bb = np.asarray(below.brick)
    kid_brick = kids // bb
    group = zarr.open_group(zarr_store(path, below.storage_options), mode="r+")
    prefix = f"levels/{level}/"
    digests = []
    for channel in meta.channel_names:
        K = meta.components(channel)
        parts: list[np.ndarray] = []  # per child brick: (rows, K, W) partial products, with their owners
        owners: list[np.ndarray] = []
        for child in map(tuple, np.unique(kid_brick, axis=0).tolist()):  # at most 8 child bricks
            mine = np.flatnonzero((kid_brick == child).all(axis=1))
            data = below.read_brick_bytes(child, channel)  # digest checked
            recs = data.reshape((1,) + data.shape) if data_channel(channel) == "scalar" else data  # (K, bz, by, bx, W)
            csl = below.brick_slices(child)
            local = kids[mine] - np.array([s.start for s in csl])
            who = owner[mine]  # sorted: children were listed coarse voxel by coarse voxel
            starts = np.flatnonzero(np.r_[True, who[1:] != who[:-1]])
            rows = recs[:, local[:, 0], local[:, 1], local[:, 2]]  # (K, entries, W)
            rows = np.ascontiguousarray(rows.transpose(1, 0, 2)).reshape(-1, width)  # entry-major, K per row
            vals = be.segment_products(be.from_bytes(rows), np.r_[starts, who.size], K, n2)
            parts.append(be.to_bytes(vals, width).reshape(-1, K, width))
            owners.append(who[starts])
        who = np.concatenate(owners)
        order = np.argsort(who, kind="stable")
        who = who[order]
        rows = np.concatenate(parts)[order].reshape(-1, width)
        starts = np.flatnonzero(np.r_[True, who[1:] != who[:-1]])
        sums = be.segment_products(be.from_bytes(rows), np.r_[starts, who.size], K, n2)
        means = be.combine(sums, [[LEVEL_FACTOR]], n2)  # each value ⊗ 125 (rows of one value)
        out = be.to_bytes(means, width).reshape(bshape + (K, width))
        out = out[..., 0, :] if data_channel(channel) == "scalar" else np.moveaxis(out, 3, 0)
        out = np.ascontiguousarray(out)
        digests.append(brick_digest(meta.store_id, prefix + channel, index, out))
        store_array(group, prefix + channel)[sl if data_channel(channel) == "scalar" else (slice(None),) + sl] = out
    store_array(group, prefix + "done")[index] = marker(digests)
    return index


def _done(path: str, level: int, so: dict[str, Any] | None) -> Any:
    """The digest markers of level ``level`` of the store at ``path``, read now."""
    return store_array(zarr.open_group(zarr_store(path, so, read_only=True), mode="r"), f"levels/{level}/done")[...]


def write_meta(path: str, meta: VolumeMetadata, so: dict[str, Any] | None) -> None:
    """Record ``meta`` (and its OME attribute) — only over the same store (its id on disk)."""
    group = zarr.open_group(zarr_store(path, so), mode="r+")
    attr = dict(group.attrs).get("hevr")
    on_disk = attr.get("store_id") if isinstance(attr, dict) else None
    if on_disk != meta.store_id:
        raise StoreError(
            f"ev: the store at {path} was replaced while its pyramid was being built (store id "
            f"{on_disk!r}, expected {meta.store_id!r}); nothing was written; open it again"
        )
    group.attrs.update({"hevr": meta.to_dict(), "ome": ome_attribute(meta)})


def level_arrays_ok(path: str, info: LevelInfo, so: dict[str, Any] | None) -> bool:
    """Whether level ``info``'s arrays are all there with the documents its metadata pins."""
    try:
        return all(
            document_digest(path, f"levels/{info.level}/{name}", so) == want for name, want in info.arrays.items()
        )
    except (OSError, ValueError, KeyError):
        return False


def _start_level(path: str, meta: VolumeMetadata, level: int, so: dict[str, Any] | None) -> VolumeMetadata:
    """Create level ``level``'s arrays (if not there from an interrupted run, or gone since) and
    record them, the level incomplete."""
    if len(meta.levels) >= level and level_arrays_ok(path, meta.levels[level - 1], so):
        return meta
    shape, brick = level_shape(meta.shape, level), level_brick(meta.brick, level)
    layout = array_layout(dataclasses.replace(meta, shape=shape, brick=brick, levels=()))
    group = zarr.open_group(zarr_store(path, so), mode="r+").require_group("levels").require_group(str(level))
    for name, (ashape, chunks) in layout.items():
        group.create_array(
            name,
            shape=ashape,
            chunks=chunks,
            dtype="uint8",
            compressors=compressors(name),
            fill_value=0,
            overwrite=True,
        )
    digests = {name: document_digest(path, f"levels/{level}/{name}", so) for name in layout}
    info = LevelInfo(level, shape, brick, False, digests)
    meta = dataclasses.replace(meta, levels=meta.levels[: level - 1] + (info,))  # levels above it are rebuilt too
    write_meta(path, meta, so)
    return meta


def build_pyramid(
    ev: EncryptedVolume | str,
    levels: int = 1,
    *,
    client: Any = None,
    progress: bool = True,
    backend: str | None = None,
    storage_options: dict[str, Any] | None = None,
) -> EncryptedVolume:
    """Add pyramid levels 1 … ``levels`` to an encrypted store, on the cluster, without a key.

    Parameters
    ----------
    ev : EncryptedVolume or path
        A complete store (:func:`hevr.open_volume`).
    levels : int
        Build up to this level (1 … 8); levels already complete are kept, an interrupted level
        is finished (only its missing bricks are computed).
    client : distributed.Client, optional
        Default: the active client, else Dask's default scheduler. One task per brick of a level.
    progress : bool
    backend : str, optional
        Arithmetic backend (:mod:`hevr.backends`).
    storage_options : dict, optional
        Options of a URL's fsspec filesystem; default: the handle's (``ev.storage_options``).

    Returns
    -------
    EncryptedVolume
        The store reopened; ``.levels`` complete levels, ``.at_level(L)`` and
        ``hevr.render(..., level=L)`` use them.
    """
    if isinstance(ev, EncryptedVolume) and ev.level:
        raise ParameterError(f"ev: expected a store (level 0), got a view of pyramid level {ev.level}")
    if storage_options is None and isinstance(ev, EncryptedVolume):
        storage_options = ev.storage_options
    # never build from a stale handle
    fresh = open_volume(ev.path if isinstance(ev, EncryptedVolume) else ev, storage_options=storage_options)
    if isinstance(ev, EncryptedVolume) and fresh.meta.store_id != ev.meta.store_id:
        raise StoreError(
            f"ev: the store at {ev.path} was replaced since this handle was opened (store id "
            f"{fresh.meta.store_id}, the handle's {ev.meta.store_id}); open it again"
        )
    ev = fresh
    if ev.meta.packing is not None:
        raise ParameterError(
            f"ev: expected a per-voxel store, got the packed store {ev.meta.store_id}: the server "
            "cannot downsample across slots; a packed store's levels are encrypted by the owner with "
            "the volume: hevr.encrypt_volume(vol, path, key, layout='packed', levels=L) (hevr encrypt "
            "--layout packed --levels L)"
        )
    if isinstance(levels, bool) or not isinstance(levels, int) or not 1 <= levels <= MAX_LEVELS:
        raise ParameterError(f"levels: expected an int in [1, {MAX_LEVELS}], got {levels!r}")
    meta = ev.meta
    for ch in (meta.scalar, meta.vector, meta.gradient):
        if ch is not None and ch.digits is not None and ch.digits + 3 * levels > _MAX_DIGITS:
            raise ParameterError(
                f"levels: expected at most {(_MAX_DIGITS - ch.digits) // 3} levels for a channel of "
                f"{ch.digits} digits (each level adds 3), got {levels}"
            )
    backend = resolve_backend_name(backend, int(meta.n).bit_length(), client=active_client(client))
    path, so = ev.path, ev.storage_options
    check_reachable(path, active_client(client))
    for level in range(1, levels + 1):
        if (
            len(meta.levels) >= level
            and meta.levels[level - 1].complete
            and level_arrays_ok(path, meta.levels[level - 1], so)
        ):
            continue
        below = EncryptedVolume(path, meta, storage_options=so).at_level(level - 1)  # readable before anything starts
        meta = _start_level(path, meta, level, so)
        lmeta = meta.level_meta(level)
        done = written(_done(path, level, so))
        todo = [(int(z), int(y), int(x)) for z, y, x in np.ndindex(*lmeta.grid) if not done[z, y, x]]
        log.info("pyramid level %d: %d of %d bricks to compute", level, len(todo), lmeta.n_bricks)
        task = dask.delayed(_level_brick, pure=False)
        compute(
            [
                task(
                    below,
                    path,
                    level,
                    idx,
                    lmeta,
                    backend,
                    dask_key_name=f"hevr-pyramid-{meta.store_id}-{level}-{idx[0]}-{idx[1]}-{idx[2]}",
                )
                for idx in todo
            ],
            client=client,
            progress=progress,
            desc=f"pyramid level {level}",
        )
        if not written(_done(path, level, so)).all():  # pragma: no cover
            raise StoreError(f"ev: level {level} of {path} still has missing bricks")
        infos = list(meta.levels)
        infos[level - 1] = dataclasses.replace(infos[level - 1], complete=True)
        meta = dataclasses.replace(meta, levels=tuple(infos))
        write_meta(path, meta, so)
    return open_volume(path, storage_options=so)
