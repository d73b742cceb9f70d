"""The render processes' allocator thresholds (hevr.runtime.malloc): set once per process with glibc's
mallopt, never when ``hevr.malloc-tuning`` is false, and in Dask workers by the first render task."""

from __future__ import annotations

import ctypes
import sys

import dask
import numpy as np
import pytest
from distributed import Client, LocalCluster

import hevr
from hevr.runtime import malloc

glibc = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mallopt is glibc's (Linux)")


class _Calls:
    def __init__(self, result: int = 1):
        self.calls = []
        self.result = result
        self.argtypes = self.restype = None

    def __call__(self, param, value):
        self.calls.append((param, value))
        return self.result


@glibc
def test_tune_sets_both_thresholds_once(monkeypatch):
    fake = _Calls()
    monkeypatch.setattr(malloc, "_DONE", [])
    monkeypatch.setattr(ctypes, "CDLL", lambda name: type("Libc", (), {"mallopt": fake})())
    assert malloc.tune() is True and malloc.tune() is True
    assert fake.calls == [(malloc.M_MMAP_THRESHOLD, 32 << 20), (malloc.M_TRIM_THRESHOLD, 64 << 20)]


@pytest.mark.parametrize("off", [False, "false", "0", "off"])
def test_config_off_leaves_the_allocator_alone(monkeypatch, off):
    fake = _Calls()
    monkeypatch.setattr(malloc, "_DONE", [])
    monkeypatch.setattr(ctypes, "CDLL", lambda name: type("Libc", (), {"mallopt": fake})())
    with dask.config.set({"hevr.malloc-tuning": off}):
        assert malloc.tune() is False
    assert fake.calls == [] and malloc._DONE == []  # asked again once the setting allows it


@glibc
def test_a_refused_mallopt_or_no_glibc_is_false(monkeypatch):
    monkeypatch.setattr(malloc, "_DONE", [])
    monkeypatch.setattr(ctypes, "CDLL", lambda name: type("Libc", (), {"mallopt": _Calls(0)})())
    assert malloc.tune() is False
    monkeypatch.setattr(malloc, "_DONE", [])

    def missing(name):
        raise OSError("no libc")

    monkeypatch.setattr(ctypes, "CDLL", missing)
    assert malloc.tune() is False


def _tuned() -> list:
    return list(malloc._DONE)


@glibc
def test_render_tasks_tune_their_worker(tmp_path, keypair256):
    """Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_ set; the first render task there
    sets the thresholds (and a worker of a cluster started with the setting off does not)."""
    ev = hevr.encrypt_volume(
        np.arange(60, dtype=np.uint8).reshape(3, 4, 5), tmp_path / "v.zarr", keypair256[1], brick=2, progress=False
    )
    cam = hevr.Camera.orbit(ev, width=5, height=4)
    for setting, want in ((True, [True]), (False, [])):
        with (
            dask.config.set({"hevr.malloc-tuning": setting}),
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as lc,
            Client(lc) as c,
        ):
            assert list(c.run(_tuned).values()) == [[]]  # a fresh worker: nothing set yet
            hevr.render(ev, cam, progress=False, cache=False, client=c)
            assert list(c.run(_tuned).values()) == [want]


def test_a_misspelt_setting_is_refused_by_name(monkeypatch):
    monkeypatch.setattr(malloc, "_DONE", [])
    with (
        dask.config.set({"hevr.malloc-tuning": "flase"}),
        pytest.raises(hevr.ParameterError, match="hevr.malloc-tuning: expected true or false"),
    ):
        malloc.tune()
