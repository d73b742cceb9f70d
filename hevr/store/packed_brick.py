"""A packed store's brick, written by its encryption task (:func:`hevr.encrypt_volume` with
``layout="packed"``; the slots: :mod:`hevr.store.packing`).

The brick's scalar mantissas (the per-voxel store's, :func:`~hevr.store.quantise.quantise_scalar`)
are packed S to a plaintext along the packing axis, encrypted (the key's path: the owner's with a
private key), written as the brick's chunk of the packed scalar array; a verifiable store then gets
one tag per packed ciphertext, E(α·P + β) with β of the pack's flat index in the packed array
(:mod:`hevr.crypto.tags`), and last the brick's digest marker, as for a per-voxel brick.
"""

from __future__ import annotations

from typing import Any

import gmpy2
import numpy as np

from .. import _stats
from ..backends import CpuBackend
from ..crypto.tags import betas, raw_tags, tag_channel, tag_key_of
from ..errors import ParameterError
from .brick_crypto import encrypt_components
from .digests import brick_digest, marker
from .layout import array_slices
from .metadata import VolumeMetadata
from .packing import pack_columns
from .quantise import quantise_scalar

__all__ = ["pack_axis_of", "write_packed_brick"]

_CPU = CpuBackend()  # the tags' records


def write_packed_brick(be: Any, block: np.ndarray, group: Any, index: tuple[int, int, int], meta: VolumeMetadata,
                        key: Any, unsafe_no_obfuscation: bool) -> tuple[int, int, int]:
    """A packed store's brick: its columns of S voxels packed into one plaintext each, encrypted,
    written as the brick's chunk of the scalar array, then (a verifiable store) one tag per packed
    ciphertext, E(α·P + β) at the packed array's flat index, then the digest marker."""
    info = meta.packing
    q = np.array(quantise_scalar(block, meta.scalar), dtype=object if block.dtype == np.uint64 else np.int64)
    plain = pack_columns(q.reshape(block.shape), info)
    shape = plain.shape
    width = meta.ciphertext_bytes
    out = encrypt_components(be, key, [plain.ravel().tolist()], shape, width, unsafe_no_obfuscation)[0]
    digests = [brick_digest(meta.store_id, "scalar", index, out)]
    sl = array_slices(meta, index)
    with _stats.timed("encrypt.write"):
        group["scalar"][sl] = out
    if meta.tags:
        tk = tag_key_of(key)
        packs = np.ravel_multi_index(np.meshgrid(*(np.arange(s.start, s.stop) for s in sl), indexing="ij"),
                                     info.array_shape(meta.shape)).reshape(-1)
        with _stats.timed("encrypt.tags", len(packs)):
            plain_tags = raw_tags(tk, [int(p) % tk.n for p in plain.ravel()], betas(tk, meta.store_id, "scalar", 0, 0, packs))
            tags = key.owner.encrypt_residues(gmpy2.mpz(t) for t in plain_tags)
        rec = _CPU.to_bytes(tags, width).reshape(shape + (width,))
        digests.append(brick_digest(meta.store_id, tag_channel("scalar"), index, rec))
        with _stats.timed("encrypt.write"):
            group[tag_channel("scalar")][sl] = rec
    group["done"][index] = marker(digests)
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
