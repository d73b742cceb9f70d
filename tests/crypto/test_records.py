"""Tests of hevr.crypto.records: fixed-width big-endian records <-> lists of mpz."""

from __future__ import annotations

import numpy as np
import pytest
from gmpy2 import mpz
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr.crypto.records as mb
from hevr.crypto.records import bytes_to_mpz, mpz_to_bytes
from hevr.errors import ParameterError


def _reference(arr: np.ndarray) -> list[int]:
    flat = arr.reshape(-1, arr.shape[-1])
    return [int.from_bytes(bytes(row), "big") for row in flat]


@pytest.mark.parametrize("width", [1, 7, 64, 512])
@pytest.mark.parametrize("shape", [(5,), (2, 3)])
def test_decode_matches_int_from_bytes(width, shape):
    rng = np.random.default_rng(width)
    arr = rng.integers(0, 256, shape + (width,), dtype=np.uint8)
    got = bytes_to_mpz(arr)
    assert got == _reference(arr)
    assert all(isinstance(v, type(mpz(0))) for v in got)


def test_round_trip_extremes():
    width = 16
    values = [mpz(0), mpz(1), mpz(255), mpz(256), mpz(256) ** width - 1]
    arr = mpz_to_bytes(values, width)
    assert arr.shape == (5, width) and arr.dtype == np.uint8
    assert arr.flags.c_contiguous and arr.flags.writeable
    assert arr[0].tolist() == [0] * width and arr[-1].tolist() == [255] * width
    assert bytes_to_mpz(arr) == values


def test_non_contiguous_input():
    rng = np.random.default_rng(1)
    base = rng.integers(0, 256, (6, 40), dtype=np.uint8)
    view = base[::2, 3:35]  # strided rows, offset columns
    assert not view.flags.c_contiguous
    assert bytes_to_mpz(view) == _reference(np.ascontiguousarray(view))


def test_empty():
    assert bytes_to_mpz(np.zeros((0, 8), np.uint8)) == []
    assert bytes_to_mpz(np.zeros((3, 0, 8), np.uint8)) == []
    out = mpz_to_bytes([], 8)
    assert out.shape == (0, 8) and out.dtype == np.uint8


def test_python_ints_generators_and_numpy_ints():
    assert mpz_to_bytes((v for v in [1, 2**20]), 3).tolist() == [[0, 0, 1], [16, 0, 0]]
    assert mpz_to_bytes([np.int64(5), np.uint16(258)], 2).tolist() == [[0, 5], [1, 2]]


@pytest.mark.parametrize(
    "arr",
    [
        np.zeros((2, 4), np.int8),
        np.zeros((2, 4), np.uint16),
        np.array(5, np.uint8),
        np.zeros((3, 0), np.uint8),
        [[1, 2]],
    ],
)
def test_decode_rejects_bad_arrays(arr):
    with pytest.raises(ParameterError, match="arr"):
        bytes_to_mpz(arr)


@pytest.mark.parametrize(
    "values, width, match",
    [
        ([1, 256], 1, r"values\[1\].*does not fit"),
        ([mpz(2) ** 64], 8, r"values\[0\].*does not fit"),
        ([3, -1], 4, r"values\[1\].*non-negative"),
        ([1.0], 4, r"values\[0\].*integer"),
        (["12"], 4, r"values\[0\].*integer"),
        ([None], 4, r"values\[0\].*integer"),
        ([1], 0, "width"),
        ([1], 2.0, "width"),
        ([1], True, "width"),
    ],
)
def test_encode_rejects_bad_values(values, width, match):
    with pytest.raises(ParameterError, match=match):
        mpz_to_bytes(values, width)
    with pytest.raises(ValueError):  # ParameterError is also a ValueError
        mpz_to_bytes(values, width)


def test_fallback_without_native_from_bytes(monkeypatch):
    """Older gmpy2 (< 2.3) lacks mpz.from_bytes/to_bytes: the int path must agree."""
    rng = np.random.default_rng(7)
    arr = rng.integers(0, 256, (9, 33), dtype=np.uint8)
    fast = bytes_to_mpz(arr)
    monkeypatch.setattr(mb, "_HAS_NATIVE_BYTES", False)
    assert bytes_to_mpz(arr) == fast
    assert np.array_equal(mpz_to_bytes(fast, 33), arr)
    with pytest.raises(ParameterError, match="does not fit"):
        mpz_to_bytes([mpz(1) << 264], 33)


@settings(max_examples=60, deadline=None)
@given(width=st.integers(1, 70), data=st.data())
def test_round_trip_random(width, data):
    values = data.draw(st.lists(st.integers(0, 256**width - 1), max_size=12))
    arr = mpz_to_bytes([mpz(v) for v in values], width)
    assert arr.shape == (len(values), width)
    assert bytes_to_mpz(arr) == values
    assert np.array_equal(mpz_to_bytes(values, width), arr)  # Python ints too
