"""``hevr stores --server URL``: the stores a ``hevr serve`` serves to the token (issue 48, item 7),
against the application served by uvicorn in a thread of this process (no ``hevr serve``
subprocess, no Dask cluster: listing renders nothing)."""

from __future__ import annotations

import json
import re
import threading
import time
from contextlib import contextmanager

import dask
import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.serve.app import create_app
from hevr.serve.tokens import TokenTable, hash_token, new_token

uvicorn = pytest.importorskip("uvicorn")


@contextmanager
def served(app):
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    t0 = time.monotonic()
    while not server.started:
        assert time.monotonic() - t0 < 30 and thread.is_alive(), "uvicorn did not start"
        time.sleep(0.02)
    port = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(30)


@pytest.fixture(scope="module")
def two(tmp_path_factory, keypair256):
    pub, priv = keypair256
    d = tmp_path_factory.mktemp("listed")
    with dask.config.set(scheduler="sync"):
        a = hevr.encrypt_volume(hevr.phantom(8), str(d / "ct.zarr"), priv, brick=4, verifiable=True, progress=False)
        vol = np.random.default_rng(3).integers(0, 256, (6, 5, 7)).astype(np.uint8)
        b = hevr.encrypt_volume(vol, str(d / "p.zarr"), pub, brick=4, layout="packed", progress=False)
    alice = new_token()
    tokens = TokenTable.from_dict(
        {"version": 1, "tokens": [{"name": "alice", "sha256": hash_token(alice), "stores": [b.meta.store_id]}]}
    )
    return d, a, b, alice, tokens


def test_hevr_stores_lists_name_id_size_layout_and_tags(two, capsys, monkeypatch):
    d, a, b, alice, _ = two
    app = create_app({"ct": hevr.open_volume(d / "ct.zarr"), b.meta.store_id: hevr.open_volume(d / "p.zarr")})
    monkeypatch.delenv("HEVR_TOKEN", raising=False)
    with served(app) as url:
        assert main(["stores", "--server", url]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert main(["stores", "--server", url, "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        rv = hevr.connect(url).open("ct")
    assert lines[0].split() == ["NAME", "ID", "SIZE", "x*y*z", "LAYOUT", "VERIFIABLE", "CHANNELS", "LEVELS", "KEY"]
    ct, packed = lines[1].split(), lines[2].split()
    assert ct[:5] == ["ct", a.meta.store_id, "8x8x8", "per-voxel", "yes"]
    assert packed[:5] == ["-", b.meta.store_id, "7x5x6", "packed", "no"]  # x*y*z: the CLI's order
    assert ct[-1] == a.meta.fingerprint[:16]
    by_name = {s["name"]: s for s in doc["stores"]}
    assert tuple(by_name["ct"]["shape"]) == rv.shape and tuple(by_name[None]["shape"]) == b.shape == (6, 5, 7)
    assert by_name[None]["packed"] and not by_name["ct"]["packed"] and by_name["ct"]["verifiable"]


def test_hevr_stores_takes_the_token_from_the_environment(two, capsys, monkeypatch):
    d, a, b, alice, tokens = two
    app = create_app({"ct": hevr.open_volume(d / "ct.zarr"), "p": hevr.open_volume(d / "p.zarr")}, tokens=tokens)
    with served(app) as url:
        monkeypatch.delenv("HEVR_TOKEN", raising=False)
        assert main(["stores", "--server", url]) in (1, 2)
        err = capsys.readouterr().err
        assert "401" in err and alice not in err
        monkeypatch.setenv("HEVR_TOKEN", alice)
        assert main(["stores", "--server", url]) == 0
        out = capsys.readouterr().out
    assert re.search(rf"^p\s+{b.meta.store_id}\s", out, re.MULTILINE) and a.meta.store_id not in out
    assert alice not in out


def test_hevr_stores_needs_a_server(capsys):
    assert main(["stores"]) == 2
    assert "--server" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, option",
    [
        (["--timeout", "-1"], "--timeout"),
        (["--connect-timeout", "0"], "--connect-timeout"),
        (["--cafile", "ca.pem"], "--cafile"),
    ],
)
def test_hevr_stores_names_the_option_it_refuses(argv, option, capsys, monkeypatch):
    """``hevr stores`` connects as ``hevr render --server`` does (hevr.cli.remote.connect_remote): a
    refused setting is a usage error naming the option, not the library's parameter name."""
    monkeypatch.delenv("HEVR_TOKEN", raising=False)
    assert main(["stores", "--server", "http://127.0.0.1:9", *argv]) == 2
    err = capsys.readouterr().err
    assert f"{option}: expected" in err, err


def test_hevr_stores_names_hevr_token(capsys, monkeypatch):
    monkeypatch.setenv("HEVR_TOKEN", "two words")
    assert main(["stores", "--server", "http://127.0.0.1:9"]) == 2
    assert "HEVR_TOKEN: expected" in capsys.readouterr().err
