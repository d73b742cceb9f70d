"""Issue 38: a lying server against verified renders, under the *default* settings.

Each attack of the issue — edited metadata (spacing, exponent, digits, value range) with the checksum
recomputed, another store or an older version or a store without tags under a known name, frame
files swapped, edited or stripped, a streamed frame of a tampered store, a record whose level does
not fit — ends in a refusal before rendering or a VerificationError (IntegrityError) before any
pixel, in Python and on the command line; and honest renders of every kind still verify
(Hypothesis over views, modes, samplings, levels, slices and streaming). ``benchmarks/verify_attacks.py``
prints the whole table (every attack × verify=None / True / pinned / CLI)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import stat

import dask
import numpy as np
import pytest
import zarr
from _stores import edit_meta
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hevr
from hevr.cli.main import main
from hevr.image.header import MAGIC
from hevr.store.known import check_known, known_stores, trust_store

VOL = np.random.default_rng(5).integers(0, 256, (9, 8, 8)).astype(np.uint8)
NODES = [(0.3, "red"), (0.8, "blue")]


@pytest.fixture
def known(tmp_path, monkeypatch):
    """A key holder of its own: an empty known-stores file for this test."""
    path = tmp_path / "known" / "known_stores.json"
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(path))
    return path


def _encrypt(vol, path, priv, **kw):
    with dask.config.set(scheduler="sync"):
        return hevr.encrypt_volume(vol, path, priv, brick=4, vector_dims=3, progress=False, verifiable=True, **kw)


def _render(ev, cam=None, **kw):
    cam = cam or hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=10, height=9)
    with dask.config.set(scheduler="sync"):
        return hevr.render(ev, cam, progress=False, cache=False, **kw)


def _spacing(d):
    d["spacing"] = [2 * s for s in d["spacing"]]


def _anisotropic(d):
    d["spacing"] = [d["spacing"][0], d["spacing"][1], 3 * d["spacing"][2]]


def _exponent(d):
    d["channels"]["scalar"]["exponent"] = -3


def _digits(d):
    for name in ("vector",):
        d["channels"][name]["digits"] += 1
        d["channels"][name]["exponent"] -= 1


def _value_range(d):
    d["value_range"] = [0.0, 25.5]


EDITS = [_spacing, _anisotropic, _exponent, _digits, _value_range]


@pytest.mark.parametrize("edit", EDITS, ids=lambda f: f.__name__.strip("_"))
def test_edited_metadata_is_refused_or_caught(edit, keypair256, tmp_path, known):
    """With the store recorded (the owner encrypted it here) the render is refused before it
    starts; on a machine that never saw the store, the owner's MAC catches it at decryption."""
    _, priv = keypair256
    ev = _encrypt(VOL, tmp_path / "v.zarr", priv)
    sid = ev.meta.store_id
    edit_meta(ev.path, edit)
    for verify in (None, True, sid):
        with pytest.raises(hevr.VerificationError, match="metadata"):
            _render(hevr.open_volume(ev.path), verify=verify)
    os.remove(known)  # a new machine: trust on first use, and the MAC
    mode = {"mode": "tf", "nodes": NODES} if edit is _digits else {}
    img = _render(hevr.open_volume(ev.path), **mode)
    assert img.verification is not None
    with pytest.raises(hevr.VerificationError, match="owner's MAC"):
        img.decrypt(priv)


def test_the_metadata_mac_is_required_on_a_verifiable_store(keypair256, tmp_path, known):
    _, priv = keypair256
    ev = _encrypt(VOL, tmp_path / "v.zarr", priv)
    assert ev.meta.auth.startswith("hmac-sha256:")
    edit_meta(ev.path, lambda d: d.pop("auth"))
    with pytest.raises(hevr.CorruptStoreError, match="auth: expected the owner's MAC"):
        hevr.open_volume(ev.path)


