"""One encryption task's work (:func:`hevr.store.writer.encrypt_volume`): a plaintext brick's
ciphertexts, channel by channel in store order, then (a verifiable store) its tags, each written as
the brick's own chunks, and last its digest marker, so that no two tasks ever write the same chunk
and a brick counts as written only once all of it is. A packed store's brick is
:func:`hevr.store.packed_brick.write_packed_brick`'s.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import zarr

from ..backends import CpuBackend, get_backend
from ..crypto.tags import tag_channel, tag_ciphertexts
from ..errors import StoreError
from ..runtime import stats
from ..volume import gradient as grad
from ..volume.density import check_brick_range, encode_density, normalize_density
from .brick_crypto import encrypt_components
from .digests import brick_digest, marker
from .layout import brick_slices, store_array
from .metadata import ChannelInfo, VolumeMetadata
from .packed_brick import write_packed_brick
from .paths import zarr_store
from .quantise import quantise_scalar, quantise_vector

__all__ = ["write_brick"]

_CPU = CpuBackend()  # the tags' records (owner-encrypted on the CPU whatever the data's backend)


def write_brick(
    block: np.ndarray,
    path: str,
    index: tuple[int, int, int],
    meta_dict: dict[str, Any],
    key: Any,
    unsafe_no_obfuscation: bool,
    backend: str,
    halo: grad.Halo | None,
    m_max: float,
    storage_options: dict[str, Any] | None,
) -> tuple[int, int, int]:
    """Encrypt the brick ``index`` (``block``, with a one-voxel ``halo`` of its neighbours when the
    store has the gradient channel, whose whole-volume max |∇d| is ``m_max``) with ``key`` (a
    PublicKey, or the owner's PrivateKey) and write its chunks, then its digest marker."""
    be = get_backend(backend)
    meta = VolumeMetadata.from_dict(meta_dict)
    haloed = np.asarray(block)
    block = haloed if halo is None else haloed[tuple(slice(lo, n - hi) for (lo, hi), n in zip(halo, haloed.shape))]
    check_brick_range(block, meta.value_range, index)  # no data value in a task's message
    sl = brick_slices(meta, index)
    width = meta.ciphertext_bytes
    group = zarr.open_group(zarr_store(path, storage_options), mode="r+")
    genc = None  # g·e(d) of the brick: the gradient channel's encoding, from the brick and its halo
    if meta.gradient is not None:
        if halo is None:  # pragma: no cover - the writer always passes the halo with the gradient channel
            raise StoreError(f"brick {index}: the gradient channel needs the brick's halo")
        dims = meta.gradient.digits_dims()[1]
        genc = grad.brick_gradient_encoding(haloed, halo, meta.spacing, meta.value_range, dims, m_max)
    if meta.packing is not None:  # S voxels per ciphertext along the packing axis (hevr.store.packing)
        return write_packed_brick(be, block, group, index, meta, key, unsafe_no_obfuscation, genc)
    digests = []
    mantissas = {}  # channel -> (k, voxels) int64, for the tags of a verifiable store
    if meta.scalar is not None:
        q = quantise_scalar(block, meta.scalar)
        records = encrypt_components(be, key, [q], block.shape, width, unsafe_no_obfuscation)[0]
        digests.append(brick_digest(meta.store_id, "scalar", index, records))
        with stats.timed("encrypt.write"):
            store_array(group, "scalar")[sl] = records
        mantissas["scalar"] = np.asarray(q).reshape(1, -1)
    fields: dict[str, tuple[ChannelInfo, np.ndarray]] = {}
    if meta.vector is not None:
        density = normalize_density(block, meta.value_range)
        fields["vector"] = (meta.vector, encode_density(density, meta.vector.digits_dims()[1]))
    if meta.gradient is not None and genc is not None:
        fields["gradient"] = (meta.gradient, genc)
    for name, (info, enc) in fields.items():  # store order: vector, then gradient
        vq = quantise_vector(enc, info)
        records = encrypt_components(be, key, vq, block.shape, width, unsafe_no_obfuscation)
        digests.append(brick_digest(meta.store_id, name, index, records))
        with stats.timed("encrypt.write"):
            store_array(group, name)[(slice(None),) + sl] = records
        mantissas[name] = np.asarray(vq)
    if meta.tags:  # after every data channel: the digests' order (VolumeMetadata.channel_names)
        voxels = np.ravel_multi_index(
            np.meshgrid(*(np.arange(s.start, s.stop) for s in sl), indexing="ij"), meta.shape
        ).reshape(-1)
        for name, m in mantissas.items():
            with stats.timed("encrypt.tags", m.size):
                tags = tag_ciphertexts(key, meta.store_id, name, 0, m, voxels)
            out = np.stack([_CPU.to_bytes(t, width).reshape(block.shape + (width,)) for t in tags])
            out = out[0] if name == "scalar" else out
            digests.append(brick_digest(meta.store_id, tag_channel(name), index, out))
            with stats.timed("encrypt.write"):
                store_array(group, tag_channel(name))[sl if name == "scalar" else (slice(None),) + sl] = out
    store_array(group, "done")[index] = marker(digests)
    return index
