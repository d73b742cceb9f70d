"""Encrypted render vs the plaintext reference; partial sums; re-colouring; packing."""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.crypto.records import bytes_to_mpz
from hevr.rendering import view as view_mod
from hevr.rendering.encrypted import error_bound
from hevr.rendering.pipeline import cache as render_cache

SHAPE = (7, 9, 11)  # odd, non-cubic
BRICK = (3, 4, 5)  # 3 bricks per axis
SPACING = (1.0, 0.8, 1.3)  # anisotropic (sx, sy, sz)
NODES = [(0.279, (0, 0, 1)), (0.797, "red"), (0.5, "#00ff00")]
MODES = [("xray", {}), ("emphasize", {"density": 0.653}), ("tf", {"nodes": NODES})]


@pytest.fixture(scope="module")
def volume():
    rng = np.random.default_rng(3)
    return rng.integers(0, 256, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("render") / "v.zarr"
    return hevr.encrypt_volume(
        volume, path, keypair256[1], brick=BRICK, spacing=SPACING, vector_dims=4, vector_digits=4, progress=False
    )


CAMERAS = {
    "perspective": lambda ev: hevr.Camera.orbit(ev, azimuth=35, elevation=25, width=13, height=10),
    "parallel": lambda ev: hevr.Camera.orbit(ev, azimuth=-60, elevation=-15, width=12, height=12, parallel=True),
}


@pytest.mark.parametrize("cam_name", list(CAMERAS))
@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("mode, kw", MODES, ids=[m for m, _ in MODES])
def test_render_matches_plain(store, volume, keypair256, mode, kw, sampling, cam_name):
    _, priv = keypair256
    cam = CAMERAS[cam_name](store)
    img = hevr.render(store, cam, mode=mode, sampling=sampling, progress=False, digits=4, **kw)
    got = img.decrypt(priv)
    ref = hevr.render_plain(volume, cam, mode=mode, sampling=sampling, spacing=SPACING, vector_dims=4, **kw)
    bound = error_bound(store, cam, mode, sampling, digits=4, **kw)
    assert got.shape == ref.shape == bound.shape
    assert np.all(np.abs(got - ref) <= bound), np.abs(got - ref).max()
    assert np.count_nonzero(ref) > 10  # the camera sees the volume
    # the bound is meaningful: far smaller than the signal
    assert bound.max() < 0.01 * max(ref.max(), 1e-9) * (255 if mode == "xray" else 1) + 0.05


def _decrypt_sums(sums, priv, n_pixels, channels):
    out = np.zeros((n_pixels, channels), dtype=object)
    for merged in sums.tiles.values():
        if merged is None or merged[0].size == 0:
            continue
        rays, recs = merged
        vals = priv.decrypt_array(bytes_to_mpz(recs.reshape(-1, recs.shape[-1])))
        out[rays] = np.array(vals, dtype=object).reshape(len(rays), channels)
    return out


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_axis_aligned_parallel_is_exact_mean(tmp_path, keypair256, sampling):
    """Pixel centres on voxel columns: decrypted ray sums / n == flipud(vol.mean(axis=0)) exactly."""
    pub, priv = keypair256
    rng = np.random.default_rng(5)
    vol = rng.integers(0, 200, SHAPE).astype(np.uint8)
    nz, ny, nx = SHAPE
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", priv, brick=BRICK, progress=False)
    centre = ((nx - 1) / 2, (ny - 1) / 2, (nz - 1) / 2)
    cam = hevr.Camera(
        position=(centre[0], centre[1], nz + 5.0),
        focal_point=centre,
        width=nx,
        height=ny,
        parallel=True,
        parallel_scale=ny / 2,
    )
    hevr.clear_cache()
    img = hevr.render(ev, cam, sampling=sampling, progress=False)
    sums = next(iter(render_cache._CACHE.values()))
    s = _decrypt_sums(sums, priv, nx * ny, 1)[:, 0].reshape(ny, nx)
    scale = 10 ** (-img.info["plan"]["weight_exponent"])
    assert np.array_equal(s.astype(np.int64), np.flipud(vol.astype(np.int64).sum(axis=0)) * scale)
    ref = np.flipud(vol.mean(axis=0))
    assert np.allclose(img.decrypt(priv), ref, rtol=0.5e-4, atol=0)  # precision=4: reciprocal error <= 0.5e-4
    assert np.allclose(hevr.render_plain(vol, cam, sampling=sampling), ref, rtol=1e-12, atol=1e-12)


def test_rays_that_miss_give_zero(store, keypair256):
    _, priv = keypair256
    cam = hevr.Camera(position=(500, 500, 500), focal_point=(600, 600, 600), width=6, height=4)
    for mode, kw in MODES:
        img = hevr.render(store, cam, mode=mode, progress=False, **kw)
        assert np.array_equal(img.decrypt(priv), np.zeros(img.shape))


def test_pack_on_and_off_agree(store, keypair256):
    _, priv = keypair256
    cam = CAMERAS["perspective"](store)
    a = hevr.render(store, cam, mode="tf", nodes=NODES, sampling="trilinear", progress=False)
    b = hevr.render(store, cam, mode="tf", nodes=NODES, sampling="trilinear", progress=False, pack=False)
    assert a.per_pack > 1 and b.per_pack == 1
    assert b.n_ciphertexts == int(b.hits.sum()) * 4 and 0 < b.hits.sum() < 13 * 10  # 4 sums per hit pixel only
    assert a.n_ciphertexts <= -(-b.n_ciphertexts // a.per_pack) + 4  # per-tile rounding only
    assert np.array_equal(a.decrypt(priv), b.decrypt(priv))
    assert a.exponent == b.exponent


def test_recolouring_reuses_ray_sums(store, volume, keypair256):
    _, priv = keypair256
    hevr.clear_cache()
    cam = CAMERAS["parallel"](store)
    first = hevr.render(store, cam, mode="tf", nodes=NODES, progress=False)
    assert first.stats["map_tasks"] > 0 and not first.stats["reused_ray_sums"]
    for kw in ({"mode": "tf", "nodes": [(0.0, "blue"), (1.0, "red")]}, {"mode": "emphasize", "density": 0.331}):
        again = hevr.render(store, cam, progress=False, **kw)
        assert again.stats["reused_ray_sums"] and again.stats["map_tasks"] == 0
        ref = hevr.render_plain(volume, cam, spacing=SPACING, vector_dims=4, **kw)
        assert np.all(np.abs(again.decrypt(priv) - ref) <= error_bound(store, cam, **kw))
    other = hevr.render(store, cam, mode="tf", nodes=NODES, progress=False, cache=False)
    assert other.stats["map_tasks"] == first.stats["map_tasks"]


def test_common_exponent_and_no_secret_needed(store, keypair256):
    cam = CAMERAS["perspective"](store)
    img = hevr.render(store, cam, mode="xray", sampling="trilinear", progress=False)
    assert isinstance(img.exponent, int)  # one exponent for every pixel, by construction
    assert "p" not in img.info and img.fingerprint == store.meta.fingerprint


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"mode": "mip"}, "xray, emphasize, tf"),
        ({"sampling": "cubic"}, "nearest, trilinear"),
        ({"mode": "emphasize"}, "density"),
        ({"mode": "emphasize", "density": 1.5}, "density"),
        ({"mode": "tf", "nodes": []}, "nodes"),
        ({"mode": "tf", "nodes": [(0.5, (2, 0, 0))]}, "[0, 1]"),
        ({"step": 0}, "step"),
        ({"step": -1.0}, "step"),
        ({"precision": -1}, "precision"),
        ({"digits": 99}, "digits"),
    ],
)
def test_bad_input(store, kw, match):
    cam = CAMERAS["perspective"](store)
    with pytest.raises(hevr.HevrError, match=match):
        hevr.render(store, cam, progress=False, **kw)