def test_another_store_an_older_version_or_a_store_without_tags_under_a_known_name(keypair256, tmp_path, known):
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    first = _encrypt(VOL, path, priv)
    _render(first).decrypt(priv)
    keep = tmp_path / "old.zarr"
    shutil.copytree(path, keep)
    second = _encrypt(255 - VOL, path, priv, overwrite=True)  # the owner re-encrypts: recorded again
    _render(second).decrypt(priv)
    shutil.rmtree(path)
    shutil.copytree(keep, path)  # the server serves the older version
    for verify in (None, True):
        with pytest.raises(hevr.VerificationError, match="another store, or another version"):
            _render(hevr.open_volume(path), verify=verify)
    with pytest.raises(hevr.VerificationError, match=f"expected the store {second.meta.store_id}"):
        _render(hevr.open_volume(path), verify=second.meta.store_id)
    other = _encrypt(VOL, tmp_path / "other.zarr", priv)  # another verifiable store of the key
    shutil.rmtree(path)
    shutil.copytree(other.path, path)
    with pytest.raises(hevr.VerificationError, match="another store"):
        _render(hevr.open_volume(path))
    with dask.config.set(scheduler="sync"):  # a store without tags, encrypted with the public key
        plain = hevr.encrypt_volume(VOL, tmp_path / "plain.zarr", pub, brick=4, vector_dims=3, progress=False)
    shutil.rmtree(path)
    shutil.copytree(plain.path, path)
    with pytest.raises(hevr.VerificationError):
        _render(hevr.open_volume(path))
    trust_store(hevr.open_volume(path), priv, untagged=True)  # accepted explicitly: renders, unverified, warned
    assert _render(hevr.open_volume(path)).verification is None
    assert _render(hevr.open_volume(path), verify=False).verification is None


def test_stripped_tags_under_a_known_name_are_named(keypair256, tmp_path, known):
    _, priv = keypair256
    ev = _encrypt(VOL, tmp_path / "v.zarr", priv)
    entry = known_stores()[str(ev.path)]
    assert entry.verifiable and entry.store_id == ev.meta.store_id
    stripped = dataclasses.replace(ev.meta, tags=False, auth="")
    fake = type("V", (), {"path": ev.path, "level": 0, "meta": stripped})()
    with pytest.raises(hevr.VerificationError, match="without tags: they were stripped"):
        check_known(fake)


def test_the_known_stores_file_is_private(keypair256, tmp_path, known):
    _, priv = keypair256
    _encrypt(VOL, tmp_path / "v.zarr", priv)
    assert stat.S_IMODE(known.stat().st_mode) == 0o600
    assert stat.S_IMODE(known.parent.stat().st_mode) == 0o700
    known.write_text("{not json")
    with pytest.raises(hevr.ParameterError, match="known stores: expected the key holder's known-stores file"):
        _render(hevr.open_volume(tmp_path / "v.zarr"))


def _frame_file(img, priv, path):
    img.save(path, private_key=priv)
    return path


def _rewrite_header(path, out, change):
    raw = path.read_bytes()
    m = len(MAGIC)
    hl = int.from_bytes(raw[m : m + 4], "little")
    head = json.loads(raw[m + 4 : m + 4 + hl])
    change(head)
    text = json.dumps(head, separators=(",", ":")).encode()
    body = raw[:m] + len(text).to_bytes(4, "little") + text + raw[m + 4 + hl : -32]
    out.write_bytes(body + hashlib.sha256(body).digest())
    return out


