"""Slot-packed stores: S voxels of one column along the packing axis in one Paillier plaintext.

A per-voxel store spends one ciphertext (2·bits/8 bytes) on every voxel. A packed store
(``encrypt_volume(..., layout="packed")``) picks a packing axis ``a`` (an array axis; default 0,
the scan's z axis, which is the patient's superior axis in RAS+) and S slots of K bits, and
stores for every column ``A`` of S consecutive voxels along ``a``

    P[A] = Σ_{s<S} u[S·A + s] · 2^(K·s),        u = m − offset ≥ 0,

where ``m`` are the scalar channel's integer mantissas (exactly the per-voxel store's) and
``offset`` is the lowest mantissa the value range allows, so that every slot value lies in
[0, span], span = hi − lo of the mantissa range. A voxel beyond the volume's end (a ragged
last column) holds 0. Paillier adds plaintexts and multiplies them by public integers, so a
sum of packed ciphertexts with public weights adds every slot at once, exactly, while no slot
reaches 2^K.

Choosing K and S (public parameters only). A frame (:mod:`hevr.rendering.packed`) adds, per
ray, at most one sample per slice of a non-packing axis, each with in-slice bilinear weights of
its 2×2 neighbours rounded to multiples of 1/U, U = 2^weight_bits, which sum to at most U + 2 per
slice (four roundings of at most 1/2 each; nearest: weight 1). So every slot of every sum stays
below

    span · (U + 2) · N,          N = the longest non-packing axis,

and K is the bit length of that bound (:func:`slot_bits`). A frame combines up to S slot classes
into 2S − 1 slots (:mod:`hevr.rendering.packed.plan`), whose plaintext must stay below n with an
integrity margin of :data:`INTEGRITY_BITS` zero bits on top (a corrupted ciphertext decrypts to
a value with non-zero top bits, except with probability 2^-64):

    K·(2S − 1) ≤ bits(n) − 1 − INTEGRITY_BITS                        (:func:`max_slots`).

At 2048 bits with 10-bit weights: 12-bit values and 512 slices: K = 32, S = 31; 8-bit values and
64 slices: K = 24, S = 41.

>>> info = PackingInfo(axis=0, slots=4, slot_bits=10, weight_bits=2, offset=-3)
>>> PackingInfo.from_dict(info.to_dict()) == info
True
>>> info.array_shape((10, 5, 6)), info.array_brick((8, 4, 4))
((3, 5, 6), (2, 4, 4))
>>> vals = pack_columns(np.array([[[0, 1]], [[2, 3]], [[4, 5]]]) + -3, info)   # z = 3 voxels, one pack
>>> vals.shape, [int(v) for v in vals.ravel()] == [(4 << 20) + (2 << 10), (5 << 20) + (3 << 10) + 1]
((1, 1, 2), True)
>>> unpack_slots([(4 << 20) + (2 << 10)], 4, 10).tolist()
[[0, 2, 4, 0]]
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np

from ..errors import CorruptStoreError, ParameterError

__all__ = [
    "INTEGRITY_BITS",
    "DEFAULT_WEIGHT_BITS",
    "MAX_SLOT_BITS",
    "PackingInfo",
    "choose_packing",
    "mantissa_range",
    "max_slots",
    "pack_columns",
    "slot_bits",
    "store_span",
    "unpack_slots",
]

INTEGRITY_BITS = 64  # zero bits above the last slot of every decrypted frame value
DEFAULT_WEIGHT_BITS = 10  # in-slice bilinear weights, quantised to 1/2^10 (the per-voxel store's 3 digits)
MAX_WEIGHT_BITS = 16
MAX_SLOT_BITS = 62  # slots are decoded into int64


def mantissa_range(value_range: tuple[float, float], ch_exp: int) -> tuple[int, int]:
    """floor(lo·10^-e), ceil(hi·10^-e): the stored mantissas' range, in float64 as always, exactly
    (never overflowing) when the product leaves float64's range (a store's value_range beyond
    1e100, written by an older hevr or by hand).

    >>> mantissa_range((-1.5, 2.25), -1), mantissa_range((0.0, 1e300), -30)[1] > 10**329
    ((-15, 23), True)
    """
    lo, hi = (float(v) for v in value_range)
    scale = 10 ** (-int(ch_exp))
    try:
        return math.floor(lo * scale), math.ceil(hi * scale)
    except (OverflowError, ValueError):  # inf (or nan) from an overflowing product
        return math.floor(Fraction(lo) * Fraction(scale)), math.ceil(Fraction(hi) * Fraction(scale))


def slot_bits(span: int, weight_bits: int, max_slices: int) -> int:
    """K: the bits of the largest slot sum of any frame, span·(2^weight_bits + 2)·max_slices (module docstring).

    >>> slot_bits(255, 10, 64), slot_bits(4095, 10, 512), slot_bits(4095, 8, 512)
    (24, 32, 30)
    """
    return max(1, (int(span) * ((1 << int(weight_bits)) + 2) * max(1, int(max_slices))).bit_length())


def store_span(scalar_span: int, vector_digits: int | None = None) -> int:
    """The span K is sized for: the scalar mantissas' (hi − lo), or the vector channel's 10^digits
    when that is wider. The vector channel (the density encoding e(d), components in [0, 1], stored
    as rint(c·10^digits), :mod:`hevr.store.quantise`) is packed with the scalar's S and K and offset 0,
    so that one frame plan (:class:`hevr.rendering.packed.SlicePlan`) serves both channels.

    >>> store_span(255), store_span(255, 3), store_span(4095, 3)
    (255, 1000, 4095)
    """
    return max(int(scalar_span), 10 ** int(vector_digits) if vector_digits is not None else 0)


def max_slots(key_bits: int, k: int) -> int:
    """The most slots S with K·(2S − 1) ≤ key_bits − 1 − INTEGRITY_BITS (0 when none fits).

    >>> max_slots(2048, 24), max_slots(2048, 32), max_slots(256, 200)
    (41, 31, 0)
    """
    room = int(key_bits) - 1 - INTEGRITY_BITS
    return max(0, (room // int(k) + 1) // 2) if room > 0 else 0


@dataclass(frozen=True)
class PackingInfo:
    """How a packed store's scalar channel is laid out (recorded in its metadata, under the owner's MAC).

    Attributes
    ----------
    axis : int
        The packing axis, an array axis (0 = z, 1 = y, 2 = x).
    slots : int
        S, voxels per ciphertext.
    slot_bits : int
        K, bits per slot.
    weight_bits : int
        Bits of the in-slice bilinear weights K was sized for (multiples of 2^-weight_bits).
    offset : int
        The mantissa stored as slot value 0 (slot value = mantissa − offset).
    """

    axis: int
    slots: int
    slot_bits: int
    weight_bits: int
    offset: int

    def packs(self, length: int) -> int:
        """Packed ciphertexts along the packing axis for ``length`` voxels."""
        return -(-int(length) // self.slots)

    def array_shape(self, shape: tuple[int, ...]) -> tuple[int, int, int]:
        """The packed array's shape (pack units along the axis) of a volume of ``shape``."""
        out = list(shape)
        out[self.axis] = self.packs(shape[self.axis])
        return tuple(out)  # type: ignore[return-value]

    def array_brick(self, brick: tuple[int, ...]) -> tuple[int, int, int]:
        """A brick's chunk in the packed array (its packing-axis edge is a multiple of S)."""
        out = list(brick)
        out[self.axis] = brick[self.axis] // self.slots
        return tuple(out)  # type: ignore[return-value]

    def to_dict(self) -> dict:
        return {
            "kind": "packed",
            "axis": self.axis,
            "slots": self.slots,
            "slot_bits": self.slot_bits,
            "weight_bits": self.weight_bits,
            "offset": str(self.offset),
        }

    @classmethod
    def from_dict(cls, d: Any, where: str = "store") -> PackingInfo:
        keys = {"kind", "axis", "slots", "slot_bits", "weight_bits", "offset"}
        if not isinstance(d, dict) or set(d) != keys or d.get("kind") != "packed":
            raise CorruptStoreError(
                f"{where}: layout: expected an object with {sorted(keys)} and kind 'packed', got {str(d)[:80]!r}"
            )

        def integer(name: str, lo: int, hi: int) -> int:
            v = d[name]
            if type(v) is not int or not lo <= v <= hi:
                raise CorruptStoreError(f"{where}: layout.{name}: expected an integer in [{lo}, {hi}], got {v!r}")
            return v

        off = d["offset"]
        if not (isinstance(off, str) and 0 < len(off) <= 40 and off.lstrip("-").isdigit() and off.isascii()):
            raise CorruptStoreError(f"{where}: layout.offset: expected a decimal integer string, got {off!r}")
        return cls(
            axis=integer("axis", 0, 2),
            slots=integer("slots", 1, 4096),
            slot_bits=integer("slot_bits", 1, MAX_SLOT_BITS),
            weight_bits=integer("weight_bits", 0, MAX_WEIGHT_BITS),
            offset=int(off),
        )

    def check(
        self, key_bits: int, shape: tuple[int, ...], brick: tuple[int, ...], span: int, where: str = "store"
    ) -> None:
        """Consistency with the rest of the metadata: S slots fit the key, the brick's packing-axis
        edge is a multiple of S, and K holds every frame's largest slot sum (a K edited smaller
        would let sums carry into the next slot): :class:`hevr.CorruptStoreError` otherwise."""
        if self.slot_bits * (2 * self.slots - 1) > key_bits - 1 - INTEGRITY_BITS:
            raise CorruptStoreError(
                f"{where}: layout.slots: expected at most {max_slots(key_bits, self.slot_bits)} "
                f"slots of {self.slot_bits} bits for a {key_bits}-bit key, got {self.slots}"
            )
        if brick[self.axis] % self.slots:
            raise CorruptStoreError(
                f"{where}: brick: expected a multiple of layout.slots ({self.slots}) along the "
                f"packing axis {self.axis}, got {brick[self.axis]}"
            )
        need = slot_bits(span, self.weight_bits, max(s for i, s in enumerate(shape) if i != self.axis))
        if self.slot_bits < need:
            raise CorruptStoreError(
                f"{where}: layout.slot_bits: expected at least {need} (the largest slot sum of "
                f"this shape and value range), got {self.slot_bits}"
            )