def test_modes_need_vector_channel(tmp_path, keypair256, volume):
    ev = hevr.encrypt_volume(volume, tmp_path / "s.zarr", keypair256[0], brick=BRICK, progress=False)
    cam = CAMERAS["perspective"](ev)
    with pytest.raises(hevr.ParameterError, match="vector"):
        hevr.render(ev, cam, mode="emphasize", density=0.5, progress=False)
    with pytest.raises(hevr.ParameterError, match="camera"):
        hevr.render(ev, "not a camera", progress=False)


@pytest.mark.parametrize("bad", [dict(view_up=(0, 0, 1)), dict(width=0), dict(view_angle=180), dict(view_angle=0)])
def test_degenerate_cameras(bad):
    kw = dict(position=(0, 0, 10), focal_point=(0, 0, 0))
    kw.update(bad)
    with pytest.raises(hevr.HevrError):
        hevr.Camera(**kw)


def test_cache_never_serves_another_volume_at_the_same_path(tmp_path, keypair256, volume):
    _, priv = keypair256
    path = tmp_path / "v.zarr"
    ev1 = hevr.encrypt_volume(volume, path, priv, brick=BRICK, progress=False)
    cam = hevr.Camera.orbit(ev1, width=8, height=8)
    hevr.render(ev1, cam, progress=False)
    other = (255 - volume).astype(np.uint8)
    ev2 = hevr.encrypt_volume(other, path, priv, brick=BRICK, progress=False, overwrite=True)
    img = hevr.render(ev2, cam, progress=False)
    assert not img.stats["reused_ray_sums"]
    assert np.allclose(img.decrypt(priv), hevr.render_plain(other, cam), atol=0.01)


def test_renders_from_many_threads_share_the_cache(store, volume, keypair256, monkeypatch):
    """hevr serve renders on several threads at once: the ray-sum cache (2 entries) is looked up,
    evicted and refilled by all of them, and no render may read what another just evicted
    (a KeyError before the cache had a lock, issue 48); every image still matches its reference."""
    import time
    from concurrent.futures import ThreadPoolExecutor

    _, priv = keypair256
    cams = [hevr.Camera.orbit(store, azimuth=a, elevation=10, width=8, height=7) for a in (10, 70, 130, 190)]
    refs = [hevr.render_plain(volume, c, spacing=SPACING) for c in cams]
    bounds = [error_bound(store, c) for c in cams]
    render_cache.clear_cache()
    fields = view_mod.image_fields

    def slow_fields(*a, **kw):  # widens the window between a render's cache look-up and its use
        time.sleep(0.02)
        return fields(*a, **kw)

    monkeypatch.setattr(view_mod, "image_fields", slow_fields)

    def one(i):
        k = i % len(cams)
        got = hevr.render(store, cams[k], progress=False).decrypt(priv)
        return bool(np.all(np.abs(got - refs[k]) <= bounds[k]))

    with ThreadPoolExecutor(max_workers=8) as pool:
        assert all(pool.map(one, range(32)))
    assert len(render_cache._CACHE) <= render_cache.CACHE_SIZE
