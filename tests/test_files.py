"""hevr._files: atomic writes with a fixed mode, and the one missing-file error."""

from __future__ import annotations

import os
import stat
import warnings

import numpy as np
import pytest

import hevr
from hevr._files import require_file, write_atomic


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
    for call in (lambda: priv.save(tmp_path / "nodir" / "k.json"),
                 lambda: hevr.save_volume(tmp_path / "nodir" / "v.npy", np.ones((2, 2, 2)))):
        with pytest.raises(hevr.MissingFileError, match="path: expected an existing folder") as info:
            call()
        assert isinstance(info.value, FileNotFoundError) and info.value.filename == str(tmp_path / "nodir")
    assert list(tmp_path.iterdir()) == []


def test_require_file(tmp_path):
    (tmp_path / "f").write_text("x")
    assert require_file(tmp_path / "f", "f", "a file") == tmp_path / "f"
    with pytest.raises(hevr.MissingFileError, match="d: expected a folder"):
        require_file(tmp_path / "f", "d", "a folder", directory=True)
