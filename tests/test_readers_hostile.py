"""Issue 24: every reader refuses a file that is not a regular file, fast, instead of blocking
forever (a FIFO in place of a chunk, a ``zarr.json``, a ``.hevr``, a ``.hevrsums`` or a volume
input; also a folder or a socket); a zstd chunk that does not parse says what is wrong; the
full check (:func:`hevr.store.verify.verify_bricks`) names every damaged brick.

Every call that could block runs in a thread bounded by :func:`_bounded`: a regression fails
(after opening the FIFO's other end, so the blocked thread returns) instead of hanging the suite.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import threading
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.rendering.pipeline.sums import load_sums, recolour
from hevr.store.verify import verify_bricks
from hevr.volume.loaders import read_scan, save_volume

pytestmark = [pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning"), pytest.mark.timeout(120)]

SHAPE, BRICK = (5, 7, 9), (2, 3, 4)  # 3 x 3 x 3 bricks


def _unblock(path: Path) -> None:
    """Open the write end of the FIFO ``path`` (and close it): a reader blocked opening it returns."""
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
    except OSError:
        pass


def _bounded(fn, fifo: Path | None = None, timeout: float = 20.0):
    """``fn()`` in a thread; its exception is re-raised here. Still running after ``timeout`` s:
    the test fails (once the FIFO's other end has let the thread go)."""
    box: dict = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout)
    if t.is_alive():
        for _ in range(50):
            if fifo is not None:
                _unblock(fifo)
            t.join(0.1)
            if not t.is_alive():
                break
        pytest.fail(f"blocked for more than {timeout:g} s on a non-regular file")
    if "error" in box:
        raise box["error"]
    return box.get("value")


def _replace(path: Path, kind: str) -> Path:
    """Put a FIFO, a folder or a Unix socket where the file ``path`` was; return ``path``."""
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    else:
        cwd = os.getcwd()  # a socket's name is limited to ~107 bytes: bind relative to its folder
        os.chdir(path.parent)
        try:
            s = socket.socket(socket.AF_UNIX)
            s.bind(path.name)
            s.close()
        finally:
            os.chdir(cwd)
    return path


@pytest.fixture()
def store(tmp_path, keypair256):
    vol = np.random.default_rng(5).integers(0, 256, SHAPE).astype(np.uint8)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[0], brick=BRICK, vector_dims=3, progress=False)
    return Path(ev.path)


# -- stores ------------------------------------------------------------------------------------
DOCUMENTS = ["zarr.json", "scalar/zarr.json", "vector/zarr.json", "done/zarr.json"]
CHUNKS = {
    "scalar/c/0/1/1/0": ("scalar", (0, 1, 1)),
    "vector/c/0/2/0/1/0": ("vector", (2, 0, 1)),
    "done/c/1/2/0/0/0": ("scalar", (1, 2, 0)),
}


@pytest.mark.parametrize("kind", ["fifo", "folder", "socket"])
@pytest.mark.parametrize("rel", DOCUMENTS)
def test_a_metadata_document_that_is_not_a_file_is_a_corrupt_store(store, rel, kind):
    f = _replace(store / rel, kind)
    with pytest.raises(
        hevr.CorruptStoreError,
        match=rf"expected the metadata document {rel} \(a regular file\), "
        rf"got a {'FIFO' if kind == 'fifo' else kind}",
    ):
        _bounded(lambda: hevr.open_volume(store), f)


@pytest.mark.parametrize("kind", ["fifo", "folder"])
@pytest.mark.parametrize("rel", list(CHUNKS))
def test_a_chunk_that_is_not_a_file_is_named_at_open_and_on_read(store, rel, kind):
    channel, brick = CHUNKS[rel]
    f = _replace(store / rel, kind)
    got = "a FIFO" if kind == "fifo" else "a folder"
    with pytest.raises(hevr.CorruptStoreError, match=rf"brick \({brick[0]}, {brick[1]}, {brick[2]}\).*{got}"):
        _bounded(lambda: hevr.open_volume(store), f)  # the quick check
    ev = hevr.open_volume(store, verify="none")
    with pytest.raises(
        hevr.CorruptStoreError,
        match=rf"brick \({brick[0]}, {brick[1]}, {brick[2]}\) of channel "
        rf"'{channel}'.*{got} at {re.escape(str(f))}",
    ):
        _bounded(lambda: ev.read_brick(brick, channel), f)
    with pytest.raises(hevr.CorruptStoreError, match=rf"brick \({brick[0]}, {brick[1]}, {brick[2]}\)"):
        _bounded(lambda: hevr.open_volume(store, verify="full"), f)