def test_frame_files_put_in_place_edited_or_stripped(keypair256, tmp_path, known):
    """Another camera's, another store's, a level-1 and an old (re-encrypted store's) verified
    frame put where the key holder saved its frame; the header and record exponent raised together;
    a record without the stamp: each refused by ``hevr.load_image(...).decrypt`` and ``hevr decrypt``
    (exit 1); a frame stripped of its record decrypts as "not verified" unless verification is
    required."""
    _, priv = keypair256
    key = tmp_path / "key.json"
    priv.save(key)
    ev = _encrypt(VOL, tmp_path / "v.zarr", priv)
    asked = tmp_path / "frame.hevr"
    _frame_file(_render(ev), priv, asked)
    np.testing.assert_array_equal(
        hevr.load_image(asked).decrypt(priv, require_verified=ev.meta.store_id), _render(ev).decrypt(priv)
    )
    with dask.config.set(scheduler="sync"):
        hevr.build_pyramid(ev, 1, progress=False)
    other = _encrypt(255 - VOL, tmp_path / "w.zarr", priv)
    gone = _encrypt(VOL, tmp_path / "r.zarr", priv)
    substitutes = {
        "camera": _render(ev, hevr.Camera.orbit(ev, azimuth=70, elevation=0, width=10, height=9)),
        "store": _render(other),
        "level": _render(hevr.open_volume(ev.path), level=1),
        "replay": _render(gone),
    }
    _encrypt(255 - VOL, tmp_path / "r.zarr", priv, overwrite=True)  # the owner replaced it
    want = hevr.Expect(store=ev.meta.store_id, view=hevr.proof_of(hevr.load_image(asked)).view_key)
    for name, img in substitutes.items():
        (tmp_path / name / "src").mkdir(parents=True)
        src = _frame_file(img, priv, tmp_path / name / "src" / "frame.hevr")  # the same file name, elsewhere
        shutil.copyfile(src, tmp_path / name / "frame.hevr")  # put in place of the key holder's frame
        moved = hevr.load_image(tmp_path / name / "frame.hevr")
        if name != "replay":  # by default: the image, and a warning saying what it proves, not "verified"
            with pytest.warns(hevr.FrameMovedWarning, match="not verified for .*saved this frame as"):
                moved.decrypt(priv)
            code = main(
                [
                    "decrypt",
                    str(tmp_path / name / "frame.hevr"),
                    "--key",
                    str(key),
                    "-q",
                    "--out",
                    str(tmp_path / name / "f.png"),
                ]
            )
            assert code == 0
        with pytest.raises(hevr.VerificationError, match="saved this verified frame as|which the owner replaced"):
            moved.decrypt(priv, require_verified=True)
        with pytest.raises(
            hevr.VerificationError, match="expected the view|expected a frame of the store|which the owner replaced"
        ):
            moved.decrypt(priv, require_verified=want)  # what the key holder asked for: not this frame
        for flags in (["--require-verified"], ["--expect-store", want.store, "--expect-view", want.view]):
            assert (
                main(
                    [
                        "decrypt",
                        str(tmp_path / name / "frame.hevr"),
                        "--key",
                        str(key),
                        "-q",
                        *flags,
                        "--out",
                        str(tmp_path / name / "g.png"),
                    ]
                )
                == 1
            )
    # the frame the key holder asked for, moved on purpose: what it proves is what is expected
    (tmp_path / "archive").mkdir()
    shutil.copyfile(asked, tmp_path / "archive" / "frame.hevr")
    np.testing.assert_array_equal(
        hevr.load_image(tmp_path / "archive" / "frame.hevr").decrypt(priv, require_verified=want),
        _render(ev).decrypt(priv),
    )
    with pytest.raises(hevr.VerificationError, match="which the owner replaced"):
        hevr.load_image(tmp_path / "replay" / "src" / "frame.hevr").decrypt(priv)  # where it was saved

    def raise_exponent(h):
        h["exponent"] -= 3
        h["verification"]["exponent"] -= 3

    (tmp_path / "edit").mkdir()
    for change, match in (
        (raise_exponent, "stamp that does not match"),
        (lambda h: [h.pop(k, None) for k in ("stamp", "saved_as", "rendered_at")], "carries no stamp"),
    ):
        bad = _rewrite_header(asked, tmp_path / "edit" / "frame.hevr", change)
        with pytest.raises(hevr.VerificationError, match=match):
            hevr.load_image(bad).decrypt(priv)
        assert main(["decrypt", str(bad), "--key", str(key), "--out", str(tmp_path / "x.png"), "-q"]) == 1
    bare = _rewrite_header(
        asked,
        tmp_path / "edit" / "frame.hevr",
        lambda h: [h.pop(k, None) for k in ("verification", "stamp", "saved_as", "rendered_at")],
    )
    assert hevr.load_image(bare).decrypt(priv).shape == (9, 10)  # not verified, and says so
    with pytest.raises(hevr.VerificationError, match="not verified"):
        hevr.load_image(bare).decrypt(priv, require_verified=True)
    assert (
        main(["decrypt", str(bare), "--key", str(key), "--out", str(tmp_path / "y.png"), "--require-verified", "-q"])
        == 1
    )


def test_a_record_whose_level_does_not_fit_is_an_integrity_error(keypair256, tmp_path, known):
    _, priv = keypair256
    ev = _encrypt(VOL, tmp_path / "v.zarr", priv)
    f = _frame_file(_render(ev), priv, tmp_path / "f.hevr")
    for change, field in (
        (lambda h: h["verification"].update(level=1), "level"),
        (lambda h: h["verification"].update(base_shape=[5, 4, 4]), "base_shape"),
        (lambda h: h["verification"].update(shape=[5, 4, 4]), "shape"),
    ):
        bad = _rewrite_header(f, tmp_path / "bad.hevr", change)
        with pytest.raises(hevr.IntegrityError, match=f"verification.{field}"):
            hevr.load_image(bad)


