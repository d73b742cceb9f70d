"""Field readers of the store metadata: each one checks a single field's type and range exactly (a
bool is not an int, a float is not an int) and names the field when it is wrong.

:mod:`hevr.store.metadata_parts` and :mod:`hevr.store.metadata_parse` read the ``hevr`` attribute
with them; the message is :class:`hevr.CorruptStoreError`'s ``"<where>: <field>: expected …, got …"``.

>>> int_field(3, "brick", "store", 1)
3
>>> int_field(True, "brick", "store", 1)
Traceback (most recent call last):
    ...
hevr.errors.CorruptStoreError: store: brick: expected an integer in [1, ∞], got True
"""

from __future__ import annotations

import math
import re
from typing import Any

from ..errors import CorruptStoreError

__all__ = [
    "CHANNELS",
    "DOC_DIGEST",
    "DTYPES",
    "HEX64",
    "MAX_N_DIGITS",
    "STORE_ID",
    "bad_field",
    "float_triple",
    "get_field",
    "int_field",
    "int_triple",
    "number_field",
]

DTYPES = (
    "bool",
    "int8",
    "int16",
    "int32",
    "int64",
    "uint8",
    "uint16",
    "uint32",
    "uint64",
    "float16",
    "float32",
    "float64",
)
MAX_N_DIGITS = 4300  # Python's int/str conversion limit (a 14 000-bit modulus): longer ones refused before int()
HEX64 = re.compile(r"[0-9a-f]{64}")
STORE_ID = re.compile(r"[0-9a-f]{16}")
DOC_DIGEST = re.compile(r"sha256:[0-9a-f]{64}")
CHANNELS = ("scalar", "vector", "gradient")  # store order: the order of a brick's digests


def bad_field(where: str, name: str, expected: str, got: Any) -> CorruptStoreError:
    """The error that field ``name`` is not ``expected`` (its value's ``repr`` cut at 80 characters)."""
    text = repr(got)
    return CorruptStoreError(f"{where}: {name}: expected {expected}, got {text[:80] + '…' if len(text) > 80 else text}")


def get_field(d: dict[str, Any], key: str, where: str, prefix: str = "") -> Any:
    """``d[key]``, or the error that the field ``prefix + key`` is missing."""
    if key not in d:
        raise CorruptStoreError(f"{where}: malformed metadata (missing field '{prefix}{key}')")
    return d[key]


def int_field(v: Any, name: str, where: str, lo: int, hi: int | None = None) -> int:
    """``v``, an int (not a bool) in ``[lo, hi]`` (no upper bound when ``hi`` is None)."""
    if type(v) is not int or v < lo or (hi is not None and v > hi):
        raise bad_field(where, name, f"an integer in [{lo}, {hi if hi is not None else '∞'}]", v)
    return v


def number_field(v: Any, name: str, where: str, positive: bool = False) -> float:
    """``v`` as a float: an int or float (not a bool), finite, and > 0 when ``positive``."""
    if type(v) not in (int, float) or not math.isfinite(v) or (positive and not v > 0):
        raise bad_field(where, name, "a positive finite number" if positive else "a finite number", v)
    return float(v)


def _three(v: Any, name: str, where: str) -> list[Any]:
    if not isinstance(v, list) or len(v) != 3:
        raise bad_field(where, name, "a list of 3 entries", v)
    return v


def int_triple(v: Any, name: str, where: str) -> tuple[int, int, int]:
    """A list of 3 integers >= 1 (a shape, a brick) as a tuple."""
    a, b, c = (int_field(x, name, where, 1) for x in _three(v, name, where))
    return a, b, c


def float_triple(v: Any, name: str, where: str) -> tuple[float, float, float]:
    """A list of 3 positive finite numbers (a spacing) as a tuple of floats."""
    a, b, c = (number_field(x, name, where, positive=True) for x in _three(v, name, where))
    return a, b, c