@pytest.mark.parametrize("rel", ["levels/1/scalar/zarr.json", "levels/1/vector/c/0/1/0/1/0"])
def test_a_pyramid_level_file_that_is_a_fifo_is_named(store, rel):
    hevr.build_pyramid(hevr.open_volume(store), 1, progress=False)
    f = _replace(store / rel, "fifo")
    with pytest.raises(hevr.CorruptStoreError, match=rf"got a FIFO at {re.escape(str(f))}"):
        _bounded(lambda: hevr.open_volume(store), f)


def test_render_and_persist_with_a_fifo_chunk_fail_fast(store, cluster):
    ev = hevr.open_volume(store)
    cam = hevr.Camera.orbit(ev, azimuth=20, elevation=10, width=8, height=6)
    f = _replace(store / "scalar/c/1/1/1/0", "fifo")
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 1, 1\) of channel 'scalar'.*FIFO"):
        _bounded(lambda: hevr.render(ev, cam, progress=False, cache=False), f)
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 1, 1\).*FIFO"):
        _bounded(lambda: hevr.render(ev, cam, progress=False, cache=False, client=cluster), f)
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 1, 1\).*FIFO"):
        _bounded(lambda: ev.persist("scalar"), f)


# -- images and sums ---------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["fifo", "folder", "socket"])
def test_load_image_refuses_what_is_not_a_file(tmp_path, kind):
    f = _replace(tmp_path / "frame.hevr", kind)
    with pytest.raises(hevr.NotRegularFileError, match=r"path: expected an encrypted image file \(a regular file\)"):
        _bounded(lambda: hevr.load_image(f), f)


@pytest.mark.parametrize("kind", ["fifo", "socket"])
def test_load_sums_and_recolour_refuse_what_is_not_a_file(tmp_path, kind):
    f = _replace(tmp_path / "view.hevrsums", kind)
    with pytest.raises(hevr.NotRegularFileError, match=r"sums: expected a ray-sums file .*\(a regular file\)"):
        _bounded(lambda: load_sums(f), f)
    with pytest.raises(OSError, match="a regular file"):
        _bounded(lambda: recolour(f, mode="xray", progress=False), f)


# -- volume inputs -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name", ["a.npy", "b_4x4x4_uint8.raw", "c.nrrd", "d.nhdr", "e.nii", "f.nii.gz", "g.mgz", "h.tif", "i.dcm"]
)
def test_a_volume_input_that_is_a_fifo_is_refused(tmp_path, name):
    f = _replace(tmp_path / name, "fifo")
    with pytest.raises(hevr.NotRegularFileError, match=r"expected a volume file \(a regular file\), got a FIFO"):
        _bounded(lambda: read_scan(f), f)


def test_an_nrrd_data_file_that_is_a_fifo_is_refused(tmp_path):
    header = save_volume(tmp_path / "v.nhdr", np.zeros((4, 5, 6), np.int16))
    f = _replace(tmp_path / "v.raw", "fifo")
    with pytest.raises(hevr.NotRegularFileError, match="got a FIFO at .*v.raw"):
        _bounded(lambda: read_scan(header), f)


def test_a_fifo_in_a_dicom_folder_is_skipped(tmp_path):
    folder = tmp_path / "dicom"
    folder.mkdir()
    f = _replace(folder / "IM0001", "fifo")  # no suffix: the folder scan would open it to look
    with pytest.raises(hevr.VolumeFormatError, match="no DICOM file"):
        _bounded(lambda: read_scan(folder), f)


def test_a_fifo_chunk_in_a_zarr_input_is_refused(tmp_path):
    import zarr

    z = tmp_path / "in.zarr"
    zarr.create_array(z, shape=(4, 4, 4), chunks=(2, 2, 2), dtype="int16")[:] = 1
    f = _replace(z / "c/1/0/1", "fifo")
    with pytest.raises(
        hevr.VolumeFormatError, match=r"a file of the Zarr input in.zarr \(a regular file\), got a FIFO"
    ):
        _bounded(lambda: read_scan(z), f)


