"""Stores, frames and ray sums on object storage (hevr.store.paths): a real S3-compatible server
(moto's, conftest's ``s3_server``) on 127.0.0.1, renders on a LocalCluster of two worker
processes, ``file://`` and ``memory://`` URLs, and ``hevr --storage-option``."""

from __future__ import annotations

import contextlib
import io
import logging
import pickle
import re
import uuid

import dask
import numpy as np
import pytest
import s3fs
from distributed import Client, LocalCluster

import hevr
from hevr.cli.main import main
from hevr.store import writer as store_mod

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

SHAPE, BRICK = (5, 6, 7), (2, 3, 4)  # 3 × 2 × 2 bricks, ragged on every axis


@pytest.fixture(scope="module")
def procs():
    """Two worker processes: they see the S3 server over HTTP, and nothing of this process's memory."""
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as lc,
        Client(lc, set_as_default=False) as c,
    ):
        yield c


def _vol() -> np.ndarray:
    return np.random.default_rng(7).integers(0, 256, SHAPE).astype(np.uint8)


def _url(s3_server, name: str) -> tuple[str, dict]:
    base, so = s3_server
    return f"{base}/{uuid.uuid4().hex[:8]}/{name}", so


def _fs(so: dict) -> s3fs.S3FileSystem:
    return s3fs.S3FileSystem(skip_instance_cache=True, **so)


def _check(ev, vol, priv, client=None, **kw) -> hevr.EncryptedImage:
    """Render, decrypt and compare with the plaintext render within the error bound."""
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=6, height=6)
    img = hevr.render(ev, cam, client=client, cache=False, progress=False, **kw)
    ref = hevr.render_plain(vol, cam, vector_dims=ev.vector_dims, **kw)
    assert np.count_nonzero(ref) > 5
    assert np.all(np.abs(img.decrypt(priv) - ref) <= hevr.error_bound(ev, cam, **kw))
    return img


def test_s3_encrypt_render_decrypt_on_two_worker_processes(s3_server, procs, keypair256, caplog):
    pub, priv = keypair256
    vol = _vol()
    url, so = _url(s3_server, "v.zarr")
    with caplog.at_level(logging.INFO, logger="hevr"):
        ev = hevr.encrypt_volume(
            vol, url, pub, brick=BRICK, vector_dims=2, client=procs, progress=False, storage_options=so
        )
    assert ev.path == url and ev.storage_options == so
    assert so["secret"] not in repr(ev) and so["secret"] not in caplog.text
    assert pickle.loads(pickle.dumps(ev)).storage_options == so  # what the tasks get
    ev = hevr.open_volume(url, storage_options=so)
    _check(ev, vol, priv, client=procs)
    img = _check(ev, vol, priv, client=procs, mode="emphasize", density=0.5)
    frame = url.replace("v.zarr", "frame.hevr")
    img.save(frame, storage_options=so)
    again = hevr.load_image(frame, storage_options=so)
    assert np.array_equal(again.decrypt(priv, density=0.5), img.decrypt(priv))  # the density stays with the client
    with pytest.raises(hevr.MissingFileError):
        hevr.load_image(frame + ".nothing", storage_options=so)
    with pytest.raises(hevr.MissingFileError):
        hevr.open_volume(url + ".nothing", storage_options=so)
    # a pyramid level built by the workers, from the store alone
    ev = hevr.build_pyramid(ev, 1, client=procs, progress=False)
    assert ev.levels == 1 and ev.storage_options == so
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=6, height=6)
    lvl = hevr.render(ev, cam, level=1, client=procs, cache=False, progress=False).decrypt(priv)
    ref = hevr.render_plain(vol, cam, level=1)
    assert np.all(np.abs(lvl - ref) <= hevr.error_bound(ev, cam, level=1))


