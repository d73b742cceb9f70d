"""Packed stores on a real ``hevr serve``: the remote frame is the in-process one byte for byte,
verified by default with a seed drawn after the values arrived, and a server's lie (a changed,
missing or extra tile, a wrong aggregate) ends in an error, never a picture."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest

import hevr
from hevr.remote import connect
from hevr.remote.protocol import END


@pytest.fixture(scope="module")
def packed_served(tmp_path_factory, keypair256):
    from _serving import hevr_serve

    pub, priv = keypair256
    d = tmp_path_factory.mktemp("packed-served")
    vol = np.random.default_rng(3).integers(0, 256, (13, 9, 11)).astype(np.uint8)
    ev = hevr.encrypt_volume(
        vol, str(d / "p.zarr"), priv, brick=4, spacing=(1.0, 0.8, 1.3), layout="packed", levels=1, progress=False
    )
    assert ev.meta.tags
    with hevr_serve(str(d / "p.zarr"), "--workers", "1") as (url, proc, lines):
        yield types.SimpleNamespace(url=url, ev=ev, priv=priv, vol=vol, lines=lines)


@pytest.fixture(scope="module")
def rv(packed_served):
    server = connect(packed_served.url, timeout=120)
    yield server.open(packed_served.ev.meta.store_id)
    server.close()


def _cam(ev, az=60, el=10):
    return hevr.Camera.orbit(ev, azimuth=az, elevation=el, width=14, height=11, parallel=True)


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_remote_frame_is_the_in_process_frame(packed_served, rv, sampling, monkeypatch):
    from _serving import refuse_unpickling

    s = packed_served
    assert rv.packing == s.ev.packing and rv.meta == s.ev.meta
    attempts = refuse_unpickling(monkeypatch)
    remote = hevr.render(rv, _cam(rv), sampling=sampling, verify=False, tile=4, progress=False)
    monkeypatch.undo()
    assert not attempts and remote.stats["remote"] == s.url and not remote.verified
    local = hevr.render(s.ev, _cam(s.ev), sampling=sampling, verify=False, tile=4, progress=False)
    assert len(remote.ciphertexts) == len(local.ciphertexts) > 1
    assert all(np.array_equal(a, b) for a, b in zip(remote.ciphertexts, local.ciphertexts))
    arr = remote.decrypt(s.priv)
    np.testing.assert_array_equal(arr, local.decrypt(s.priv))
    ref = hevr.render_plain(s.vol, _cam(s.ev), sampling=sampling, spacing=(1.0, 0.8, 1.3), slices=True)
    assert (np.abs(arr - ref) <= hevr.error_bound(s.ev, _cam(s.ev), sampling=sampling)).all()


def test_verified_by_default(packed_served, rv):
    s = packed_served
    img = hevr.render(rv, _cam(rv, 120, -25), sampling="trilinear", progress=False)
    assert img.verified and img.verification.drawn_here and img.verification.store_id == s.ev.meta.store_id
    local = hevr.render(s.ev, _cam(s.ev, 120, -25), sampling="trilinear", verify=False, progress=False)
    np.testing.assert_array_equal(img.decrypt(s.priv, require_verified=s.ev.meta.store_id), local.decrypt(s.priv))
    with pytest.raises(hevr.VerificationError, match="another store"):
        hevr.render(rv, _cam(rv), progress=False, verify="0123456789abcdef")


def test_a_lying_server_is_caught(packed_served, rv, monkeypatch):
    """What the server sends is checked against the key holder's own plan, and its values against
    the tags: a changed tile, a missing or extra one, a tile of another view, a wrong aggregate."""
    s = packed_served
    honest_frames = rv.server.frames
    cam = _cam(rv, 250, 30)

    def lying(change):
        def frames(path, body, limit):
            got = list(honest_frames(path, body, limit))
            yield from change(got)

        return frames

    def swap_values(got):  # two different records of a tile swapped: well-formed ciphertexts
        w = s.ev.meta.ciphertext_bytes
        out = [list(x) for x in got]
        for item in out[:-1]:
            recs = np.frombuffer(item[1], np.uint8).reshape(-1, w).copy()
            distinct = np.unique(recs, axis=0, return_index=True)[1]
            if len(distinct) > 1:
                i, j = sorted(distinct[:2])
                recs[[i, j]] = recs[[j, i]]
                item[1] = recs.tobytes()
                return [tuple(x) for x in out]
        raise AssertionError("no tile with two different values")

    other = list(
        honest_frames(
            f"/v1/stores/{rv.store_id}/render",
            dict(
                hevr.remote.protocol.RenderRequest(
                    view=_cam(rv, 250, 31), channel="scalar", sampling="trilinear", tile=4
                ).to_dict()
            ),
            1 << 24,
        )
    )
    for change, error in (
        (swap_values, (hevr.VerificationError, hevr.IntegrityError)),
        (lambda got: got[:1] + got[2:], hevr.RemoteError),  # a tile missing
        (lambda got: got[:1] + got[:1] + got[1:], hevr.RemoteError),  # a tile twice
        (lambda got: [(i, d + b"\0") if i == 0 else (i, d) for i, d in got], hevr.RemoteError),
        (lambda got: other, (hevr.RemoteError, hevr.VerificationError, hevr.IntegrityError)),
    ):
        monkeypatch.setattr(rv.server, "frames", lying(change))
        with pytest.raises(error):
            hevr.render(rv, cam, sampling="trilinear", tile=4, progress=False).decrypt(s.priv)
    monkeypatch.setattr(rv.server, "frames", honest_frames)
    img = hevr.render(rv, cam, sampling="trilinear", tile=4, progress=False)
    assert img.plan.n_tiles > 2
    bad = dataclasses.replace(img.verification, aggregate=img.verification.aggregate * 2 % int(rv.meta.n) ** 2)
    with pytest.raises(hevr.VerificationError, match="does not verify"):
        dataclasses.replace(img, verification=bad).decrypt(s.priv)
    img.decrypt(s.priv, require_verified=True)  # the honest answer still verifies
    assert END == 0xFFFFFFFF


def test_what_a_packed_store_does_not_serve(packed_served, rv):
    import httpx

    s = packed_served
    body = {"view": _cam(rv).to_dict(), "channel": "scalar"}
    with httpx.Client(base_url=s.url, timeout=60) as http:
        r = http.post(f"/v1/stores/{rv.store_id}/stream", json=body)
        assert r.status_code == 400 and "packed store" in r.json()["detail"]
        r = http.post(f"/v1/stores/{rv.store_id}/render", json={**body, "channel": "vector"})
        assert r.status_code == 400 and "channel: expected 'scalar'" in r.json()["detail"]
        r = http.post(
            f"/v1/stores/{rv.store_id}/render",
            json={**body, "view": hevr.Camera.orbit(rv, azimuth=60, width=8, height=8).to_dict()},
        )  # a perspective camera
        assert r.status_code == 400 and "parallel" in r.json()["detail"]
    with pytest.raises(hevr.ParameterError, match="client: expected None"):
        hevr.render(rv, _cam(rv), progress=False, client=object())


def test_remote_frames_save_and_load(packed_served, rv, tmp_path):
    """A remote packed frame is saved like an in-process one: unverified as it is, verified only
    with the key holder's stamp; both load and decrypt to the same picture."""
    s = packed_served
    cam = _cam(rv, 60, 10)
    plain = hevr.render(rv, cam, verify=False, progress=False)
    plain.save(tmp_path / "u.hevr")
    img = hevr.render(rv, cam, progress=False)
    img.save(tmp_path / "v.hevr", private_key=s.priv)
    want = plain.decrypt(s.priv)
    np.testing.assert_array_equal(hevr.load_image(tmp_path / "u.hevr").decrypt(s.priv), want)
    again = hevr.load_image(tmp_path / "v.hevr")
    assert again.verified
    np.testing.assert_array_equal(again.decrypt(s.priv, require_verified=True), want)


