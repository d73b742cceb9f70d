"""Slice planes: validation, identity, the helpers' geometry, their rays and brick footprints."""

from __future__ import annotations

import math

import numpy as np
import pytest

import hevr
from hevr.image.tiles import TileLayout
from hevr.rendering.geometry.camera import Camera
from hevr.rendering.geometry.footprint import brick_footprints
from hevr.rendering.geometry.plane import MAX_SLAB, Plane, view_from_dict
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.geometry.weights import brick_grid, brick_weights
from hevr.rendering.planning.planner import check_render_size

X, Y, Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)


def _plane(**kw):
    args = dict(origin=(0, 0, 0), u=X, v=Y, width=4, height=3)
    args.update(kw)
    return Plane(**args)


# -- validation ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kw, match",
    [
        ({"v": (2, 0, 0)}, r"^v: expected a direction not parallel to u = \(1.0, 0.0, 0.0\)"),
        ({"v": (-1, 1e-12, 0)}, r"^v: expected a direction not parallel to u"),
        ({"v": (1, 1, 0)}, r"^v: expected a direction orthogonal to u .* at 45 degrees"),
        ({"u": (0, 0, 0)}, r"^u: expected a non-zero direction"),
        ({"v": (0, float("nan"), 0)}, r"^v: expected 3 finite numbers"),
        ({"origin": (0, float("nan"), 0)}, r"^origin: expected 3 finite numbers"),
        ({"origin": (0, 1)}, r"^origin: expected 3 finite numbers"),
        ({"width": 0}, r"^width: expected a positive integer, got 0"),
        ({"height": 0}, r"^height: expected a positive integer, got 0"),
        ({"width": 2.5}, r"^width: expected a positive integer"),
        ({"pixel_spacing": 0}, r"^pixel_spacing: expected a positive pixel spacing"),
        ({"pixel_spacing": float("nan")}, r"^pixel_spacing: expected"),
        ({"pixel_spacing": (1, -1)}, r"^pixel_spacing: expected"),
        ({"pixel_spacing": (1, 2, 3)}, r"^pixel_spacing: expected"),
        ({"pixel_spacing": "1"}, r"^pixel_spacing: expected"),
        ({"pixel_spacing": True}, r"^pixel_spacing: expected"),
        ({"slab": 0}, r"^slab: expected an integer in \[1, 65536\], got 0"),
        ({"slab": MAX_SLAB + 1}, r"^slab: expected an integer in"),
        ({"slab": 1.5}, r"^slab: expected an integer in"),
        ({"slab_step": 0}, r"^slab_step: expected a positive finite number"),
        ({"slab_step": float("inf")}, r"^slab_step: expected a positive finite number"),
    ],
)
def test_bad_planes_are_refused_naming_the_parameter(kw, match):
    with pytest.raises(hevr.ParameterError, match=match):
        _plane(**kw)


def test_directions_are_normalised_and_spacing_is_a_pair():
    p = _plane(u=(3, 0, 0), v=(0, 0, -0.5), pixel_spacing=2)
    assert p.u == X and p.v == (0.0, 0.0, -1.0) and p.pixel_spacing == (2.0, 2.0)
    assert p.normal.tolist() == [0.0, 1.0, 0.0]  # x × (−z) = +y
    assert _plane(pixel_spacing=(0.5, np.float32(2))).pixel_spacing == (0.5, 2.0)


