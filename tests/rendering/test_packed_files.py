"""Packed frames as files (hevr.rendering.packed.files): PackedImage.save / hevr.load_image give the
same picture back, a verified frame keeps its proof only with the key holder's stamp, and every
damaged, hand-made, renamed or replaced file ends in an error, never in a plausible image."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import shutil
import struct

import numpy as np
import pytest

import hevr
from hevr.errors import CorruptStoreError, ExistingFileError, IntegrityError, VerificationError
from hevr.image.files import image_from_bytes
from hevr.rendering.packed import PackedImage
from hevr.rendering.packed import files as pf

SHAPE = (12, 9, 10)


@pytest.fixture(scope="module")
def volume():
    return np.random.default_rng(11).integers(0, 200, SHAPE).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("packed-files") / "v.zarr"
    return hevr.encrypt_volume(
        volume, path, keypair256[1], brick=4, spacing=(1.0, 0.9, 1.2), layout="packed", progress=False
    )


@pytest.fixture(scope="module")
def frames(store):
    cam = hevr.Camera.orbit(store, view="anterior", azimuth=20, width=13, height=11, parallel=True)
    verified = hevr.render(store, cam, sampling="trilinear", progress=False)
    plain = hevr.render(store, cam, sampling="trilinear", progress=False, verify=False)
    return cam, verified, plain


def parts(blob: bytes) -> tuple[dict, bytes]:
    (hl,) = struct.unpack_from("<I", blob, len(pf.MAGIC))
    return json.loads(blob[pf.HEAD : pf.HEAD + hl]), blob[pf.HEAD + hl : -32]


def rebuild(header: dict, body: bytes) -> bytes:
    """A file written by hand: any header and body, with a valid checksum."""
    head = json.dumps(header, separators=(",", ":")).encode()
    blob = pf.MAGIC + struct.pack("<I", len(head)) + head + body
    return blob + hashlib.sha256(blob).digest()


def rebuild_raw(head: bytes, body: bytes = b"") -> bytes:
    blob = pf.MAGIC + struct.pack("<I", len(head)) + head + body
    return blob + hashlib.sha256(blob).digest()


def test_unverified_round_trip(frames, keypair256, tmp_path, store, volume):
    cam, _, plain = frames
    priv = keypair256[1]
    path = tmp_path / "f.hevr"
    plain.save(path)
    img = hevr.load_image(path)
    assert isinstance(img, PackedImage) and img.verification is None and not img.verified
    assert img.n_ciphertexts == plain.n_ciphertexts and img.shape == plain.shape == (11, 13)
    assert img.plan.sampling == "trilinear" and img.plan.classes == plain.plan.classes
    assert img.exponent == plain.exponent and img.offset == plain.offset and img.span == plain.span
    arr = img.decrypt(priv)
    assert np.array_equal(arr, plain.decrypt(priv))
    ref = hevr.render_plain(volume, cam, sampling="trilinear", spacing=store.spacing, slices=True)
    assert (np.abs(arr - ref) <= hevr.error_bound(store, cam, sampling="trilinear")).all()
    with pytest.raises(VerificationError, match="not verified"):
        img.decrypt(priv, require_verified=True)
    assert image_from_bytes(plain.to_bytes()).decrypt(priv).tolist() == arr.tolist()
    assert path.read_bytes().startswith(b"HEVRIMGP\x01")


def test_never_over_a_file_unasked(frames, tmp_path):
    _, _, plain = frames
    path = tmp_path / "f.hevr"
    path.write_bytes(b"the user's file")
    with pytest.raises(ExistingFileError):
        plain.save(path)
    assert path.read_bytes() == b"the user's file"
    plain.save(path, overwrite=True)
    assert isinstance(hevr.load_image(path), PackedImage)
    assert [p.name for p in tmp_path.iterdir()] == ["f.hevr"]  # no temporary left


def test_verified_frame_keeps_its_proof_with_the_stamp(frames, keypair256, tmp_path, caplog):
    _, verified, plain = frames
    priv = keypair256[1]
    want = plain.decrypt(priv)
    path = tmp_path / "v.hevr"
    verified.save(path, private_key=priv)
    img = hevr.load_image(path)
    assert img.verified and not img.verification.drawn_here and img.stamp is not None
    assert (
        img.verification.store_id == verified.verification.store_id
        and img.verification.seed == verified.verification.seed
    )
    assert np.array_equal(img.decrypt(priv, require_verified=verified.store_id), want)
    # a stamped file copied as it is keeps its stamp (saved again without the key, same name): it
    # proves its store and view, not that it belongs in the other folder
    other = tmp_path / "copy"
    other.mkdir()
    img.save(other / "v.hevr")
    moved = hevr.load_image(other / "v.hevr")
    with pytest.raises(VerificationError, match="saved this verified frame as .*v.hevr, and it was read from"):
        moved.decrypt(priv, require_verified=True)
    proof = hevr.proof_of(moved)
    assert proof.moved and proof.store_id == verified.store_id and proof.rendered_at
    expect = hevr.Expect(store=verified.store_id, view=proof.view_key)
    assert np.array_equal(moved.decrypt(priv, require_verified=expect), want)
    with pytest.raises(hevr.ParameterError, match="view: expected a view key"):  # a camera alone fixes too little
        hevr.Expect(store=verified.store_id, view=verified.camera)
    assert np.array_equal(moved.decrypt(priv, require_verified=hevr.Expect(moved=True)), want)
    # saved again with the key there: stamped for its new place, its render time kept
    moved.save(other / "w.hevr", private_key=priv)
    again = hevr.load_image(other / "w.hevr")
    assert np.array_equal(again.decrypt(priv, require_verified=True), want)
    assert hevr.proof_of(again).rendered_at == proof.rendered_at
    # without the key, a record drawn here is left out, with a warning
    with caplog.at_level(logging.WARNING, logger="hevr"):
        verified.save(tmp_path / "nokey.hevr")
    assert any("without private_key" in r.getMessage() for r in caplog.records)
    bare = hevr.load_image(tmp_path / "nokey.hevr")
    assert bare.verification is None and np.array_equal(bare.decrypt(priv), want)
    with pytest.raises(VerificationError, match="not verified"):
        bare.decrypt(priv, require_verified=True)


def test_renamed_or_forged_proof_is_refused(frames, keypair256, tmp_path):
    _, verified, _ = frames
    priv = keypair256[1]
    path = tmp_path / "a.hevr"
    verified.save(path, private_key=priv)
    shutil.copy(path, tmp_path / "b.hevr")  # another frame's place
    with pytest.raises(VerificationError, match="saved this verified frame as .*a.hevr, and it was read from .*b.hevr"):
        hevr.load_image(tmp_path / "b.hevr").decrypt(priv, require_verified=True)
    with pytest.warns(hevr.FrameMovedWarning, match="not verified for .*b.hevr"):
        hevr.load_image(tmp_path / "b.hevr").decrypt(priv)
    header, body = parts(path.read_bytes())
    # a record without a stamp: refused, even though it is genuine
    bare = {k: v for k, v in header.items() if k not in ("stamp", "saved_as", "rendered_at")}
    (tmp_path / "c.hevr").write_bytes(rebuild(bare, body))
    with pytest.raises(VerificationError, match="carries no stamp"):
        hevr.load_image(tmp_path / "c.hevr").decrypt(priv)
    # an altered aggregate under the old stamp: the stamp no longer matches
    forged = dict(
        header, verification=dict(header["verification"], aggregate=str(int(header["verification"]["aggregate"]) + 1))
    )
    (tmp_path / "a.hevr").write_bytes(rebuild(forged, body))
    with pytest.raises(VerificationError, match="does not match its bytes"):
        hevr.load_image(tmp_path / "a.hevr").decrypt(priv)
    # an altered ciphertext under the old stamp
    flipped = bytearray(body)
    flipped[5] ^= 1
    (tmp_path / "a.hevr").write_bytes(rebuild(header, bytes(flipped)))
    with pytest.raises(VerificationError, match="does not match its bytes"):
        hevr.load_image(tmp_path / "a.hevr").decrypt(priv)


def test_saving_with_the_key_checks_the_frame(frames, keypair256, tmp_path):
    """The key holder stamps only a frame that verifies: a record of another frame is refused."""
    _, verified, plain = frames
    priv = keypair256[1]
    other = dataclasses.replace(plain, verification=verified.verification)
    bad = dataclasses.replace(other, ciphertexts=[np.flipud(c).copy() for c in other.ciphertexts])
    with pytest.raises(hevr.IntegrityError):  # VerificationError (or a slot out of bounds): never stamped
        bad.save(tmp_path / "bad.hevr", private_key=priv)
    assert not (tmp_path / "bad.hevr").exists()


@pytest.mark.parametrize("where", ["magic-version", "length", "header", "body", "trailer"])
def test_flipped_or_truncated_file(frames, tmp_path, where):
    _, _, plain = frames
    blob = bytearray(plain.to_bytes())
    (hl,) = struct.unpack_from("<I", blob, len(pf.MAGIC))
    at = {
        "magic-version": len(pf.MAGIC) - 1,
        "length": len(pf.MAGIC),
        "header": pf.HEAD + 10,
        "body": pf.HEAD + hl + 3,
        "trailer": len(blob) - 1,
    }[where]
    blob[at] ^= 0x10
    (tmp_path / "f.hevr").write_bytes(bytes(blob))
    err = CorruptStoreError if where == "magic-version" else IntegrityError
    with pytest.raises(err):
        hevr.load_image(tmp_path / "f.hevr")
    for cut in (len(blob) - 1, len(blob) - 40, pf.HEAD + 3, 11):
        (tmp_path / "t.hevr").write_bytes(plain.to_bytes()[:cut])
        with pytest.raises(IntegrityError):
            hevr.load_image(tmp_path / "t.hevr")


def _edit(header: dict, **kw) -> dict:
    out = json.loads(json.dumps(header))
    for k, v in kw.items():
        if v is None:
            out.pop(k)
        else:
            out[k] = v
    return out


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(format="hevr-encrypted-image"), "'format'"),
        (dict(version=2), "'version'"),
        (dict(extra=1), "unexpected field"),
        (dict(counts=None), "'counts'"),
        (dict(sampling="cubic"), "'sampling'"),
        (dict(weight_bits=17), "'weight_bits'"),
        (dict(weight_bits=True), "'weight_bits'"),
        (dict(tile=0), "'tile'"),
        (dict(level=1), "'level'"),
        (dict(camera={"position": "x"}), "'camera'"),
        (dict(camera={"position": [0, 0, 30], "focal_point": [0, 0, 0], "parallel": False}), "perspective"),
        (
            dict(
                camera={
                    "position": [5, 30, 5],
                    "focal_point": [5, 4, 5],
                    "parallel": True,
                    "width": 100000,
                    "height": 100000,
                }
            ),
            "'camera'",
        ),
        (dict(stamp="hmac-sha256:" + "0" * 64), "'stamp'"),
        (dict(verification={"aggregate": "1", "seed": "zz" * 32}), "'verification.seed'"),
        (dict(verification={"aggregate": "0", "seed": "00" * 32}), "'verification.aggregate'"),
        (dict(verification={"aggregate": "1", "seed": "00" * 32, "level": 0}), "'verification'"),
    ],
)
def test_hand_made_fields(frames, tmp_path, change, match):
    """A file whose checksum is right but whose fields are not: IntegrityError naming the field."""
    _, _, plain = frames
    header, body = parts(plain.to_bytes())
    (tmp_path / "f.hevr").write_bytes(rebuild(_edit(header, **change), body))
    with pytest.raises(IntegrityError, match=match):
        hevr.load_image(tmp_path / "f.hevr")


def test_hand_made_counts_metadata_and_body(frames, tmp_path, keypair256):
    _, verified, plain = frames
    header, body = parts(plain.to_bytes())
    f = tmp_path / "f.hevr"
    counts = list(header["counts"])
    counts[0] += 1
    f.write_bytes(rebuild(_edit(header, counts=counts), body))
    with pytest.raises(IntegrityError, match=r"counts\[0\]"):
        hevr.load_image(f)
    f.write_bytes(rebuild(header, body[:-1]))
    with pytest.raises(IntegrityError, match="truncated"):
        hevr.load_image(f)
    f.write_bytes(rebuild(header, body + b"\0"))
    with pytest.raises(IntegrityError, match="too long"):
        hevr.load_image(f)
    meta = dict(header["metadata"], value_range=[0.0, 99.0])  # checksum of the metadata now wrong
    f.write_bytes(rebuild(_edit(header, metadata=meta), body))
    with pytest.raises(IntegrityError, match="'metadata'.*checksum"):
        hevr.load_image(f)
    f.write_bytes(rebuild(_edit(header, metadata={"format": "x"}), body))
    with pytest.raises(IntegrityError, match="'metadata'"):
        hevr.load_image(f)
    f.write_bytes(rebuild_raw(b"{" * 40))
    with pytest.raises(IntegrityError, match="JSON"):
        hevr.load_image(f)
    f.write_bytes(rebuild_raw(b'{"format":' + b"[" * 5000 + b"1" + b"]" * 5000 + b"}"))
    with pytest.raises(IntegrityError, match="nested too deeply"):  # never a RecursionError
        hevr.load_image(f)
    f.write_bytes(rebuild_raw(b'{"format":"a","format":"b"}'))
    with pytest.raises(IntegrityError, match="duplicate"):
        hevr.load_image(f)


def test_metadata_altered_and_restamped_is_refused(frames, keypair256, tmp_path):
    """A verified file whose metadata an attacker edits (and whose metadata checksum and file
    checksum are recomputed) fails the stamp; the owner's MAC is checked as well at decryption."""
    _, verified, _ = frames
    priv = keypair256[1]
    path = tmp_path / "v.hevr"
    verified.save(path, private_key=priv)
    header, body = parts(path.read_bytes())
    from hevr.store.metadata import metadata_checksum

    meta = dict(header["metadata"], value_range=[0.0, 300.0])
    meta.pop("checksum")
    meta["checksum"] = metadata_checksum(meta)
    path.write_bytes(rebuild(_edit(header, metadata=meta), body))
    img = hevr.load_image(path)  # the file is well-formed; its proof is not
    with pytest.raises(VerificationError):
        img.decrypt(priv)


