"""Brick footprints: conservative image rectangles and tiles; subset ray casts equal the whole."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hevr.image.tiles import TileLayout
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.footprint import Footprint, brick_footprints
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.geometry.weights import brick_grid, brick_weights

SPACINGS = [0.5, 0.8, 1.0, 1.3, 2.0]
KINDS = ["orbit", "inside", "axis", "near"]
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _extent(shape, spacing) -> np.ndarray:
    nz, ny, nx = shape
    return np.array([(nx - 1) * spacing[0], (ny - 1) * spacing[1], (nz - 1) * spacing[2]], np.float64)


def _unit(draw) -> np.ndarray:
    """A random direction, never close to zero length."""
    # on a 1e-3 grid: exact zeros (axis-parallel rays) but no subnormal components, whose
    # 1/d overflows with a RuntimeWarning in cast_rays (harmless, reported separately)
    v = np.array([draw(st.integers(-1000, 1000)) / 1000 for _ in range(3)])
    i = int(np.argmax(np.abs(v)))
    v[i] += 2.0 if v[i] >= 0 else -2.0
    return v / np.linalg.norm(v)


def _up_for(draw, d: np.ndarray) -> tuple:
    """A view-up far from parallel to ``d``."""
    up = _unit(draw)
    if np.linalg.norm(np.cross(up, d)) < 0.3:
        up = np.cross(d, [0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.cross(d, [1.0, 0.0, 0.0])
    return tuple(up)


@st.composite
def cameras(draw, shape, spacing, width, height):
    """Perspective or parallel cameras: orbiting, inside the volume, along an axis, beside a face."""
    kind = draw(st.sampled_from(KINDS))
    parallel = draw(st.booleans())
    ext = _extent(shape, spacing)
    centre = ext / 2
    scale = draw(st.floats(0.3, 6.0)) if parallel else None
    if kind == "orbit":
        return Camera.orbit(
            shape,
            azimuth=draw(st.floats(-180, 180)),
            elevation=draw(st.floats(-89, 89)),
            width=width,
            height=height,
            spacing=spacing,
            parallel=parallel,
            view_angle=draw(st.floats(10, 100)),
        )
    if kind == "inside":  # the camera stands inside the voxel-centre box
        pos = np.array([draw(st.floats(0, 1)) for _ in range(3)]) * ext
        d = _unit(draw)
        return Camera(
            tuple(pos),
            tuple(pos + d),
            _up_for(draw, d),
            view_angle=draw(st.floats(20, 150)),
            width=width,
            height=height,
            parallel=parallel,
            parallel_scale=scale,
        )
    if kind == "axis":  # looking exactly along +-x, +-y or +-z, pixel centres on voxel rows
        ax, sign = draw(st.integers(0, 2)), draw(st.sampled_from([-1.0, 1.0]))
        off = np.zeros(3)
        off[ax] = sign * (ext.max() + draw(st.floats(1, 10)))
        shift = np.array([draw(st.integers(-2, 2)) * 0.5 * spacing[i] for i in range(3)])
        shift[ax] = 0.0
        pos = centre + shift + off
        up = np.zeros(3)
        up[(ax + 1) % 3] = 1.0
        if parallel:
            scale = draw(st.sampled_from([height / 2 * spacing[(ax + 1) % 3], ext.max() / 2 + 0.5, scale]))
        return Camera(
            tuple(pos), tuple(pos - off), tuple(up), width=width, height=height, parallel=parallel, parallel_scale=scale
        )
    # "near": on, or just beside, a face of the voxel box or of a brick's grown box
    sp = np.asarray(spacing)
    pos = np.array([draw(st.floats(-sp[i] - 0.3, ext[i] + sp[i] + 0.3)) for i in range(3)])
    ax = draw(st.integers(0, 2))
    pos[ax] = draw(st.sampled_from([-sp[ax], 0.0, ext[ax], ext[ax] + sp[ax], -0.5 * sp[ax], -1e-9, ext[ax] + 1e-9]))
    foc = centre + np.array([draw(st.floats(-1, 1)) for _ in range(3)]) * ext.max()
    if np.linalg.norm(foc - pos) < 1e-3:
        foc = pos + 1.0
    d = (foc - pos) / np.linalg.norm(foc - pos)
    return Camera(
        tuple(pos),
        tuple(foc),
        _up_for(draw, d),
        view_angle=draw(st.sampled_from([5.0, 30.0, 90.0, 170.0])),
        width=width,
        height=height,
        parallel=parallel,
        parallel_scale=scale,
    )


@st.composite
def scenes(draw):
    shape = tuple(draw(st.integers(2, 9)) for _ in range(3))
    brick = tuple(draw(st.integers(1, s)) for s in shape)  # often not dividing the shape
    spacing = tuple(draw(st.sampled_from(SPACINGS)) for _ in range(3))
    width, height = draw(st.integers(1, 15)), draw(st.integers(1, 15))
    cam = draw(cameras(shape, spacing, width, height))
    sampling = draw(st.sampled_from(["nearest", "trilinear"]))
    step = draw(st.sampled_from([0.3, 0.5, 0.7, 1.0, 1.5]))
    tile = draw(st.integers(1, 8))
    return shape, brick, spacing, cam, sampling, step, tile


def _check_footprints(shape, brick, spacing, cam, sampling, step, tile) -> int:
    """Every pixel a brick's weights reach lies in its rectangle and planned tiles; returns #bricks seen."""
    rays = cast_rays(cam, shape, spacing, step)
    hit = rays.n_samples > 0
    prints = brick_footprints(cam, shape, spacing, brick, hit, tile)
    W, H = cam.width, cam.height
    lay = TileLayout(W, H, tile)
    grid = brick_grid(shape, brick)
    assert set(prints) <= set(np.ndindex(*grid))
    assert list(prints) == sorted(prints)  # brick raster order
    for idx, fp in prints.items():
        r0, r1, c0, c1 = fp.rect
        assert 0 <= r0 < r1 <= H and 0 <= c0 < c1 <= W, (idx, fp)
        assert list(fp.tiles) == sorted(set(fp.tiles))
        inside = hit.reshape(H, W)[r0:r1, c0:c1]
        assert inside.any()  # only bricks whose rectangle holds a hit pixel get a footprint
        # a planned tile overlaps the rectangle and holds a hit pixel inside it; no other tile does
        rect_hits = fp.pixels(W)[hit[fp.pixels(W)]]
        assert set(fp.tiles) == set(lay.ids(rect_hits).tolist())
    seen = 0
    for idx in np.ndindex(*grid):
        bw = brick_weights(rays, shape, spacing, brick, idx, sampling, step, 3)
        if bw.rays.size == 0:
            continue
        seen += 1
        assert idx in prints, f"brick {idx} has weights but no footprint"
        fp = prints[idx]
        rows, cols = np.divmod(bw.rays, W)
        r0, r1, c0, c1 = fp.rect
        outside = ~((rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1))
        assert not outside.any(), f"brick {idx}: pixels {bw.rays[outside].tolist()} outside {fp.rect}"
        missing = set(lay.ids(bw.rays).tolist()) - set(fp.tiles)
        assert not missing, f"brick {idx}: tiles {sorted(missing)} not in {fp.tiles}"
    return seen