@pytest.fixture(scope="module")
def colour_served(tmp_path_factory, keypair256):
    from _serving import hevr_serve

    pub, priv = keypair256
    d = tmp_path_factory.mktemp("packed-colour-served")
    vol = np.random.default_rng(8).integers(0, 256, (9, 8, 10)).astype(np.uint8)
    ev = hevr.encrypt_volume(
        vol, str(d / "c.zarr"), priv, brick=4, layout="packed", vector_dims=3, gradient=True, progress=False
    )
    with hevr_serve(str(d / "c.zarr"), "--workers", "1") as (url, proc, lines):
        server = connect(url, timeout=120)
        yield types.SimpleNamespace(ev=ev, priv=priv, vol=vol, rv=server.open(ev.meta.store_id), server=server)
        server.close()


@pytest.mark.parametrize(
    "mode, kw",
    [
        ("tf", {"nodes": [(0.2, "blue"), (0.8, "red")]}),
        ("emphasize", {"density": 0.5}),
        ("tf", {"nodes": [(0.3, "white")], "gradient": True}),
    ],
)
def test_colour_frames_through_the_server(colour_served, mode, kw):
    """Transfer-function and emphasis frames of a packed store on hevr serve: the server sums the
    vector channel's k components (it never sees the colouring), the key holder colours them: the
    in-process frame exactly, verified by default with one aggregate for all k components."""
    s = colour_served
    cam = _cam(s.rv, 60, 10)
    remote = hevr.render(s.rv, cam, mode=mode, sampling="trilinear", tile=4, progress=False, **kw)
    local = hevr.render(
        s.ev, _cam(s.ev, 60, 10), mode=mode, sampling="trilinear", tile=4, verify=False, progress=False, **kw
    )
    assert remote.verified and remote.verification.components == 3 and len(remote.components) == 3
    for a, b in zip(remote.components, local.components):
        assert all(np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts))
    np.testing.assert_array_equal(remote.decrypt(s.priv, require_verified=True), local.decrypt(s.priv))
    swapped = [remote.components[1], remote.components[0], remote.components[2]]
    with pytest.raises(hevr.VerificationError, match="does not verify"):
        dataclasses.replace(remote, components=swapped).decrypt(s.priv)


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
def test_slices_through_the_server(packed_served, rv, sampling):
    """Slices of a packed store on hevr serve: planned here with the server's PlanePlan, the same
    ciphertexts and pixels as in process, verified by default; an unsupported plane refused here."""
    s = packed_served
    for plane in (hevr.Plane.axial(rv, 4), hevr.Plane.coronal(rv, 3.5, slab=2)):
        remote = hevr.render_slice(rv, plane, sampling=sampling, progress=False)
        local = hevr.render_slice(s.ev, plane, sampling=sampling, verify=False, progress=False)
        assert remote.verified and len(remote.ciphertexts) == len(local.ciphertexts)
        assert all(np.array_equal(a, b) for a, b in zip(remote.ciphertexts, local.ciphertexts))
        np.testing.assert_array_equal(remote.decrypt(s.priv, require_verified=True), local.decrypt(s.priv))
        bad = dataclasses.replace(remote.verification, seed=bytes(32))
        with pytest.raises(hevr.VerificationError, match="does not verify"):
            dataclasses.replace(remote, verification=bad).decrypt(s.priv)
    with pytest.raises(hevr.ParameterError, match="plane: expected a plane perpendicular"):
        hevr.render_slice(rv, hevr.Plane.oblique(rv, normal=(1, 0, 1)), progress=False)


