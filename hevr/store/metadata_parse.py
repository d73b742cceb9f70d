"""Reading the ``hevr`` attribute back: every field of a :class:`~hevr.store.metadata.VolumeMetadata`
validated, types exactly, ranges, and consistency (fingerprint length, ``n_bricks`` and ``bits``
when present, a packed store's layout against its key, brick and value range, each pyramid level
against the level below). :meth:`VolumeMetadata.from_dict <hevr.store.metadata.VolumeMetadata.from_dict>`
checks the format, version and checksum, then calls :func:`parse_metadata`.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from ..core.validate import is_decimal
from ..crypto.tags import tag_channel
from ..volume.pyramid import MAX_LEVELS, level_brick
from .authenticity import is_auth
from .metadata_fields import (
    CHANNELS,
    DOC_DIGEST,
    DTYPES,
    HEX64,
    MAX_N_DIGITS,
    STORE_ID,
    bad_field,
    float_triple,
    get_field,
    int_field,
    int_triple,
    number_field,
)
from .metadata_parts import ChannelInfo, LevelInfo
from .packing import PackingInfo, mantissa_range, store_span

if TYPE_CHECKING:
    from .metadata import VolumeMetadata

__all__ = ["parse_metadata"]


def parse_metadata(cls: type[VolumeMetadata], d: dict[str, Any], where: str, version: int) -> VolumeMetadata:
    """The :class:`~hevr.store.metadata.VolumeMetadata` of the ``hevr`` attribute ``d`` (format ``version``,
    its checksum already checked), every field validated; the error names the first that is wrong."""
    shape = int_triple(get_field(d, "shape", where), "shape", where)
    spacing = float_triple(get_field(d, "spacing", where), "spacing", where)
    brick = int_triple(get_field(d, "brick", where), "brick", where)
    pk = get_field(d, "public_key", where)
    if not isinstance(pk, dict):
        raise bad_field(where, "public_key", "an object", pk)
    n = get_field(pk, "n", where, "public_key.")
    if not (is_decimal(n, MAX_N_DIGITS) and n[0] != "0"):
        raise bad_field(
            where,
            "public_key.n",
            f"a decimal string of at most {MAX_N_DIGITS} digits (public_key.n must be a decimal string)",
            n,
        )
    fingerprint = get_field(pk, "fingerprint", where, "public_key.")
    if not (isinstance(fingerprint, str) and HEX64.fullmatch(fingerprint)):
        raise bad_field(where, "public_key.fingerprint", "64 lower-case hex digits", fingerprint)
    if "bits" in pk and pk["bits"] != int(n).bit_length():
        raise bad_field(where, "public_key.bits", f"{int(n).bit_length()} (the bit length of n)", pk["bits"])
    width = int_field(get_field(d, "ciphertext_bytes", where), "ciphertext_bytes", where, 1)
    dtype = get_field(d, "dtype", where)
    if dtype not in DTYPES:
        raise bad_field(where, "dtype", f"one of {', '.join(DTYPES)}", dtype)
    vr = get_field(d, "value_range", where)
    if not isinstance(vr, list) or len(vr) != 2:
        raise bad_field(where, "value_range", "a list [lo, hi]", vr)
    lo, hi = (number_field(x, "value_range", where) for x in vr)
    if not lo < hi:
        raise bad_field(where, "value_range", "lo < hi", vr)
    base = d.get("base", 10)
    if type(base) is not int or base != 10:
        raise bad_field(where, "base", "10", base)
    ch = get_field(d, "channels", where)
    if not isinstance(ch, dict) or not (set(ch) & {"scalar", "vector"}) or set(ch) - set(CHANNELS):
        raise bad_field(where, "channels", "an object with 'scalar' and/or 'vector' (and 'gradient')", ch)
    scalar = ChannelInfo.from_dict(ch["scalar"], where, "channels.scalar") if "scalar" in ch else None
    vector = ChannelInfo.from_dict(ch["vector"], where, "channels.vector") if "vector" in ch else None
    if vector is not None and (vector.dims is None or vector.digits is None):
        raise bad_field(where, "channels.vector", "'digits' and 'dims'", ch["vector"])
    gradient = ChannelInfo.from_dict(ch["gradient"], where, "channels.gradient") if "gradient" in ch else None
    if gradient is not None and (vector is None or gradient != vector):
        raise bad_field(
            where, "channels.gradient", "the same 'exponent', 'digits' and 'dims' as channels.vector", ch["gradient"]
        )
    complete = d.get("complete", False)
    if type(complete) is not bool:
        raise bad_field(where, "complete", "true or false", complete)
    store_id = d.get("store_id", "")
    if not isinstance(store_id, str) or (version >= 2 and not STORE_ID.fullmatch(store_id)):
        raise bad_field(where, "store_id", "16 lower-case hex digits", store_id)
    extra = d.get("extra", {})
    if not isinstance(extra, dict):
        raise bad_field(where, "extra", "an object", extra)
    patient = _patient(d.get("patient", {}), where)
    tags = d.get("tags", False)
    if type(tags) is not bool:
        raise bad_field(where, "tags", "true or false", tags)
    auth = d.get("auth", "")
    if (tags or "auth" in d) and not (tags and is_auth(auth)):
        raise bad_field(
            where,
            "auth",
            "the owner's MAC 'hmac-sha256:<64 hex>' on a verifiable store (tags: true) and "
            "nothing else (a verifiable store written before hevr bound its metadata: encrypt it again)",
            auth,
        )
    arrays = d.get("arrays", {})
    names = {*(k for k in CHANNELS if k in ch), *(tag_channel(k) for k in CHANNELS if k in ch and tags), "done"}
    if version >= 2 and not (
        isinstance(arrays, dict)
        and set(arrays) == names
        and all(isinstance(v, str) and DOC_DIGEST.fullmatch(v) for v in arrays.values())
    ):
        raise bad_field(where, "arrays", f"a 'sha256:…' digest for each of {sorted(names)}", arrays)
    meta = cls(
        shape=shape,
        spacing=spacing,
        brick=brick,
        n=n,
        fingerprint=fingerprint,
        ciphertext_bytes=width,
        dtype=dtype,
        value_range=(lo, hi),
        scalar=scalar,
        vector=vector,
        gradient=gradient,
        base=base,
        complete=complete,
        store_id=store_id,
        version=version,
        extra=dict(extra),
        arrays=dict(arrays) if version >= 2 else {},
        patient=patient,
        tags=tags,
        auth=auth,
    )
    if "layout" in d:
        meta = dataclasses.replace(meta, packing=_packing(d, meta, where))
    levels = d.get("levels", [])
    if not isinstance(levels, list) or len(levels) > MAX_LEVELS:
        raise bad_field(where, "levels", f"a list of at most {MAX_LEVELS} pyramid levels", levels)
    parsed: list[LevelInfo] = []
    below: tuple[int, ...] = shape
    for i, lv in enumerate(levels):
        below = tuple(-(-s // 2) for s in below)
        info = LevelInfo.from_dict(
            lv,
            where,
            i + 1,
            below,
            level_brick(brick, i + 1),
            names,
            None if meta.packing is None else meta.packing.axis,
        )
        if info.packing is not None:  # as level 0's: shape, exponent, key
            if meta.scalar is None:  # (_packing refuses a packed store without it; never skip the check)
                raise bad_field(
                    where, "channels", "'scalar' in a store with packed levels", sorted(d.get("channels", {}))
                )
            _level_packing(meta, meta.scalar, info, info.packing, where)
        parsed.append(info)
    if parsed:
        meta = dataclasses.replace(meta, levels=tuple(parsed))
    if "n_bricks" in d and d["n_bricks"] != meta.n_bricks:
        raise bad_field(where, "n_bricks", f"{meta.n_bricks} (the brick grid of shape and brick)", d["n_bricks"])
    return meta


def _packing(d: dict[str, Any], meta: VolumeMetadata, where: str) -> PackingInfo:
    """A packed store's ``layout``, checked against the rest: the scalar (and vector, gradient, packed
    alike: :func:`~hevr.store.packing.store_span`) channel, the value range's offset, slots that fit
    the key and brick, a slot width for every frame's largest sum (:meth:`PackingInfo.check`)."""
    packing = PackingInfo.from_dict(d["layout"], where)
    if meta.scalar is None:
        raise bad_field(where, "channels", "'scalar' (and 'vector', 'gradient') in a packed store", d.get("channels"))
    if meta.vector is not None and d.get("levels"):  # the owner encrypts a packed store's levels: scalar only
        raise bad_field(where, "levels", "none in a packed store with the vector channel", "a list of levels")
    lo, hi = mantissa_range(meta.value_range, meta.scalar.exponent)
    if packing.offset != lo:
        raise bad_field(where, "layout.offset", f"{lo} (the lowest mantissa of value_range)", str(packing.offset))
    span = store_span(hi - lo, None if meta.vector is None else meta.vector.digits)
    packing.check(int(meta.n).bit_length(), meta.shape, meta.brick, span, where)
    return packing


