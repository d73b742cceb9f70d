"""Fault injection: every corruption of a store or an image ends in a HevrError, never in a
plausible wrong image and never in another exception type.

On a small multi-brick store (256-bit key, scalar + 3-vector channel, 3 × 2 × 2 bricks,
ragged edges) one bit is flipped at positions spread over every chunk file (ciphertexts,
edge padding, crc32c), every digest marker and every metadata document; after each flip
an X-ray render (scalar channel) and an emphasis render (vector channel) run end to end
(open, map, merge, finish, decrypt). Each must either raise a HevrError or give exactly
the clean image (it did not read the flipped byte), and at least one of them must raise.
Then whole-brick faults: swapped bricks, a brick copied from another store of the same
key. The counts are logged by the tests (pytest -s shows them) and asserted.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

import hevr

log = logging.getLogger(__name__)

SHAPE, BRICK = (5, 6, 7), (2, 3, 4)  # grid (3, 2, 2), ragged along every axis


@pytest.fixture(scope="module")
def clean(tmp_path_factory, keypair256):
    pub, priv = keypair256
    vol = np.random.default_rng(17).integers(0, 256, SHAPE).astype(np.uint8)
    root = tmp_path_factory.mktemp("faults")
    ev = hevr.encrypt_volume(vol, root / "v.zarr", pub, brick=BRICK, vector_dims=3, progress=False)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=6, height=6)
    ref = {mode: _render(Path(ev.path), cam, mode, priv) for mode in ("xray", "emphasize")}
    return Path(ev.path), cam, priv, ref, vol


def _render(path: Path, cam, mode: str, priv) -> np.ndarray:
    ev = hevr.open_volume(path)
    kw = {"density": 0.5} if mode == "emphasize" else {}
    return hevr.render(ev, cam, mode=mode, cache=False, progress=False, **kw).decrypt(priv)


def _outcomes(path: Path, cam, priv, ref) -> list[bool]:
    """Per mode: True if the render raised a HevrError; False if it gave exactly the clean
    image. Anything else (another exception, a different image) fails the test."""
    out = []
    for mode in ("xray", "emphasize"):
        try:
            img = _render(path, cam, mode, priv)
        except hevr.HevrError:
            out.append(True)
            continue
        assert np.array_equal(img, ref[mode]), f"a wrong image after a fault ({mode})"
        out.append(False)
    return out


@contextlib.contextmanager
def _flipped(f: Path, pos: int):
    """One bit of ``f`` flipped (bit pos % 8 of byte pos) while the block runs, then restored."""
    blob = f.read_bytes()
    damaged = bytearray(blob)
    damaged[pos] ^= 1 << (pos % 8)
    f.write_bytes(bytes(damaged))
    try:
        yield
    finally:
        f.write_bytes(blob)


def _positions(size: int, width: int) -> list[int]:
    """First byte, inside the first record, the middle, near the end (edge padding in edge
    bricks), and the crc32c trailer."""
    return sorted({0, min(width - 1, size - 1), size // 2, max(size - 9, 0), size - 1})


def test_one_bit_flips_in_every_chunk_and_marker_are_all_detected(clean):
    path, cam, priv, ref, _ = clean
    width = hevr.open_volume(path).meta.ciphertext_bytes
    files = sorted(f for name in ("scalar", "vector", "done") for f in (path / name / "c").rglob("*") if f.is_file())
    assert len(files) == 3 * 12
    injected = detected = 0
    for f in files:
        for pos in _positions(f.stat().st_size, width):
            with _flipped(f, pos):
                outcome = _outcomes(path, cam, priv, ref)
            injected += 1
            detected += any(outcome)
    log.warning("chunk faults: %d injected, %d detected", injected, detected)
    assert injected >= 150 and detected == injected


@pytest.mark.parametrize("doc", ["zarr.json", "scalar/zarr.json", "vector/zarr.json", "done/zarr.json"])
def test_one_bit_flips_in_the_metadata_are_all_detected(clean, doc):
    path, cam, priv, ref, _ = clean
    f = path / doc
    size = f.stat().st_size
    injected = detected = 0
    for pos in range(0, size, 7 if doc == "zarr.json" else 11):
        with _flipped(f, pos):
            outcome = _outcomes(path, cam, priv, ref)
        injected += 1
        detected += all(outcome)  # metadata is read by every render
    log.warning("metadata faults in %s: %d injected, %d detected", doc, injected, detected)
    assert injected >= 45 and detected == injected


def _swap(a: Path, b: Path) -> None:
    tmp = a.with_name(a.name + ".swap")
    a.rename(tmp)
    b.rename(a)
    tmp.rename(b)


def _chunk(path: Path, name: str, idx: tuple[int, int, int]) -> Path:
    lead = "0/" if name == "vector" else ""
    tail = "/0/0" if name == "done" else "/0"
    return path / name / "c" / (lead + "/".join(map(str, idx)) + tail)


@pytest.mark.parametrize("names", [("scalar",), ("scalar", "done"), ("vector", "done"), ("scalar", "vector", "done")])
def test_swapped_bricks_are_detected(clean, names):
    """Two interior bricks of the same size swapped, with or without their digest markers."""
    path, cam, priv, ref, _ = clean
    a, b = (0, 0, 0), (1, 1, 0)
    for name in names:
        _swap(_chunk(path, name, a), _chunk(path, name, b))
    try:
        outcome = _outcomes(path, cam, priv, ref)
    finally:
        for name in names:
            _swap(_chunk(path, name, a), _chunk(path, name, b))
    done = "done" in names  # a marker holds the digests of both channels
    assert outcome == ["scalar" in names or done, "vector" in names or done]


def test_a_brick_from_another_store_of_the_same_key_is_detected(clean, tmp_path, keypair256):
    """Even the same volume, encrypted again under the same key: chunk and marker copied."""
    path, cam, priv, ref, vol = clean
    other = hevr.encrypt_volume(vol, tmp_path / "other.zarr", keypair256[0], brick=BRICK, vector_dims=3, progress=False)
    copy = tmp_path / "copy.zarr"
    shutil.copytree(path, copy)
    for name in ("scalar", "vector", "done"):
        shutil.copyfile(_chunk(Path(other.path), name, (2, 1, 1)), _chunk(copy, name, (2, 1, 1)))
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(2, 1, 1\) of channel 'scalar': digest mismatch"):
        _render(copy, cam, "xray", priv)
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(2, 1, 1\) of channel 'vector': digest mismatch"):
        _render(copy, cam, "emphasize", priv)
    assert np.array_equal(_render(Path(other.path), cam, "xray", priv), ref["xray"])  # the donor itself is fine


def test_a_truncated_or_missing_chunk_is_detected_without_quick_verify(clean, tmp_path):
    path, cam, priv, ref, _ = clean
    copy = tmp_path / "copy.zarr"
    shutil.copytree(path, copy)
    f = _chunk(copy, "scalar", (1, 0, 1))
    f.write_bytes(f.read_bytes()[:-100])
    ev = hevr.open_volume(copy, verify="none")
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 0, 1\)"):
        hevr.render(ev, cam, cache=False, progress=False)
    f.unlink()
    with pytest.raises(hevr.CorruptStoreError, match=r"brick \(1, 0, 1\).*digest mismatch"):
        hevr.render(ev, cam, cache=False, progress=False)


# -- the image file -------------------------------------------------------------------------------

IMAGES = {
    "xray-packed": ("xray", True),
    "xray-unpacked": ("xray", False),
    "emphasize-packed": ("emphasize", True),
    "emphasize-unpacked": ("emphasize", False),
}


@pytest.mark.parametrize("name", list(IMAGES))
def test_one_bit_flips_in_an_image_file_are_all_detected(clean, tmp_path, name):
    """Scalar and vector renders, packed and unpacked: a bit flipped anywhere in the saved
    .hevr file (magic, header length, header, ciphertexts, checksum) is a HevrError on loading
    or decrypting, never an image."""
    path, cam, priv, ref, _ = clean
    mode, pack = IMAGES[name]
    kw = {"density": 0.5} if mode == "emphasize" else {}
    img = hevr.render(hevr.open_volume(path), cam, mode=mode, pack=pack, cache=False, progress=False, **kw)
    f = tmp_path / "frame.hevr"
    img.save(f)
    assert np.array_equal(hevr.load_image(f).decrypt(priv, **kw), ref[mode])  # the density is not in the file
    size = f.stat().st_size
    injected = 0
    for pos in sorted({*range(0, 64), *range(64, size, max(1, size // 120)), *range(size - 40, size)}):
        with _flipped(f, pos), pytest.raises((hevr.IntegrityError, hevr.CorruptStoreError)):
            hevr.load_image(f).decrypt(priv, **kw)
        injected += 1
    log.warning("image file faults (%s): %d injected, all detected", name, injected)
    assert injected >= 150


def test_impossible_work_is_refused_at_once(clean):
    """step=1e-9 (10^11 samples per ray) and a 16384² image: RenderPlanError before any
    allocation; the crafted image headers are in tests/test_image_integrity.py (each < 1 s)."""
    path, cam, _, _, vol = clean
    ev = hevr.open_volume(path)
    big = hevr.Camera.orbit(ev, width=16384, height=16384)
    for call in (
        lambda: hevr.render(ev, cam, step=1e-9, progress=False),
        lambda: hevr.render_plain(vol, cam, step=1e-9),
        lambda: hevr.render(ev, big, progress=False),
    ):
        with pytest.raises(hevr.RenderPlanError, match="step|width, height"):
            call()


@pytest.mark.slow
def test_every_bit_of_every_metadata_document(clean):
    """Exhaustive: each of the ~24 000 single-bit flips of the four metadata documents makes
    open_volume raise a HevrError (Zarr alone tolerates some of them, e.g. a misspelt key)."""
    path = clean[0]
    flips = 0
    for doc in ("zarr.json", "scalar/zarr.json", "vector/zarr.json", "done/zarr.json"):
        f = path / doc
        blob = f.read_bytes()
        for pos in range(len(blob)):
            for bit in range(8):
                damaged = bytearray(blob)
                damaged[pos] ^= 1 << bit
                f.write_bytes(bytes(damaged))
                with pytest.raises(hevr.HevrError):
                    hevr.open_volume(path, verify="none")
                flips += 1
        f.write_bytes(blob)
    log.warning("metadata sweep: %d flips, all detected", flips)
    assert flips > 20000
