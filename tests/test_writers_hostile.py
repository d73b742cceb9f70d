"""Issue 24, items 1 and 6, for hevr's file writers (frames, ray sums, PNGs, keys, volumes; upgrade
targets: tests/store/test_upgrade.py).

Every writer refuses an existing path unless ``overwrite=True`` (``ExistingFileError``, the file
untouched), atomically; an operating-system refusal while writing (disk full, file-size limit,
read-only filesystem, name too long, is a folder) is a ``hevr.FileSystemError`` carrying the
errno and naming the path, and leaves the old file as it was and no temporary behind; a local
name containing ``://`` is a ``ParameterError`` naming ``path`` rather than fsspec's ValueError.
"""

from __future__ import annotations

import errno
import os
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.core import files as _files
from hevr.rendering.pipeline.sums import load_sums


@pytest.fixture(scope="module")
def scene(tmp_path_factory, keypair256):
    vol = np.random.default_rng(3).integers(0, 256, (5, 6, 7)).astype(np.uint8)
    ev = hevr.encrypt_volume(
        vol, tmp_path_factory.mktemp("w") / "v.zarr", keypair256[1], brick=3, vector_dims=2, progress=False
    )
    cam = hevr.Camera.orbit(ev, azimuth=10, width=9, height=8)
    img = hevr.render(ev, cam, progress=False)
    return ev, cam, img, img.decrypt(keypair256[1])


def _temporaries(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if ".hevr-" in p.name]


# -- item 1: refuse an existing path unless asked -----------------------------------------------
def test_a_frame_saved_over_the_private_key_is_refused(tmp_path, scene, keypair256):
    key = tmp_path / "key.json"
    keypair256[1].save(key)
    before = key.read_bytes()
    with pytest.raises(
        hevr.ExistingFileError,
        match=r"^path: expected no file at .*key\.json \(pass "
        r"overwrite=True to replace it\), found one$",
    ):
        scene[2].save(key)
    assert key.read_bytes() == before and stat.S_IMODE(key.stat().st_mode) == 0o600
    assert hevr.load_key(key).public_key.fingerprint == keypair256[0].fingerprint
    assert _temporaries(tmp_path) == []


def test_save_replaces_only_with_overwrite(tmp_path, scene, keypair256):
    path = tmp_path / "f.hevr"
    path.write_bytes(b"an older frame")
    scene[2].save(path, overwrite=True)
    assert np.array_equal(hevr.load_image(path).decrypt(keypair256[1]), scene[3])
    with pytest.raises(hevr.ExistingFileError):
        scene[2].save(path)
    with pytest.raises(hevr.ParameterError, match="overwrite: expected True or False, got 'yes'"):
        scene[2].save(tmp_path / "g.hevr", overwrite="yes")
    assert _temporaries(tmp_path) == []


def test_save_png_refuses_an_existing_file(tmp_path, scene):
    png = tmp_path / "a.png"
    png.write_bytes(b"mine")
    with pytest.raises(hevr.ExistingFileError, match="a.png"):
        hevr.save_png(scene[3], png)
    assert png.read_bytes() == b"mine"
    hevr.save_png(scene[3], png, overwrite=True)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert _temporaries(tmp_path) == []


def test_keep_sums_is_refused_before_the_render_and_replaced_when_asked(tmp_path, scene):
    ev, cam, _, _ = scene
    sums = tmp_path / "v.hevrsums"
    sums.write_bytes(b"not mine to replace")
    with pytest.raises(hevr.ExistingFileError, match=r"^keep_sums: expected no file at .*v\.hevrsums"):
        hevr.render(ev, cam, keep_sums=sums, cache=False, progress=False)
    assert sums.read_bytes() == b"not mine to replace"
    hevr.render(ev, cam, keep_sums=sums, cache=False, progress=False, overwrite=True)
    assert load_sums(sums).camera.width == cam.width
    assert _temporaries(tmp_path) == []


def test_an_object_is_refused_unless_overwrite(scene):
    url = "memory://hevr-writers-24/f.hevr"
    scene[2].save(url)
    with pytest.raises(hevr.ExistingFileError, match="memory://hevr-writers-24/f.hevr"):
        scene[2].save(url)
    scene[2].save(url, overwrite=True)
    assert hevr.load_image(url).shape == scene[2].shape


