"""Access and transport: bearer tokens per store (hashed in the file, compared in constant time,
never logged), TLS with a throw-away CA, per-token limits on concurrent renders."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import pytest

import hevr
from hevr.remote import connect
from hevr.serve.tokens import TokenTable, hash_token, new_token


def test_token_table_is_strict(tmp_path):
    good = {"name": "a", "sha256": hash_token("t"), "stores": ["*"]}
    assert TokenTable.from_dict({"version": 1, "tokens": [good]}).lookup("t").concurrent == 2
    bad = [
        ({"version": 2, "tokens": [good]}, "version"),
        ({"version": 1, "tokens": []}, "tokens"),
        ({"version": 1, "tokens": [dict(good, token="t")]}, "fields"),
        ({"version": 1, "tokens": [dict(good, sha256="t")]}, "sha256"),
        ({"version": 1, "tokens": [good, dict(good, name="b")]}, "unique SHA-256"),
        ({"version": 1, "tokens": [good, dict(good, sha256=hash_token("u"))]}, "unique name"),
        ({"version": 1, "tokens": [dict(good, stores=["../x"])]}, "stores"),
        ({"version": 1, "tokens": [dict(good, concurrent=0)]}, "concurrent"),
        ({"version": 1, "tokens": [dict(good, name="a b")]}, "name"),
        ([], "exactly"),
    ]
    for doc, match in bad:
        with pytest.raises(hevr.ParameterError, match=match):
            TokenTable.from_dict(doc)
    (tmp_path / "t.json").write_text('{"version": 1, "version": 1}')
    with pytest.raises(hevr.ParameterError, match="duplicate"):
        TokenTable.load(tmp_path / "t.json")
    with pytest.raises(hevr.MissingFileError):
        TokenTable.load(tmp_path / "none.json")
    assert len(new_token()) >= 43 and new_token() != new_token()
    assert "sha" not in repr(TokenTable.from_dict({"version": 1, "tokens": [good]}).tokens[0])


@pytest.fixture(scope="module")
def secure(tmp_path_factory, keypair256):
    trustme = pytest.importorskip("trustme")
    from _serving import hevr_serve

    d = tmp_path_factory.mktemp("secure")
    pub, priv = keypair256
    a = hevr.encrypt_volume(hevr.phantom(8), str(d / "a.zarr"), priv, brick=4, progress=False)
    b = hevr.encrypt_volume(hevr.phantom(8), str(d / "b.zarr"), priv, brick=4, progress=False)
    alice, bob = new_token(), new_token()
    (d / "tokens.json").write_text(json.dumps({"version": 1, "tokens": [
        {"name": "alice", "sha256": hash_token(alice), "stores": [a.meta.store_id], "concurrent": 1},
        {"name": "bob", "sha256": hash_token(bob), "stores": ["*"]}]}))
    ca = trustme.CA()
    cert = ca.issue_cert("127.0.0.1")
    cert.cert_chain_pems[0].write_to_path(str(d / "cert.pem"))
    cert.private_key_pem.write_to_path(str(d / "key.pem"))
    ca.cert_pem.write_to_path(str(d / "ca.pem"))
    with hevr_serve(str(d / "a.zarr"), str(d / "b.zarr"), "--tokens", str(d / "tokens.json"), "--tls-cert",
                    str(d / "cert.pem"), "--tls-key", str(d / "key.pem"), "-v") as (url, proc, lines):
        assert url.startswith("https://")
        yield url, str(d / "ca.pem"), a, b, alice, bob, priv, lines


def test_tls_and_tokens(secure):
    url, ca, a, b, alice, bob, priv, lines = secure
    ids = {s["id"] for s in connect(url, token=bob, cafile=ca).stores()}
    assert ids == {a.meta.store_id, b.meta.store_id}
    assert {s["id"] for s in connect(url, token=alice, cafile=ca).stores()} == {a.meta.store_id}
    rv = connect(url, token=alice, cafile=ca).open(a.meta.store_id)
    cam = hevr.Camera.orbit(rv, width=6, height=5)
    img = hevr.render(rv, cam, progress=False)
    assert img.to_bytes() == hevr.render(a, cam, progress=False, cache=False).to_bytes()
    with pytest.raises(hevr.RemoteError, match="404") as e:
        connect(url, token=alice, cafile=ca).open(b.meta.store_id)  # not hers: as if it did not exist
    assert e.value.status == 404
    assert connect(url, token=alice, cafile=ca).open("a").store_id == a.meta.store_id  # by its served name
    with pytest.raises(hevr.RemoteError, match="404"):
        connect(url, token=alice, cafile=ca).open("b")  # nor by its name
    for token in (None, "wrong", bob + "x"):
        with pytest.raises(hevr.RemoteError, match="401") as e:
            connect(url, token=token, cafile=ca).stores()
        assert e.value.status == 401 and e.value.problem["status"] == 401
    with pytest.raises(hevr.RemoteError, match="SSL|certificate|CERTIFICATE"):
        connect(url, token=bob).stores()  # the throw-away CA is not the system's
    with pytest.raises(hevr.RemoteError):
        connect(url.replace("https", "http"), token=bob, timeout=5).stores()


def test_per_token_concurrency_is_429_with_retry_after(secure):
    url, ca, a, b, alice, bob, priv, lines = secure

    def one(i):
        rv = connect(url, token=alice, cafile=ca, timeout=120).open(a.meta.store_id)
        try:
            hevr.render(rv, hevr.Camera.orbit(rv, azimuth=100 + i, width=24, height=24), sampling="trilinear",
                        progress=False, verify=False)
            return 200
        except hevr.RemoteError as exc:
            assert "retry" in str(exc)
            return exc.status

    with ThreadPoolExecutor(6) as pool:
        codes = list(pool.map(one, range(6)))
    assert 200 in codes and 429 in codes, codes


def test_logs_name_the_token_never_the_token(secure):
    url, ca, a, b, alice, bob, priv, lines = secure
    connect(url, token=alice, cafile=ca).stores()
    text = "\n".join(lines)
    assert "GET /v1/stores 200 alice" in text
    assert alice not in text and bob not in text and hash_token(alice) not in text
