"""Access and transport: bearer tokens per store (hashed in the file, compared in constant time,
never logged), TLS with a throw-away CA, per-token limits on concurrent renders."""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import stat
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from _serving import hevr_serve, wait_until

import hevr
from hevr.remote import connect
from hevr.serve.token_file import add_token
from hevr.serve.tokens import DEFAULT_CONCURRENT, TokenTable, hash_token, new_token


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
    d = tmp_path_factory.mktemp("secure")
    pub, priv = keypair256
    a = hevr.encrypt_volume(hevr.phantom(8), str(d / "a.zarr"), priv, brick=4, progress=False)
    b = hevr.encrypt_volume(hevr.phantom(8), str(d / "b.zarr"), priv, brick=4, progress=False)
    alice, bob = new_token(), new_token()
    (d / "tokens.json").write_text(
        json.dumps(
            {
                "version": 1,
                "tokens": [
                    {"name": "alice", "sha256": hash_token(alice), "stores": [a.meta.store_id], "concurrent": 1},
                    {"name": "bob", "sha256": hash_token(bob), "stores": ["*"]},
                ],
            }
        )
    )
    ca = trustme.CA()
    cert = ca.issue_cert("127.0.0.1")
    cert.cert_chain_pems[0].write_to_path(str(d / "cert.pem"))
    cert.private_key_pem.write_to_path(str(d / "key.pem"))
    ca.cert_pem.write_to_path(str(d / "ca.pem"))
    with hevr_serve(
        str(d / "a.zarr"),
        str(d / "b.zarr"),
        "--tokens",
        str(d / "tokens.json"),
        "--tls-cert",
        str(d / "cert.pem"),
        "--tls-key",
        str(d / "key.pem"),
        "-v",
    ) as (url, proc, lines):
        assert url.startswith("https://")
        yield url, str(d / "ca.pem"), a, b, alice, bob, priv, lines, proc


def test_tls_and_tokens(secure):
    url, ca, a, b, alice, bob, priv, lines, proc = secure
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
    url, ca, a, b, alice, bob, priv, lines, proc = secure

    def one(i):
        rv = connect(url, token=alice, cafile=ca, timeout=120, retries=0).open(a.meta.store_id)  # no retry of a 429
        try:
            hevr.render(
                rv,
                hevr.Camera.orbit(rv, azimuth=100 + i, width=24, height=24),
                sampling="trilinear",
                progress=False,
                verify=False,
            )
            return 200
        except hevr.RemoteError as exc:
            assert "retry" in str(exc)
            return exc.status

    with ThreadPoolExecutor(6) as pool:
        codes = list(pool.map(one, range(6)))
    assert 200 in codes and 429 in codes, codes


def test_logs_name_the_token_never_the_token(secure):
    url, ca, a, b, alice, bob, priv, lines, proc = secure
    connect(url, token=alice, cafile=ca).stores()
    assert wait_until(lambda: any(" GET /v1/stores 200 " in x and " alice " in x for x in lines))
    text = "\n".join(lines)
    line = r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ INFO 127\.0\.0\.1 GET /v1/stores 200 \d+ alice \d+\.\d{3}$"
    assert re.search(line, text, re.MULTILINE), text[-2000:]
    assert alice not in text and bob not in text and hash_token(alice) not in text


def test_a_token_added_to_the_running_server_works_without_a_restart(secure, tmp_path):
    url, ca, a, b, alice, bob, priv, lines, proc = secure
    path = Path(ca).parent / "tokens.json"
    before = path.read_bytes()
    carol, entry = add_token(path, "carol", [b.meta.store_id])
    assert path.read_bytes().startswith(before.rstrip(b"]}\n")) and stat.S_IMODE(path.stat().st_mode) == 0o600
    assert wait_until(lambda: _ok(url, carol, ca), timeout=20)  # read again within a second of the change
    assert {s["id"] for s in connect(url, token=carol, cafile=ca).stores()} == {b.meta.store_id}
    path.write_bytes(before)  # carol revoked: SIGHUP reads the file at the next request (and keeps the server up)
    os.kill(proc.pid, signal.SIGHUP)
    assert wait_until(lambda: not _ok(url, carol, ca), timeout=20)
    assert proc.poll() is None and _ok(url, bob, ca)
    assert any("removed: carol" in x for x in lines)
    assert carol not in "\n".join(lines)


def _ok(url, token, ca):
    try:
        connect(url, token=token, cafile=ca, timeout=20).stores()
        return True
    except hevr.RemoteError as exc:
        assert exc.status == 401
        return False


