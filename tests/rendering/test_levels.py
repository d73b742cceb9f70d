"""Rendering pyramid levels: ``hevr.render(..., level=L)`` decrypts to ``render_plain(..., level=L)``
(the plaintext definition: means of the per-voxel field on the level's grid) within
``error_bound(..., level=L)``, for every mode and sampling, on odd shapes, anisotropic spacing,
float volumes and a cluster; levels never share cached sums; bad levels are named."""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.store.pyramid import build_pyramid

NODES = [(0.2, "red"), (0.6, "lime"), (0.9, "blue")]
MODES = [("xray", {}), ("emphasize", {"density": 0.65}), ("tf", {"nodes": NODES})]


@pytest.fixture(scope="module")
def stores(tmp_path_factory, keypair256):
    pub, priv = keypair256
    d = tmp_path_factory.mktemp("levels")
    out = {}
    vol = hevr.phantom(12)
    ev = hevr.encrypt_volume(vol, d / "ph.zarr", priv, brick=4, vector_dims=3, progress=False)
    out["phantom"] = (build_pyramid(ev, 2, progress=False), vol, (1.0, 1.0, 1.0))
    rnd = np.random.default_rng(8).integers(0, 256, (7, 11, 9)).astype(np.uint8)
    ev = hevr.encrypt_volume(
        rnd, d / "rnd.zarr", priv, brick=(3, 4, 5), vector_dims=4, spacing=(0.8, 1.0, 1.7), progress=False
    )
    out["random"] = (build_pyramid(ev, 2, progress=False), rnd, (0.8, 1.0, 1.7))
    flt = (np.random.default_rng(9).random((6, 8, 10)) * 5 - 2).astype(np.float32)
    ev = hevr.encrypt_volume(
        flt, d / "flt.zarr", priv, brick=4, vector_dims=2, value_range=(-2.0, 3.0), digits=2, progress=False
    )
    out["float"] = (build_pyramid(ev, 1, progress=False), flt, (1.0, 1.0, 1.0))
    return out, priv


def _check(ev, vol, spacing, priv, cam, level, mode, kw, sampling, **extra):
    img = hevr.render(ev, cam, mode=mode, sampling=sampling, level=level, progress=False, **extra, **kw)
    got = img.decrypt(priv)
    ref = hevr.render_plain(
        vol,
        cam,
        mode=mode,
        sampling=sampling,
        spacing=spacing,
        value_range=ev.value_range,
        vector_dims=ev.vector_dims,
        level=level,
        **kw,
    )
    bound = hevr.error_bound(ev, cam, mode=mode, sampling=sampling, level=level, **kw)
    assert (np.abs(got - ref) <= bound).all(), (mode, sampling, level, float(np.abs(got - ref).max()))
    return img, got, ref


@pytest.mark.parametrize("name", ["phantom", "random", "float"])
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_level_renders_match_the_plaintext_definition(stores, name, sampling):
    out, priv = stores
    ev, vol, spacing = out[name]
    cams = [
        hevr.Camera.orbit(ev, azimuth=35, elevation=25, width=13, height=11),
        hevr.Camera.orbit(ev, azimuth=-70, elevation=-10, width=9, height=12, parallel=True),
    ]
    for level in range(ev.levels + 1):
        for cam in cams:
            for mode, kw in MODES:
                img, got, ref = _check(ev, vol, spacing, priv, cam, level, mode, kw, sampling)
                if level:
                    assert img.info["level"] == level
                assert np.abs(ref).max() > 0  # the view sees the volume


def test_coarser_levels_do_less_work(stores):
    out, priv = stores
    ev, vol, spacing = out["phantom"]
    cam = hevr.Camera.orbit(ev, azimuth=20, elevation=10, width=16, height=16)
    hevr.clear_cache()
    tasks = [hevr.render(ev, cam, level=L, progress=False).stats["map_tasks"] for L in (0, 1, 2)]
    assert tasks[0] > tasks[1] > tasks[2] >= 1  # 27 bricks, then 8, then 1
    again = hevr.render(ev, cam, level=1, progress=False)  # cached per level
    assert again.stats["reused_ray_sums"] and hevr.render(ev, cam, level=2, progress=False).stats["reused_ray_sums"]
    lv = ev.at_level(1)
    same = hevr.render(lv, cam, progress=False)  # a level's view renders its level with the same camera
    assert [c.tobytes() for c in same.ciphertexts] == [c.tobytes() for c in again.ciphertexts]


def test_levels_on_a_cluster_with_sums_and_deferred(stores, cluster, tmp_path):
    out, priv = stores
    ev, vol, spacing = out["random"]
    cam = hevr.Camera.orbit(ev, azimuth=10, elevation=40, width=10, height=10)
    hevr.clear_cache()
    a = hevr.render(
        ev, cam, mode="tf", nodes=NODES, level=1, client=cluster, progress=False, keep_sums=tmp_path / "l1.hevrsums"
    )
    b = hevr.recolour(tmp_path / "l1.hevrsums", mode="tf", nodes=NODES, client=cluster, progress=False)
    assert [c.tobytes() for c in a.ciphertexts] == [c.tobytes() for c in b.ciphertexts]
    c = cluster.compute(
        hevr.render(ev, cam, mode="emphasize", density=0.3, level=2, client=cluster, compute=False)
    ).result()
    _check(ev, vol, spacing, priv, cam, 2, "emphasize", {"density": 0.3}, "nearest")
    ref = hevr.render_plain(vol, cam, mode="emphasize", density=0.3, spacing=spacing, vector_dims=4, level=2)
    assert c.colouring is None  # computed by the scheduler: the density never went there
    assert (
        np.abs(c.decrypt(priv, density=0.3) - ref) <= hevr.error_bound(ev, cam, mode="emphasize", density=0.3, level=2)
    ).all()
    resident = ev.at_level(1).persist(client=cluster)
    d = hevr.render(resident, cam, level=1, client=cluster, progress=False)
    assert d.stats["resident"] is True
    _check(ev, vol, spacing, priv, cam, 1, "xray", {}, "nearest")


def test_bad_levels(stores, tmp_path, keypair256):
    out, priv = stores
    ev, vol, spacing = out["float"]
    cam = hevr.Camera.orbit(ev, width=8, height=8)
    with pytest.raises(hevr.ParameterError, match="level: expected a level of this store's pyramid, 0 to 1, got 2"):
        hevr.render(ev, cam, level=2)
    with pytest.raises(hevr.ParameterError, match="level: expected an int"):
        hevr.render(ev, cam, level=1.5)
    with pytest.raises(hevr.ParameterError, match="level"):
        hevr.error_bound(ev, cam, level=-1)
    plain = hevr.encrypt_volume(hevr.phantom(6), tmp_path / "p.zarr", keypair256[0], brick=3, progress=False)
    with pytest.raises(hevr.ParameterError, match="0 to 0, got 1"):
        hevr.render(plain, hevr.Camera.orbit(plain, width=4, height=4), level=1)
