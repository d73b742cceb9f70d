"""Remote renders through a real ``hevr serve`` (2 workers): byte for byte the in-process images,
verified over the wire, and the key holder's process never unpickles or joins a Dask cluster."""

from __future__ import annotations

import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.remote import connect
from hevr.remote.volume import RemoteVolume

NODES = [(0.2, "blue"), (0.8, "red")]


@pytest.fixture(scope="module")
def rv(served):
    server = connect(served.url, timeout=120)
    yield server.open(served.ev.meta.store_id)
    server.close()


def _cam(ev, **kw):
    return hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=14, height=12, **kw)


def test_open_describes_the_store(served, rv):
    assert isinstance(rv, RemoteVolume) and isinstance(rv, hevr.EncryptedVolume)
    assert rv.meta == served.ev.meta and rv.shape == served.ev.shape and rv.levels == 1
    (item,) = rv.server.stores()
    assert item["id"] == served.ev.meta.store_id and item["tags"] and item["channels"] == ["scalar", "vector"]
    assert item["shape"] == rv.shape  # one order for sizes: rv.shape's (z, y, x), issue 48
    assert _cam(rv) == _cam(served.ev)
    with pytest.raises(hevr.ParameterError, match="persist"):
        rv.persist()


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("mode", ["xray", "tf"])
def test_render_is_the_in_process_image_byte_for_byte(served, rv, sampling, mode):
    kw = dict(mode=mode, sampling=sampling, nodes=NODES if mode == "tf" else None, progress=False)
    remote = hevr.render(rv, _cam(rv), verify=False, **kw)
    local = hevr.render(served.ev, _cam(served.ev), verify=False, cache=False, **kw)
    assert remote.to_bytes() == local.to_bytes()
    arr = remote.decrypt(served.priv)
    np.testing.assert_array_equal(arr, local.decrypt(served.priv))
    ref = hevr.render_plain(
        served.vol, _cam(served.ev), mode=mode, sampling=sampling, nodes=NODES if mode == "tf" else None, vector_dims=3
    )
    assert (
        np.abs(arr - ref)
        <= hevr.error_bound(
            served.ev, _cam(served.ev), mode=mode, sampling=sampling, nodes=NODES if mode == "tf" else None
        )
    ).all()


def test_verified_by_default_with_a_seed_drawn_here(served, rv):
    img = hevr.render(rv, _cam(rv), sampling="trilinear", progress=False)  # the store has tags: verified
    assert img.verification is not None and img.verification.store_id == served.ev.meta.store_id
    assert img.verification.camera == _cam(rv)  # the key holder's own request, never the server's word
    local = hevr.render(served.ev, _cam(served.ev), sampling="trilinear", verify=False, cache=False, progress=False)
    np.testing.assert_array_equal(img.decrypt(served.priv), local.decrypt(served.priv))
    pinned = hevr.render(rv, _cam(rv), progress=False, verify=served.ev.meta.store_id)
    pinned.decrypt(served.priv)
    with pytest.raises(hevr.VerificationError, match="another store"):
        hevr.render(rv, _cam(rv), progress=False, verify="0123456789abcdef")


def test_a_wrong_aggregate_is_caught(served, rv):
    img = hevr.render(rv, _cam(rv), progress=False)
    import dataclasses

    img.verification = dataclasses.replace(
        img.verification, aggregate=img.verification.aggregate * 2 % int(rv.meta.n) ** 2
    )
    with pytest.raises(hevr.VerificationError):
        img.decrypt(served.priv)