def test_s3_refuses_a_racing_writer_with_a_conditional_put(s3_server, scene, monkeypatch):
    """The existence check passes (as it would for two writers at once): the PUT itself is
    conditional (If-None-Match: *), so the object written in between is not replaced."""
    import s3fs

    bucket, so = s3_server
    url = f"{bucket}/race-24.hevr"
    fs = s3fs.S3FileSystem(skip_instance_cache=True, **so)
    fs.pipe_file(url[5:], b"written by the other writer")
    monkeypatch.setattr(s3fs.S3FileSystem, "exists", lambda self, path, **kw: False)
    with pytest.raises(hevr.ExistingFileError, match="race-24.hevr"):
        scene[2].save(url, storage_options=so)
    assert fs.cat_file(url[5:]) == b"written by the other writer"


# -- item 6: the operating system's refusals, one error family --------------------------------
def _writers(scene, keypair256):
    img, arr = scene[2], scene[3]
    return {
        "image": lambda p, o: img.save(p, overwrite=o),
        "png": lambda p, o: hevr.save_png(arr, p, overwrite=o),
        "private key": lambda p, o: keypair256[1].save(p, overwrite=o),
        "public key": lambda p, o: keypair256[0].save(p, overwrite=o),
    }


def _raise(code: int):
    def fake(*args, **kwargs):
        raise OSError(code, os.strerror(code))

    return fake


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EFBIG, errno.EROFS], ids=errno.errorcode.get)
@pytest.mark.parametrize("step", ["write", "replace", "link"])
@pytest.mark.parametrize("writer", ["image", "png", "private key", "public key"])
def test_a_failed_write_is_a_filesystem_error_and_leaves_the_old_file(
    tmp_path, scene, keypair256, monkeypatch, writer, step, code
):
    write = _writers(scene, keypair256)[writer]
    path = tmp_path / "out.bin"
    overwrite = step != "link"  # a new file is linked into place, a replaced one renamed over the old
    if overwrite:
        path.write_bytes(b"the old file")
    with monkeypatch.context() as m:
        m.setattr(_files.os, step, _raise(code))
        with pytest.raises(hevr.FileSystemError) as info:
            write(path, overwrite)
    exc = info.value
    assert isinstance(exc, OSError) and isinstance(exc, hevr.HevrError) and exc.errno == code
    assert str(path) in str(exc) and str(exc).startswith("writing") and f"({errno.errorcode[code]})" in str(exc)
    assert "\n" not in str(exc)
    if overwrite:
        assert path.read_bytes() == b"the old file"
    else:
        assert not path.exists()
    assert _temporaries(tmp_path) == []


def test_a_name_too_long_and_a_folder_in_the_way(tmp_path, scene):
    img = scene[2]
    with pytest.raises(hevr.FileSystemError) as info:
        img.save(tmp_path / ("x" * 300 + ".hevr"))
    assert info.value.errno == errno.ENAMETOOLONG
    near = tmp_path / ("y" * 250 + ".hevr")  # 255 bytes: the temporary sibling gets a short hashed name
    img.save(near)
    img.save(near, overwrite=True)
    assert hevr.load_image(near).shape == img.shape
    folder = tmp_path / "f.hevr"
    folder.mkdir()
    with pytest.raises(hevr.ExistingFileError):
        img.save(folder)
    with pytest.raises(hevr.FileSystemError) as info:
        img.save(folder, overwrite=True)
    assert info.value.errno == errno.EISDIR and folder.is_dir()
    (tmp_path / "plain").write_text("a file")
    with pytest.raises(hevr.HevrError) as info:  # a file where a folder should be: nothing to write into
        hevr.save_png(scene[3], tmp_path / "plain" / "a.png")
    assert isinstance(info.value, OSError) and "plain" in str(info.value)
    assert _temporaries(tmp_path) == []