def test_identity_round_trips_and_tells_planes_from_cameras():
    a = 0.3
    p = Plane(
        (1.5, -2, 3),
        (math.cos(a), math.sin(a), 0),
        (-math.sin(a), math.cos(a), 0),
        7,
        5,
        pixel_spacing=(0.7, 1.1),
        slab=4,
        slab_step=0.6,
    )
    q = Plane.from_dict(p.to_dict())
    assert q == p and q.key() == p.key() and hash(q) == hash(p)
    assert Plane.from_dict(q.to_dict()) == p  # normalising is idempotent: no drift
    assert view_from_dict(p.to_dict()) == p
    cam = Camera((0, 0, 5), (0, 0, 0))
    assert view_from_dict(cam.to_dict()) == cam
    assert p.to_dict()["kind"] == "plane"
    keys = {
        p.key(),
        cam.key(),
        _plane().key(),
        _plane(slab=3).key(),
        _plane(slab_step=2).key(),
        _plane(pixel_spacing=(1, 2)).key(),
        _plane(origin=(0, 0, 1e-9)).key(),
    }
    assert len(keys) == 7
    with pytest.raises(hevr.ParameterError, match="extra keys"):
        Plane.from_dict({**p.to_dict(), "position": [0, 0, 0]})
    with pytest.raises(hevr.ParameterError, match="kind 'plane'"):
        Plane.from_dict({**p.to_dict(), "kind": "camera"})
    with pytest.raises(hevr.ParameterError, match="missing"):
        Plane.from_dict({"origin": [0, 0, 0], "u": list(X), "v": list(Y)})
    with pytest.raises(hevr.ParameterError, match="^data: expected a dict"):
        Plane.from_dict([1, 2])


# -- helpers ------------------------------------------------------------------------------------
SHAPE, SPACING = (4, 3, 5), (0.5, 2.0, 1.5)  # (nz, ny, nx), (sx, sy, sz)


def _voxel_centres(index_grid):
    return np.stack([index_grid[2] * SPACING[0], index_grid[1] * SPACING[1], index_grid[0] * SPACING[2]], -1)


@pytest.mark.parametrize(
    "kind, index, sl",
    [("axial", 2, lambda a: a[2]), ("coronal", 1, lambda a: a[:, 1, :]), ("sagittal", 3, lambda a: a[:, :, 3])],
)
def test_aligned_helpers_put_every_pixel_on_the_array_slice(kind, index, sl):
    p = getattr(Plane, kind)(SHAPE, index, spacing=SPACING)
    grid = np.indices(SHAPE)
    want = sl(_voxel_centres(grid))  # (H, W, 3): the world centres of the array slice
    assert (p.height, p.width) == want.shape[:2]
    assert np.array_equal(p.centres().reshape(want.shape), want)


def test_aligned_helpers_orientation_and_spacing():
    ax = Plane.axial(SHAPE, 1, spacing=SPACING)
    assert (ax.u, ax.v, ax.normal.tolist()) == (X, Y, [0, 0, 1]) and ax.pixel_spacing == (0.5, 2.0)
    assert ax.slab_step == 1.5  # default slab step: the spacing along the normal
    co = Plane.coronal(SHAPE, 1, spacing=SPACING)
    assert (co.u, co.v, co.normal.tolist()) == (X, Z, [0, -1, 0])
    sa = Plane.sagittal(SHAPE, 1, spacing=SPACING)
    assert (sa.u, sa.v, sa.normal.tolist()) == (Y, Z, [1, 0, 0])
    ev_like = type("EV", (), {"shape": SHAPE, "spacing": SPACING})()
    assert Plane.axial(ev_like, 1) == ax  # a volume-like object gives shape and spacing


def test_size_or_spacing_alone_fit_the_extent():
    ext_x, ext_y = (SHAPE[2] - 1) * SPACING[0], (SHAPE[1] - 1) * SPACING[1]  # 2.0, 4.0
    p = Plane.axial(SHAPE, 0, width=9, height=9, spacing=SPACING)
    assert p.pixel_spacing == (0.5, 0.5)  # square pixels: the larger extent (y, 4.0) over 8 steps
    c = p.centres().reshape(9, 9, 3)
    assert np.allclose(c[0, :, 1].min(), 0.0) and np.allclose(c[-1, 0, 1], ext_y)  # y spans the volume
    assert np.allclose(c[0, 4, 0], ext_x / 2)  # centred along x
    q = Plane.axial(SHAPE, 0, pixel_spacing=0.25, spacing=SPACING)
    assert (q.width, q.height) == (9, 17)
    r = Plane.axial(SHAPE, 0, width=3, spacing=SPACING)
    assert r.pixel_spacing == (1.0, 1.0) and r.height == 5