@SETTINGS
@given(scenes())
def test_footprints_are_conservative(scene):
    _check_footprints(*scene)


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("parallel", [False, True], ids=["perspective", "parallel"])
@pytest.mark.parametrize("view", ["orbit", "inside", "x-axis", "y-axis", "z-axis"])
def test_footprints_are_conservative_fixed_views(view, parallel, sampling):
    """Hand-picked views on an odd-shaped, anisotropic volume with bricks that do not divide it."""
    shape, brick, spacing = (7, 9, 11), (3, 4, 5), (0.8, 1.1, 1.3)
    ext = _extent(shape, spacing)
    c = ext / 2
    scale = 6.0 if parallel else None
    if view == "orbit":
        cam = Camera.orbit(shape, azimuth=33, elevation=21, width=17, height=13, spacing=spacing, parallel=parallel)
    elif view == "inside":
        cam = Camera(
            tuple(c + [0.3, -0.2, 0.1]),
            tuple(c + [5.0, 1.0, 2.0]),
            view_angle=100,
            width=16,
            height=12,
            parallel=parallel,
            parallel_scale=scale,
        )
    else:
        ax = "xyz".index(view[0])
        off = np.zeros(3)
        off[ax] = 20.0
        up = (0.0, 0.0, 1.0) if view[0] == "y" else (0.0, 1.0, 0.0)
        cam = Camera(tuple(c + off), tuple(c), up, width=12, height=11, parallel=parallel, parallel_scale=scale)
    assert _check_footprints(shape, brick, spacing, cam, sampling, 0.7, 4) >= 3


def test_camera_inside_a_brick_sees_it_over_the_whole_image():
    shape, brick, spacing = (8, 8, 8), (4, 4, 4), (1.0, 1.0, 1.0)
    cam = Camera((1.5, 1.5, 1.5), (7.0, 6.0, 5.0), width=9, height=7, view_angle=120)
    rays = cast_rays(cam, shape, spacing, 0.5)
    prints = brick_footprints(cam, shape, spacing, brick, rays.n_samples > 0, 3)
    assert prints[(0, 0, 0)].rect == (0, 7, 0, 9)
    assert prints[(0, 0, 0)].tiles == tuple(range(TileLayout(9, 7, 3).n_tiles))
    assert _check_footprints(shape, brick, spacing, cam, "trilinear", 0.5, 3) >= 2