def test_s3_resume_after_an_interrupted_upload(s3_server, procs, keypair256, monkeypatch):
    pub, priv = keypair256
    vol = _vol()
    url, so = _url(s3_server, "v.zarr")
    real, calls = store_mod._encrypt_brick, []

    def flaky(*args, **kw):
        if len(calls) >= 5:
            raise RuntimeError("upload interrupted")
        calls.append(args[2])
        return real(*args, **kw)

    monkeypatch.setattr(store_mod, "_encrypt_brick", flaky)
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError, match="upload interrupted"):
        hevr.encrypt_volume(vol, url, pub, brick=BRICK, progress=False, storage_options=so)
    monkeypatch.setattr(store_mod, "_encrypt_brick", real)
    with pytest.raises(hevr.IncompleteStoreError, match="7 of 12 bricks missing"):
        hevr.open_volume(url, storage_options=so)
    with pytest.raises(hevr.StoreExistsError):
        hevr.encrypt_volume(vol, url, pub, brick=BRICK, progress=False, storage_options=so)
    with pytest.raises(hevr.ParameterError, match="brick .* differs"):  # the journal guards a resume on S3 too
        hevr.encrypt_volume(vol[::-1].copy(), url, pub, brick=BRICK, progress=False, resume=True, storage_options=so)
    ev = hevr.encrypt_volume(vol, url, pub, brick=BRICK, progress=False, resume=True, client=procs, storage_options=so)
    assert ev.meta.complete
    _check(hevr.open_volume(url, verify="full", storage_options=so), vol, priv, client=procs)


def test_s3_overwrite_replaces_the_store(s3_server, keypair256):
    """overwrite=True on S3: the new store is written beside the old one and moved in (object
    by object: S3 has no rename and no folders); nothing else is left in the prefix."""
    pub, priv = keypair256
    vol = _vol()
    url, so = _url(s3_server, "v.zarr")
    first = hevr.encrypt_volume(vol, url, pub, brick=SHAPE, progress=False, storage_options=so)  # one brick
    other = (255 - vol).astype(np.uint8)
    ev = hevr.encrypt_volume(other, url, pub, brick=SHAPE, progress=False, overwrite=True, storage_options=so)
    ev = hevr.open_volume(url, storage_options=so)
    assert ev.meta.store_id != first.meta.store_id
    assert priv.decrypt_array(ev.read_brick((0, 0, 0))) == other.ravel().tolist()
    assert _fs(so).ls(url[len("s3://") :].rsplit("/", 1)[0]) == [url[len("s3://") :]]


def test_s3_integrity_checks_hold(s3_server, keypair256):
    """A damaged, truncated or missing chunk object, or an edited metadata document, is a
    CorruptStoreError (at open or at the read), never an image."""
    pub, priv = keypair256
    vol = _vol()
    url, so = _url(s3_server, "v.zarr")
    ev = hevr.encrypt_volume(vol, url, pub, brick=BRICK, progress=False, storage_options=so)
    fs, root = _fs(so), url[len("s3://") :]
    chunk = f"{root}/scalar/c/1/1/0/0"
    blob = fs.cat_file(chunk)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=6, height=6)
    clean = hevr.render(ev, cam, cache=False, progress=False).decrypt(priv)
    for pos in (0, len(blob) // 2, len(blob) - 1):
        bad = bytearray(blob)
        bad[pos] ^= 0x10
        fs.pipe_file(chunk, bytes(bad))
        with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 1, 0\)"):
            hevr.render(hevr.open_volume(url, storage_options=so), cam, cache=False, progress=False)
    fs.pipe_file(chunk, blob[:5])
    with pytest.raises(hevr.CorruptStoreError, match="truncated"):
        hevr.open_volume(url, storage_options=so)
    fs.rm_file(chunk)
    with pytest.raises(hevr.CorruptStoreError, match=r"missing chunk for brick \(1, 1, 0\)"):
        hevr.open_volume(url, storage_options=so)
    fs.pipe_file(chunk, blob)
    assert np.array_equal(
        hevr.render(hevr.open_volume(url, storage_options=so), cam, cache=False, progress=False).decrypt(priv), clean
    )
    doc = fs.cat_file(f"{root}/scalar/zarr.json")
    fs.pipe_file(f"{root}/scalar/zarr.json", doc.replace(b'"fill_value": 0', b'"fill_value":0'))
    with pytest.raises(hevr.CorruptStoreError, match="metadata document of array 'scalar'") as info:
        hevr.open_volume(url, storage_options=so)
    assert so["secret"] not in str(info.value)