def _level_packing(
    meta: VolumeMetadata, scalar: ChannelInfo, info: LevelInfo, packing: PackingInfo, where: str
) -> None:
    """A packed level's ``layout`` (:mod:`hevr.store.packed_levels`; its axis checked on parsing): the offset
    at the level's exponent e − 3·level, slots for the key and brick, a width for the level's largest sum."""
    name = f"levels[{info.level - 1}].layout"
    lo, hi = mantissa_range(meta.value_range, scalar.exponent - 3 * info.level)
    if packing.offset != lo:
        raise bad_field(
            where,
            f"{name}.offset",
            f"{lo} (the lowest mantissa of value_range at the level's exponent)",
            str(packing.offset),
        )
    packing.check(int(meta.n).bit_length(), info.shape, info.brick, hi - lo, f"{where}: {name}")


def _patient(p: Any, where: str) -> dict[str, Any]:
    """The optional ``patient`` object: the frame the volume is in (only ``"RAS"``) and the
    world position (mm) of voxel (0, 0, 0); both public header facts of the input file.

    >>> _patient({"frame": "RAS", "origin": [-50.5, -46, -80.5]}, "store")
    {'frame': 'RAS', 'origin': (-50.5, -46.0, -80.5)}
    """
    if p == {}:
        return {}
    if not (
        isinstance(p, dict)
        and set(p) == {"frame", "origin"}
        and p["frame"] == "RAS"
        and isinstance(p["origin"], list)
        and len(p["origin"]) == 3
    ):
        raise bad_field(where, "patient", '{"frame": "RAS", "origin": [x, y, z]}', p)
    origin = tuple(number_field(v, "patient.origin", where) for v in p["origin"])
    return {"frame": "RAS", "origin": origin}