README_FILE = """{"version": 1,
 "tokens": [{"name": "radiology", "sha256": "%s", "stores": ["3f2a9c0d1e4b5a67"], "concurrent": 2},
            {"name": "research",  "sha256": "%s", "stores": ["*"]}]}
""" % (hash_token("r1"), hash_token("r2"))  # noqa: UP031 (the JSON's braces would need doubling in a format string)


def test_add_token_keeps_every_other_byte(tmp_path):
    path = tmp_path / "tokens.json"
    path.write_text(README_FILE)
    path.chmod(0o644)
    token, entry = add_token(path, "carol", ["0123456789abcdef"])
    text = path.read_text()
    head, tail = README_FILE.rsplit("]}", 1)
    assert text.startswith(head) and text.endswith("]}" + tail)  # the entries there, byte for byte
    assert text[len(head) :].startswith(',\n            {"name": "carol"')  # indented as the first entry
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    table = TokenTable.load(path)
    assert [t.name for t in table.tokens] == ["radiology", "research", "carol"]
    assert table.lookup(token).stores == {"0123456789abcdef"} and entry["sha256"] == hash_token(token)
    assert token not in text
    assert [p.name for p in tmp_path.iterdir()] == ["tokens.json"]  # no temporary left


def test_add_token_creates_refuses_and_never_half_writes(tmp_path):
    path = tmp_path / "new.json"
    token, _ = add_token(path, "first")
    assert TokenTable.load(path).lookup(token).name == "first" and stat.S_IMODE(path.stat().st_mode) == 0o600
    before = path.read_bytes()
    for name, stores, match in [("first", ["*"], "not yet in"), ("a b", ["*"], "name"), ("x", ["../etc"], "stores")]:
        with pytest.raises(hevr.ParameterError, match=match):
            add_token(path, name, stores)
    assert path.read_bytes() == before
    link = tmp_path / "link.json"
    link.symlink_to(path)
    with pytest.raises(hevr.ParameterError, match="symbolic link"):
        add_token(link, "second")
    path.chmod(0o664)
    with pytest.raises(hevr.ParameterError, match="your group may write"):
        add_token(path, "second")
    path.chmod(0o600)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(hevr.ParameterError, match="JSON"):
        add_token(tmp_path / "bad.json", "second")
    with pytest.raises(hevr.ParameterError, match="existing folder"):
        add_token(tmp_path / "nowhere" / "t.json", "second")
    open_dir = tmp_path / "open"
    open_dir.mkdir()
    open_dir.chmod(0o777)
    with pytest.raises(hevr.ParameterError, match="anyone may write"):
        add_token(open_dir / "t.json", "second")
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [
        "bad.json",
        "link.json",
        "new.json",
        "open",
    ]


def test_new_token_on_the_command_line(tmp_path, capsys, caplog):
    from hevr.cli.main import main

    path = tmp_path / "tokens.json"
    assert main(["serve", "--new-token", "radiology", "--tokens", str(path), "--stores", "3f2a9c0d1e4b5a67"]) == 0
    out = capsys.readouterr().out
    token = re.search(r"^token:  (\S{43})$", out, re.MULTILINE).group(1)
    assert out.count(token) == 1 and "added 'radiology'" in out
    assert TokenTable.load(path).lookup(token).stores == {"3f2a9c0d1e4b5a67"}
    assert token not in caplog.text and token not in path.read_text()
    assert main(["serve", "--new-token", "radiology", "--tokens", str(path)]) == 2  # the name is there already
    assert "not yet in" in capsys.readouterr().err
    assert main(["serve", "--new-token", "legacy"]) == 0  # without --tokens: the entry, to add by hand
    out = capsys.readouterr().out
    entry = json.loads(out.strip().splitlines()[-1])
    assert entry["name"] == "legacy" and entry["stores"] == ["*"] and entry["concurrent"] == DEFAULT_CONCURRENT
    assert main(["serve", "vol.zarr", "--stores", "3f2a9c0d1e4b5a67"]) == 2
    assert "--new-token" in capsys.readouterr().err


# -- the one policy of the tokens file: at the start, at every re-read, in add_token ---------------
def _file(path, **names):
    path.write_text(
        json.dumps(
            {"version": 1, "tokens": [{"name": n, "sha256": hash_token(t), "stores": ["*"]} for n, t in names.items()]}
        )
    )
    path.chmod(0o600)
    return path


def _another_users(path, monkeypatch):
    """``path`` as another user's (chown as root; else this process pretends to be someone else)."""
    if os.geteuid() == 0:
        os.chown(path, 54321, -1)
    else:
        uid = os.geteuid()
        monkeypatch.setattr(os, "geteuid", lambda: uid + 1)


class _Clock:
    t = 0.0

    def __call__(self):
        return self.t