def test_file_urls_are_local_paths(tmp_path, keypair256):
    pub, priv = keypair256
    vol = _vol()
    ev = hevr.encrypt_volume(vol, f"file://{tmp_path}/v.zarr", pub, brick=BRICK, progress=False)
    assert ev.path == str((tmp_path / "v.zarr").resolve()) and (tmp_path / "v.zarr" / "zarr.json").is_file()
    ev = hevr.open_volume(f"file://{tmp_path}/v.zarr/")
    img = _check(ev, vol, priv)
    img.save(f"file://{tmp_path}/f.hevr")
    assert (tmp_path / "f.hevr").is_file()
    assert np.array_equal(hevr.load_image(f"file://{tmp_path}/f.hevr").decrypt(priv), img.decrypt(priv))


def test_memory_urls_work_in_this_process_and_are_refused_on_a_cluster(procs, cluster, keypair256):
    pub, priv = keypair256
    vol = _vol()
    url = f"memory://hevr-test-{uuid.uuid4().hex[:8]}/v.zarr"
    ev = hevr.encrypt_volume(vol, url, pub, brick=BRICK, progress=False)  # Dask's threaded scheduler
    _check(ev, vol, priv)
    _check(ev, vol, priv, client=cluster)  # in-process workers (LocalCluster(processes=False)) share it
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=6, height=6)
    refused = "memory:// stores live in this process; workers of a distributed cluster cannot see them"
    with pytest.raises(hevr.ParameterError, match=refused) as info:
        hevr.render(ev, cam, client=procs, cache=False, progress=False)
    assert url in str(info.value)
    with pytest.raises(hevr.ParameterError, match=refused):
        hevr.encrypt_volume(vol, url + "2", pub, brick=BRICK, client=procs, progress=False)
    with pytest.raises(hevr.ParameterError, match=refused):
        hevr.build_pyramid(ev, 1, client=procs, progress=False)
    with pytest.raises(hevr.ParameterError, match=refused):
        ev.persist(client=procs)
    with procs.as_current(), pytest.raises(hevr.ParameterError, match=refused):  # the active client too
        hevr.render(ev, cam, cache=False, progress=False)


def test_storage_options_must_be_a_dict(tmp_path, keypair256):
    with pytest.raises(hevr.ParameterError, match="storage_options: expected a dict"):
        hevr.open_volume("memory://x/v.zarr", storage_options=["endpoint"])


