"""The answers of ``hevr serve`` carry none of the server's internals (issue 48, item 5): a store
that fails a check on the server is a problem document without the server's file paths, while
the server's log keeps the whole message. The app runs in process (Starlette's test client)."""

from __future__ import annotations

import logging

import dask
import numpy as np
import pytest
from starlette.testclient import TestClient

import hevr
from hevr.serve.app import create_app


def test_a_storage_fault_is_said_without_the_servers_paths(keypair256, tmp_path, caplog):
    pub, _ = keypair256
    root = tmp_path / "secret-hospital-share"
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(
            np.arange(512, dtype=np.uint16).reshape(8, 8, 8), root / "ct.zarr", pub, brick=4, progress=False
        )
    chunks = sorted(p for p in (root / "ct.zarr" / "scalar").rglob("*") if p.is_file() and p.name != "zarr.json")
    raw = bytearray(chunks[0].read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    chunks[0].write_bytes(bytes(raw))  # a bit flipped on the server's disk
    app = create_app({ev.meta.store_id: hevr.open_volume(root / "ct.zarr")})
    cam = hevr.Camera.orbit(ev, azimuth=5, width=8, height=8).to_dict()
    with TestClient(app) as http, caplog.at_level(logging.ERROR, logger="hevr.serve"):
        r = http.post(f"/v1/stores/{ev.meta.store_id}/render", json={"view": cam, "channel": "scalar"})
    assert r.status_code == 500 and r.headers["content-type"].startswith("application/problem+json")
    body = r.text
    assert "store failed a check" in body and "<server path>" in body, body
    assert str(tmp_path) not in body and "secret-hospital-share" not in body, body
    assert any(str(root) in rec.getMessage() for rec in caplog.records)  # the operator's log has it all


@pytest.mark.parametrize("text", ["/a/b.zarr", "file /srv/x/y: gone", "at /tmp/pytest-1/x.zarr/scalar/c/0/0/0"])
def test_public_text_leaves_no_absolute_path(text):
    from hevr.serve.app import public_text

    assert "/" not in public_text(text).replace("<server path>", "")


def test_public_text_keeps_what_is_not_a_path():
    from hevr.serve.app import public_text

    text = "brick (1, 1, 1): W/H 1/2, a/b, step 0.5/voxel, -v/--verbose"
    assert public_text(text) == text


@pytest.mark.parametrize(
    "text",
    [
        "s3://hospital-bucket/scans/ct.zarr",
        "store gs://b/k: missing",
        "at https://minio.internal:9000/b/k.zarr/scalar/c/0/0/0, status 403",
        "file:///srv/share/ct.zarr (gone)",
        "'s3://b/k.zarr'",
    ],
)
def test_public_text_leaves_no_url(text):
    from hevr.serve.app import public_text

    out = public_text(text)
    assert "://" not in out and "bucket" not in out and "minio" not in out and "<server path>" in out, out


def test_the_served_stores_locations_as_given_are_not_said(keypair256, tmp_path, monkeypatch):
    """A relative path (as the operator typed it) or a URL's key without its scheme (as fsspec
    says it) of a served store is replaced too; the same words elsewhere stay."""
    from hevr.serve.app import public_text
    from hevr.serve.problems import private_locations

    pub, _ = keypair256
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ward7").mkdir()
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(hevr.phantom(8), "ward7/ct.zarr", pub, brick=4, progress=False)
    create_app({"ct": hevr.open_volume("ward7/ct.zarr")})  # the service registers its stores' locations
    private_locations(["s3://secret-bucket/scans/mr.zarr", "scans"])
    for said in [
        "ward7/ct.zarr",
        "ward7/ct.zarr/scalar/c/0/0/1",
        "secret-bucket/scans/mr.zarr/zarr.json",
        "scans/mr.zarr",
    ]:
        assert public_text(f"brick at {said}: gone") == "brick at <server path>: gone", said
    kept = f"the scans of {ev.meta.store_id}: W/H 1/2 (ct.zarr)"
    assert public_text(kept) == kept  # a one-word location alone is a word; a file name alone is no location