def test_bricks_behind_the_camera_get_no_footprint():
    """A camera in the volume looking +x: the bricks wholly behind it (x far below) get no task."""
    shape, brick, spacing = (8, 8, 16), (4, 4, 4), (1.0, 1.0, 1.0)
    for parallel in (False, True):
        cam = Camera(
            (10.5, 3.5, 3.5),
            (20.0, 3.5, 3.5),
            width=8,
            height=8,
            view_angle=60,
            parallel=parallel,
            parallel_scale=3.0 if parallel else None,
        )
        rays = cast_rays(cam, shape, spacing, 0.5)
        prints = brick_footprints(cam, shape, spacing, brick, rays.n_samples > 0, 4)
        assert prints and all(bx >= 2 for _, _, bx in prints), sorted(prints)  # bx 0, 1 lie behind (x < 8)
        _check_footprints(shape, brick, spacing, cam, "trilinear", 0.5, 4)


def test_no_hit_pixels_no_footprints():
    cam = Camera.orbit((6, 6, 6), azimuth=10, elevation=10, width=8, height=8)
    assert brick_footprints(cam, (6, 6, 6), (1, 1, 1), (2, 2, 2), np.zeros(64, bool), 4) == {}
    # one hit pixel: only bricks whose rectangle holds it, each with exactly that pixel's tile
    hit = np.zeros(64, bool)
    hit[3 * 8 + 5] = True
    prints = brick_footprints(cam, (6, 6, 6), (1, 1, 1), (2, 2, 2), hit, 4)
    assert 0 < len(prints) < 27
    assert all(fp.tiles == (TileLayout(8, 8, 4).ids([29])[0],) for fp in prints.values())
    assert all(fp.rect[0] <= 3 < fp.rect[1] and fp.rect[2] <= 5 < fp.rect[3] for fp in prints.values())


def test_footprint_pixels():
    fp = Footprint((1, 3, 2, 5), (0,))
    assert fp.pixels(7).tolist() == [9, 10, 11, 16, 17, 18]
    assert fp.pixels(7).dtype == np.int64


# -- subsets of the ray set: what a map task casts ------------------------------------------------------


def _bits(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    return a.view(np.uint64) if a.dtype == np.float64 else a


@SETTINGS
@given(scenes(), st.data())
def test_subset_cast_is_bit_identical(scene, data):
    shape, _, spacing, cam, _, step, _ = scene
    n = cam.width * cam.height
    full = cast_rays(cam, shape, spacing, step)
    assert full.pixel_ids is None and full.n_rays == n
    pix = data.draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=2 * n))  # unsorted, with repeats
    sub = cast_rays(cam, shape, spacing, step, pixels=np.array(pix))
    ids = np.unique(pix)
    assert np.array_equal(sub.pixel_ids, ids) and sub.pixel_ids.dtype == np.int64
    assert sub.n_rays == ids.size and (sub.width, sub.height) == (cam.width, cam.height)
    for name in ("origins", "directions", "t_enter", "t_exit", "n_samples"):
        a, b = getattr(sub, name), getattr(full, name)[ids]
        assert a.dtype == b.dtype and a.shape == b.shape
        assert np.array_equal(_bits(a), _bits(b)), name  # bit for bit, also the signs of zeros
    assert np.array_equal(sub.global_ids(np.arange(ids.size)), ids)


@SETTINGS
@given(scenes(), st.data())
def test_weights_of_footprint_rays_equal_whole_image(scene, data):
    """A map task's weights (its footprint's rays only) equal the brick's weights on the whole image."""
    shape, brick, spacing, cam, sampling, step, tile = scene
    W = cam.width
    full = cast_rays(cam, shape, spacing, step)
    prints = brick_footprints(cam, shape, spacing, brick, full.n_samples > 0, tile)
    digits = data.draw(st.integers(0, 4))
    for idx in np.ndindex(*brick_grid(shape, brick)):
        want = brick_weights(full, shape, spacing, brick, idx, sampling, step, digits)
        if idx not in prints:
            assert want.rays.size == 0
            continue
        pix = prints[idx].pixels(W)
        extra = data.draw(st.lists(st.integers(0, full.n_rays - 1), max_size=5))
        for subset in (pix, np.concatenate([pix, np.array(extra, np.int64)])):
            rays = cast_rays(cam, shape, spacing, step, pixels=subset)
            got = brick_weights(rays, shape, spacing, brick, idx, sampling, step, digits)
            assert got.brick == want.brick and got.exponent == want.exponent
            for name in ("rays", "indptr", "voxels", "weights"):
                a, b = getattr(got, name), getattr(want, name)
                assert a.dtype == b.dtype == np.int64 and np.array_equal(a, b), (idx, name)


def test_subset_cast_rejects_out_of_range_pixels():
    from hevr.errors import ParameterError

    cam = Camera.orbit((4, 4, 4), width=3, height=2)
    with pytest.raises(ParameterError, match="pixels"):
        cast_rays(cam, (4, 4, 4), (1, 1, 1), 1.0, pixels=[0, 6])
    with pytest.raises(ParameterError, match="pixels"):
        cast_rays(cam, (4, 4, 4), (1, 1, 1), 1.0, pixels=[-1])
    empty = cast_rays(cam, (4, 4, 4), (1, 1, 1), 1.0, pixels=np.zeros(0, np.int64))
    assert empty.n_rays == 0 and empty.pixel_ids.size == 0
