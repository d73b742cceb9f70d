"""Whole renders with ``backend="cuda-host"`` (the CUDA kernels compiled for the host) give the
byte-identical packed image of ``backend="cpu"``: every mode × sampling, finished on the server and
on the client, a slice, a pyramid level (built by either backend: identical level bricks), the
gradient channel, re-colouring saved sums, resident bricks; decryption with either backend agrees
and lies within ``error_bound`` of the plaintext render. A small multi-brick store and a 256-bit
key keep it to a few seconds. On a GPU machine ``HEVR_TEST_KERNELS=cuda`` runs them on the ``cuda`` backend."""

from __future__ import annotations

import os
import shutil

import dask
import numpy as np
import pytest

import hevr
from hevr.backends.cuda.backend import KernelBackend
from hevr.backends.cuda.residues import LimbBatch
from hevr.store.pyramid import build_pyramid

KERNELS = os.environ.get("HEVR_TEST_KERNELS", "cuda-host")  # "cuda" on a GPU machine
SHAPE, BRICK, SPACING = (7, 8, 9), (3, 4, 4), (1.0, 0.9, 1.2)
NODES = [(0.2, "blue"), (0.6, "red"), (0.9, "#00ff00")]
KW = {"xray": {}, "emphasize": {"density": 0.5}, "tf": {"nodes": NODES}}
CASES = [(m, s, f) for m in KW for s in ("nearest", "trilinear") for f in ("server", "client")]


@pytest.fixture(scope="module")
def scene(tmp_path_factory, keypair256):
    """The store is encrypted through cuda-host (its encrypt delegates to cpu's); level 1 built by cpu."""
    _, priv = keypair256
    d = tmp_path_factory.mktemp("cuda-host")
    vol = np.random.default_rng(5).integers(-200, 900, SHAPE).astype(np.int16)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(
            vol,
            d / "v.zarr",
            priv,
            brick=BRICK,
            spacing=SPACING,
            vector_dims=3,
            gradient=True,
            value_range=(-200, 900),
            backend=KERNELS,
            progress=False,
        )
    shutil.copytree(d / "v.zarr", d / "w.zarr")
    with dask.config.set(scheduler="sync"):
        ev = build_pyramid(ev, 1, backend="cpu", progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=40, elevation=20, width=9, height=8)
    return ev, vol, cam, priv, d


@pytest.fixture
def calls(monkeypatch):
    """Counts the kernel backend's operations (so a test sees that cuda-host did the work)."""
    seen: dict[str, int] = {}

    def counting(op: str):
        fn = getattr(KernelBackend, op)

        def spy(self, *a, **kw):
            seen[op] = seen.get(op, 0) + 1
            return fn(self, *a, **kw)

        return spy

    for op in ("ray_products", "segment_products", "combine", "pack", "decrypt", "first_out_of_range"):
        monkeypatch.setattr(KernelBackend, op, counting(op))
    return seen


def _pair(fn, **kw):
    """The same call with each backend (sync scheduler, no cache): (cpu result, cuda-host result)."""
    with dask.config.set(scheduler="sync"):
        return fn(backend="cpu", **kw), fn(backend=KERNELS, **kw)


def _same_image(a: hevr.EncryptedImage, b: hevr.EncryptedImage) -> None:
    assert a.shape == b.shape and len(a.ciphertexts) == len(b.ciphertexts)
    assert sum(len(t) for t in a.ciphertexts) > 0
    for ta, tb in zip(a.ciphertexts, b.ciphertexts):
        np.testing.assert_array_equal(ta, tb)


def _render(ev, view, **kw):
    return lambda backend: hevr.render(ev, view, progress=False, cache=False, backend=backend, **kw)


@pytest.mark.parametrize("mode, sampling, finish", CASES, ids=["-".join(c) for c in CASES])
def test_renders_are_byte_identical(scene, calls, mode, sampling, finish):
    ev, vol, cam, priv, _ = scene
    a, b = _pair(_render(ev, cam, mode=mode, sampling=sampling, finish=finish, **KW[mode]))
    _same_image(a, b)
    got = b.decrypt(priv, backend=KERNELS)
    assert calls["ray_products"] >= 4 and calls["segment_products"] and calls["pack"] and calls["decrypt"]
    assert calls.get("combine", 0) == (finish == "server" and mode != "xray")
    np.testing.assert_array_equal(got, a.decrypt(priv, backend="cpu"))
    ref = hevr.render_plain(
        vol, cam, mode=mode, sampling=sampling, spacing=SPACING, vector_dims=3, value_range=(-200, 900), **KW[mode]
    )
    assert np.all(np.abs(got - ref) <= hevr.error_bound(ev, cam, mode, sampling, finish=finish, **KW[mode]))
    assert np.count_nonzero(ref) > 5


@pytest.mark.parametrize("finish", ["server", "client"])
def test_a_slice_a_level_and_the_gradient(scene, finish):
    ev, _, cam, priv, _ = scene
    plane = hevr.Plane.oblique(ev, normal=(0.3, -1, 0.5), width=8, height=7, slab=3, slab_step=0.7)
    for fn in (
        lambda backend: hevr.render_slice(
            ev,
            plane,
            mode="tf",
            nodes=NODES,
            sampling="trilinear",
            progress=False,
            cache=False,
            backend=backend,
            finish=finish,
        ),
        _render(ev, cam, mode="emphasize", density=0.4, level=1, finish=finish),
        _render(ev, cam, mode="tf", nodes=NODES, sampling="trilinear", gradient=True, finish=finish),
    ):
        a, b = _pair(fn)
        _same_image(a, b)
        np.testing.assert_array_equal(a.decrypt(priv), b.decrypt(priv, backend=KERNELS))


def test_pyramid_levels_are_identical(scene):
    d = scene[4]
    with dask.config.set(scheduler="sync"):
        other = build_pyramid(hevr.open_volume(d / "w.zarr"), 1, backend=KERNELS, progress=False)
    a, b = hevr.open_volume(d / "v.zarr").at_level(1), other.at_level(1)
    for idx in a.brick_indices():
        for ch in ("scalar", "vector", "gradient"):
            np.testing.assert_array_equal(a.read_brick_bytes(idx, ch), b.read_brick_bytes(idx, ch))


def test_recolour_and_resident_bricks(scene, tmp_path):
    ev, _, cam, _, _ = scene
    path = tmp_path / "view.hevrsums"
    with dask.config.set(scheduler="sync"):
        hevr.render(ev, cam, mode="tf", nodes=NODES, keep_sums=path, cache=False, progress=False, backend=KERNELS)
    a, b = _pair(
        lambda backend: hevr.recolour(
            path, mode="emphasize", density=0.3, progress=False, backend=backend, finish="server"
        )
    )
    _same_image(a, b)
    resident = hevr.open_volume(ev.path).persist(backend=KERNELS)
    brick = next(iter(resident.resident.bricks.values()))
    assert isinstance(brick.channel("scalar"), LimbBatch) and brick.channel("scalar").modulus is None
    with dask.config.set(scheduler="sync"):
        want = hevr.render(ev, cam, mode="xray", progress=False, cache=False, backend="cpu")
        for _ in range(2):  # the second frame finds the bricks in Montgomery form already
            got = hevr.render(resident, cam, mode="xray", progress=False, cache=False, backend=KERNELS)
            assert got.stats["resident"] is True
            _same_image(want, got)
    assert any(b.channel("scalar").modulus == int(ev.public_key.nsquare) for b in resident.resident.bricks.values())