@pytest.mark.parametrize("kind, bad", [("axial", 4), ("axial", -0.5), ("coronal", 3), ("sagittal", float("nan"))])
def test_helper_index_out_of_the_volume_is_refused(kind, bad):
    name = {"axial": "k", "coronal": "j", "sagittal": "i"}[kind]
    with pytest.raises(hevr.ParameterError, match=f"^{name}: expected a position in"):
        getattr(Plane, kind)(SHAPE, bad)


def test_oblique_defaults_reproduce_the_aligned_orientations():
    for normal, u, v in [((0, 0, 1), X, Y), ((0, -1, 0), X, Z), ((1, 0, 0), Y, Z)]:
        p = Plane.oblique(SHAPE, normal=normal, width=3, height=3, spacing=SPACING)
        assert np.allclose(p.u, u) and np.allclose(p.v, v) and np.allclose(p.normal, normal)


def test_oblique_geometry():
    c = (1.0, 2.0, 2.5)
    p = Plane.oblique(
        SHAPE, c, normal=(1, 2, 3), v=(0, 0, 1), width=5, height=7, pixel_spacing=(0.5, 0.25), spacing=SPACING, slab=3
    )
    u, v, n = p.basis()
    assert np.allclose([u @ u, v @ v, n @ n], 1) and np.allclose([u @ v, u @ n, v @ n], 0, atol=1e-15)
    assert np.allclose(n, np.array([1, 2, 3]) / math.sqrt(14))
    hint = np.array([0.0, 0.0, 1.0]) - n[2] * n  # the hint, made orthogonal to n
    assert np.allclose(v, hint / np.linalg.norm(hint)) and np.allclose(np.cross(u, v), n)
    assert np.allclose(p.centres([3 * 5 + 2])[0], c)  # the middle pixel sits on the centre
    assert p.slab_step == 0.5  # the smallest voxel spacing
    d = Plane.oblique(SHAPE, spacing=SPACING)  # default centre, size and spacing
    assert np.allclose(d.centres([(d.height // 2) * d.width + d.width // 2])[0], [1.0, 2.0, 2.25])
    diag = math.dist((0, 0, 0), (2.0, 4.0, 4.5))
    assert d.width == d.height == math.floor(diag / 0.5) + 1
    with pytest.raises(hevr.ParameterError, match="^v: expected a direction not parallel to normal"):
        Plane.oblique(SHAPE, normal=(0, 0, 1), v=(0, 0, -2))
    with pytest.raises(hevr.ParameterError, match="^normal: expected a non-zero direction"):
        Plane.oblique(SHAPE, normal=(0, 0, 0))
    with pytest.raises(hevr.ParameterError, match="^center: expected 3 finite numbers"):
        Plane.oblique(SHAPE, center=(1, 2))


# -- rays ---------------------------------------------------------------------------------------------
def test_rays_start_at_the_first_slab_plane_and_subsets_are_bit_identical():
    p = Plane.oblique(SHAPE, normal=(0.2, -1, 0.4), width=6, height=5, spacing=SPACING, slab=4, slab_step=0.3)
    o, d = p.rays()
    assert np.allclose(o, p.centres() - 1.5 * 0.3 * p.normal)
    assert np.array_equal(d, np.broadcast_to(p.normal, d.shape))
    sub = [3, 17, 29]
    assert np.array_equal(p.rays(sub)[0], o[sub]) and np.array_equal(p.rays(sub)[1], d[sub])
    rs, whole = cast_rays(p, SHAPE, SPACING, 0.3, pixels=sub), cast_rays(p, SHAPE, SPACING, 0.3)
    assert np.array_equal(rs.n_samples, whole.n_samples[sub]) and np.array_equal(rs.t_enter, whole.t_enter[sub])


def test_cast_rays_keeps_the_slab_samples_inside_the_box():
    # axial at z = 1·sz with 5 planes one layer apart: z = −1, 0, 1, 2, 3 (layers); 4 layers exist
    p = Plane.axial(SHAPE, 1, slab=5, spacing=SPACING)
    rs = cast_rays(p, SHAPE, SPACING, p.slab_step)
    assert set(rs.n_samples.tolist()) == {4} and set(rs.t_index.tolist()) == {-1.0}  # samples k = 1..4 of 0..4
    # brute force: every sample position tested against the box
    for pl in (
        p,
        Plane.oblique(SHAPE, normal=(1, 1, 1), width=9, height=9, spacing=SPACING, slab=7),
        _plane(origin=(-1, 0, 0), slab=3),
    ):
        rs = cast_rays(pl, SHAPE, SPACING, pl.slab_step)
        hi = np.array([(SHAPE[2] - 1) * SPACING[0], (SHAPE[1] - 1) * SPACING[1], (SHAPE[0] - 1) * SPACING[2]])
        pts = pl.centres()[:, None, :] + pl.slab_offsets[None, :, None] * pl.normal
        inside = np.all((pts >= -1e-9) & (pts <= hi + 1e-9), axis=2)
        assert np.array_equal(rs.n_samples, inside.sum(axis=1))
        first = np.where(inside.any(axis=1), inside.argmax(axis=1), 0)
        hit = inside.any(axis=1)  # the first inside sample, counted from the pixel centre
        assert np.array_equal(rs.t_index[hit], first[hit] - (pl.slab - 1) / 2.0)
    with pytest.raises(hevr.ParameterError, match="^step: expected the plane's slab_step 1.5"):
        cast_rays(p, SHAPE, SPACING, 1.0)


def test_plane_wholly_outside_hits_nothing():
    p = _plane(origin=(0, 0, 100), slab=3)
    assert cast_rays(p, SHAPE, SPACING, 1.0).n_samples.sum() == 0
    assert brick_footprints(p, SHAPE, SPACING, (2, 2, 2), np.zeros(12, bool), 2) == {}


def test_render_size_limit_applies_to_planes():
    p = _plane(width=5000, height=5000)
    with pytest.raises(hevr.RenderPlanError, match="^width, height: expected an image of at most"):
        check_render_size(p, SHAPE, SPACING, 1.0)


# -- footprints --------------------------------------------------------------------------------------
PLANES = {
    "axial-slab": lambda s, sp: Plane.axial(s, 3, slab=3, spacing=sp),
    "coronal-fit": lambda s, sp: Plane.coronal(s, 2.5, width=13, height=11, spacing=sp),
    "sagittal": lambda s, sp: Plane.sagittal(s, 0, spacing=sp),
    "oblique": lambda s, sp: Plane.oblique(s, normal=(1, 2, 3), width=17, height=15, pixel_spacing=0.6, spacing=sp),
    "oblique-slab": lambda s, sp: Plane.oblique(
        s, normal=(-0.3, 1, 0.2), width=14, height=12, spacing=sp, slab=5, slab_step=0.7
    ),
    "partly-outside": lambda s, sp: Plane(
        (-2.0, 1.0, -1.0), (0.6, 0.8, 0.0), (0.0, 0.0, 1.0), 15, 12, pixel_spacing=0.7, slab=2
    ),
}


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("name", list(PLANES))
def test_plane_footprints_are_conservative(name, sampling):
    shape, brick, spacing, tile = (7, 9, 11), (3, 4, 5), (0.8, 1.1, 1.3), 4
    p = PLANES[name](shape, spacing)
    rays = cast_rays(p, shape, spacing, p.slab_step)
    hit = rays.n_samples > 0
    assert hit.any()
    prints = brick_footprints(p, shape, spacing, brick, hit, tile)
    lay = TileLayout(p.width, p.height, tile)
    seen = 0
    for idx in np.ndindex(*brick_grid(shape, brick)):
        bw = brick_weights(rays, shape, spacing, brick, idx, sampling, p.slab_step, 3)
        if bw.rays.size == 0:
            continue
        seen += 1
        assert idx in prints, f"brick {idx} has weights but no footprint"
        rows, cols = np.divmod(bw.rays, p.width)
        r0, r1, c0, c1 = prints[idx].rect
        assert np.all((rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)), (idx, prints[idx].rect)
        assert set(lay.ids(bw.rays).tolist()) <= set(prints[idx].tiles)
    assert seen
    # thin slices skip far bricks: an axis-aligned one-plane slice reaches at most two brick layers
    if name == "sagittal":
        assert {i[2] for i in prints} <= {0}
