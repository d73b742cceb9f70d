"""Tests for hevr.volume.phantom: the paper's cube-in-sphere test object."""

from __future__ import annotations

import numpy as np
import pytest

from hevr.errors import ParameterError
from hevr.volume.phantom import PHANTOM_LEVELS, phantom


def _levels(dtype: np.dtype) -> dict[str, float]:
    """Expected voxel value of each object for ``dtype``."""
    top = 1.0 if dtype.kind == "f" else np.iinfo(dtype).max
    return {name: dtype.type(frac if dtype.kind == "f" else round(frac * top)) for name, frac in PHANTOM_LEVELS.items()}


@pytest.mark.parametrize("size", [8, 9, 16, 33, 100])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int16, np.float32, np.float64])
def test_shape_dtype_and_exactly_four_values(size: int, dtype: type) -> None:
    vol = phantom(size, dtype=dtype)
    dt = np.dtype(dtype)
    assert vol.shape == (size, size, size)
    assert vol.dtype == dt
    expected = {dt.type(0), *_levels(dt).values()}
    assert set(np.unique(vol).tolist()) == {float(v) if dt.kind == "f" else int(v) for v in expected}


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_levels_match_the_papers_emphasis_densities(dtype: type) -> None:
    # Normalised by the dtype's range, each object sits within one step of the
    # density the paper emphasises (0.331 sphere, 0.781 cube, 0.653 small sphere).
    dt = np.dtype(dtype)
    top = 1.0 if dt.kind == "f" else float(np.iinfo(dt).max)
    vol = phantom(40, dtype=dtype)
    values = sorted(v / top for v in np.unique(vol).tolist() if v)
    assert values == pytest.approx([0.331, 0.653, 0.781], abs=0.5 / 255 + 1e-6)
    assert 0.33 <= PHANTOM_LEVELS["sphere"] < 0.34
    assert 0.78 <= PHANTOM_LEVELS["cube"] < 0.79
    assert 0.65 <= PHANTOM_LEVELS["small_sphere"] < 0.66


@pytest.mark.parametrize("size", [8, 32, 100, 101])
def test_geometry(size: int) -> None:
    vol = phantom(size)
    lv = _levels(np.dtype(np.uint8))
    c = (size - 1) / 2
    mid = size // 2
    # Cube in the centre, wrapped by the outer sphere.
    assert vol[mid, mid, mid] == lv["cube"]
    k, j, i = np.nonzero(vol == lv["cube"])
    assert np.allclose([k.mean(), j.mean(), i.mean()], c)
    sk, sj, si = np.nonzero(vol == lv["sphere"])
    assert np.allclose([sk.mean(), sj.mean(), si.mean()], c, atol=0.5)
    assert sk.min() < k.min() and sk.max() > k.max()  # the sphere wraps the cube
    # The small sphere lies entirely in the top-left-front octant: high z (slice k),
    # high y (row j), low x (column i).
    k, j, i = np.nonzero(vol == lv["small_sphere"])
    assert k.size > 0
    assert (k > c).all() and (j > c).all() and (i < c).all()
    # Nothing touches the border of the box.
    for face in (vol[0], vol[-1], vol[:, 0], vol[:, -1], vol[:, :, 0], vol[:, :, -1]):
        assert not face.any()


def test_symmetry_of_the_centred_objects() -> None:
    vol = phantom(64)
    centred = np.where(vol == _levels(np.dtype(np.uint8))["small_sphere"], 0, vol)
    for axis in range(3):
        assert np.array_equal(centred, np.flip(centred, axis=axis))


def test_deterministic() -> None:
    a, b = phantom(50), phantom(50)
    assert np.array_equal(a, b)
    assert a.flags.c_contiguous and a.flags.writeable


def test_default_size_and_small_sizes() -> None:
    assert phantom().shape == (100, 100, 100)
    assert phantom().dtype == np.uint8
    for size in (4, 5, 6, 7):  # valid, though too coarse to resolve every object
        assert phantom(size).shape == (size,) * 3
    assert phantom(np.int64(12)).shape == (12,) * 3


def test_large_size_is_fast() -> None:
    import time

    t0 = time.perf_counter()
    vol = phantom(256)
    assert time.perf_counter() - t0 < 5.0
    assert vol[128, 128, 128] == _levels(np.dtype(np.uint8))["cube"]


@pytest.mark.parametrize("size", [3, 0, -5, 4.0, 10.5, "10", None, True])
def test_invalid_size(size: object) -> None:
    with pytest.raises(ParameterError, match="size") as info:
        phantom(size)  # type: ignore[arg-type]
    assert repr(size) in str(info.value)


@pytest.mark.parametrize("dtype", [bool, np.complex64, "S4", object, "not-a-type"])
def test_invalid_dtype(dtype: object) -> None:
    with pytest.raises(ParameterError, match="dtype"):
        phantom(16, dtype=dtype)  # type: ignore[arg-type]
