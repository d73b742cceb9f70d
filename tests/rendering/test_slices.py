"""Encrypted slices (render_slice) against the independent plaintext reference (render_slice_plain).

Tiny multi-brick volumes and 256-bit keys: fast, NOT secure.
"""

from __future__ import annotations

import dask
import numpy as np
import pytest
from dask.delayed import Delayed

import hevr
from hevr.rendering import (
    Plane,
    clear_cache,
    load_sums,
    recolour,
    render_slice,
    render_slice_plain,
)
from hevr.rendering.encrypted import error_bound

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

SHAPE = (8, 9, 10)  # (nz, ny, nx)
SPACING = (0.8, 1.1, 1.3)  # (sx, sy, sz), anisotropic
NODES = [(0.2, "red"), (0.6, (0, 1, 0)), (0.9, "#0000ff")]
EXTENT = np.array([(SHAPE[2] - 1) * SPACING[0], (SHAPE[1] - 1) * SPACING[1], (SHAPE[0] - 1) * SPACING[2]])


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(11).integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("slices") / "v.zarr"
    return hevr.encrypt_volume(
        volume, path, keypair256[1], brick=4, spacing=SPACING, vector_dims=4, vector_digits=4, progress=False
    )


@pytest.fixture(scope="module")
def phantom_store(tmp_path_factory, keypair256):
    path = tmp_path_factory.mktemp("slices") / "p.zarr"
    return hevr.encrypt_volume(hevr.phantom(8), path, keypair256[1], brick=4, progress=False)


def _check(ev, vol, plane, priv, sampling="nearest", mode="xray", spacing=SPACING, **kw):
    """Decrypted slice vs the plaintext reference, within error_bound; returns (got, ref, img)."""
    img = render_slice(ev, plane, mode=mode, sampling=sampling, progress=False, **kw)
    got = img.decrypt(priv)
    ref = render_slice_plain(
        vol,
        plane,
        mode=mode,
        sampling=sampling,
        spacing=spacing,
        vector_dims=ev.vector_dims,
        **{k: v for k, v in kw.items() if k in ("density", "nodes")},
    )
    bound = error_bound(ev, plane, mode, sampling, **{k: v for k, v in kw.items() if k in ("density", "nodes")})
    assert got.shape == ref.shape == bound.shape
    assert np.all(np.abs(got - ref) <= bound), float(np.abs(got - ref).max())
    return got, ref, img


# -- voxel layers are reproduced exactly ------------------------------------------------------------
def test_axial_nearest_is_the_array_layer(store, phantom_store, volume, keypair256):
    priv = keypair256[1]
    for ev, vol, sp in ((store, volume, SPACING), (phantom_store, hevr.phantom(8), (1, 1, 1))):
        for k in range(vol.shape[0]):
            got, ref, img = _check(ev, vol, Plane.axial(ev, k), priv, spacing=sp)
            assert got.shape == vol[k].shape and np.abs(got - vol[k]).max() <= 1e-9
            assert np.array_equal(ref, vol[k]) and img.hits.all()
            assert img.info["plan"]["precision"] == 0  # one sample per pixel: exact without digits


@pytest.mark.parametrize("kind, index", [("coronal", 0), ("coronal", 5), ("sagittal", 9), ("sagittal", 4)])
def test_coronal_and_sagittal_nearest_are_array_slices(store, volume, keypair256, kind, index):
    got, _, _ = _check(store, volume, getattr(Plane, kind)(store, index), keypair256[1])
    want = volume[:, index, :] if kind == "coronal" else volume[:, :, index]
    assert np.abs(got - want).max() <= 1e-9


# -- resampled planes within the error bound ----------------------------------------------------------
PLANES = {
    "axial-between": lambda ev: Plane.axial(ev, 2.4, width=13, height=12),
    "coronal-fit": lambda ev: Plane.coronal(ev, 3.7, width=16, height=11),
    "sagittal-spacing": lambda ev: Plane.sagittal(ev, 6.2, pixel_spacing=0.45),
    "oblique": lambda ev: Plane.oblique(ev, normal=(1, 2, 3), width=15, height=13, pixel_spacing=0.55),
    "oblique-v": lambda ev: Plane.oblique(
        ev, (4, 5, 3), normal=(-0.4, 0.1, 1), v=(1, 1, 0), width=12, height=14, pixel_spacing=(0.6, 0.5)
    ),
}


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("name", list(PLANES))
def test_resampled_planes_match_the_reference(store, volume, keypair256, name, sampling):
    got, ref, img = _check(store, volume, PLANES[name](store), keypair256[1], sampling=sampling)
    assert np.count_nonzero(ref) > 20
    assert np.array_equal(img.hits, _inside_mask(PLANES[name](store)))


