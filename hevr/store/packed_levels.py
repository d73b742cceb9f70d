"""Pyramid levels of a packed store, encrypted by the owner (``encrypt_volume(..., layout="packed", levels=L)``).

The server builds a per-voxel store's pyramid from its ciphertexts (:mod:`hevr.store.pyramid`); it
cannot build a packed store's: a level's pack holds S_L voxels of the level, each the mean of 8
children that sit in other slots (and other packs) of the level below, and Paillier cannot move a
value from one slot to another. So the owner, who has the plaintext, encrypts each level packed,
in the same run as level 0 (about 1/7 more ciphertexts for all levels together).

Level L's values follow the per-voxel pyramid's rule (:mod:`hevr.volume.pyramid`): the mean of the
2×2×2 children of level L − 1, edges clamped, i.e. ``v_L = downsample(v, L)``, stored at the
per-voxel level's exponent ``e_L = e − 3L``:

    m_L = rint(v_L · 10^(−e_L))

An integer volume (e = 0) gets exactly the per-voxel pyramid's mantissas, 125^L · Σ of its 8^L
leaves, computed in integers; a float volume the level's mean of the plaintext rounded to
``digits + 3L`` digits (the per-voxel pyramid averages the rounded level-0 mantissas instead), so
``render_plain(..., level=L, slices=True)`` is the reference and ``error_bound`` at the level's
exponent bounds the rounding. Each level is packed along the store's axis with a
:class:`~hevr.store.packing.PackingInfo` of its own, chosen from public parameters only as level
0's is (:func:`~hevr.store.packing.choose_packing` on the level's shape and the mantissa range of
``value_range`` at ``e_L``: its span is 1000^L times level 0's, so K grows by about 10 − 1 bits per
level and S shrinks), and bricked as level 0 with its packing-axis edge rounded up to a multiple of
S_L. A verifiable store gets one tag per packed ciphertext of the level,

    E(α·P_L[A] + β),   β = betas(key, store_id, "scalar", L, 0, A)

at the pack's flat index A in the level's packed array: the level's own PRF values (not the
per-voxel pyramid's 125·Σ children's, which the server derives). The levels' layouts are recorded in
the metadata (``levels[L − 1].layout``) and bound by the owner's MAC (``level_layouts``,
:mod:`hevr.store.authenticity`). Arrays, digests (over ``levels/L/<channel>``) and markers are a
per-voxel level's; a level is marked complete once its bricks are written, and ``resume=True``
finishes the bricks without markers.

>>> from hevr.store.metadata import ChannelInfo
>>> level_values(np.array([[[0.375, 0.5]]]), ChannelInfo(-5, 5)).tolist()   # level 1 of a 2-digit channel
[[[37500.0, 50000.0]]]
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import dask
import dask.array
import gmpy2
import numpy as np
import zarr

from ..backends import CpuBackend, get_backend
from ..core.files import fs_errors
from ..crypto.tags import betas, raw_tags, tag_channel, tag_key_of
from ..errors import ParameterError
from ..runtime import stats
from ..runtime.scheduler import compute
from ..volume.pyramid import MAX_LEVELS, level_brick, level_shape
from .authenticity import authenticate
from .brick_crypto import encrypt_components
from .digests import brick_digest, marker, written
from .layout import array_layout, array_slices, compressors, store_array
from .metadata import ChannelInfo, LevelInfo, VolumeMetadata
from .packed_brick import packed_parts
from .packing import choose_packing, mantissa_range, pack_columns
from .paths import document_digest, token, zarr_store
from .pyramid import build_pyramid, level_arrays_ok, write_meta  # noqa: F401 - build_pyramid: hevr.store.writer

log = logging.getLogger(__name__)

__all__ = ["check_levels", "encrypt_levels", "level_values", "plan_levels", "prepare_levels"]

_CPU = CpuBackend()  # the tags' records
_MAX_DIGITS = 30  # hevr.core.validate.MAX_STORE_DIGITS


def check_levels(levels: Any) -> int:
    """``levels=`` of :func:`hevr.encrypt_volume`: an int in [0, MAX_LEVELS].

    >>> check_levels(2)
    2
    """
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or not 0 <= levels <= MAX_LEVELS:
        raise ParameterError(f"levels: expected an int in [0, {MAX_LEVELS}] (pyramid levels), got {levels!r}")
    return int(levels)


def plan_levels(meta: VolumeMetadata, levels: int) -> tuple[LevelInfo, ...]:
    """The layouts of a packed store's levels 1 … ``levels`` (shape, brick, packing; no arrays yet),
    from public parameters only; :class:`hevr.ParameterError` when a level's slots do not fit."""
    info0, sc = packed_parts(meta)
    if sc.digits is not None and sc.digits + 3 * levels > _MAX_DIGITS:
        raise ParameterError(
            f"levels: expected at most {(_MAX_DIGITS - sc.digits) // 3} levels for a channel of "
            f"{sc.digits} digits (each level adds 3), got {levels}"
        )
    bits = int(meta.n).bit_length()
    out: list[LevelInfo] = []
    for level in range(1, levels + 1):
        shape = level_shape(meta.shape, level)
        try:
            packing = choose_packing(
                bits, shape, info0.axis, mantissa_range(meta.value_range, sc.exponent - 3 * level), info0.weight_bits
            )
        except ParameterError as exc:
            raise ParameterError(
                f"levels: expected at most {level - 1} levels for this key and value range (level "
                f"{level}'s values carry 3 more digits each: {exc})"
            ) from None
        b0, b1, b2 = (
            -(-b // packing.slots) * packing.slots if i == packing.axis else b
            for i, b in enumerate(level_brick(meta.brick, level))
        )
        out.append(LevelInfo(level, shape, (b0, b1, b2), False, {}, packing))
    return tuple(out)


def prepare_levels(
    path: str, meta: VolumeMetadata, wanted: tuple[LevelInfo, ...], key: Any, so: dict[str, Any] | None
) -> VolumeMetadata:
    """Record the levels ``wanted`` (:func:`plan_levels`; none: nothing to do) in the store at ``path``,
    incomplete, their arrays created, unless they are there with the same layout and arrays (a
    resume); levels recorded beyond them are kept. Writes the metadata (and its OME attribute)
    only when something changed; returns it."""
    levels = list(meta.levels)
    changed = False
    for want in wanted:
        i = want.level - 1
        if (
            i < len(levels)
            and levels[i].packing == want.packing
            and levels[i].brick == want.brick
            and level_arrays_ok(path, levels[i], so)
        ):
            continue
        lmeta = dataclasses.replace(meta, shape=want.shape, brick=want.brick, packing=want.packing, levels=())
        layout = array_layout(lmeta)
        with fs_errors("creating a pyramid level of the store", path):
            group = (
                zarr.open_group(zarr_store(path, so), mode="r+").require_group("levels").require_group(str(want.level))
            )
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
        digests = {name: document_digest(path, f"levels/{want.level}/{name}", so) for name in layout}
        levels = levels[:i] + [dataclasses.replace(want, complete=False, arrays=digests)]  # levels above: again
        changed = True
    if changed:
        meta = authenticate(dataclasses.replace(meta, levels=tuple(levels)), key)
        write_meta(path, meta, so)
    return meta


def level_values(means: np.ndarray, scalar: ChannelInfo) -> np.ndarray:
    """A float volume's level mantissas: the level's means rounded at the level channel's digits
    (``digits + 3·level``; NumPy's ``rint``, as level 0's :func:`~hevr.store.quantise.quantise_scalar`)."""
    digits = 0 if scalar.digits is None else scalar.digits  # an integer channel: whole values
    out: np.ndarray = np.rint(np.asarray(means, np.float64) * 10.0**digits)
    return out


def _level_array(darr: Any, meta: VolumeMetadata, info: LevelInfo) -> Any:
    """The dask array of level ``info.level`` chunked by its bricks: an integer volume's exact
    125^L·Σ of (m − offset) over the leaves, a float volume's means (float64), 2×2×2 children
    at a time, the last voxel of an odd axis repeated (:func:`hevr.volume.pyramid.downsample`)."""
    packing, scalar = packed_parts(meta)
    integer = scalar.digits is None
    if integer:  # slot values of level 0, exact in int64 (two's complement: uint64 too)
        off = packing.offset

        def shift(b: np.ndarray) -> np.ndarray:
            if b.dtype == np.uint64:
                return (b - np.uint64(off % 2**64)).view(np.int64)
            return b.astype(np.int64) - np.int64(off)

        x = darr.map_blocks(shift, dtype=np.int64)
    else:
        x = darr.astype(np.float64)
    for _ in range(info.level):
        x = dask.array.pad(x, [(0, s % 2) for s in x.shape], mode="edge")
        x = x.rechunk(tuple(2 * b for b in info.brick))
        x = dask.array.coarsen(np.sum, x, {0: 2, 1: 2, 2: 2})
        x = x * 125 if integer else x / 8.0
    return x.rechunk(info.brick)


def _encrypt_level_brick(
    block: np.ndarray,
    path: str,
    level: int,
    index: tuple[int, int, int],
    meta_dict: dict[str, Any],
    delta: int,
    key: Any,
    unsafe_no_obfuscation: bool,
    backend: str,
    storage_options: dict[str, Any] | None,
) -> tuple[int, int, int]:
    """One task: brick ``index`` of level ``level`` packed, encrypted and written with its tags and marker."""
    with fs_errors("writing a brick of a pyramid level", path):
        base = VolumeMetadata.from_dict(meta_dict)
        meta = base.level_meta(level)
        info, scalar = packed_parts(meta)
        if scalar.digits is None:  # 125^L·Σ(m − offset_0) + 1000^L·offset_0 − offset_L
            u = np.asarray(block, np.int64) + np.int64(delta)
        else:
            lo, hi = mantissa_range(meta.value_range, scalar.exponent)
            u = (np.clip(level_values(block, scalar), lo, hi) - lo).astype(np.int64)
        plain = pack_columns(u, dataclasses.replace(info, offset=0))
        shape, width, prefix = plain.shape, meta.ciphertext_bytes, f"levels/{level}/"
        out = encrypt_components(
            get_backend(backend), key, [plain.ravel().tolist()], shape, width, unsafe_no_obfuscation
        )[0]
        digests = [brick_digest(meta.store_id, prefix + "scalar", index, out)]
        sl = array_slices(meta, index)
        group = zarr.open_group(zarr_store(path, storage_options), mode="r+")
        with stats.timed("encrypt.write"):
            store_array(group, prefix + "scalar")[sl] = out
        if meta.tags:
            tk = tag_key_of(key)
            packs = np.ravel_multi_index(
                np.meshgrid(*(np.arange(s.start, s.stop) for s in sl), indexing="ij"), info.array_shape(meta.shape)
            ).reshape(-1)
            with stats.timed("encrypt.tags", len(packs)):
                plain_tags = raw_tags(
                    tk, [int(p) % tk.n for p in plain.ravel()], betas(tk, meta.store_id, "scalar", level, 0, packs)
                )
                tags = key.owner.encrypt_residues(gmpy2.mpz(t) for t in plain_tags)
            rec = _CPU.to_bytes(tags, width).reshape(shape + (width,))
            digests.append(brick_digest(meta.store_id, prefix + tag_channel("scalar"), index, rec))
            with stats.timed("encrypt.write"):
                store_array(group, prefix + tag_channel("scalar"))[sl] = rec
        store_array(group, prefix + "done")[index] = marker(digests)
    return index


def encrypt_levels(
    vol: Any,
    brick: tuple[int, int, int],
    path: str,
    meta: VolumeMetadata,
    key: Any,
    unsafe_no_obfuscation: bool,
    backend: str,
    client: Any,
    progress: bool,
    storage_options: dict[str, Any] | None,
    counted: int = 0,
) -> tuple[VolumeMetadata, int]:
    """Encrypt the bricks without markers of every recorded level of the packed store at ``path``,
    whose level 0 is complete (one impure task per brick, all levels in one graph), then mark the
    levels complete; returns the metadata and ``counted`` plus the packed ciphertexts encrypted
    (tags not counted). A per-voxel store's levels are the server's (:func:`hevr.build_pyramid`)."""
    if meta.packing is None or not meta.levels:
        return meta, counted
    so, meta = storage_options, dataclasses.replace(meta, complete=True)
    group = zarr.open_group(zarr_store(path, so, read_only=True), mode="r")
    darr = (
        vol
        if isinstance(vol, dask.array.Array)
        else dask.array.from_array(vol, chunks=brick, name=f"hevr-plain-{token()}{token()}")
    )  # a random name: never a hash of the voxels
    darr = darr.rechunk(brick)
    task = dask.delayed(_encrypt_level_brick, pure=False)
    meta_dict, tasks, values = meta.to_dict(), [], 0
    for info in meta.levels:
        if info.complete and level_arrays_ok(path, info, so):
            continue
        lmeta = meta.level_meta(info.level)
        done = written(store_array(group, f"levels/{info.level}/done")[...])
        todo = [(int(z), int(y), int(x)) for z, y, x in np.ndindex(*lmeta.grid) if not done[z, y, x]]
        log.info("packed level %d: %d of %d bricks to encrypt", info.level, len(todo), lmeta.n_bricks)
        if not todo:
            continue
        blocks = _level_array(darr, meta, info).to_delayed()
        delta = (1000**info.level) * packed_parts(meta)[0].offset - packed_parts(lmeta)[0].offset
        for idx in todo:
            tasks.append(
                task(
                    blocks[idx],
                    path,
                    info.level,
                    idx,
                    meta_dict,
                    delta,
                    key,
                    unsafe_no_obfuscation,
                    backend,
                    so,
                    dask_key_name=f"hevr-encrypt-{meta.fingerprint[:8]}-L{info.level}-"
                    f"{idx[0]}-{idx[1]}-{idx[2]}-{token()}",
                )
            )
            values += int(np.prod([s.stop - s.start for s in array_slices(lmeta, idx)]))
    if tasks:
        compute(tasks, client=client, progress=progress, desc="encrypt levels", steps=values, unit="ciphertexts")
    group = zarr.open_group(zarr_store(path, so, read_only=True), mode="r")
    infos = tuple(
        dataclasses.replace(info, complete=True)
        if written(store_array(group, f"levels/{info.level}/done")[...]).all()
        else info
        for info in meta.levels
    )
    if infos != meta.levels:
        meta = authenticate(dataclasses.replace(meta, levels=infos), key)
        write_meta(path, meta, so)
    return meta, counted + values