def test_slices_levels_and_frames(served, rv):
    for plane in (hevr.Plane.axial(rv, 5), hevr.Plane.coronal(rv, 6.5, slab=3)):
        remote = hevr.render_slice(rv, plane, progress=False, verify=False)
        local = hevr.render_slice(served.ev, plane, progress=False, verify=False, cache=False)
        assert remote.to_bytes() == local.to_bytes()
        hevr.render_slice(rv, plane, progress=False).decrypt(served.priv)  # verified slice
    small = hevr.Camera.orbit(rv, azimuth=10, width=8, height=8)
    remote = hevr.render(rv, small, level=1, verify=False, progress=False)
    assert (
        remote.to_bytes()
        == hevr.render(served.ev, small, level=1, verify=False, cache=False, progress=False).to_bytes()
    )
    hevr.render(rv, small, level=1, progress=False).decrypt(served.priv)  # a level verifies too
    frame = hevr.render_frame(rv, _cam(rv), served.priv, mode="tf", nodes=NODES, progress=False)
    here = hevr.render_frame(
        served.ev, _cam(served.ev), served.priv, mode="tf", nodes=NODES, progress=False, cache=False
    )
    np.testing.assert_array_equal(frame.image, here.image)
    assert frame.stats["ciphertexts"] == here.stats["ciphertexts"]
    assert frame.stats["verified"] and here.stats["verified"]  # streamed frames verified when they settle


def test_what_the_server_cannot_be_asked(rv):
    cam = _cam(rv)
    with pytest.raises(hevr.ParameterError, match="finish"):
        hevr.render(rv, cam, mode="tf", nodes=NODES, finish="server", progress=False)
    with pytest.raises(hevr.ParameterError, match="compute"):
        hevr.render(rv, cam, compute=False, progress=False)
    with pytest.raises(hevr.ParameterError, match="keep_sums"):
        hevr.render(rv, cam, keep_sums="x.hevrsums", progress=False)


def test_key_holder_never_unpickles_nor_joins_a_cluster(served, rv, monkeypatch):
    from _serving import refuse_unpickling

    attempts = refuse_unpickling(monkeypatch)
    server = connect(served.url, timeout=120)
    rv2 = server.open(served.ev.meta.store_id)
    cam = hevr.Camera.orbit(rv2, azimuth=75, width=10, height=9)
    img = hevr.render(rv2, cam, mode="tf", nodes=NODES, progress=False)
    assert img.decrypt(served.priv).shape == (9, 10, 3)  # verified on decryption
    hevr.render_slice(rv2, hevr.Plane.sagittal(rv2, 3), progress=False).decrypt(served.priv)
    frame = hevr.render_frame(rv2, cam, served.priv, progress=False)
    assert frame.image.shape == (9, 10)
    viewer = hevr.Viewer(rv2, served.priv, volume=served.vol, width=10, height=8, mode="tf", show=False, preview=0)
    viewer.azimuth.value = 50  # a second frame from the server, then a colour change on the client alone
    viewer.node_rows[0][1].value = "#00ff00"
    assert len(viewer.history) == 2 and viewer.history[-1]["client_recolour"] is True  # show=False: no first frame
    assert all(h["error"] <= h["bound"] for h in viewer.history)
    assert not attempts
    server.close()


def test_cli_render_and_slice_write_the_same_files(served, tmp_path, monkeypatch):
    store = str(served.dir / "v.zarr")
    sid = served.ev.meta.store_id
    common = ["--size", "12x10", "--azimuth", "40", "--no-verify", "-q"]
    assert main(["render", "--server", served.url, sid, "--out", str(tmp_path / "r.hevr"), *common]) == 0
    assert main(["render", store, "--out", str(tmp_path / "l.hevr"), *common]) == 0
    assert (tmp_path / "r.hevr").read_bytes() == (tmp_path / "l.hevr").read_bytes()
    sl = ["--coronal", "5", "--no-verify", "-q"]
    assert main(["slice", "--server", served.url, sid, "--out", str(tmp_path / "rs.hevr"), *sl]) == 0
    assert main(["slice", store, "--out", str(tmp_path / "ls.hevr"), *sl]) == 0
    assert (tmp_path / "rs.hevr").read_bytes() == (tmp_path / "ls.hevr").read_bytes()
    # a verified remote frame (the key holder's --key) decrypts as verified
    served.priv.save(str(tmp_path / "key.json"))
    assert (
        main(
            [
                "render",
                "--server",
                served.url,
                sid,
                "--key",
                str(tmp_path / "key.json"),
                "--out",
                str(tmp_path / "v.hevr"),
                "--size",
                "8x8",
                "-q",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "decrypt",
                str(tmp_path / "v.hevr"),
                "--key",
                str(tmp_path / "key.json"),
                "--require-verified",
                "--out",
                str(tmp_path / "v.png"),
                "-q",
            ]
        )
        == 0
    )
    # the server refuses what it does not serve; nothing is written
    assert main(["render", "--server", served.url, "0" * 16, "--out", str(tmp_path / "x.hevr"), "-q"]) == 1
    assert not (tmp_path / "x.hevr").exists()
    assert main(["render", "--server", served.url, sid, "--workers", "2", "--out", str(tmp_path / "y.hevr")]) == 2