def choose_packing(
    key_bits: int,
    shape: tuple[int, int, int],
    axis: int,
    mantissa_range: tuple[int, int],
    weight_bits: int = DEFAULT_WEIGHT_BITS,
    vector_digits: int | None = None,
) -> PackingInfo:
    """The packing of a new store: K from the value span, the weights and the longest
    non-packing axis; S the most slots that fit the key (module docstring). ``vector_digits``:
    the store also holds the vector channel, packed alike (:func:`store_span`).

    >>> choose_packing(2048, (64, 64, 64), 0, (0, 255))
    PackingInfo(axis=0, slots=41, slot_bits=24, weight_bits=10, offset=0)
    >>> choose_packing(2048, (64, 64, 64), 0, (0, 255), vector_digits=3).slot_bits
    26
    """
    lo, hi = (int(v) for v in mantissa_range)
    span = store_span(hi - lo, vector_digits)
    longest = max(s for i, s in enumerate(shape) if i != axis)
    k = slot_bits(span, weight_bits, longest)
    if k > MAX_SLOT_BITS:
        raise ParameterError(
            f"value_range: expected a mantissa span of at most {MAX_SLOT_BITS - weight_bits - 1} "
            f"bits less the {math.ceil(math.log2(longest + 1))} bits of {longest} slices for a packed "
            f"store, got a span of {span.bit_length()} bits (give a narrower value_range, or fewer "
            "digits, or layout='voxel')"
        )
    s = max_slots(key_bits, k)
    if s < 2:
        raise ParameterError(
            f"layout: expected a key with room for at least 2 slots of {k} bits plus "
            f"{INTEGRITY_BITS} integrity bits, got a {key_bits}-bit key (use a larger key or "
            "layout='voxel')"
        )
    return PackingInfo(axis=int(axis), slots=s, slot_bits=k, weight_bits=int(weight_bits), offset=lo)