@pytest.mark.skipif(not hasattr(os, "fork") or sys.platform != "linux", reason="RLIMIT_FSIZE on Linux")
def test_a_real_file_size_limit_is_efbig(tmp_path):
    """A process whose file-size limit is below the PNG (SIGXFSZ ignored): write() fails with EFBIG."""
    code = textwrap.dedent(f"""
        import errno, resource, signal, sys, numpy as np, hevr
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        noise = np.random.default_rng(0).random((300, 300))
        try:
            hevr.save_png(noise, {str(tmp_path / "big.png")!r})
        except hevr.FileSystemError as exc:
            print("FileSystemError", errno.errorcode[exc.errno], exc)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("FileSystemError EFBIG writing the PNG"), out.stdout
    assert "big.png" in out.stdout and list(tmp_path.iterdir()) == []


# -- a local name with '://' ---------------------------------------------------------------------
@pytest.mark.parametrize("name", ["a://b.hevr", "dir/x://y.hevr", "S3://bucket/f.hevr"])
def test_a_local_name_with_a_scheme_separator_is_a_parameter_error(tmp_path, scene, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(hevr.ParameterError, match=r"^path: expected a local path or an fsspec URL"):
        scene[2].save(name)
    with pytest.raises(hevr.ParameterError, match=r"^path: expected a local path or an fsspec URL"):
        hevr.load_image(name)
    ev, cam = scene[0], scene[1]
    with pytest.raises(hevr.ParameterError, match=r"^keep_sums: expected a local path or an fsspec URL"):
        hevr.render(ev, cam, keep_sums=name.replace(".hevr", ".hevrsums"), cache=False, progress=False)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["v.npy", "v_5x4x3_int16.raw", "v.nrrd", "v.nhdr", "g.nhdr"])
def test_save_volume_refuses_an_existing_file_and_replaces_only_when_asked(tmp_path, name):
    vol = np.arange(60, dtype=">i2").reshape(3, 4, 5)  # big-endian, as some NRRD files are
    kw = {"encoding": "gzip"} if name == "g.nhdr" else {}
    path = hevr.save_volume(tmp_path / name, vol, **kw)
    written = sorted(p.name for p in tmp_path.iterdir())
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(hevr.ExistingFileError, match="pass overwrite=True"):
        hevr.save_volume(tmp_path / name, vol + 1, **kw)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # nothing touched, nothing left
    hevr.save_volume(tmp_path / name, vol + 1, overwrite=True, **kw)
    assert sorted(p.name for p in tmp_path.iterdir()) == written
    if not name.endswith(".raw"):
        assert np.array_equal(hevr.load_volume(path)[0], vol + 1)


def test_save_volume_refuses_a_header_whose_data_file_exists(tmp_path):
    (tmp_path / "v.raw").write_bytes(b"someone else's data")
    with pytest.raises(hevr.ExistingFileError, match="v.raw"):
        hevr.save_volume(tmp_path / "v.nhdr", np.zeros((2, 2, 2), np.uint8))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.raw"]
    assert (tmp_path / "v.raw").read_bytes() == b"someone else's data"


def test_save_volume_on_a_full_disk_is_a_filesystem_error(tmp_path, monkeypatch):
    monkeypatch.setattr(_files.os, "write", _raise(errno.ENOSPC))
    with pytest.raises(hevr.FileSystemError, match=r"writing the volume .*v\.npy: .*\(ENOSPC\)"):
        hevr.save_volume(tmp_path / "v.npy", np.zeros((2, 2, 2), np.uint8))
    assert list(tmp_path.iterdir()) == []


# -- review: the temporary stays locked from its creation until it is in place -------------------
def test_a_temporary_removed_before_its_lock_is_taken_is_made_afresh(tmp_path, monkeypatch):
    """Another writer's clean-up may find the temporary in the instant between its creation and
    its lock, and remove it: the write starts over with a fresh temporary, never fails."""
    real, calls = _files.fcntl.flock, []

    def flock(fd, op):
        if not calls:  # the first lock of a fresh temporary: a clean-up removes it just before
            calls.append(fd)
            assert _files.remove_stale(tmp_path / "a.bin")
        return real(fd, op)

    monkeypatch.setattr(_files.fcntl, "flock", flock)
    _files.write_file(tmp_path / "a.bin", [b"payload"])
    assert calls and (tmp_path / "a.bin").read_bytes() == b"payload"
    assert _temporaries(tmp_path) == []


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_concurrent_clean_up_keeps_off_a_temporary_until_it_is_in_place(tmp_path, monkeypatch, overwrite):
    """The lock is held up to the final link or rename, so another writer of the same path
    removing stale temporaries at that moment leaves this one alone."""
    path = tmp_path / "a.bin"
    if overwrite:
        path.write_bytes(b"old")
    link, replace = _files._link_new, _files.os.replace

    def cleaned_first(fn):
        def run(src, dst, *rest):
            assert _files.remove_stale(path) == []  # the writer holds the lock: nothing removed
            return fn(src, dst, *rest)

        return run

    monkeypatch.setattr(_files, "_link_new", cleaned_first(link))
    monkeypatch.setattr(_files.os, "replace", cleaned_first(replace))
    _files.write_file(path, [b"new"], overwrite=overwrite)
    assert path.read_bytes() == b"new" and _temporaries(tmp_path) == []