def test_level_frame_round_trip(tmp_path, keypair256, volume):
    """A frame of a packed store's pyramid level: the file holds the store's metadata and the level;
    the reader plans on the level's metadata, and the record verifies against the level's tags."""
    priv = keypair256[1]
    ev = hevr.encrypt_volume(volume, tmp_path / "l.zarr", priv, brick=4, layout="packed", levels=1, progress=False)
    cam = hevr.Camera.orbit(ev, view="anterior", width=7, height=6, parallel=True)
    img = hevr.render(ev, cam, level=1, progress=False)
    assert img.level == 1 and img.verified
    want = img.decrypt(priv)
    img.save(tmp_path / "l.hevr", private_key=priv)
    back = hevr.load_image(tmp_path / "l.hevr")
    assert back.level == 1 and back.plan.geometry.shape == img.plan.geometry.shape != tuple(ev.shape)
    assert np.array_equal(back.decrypt(priv, require_verified=True), want)
    header, body = parts((tmp_path / "l.hevr").read_bytes())
    (tmp_path / "m.hevr").write_bytes(
        rebuild(_edit(header, level=0, stamp=None, saved_as=None, rendered_at=None), body)
    )
    with pytest.raises(IntegrityError, match="'counts|'camera"):  # level 0's plan: other tiles
        hevr.load_image(tmp_path / "m.hevr")