# -- a zstd chunk that does not parse ----------------------------------------------------------
@pytest.mark.parametrize(
    "damage, words",
    [
        (lambda b: b"\0\0\0\0" + b[4:], "does not start with the zstd magic number"),
        (lambda b: b[:8], r"a block header was due at byte 7, but the file has 8 bytes \(truncated\)"),
        (lambda b: b[:7] + bytes([b[7] | 0b110]) + b[8:], "the block header at byte 7 has the reserved block type 3"),
        (lambda b: b[:3], "too few for a zstd frame header"),
    ],
    ids=["magic", "cut-in-a-block-header", "reserved-block-type", "cut-in-the-frame-header"],
)
def test_a_zstd_chunk_that_does_not_parse_says_what_is_wrong(store, damage, words):
    """Not "expected 3 bytes" (the frame length -1 plus the crc): the chunk, and why. The chunk
    is one raw zstd block behind a 7-byte frame header (single segment, 2-byte content size)."""
    f = store / "scalar/c/0/1/1/0"
    f.write_bytes(damage(f.read_bytes()))
    with pytest.raises(hevr.CorruptStoreError) as info:
        hevr.open_volume(store)
    text = str(info.value)
    assert "expected 3 bytes" not in text
    assert (
        "chunk scalar/c/0/1/1/0 of brick (0, 1, 1) in channel 'scalar' is damaged (not a complete zstd frame: " in text
    )
    assert re.search(words, text), text


# -- the full check ----------------------------------------------------------------------------
def _flip(f: Path, at: float = 0.5) -> None:
    b = bytearray(f.read_bytes())
    b[int(len(b) * at)] ^= 0x10
    f.write_bytes(bytes(b))


@pytest.mark.parametrize("on_cluster", [False, True])
def test_verify_bricks_names_every_damaged_brick(store, cluster, on_cluster):
    ev = hevr.open_volume(store)
    assert verify_bricks(ev).ok and verify_bricks(ev).bricks == 27
    _flip(store / "scalar/c/2/0/1/0")
    _flip(store / "vector/c/0/0/2/2/0")
    hevr.open_volume(store)  # the quick check reads no ciphertext: it passes
    report = verify_bricks(ev, client=cluster if on_cluster else None)
    assert not report.ok and report.bricks == 27
    assert sorted(report.damaged) == [(0, (0, 2, 2)), (0, (2, 0, 1))]
    assert {(p.index, p.channel) for p in report.problems} == {((2, 0, 1), "scalar"), ((0, 2, 2), "vector")}
    assert all(str(p).startswith(f"brick {p.index} of channel '{p.channel}'") for p in report.problems)
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(0, 2, 2\) of channel 'vector'"):
        ev.verify()  # the first damaged brick, in raster order


def test_overwriting_or_resuming_a_store_whose_zarr_json_is_a_fifo_does_not_block(store, keypair256):
    """The writer reads the old store's documents too (is it an hevr store? is it complete?)."""
    fifo = _replace(store / "zarr.json", "fifo")
    vol = np.zeros(SHAPE, np.uint8)
    for kw in ({"overwrite": True}, {"resume": True}):
        with pytest.raises(hevr.HevrError):
            _bounded(lambda: hevr.encrypt_volume(vol, store, keypair256[0], brick=BRICK, progress=False, **kw), fifo)  # noqa: B023 - _bounded calls it at once
    assert fifo.is_fifo()  # refused, not replaced: it is no hevr store


def test_a_fifo_journal_does_not_block_a_resume(tmp_path, keypair256, monkeypatch):
    from hevr.store import journal

    monkeypatch.setattr(journal, "journal_path", lambda store_id: tmp_path / "journal.json")
    os.mkfifo(tmp_path / "journal.json")
    with pytest.raises(hevr.ParameterError):
        _bounded(lambda: journal.check_journal("abc", "v.zarr", "f" * 64, {}), tmp_path / "journal.json")


def test_resuming_a_store_with_a_fifo_digest_marker_does_not_block(store, keypair256):
    vol = np.random.default_rng(5).integers(0, 256, SHAPE).astype(np.uint8)  # the fixture's volume
    fifo = _replace(store / "done/c/1/2/0/0/0", "fifo")
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 2, 0\).*got a FIFO"):
        _bounded(
            lambda: hevr.encrypt_volume(
                vol, store, keypair256[0], brick=BRICK, vector_dims=3, progress=False, resume=True
            ),
            fifo,
        )


# -- review: upgrade_store reads its source through the same checks ------------------------------
def test_upgrade_store_with_a_fifo_as_its_source_document_fails_fast(store, tmp_path):
    """(A FIFO chunk of a format-1 source: tests/store/test_upgrade.py.)"""
    f = _replace(store / "zarr.json", "fifo")
    with pytest.raises(hevr.CorruptStoreError, match=r"\(a regular file\), got a FIFO"):
        _bounded(lambda: hevr.upgrade_store(store, tmp_path / "new.zarr", progress=False), f)
    assert not (tmp_path / "new.zarr").exists()
