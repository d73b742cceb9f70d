"""Tests of hevr.rendering.pipeline.finishing: merging partial ray sums and finishing a tile, checked
against plaintext integer arithmetic on the decrypted inputs (an independent reference)."""

from __future__ import annotations

import dask
import numpy as np
import pytest

import hevr
from hevr.crypto.records import bytes_to_mpz, mpz_to_bytes
from hevr.image.tiles import TileLayout
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.pipeline import cache as render_cache
from hevr.rendering.pipeline.finishing import finish_tile, merge_partials, one_records
from hevr.rendering.planning.planner import RenderPlan

SHAPE, BRICK = (5, 6, 7), (3, 3, 4)
NODES = [(0.25, "blue"), (0.75, "red")]


def _recs(pub, values, k):
    cts = [pub.encrypt(v) for v in values]
    return mpz_to_bytes(cts, pub.ciphertext_bytes).reshape(-1, k, pub.ciphertext_bytes)


def test_merge_partials_sums_per_ray_and_passes_singles_through(keypair256):
    pub, priv = keypair256
    a = (np.array([3, 5, 9]), _recs(pub, [1, 2, 3, 4, 5, 6], 2))
    b = (np.array([5, 7]), _recs(pub, [10, 20, 30, 40], 2))
    c = (np.array([5, 9]), _recs(pub, [100, 200, 300, 400], 2))
    rays, recs = merge_partials([a, (np.zeros(0, np.int64), np.zeros((0, 2, 64), np.uint8)), b, c], pub.nsquare)
    assert rays.tolist() == [3, 5, 7, 9]
    vals = priv.decrypt_array(bytes_to_mpz(recs.reshape(-1, recs.shape[-1])))
    assert vals == [1, 2, 3 + 10 + 100, 4 + 20 + 200, 30, 40, 5 + 300, 6 + 400]
    np.testing.assert_array_equal(recs[0], a[1][0])  # a ray in one part only: bytes untouched
    np.testing.assert_array_equal(recs[2], b[1][1])


def test_merge_partials_of_nothing_and_of_one():
    empty = (np.zeros(0, np.int64), np.zeros((0, 1, 8), np.uint8))
    rays, recs = merge_partials([empty, empty], 77)
    assert rays.size == 0 and recs.shape[0] == 0
    one = (np.array([1, 2]), np.ones((2, 1, 8), np.uint8))
    assert merge_partials([empty, one], 77) is one


def test_one_records_are_the_trivial_encryption_of_zero(keypair256):
    pub, priv = keypair256
    recs = one_records((3,), pub.ciphertext_bytes)
    assert priv.decrypt_array(bytes_to_mpz(recs)) == [0, 0, 0]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory, keypair256):
    """A tf render of a tiny signed volume, with its cached merged ray sums."""
    _, priv = keypair256
    rng = np.random.default_rng(2)
    vol = rng.integers(-50, 200, SHAPE).astype(np.int16)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(
            vol,
            tmp_path_factory.mktemp("fin") / "v.zarr",
            priv,
            brick=BRICK,
            vector_dims=2,
            value_range=(-50, 200),
            progress=False,
        )
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=15, width=7, height=6)
        out = {}
        for mode, kw in (("xray", {}), ("tf", {"nodes": NODES})):
            hevr.clear_cache()
            img = hevr.render(ev, cam, mode=mode, sampling="trilinear", tile=4, progress=False, finish="server", **kw)
            out[mode] = (img, next(iter(render_cache._CACHE.values())))
    return ev, cam, out


@pytest.mark.parametrize("mode", ["xray", "tf"])
def test_finish_tile_is_combination_times_reciprocal_plus_offset_packed(rendered, keypair256, mode):
    _, priv = keypair256
    ev, cam, out = rendered
    img, sums = out[mode]
    plan = RenderPlan.from_dict(img.info["plan"])
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    n = int(ev.public_key.n)
    W = ev.public_key.ciphertext_bytes
    checked = 0
    for t, merged in sums.tiles.items():
        if merged is None:
            continue
        pix = TileLayout(cam.width, cam.height, 4).pixels(t)
        packed = finish_tile(plan, merged, pix, rays.n_samples[pix], n, W)
        np.testing.assert_array_equal(packed, img.ciphertexts[t])  # the render's own finishing
        # the reference: plaintext arithmetic on the decrypted merged sums
        r_ids, recs = merged
        K = recs.shape[1]
        dec = np.array(priv.decrypt_array(bytes_to_mpz(recs.reshape(-1, W))), dtype=object).reshape(-1, K)
        by_ray = {int(r): dec[i] for i, r in enumerate(r_ids.tolist())}
        recips = plan.reciprocal(rays.n_samples[pix])
        want = []
        for p, R in zip(pix.tolist(), recips):
            if R == 0:
                continue
            s = by_ray.get(p, np.zeros(K, dtype=object))
            chans = (
                [s[0]]
                if plan.comb is None
                else [sum(int(s[k]) * plan.comb[k][ch] for k in range(K)) for ch in range(plan.channels_out)]
            )
            want += [int(v) * R + plan.offset for v in chans]
        got = []
        for m in priv.decrypt_array(bytes_to_mpz(packed), signed=False):
            for _ in range(plan.per_pack):
                got.append(m & ((1 << plan.pack_bits) - 1))
                m >>= plan.pack_bits
        assert got[: len(want)] == want and not any(got[len(want) :])
        checked += len(want)
    assert checked > 10
