"""Gradient-magnitude modulation in rendering: ``hevr.render(..., gradient=True)`` (emphasize and tf,
nearest and trilinear, several cameras, anisotropic spacing) decrypts to ``render_plain(...,
gradient=True)`` within ``error_bound(..., gradient=True)``; slices, pyramid levels, a cluster,
cached and saved sums; boundaries are emphasised (a homogeneous interior goes to 0); bad requests
name ``gradient``."""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.store.pyramid import build_pyramid

NODES = [(0.2, "red"), (0.6, "lime"), (0.9, "blue")]
MODES = [("emphasize", {"density": 0.65}), ("tf", {"nodes": NODES})]
RND_SPACING = (0.7, 1.3, 2.0)


@pytest.fixture(scope="module")
def stores(tmp_path_factory, keypair256):
    _, priv = keypair256
    d = tmp_path_factory.mktemp("gradient-render")
    ph = hevr.phantom(10)
    rnd = np.random.default_rng(11).integers(0, 256, (7, 9, 8)).astype(np.uint8)
    cube = np.zeros((10, 10, 10), np.uint8)
    cube[2:8, 2:8, 2:8] = 200  # interior 4:6 of the cube is homogeneous: |∇d| = 0 there
    kw = dict(brick=4, gradient=True, progress=False)
    return {
        "phantom": (
            build_pyramid(hevr.encrypt_volume(ph, d / "ph.zarr", priv, vector_dims=4, **kw), 1, progress=False),
            ph,
            (1.0, 1.0, 1.0),
        ),
        "random": (
            hevr.encrypt_volume(rnd, d / "rnd.zarr", priv, vector_dims=3, spacing=RND_SPACING, **kw),
            rnd,
            RND_SPACING,
        ),
        "cube": (hevr.encrypt_volume(cube, d / "cube.zarr", priv, vector_dims=2, **kw), cube, (1.0, 1.0, 1.0)),
    }


def _plain(vol, view, spacing, ev, mode, kw, sampling="nearest", **extra):
    fn = hevr.render_slice_plain if isinstance(view, hevr.Plane) else hevr.render_plain
    return fn(vol, view, mode=mode, sampling=sampling, spacing=spacing, vector_dims=ev.vector_dims, **kw, **extra)


@pytest.mark.parametrize("name", ["phantom", "random"])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_gradient_renders_match_the_plaintext_definition(stores, keypair256, name, sampling):
    ev, vol, spacing = stores[name]
    priv = keypair256[1]
    for cam in (
        hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=9, height=8),
        hevr.Camera.orbit(ev, azimuth=200, elevation=-50, width=8, height=9, parallel=True),
    ):
        for mode, kw in MODES:
            img = hevr.render(ev, cam, mode=mode, sampling=sampling, gradient=True, progress=False, **kw)
            assert img.info["gradient"] and img.info["plan"]["channel"] == "gradient"
            got = img.decrypt(priv)
            ref = _plain(vol, cam, spacing, ev, mode, kw, sampling, gradient=True)
            bound = hevr.error_bound(ev, cam, mode=mode, sampling=sampling, gradient=True, **kw)
            assert (np.abs(got - ref) <= bound).all(), (mode, float(np.abs(got - ref).max()))
            without = _plain(vol, cam, spacing, ev, mode, kw, sampling)
            assert np.abs(ref - without).max() > 10 * bound.max()  # another image than the vector channel's


def test_boundaries_are_emphasised(stores, keypair256):
    ev, vol, spacing = stores["cube"]
    priv = keypair256[1]
    plane = hevr.Plane.axial(ev, 5)
    grad = hevr.render_slice(ev, plane, mode="emphasize", density=200 / 255, gradient=True, progress=False)
    plain = hevr.render_slice(ev, plane, mode="emphasize", density=200 / 255, progress=False)
    assert grad.stats["map_tasks"] > 0 and not grad.stats["reused_ray_sums"]  # no sums shared with the vector channel
    g, p = grad.decrypt(priv), plain.decrypt(priv)
    ref = _plain(vol, plane, spacing, ev, "emphasize", {"density": 200 / 255}, gradient=True)
    assert (np.abs(g - ref) <= hevr.error_bound(ev, plane, mode="emphasize", density=200 / 255, gradient=True)).all()
    assert np.allclose(p[2:8, 2:8], 1.0, atol=1e-3)  # without the gradient: the whole cube section
    assert np.abs(g[4:6, 4:6]).max() < 1e-3  # with it: the homogeneous interior vanishes ...
    assert g[2, 2:8].min() > 0.3 and g[7, 2:8].min() > 0.3  # ... and the cube's faces stay
    tf = hevr.render_slice(ev, plane, mode="tf", nodes=NODES, sampling="trilinear", gradient=True, progress=False)
    ref = _plain(vol, plane, spacing, ev, "tf", {"nodes": NODES}, "trilinear", gradient=True)
    assert (
        np.abs(tf.decrypt(priv) - ref)
        <= hevr.error_bound(ev, plane, mode="tf", nodes=NODES, sampling="trilinear", gradient=True)
    ).all()


