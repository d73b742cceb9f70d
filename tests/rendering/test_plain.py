"""Tests for hevr.rendering.reference.plain.render_plain, the plaintext reference renderer."""

from __future__ import annotations

import math

import numpy as np
import pytest

import hevr
from hevr.errors import HevrError, ParameterError
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.planning.modes import parse_color
from hevr.rendering.reference.plain import render_plain
from hevr.volume.density import encode_density

_NODES = [(0.279, (0, 0, 1)), (0.797, "red"), (0.5, "#00ff00")]
_MODE_KW = {"xray": {}, "emphasize": {"density": 0.653}, "tf": {"nodes": _NODES}}


def column_camera(shape: tuple, spacing: tuple, pad: float = 0.0) -> Camera:
    """Parallel camera looking down -z, pixel centres exactly on the voxel columns (sx == sy)."""
    nz, ny, nx = shape
    sx, sy, sz = spacing
    centre = ((nx - 1) * sx / 2, (ny - 1) * sy / 2)
    return Camera(
        (*centre, (nz - 1) * sz + 7.0),
        (*centre, 0.0),
        width=nx,
        height=ny,
        parallel=True,
        parallel_scale=ny * sy / 2 + pad,
    )


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.7, 0.7, 1.9), (2.0, 2.0, 0.3)])
@pytest.mark.parametrize("shape", [(5, 7, 9), (9, 5, 3), (3, 11, 7)])
def test_axis_aligned_parallel_xray_is_mean_projection(shape: tuple, spacing: tuple, sampling: str) -> None:
    vol = np.random.default_rng(sum(shape)).random(shape) * 100
    img = render_plain(
        vol, column_camera(shape, spacing), mode="xray", sampling=sampling, step=spacing[2], spacing=spacing
    )
    # Pins the conventions: x to the right, y up (row 0 on top), border rows/columns kept.
    np.testing.assert_allclose(img, np.flipud(vol.mean(axis=0)), rtol=1e-12, atol=1e-12)


def test_axis_aligned_side_view() -> None:
    # Looking down -x: right = -z, so columns run from z = nz-1 down to z = 0.
    shape, spacing = (5, 7, 9), (1.0, 1.0, 1.0)
    vol = np.random.default_rng(0).random(shape)
    nz, ny, nx = shape
    cam = Camera(
        (nx + 5.0, (ny - 1) / 2, (nz - 1) / 2),
        (0.0, (ny - 1) / 2, (nz - 1) / 2),
        width=nz,
        height=ny,
        parallel=True,
        parallel_scale=ny / 2,
    )
    img = render_plain(vol, cam, sampling="trilinear", spacing=spacing)
    np.testing.assert_allclose(img, vol.mean(axis=2).T[::-1, ::-1], atol=1e-12)


@pytest.mark.parametrize("mode", ["xray", "emphasize", "tf"])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_missing_rays_are_zero(mode: str, sampling: str) -> None:
    shape = (5, 7, 9)
    vol = np.random.default_rng(1).integers(1, 255, shape).astype(np.uint8)
    img = render_plain(vol, column_camera(shape, (1, 1, 1), pad=3.0), mode=mode, sampling=sampling, **_MODE_KW[mode])
    hit = cast_rays(column_camera(shape, (1, 1, 1), pad=3.0), shape, (1, 1, 1), 1.0).n_samples > 0
    flat = img.reshape(hit.size, -1)
    assert np.all(flat[~hit] == 0) and np.all(flat[hit].sum(axis=1) > 0)
    away = Camera((4, 3, 20), (4, 3, 40), width=4, height=3)
    assert not render_plain(vol, away, mode=mode, sampling=sampling, **_MODE_KW[mode]).any()


