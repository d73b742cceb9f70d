"""A packed store's brick, written by its encryption task (:func:`hevr.encrypt_volume` with
``layout="packed"``; the slots: :mod:`hevr.store.packing`).

The brick's scalar mantissas (the per-voxel store's, :func:`~hevr.store.quantise.quantise_scalar`)
are packed S to a plaintext along the packing axis, encrypted (the key's path: the owner's with a
private key), written as the brick's chunk of the packed scalar array. With the vector channel
(``vector_dims=k``) the k components of the density encoding e(d) (the per-voxel store's mantissas,
:func:`~hevr.store.quantise.quantise_vector`, in [0, 10^digits]) are packed alike, with the same S
and K and offset 0, into the brick's chunk of the packed vector array (k, packs…). A verifiable
store then gets one tag per packed ciphertext and component, E(α·P + β) with β =
``betas(key, store_id, channel, 0, component, pack)`` of the pack's flat index in the packed array
(:mod:`hevr.crypto.tags`), and last the brick's digest marker (scalar, vector, then their tags), as
for a per-voxel brick.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gmpy2
import numpy as np
import zarr

from ..backends import CpuBackend
from ..crypto.tags import betas, raw_tags, tag_channel, tag_key_of
from ..errors import ParameterError
from ..runtime import stats
from ..volume.density import encode_density, normalize_density
from .brick_crypto import encrypt_components
from .digests import brick_digest, marker
from .layout import array_slices, store_array
from .metadata import ChannelInfo, VolumeMetadata
from .packing import PackingInfo, pack_columns
from .quantise import quantise_scalar, quantise_vector

__all__ = ["pack_axis_of", "write_packed_brick"]

_CPU = CpuBackend()  # the tags' records


def packed_parts(meta: VolumeMetadata) -> tuple[PackingInfo, ChannelInfo]:
    """A packed store's (or packed level's) packing and scalar channel, which it always has
    (:mod:`hevr.store.metadata_parse` refuses a layout without the scalar channel)."""
    if meta.packing is None or meta.scalar is None:
        raise ParameterError("meta: expected a packed store's metadata (its layout and scalar channel)")
    return meta.packing, meta.scalar


def write_packed_brick(
    be: Any,
    block: np.ndarray,
    group: zarr.Group,
    index: tuple[int, int, int],
    meta: VolumeMetadata,
    key: Any,
    unsafe_no_obfuscation: bool,
    gradient: np.ndarray | None = None,
) -> tuple[int, int, int]:
    """A packed store's brick: its columns of S voxels packed into one plaintext each (per channel
    and component), encrypted, written as the brick's chunks of the scalar (and vector) arrays,
    then (a verifiable store) one tag per packed ciphertext, E(α·P + β) at the packed array's flat
    index, then the digest marker. ``gradient``: the brick's g·e(d) (the writer computes it with the
    brick's halo, :mod:`hevr.volume.gradient`), packed as the vector channel is."""
    info, scalar = packed_parts(meta)
    dtype: Any = object if block.dtype == np.uint64 else np.int64  # uint64 mantissas: Python ints
    q = np.array(quantise_scalar(block, scalar), dtype=dtype)
    plains = {"scalar": [pack_columns(q.reshape(block.shape), info)]}
    if meta.vector is not None:  # e(d)'s k components, in [0, 10^digits]: slot value = mantissa (offset 0)
        enc = encode_density(normalize_density(block, meta.value_range), meta.vector.digits_dims()[1])
        vq = quantise_vector(enc, meta.vector)
        vinfo = dataclasses.replace(info, offset=0)
        plains["vector"] = [pack_columns(row.reshape(block.shape), vinfo) for row in vq]
    if meta.gradient is not None:  # g·e(d)'s k components, in [0, 10^digits] like e(d)'s
        if gradient is None:  # pragma: no cover - the writer passes it with the gradient channel
            raise ParameterError("gradient: expected the brick's g·e(d) for the store's gradient channel")
        gq = quantise_vector(gradient, meta.gradient)
        plains["gradient"] = [pack_columns(row.reshape(block.shape), dataclasses.replace(info, offset=0)) for row in gq]
    shape = plains["scalar"][0].shape
    width = meta.ciphertext_bytes
    sl = array_slices(meta, index)
    digests = []
    for name, parts in plains.items():  # store order: scalar, vector, gradient
        out = encrypt_components(be, key, [p.ravel().tolist() for p in parts], shape, width, unsafe_no_obfuscation)
        out = out[0] if name == "scalar" else out
        digests.append(brick_digest(meta.store_id, name, index, out))
        with stats.timed("encrypt.write"):
            store_array(group, name)[sl if name == "scalar" else (slice(None),) + sl] = out
    if meta.tags:  # after every data channel: the digests' order (VolumeMetadata.channel_names)
        tk = tag_key_of(key)
        packs = np.ravel_multi_index(
            np.meshgrid(*(np.arange(s.start, s.stop) for s in sl), indexing="ij"), info.array_shape(meta.shape)
        ).reshape(-1)
        for name, parts in plains.items():
            recs = []
            for j, plain in enumerate(parts):
                with stats.timed("encrypt.tags", len(packs)):
                    plain_tags = raw_tags(
                        tk, [int(p) % tk.n for p in plain.ravel()], betas(tk, meta.store_id, name, 0, j, packs)
                    )
                    tags = key.owner.encrypt_residues(gmpy2.mpz(t) for t in plain_tags)
                recs.append(_CPU.to_bytes(tags, width).reshape(shape + (width,)))
            rec = recs[0] if name == "scalar" else np.stack(recs)
            digests.append(brick_digest(meta.store_id, tag_channel(name), index, rec))
            with stats.timed("encrypt.write"):
                store_array(group, tag_channel(name))[sl if name == "scalar" else (slice(None),) + sl] = rec
    store_array(group, "done")[index] = marker(digests)
    return index


def pack_axis_of(value: Any) -> int:
    """The packing axis as an array axis: 0, 1, 2 or "z", "y", "x"; None is 0 (z: superior in RAS+).

    >>> pack_axis_of(None), pack_axis_of("x"), pack_axis_of(1)
    (0, 2, 1)
    """
    if value is None:
        return 0
    names = {"z": 0, "y": 1, "x": 2}
    if isinstance(value, str) and value.lower() in names:
        return names[value.lower()]
    if type(value) is int and 0 <= value <= 2:
        return value
    raise ParameterError(f"pack_axis: expected 0, 1, 2 or 'z', 'y', 'x' (an array axis), got {value!r}")