@pytest.mark.parametrize("bad", ["group", "anyone", "owner"])
def test_a_server_does_not_start_on_a_tokens_file_others_may_write(tmp_path, monkeypatch, bad):
    from hevr.serve.token_file import TokenFile

    path = _file(tmp_path / "t.json", alice=new_token())
    if bad == "owner":
        _another_users(path, monkeypatch)
    else:
        path.chmod(0o620 if bad == "group" else 0o602)
    match = {"group": "your group may write", "anyone": "anyone may write", "owner": "owned by another user"}[bad]
    with pytest.raises(hevr.ParameterError, match=match):
        TokenFile(path)
    with pytest.raises(hevr.ParameterError, match=match):  # add_token: the same policy
        add_token(path, "second")


@pytest.mark.parametrize("bad", ["group", "anyone", "owner", "empty then bad"])
def test_a_re_read_keeps_the_tokens_when_the_file_breaks_the_policy(tmp_path, monkeypatch, caplog, bad):
    from hevr.serve.token_file import TokenFile

    alice, mallory = new_token(), new_token()
    path = _file(tmp_path / "t.json", alice=alice)
    clock = _Clock()
    tf = TokenFile(path, clock=clock)
    if bad == "empty then bad":
        path.write_text('{"version": 1, "tokens": []}')
        clock.t += 1.5
        assert tf.lookup(alice) is None
        bad = "anyone"
    mode = {"group": 0o620, "anyone": 0o606, "owner": 0o600}[bad]
    _file(path, alice=alice, mallory=mallory)
    path.chmod(mode)
    if bad == "owner":
        _another_users(path, monkeypatch)
    clock.t += 1.5
    with caplog.at_level(logging.ERROR, logger="hevr.serve"):
        assert tf.lookup(mallory) is None and tf.lookup(mallory) is None  # refused, and said once
    errors = [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 1 and "stay in force" in errors[0], errors
    assert ("another user" if bad == "owner" else "chmod go-w") in errors[0], errors
    monkeypatch.undo()
    path.unlink()
    _file(path, alice=alice, mallory=mallory)  # put right: read at the next look
    clock.t += 1.5
    assert tf.lookup(mallory).name == "mallory"


def test_an_emptied_tokens_file_revokes_every_token(tmp_path, caplog):
    from hevr.serve.token_file import TokenFile

    alice = new_token()
    path = _file(tmp_path / "t.json", alice=alice)
    clock = _Clock()
    tf = TokenFile(path, clock=clock)
    path.write_text('{"version": 1, "tokens": []}')
    clock.t += 1.5
    with caplog.at_level(logging.WARNING, logger="hevr.serve"):
        assert tf.lookup(alice) is None and tf.tokens == ()
    assert any("lists no tokens" in r.getMessage() and "401" in r.getMessage() for r in caplog.records)
    with pytest.raises(hevr.ParameterError, match="1 to 256 entries, got 0 entries"):
        TokenFile(path)  # a server does not start with none


def test_a_tokens_file_mounted_as_a_kubernetes_secret_is_followed(tmp_path, monkeypatch):
    """A Secret volume: ``t.json -> ..data/t.json``, ``..data -> ..2026_01``, swapped on update."""
    from hevr.serve.token_file import TokenFile

    alice, bob = new_token(), new_token()
    (tmp_path / "..v1").mkdir()
    _file(tmp_path / "..v1" / "t.json", alice=alice)
    (tmp_path / "..data").symlink_to("..v1")
    (tmp_path / "t.json").symlink_to("..data/t.json")
    clock = _Clock()
    tf = TokenFile(tmp_path / "t.json", clock=clock)
    assert tf.lookup(alice).name == "alice"
    (tmp_path / "..v2").mkdir()
    _file(tmp_path / "..v2" / "t.json", bob=bob)
    (tmp_path / "..tmp").symlink_to("..v2")
    os.replace(tmp_path / "..tmp", tmp_path / "..data")  # the kubelet's atomic update
    clock.t += 1.5
    assert tf.lookup(alice) is None and tf.lookup(bob).name == "bob"
    (tmp_path / "..v2" / "t.json").chmod(0o666)  # the target is what is checked
    with pytest.raises(hevr.ParameterError, match="anyone may write"):
        TokenFile(tmp_path / "t.json")
    with pytest.raises(hevr.ParameterError, match="symbolic link"):
        add_token(tmp_path / "t.json", "carol")  # it would replace the link, not the target


def test_add_token_refuses_a_folder_its_group_may_write(tmp_path):
    team = tmp_path / "team"
    team.mkdir()
    team.chmod(0o770)
    with pytest.raises(hevr.ParameterError, match="a folder your group may write"):
        add_token(team / "t.json", "first")
    team.chmod(0o750)
    assert add_token(team / "t.json", "first")[1]["concurrent"] == 2
