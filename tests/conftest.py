"""Shared session fixtures: keys are generated once per test session.

``HEVR_TEST_FAKE_CUPY=1``: the kernel suites (``HEVR_TEST_KERNELS``) run on the ``cuda`` backend
over ``tests/backends/_fake_cupy.FakeCupy`` — CuPy played by the host build — so the CUDA
launcher's whole path (device arrays, marshalling, the key holder's kernels) runs without a GPU;
``tests/backends/test_cuda_device.py`` runs the three kernel suites so in a subprocess."""

from __future__ import annotations

import os
import signal
import sys
import threading
import warnings
from pathlib import Path

import dask
import pytest
from distributed import Client, LocalCluster

import hevr
from hevr.crypto.keys import generate_keypair

if os.environ.get("HEVR_TEST_FAKE_CUPY") == "1":  # before any test module asks for the cuda backend
    sys.path.insert(0, str(Path(__file__).resolve().parent / "backends"))
    from _fake_cupy import FakeCupy

    sys.modules["cupy"] = FakeCupy
    os.environ["HEVR_TEST_KERNELS"] = "cuda"


def pytest_configure(config):
    """pytest-xdist starts its workers with SIGINT ignored (a terminal's Ctrl-C is for the
    controller), as a shell without job control starts a command run with ``&``, and a process
    started so ignores it too: the Ctrl-C tests (tests/test_dask.py, the CLI's, hevr serve's) would
    interrupt nothing. The test process takes Python's handler back.

    Dask's connect timeout, 30 s, is raised to 120 s here and in the processes the tests start
    (hevr serve, the CLI): at a load of 20 on 2 cores, starting a local cluster's worker processes
    beside the other test processes took longer (issue 49: "hevr: error: TimeoutError")."""
    os.environ["DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT"] = "120s"
    dask.config.set({"distributed.comm.timeouts.connect": "120s"})
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def _keypair(bits: int, require_tags: bool = False):
    """The session's keys are made without the key policy (``require_tags``, on by default for new
    keys since issue 47): the suites of the render pipeline build stores with and without tags on
    purpose. ``policy_keypair256`` has it; tests/crypto/test_key_policy.py tests the default."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        return generate_keypair(bits, require_tags=require_tags)


@pytest.fixture(scope="session")
def policy_keypair256(keypair256):
    """The 256-bit session key with the policy that every store of it carries tags."""
    pub, priv = keypair256
    return pub, priv.with_policy(require_tags=True)


@pytest.fixture(scope="session")
def keypair256():
    return _keypair(256)


@pytest.fixture(scope="session")
def keypair512():
    return _keypair(512)


@pytest.fixture(scope="session")
def keypair2048():
    return _keypair(2048)


@pytest.fixture(scope="session", params=[256, 512], ids=["k256", "k512"])
def keypair(request, keypair256, keypair512):
    return keypair256 if request.param == 256 else keypair512


@pytest.fixture(autouse=True, scope="session")
def _known_stores(tmp_path_factory):
    """The key holder's known stores of the test session: a temporary file, never ~/.config."""
    os.environ["HEVR_KNOWN_STORES"] = str(tmp_path_factory.mktemp("known") / "known_stores.json")
    yield os.environ["HEVR_KNOWN_STORES"]


@pytest.fixture(autouse=True, scope="session")
def _journal_dir(tmp_path_factory):
    """Resume journals of the test session go to a temporary folder, never ~/.cache."""
    folder = tmp_path_factory.mktemp("journals")
    os.environ["DASK_HEVR__JOURNAL_DIR"] = str(folder)  # subprocesses (CLI tests) inherit it
    with dask.config.set({"hevr.journal-dir": str(folder)}):
        yield folder


@pytest.fixture(scope="module")
def cluster():
    """Two in-process workers (1 thread each) behind a client that is NOT the global default:
    hevr must use the client it is given (tests enter ``as_current`` where they want the default)."""
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as lc,
        Client(lc, set_as_default=False) as c,
    ):
        yield c


@pytest.fixture(scope="session")
def s3_server():
    """A real S3-compatible server (moto's, in a thread of this process) on 127.0.0.1 with one
    bucket; yields ``(bucket URL, storage_options)``. Worker processes of a LocalCluster reach it
    over HTTP like any S3 endpoint. Skipped where moto's server or s3fs is not installed."""
    import logging

    server_mod = pytest.importorskip("moto.server")
    s3fs = pytest.importorskip("s3fs")
    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # no line per request
    server = server_mod.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    options = {"endpoint_url": f"http://{host}:{port}", "key": "hevr-test-key", "secret": "hevr-test-secret-5f3a9c"}
    s3fs.S3FileSystem(skip_instance_cache=True, **options).mkdir("hevr-test")
    try:
        yield "s3://hevr-test", options
    finally:
        from hevr.store.sessions import close_sessions

        close_sessions()  # the aiohttp sessions of the stores the tests opened (else "Unclosed client session")
        s3fs.S3FileSystem.clear_instance_cache()
        server.stop()


@pytest.fixture(scope="session")
def cli_store(tmp_path_factory):
    """The CLI tests' set-up: ``cli_store(name, size=10, brick=4, dims=3, store="vol.zarr")``, a
    folder holding ``key.json`` (256 bits) and ``hevr encrypt phantom:SIZE`` (brick ``brick``, a
    ``dims``-dim vector channel) at ``store``."""

    from hevr.cli.main import main  # only where a CLI test asks for it

    def make(name: str, size: int = 10, brick: int = 4, dims: int = 3, store: str = "vol.zarr"):
        d = tmp_path_factory.mktemp(name)
        assert main(["keygen", "--bits", "256", "--out", str(d / "key.json"), "-q"]) == 0
        assert (
            main(
                [
                    "encrypt",
                    f"phantom:{size}",
                    "--key",
                    str(d / "key.json"),
                    "--out",
                    str(d / store),
                    "--brick",
                    str(brick),
                    "--vector-dims",
                    str(dims),
                    "-q",
                ]
            )
            == 0
        )
        return d

    return make


@pytest.fixture(scope="session")
def served_store(tmp_path_factory, keypair256):
    """A 12³ verifiable store with a 3-dim vector channel, 27 bricks and one pyramid level:
    ``SimpleNamespace(ev, priv, vol, dir)`` (the store is ``dir / "v.zarr"``)."""
    import types

    import hevr

    pub, priv = keypair256
    d = tmp_path_factory.mktemp("served")
    vol = hevr.phantom(12)
    hevr.encrypt_volume(vol, str(d / "v.zarr"), priv, brick=4, vector_dims=3, verifiable=True, progress=False)
    hevr.build_pyramid(str(d / "v.zarr"), levels=1, progress=False)
    return types.SimpleNamespace(ev=hevr.open_volume(str(d / "v.zarr")), priv=priv, vol=vol, dir=d)


@pytest.fixture(scope="module")
def served(served_store):
    """A real ``hevr serve`` of ``served_store`` (2-worker LocalCluster, 127.0.0.1), per test module
    (an idle server and its cluster still cost a few % of a core: not kept for the whole session):
    ``SimpleNamespace(url, ev, priv, vol, dir, lines, proc)``."""
    import types

    from _serving import hevr_serve

    s = served_store
    with hevr_serve(str(s.dir / "v.zarr"), "--workers", "2") as (url, proc, lines):
        yield types.SimpleNamespace(url=url, ev=s.ev, priv=s.priv, vol=s.vol, dir=s.dir, lines=lines, proc=proc)
