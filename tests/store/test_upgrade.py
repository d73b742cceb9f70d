"""hevr.store.upgrade: a format-1 store (built here exactly as the format-1 writer laid it
out: no crc32c, one-byte done markers, no checksum, no store_id) is refused by open_volume
with the upgrade command, and upgrade_store copies it into a format-2 store whose records are
byte-identical and whose renders match render_plain."""

from __future__ import annotations

import dataclasses
import os
import threading
from pathlib import Path

import numpy as np
import pytest
import zarr

import hevr
from hevr.cli.main import main
from hevr.crypto.records import record_width
from hevr.store.metadata import ChannelInfo, VolumeMetadata
from hevr.store.reader import brick_slices

SHAPE, BRICK = (5, 6, 7), (2, 3, 4)


def _v1_store(path: Path, pub, vol: np.ndarray, complete: bool = True) -> VolumeMetadata:
    w = record_width(int(pub.n))
    meta = VolumeMetadata(
        shape=SHAPE,
        spacing=(1.0, 1.0, 1.0),
        brick=BRICK,
        n=str(int(pub.n)),
        fingerprint=pub.fingerprint,
        ciphertext_bytes=w,
        dtype="uint8",
        value_range=(0.0, 255.0),
        scalar=ChannelInfo(exponent=0),
        vector=None,
        complete=complete,
        version=1,
    )
    group = zarr.open_group(str(path), mode="w")
    group.create_array("scalar", shape=SHAPE + (w,), chunks=BRICK + (w,), dtype="uint8", compressors=None, fill_value=0)
    group.create_array("done", shape=meta.grid, chunks=(1, 1, 1), dtype="uint8", compressors=None, fill_value=0)
    for idx in np.ndindex(*meta.grid):
        sl = brick_slices(meta, idx)
        cts = pub.encrypt_array(vol[sl].ravel().tolist())
        group["scalar"][sl] = np.array([list(int(c).to_bytes(w, "big")) for c in cts], np.uint8).reshape(
            vol[sl].shape + (w,)
        )
        group["done"][idx] = 1
    group.attrs["hevr"] = meta.to_dict()
    return meta


@pytest.fixture()
def v1(tmp_path, keypair256):
    vol = np.random.default_rng(5).integers(0, 256, SHAPE).astype(np.uint8)
    _v1_store(tmp_path / "old.zarr", keypair256[0], vol)
    return tmp_path / "old.zarr", vol


def test_v1_store_is_refused_with_the_upgrade_command(v1):
    path, _ = v1
    with pytest.raises(hevr.CorruptStoreError, match=rf"format version 1 .* hevr upgrade-store {path} NEW.zarr"):
        hevr.open_volume(path)


def test_upgrade_copies_records_and_renders_right(v1, tmp_path, keypair256):
    path, vol = v1
    old_files = {f: f.read_bytes() for f in path.rglob("*") if f.is_file()}
    ev = hevr.upgrade_store(path, tmp_path / "new.zarr", progress=False)
    assert ev.meta.version == 2 and ev.meta.complete and len(ev.meta.store_id) == 16
    assert old_files == {f: f.read_bytes() for f in path.rglob("*") if f.is_file()}  # source untouched
    old = zarr.open_array(str(path / "scalar"), mode="r")[...]
    assert np.array_equal(np.asarray(zarr.open_array(str(tmp_path / "new.zarr" / "scalar"), mode="r")[...]), old)
    hevr.open_volume(ev.path, verify="full")
    cam = hevr.Camera.orbit(ev, azimuth=30, width=8, height=8)
    got = hevr.render(ev, cam, progress=False).decrypt(keypair256[1])
    ref = hevr.render_plain(vol, cam, value_range=ev.value_range)
    assert np.all(np.abs(got - ref) <= hevr.error_bound(ev, cam))


def test_upgrade_refuses_what_it_cannot_convert(v1, tmp_path, keypair256):
    path, vol = v1
    with pytest.raises(hevr.StoreExistsError, match="dst: .* already exists"):
        hevr.upgrade_store(path, path, progress=False)
    new = hevr.upgrade_store(path, tmp_path / "new.zarr", progress=False)
    with pytest.raises(hevr.ParameterError, match="src: expected a format-1 store, got format 2"):
        hevr.upgrade_store(new.path, tmp_path / "again.zarr", progress=False)
    with pytest.raises(hevr.MissingFileError):
        hevr.upgrade_store(tmp_path / "nothing.zarr", tmp_path / "x.zarr", progress=False)
    _v1_store(tmp_path / "half.zarr", keypair256[0], vol, complete=False)
    with pytest.raises(hevr.IncompleteStoreError):
        hevr.upgrade_store(tmp_path / "half.zarr", tmp_path / "y.zarr", progress=False)


def test_upgrade_refuses_out_of_range_records(v1, tmp_path):
    path, _ = v1
    arr = zarr.open_array(str(path / "scalar"), mode="r+")
    arr[1, 4, 5] = 255  # >= n² (n² < 2^512 = 64 bytes of 0xFF)
    with pytest.raises(
        hevr.CorruptStoreError, match=r"brick \(0, 1, 1\) of channel 'scalar': ciphertext \d+ is not in"
    ):
        hevr.upgrade_store(path, tmp_path / "new.zarr", progress=False)


