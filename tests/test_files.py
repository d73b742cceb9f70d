"""hevr.core.files: atomic writes with a fixed mode, and the one missing-file error."""

from __future__ import annotations

import os
import stat
import warnings

import numpy as np
import pytest

import hevr
from hevr.core.files import require_file, write_atomic


def test_write_atomic_mode_and_no_leftovers(tmp_path):
    target = tmp_path / "k.json"
    write_atomic(target, "secret\n", mode=0o600)
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o600 and target.read_text() == "secret\n"
    write_atomic(target, "public\n", mode=0o644)  # replaces, never appends
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o644 and target.read_text() == "public\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.json"]


def test_missing_folder_is_a_missing_file_error_naming_the_folder(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        _, priv = hevr.generate_keypair(128)
    for call in (
        lambda: priv.save(tmp_path / "nodir" / "k.json"),
        lambda: hevr.save_volume(tmp_path / "nodir" / "v.npy", np.ones((2, 2, 2))),
    ):
        with pytest.raises(hevr.MissingFileError, match="path: expected an existing folder") as info:
            call()
        assert isinstance(info.value, FileNotFoundError) and info.value.filename == str(tmp_path / "nodir")
    assert list(tmp_path.iterdir()) == []


def test_require_file(tmp_path):
    (tmp_path / "f").write_text("x")
    assert require_file(tmp_path / "f", "f", "a file") == tmp_path / "f"
    with pytest.raises(hevr.MissingFileError, match="d: expected a folder"):
        require_file(tmp_path / "f", "d", "a folder", directory=True)


@pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")
def test_names_that_are_not_utf8_are_written_and_read_back(tmp_path, keypair256):
    """Issue 39, item 3: a Linux name that is not UTF-8 (b"\\xff", decoded by os.fsdecode into a
    surrogate escape) raised UnicodeEncodeError in every writer; now each writes those bytes."""
    pub, priv = keypair256
    name = os.fsdecode(b"\xff\xfe")
    d = str(tmp_path) + os.sep
    priv.save(d + name + ".json")
    pub.save(d + name + ".pub.json")
    vol = hevr.phantom(8)
    ev = hevr.encrypt_volume(vol, d + name + ".zarr", priv, brick=4, progress=False)
    ev = hevr.encrypt_volume(
        vol, d + name + ".zarr", priv, brick=4, progress=False, overwrite=True
    )  # beside, then swapped
    cam = hevr.Camera.orbit(ev, width=6, height=5)
    img = hevr.render(ev, cam, progress=False, keep_sums=d + name + ".hevrsums")
    img.save(d + name + ".hevr")
    back = hevr.load_image(d + name + ".hevr").decrypt(hevr.load_key(d + name + ".json"))
    assert (np.abs(back - hevr.render_plain(vol, cam)) <= hevr.error_bound(ev, cam)).all()
    hevr.save_png(back, d + name + ".png")
    hevr.save_volume(d + name + ".npy", vol)
    assert hevr.load_key(d + name + ".pub.json").fingerprint == pub.fingerprint
    written = sorted(os.listdir(os.fsencode(str(tmp_path))))
    assert written == sorted(
        b"\xff\xfe" + s for s in (b".json", b".pub.json", b".zarr", b".hevrsums", b".hevr", b".png", b".npy")
    ), written


def test_a_name_no_filesystem_can_store_is_a_parameter_error(tmp_path, keypair256):
    bad = str(tmp_path / (chr(0xD800) + "x"))  # a lone surrogate that no bytes decode to
    for call, name in (
        (lambda: keypair256[1].save(bad + ".json"), "path"),
        (lambda: hevr.save_png(np.ones((2, 2)), bad + ".png"), "path"),
        (lambda: hevr.encrypt_volume(hevr.phantom(4), bad + ".zarr", keypair256[1], progress=False), "path"),
    ):
        with pytest.raises(hevr.ParameterError) as info:
            call()
        assert str(info.value).startswith(f"{name}: expected a name the filesystem can store")
        assert repr(bad)[1:-1] in str(info.value)
    assert os.listdir(tmp_path) == []
