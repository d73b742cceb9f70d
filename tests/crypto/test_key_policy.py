"""The key's policy (issue 47): every store of a key with ``require_tags`` carries tags, and a store
without them is refused on every machine — first contact included — before it is rendered where
the process knows the key, at the latest when the key holder decrypts: never an image."""

from __future__ import annotations

import dataclasses
import json
import pickle
import shutil
import warnings

import dask
import numpy as np
import pytest

import hevr
from hevr.cli.main import main

VOL = np.random.default_rng(47).integers(0, 256, (8, 8, 8)).astype(np.uint8)


@pytest.fixture
def known(tmp_path, monkeypatch):
    """A machine that never saw the store: an empty known-stores file of its own."""
    path = tmp_path / "known" / "known_stores.json"
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(path))
    return path


def _encrypt(path, key, **kw):
    with dask.config.set(scheduler="sync"):
        return hevr.encrypt_volume(VOL, path, key, brick=4, progress=False, **kw)


def _cam(ev):
    return hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=8, height=7)


def _render(ev, **kw):
    with dask.config.set(scheduler="sync"):
        return hevr.render(ev, _cam(ev), progress=False, cache=False, **kw)


def test_new_keys_carry_the_policy_in_their_file(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        pub, priv = hevr.generate_keypair(256)
        _, old = hevr.generate_keypair(256, require_tags=False)
        priv.save(tmp_path / "k.json")
        back = hevr.load_key(tmp_path / "k.json")
        assert priv.require_tags and back.require_tags and back == priv and not old.require_tags
        assert pickle.loads(pickle.dumps(priv)).require_tags  # a Dask task's copy keeps it
        doc = json.loads((tmp_path / "k.json").read_text())
        assert doc["policy"] == {"require_tags": True}
        del doc["policy"]  # a key file written before issue 47: no policy
        (tmp_path / "old.json").write_text(json.dumps(doc))
        assert not hevr.load_key(tmp_path / "old.json").require_tags
        doc["policy"] = {"require_tags": "yes"}
        (tmp_path / "bad.json").write_text(json.dumps(doc))
        with pytest.raises(hevr.InvalidKeyError, match="field 'policy': expected"):
            hevr.load_key(tmp_path / "bad.json")
    with pytest.raises(hevr.ParameterError, match="require_tags: expected True or False"):
        hevr.generate_keypair(256, require_tags=1)
    assert pub.to_dict().get("policy") is None  # the public key's file says nothing of it


def test_the_owner_writes_tags_unasked(policy_keypair256, tmp_path, known):
    pub, priv = policy_keypair256
    ev = _encrypt(tmp_path / "v.zarr", priv)  # a per-voxel store: with tags, unasked
    assert ev.meta.tags
    with pytest.raises(hevr.ParameterError, match=r"verifiable: expected True or None .*require_tags"):
        _encrypt(tmp_path / "n.zarr", priv, verifiable=False)
    assert not (tmp_path / "n.zarr").exists()
    assert not _encrypt(tmp_path / "p.zarr", pub).meta.tags  # the public key cannot make tags


def test_first_contact_with_a_relabelled_tagless_store(policy_keypair256, tmp_path, known, monkeypatch):
    """Anyone can make a tagless store from the public key and put it where the real one was: on a
    machine that never saw the store, no image comes out of it by default."""
    pub, priv = policy_keypair256
    real = tmp_path / "ct.zarr"
    _encrypt(real, priv)
    fake = _encrypt(tmp_path / "fake.zarr", pub)
    shutil.rmtree(real)
    shutil.copytree(fake.path, real)  # the server's answer under the real store's name
    monkeypatch.setenv(
        "HEVR_KNOWN_STORES", str(tmp_path / "fresh" / "known_stores.json")
    )  # a machine that never saw it
    ev = hevr.open_volume(real)
    assert not ev.meta.tags
    img = _render(ev)  # the render itself needs no key (the server's side): unverified
    assert img.verification is None
    with pytest.raises(hevr.VerificationError, match="policy .* without tags"):
        img.decrypt(priv)
    img.save(tmp_path / "f.hevr")
    with pytest.raises(hevr.VerificationError, match="policy"):
        hevr.load_image(tmp_path / "f.hevr").decrypt(priv)
    with pytest.raises(hevr.VerificationError, match="expected a store with tags"):  # before any work
        hevr.render_frame(ev, _cam(ev), priv)
    with pytest.raises(hevr.VerificationError, match="expected a store with tags"):
        hevr.Viewer(ev, priv)
    # the CLI, with exit codes: render with the key refused, decrypt of the file refused
    key = tmp_path / "key.json"
    priv.save(key)
    assert main(["render", str(real), "--key", str(key), "--size", "8x7", "-q", "--out", str(tmp_path / "c.hevr")]) == 1
    assert not (tmp_path / "c.hevr").exists()
    assert main(["decrypt", str(tmp_path / "f.hevr"), "--key", str(key), "--out", str(tmp_path / "f.png"), "-q"]) == 1
    assert not (tmp_path / "f.png").exists()
    # an unverified image asked for by name, or the store accepted explicitly by the key holder
    assert img.decrypt(priv, require_verified=False).shape == (7, 8)
    assert (
        main(
            [
                "decrypt",
                str(tmp_path / "f.hevr"),
                "--key",
                str(key),
                "--out",
                str(tmp_path / "f.png"),
                "-q",
                "--unverified",
            ]
        )
        == 0
    )
    with pytest.raises(hevr.VerificationError, match="untagged=True"):
        hevr.trust_store(ev, priv)  # the refusal's advice alone does not accept a store without tags
    hevr.trust_store(ev, priv, untagged=True)
    assert img.decrypt(priv).shape == (7, 8)
    assert hevr.render_frame(ev, _cam(ev), priv).image.shape == (7, 8)


def test_a_tagless_store_relabelled_with_a_known_id(policy_keypair256, tmp_path, known):
    """The server serves a tagless store under the id of a store the key holder knows as verifiable:
    a render with verify=False (which skips the known-stores check) still gives no image."""
    pub, priv = policy_keypair256
    real = _encrypt(tmp_path / "ct.zarr", priv)  # recorded here (the owner's machine), verifiable
    fake = _encrypt(tmp_path / "fake.zarr", pub)
    img = _render(fake, verify=False)
    relabelled = dataclasses.replace(img, info={**img.info, "store": real.meta.store_id})  # what its frame says
    assert relabelled.info["tags"] is False
    with pytest.raises(hevr.VerificationError, match="policy"):
        relabelled.decrypt(priv)
    assert _render(real, verify=False).decrypt(priv).shape == (7, 8)  # the real one: "not verified", an image


def test_unverified_frames_of_a_store_with_tags_still_decrypt(policy_keypair256, tmp_path, known):
    """The policy keeps a tagless store from passing for one; a frame rendered without the check
    (verify=False, or where the key is not) of a store with tags decrypts, and says so."""
    _, priv = policy_keypair256
    ev = _encrypt(tmp_path / "v.zarr", priv)
    arr = _render(ev, verify=False).decrypt(priv)
    np.testing.assert_array_equal(arr, _render(ev).decrypt(priv, require_verified=True))
    with pytest.raises(hevr.VerificationError, match="not verified"):
        _render(ev, verify=False).decrypt(priv, require_verified=True)


def test_a_key_without_the_policy_keeps_the_old_behaviour(keypair256, tmp_path, known):
    pub, priv = keypair256
    assert not priv.require_tags
    ev = _encrypt(tmp_path / "p.zarr", pub)
    assert _render(ev).decrypt(priv).shape == (7, 8)  # not verified, with a warning, as before issue 47


def test_key_policy_command(tmp_path, capsys):
    key = tmp_path / "k.json"
    assert main(["keygen", "--bits", "256", "--out", str(key), "-q"]) == 0
    assert hevr.load_key(key).require_tags
    assert main(["key-policy", str(key), "--no-require-tags"]) == 0
    assert not hevr.load_key(key).require_tags and (key.stat().st_mode & 0o777) == 0o600
    assert main(["key-policy", str(key), "--require-tags"]) == 0 and hevr.load_key(key).require_tags
    capsys.readouterr()
    assert main(["key-policy", str(key)]) == 0 and "every store of this key carries tags" in capsys.readouterr().out
    assert main(["convert-key", str(key), "--out", str(tmp_path / "p.json"), "-q"]) == 0
    code = main(["key-policy", str(tmp_path / "p.json"), "--require-tags"])  # pheutil: no room for it
    assert code == 2 and "hevr's format" in capsys.readouterr().err


def test_a_frame_file_saying_its_store_has_tags(policy_keypair256, tmp_path, known, monkeypatch):
    """An unverified frame file is anybody's to write: its header's word that the store carries
    tags (the SHA-256 trailer recomputed) does not make a tagless store's frame decrypt."""
    import hashlib

    from hevr.image.header import HEAD, LENGTH, MAGIC

    pub, priv = policy_keypair256
    img = _render(_encrypt(tmp_path / "p.zarr", pub))
    img.save(tmp_path / "f.hevr")
    raw = (tmp_path / "f.hevr").read_bytes()
    (hl,) = LENGTH.unpack_from(raw, len(MAGIC))
    header = json.loads(raw[HEAD : HEAD + hl])
    for info in ({**header["info"], "tags": True}, {k: v for k, v in header["info"].items() if k != "store"}):
        head = json.dumps(dict(header, info=info)).encode()
        body = MAGIC + LENGTH.pack(len(head)) + head + raw[HEAD + hl : -32]
        (tmp_path / "g.hevr").write_bytes(body + hashlib.sha256(body).digest())
        with pytest.raises(hevr.VerificationError, match="policy"):
            hevr.load_image(tmp_path / "g.hevr").decrypt(priv)