def test_a_pyramid_level_through_the_server(packed_served, rv):
    """A level the owner encrypted, rendered on hevr serve: the request names level 0's camera and the
    level, the key holder plans the level itself; the in-process level frame exactly, verified."""
    s = packed_served
    cam = _cam(rv, 60, 10)
    remote = hevr.render(rv, cam, level=1, sampling="trilinear", progress=False)
    local = hevr.render(s.ev, _cam(s.ev, 60, 10), level=1, sampling="trilinear", verify=False, progress=False)
    assert remote.verified and remote.verification.level == 1
    assert remote.plan.geometry.shape == local.plan.geometry.shape
    assert all(np.array_equal(a, b) for a, b in zip(remote.ciphertexts, local.ciphertexts))
    np.testing.assert_array_equal(remote.decrypt(s.priv, require_verified=True), local.decrypt(s.priv))


def test_cli_slice_and_render_through_the_server(packed_served, rv, tmp_path, capsys):
    """hevr slice / hevr render --server on a packed store: the slice decrypted here with --key and
    verified, the frame file stamped; both the in-process pictures."""
    from hevr.cli.main import main

    s = packed_served
    key = tmp_path / "key.json"
    s.priv.save(str(key))
    sid = s.ev.meta.store_id
    out = tmp_path / "ax.npy"
    assert main(["slice", "--server", s.url, sid, "--axial", "4", "--key", str(key), "--out", str(out), "-q"]) == 0
    text = capsys.readouterr().out
    assert "verified:" in text
    plane = hevr.Plane.axial(s.ev, 4)
    np.testing.assert_array_equal(
        np.load(out), hevr.render_slice(s.ev, plane, verify=False, progress=False).decrypt(s.priv)
    )
    frame = tmp_path / "f.hevr"
    assert (
        main(["render", "--server", s.url, sid, "--key", str(key), "--out", str(frame), "--size", "14x11", "-q"]) == 0
    )
    img = hevr.load_image(frame)
    assert img.verified and img.plan.geometry.principal != 0


def test_verify_requests_have_the_render_size_limits(packed_served, rv):
    """/verify on a packed store refuses what /render refuses for its size, before any work."""
    import dask
    import httpx

    s = packed_served
    body = {"render": {"view": _cam(rv).to_dict(), "channel": "scalar"}, "seed": "ab" * 32}
    with httpx.Client(base_url=s.url, timeout=60) as http:
        ok = http.post(f"/v1/stores/{rv.store_id}/verify", json=body)
        assert ok.status_code == 200 and int(ok.json()["aggregate"]) > 0
    from hevr.remote.protocol import RenderRequest
    from hevr.serve.jobs import verify_aggregate

    big = hevr.Camera.orbit(rv, azimuth=60, elevation=10, width=64, height=64, parallel=True)
    with dask.config.set({"hevr.limits.max-samples": 2000}):  # the plan (~340 cells) fits; its ~10^4 samples do not
        with pytest.raises(hevr.RenderPlanError, match="step"):
            verify_aggregate(s.ev, RenderRequest(view=big, channel="scalar"), bytes(32), client=None)