def pack_columns(mantissas: np.ndarray, info: PackingInfo) -> np.ndarray:
    """The packed plaintexts (Python ints, an object array in the packed array's shape) of a block
    of integer ``mantissas`` whose packing-axis edge starts at a multiple of S (a ragged end is
    filled with slot value 0). Every slot value must lie in [0, 2^K)."""
    m = np.asarray(mantissas)
    S, K = info.slots, info.slot_bits
    u = np.moveaxis(m, info.axis, -1)
    if u.dtype == object or u.dtype == np.uint64:
        u = np.array([int(v) - info.offset for v in u.ravel()], dtype=object).reshape(u.shape)
    else:
        u = u.astype(np.int64) - np.int64(info.offset)
    if u.size and (min(int(u.min()), 0) < 0 or int(u.max()) >> K):
        raise ParameterError(f"mantissas: expected slot values in [0, 2^{K}), got {int(u.min())}..{int(u.max())}")
    u = u.astype(np.int64)
    L = u.shape[-1]
    packs = -(-L // S)
    if packs * S != L:
        u = np.concatenate([u, np.zeros(u.shape[:-1] + (packs * S - L,), np.int64)], axis=-1)
    cols = u.reshape(-1, S)  # one row per pack
    bits = ((cols[:, :, None] >> np.arange(K, dtype=np.int64)) & 1).astype(np.uint8).reshape(len(cols), S * K)
    raw = np.packbits(bits, axis=1, bitorder="little")
    out = np.empty(len(cols), dtype=object)
    for r in range(len(cols)):
        out[r] = int.from_bytes(raw[r].tobytes(), "little")
    return np.moveaxis(out.reshape(u.shape[:-1] + (packs,)), -1, info.axis)


def unpack_slots(values: Any, n_slots: int, k: int) -> np.ndarray:
    """(N, n_slots) int64 slot values (K bits each, slot 0 lowest) of N non-negative integers;
    bits above the last slot are ignored here (the caller checks them)."""
    vals = [int(v) for v in values]
    nbytes = max(1, -(-(n_slots * k) // 8))
    mask = (1 << (n_slots * k)) - 1
    raw = np.frombuffer(b"".join((v & mask).to_bytes(nbytes, "little") for v in vals), np.uint8).reshape(
        len(vals), nbytes
    )
    bits = np.unpackbits(raw, axis=1, bitorder="little")[:, : n_slots * k].reshape(len(vals), n_slots, k)
    return (bits.astype(np.int64) << np.arange(k, dtype=np.int64)).sum(axis=2)
