"""A store behind ``hevr serve`` is known under the name its owner serves it as (issue 47): the
key holder opens it by that name, its known-stores entry is keyed by the name, and a new version
the owner encrypts under the same served path is refused — once the server serves it — until the
key holder trusts it; the old volume (pinned to the old id) is refused by the restarted server."""

from __future__ import annotations

import inspect
import socket

import pytest

import hevr
from hevr.cli.main import main
from hevr.serve.run import open_stores, store_name


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _trust(rv, priv):
    """``hevr.trust_store`` as it is now: (volume, private key), or (volume) before that change."""
    params = inspect.signature(hevr.trust_store).parameters
    return hevr.trust_store(rv, priv) if len(params) >= 2 else hevr.trust_store(rv)


@pytest.mark.parametrize(
    "spec, want",
    [
        ("/data/ct/vol.zarr", ("vol", "/data/ct/vol.zarr")),
        ("/data/ct/vol.zarr/", ("vol", "/data/ct/vol.zarr/")),
        ("s3://bucket/x=1/b.zarr", ("b", "s3://bucket/x=1/b.zarr")),
        ("ct=/data/2024/vol.zarr", ("ct", "/data/2024/vol.zarr")),
        ("scan_7", ("scan_7", "scan_7")),
    ],
)
def test_store_names_from_the_command_line(spec, want):
    assert store_name(spec) == want


@pytest.mark.parametrize(
    "argv, words",
    [
        (["/x/a/vol.zarr", "/x/b/vol.zarr"], ["'vol' twice", "NAME=PATH"]),
        (["0123456789abcdef=/x/v.zarr"], ["16 hex digits"]),
        (["/x/0123456789ABCDEF.zarr"], ["16 hex digits", "NAME=PATH"]),
        (["a b=/x/v.zarr"], ["letters, digits"]),
        (["ct="], ["NAME=PATH with a path"]),
    ],
)
def test_bad_names_are_refused_at_startup(argv, words, capsys):
    assert main(["serve", *argv]) == 2  # before any store is opened or a port bound
    err = capsys.readouterr().err
    assert all(w in err for w in words), err


def test_two_names_of_one_store_are_refused(served_store):
    path = str(served_store.dir / "v.zarr")
    assert list(open_stores([path])) == ["v"] and list(open_stores([f"w={path}"])) == ["w"]
    with pytest.raises(hevr.ParameterError, match="the store .* twice"):
        open_stores([path, f"w={path}"])


def test_a_new_version_under_a_served_name_is_refused_until_trusted(tmp_path, keypair256):
    from _serving import hevr_serve

    _, priv = keypair256
    store = tmp_path / "scans" / "ct.zarr"
    store.parent.mkdir()
    vol = hevr.phantom(8)
    old = hevr.encrypt_volume(vol, str(store), priv, brick=4, verifiable=True, progress=False).meta.store_id
    port = _free_port()
    with hevr_serve(str(store), port=port) as (url, proc, lines):
        server = hevr.connect(url, timeout=120)
        (item,) = server.stores()
        assert (item["id"], item["name"]) == (old, "ct")
        rv = server.open("ct")
        assert rv.path == f"{url}/v1/stores/ct" and rv.store_id == old
        cam = hevr.Camera.orbit(rv, azimuth=20, width=8, height=6)
        hevr.render(rv, cam, progress=False).decrypt(priv, require_verified=old)  # verified: recorded under the name
        assert hevr.known_stores()[rv.path].store_id == old
    new = hevr.encrypt_volume(
        vol, str(store), priv, brick=4, verifiable=True, overwrite=True, progress=False
    ).meta.store_id
    assert new != old
    with hevr_serve(f"ct={store}", port=port) as (url2, proc, lines):
        assert url2 == url
        with pytest.raises(hevr.RemoteError, match="404"):  # the old volume is pinned to the old id
            hevr.render(rv, cam, progress=False)
        rv2 = hevr.connect(url, timeout=120).open("ct")
        assert rv2.path == rv.path and rv2.store_id == new
        with pytest.raises(hevr.VerificationError, match="another version"):
            hevr.render(rv2, cam, progress=False)
        by_id = hevr.connect(url, timeout=120).open(new)  # by id: another name, not refused by this record
        assert by_id.path == f"{url}/v1/stores/{new}"
        _trust(rv2, priv)
        img = hevr.render(rv2, cam, progress=False)
        assert img.verification.store_id == new
        img.decrypt(priv, require_verified=new)
        assert hevr.known_stores()[rv.path].store_id == new