def _reference(vol, cam, mode, sampling, step, spacing, value_range, k, density=None, nodes=None):
    """Slow per-sample renderer written straight from API.md (interpolates encoded vectors)."""
    rs = cast_rays(cam, vol.shape, spacing, step)
    lo, hi = value_range
    enc = encode_density(np.clip((vol.astype(float) - lo) / (hi - lo), 0, 1), k)
    nz, ny, nx = vol.shape
    sp = np.asarray(spacing, dtype=float)
    out = np.zeros((rs.n_rays, 3 if mode == "tf" else 1))

    def voxel(field, x, y, z):
        return field[min(max(z, 0), nz - 1), min(max(y, 0), ny - 1), min(max(x, 0), nx - 1)]

    def sample(field, p):
        if sampling == "nearest":
            return voxel(field, *(math.floor(c + 0.5) for c in p))
        b = [math.floor(c) for c in p]
        f = [c - bb for c, bb in zip(p, b)]
        acc = 0.0
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    w = (f[0] if dx else 1 - f[0]) * (f[1] if dy else 1 - f[1]) * (f[2] if dz else 1 - f[2])
                    acc = acc + w * voxel(field, b[0] + dx, b[1] + dy, b[2] + dz)
        return acc

    for r in range(rs.n_rays):
        n = int(rs.n_samples[r])
        for kk in range(n):
            p = (rs.origins[r] + (rs.t_enter[r] + kk * step) * rs.directions[r]) / sp
            if mode == "xray":
                out[r] += sample(vol.astype(float), p) / n
            else:
                s = sample(enc, p)
                if mode == "emphasize":
                    out[r] += s @ encode_density(density, k) / n
                else:
                    for d, c in nodes:
                        out[r] += (s @ encode_density(d, k)) * np.array(parse_color(c)) / (n * len(nodes))
    return out.reshape((cam.height, cam.width) + ((3,) if mode == "tf" else ()))


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("mode", ["xray", "emphasize", "tf"])
def test_matches_slow_reference(mode: str, sampling: str, parallel: bool) -> None:
    shape, spacing, step = (5, 6, 7), (0.9, 1.2, 1.5), 0.8
    vol = np.random.default_rng(7).integers(0, 4096, shape).astype(np.uint16)
    cam = Camera.orbit(shape, azimuth=37, elevation=-23, width=7, height=5, spacing=spacing, parallel=parallel)
    kw = dict(_MODE_KW[mode])
    value_range = (100.0, 4000.0)
    img = render_plain(
        vol, cam, mode=mode, sampling=sampling, step=step, spacing=spacing, value_range=value_range, vector_dims=5, **kw
    )
    ref = _reference(vol, cam, mode, sampling, step, spacing, value_range, 5, **kw)
    assert img.shape == ref.shape and img.dtype == np.float64
    np.testing.assert_allclose(img, ref, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_constant_volume(sampling: str) -> None:
    shape = (4, 6, 5)
    vol = np.full(shape, 153, dtype=np.uint8)  # density 0.6
    cam = Camera.orbit(shape, azimuth=20, elevation=10, width=9, height=9)
    hit = (cast_rays(cam, shape, (1, 1, 1), 1.0).n_samples > 0).reshape(9, 9)
    x = render_plain(vol, cam, sampling=sampling)
    np.testing.assert_allclose(x[hit], 153.0, rtol=1e-13)
    e = render_plain(vol, cam, mode="emphasize", sampling=sampling, density=0.3)
    np.testing.assert_allclose(e[hit], encode_density(0.6, 4) @ encode_density(0.3, 4), rtol=1e-12)
    t = render_plain(vol, cam, mode="tf", sampling=sampling, nodes=[(0.6, "white"), (0.0, "blue")], vector_dims=3)
    expected = (np.ones(3) + (encode_density(0.6, 3) @ encode_density(0.0, 3)) * np.array([0, 0, 1.0])) / 2
    np.testing.assert_allclose(t[hit], np.tile(expected, (hit.sum(), 1)), rtol=1e-12)


def test_value_range_defaults() -> None:
    shape = (4, 5, 6)
    rng = np.random.default_rng(2)
    vol8 = rng.integers(0, 256, shape).astype(np.uint8)
    cam = Camera.orbit(shape, 10, 10, width=6, height=6)
    kw = dict(mode="emphasize", density=0.4, sampling="trilinear")
    np.testing.assert_allclose(render_plain(vol8, cam, **kw), render_plain(vol8, cam, value_range=(0, 255), **kw))
    volf = rng.random(shape) * 7 + 3
    np.testing.assert_allclose(
        render_plain(volf, cam, **kw), render_plain(volf, cam, value_range=(volf.min(), volf.max()), **kw), atol=1e-14
    )
    # int32 data outside the LUT span goes through the direct encoder with the same result.
    vol32 = vol8.astype(np.int32) * 1000
    np.testing.assert_allclose(
        render_plain(vol32, cam, value_range=(0, 255000), **kw), render_plain(vol8, cam, **kw), atol=1e-13
    )
    assert render_plain(volf, cam, mode="tf", nodes=_NODES).shape == (6, 6, 3)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(mode="mip"), "mode"),
        (dict(sampling="cubic"), "sampling"),
        (dict(mode="emphasize"), "density"),
        (dict(mode="tf"), "nodes"),
        (dict(mode="tf", nodes=[]), "nodes"),
        (dict(mode="emphasize", density=1.2), "density"),
        (dict(mode="tf", nodes=[(0.5, (1, 2, 0))]), "color"),
        (dict(step=0), "step"),
        (dict(step=-0.5), "step"),
        (dict(spacing=(1, 1)), "spacing"),
        (dict(mode="emphasize", density=0.5, value_range=(5, 5)), "value_range"),
        (dict(mode="emphasize", density=0.5, vector_dims=1), "vector_dims"),
        (dict(camera="front"), "camera"),
        (dict(vol=np.zeros((3, 3))), "vol"),
        (dict(vol=np.full((2, 2, 2), np.nan)), "vol"),
        (dict(vol=np.zeros((2, 2, 2), dtype=complex)), "vol"),
    ],
)
def test_render_plain_rejects(kwargs: dict, match: str) -> None:
    args = dict(vol=np.zeros((3, 3, 3), dtype=np.uint8), camera=Camera.orbit((3, 3, 3), width=4, height=4))
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        render_plain(**args)