def test_pyramid_level_with_gradient(stores, keypair256):
    ev, vol, spacing = stores["phantom"]
    priv = keypair256[1]
    cam = hevr.Camera.orbit(ev, azimuth=40, elevation=25, width=8, height=8)
    for mode, kw in MODES:
        for sampling in ("nearest", "trilinear"):
            img = hevr.render(ev, cam, mode=mode, sampling=sampling, level=1, gradient=True, progress=False, **kw)
            ref = _plain(vol, cam, spacing, ev, mode, kw, sampling, gradient=True, level=1)
            bound = hevr.error_bound(ev, cam, mode=mode, sampling=sampling, level=1, gradient=True, **kw)
            assert img.info["level"] == 1 and (np.abs(img.decrypt(priv) - ref) <= bound).all()


def test_cluster_cache_and_saved_sums(stores, keypair256, cluster, tmp_path):
    ev, vol, spacing = stores["random"]
    priv = keypair256[1]
    cam = hevr.Camera.orbit(ev, azimuth=60, elevation=10, width=8, height=7)
    a = hevr.render(
        ev,
        cam,
        mode="tf",
        nodes=NODES,
        gradient=True,
        client=cluster,
        progress=False,
        keep_sums=tmp_path / "g.hevrsums",
    )
    ref = _plain(vol, cam, spacing, ev, "tf", {"nodes": NODES}, gradient=True)
    assert (np.abs(a.decrypt(priv) - ref) <= hevr.error_bound(ev, cam, mode="tf", nodes=NODES, gradient=True)).all()
    b = hevr.render(ev, cam, mode="emphasize", density=0.3, gradient=True, client=cluster, progress=False)
    assert b.stats["reused_ray_sums"]  # the gradient channel's sums, cached on the workers
    c = hevr.render(ev, cam, mode="emphasize", density=0.3, client=cluster, progress=False)
    assert not c.stats["reused_ray_sums"] and not np.allclose(b.decrypt(priv), c.decrypt(priv))
    again = hevr.recolour(tmp_path / "g.hevrsums", mode="emphasize", density=0.3, gradient=True, progress=False)
    assert [bytes(x) for x in again.ciphertexts] == [bytes(x) for x in b.ciphertexts]  # bit for bit
    hevr.render(ev, cam, mode="tf", nodes=NODES, client=cluster, progress=False, keep_sums=tmp_path / "v.hevrsums")
    with pytest.raises(
        hevr.ParameterError,
        match=r"gradient: expected sums of the gradient channel for "
        r"gradient=True, got the vector channel's",
    ):
        hevr.recolour(tmp_path / "v.hevrsums", mode="tf", nodes=NODES, gradient=True)
    with pytest.raises(
        hevr.ParameterError,
        match=r"gradient: expected sums of the vector channel for "
        r"gradient=False, got the gradient channel's",
    ):
        hevr.recolour(tmp_path / "g.hevrsums", mode="tf", nodes=NODES)


def test_bad_requests_name_gradient(stores, tmp_path, keypair256):
    ev, vol, _ = stores["random"]
    cam = hevr.Camera.orbit(ev, width=4, height=4)
    with pytest.raises(hevr.ParameterError, match=r"gradient: expected mode 'emphasize' or 'tf' with gradient=True"):
        hevr.render(ev, cam, gradient=True)
    with pytest.raises(hevr.ParameterError, match=r"gradient: expected mode 'emphasize' or 'tf'"):
        hevr.render_plain(vol, cam, mode="xray", gradient=True)
    with pytest.raises(hevr.ParameterError, match=r"gradient: expected True or False"):
        hevr.render(ev, cam, mode="tf", nodes=NODES, gradient=1)
    plain = hevr.encrypt_volume(vol, tmp_path / "p.zarr", keypair256[0], brick=4, vector_dims=3, progress=False)
    assert not plain.has_gradient
    msg = r"gradient: expected a store encrypted with gradient=True \(its 'gradient' channel\), got one without"
    for call in (
        lambda: hevr.render(plain, cam, mode="tf", nodes=NODES, gradient=True),
        lambda: hevr.render_slice(plain, hevr.Plane.axial(plain, 2), mode="emphasize", density=0.5, gradient=True),
        lambda: hevr.error_bound(plain, cam, mode="emphasize", density=0.5, gradient=True),
    ):
        with pytest.raises(hevr.ParameterError, match=msg):
            call()
    with pytest.raises(hevr.ParameterError, match="gradient: expected mode"):
        hevr.error_bound(ev, cam, mode="xray", gradient=True)