def test_streamed_frames_are_verified_when_they_settle(keypair256, tmp_path, known):
    """render_frame (the viewer's frames): an honest frame is verified; bricks swapped with their
    digests recomputed are caught before the frame is returned."""
    from hevr.store.digests import brick_digest, marker

    _, priv = keypair256
    ev = _encrypt(VOL, tmp_path / "v.zarr", priv)
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=10, height=9)
    with dask.config.set(scheduler="sync"):
        frame = hevr.render_frame(ev, cam, priv, "tf", "trilinear", nodes=NODES, progress=False, cache=False)
        assert frame.stats["verified"]
        np.testing.assert_allclose(
            frame.image, _render(ev, cam, mode="tf", sampling="trilinear", nodes=NODES).decrypt(priv)
        )
        group = zarr.open_group(str(ev.path), mode="r+")
        a, b = (0, 0, 0), (1, 0, 0)
        for ch in ("vector", "vector_tag"):  # data and tags moved together, digests recomputed
            da, db = ev.read_brick_bytes(a, ch), ev.read_brick_bytes(b, ch)
            group[ch][(slice(None),) + ev.brick_slices(a)] = db
            group[ch][(slice(None),) + ev.brick_slices(b)] = da
        for idx in (a, b):
            group["done"][idx] = marker(
                [
                    brick_digest(ev.meta.store_id, c, idx, ev.read_brick_bytes(idx, c, verify=False))
                    for c in ev.meta.channel_names
                ]
            )
        bad = hevr.open_volume(ev.path)
        unverified = hevr.render_frame(
            bad, cam, priv, "tf", "trilinear", nodes=NODES, progress=False, cache=False, verify=False
        )
        assert not unverified.stats["verified"]  # a plausible wrong frame without the check
        with pytest.raises(hevr.VerificationError):
            hevr.render_frame(bad, cam, priv, "tf", "trilinear", nodes=NODES, progress=False, cache=False)


@pytest.fixture(scope="module")
def honest(tmp_path_factory, keypair256):
    _, priv = keypair256
    folder = tmp_path_factory.mktemp("honest")
    ev = _encrypt(VOL, folder / "h.zarr", priv)
    with dask.config.set(scheduler="sync"):
        hevr.build_pyramid(ev, 1, progress=False)
    return hevr.open_volume(ev.path)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    azimuth=st.floats(0, 359),
    elevation=st.floats(-60, 60),
    kind=st.sampled_from(["xray", "tf", "slice", "stream", "level"]),
    sampling=st.sampled_from(["nearest", "trilinear"]),
)
def test_honest_renders_of_every_kind_verify(honest, keypair256, tmp_path, azimuth, elevation, kind, sampling):
    _, priv = keypair256
    ev = honest
    cam = hevr.Camera.orbit(ev, azimuth=azimuth, elevation=elevation, width=9, height=8)
    with dask.config.set(scheduler="sync"):
        if kind == "slice":
            plane = hevr.Plane.axial(ev, 4 + elevation / 60, width=9, height=8)
            img = hevr.render_slice(ev, plane, sampling=sampling, progress=False, cache=False)
        elif kind == "stream":
            frame = hevr.render_frame(ev, cam, priv, "tf", sampling, nodes=NODES, progress=False, cache=False)
            assert frame.stats["verified"]
            return
        else:
            mode = {"mode": "tf", "nodes": NODES} if kind == "tf" else {}
            img = _render(ev, cam, sampling=sampling, level=1 if kind == "level" else None, **mode)
    assert img.verification is not None
    img.save(tmp_path / "f.hevr", private_key=priv, overwrite=True)
    back = hevr.load_image(tmp_path / "f.hevr").decrypt_frame(priv, require_verified=ev.meta.store_id)
    np.testing.assert_array_equal(back.means, img.decrypt_frame(priv).means)


def test_the_command_line_refuses_another_store_until_trusted(keypair256, tmp_path, known, capsys):
    _, priv = keypair256
    key = tmp_path / "key.json"
    priv.save(key)
    path = tmp_path / "v.zarr"
    _encrypt(VOL, path, priv)
    other = _encrypt(255 - VOL, tmp_path / "o.zarr", priv)
    shutil.rmtree(path)
    shutil.copytree(other.path, path)
    argv = ["render", str(path), "--key", str(key), "--size", "8x8", "-q"]
    assert main(argv + ["--out", str(tmp_path / "a.hevr")]) == 1
    assert "another store, or another version of it, is under this name" in capsys.readouterr().err
    assert not (tmp_path / "a.hevr").exists()
    assert main(argv + ["--out", str(tmp_path / "b.hevr"), "--trust-store"]) == 0
    out = capsys.readouterr().out
    assert f"trusted: {path} is now recorded as the store {other.meta.store_id}" in out and "verified: the frame" in out
    assert main(["render", str(path), "--size", "8x8", "--trust-store", "--out", str(tmp_path / "c.hevr")]) == 2