def test_degenerate_camera_is_a_hevr_error() -> None:
    with pytest.raises(HevrError, match="view_up"):
        render_plain(np.zeros((3, 3, 3)), Camera((1, 5, 1), (1, 0, 1)))


def test_chunking_does_not_change_the_result(monkeypatch: pytest.MonkeyPatch) -> None:
    import hevr.rendering.reference.plain as plain

    shape = (6, 7, 8)
    vol = np.random.default_rng(4).random(shape)
    cam = Camera.orbit(shape, 15, 25, width=11, height=9)
    full = render_plain(vol, cam, sampling="trilinear", step=0.5)
    monkeypatch.setattr(plain, "_CHUNK_SAMPLES", 17)
    np.testing.assert_array_equal(render_plain(vol, cam, sampling="trilinear", step=0.5), full)


def test_a_scan_brings_its_spacing():
    """render_plain / render_slice_plain take a hevr.Scan as encrypt_volume does (issue 29, item 9)."""
    vol = np.arange(4 * 5 * 6, dtype=np.uint8).reshape(4, 5, 6)
    scan = hevr.Scan(volume=vol, spacing=(0.5, 1.0, 2.0), source="s.nii")
    cam = hevr.Camera.orbit(vol.shape, azimuth=20, elevation=10, width=7, height=6, spacing=(0.5, 1.0, 2.0))
    assert np.array_equal(hevr.render_plain(scan, cam), hevr.render_plain(vol, cam, spacing=(0.5, 1.0, 2.0)))
    assert not np.array_equal(hevr.render_plain(scan, cam), hevr.render_plain(vol, cam))
    assert np.array_equal(hevr.render_plain(scan, cam, spacing=(1, 1, 1)), hevr.render_plain(vol, cam))
    plane = hevr.Plane.axial(vol.shape, 2, spacing=(0.5, 1.0, 2.0), slab=3)
    assert np.array_equal(
        hevr.render_slice_plain(scan, plane), hevr.render_slice_plain(vol, plane, spacing=(0.5, 1.0, 2.0))
    )
