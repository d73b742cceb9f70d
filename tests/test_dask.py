"""hevr._dask: the one-time warning when the key holder is a Dask client of another machine's scheduler."""

from __future__ import annotations

import types
import warnings

import pytest

from hevr import _dask


def _client(address):
    return types.SimpleNamespace(scheduler=types.SimpleNamespace(address=address))


def test_remote_scheduler_warns_once_naming_connect():
    with pytest.warns(UserWarning, match=r"hevr\.connect") as rec:
        _dask.warn_if_remote(_client("tcp://10.20.30.40:8786"))
    assert "10.20.30.40" in str(rec[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _dask.warn_if_remote(_client("tcp://10.20.30.40:8786"))  # once per scheduler
        for local in ("tcp://127.0.0.1:8786", "inproc://192.168.1.1/1/2", "tcp://localhost:1", "tcp://[::1]:8786"):
            _dask.warn_if_remote(_client(local))
        _dask.warn_if_remote(None)
    with pytest.warns(UserWarning):
        _dask.warn_if_remote(_client("tls://scheduler.example.org:8786"))


def test_render_on_a_local_cluster_does_not_warn(cluster, keypair256, tmp_path):
    import hevr

    ev = hevr.encrypt_volume(hevr.phantom(6), str(tmp_path / "v.zarr"), keypair256[1], brick=6, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        hevr.render(ev, hevr.Camera.orbit(ev, width=4, height=4), client=cluster, progress=False)