def _inside_mask(plane):
    """Pixels with a slab sample in the voxel-centre box, by brute force."""
    pts = plane.centres()[:, None, :] + plane.slab_offsets[None, :, None] * plane.normal
    tol = 1e-9 * np.maximum(EXTENT, SPACING)
    inside = np.all((pts >= -tol) & (pts <= EXTENT + tol), axis=2).any(axis=1)
    return inside.reshape(plane.height, plane.width)


# -- thick slabs --------------------------------------------------------------------------------------
def test_thick_slab_is_the_mean_of_its_layers(store, volume, keypair256):
    priv = keypair256[1]
    for k in (0, 3, 7):  # at the borders only the layers inside count
        got, _, img = _check(store, volume, Plane.axial(store, k, slab=3), priv)
        want = volume[max(k - 1, 0) : k + 2].astype(np.float64).mean(axis=0)
        # finished on the client: the sum of the layers divided by their count in float64, exact
        assert np.abs(got - want).max() <= 1e-9 and img.finish == "client"
    got, _, _ = _check(store, volume, Plane.axial(store, 3.5, slab=4), priv)  # even: layers 2..5
    assert np.abs(got - volume[2:6].astype(np.float64).mean(axis=0)).max() <= 1e-9


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_oblique_thick_slab(store, volume, keypair256, sampling):
    plane = Plane.oblique(store, normal=(0.3, -1, 0.5), width=14, height=12, slab=5, slab_step=0.7)
    _check(store, volume, plane, keypair256[1], sampling=sampling)


# -- outside the volume -------------------------------------------------------------------------------
def test_planes_partly_or_wholly_outside(store, volume, keypair256):
    priv = keypair256[1]
    part = Plane((-3.0, -2.0, 4.0), (1, 0, 0), (0, 1, 0), 16, 15, pixel_spacing=0.9, slab=3, slab_step=0.5)
    got, ref, img = _check(store, volume, part, priv, sampling="trilinear")
    mask = _inside_mask(part)
    assert 0 < mask.sum() < mask.size and np.array_equal(img.hits, mask)
    assert not got[~mask].any() and not ref[~mask].any()
    away = Plane((0.0, 0.0, 50.0), (1, 0, 0), (0, 1, 0), 6, 5)
    got, ref, img = _check(store, volume, away, priv)
    assert not got.any() and not ref.any() and not img.hits.any() and img.stats["map_tasks"] == 0


# -- modes -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("mode, kw", [("emphasize", {"density": 0.4}), ("tf", {"nodes": NODES})], ids=["emph", "tf"])
def test_vector_modes(store, volume, keypair256, mode, kw, sampling):
    for plane in (Plane.coronal(store, 4), Plane.oblique(store, normal=(1, 1, 0), width=11, height=10, slab=2)):
        got, ref, _ = _check(store, volume, plane, keypair256[1], sampling=sampling, mode=mode, **kw)
        assert ref.shape == ((plane.height, plane.width, 3) if mode == "tf" else (plane.height, plane.width))
        assert np.count_nonzero(ref) > 10


# -- the reference itself ------------------------------------------------------------------------------
def test_reference_is_exact_on_a_linear_ramp():
    """Trilinear interpolation reproduces a linear function, and a symmetric slab averages to its centre."""
    k, j, i = np.indices(SHAPE).astype(np.float64)
    a = np.array([0.7, -1.3, 2.1])
    vol = a[0] * i * SPACING[0] + a[1] * j * SPACING[1] + a[2] * k * SPACING[2] + 40.0
    plane = Plane.oblique(
        SHAPE, normal=(1, -2, 2), width=9, height=9, pixel_spacing=0.4, slab=3, slab_step=0.3, spacing=SPACING
    )
    got = render_slice_plain(vol, plane, sampling="trilinear", spacing=SPACING)
    pts = plane.centres()[:, None, :] + plane.slab_offsets[None, :, None] * plane.normal
    inside = np.all((pts >= 0) & (pts <= EXTENT), axis=2)
    full = inside.all(axis=1)
    assert full.sum() > 20
    want = plane.centres() @ a + 40.0
    assert np.allclose(got.ravel()[full], want[full], atol=1e-9)