def test_metadata_of_a_v1_store_has_no_checksum():
    meta = dataclasses.replace(
        VolumeMetadata(
            shape=SHAPE,
            spacing=(1.0, 1.0, 1.0),
            brick=BRICK,
            n="3233",
            fingerprint="ab" * 32,
            ciphertext_bytes=3,
            dtype="uint8",
            value_range=(0.0, 1.0),
            scalar=ChannelInfo(0),
            vector=None,
        ),
        version=1,
    )
    assert "checksum" not in meta.to_dict()


# -- integrity on the command line ------------------------------------------------------------------


def test_upgrade_store_command_and_info_on_old_formats(tmp_path, keypair256, capsys):
    """A format-1 store: `hevr info` says how to upgrade, `hevr upgrade-store` converts it, and a
    format-1 image is named as such, not taken for a volume file."""
    vol = np.random.default_rng(1).integers(0, 256, SHAPE).astype(np.uint8)
    _v1_store(tmp_path / "old.zarr", keypair256[0], vol)
    assert main(["info", str(tmp_path / "old.zarr")]) == 1  # described, but its check fails: cannot be opened
    out = capsys.readouterr().out
    assert "version 1" in out and "hevr upgrade-store" in out and "FAILED" in out
    assert main(["upgrade-store", str(tmp_path / "old.zarr"), str(tmp_path / "new.zarr"), "--workers", "0", "-q"]) == 0
    assert hevr.open_volume(tmp_path / "new.zarr", verify="full").meta.version == 2
    assert main(["upgrade-store", str(tmp_path / "old.zarr"), str(tmp_path / "new.zarr"), "--workers", "0"]) == 2
    assert "already exists" in capsys.readouterr().err
    (tmp_path / "v1.hevr").write_bytes(b"HEVRIMG\x01" + b"\x00" * 64)
    assert main(["info", str(tmp_path / "v1.hevr")]) == 1
    assert "version 1 is no longer read" in capsys.readouterr().err


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_a_damaged_old_chunk_is_named_and_leaves_nothing(v1, tmp_path, damage):
    path, _ = v1
    f = path / "scalar" / "c" / "1" / "0" / "1" / "0"
    blob = f.read_bytes()
    f.write_bytes(blob[:-7] if damage == "truncate" else b"\x1f\x8b" + blob)
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 0, 1\) of channel 'scalar'"):
        hevr.upgrade_store(path, tmp_path / "new.zarr", progress=False)
    assert not (tmp_path / "new.zarr").exists()


@pytest.mark.parametrize("rel", ["scalar/zarr.json", "scalar/c/1/0/1/0"])
def test_a_fifo_in_the_old_store_fails_fast(v1, tmp_path, rel):
    """A FIFO in place of a document or a chunk of the source is named, never read (a read blocks)."""
    path, _ = v1
    fifo = path / rel
    fifo.unlink()
    os.mkfifo(fifo)
    box: dict = {}

    def upgrade():
        try:
            hevr.upgrade_store(path, tmp_path / "new.zarr", progress=False)
        except BaseException as exc:  # noqa: BLE001 - checked below
            box["error"] = exc

    t = threading.Thread(target=upgrade, daemon=True)
    t.start()
    t.join(60)
    for _ in range(100 if t.is_alive() else 0):  # blocked: let it go (open the FIFO's write end), then fail
        box["blocked"] = True
        try:
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:
            pass
        t.join(0.1)
        if not t.is_alive():
            break
    assert "blocked" not in box, "upgrade_store blocked on a FIFO"
    assert isinstance(box.get("error"), hevr.CorruptStoreError), box
    assert "(a regular file), got a FIFO" in str(box["error"])
    assert not (tmp_path / "new.zarr").exists()


# -- issue 24: the target is never written over (an upgrade is a writer like any other) ---------
def _hidden_left(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if ".hevr-" in p.name]


def test_upgrade_never_builds_into_a_path_that_appears_meanwhile(v1, monkeypatch):
    """The target is checked first; a folder created after that check (another writer) is not
    wiped: the finished store is put in place by a rename that never replaces, so the upgrade
    refuses."""
    from hevr.store import upgrade

    old, _ = v1
    dst = old.parent / "new.zarr"
    dst.mkdir()
    (dst / "notes.txt").write_text("someone else's")
    monkeypatch.setattr(upgrade, "store_exists", lambda *a, **k: False)  # the check raced
    with pytest.raises(hevr.StoreExistsError, match="dst: .*new.zarr"):
        hevr.upgrade_store(old, dst, progress=False)
    assert sorted(p.name for p in dst.iterdir()) == ["notes.txt"]
    assert _hidden_left(old.parent) == []


def test_upgrade_refuses_an_existing_target(v1):
    old, _ = v1
    (old.parent / "new.zarr").write_text("a file")
    with pytest.raises(hevr.StoreExistsError, match="dst: .*already exists"):
        hevr.upgrade_store(old, old.parent / "new.zarr", progress=False)
    assert (old.parent / "new.zarr").read_text() == "a file"
    ev = hevr.upgrade_store(old, old.parent / "fresh.zarr", progress=False)
    assert ev.meta.complete and _hidden_left(old.parent) == []
