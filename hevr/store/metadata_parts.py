"""The parts of the store metadata: one encrypted channel's fixed point (:class:`ChannelInfo`) and
one level of the encrypted pyramid (:class:`LevelInfo`), frozen, each read back strictly by its
``from_dict`` (:mod:`hevr.store.metadata_fields`). :mod:`hevr.store.metadata` re-exports both.

>>> ChannelInfo.from_dict({"exponent": -3, "digits": 3})
ChannelInfo(exponent=-3, digits=3, dims=None)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from ..core.validate import MAX_STORE_DIGITS
from ..errors import CorruptStoreError
from .metadata_fields import DOC_DIGEST, bad_field, int_field, int_triple
from .packing import PackingInfo

__all__ = ["ChannelInfo", "LevelInfo"]


@dataclass(frozen=True)
class ChannelInfo:
    """One encrypted channel: its fixed-point exponent and quantisation digits."""

    exponent: int
    digits: int | None = None  # None: stored exactly (integer volume)
    dims: int | None = None  # vector and gradient channels only

    def to_dict(self) -> dict[str, int]:
        return {k: v for k, v in asdict(self).items() if v is not None}

    def digits_dims(self) -> tuple[int, int]:
        """``(digits, dims)`` of a vector or gradient channel, which has both (:meth:`from_dict` and
        the writer's plan see to it); a channel without them is a :class:`hevr.CorruptStoreError`."""
        if self.digits is None or self.dims is None:
            raise CorruptStoreError(f"channels: expected 'digits' and 'dims' of a k-dimensional channel, got {self}")
        return self.digits, self.dims

    @classmethod
    def from_dict(cls, d: Any, where: str = "store", name: str = "channels") -> ChannelInfo:
        if not isinstance(d, dict) or "exponent" not in d or set(d) - {"exponent", "digits", "dims"}:
            raise CorruptStoreError(
                f"{where}: {name}: expected an object with 'exponent' (and 'digits', 'dims'), got {d!r}"
            )
        exponent = int_field(d["exponent"], f"{name}.exponent", where, -MAX_STORE_DIGITS, MAX_STORE_DIGITS)
        digits = int_field(d["digits"], f"{name}.digits", where, 0, MAX_STORE_DIGITS) if "digits" in d else None
        dims = int_field(d["dims"], f"{name}.dims", where, 2, 64) if "dims" in d else None
        if digits is not None and exponent != -digits:
            raise CorruptStoreError(f"{where}: {name}.exponent: expected -digits = {-digits}, got {exponent}")
        return cls(exponent=exponent, digits=digits, dims=dims)


@dataclass(frozen=True)
class LevelInfo:
    """One level of the encrypted multi-resolution pyramid (:mod:`hevr.store.pyramid`): its
    shape (``ceil`` halving of the level below), whether every brick is written, and the digests
    of its arrays' metadata documents (``levels/<level>/<array>``, relative names). A packed
    store's level (:mod:`hevr.store.packed_levels`, encrypted by the owner) has its own
    ``packing`` (written as ``layout``) and a brick whose packing-axis edge is a multiple of its slots."""

    level: int
    shape: tuple[int, int, int]
    brick: tuple[int, int, int]
    complete: bool = False
    arrays: dict[str, str] = field(default_factory=dict)
    packing: PackingInfo | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "level": self.level,
            "shape": list(self.shape),
            "brick": list(self.brick),
            "complete": self.complete,
            "arrays": dict(self.arrays),
            **({"layout": self.packing.to_dict()} if self.packing is not None else {}),
        }

    @classmethod
    def from_dict(
        cls,
        d: Any,
        where: str,
        expected_level: int,
        expected_shape: tuple[int, ...],
        expected_brick: tuple[int, ...],
        names: set[str],
        axis: int | None = None,
    ) -> LevelInfo:
        name = f"levels[{expected_level - 1}]"
        packed = axis is not None  # a packed store's level: its own layout, along the store's axis
        keys = {"level", "shape", "brick", "complete", "arrays"} | ({"layout"} if packed else set())
        if not isinstance(d, dict) or set(d) != keys:
            raise bad_field(
                where,
                name,
                f"an object with {', '.join(repr(k) for k in sorted(keys))}"
                + (" (a packed store's level has its own layout)" if packed else ""),
                d,
            )
        int_field(d["level"], f"{name}.level", where, expected_level, expected_level)
        shape = int_triple(d["shape"], f"{name}.shape", where)
        if shape != tuple(expected_shape):
            raise bad_field(where, f"{name}.shape", f"{list(expected_shape)} (the level below, halved)", d["shape"])
        packing = PackingInfo.from_dict(d["layout"], f"{where}: {name}") if packed else None
        if packing is not None and packing.axis != axis:
            raise bad_field(where, f"{name}.layout.axis", f"{axis} (the store's packing axis)", packing.axis)
        if packing is not None:  # the base brick, its packing-axis edge rounded up to the level's slots
            expected_brick = tuple(
                -(-b // packing.slots) * packing.slots if i == packing.axis else b for i, b in enumerate(expected_brick)
            )
        brick = int_triple(d["brick"], f"{name}.brick", where)
        if brick != tuple(expected_brick):
            raise bad_field(
                where,
                f"{name}.brick",
                f"{list(expected_brick)} (hevr.volume.pyramid.level_brick"
                + (", its packing-axis edge a multiple of the level's slots)" if packed else ")"),
                d["brick"],
            )
        if type(d["complete"]) is not bool:
            raise bad_field(where, f"{name}.complete", "true or false", d["complete"])
        arrays = d["arrays"]
        if not (
            isinstance(arrays, dict)
            and set(arrays) == names
            and all(isinstance(v, str) and DOC_DIGEST.fullmatch(v) for v in arrays.values())
        ):
            raise bad_field(where, f"{name}.arrays", f"a 'sha256:…' digest for each of {sorted(names)}", arrays)
        return cls(
            level=expected_level, shape=shape, brick=brick, complete=d["complete"], arrays=dict(arrays), packing=packing
        )
