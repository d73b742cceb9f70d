"""What a verified frame proves (hevr.image.proof, issue 47): its store, view and render time bound
under the key holder's stamp, where it was saved; a frame put over another frame file does not
pass for it, and the caller says what it expects (hevr.Expect, hevr decrypt --expect-*)."""

from __future__ import annotations

import shutil
import time

import dask
import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.image import proof as proof_module

VOL = np.random.default_rng(9).integers(0, 256, (8, 8, 8)).astype(np.uint8)


@pytest.fixture
def store(policy_keypair256, tmp_path, monkeypatch):
    monkeypatch.setenv("HEVR_KNOWN_STORES", str(tmp_path / "known" / "known_stores.json"))
    _, priv = policy_keypair256
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(VOL, tmp_path / "v.zarr", priv, brick=4, progress=False)
    return ev, priv


def _render(ev, azimuth=30):
    with dask.config.set(scheduler="sync"):
        return hevr.render(
            ev, hevr.Camera.orbit(ev, azimuth=azimuth, elevation=20, width=8, height=7), progress=False, cache=False
        )


def test_expect_is_validated():
    assert hevr.Expect(store="0123456789abcdef", view="fedcba9876543210", max_age=60).max_age == 60.0
    for kw, name in (
        ({"store": "nope"}, "store"),
        ({"view": 3}, "view"),
        ({"max_age": -1}, "max_age"),
        ({"max_age": float("nan")}, "max_age"),
        ({"moved": "yes"}, "moved"),
    ):
        with pytest.raises(hevr.ParameterError, match=f"^{name}: expected"):
            hevr.Expect(**kw)
    with pytest.raises(
        hevr.ParameterError, match="require_verified: expected True, False, a store id or a hevr.Expect"
    ):
        proof_module.as_expect(3)


def test_proof_of_a_frame_in_memory_and_in_its_file(store, tmp_path):
    ev, priv = store
    img = _render(ev)
    p = hevr.proof_of(img)
    assert p.store_id == ev.meta.store_id and p.store_version.startswith("sha256:") and len(p.view_key) == 16
    assert p.rendered_at and not p.moved and p.saved_as is None
    assert hevr.proof_of(_render(ev, azimuth=31)).view_key != p.view_key  # another camera, another view
    img.save(tmp_path / "f.hevr", private_key=priv)
    back = hevr.proof_of(hevr.load_image(tmp_path / "f.hevr"))
    assert (back.store_id, back.view_key, back.rendered_at) == (p.store_id, p.view_key, p.rendered_at)
    assert back.saved_as == str((tmp_path / "f.hevr").resolve()) == back.read_as and not back.moved
    assert hevr.proof_of(_render(ev).__class__(**{**img.__dict__, "verification": None})) is None


def test_another_patients_frame_copied_over_this_one(store, policy_keypair256, tmp_path):
    """The tester's attack: another store's stamped frame.hevr copied into this patient's folder,
    and another camera's frame of the same store: neither passes for what was asked."""
    ev, priv = store
    with dask.config.set(scheduler="sync"):
        other = hevr.encrypt_volume(255 - VOL, tmp_path / "w.zarr", priv, brick=4, progress=False)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "c").mkdir()
    mine = tmp_path / "a" / "frame.hevr"
    _render(ev).save(mine, private_key=priv)
    asked = hevr.Expect(store=ev.meta.store_id, view=hevr.proof_of(hevr.load_image(mine)).view_key)
    _render(other).save(tmp_path / "b" / "frame.hevr", private_key=priv)
    _render(ev, azimuth=80).save(tmp_path / "c" / "frame.hevr", private_key=priv)
    for src, why in (("b", "expected a frame of the store"), ("c", "expected the view")):
        shutil.copyfile(tmp_path / src / "frame.hevr", mine)
        img = hevr.load_image(mine)
        with pytest.raises(hevr.VerificationError, match="saved this verified frame as"):
            img.decrypt(priv, require_verified=True)
        with pytest.raises(hevr.VerificationError, match="saved this verified frame as"):
            img.decrypt(priv, require_verified=ev.meta.store_id if src == "c" else True)  # the store id is not enough
        with pytest.raises(hevr.VerificationError, match=why):
            img.decrypt(priv, require_verified=asked)
        with pytest.warns(hevr.FrameMovedWarning):
            img.decrypt(priv)  # the image, said to be not verified for this file


def test_max_age(store, tmp_path, monkeypatch):
    ev, priv = store
    _render(ev).save(tmp_path / "f.hevr", private_key=priv)
    img = hevr.load_image(tmp_path / "f.hevr")
    assert img.decrypt(priv, require_verified=hevr.Expect(max_age=3600)).shape == (7, 8)
    now = time.time()
    later = now + 7200
    monkeypatch.setattr(proof_module.time, "time", lambda: later)
    with pytest.raises(hevr.VerificationError, match="rendered at most 3600 s ago, got one rendered 7"):
        img.decrypt(priv, require_verified=hevr.Expect(max_age=3600))
    earlier = now - 7200  # this machine's clock behind the stamp: a render time in the future
    monkeypatch.setattr(proof_module.time, "time", lambda: earlier)
    with pytest.raises(hevr.VerificationError, match="stamped 7.* s in the future"):
        img.decrypt(priv, require_verified=hevr.Expect(max_age=3600))


def test_the_command_line_states_what_it_expects(store, tmp_path, capsys):
    ev, priv = store
    key = tmp_path / "key.json"
    priv.save(key)
    frame = tmp_path / "f.hevr"
    assert main(["render", str(ev.path), "--key", str(key), "--size", "8x7", "--out", str(frame)]) == 0
    out = capsys.readouterr().out
    view = out.split("view key ")[1][:16]
    assert view == hevr.proof_of(hevr.load_image(frame)).view_key
    (tmp_path / "elsewhere").mkdir()
    moved = tmp_path / "elsewhere" / "f.hevr"
    shutil.copyfile(frame, moved)

    def decrypt(path, *flags):
        code = main(["decrypt", str(path), "--key", str(key), "--out", str(tmp_path / "o.png"), "--force", *flags])
        return code, capsys.readouterr()

    code, (out, _) = decrypt(moved)
    assert code == 0 and "NOT verified for" in out
    assert decrypt(moved, "--require-verified")[0] == 1
    assert decrypt(moved, "--expect-store", ev.meta.store_id)[0] == 1  # the store alone: a moved frame is refused
    code, (out, _) = decrypt(moved, "--expect-store", ev.meta.store_id, "--expect-view", view)
    assert code == 0 and "verified: the frame" in out and "proof:" in out
    assert decrypt(moved, "--expect-store", ev.meta.store_id, "--expect-view", "0" * 16)[0] == 1
    assert decrypt(moved, "--moved")[0] == 0
    assert decrypt(frame, "--max-age", "1h")[0] == 0
    code, (_, err) = decrypt(frame, "--max-age", "soon")
    assert code == 2 and "--max-age" in err
    code, (_, err) = decrypt(frame, "--unverified", "--require-verified")
    assert code == 2 and "--unverified" in err