def _cli(*argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def test_cli_round_trip_with_storage_options(s3_server, tmp_path, monkeypatch):
    url, so = _url(s3_server, "vol.zarr")
    frame = url.replace("vol.zarr", "xray.hevr")
    opts = ["--storage-option", f"endpoint_url={so['endpoint_url']}", "--storage-option", f"key={so['key']}"]
    monkeypatch.setenv("HEVR_STORAGE_OPTIONS", f'{{"secret": "{so["secret"]}", "key": "overridden"}}')
    # a key without the policy (the store is made with the public key: no tags); storage options are the point
    assert _cli("keygen", "--bits", "256", "--out", tmp_path / "key.json", "--no-require-tags")[0] == 0
    code, out, err = _cli(
        "encrypt", "phantom:8", "--key", tmp_path / "key.pub.json", "--out", url, "--brick", "4", "-q", *opts
    )
    assert code == 0, err
    assert _cli("encrypt", "phantom:8", "--key", tmp_path / "key.pub.json", "--out", url, "-q", *opts)[0] == 2
    sums, again = url.replace("vol.zarr", "view.hevrsums"), url.replace("vol.zarr", "again.hevr")
    code, out, err = _cli(
        "render", url, "--out", frame, "--size", "8x8", "--azimuth", "20", "--keep-sums", sums, "-q", *opts
    )
    assert code == 0, err
    code, out, err = _cli("recolour", sums, "--out", again, "-q", *opts)  # X-ray sums: the same frame again
    assert code == 0, err
    fs = _fs(so)
    assert fs.cat_file(again[len("s3://") :]) == fs.cat_file(frame[len("s3://") :])
    code, out, err = _cli("slice", url, "--out", url.replace("vol.zarr", "axial.hevr"), "--axial", "3", "-q", *opts)
    assert code == 0, err
    code, out, err = _cli("info", url, *opts)
    assert code == 0 and "encrypted volume store" in out and re.search(r"check:\s+ok", out), (out, err)
    code, out, err = _cli("info", frame, *opts)
    assert code == 0 and "encrypted image" in out, (out, err)
    code, out, err = _cli(
        "decrypt",
        frame,
        "--key",
        tmp_path / "key.json",
        "--out",
        tmp_path / "x.png",
        "--npy",
        tmp_path / "x.npy",
        *opts,
    )
    assert code == 0, err
    ev = hevr.open_volume(url, storage_options=so)
    cam = hevr.Camera.orbit(ev, azimuth=20, elevation=0, width=8, height=8)
    ref = hevr.render_plain(hevr.phantom(8), cam)
    assert np.all(np.abs(np.load(tmp_path / "x.npy") - ref) <= hevr.error_bound(ev, cam))
    code, out, err = _cli("pyramid", url, "--levels", "1", "-q", *opts)
    assert code == 0 and "built levels 1..1" in out, err
    for text in (out, err):
        assert so["secret"] not in text
    monkeypatch.delenv("HEVR_STORAGE_OPTIONS")
    code, out, err = _cli("render", url, "--out", frame, "-q", *opts)  # no secret now: no credentials
    assert code == 1 and so["secret"] not in err
    monkeypatch.setenv("HEVR_STORAGE_OPTIONS", "not json")
    code, out, err = _cli("info", url, *opts)
    assert code == 2 and "HEVR_STORAGE_OPTIONS: expected a JSON object" in err


def test_no_unclosed_client_session_at_exit(s3_server, tmp_path):
    """Issue 39, item 9: Zarr's asynchronous s3fs filesystems kept their aiohttp sessions open;
    each printed "Unclosed client session" at interpreter exit (12 after the test suite). A
    process that encrypts to, opens and renders from S3 now exits without one."""
    import subprocess
    import sys

    url, so = _url(s3_server, "v.zarr")
    script = f"""
import warnings; warnings.simplefilter("ignore")
import hevr
pub, priv = hevr.generate_keypair(256)
ev = hevr.encrypt_volume(hevr.phantom(6), {url!r}, priv, brick=3, storage_options={so!r}, progress=False)
ev = hevr.open_volume({url!r}, storage_options={so!r})
img = hevr.render(ev, hevr.Camera.orbit(ev, width=4, height=4), progress=False)
img.save({url + ".hevr"!r}, storage_options={so!r})
print("done", hevr.load_image({url + ".hevr"!r}, storage_options={so!r}).shape)
"""
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0 and "done (4, 4)" in run.stdout, run.stderr
    assert "Unclosed" not in run.stderr and "client_session" not in run.stderr, run.stderr


def test_closed_sessions_open_again_when_used(s3_server, keypair256):
    from hevr.store.sessions import close_sessions

    url, so = _url(s3_server, "v.zarr")
    hevr.encrypt_volume(_vol(), url, keypair256[1], brick=BRICK, storage_options=so, progress=False)
    assert close_sessions() >= 1  # what this process opened on S3
    ev = hevr.open_volume(url, storage_options=so)  # the same cached filesystem: a new session
    assert ev.shape == SHAPE and close_sessions() >= 1