def test_reference_nearest_rounds_half_up_and_clamps():
    vol = np.arange(8, dtype=np.uint8).reshape(2, 2, 2)  # value = 4k + 2j + i
    plane = Plane((0.5, 0.0, 0.5), (1, 0, 0), (0, 1, 0), 1, 2)  # i = 0.5 -> 1, k = 0.5 -> 1
    assert render_slice_plain(vol, plane).ravel().tolist() == [5.0, 7.0]
    edge = Plane((1.0 + 1e-12, 0.0, 0.0), (1, 0, 0), (0, 1, 0), 1, 1)  # on the face, within tolerance
    assert render_slice_plain(vol, edge).ravel().tolist() == [1.0]
    with pytest.raises(hevr.ParameterError, match="^plane: expected a hevr.Plane"):
        render_slice_plain(vol, hevr.Camera((0, 0, 5), (0, 0, 0)))


# -- the pipeline: cluster, cache, deferred, sums ----------------------------------------------------
def test_cluster_gives_the_identical_image(store, keypair256, cluster):
    plane = Plane.oblique(store, normal=(2, 1, 1), width=12, height=11, slab=3)
    clear_cache()
    local = render_slice(store, plane, sampling="trilinear", progress=False, cache=False)
    remote = render_slice(store, plane, sampling="trilinear", progress=False, client=cluster, cache=False)
    assert len(local.ciphertexts) == len(remote.ciphertexts)
    assert all(np.array_equal(a, b) for a, b in zip(local.ciphertexts, remote.ciphertexts))
    assert np.array_equal(local.decrypt(keypair256[1]), remote.decrypt(keypair256[1]))


def test_cache_deferred_and_kept_sums(store, volume, keypair256, tmp_path):
    priv = keypair256[1]
    clear_cache()
    plane = Plane.sagittal(store, 3, slab=2)
    first = render_slice(store, plane, mode="tf", nodes=NODES, progress=False, keep_sums=tmp_path / "s.hevrsums")
    again = render_slice(store, plane, mode="emphasize", density=0.5, progress=False)
    assert not first.stats["reused_ray_sums"] and again.stats["reused_ray_sums"] and again.stats["map_tasks"] == 0
    # a camera never takes a plane's sums (their keys differ by kind)
    cam = hevr.Camera.orbit(store, width=6, height=5)
    assert not hevr.render(store, cam, mode="emphasize", density=0.5, progress=False).stats["reused_ray_sums"]
    saved = load_sums(tmp_path / "s.hevrsums")
    assert saved.camera == plane and saved.step == plane.slab_step
    re = recolour(saved, mode="emphasize", density=0.5, progress=False)
    assert all(np.array_equal(a, b) for a, b in zip(re.ciphertexts, again.ciphertexts))
    d = render_slice(store, Plane.axial(store, 2), progress=False, compute=False, cache=False)
    assert isinstance(d, Delayed)
    with dask.config.set(scheduler="sync"):
        img = d.compute()
    assert np.abs(img.decrypt(priv) - volume[2]).max() <= 1e-9


def test_wrong_view_kinds_are_refused(store):
    plane = Plane.axial(store, 1)
    with pytest.raises(hevr.ParameterError, match="^camera: expected a hevr.Camera, got a hevr.Plane .*render_slice"):
        hevr.render(store, plane)
    with pytest.raises(hevr.ParameterError, match="^plane: expected a hevr.Plane"):
        render_slice(store, hevr.Camera.orbit(store))
    with pytest.raises(hevr.ParameterError, match="^mode: "):
        render_slice(store, plane, mode="mip")
    with pytest.raises(hevr.ParameterError, match="^sampling: "):
        render_slice(store, plane, sampling="cubic")