def test_cli_remote_render_verifies_with_the_key_holders_key(served, tmp_path, capsys):
    """The README's remote flow (issue 47): ``hevr render|slice --server URL NAME --key KEY.json``
    verifies the server's answer here and stamps the file; ``hevr decrypt --require-verified`` takes
    it. Without --key the warning says to pass it."""
    sid, key = served.ev.meta.store_id, str(tmp_path / "key.json")
    served.priv.save(key)
    capsys.readouterr()
    for i, argv in enumerate((["render", "--size", "8x8", "--azimuth", "20"], ["slice", "--axial", "5"])):
        out = str(tmp_path / f"k{i}.hevr")
        assert main([argv[0], "--server", served.url, "v", "--key", key, "--out", out, *argv[1:]]) == 0
        text = capsys.readouterr()
        assert f"verified: the frame is the render of store {sid}" in text.out and "not verified" not in text.err
        assert (
            main(["decrypt", out, "--key", key, "--require-verified", sid, "--out", str(tmp_path / f"k{i}.png")]) == 0
        )
        assert "verified: the frame is the render" in capsys.readouterr().out
    out = str(tmp_path / "nokey.hevr")
    assert main(["render", "--server", served.url, "v", "--out", out, "--size", "8x8"]) == 0
    err = capsys.readouterr().err
    assert (
        "not verified" in err
        and "pass --key KEY.json, the key holder's private key, to verify the server's answer" in err
    )
    assert main(["decrypt", out, "--key", key, "--require-verified", "--out", str(tmp_path / "nokey.png")]) == 1
    assert "not verified" in capsys.readouterr().err


def test_a_store_is_served_under_its_name(served, rv):
    """``hevr serve v.zarr`` serves the store as "v" too: listed with its name, opened by it (the
    volume's path names it, every request its id), and a name never taken for an id."""
    sid = served.ev.meta.store_id
    assert [(s["id"], s["name"]) for s in rv.server.stores()] == [(sid, "v")]
    assert any(line.split()[1:3] == [sid, "v"] for line in served.lines if line.startswith("store:"))
    by_name = rv.server.open("v")
    assert by_name.path == f"{served.url}/v1/stores/v" and by_name.store_id == sid and by_name.name == "v"
    assert rv.path == f"{served.url}/v1/stores/{sid}" and rv.name is None
    assert by_name.at_level(1).path == by_name.path and by_name.at_level(1).store_id == sid
    cam = _cam(by_name)
    assert (
        hevr.render(by_name, cam, verify=False, progress=False).to_bytes()
        == hevr.render(rv, cam, verify=False, progress=False).to_bytes()
    )
    with pytest.raises(hevr.RemoteError, match="404"):
        rv.server.open("w")
    for bad in ("a/b", "", "x" * 65, "0123456789ABCDEF", 7):
        with pytest.raises(hevr.ParameterError, match="name_or_id"):
            rv.server.open(bad)
