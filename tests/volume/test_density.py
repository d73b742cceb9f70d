"""Tests for hevr.volume.density: the paper's Alg. 4 encodeDensity and density normalisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hevr.errors import HevrError, ParameterError
from hevr.volume.density import default_value_range, encode_density, normalize_density


def _unit(*v: float) -> list[float]:
    a = np.array(v, dtype=np.float64)
    return (a / np.linalg.norm(a)).tolist()


@pytest.mark.parametrize(
    "dims, density, expected",
    [
        (2, 0.0, _unit(1, 0)),
        (2, 0.25, _unit(1, 0.5)),
        (2, 0.5, _unit(1, 1)),
        (2, 0.75, _unit(0.5, 1)),
        (2, 1.0, _unit(0, 1)),
        (3, 0.0, _unit(1, 0, 0)),
        (3, 0.125, _unit(1, 0.5, 0)),
        (3, 0.25, _unit(1, 1, 0)),
        (3, 0.5, _unit(0, 1, 0)),
        (3, 0.625, _unit(0, 1, 0.5)),
        (3, 0.75, _unit(0, 1, 1)),
        (3, 0.875, _unit(0, 0.5, 1)),
        (3, 1.0, _unit(0, 0, 1)),
        (4, 0.25, _unit(0.5, 1, 0, 0)),
        (4, 0.5, _unit(0, 1, 1, 0)),
        (4, 0.75, _unit(0, 0, 1, 0.5)),
        (4, 0.653, _unit(0, 1 - (0.653 * 6 - 3), 1, 0)),
        (4, 1.0, _unit(0, 0, 0, 1)),
    ],
)
def test_known_values(dims: int, density: float, expected: list[float]) -> None:
    np.testing.assert_allclose(encode_density(density, dims), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dims", [2, 3, 4, 7])
def test_endpoints_are_basis_vectors(dims: int) -> None:
    # d = 1: s = 2(dim-1), f = dim - 1/2, index dim-1 -> e_{dim-1}; no index overflow.
    np.testing.assert_array_equal(encode_density(0.0, dims), np.eye(dims)[0])
    np.testing.assert_array_equal(encode_density(1.0, dims), np.eye(dims)[-1])


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1.0), st.integers(2, 9))
def test_unit_norm_and_nonnegative(d: float, dims: int) -> None:
    v = encode_density(d, dims)
    assert v.shape == (dims,)
    assert math.isclose(float(np.linalg.norm(v)), 1.0, rel_tol=0, abs_tol=1e-12)
    assert np.all(v >= 0)
    assert np.count_nonzero(v) <= 2  # at most two adjacent components are active


_GRID = np.linspace(0.0, 1.0, 2001)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 1.0), st.integers(2, 8))
def test_dot_product_peaks_at_the_encoded_density(d: float, dims: int) -> None:
    e = encode_density(d, dims)
    response = encode_density(_GRID, dims) @ e
    assert response.max() <= 1.0 + 1e-12
    assert math.isclose(float(e @ e), 1.0, abs_tol=1e-12)
    # The peak over a fine grid sits at the grid point(s) next to d.
    assert abs(_GRID[np.argmax(response)] - d) <= 1.0 / 2000 + 1e-12


@settings(max_examples=100, deadline=None)
@given(st.floats(0.0, 1.0 - 1e-6), st.integers(2, 8))
def test_continuous(d: float, dims: int) -> None:
    # HSV-like encoding: no jumps, so a tiny density change moves the vector a little.
    delta = np.linalg.norm(encode_density(d + 1e-6, dims) - encode_density(d, dims))
    assert delta < 1e-4 * dims


def test_vectorised_shape_matches_scalar() -> None:
    d = np.random.default_rng(0).random((3, 4, 5))
    out = encode_density(d, 4)
    assert out.shape == (3, 4, 5, 4) and out.dtype == np.float64
    np.testing.assert_array_equal(out[1, 2, 3], encode_density(float(d[1, 2, 3]), 4))


@pytest.mark.parametrize("bad", [-0.01, 1.01, float("nan"), [0.5, 2.0], float("inf")])
def test_density_out_of_range(bad: object) -> None:
    with pytest.raises(ParameterError, match="density"):
        encode_density(bad, 4)


@pytest.mark.parametrize("dims", [1, 0, -3, 2.0, True, "4", None])
def test_bad_dims(dims: object) -> None:
    with pytest.raises(ParameterError, match="dims"):
        encode_density(0.5, dims)  # type: ignore[arg-type]


def test_normalize_density() -> None:
    v = np.array([0, 51, 255], dtype=np.uint8)
    np.testing.assert_allclose(normalize_density(v, (0, 255)), [0, 0.2, 1])
    out = normalize_density(np.array([-5.0, 5.0, 15.0]), (0.0, 10.0))
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, [0.0, 0.5, 1.0])  # clipped to [0, 1]


@pytest.mark.parametrize("rng", [(1, 1), (2, 1), (0, float("nan")), (0,), "ab", None])
def test_normalize_density_bad_range(rng: object) -> None:
    with pytest.raises(ParameterError, match="value_range"):
        normalize_density(np.zeros(3), rng)


@pytest.mark.parametrize(
    "arr, expected",
    [
        (np.zeros(3, dtype=np.uint8), (0.0, 255.0)),
        (np.zeros(3, dtype=np.int16), (-32768.0, 32767.0)),
        (np.zeros(3, dtype=np.uint16), (0.0, 65535.0)),
        (np.array([True, False]), (0.0, 1.0)),
        (np.array([1.5, -2.0, 4.0]), (-2.0, 4.0)),
        (np.full(4, 3.0, dtype=np.float32), (3.0, 4.0)),  # constant: no division by zero
    ],
)
def test_default_value_range(arr: np.ndarray, expected: tuple[float, float]) -> None:
    assert default_value_range(arr) == expected


def test_default_value_range_rejects_nonfinite() -> None:
    with pytest.raises(HevrError, match="vol"):
        default_value_range(np.array([0.0, np.nan]))
