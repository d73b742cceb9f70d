"""Ray sums kept in a .hevrsums file: recolour gives bit for bit the image of a full render, on
the default scheduler and on a cluster; every corrupted byte is an error; bad requests are named.
Also ``render(compute=False)``: the deferred image is the computed one."""

from __future__ import annotations

import numpy as np
import pytest
from dask.delayed import Delayed

import hevr
from hevr.rendering.pipeline import sums_file

NODES = [(0.2, "red"), (0.8, "blue")]


@pytest.fixture(scope="module")
def scene(tmp_path_factory, keypair256):
    pub, priv = keypair256
    vol = hevr.phantom(10)
    path = tmp_path_factory.mktemp("sums") / "v.zarr"
    ev = hevr.encrypt_volume(vol, path, priv, brick=4, vector_dims=3, progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=25, elevation=15, width=11, height=9)
    return ev, priv, vol, cam


def _same(a: hevr.EncryptedImage, b: hevr.EncryptedImage) -> bool:
    return a.shape[:2] == b.shape[:2] and all(np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts))


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_recolour_equals_a_full_render(scene, tmp_path, sampling):
    ev, priv, vol, cam = scene
    path = tmp_path / "view.hevrsums"
    first = hevr.render(
        ev, cam, mode="tf", sampling=sampling, nodes=NODES, keep_sums=path, cache=False, progress=False, tile=4
    )
    assert first.stats["map_tasks"] > 0 and path.stat().st_size > 0
    for mode, kw in [
        ("tf", {"nodes": [(0.1, "lime"), (0.5, "#ff0"), (0.9, "white")]}),
        ("emphasize", {"density": 0.4}),
        ("tf", {"nodes": NODES}),
    ]:
        again = hevr.recolour(path, mode=mode, progress=False, **kw)
        full = hevr.render(ev, cam, mode=mode, sampling=sampling, cache=False, progress=False, tile=4, **kw)
        assert again.stats["map_tasks"] == 0 and again.stats["reused_ray_sums"] is True
        assert _same(again, full), (mode, kw)
        ref = hevr.render_plain(vol, cam, mode=mode, sampling=sampling, vector_dims=3, **kw)
        assert (
            np.abs(again.decrypt(priv) - ref) <= hevr.error_bound(ev, cam, mode=mode, sampling=sampling, **kw)
        ).all()


def test_xray_sums_and_a_cluster(scene, tmp_path, cluster):
    ev, priv, vol, cam = scene
    path = tmp_path / "x.hevrsums"
    hevr.clear_cache()
    a = hevr.render(ev, cam, keep_sums=path, client=cluster, progress=False)  # sums gathered from the workers
    b = hevr.recolour(path, mode="xray", client=cluster, progress=False)
    assert _same(a, b)
    saved = hevr.load_sums(path)
    assert saved.channel == "scalar" and saved.camera == cam and saved.meta.store_id == ev.meta.store_id
    with pytest.raises(hevr.ParameterError, match="sums: expected the vector channel's sums"):
        hevr.recolour(saved, mode="tf", nodes=NODES)
    # a cached view (no new map step) can still be kept
    c = hevr.render(ev, cam, keep_sums=tmp_path / "y.hevrsums", client=cluster, progress=False)
    assert c.stats["reused_ray_sums"] and (tmp_path / "y.hevrsums").read_bytes() == path.read_bytes()


def test_every_corrupted_byte_is_an_error(scene, tmp_path):
    ev, priv, vol, cam = scene
    path = tmp_path / "v.hevrsums"
    hevr.render(ev, cam, mode="emphasize", density=0.5, keep_sums=path, cache=False, progress=False)
    blob = path.read_bytes()
    rng = np.random.default_rng(5)
    for pos in sorted(set(rng.integers(0, len(blob), 40).tolist()) | {0, 9, 20, len(blob) - 1}):
        bad = bytearray(blob)
        bad[pos] ^= 0x10
        path.write_bytes(bytes(bad))
        with pytest.raises((hevr.IntegrityError, hevr.CorruptStoreError)):
            hevr.load_sums(path)
    path.write_bytes(blob[:-100])
    with pytest.raises(hevr.IntegrityError, match="checksum mismatch"):
        hevr.load_sums(path)
    with pytest.raises(hevr.MissingFileError, match="sums: expected a ray-sums file"):
        hevr.load_sums(tmp_path / "nothing.hevrsums")


def test_header_checks_name_the_field(scene, tmp_path):
    """A file with a valid checksum but a wrong header (written by something else) is refused by field."""
    import hashlib
    import json
    import struct

    ev, priv, vol, cam = scene
    path = tmp_path / "v.hevrsums"
    hevr.render(ev, cam, keep_sums=path, cache=False, progress=False)
    blob = path.read_bytes()
    (hl,) = struct.unpack_from("<I", blob, 9)
    head = json.loads(blob[13 : 13 + hl])
    body = blob[13 + hl : -32]

    def write(h, b=body):
        raw = json.dumps(h).encode()
        data = sums_file.MAGIC + struct.pack("<I", len(raw)) + raw + b
        path.write_bytes(data + hashlib.sha256(data).digest())

    for field, value, words in [
        ("channel", "gradient", "one of the volume's channels"),
        ("components", 2, "'components'"),
        ("tile", 0, "'tile'"),
        ("width", 3, "'width'"),
        ("sampling", "cubic", "'sampling'"),
        ("step", -1, "'step'"),
        ("fingerprint", "00", "'fingerprint'"),
        ("tiles", [[0, 1], [1, 1]], "'tiles'"),
        ("tiles", [[0, 500]], r"tiles\[0\]\[1\]"),
        ("note", "added by something else", r"v\.hevrsums: header: unexpected field 'note'"),
    ]:
        write(dict(head, **{field: value}))
        with pytest.raises(hevr.CorruptStoreError, match=words):
            hevr.load_sums(path)
    write(head, body[:-1])
    with pytest.raises(hevr.CorruptStoreError, match="truncated"):
        hevr.load_sums(path)
    write({k: v for k, v in head.items() if k != "camera"})
    with pytest.raises(hevr.CorruptStoreError, match="'camera'"):
        hevr.load_sums(path)
    for coordinate in (True, "1.0"):  # JSON true or a string is no coordinate (numpy would take both as 1.0)
        camera = dict(head["camera"], position=[coordinate, *head["camera"]["position"][1:]])
        write(dict(head, camera=camera))
        with pytest.raises(hevr.CorruptStoreError, match=r"'camera': position: expected 3 finite numbers"):
            hevr.load_sums(path)


def test_compute_false_returns_the_image_unevaluated(scene, cluster):
    ev, priv, vol, cam = scene
    hevr.clear_cache()
    d = hevr.render(ev, cam, mode="tf", nodes=NODES, compute=False)
    assert isinstance(d, Delayed)
    img = d.compute()
    full = hevr.render(ev, cam, mode="tf", nodes=NODES, cache=False, progress=False)
    assert _same(img, full) and img.stats["map_tasks"] == full.stats["map_tasks"]
    fut = cluster.compute(hevr.render(ev, cam, mode="tf", nodes=NODES, client=cluster, compute=False))
    assert _same(fut.result(), full)
    with pytest.raises(hevr.ParameterError, match="keep_sums: expected None with compute=False"):
        hevr.render(ev, cam, compute=False, keep_sums="x.hevrsums")
