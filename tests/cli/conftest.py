"""Shared set-up of the CLI tests: a key and a small encrypted phantom, made through the CLI."""

from __future__ import annotations

import pytest

from hevr.cli.main import main


@pytest.fixture(scope="session")
def cli_store(tmp_path_factory):
    """``cli_store(name, size=10, brick=4, dims=3, store="vol.zarr")``: a folder holding ``key.json``
    (256 bits) and ``hevr encrypt phantom:SIZE`` (brick ``brick``, a ``dims``-dim vector channel) at ``store``."""

    def make(name: str, size: int = 10, brick: int = 4, dims: int = 3, store: str = "vol.zarr"):
        d = tmp_path_factory.mktemp(name)
        assert main(["keygen", "--bits", "256", "--out", str(d / "key.json"), "-q"]) == 0
        assert main(["encrypt", f"phantom:{size}", "--key", str(d / "key.json"), "--out", str(d / store),
                     "--brick", str(brick), "--vector-dims", str(dims), "-q"]) == 0
        return d

    return make
