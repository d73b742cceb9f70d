"""Planning a store: the metadata of the store :func:`hevr.store.writer.encrypt_volume` is to write,
from its input (an array or a :class:`hevr.Scan`) and its options, every option checked before
anything runs or the disk is touched: the channels' fixed point (:mod:`hevr.store.quantise`), the
tags (``verifiable`` and the key's policy), and a packed store's slots (:mod:`hevr.store.packing`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.validate import check_brick, check_choice, check_spacing
from ..core.voxels import check_volume
from ..crypto.keys import PrivateKey, PublicKey
from ..errors import ParameterError
from ..volume.mapped import task_array
from ..volume.scan import Scan
from .metadata import VolumeMetadata
from .packed_brick import pack_axis_of
from .packed_levels import check_levels
from .packing import choose_packing, mantissa_range
from .paths import token
from .quantise import plan_channels

log = logging.getLogger("hevr.store.writer")  # the writer's messages, as hevr.store.quantise's

__all__ = ["plan_store"]


def plan_store(
    vol: Any,
    key: PublicKey | PrivateKey,
    *,
    spacing: Sequence[float] | None,
    brick: int | Sequence[int],
    scalar: bool,
    vector_dims: int | None,
    value_range: Sequence[float] | None,
    digits: int | None,
    vector_digits: int,
    gradient: bool,
    verifiable: bool | None,
    layout: str,
    pack_axis: int | str | None,
    levels: int,
) -> tuple[Any, tuple[int, int, int], VolumeMetadata, int]:
    """The volume as the encryption tasks read it (a memory-mapped file read inside them), the
    brick shape (a packed store's packing-axis edge a multiple of its slots), the store's
    metadata (no ``store_id`` yet) and the checked number of pyramid levels; the arguments are
    :func:`~hevr.store.writer.encrypt_volume`'s, each refused with a :class:`hevr.ParameterError`
    naming it."""
    patient = {"frame": vol.frame, "origin": tuple(vol.origin)} if isinstance(vol, Scan) and vol.frame else {}
    scanned = isinstance(vol, Scan)
    if scanned:
        vol, spacing = vol.volume, vol.spacing if spacing is None else spacing
    # a file's single 2-D slice is refused, as a 2-D array is (arrays with a flat axis stay: slices of them render)
    vol = check_volume(vol, thick=scanned)
    brick_t = check_brick(brick, shape=vol.shape)
    vol = task_array(vol, brick_t, f"hevr-plain-{token()}{token()}")  # memmaps: read inside the tasks
    spacing_t = check_spacing((1.0, 1.0, 1.0) if spacing is None else spacing)
    pub = key.public_key if isinstance(key, PrivateKey) else key
    if not isinstance(gradient, (bool, np.bool_)):
        raise ParameterError(f"gradient: expected True or False, got {gradient!r}")
    if verifiable is not None and not isinstance(verifiable, (bool, np.bool_)):
        raise ParameterError(f"verifiable: expected True, False or None, got {verifiable!r}")
    if verifiable and not isinstance(key, PrivateKey):
        raise ParameterError(
            "verifiable: expected a PrivateKey as key (the tags need its tag key, "
            f"hevr.crypto.tags), got a {type(key).__name__}"
        )
    if gradient and vector_dims is None:
        raise ParameterError(
            "gradient: expected vector_dims=k as well, got vector_dims=None (the gradient channel "
            "holds g·e(d), the k-dimensional density encoding scaled by the gradient magnitude)"
        )
    layout, levels = check_choice("layout", layout, ("voxel", "packed")), check_levels(levels)
    policy = isinstance(key, PrivateKey) and key.require_tags  # the key's policy: every store carries tags
    if policy and verifiable is not None and not verifiable:
        raise ParameterError(
            "verifiable: expected True or None under a key whose policy is that every store of it "
            "carries tags (PrivateKey.require_tags), got False: its key holder would refuse the "
            "store; encrypt with key.with_policy(require_tags=False) to make one without tags"
        )
    if verifiable is None:  # packed stores carry tags by default (one per packed ciphertext costs little), and
        verifiable = policy or (layout == "packed" and isinstance(key, PrivateKey))  # every store of a policy key
        if layout == "packed" and not verifiable:
            log.warning(
                "encrypt_volume: a packed store encrypted with the public key has no tags (they need the "
                "private key), so its frames cannot be verified"
            )
    if layout == "packed" and not scalar:
        raise ParameterError(
            "layout: expected 'voxel' for a store without the scalar channel (a packed store "
            "packs every channel along the scalar's slots), got 'packed' with scalar=False"
        )
    if layout == "packed" and vector_dims is not None and levels:
        raise ParameterError(
            f"levels: expected 0 for a packed store with the vector channel (its levels are "
            f"encrypted scalar only), got {levels}; encrypt without vector_dims, or layout='voxel'"
        )
    if layout == "voxel" and pack_axis is not None:
        raise ParameterError(f"pack_axis: expected None for layout='voxel', got {pack_axis!r}")
    sc, vc, vr = plan_channels(vol, int(pub.n), scalar, vector_dims, value_range, digits, vector_digits)
    shape = (int(vol.shape[0]), int(vol.shape[1]), int(vol.shape[2]))  # check_volume: 3-D
    packing = None
    if layout == "packed" and sc is not None:  # (a packed store has the scalar channel: refused above without)
        axis = pack_axis_of(pack_axis)
        packing = choose_packing(
            int(pub.n).bit_length(),
            shape,
            axis,
            mantissa_range(vr, sc.exponent),
            vector_digits=None if vc is None else vc.digits,
        )
        b0, b1, b2 = (-(-b // packing.slots) * packing.slots if i == axis else b for i, b in enumerate(brick_t))
        brick_t = (b0, b1, b2)  # the packing-axis edge a multiple of the slots
    meta = VolumeMetadata(
        shape=shape,
        spacing=spacing_t,
        brick=brick_t,
        n=str(int(pub.n)),
        fingerprint=pub.fingerprint,
        ciphertext_bytes=pub.ciphertext_bytes,
        dtype=str(np.dtype(vol.dtype)),
        value_range=vr,
        scalar=sc,
        vector=vc,
        gradient=vc if gradient else None,
        patient=patient,
        tags=bool(verifiable),
        packing=packing,
    )
    return vol, brick_t, meta, levels
