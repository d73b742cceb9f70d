"""The Dask path only for the key holder's own cluster (issue 47, item 4).

A private key is used only beside a cluster this process started (Dask's default scheduler, a
client of a cluster object made here, an ``inproc://`` scheduler) or one the user declared its own
(:func:`hevr.own_cluster`, ``$HEVR_OWN_CLUSTER``); otherwise :class:`hevr.ForeignClusterError`
names ``hevr.connect``. No address guessing: a scheduler on 127.0.0.1 that this process did not
start is what an ``ssh -L`` tunnel to another party's cluster looks like.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import textwrap
import types
import warnings

import numpy as np
import pytest
from distributed import Client, LocalCluster

import hevr
from hevr.runtime import scheduler as _dask

SCHEDULER = textwrap.dedent("""
    import asyncio, sys
    from distributed import Scheduler

    async def main():
        async with Scheduler(host="127.0.0.1", port=0, dashboard=False, dashboard_address=":0") as s:
            print(s.address, flush=True)
            await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)  # until stdin closes

    asyncio.run(main())
""")


@pytest.fixture(autouse=True)
def _no_declarations(monkeypatch):
    """Each test starts with no cluster declared own (the opt-in lasts for the process otherwise)."""
    monkeypatch.setattr(_dask, "_OWN_SCHEDULERS", set())
    monkeypatch.setattr(_dask, "_WARNED_SCHEDULERS", set())
    monkeypatch.delenv(_dask.OWN_CLUSTER_ENV, raising=False)


def _fake(address, cluster=None):
    return types.SimpleNamespace(scheduler=types.SimpleNamespace(address=address), cluster=cluster)


@pytest.fixture(scope="module")
def tcp_cluster():
    """An in-process cluster reached by its tcp address: ``Client(address)`` has no cluster object,
    the "this process did not start it" case by the rule, cheap to run for real."""
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", dashboard_address=None) as lc:
        assert lc.scheduler_address.startswith("tcp://127.0.0.1:")
        yield lc


@pytest.fixture
def joined(tcp_cluster):
    with Client(tcp_cluster.scheduler_address, set_as_default=False) as c:
        assert c.cluster is None
        yield c


# -- the decision, without a cluster --------------------------------------------------------------
def test_no_address_is_trusted_by_its_spelling():
    for address in (
        "tcp://127.0.0.1:8786",
        "tcp://localhost:8786",
        "tcp://[::1]:8786",
        "tls://127.0.0.2:1",
        "tcp://localhost.example.org:8786",
        "tcp://127.0.0.1.nip.io:8786",
        "tcp://10.0.0.5:8786",
    ):
        assert not _dask.is_own_cluster(_fake(address)), address
        with pytest.raises(hevr.ForeignClusterError, match=r"hevr\.connect"):
            _dask.refuse_foreign_cluster(_fake(address))


def test_what_this_process_started_is_its_own():
    assert _dask.is_own_cluster(None)  # Dask's default scheduler
    assert _dask.is_own_cluster(_fake("inproc://10.0.0.5/1/2"))  # reachable from this process only
    local = object.__new__(LocalCluster)  # what Client(LocalCluster(...)) holds (not started: a type check)
    assert _dask.is_own_cluster(_fake("tcp://10.0.0.5:8786", cluster=local))  # Client(LocalCluster(...))
    assert not _dask.is_own_cluster(_fake("tcp://10.0.0.5:8786", cluster=object()))  # a gateway's, an SSH one
    _dask.refuse_foreign_cluster(None)  # no client at all (none active in this test): nothing to say


def test_the_opt_in_is_exact_and_by_address(monkeypatch):
    assert hevr.own_cluster(_fake("tcp://127.0.0.1:8786")) == "tcp://127.0.0.1:8786"
    assert _dask.is_own_cluster(_fake("tcp://127.0.0.1:8786"))
    assert not _dask.is_own_cluster(_fake("tcp://127.0.0.1:8787"))  # another port: another scheduler
    assert not _dask.is_own_cluster(_fake("tcp://localhost:8786"))  # no guessing that names are the same host
    assert hevr.own_cluster("10.0.0.5:8786") == "tcp://10.0.0.5:8786"  # Dask's default scheme, as clients report it
    assert _dask.is_own_cluster(_fake("tcp://10.0.0.5:8786"))
    monkeypatch.setenv(_dask.OWN_CLUSTER_ENV, "tcp://10.0.0.6:1, 10.0.0.7:2")
    assert _dask.is_own_cluster(_fake("tcp://10.0.0.6:1")) and _dask.is_own_cluster(_fake("tcp://10.0.0.7:2"))
    assert _dask.declared_own("10.0.0.7:2") and not _dask.declared_own("tcp://10.0.0.8:2")
    for bad in ("", "  ", None, _fake(None)):
        with pytest.raises(hevr.ParameterError, match="client_or_address"):
            hevr.own_cluster(bad)


def test_the_refusal_names_the_scheduler_the_reason_and_both_ways_out():
    with pytest.raises(hevr.ForeignClusterError) as info:
        _dask.refuse_foreign_cluster(_fake("tcp://127.0.0.1:8786"), "decrypting")
    err = info.value
    assert isinstance(err, hevr.HevrError) and isinstance(err, PermissionError)
    text = str(err)
    assert text.startswith("client: expected ")
    for part in (
        "tcp://127.0.0.1:8786",
        "while decrypting",
        "unpickles",
        "private key",
        "hevr.connect(URL)",
        "hevr serve",
        "hevr.own_cluster(client)",
        "HEVR_OWN_CLUSTER=tcp://127.0.0.1:8786",
    ):
        assert part in text, part


def test_warn_if_remote_has_no_prefix_guessing():
    with pytest.warns(UserWarning, match="did not start"):
        _dask.warn_if_remote(_fake("tcp://localhost:8786"))
    hevr.own_cluster("tcp://127.0.0.1:9")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _dask.warn_if_remote(_fake("tcp://127.0.0.1:9"))  # declared: nothing to say


# -- a scheduler in a separate process, on loopback: the tunnel case --------------------------------
@pytest.fixture(scope="module")
def other_scheduler():
    proc = subprocess.Popen([sys.executable, "-c", SCHEDULER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        address = proc.stdout.readline().strip()
        assert address.startswith("tcp://127.0.0.1:"), address
        yield address
    finally:
        proc.stdin.close()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:  # pragma: no cover
            proc.kill()


def test_a_loopback_scheduler_of_another_process_is_refused_until_declared(other_scheduler, keypair256, tmp_path):
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    with Client(other_scheduler, set_as_default=False, timeout="20s") as client:
        assert client.cluster is None
        with pytest.raises(hevr.ForeignClusterError, match=r"hevr\.connect") as info:
            hevr.encrypt_volume(np.zeros((2, 2, 2), np.uint8), str(path), priv, brick=2, progress=False, client=client)
        assert other_scheduler in str(info.value)
        assert not path.exists()  # refused before anything was written
        with client.as_current():  # the active client is the one checked when none is given
            with pytest.raises(hevr.ForeignClusterError):
                _dask.refuse_foreign_cluster()
            assert hevr.own_cluster(client) == other_scheduler
            _dask.refuse_foreign_cluster()
        assert _dask.is_own_cluster(client)


# -- for real: an in-process cluster joined by address, then declared ---------------------------------
def test_encrypting_with_the_private_key_needs_the_opt_in(joined, keypair256, tmp_path):
    pub, priv = keypair256
    vol = np.arange(8, dtype=np.uint8).reshape(2, 2, 2)
    with pytest.raises(hevr.ForeignClusterError, match=r"hevr\.own_cluster"):
        hevr.encrypt_volume(vol, str(tmp_path / "a.zarr"), priv, brick=2, progress=False, client=joined)
    assert not (tmp_path / "a.zarr").exists()
    hevr.own_cluster(joined)
    ev = hevr.encrypt_volume(vol, str(tmp_path / "a.zarr"), priv, brick=2, progress=False, client=joined)
    assert priv.decrypt_array(ev.read_brick((0, 0, 0))) == [int(v) for v in vol.ravel()]


def test_public_key_encryption_is_warned_of_not_refused(joined, keypair256, tmp_path, caplog):
    pub, _ = keypair256
    with caplog.at_level(logging.WARNING, logger="hevr.store.writer"):
        hevr.encrypt_volume(
            np.zeros((2, 2, 2), np.uint8), str(tmp_path / "p.zarr"), pub, brick=2, progress=False, client=joined
        )
    assert any("plaintext bricks" in r.getMessage() and "did not start" in r.getMessage() for r in caplog.records)


def test_render_frame_refuses_a_foreign_client_before_rendering(joined, keypair256, tmp_path):
    pub, priv = keypair256
    ev = hevr.encrypt_volume(hevr.phantom(4), str(tmp_path / "f.zarr"), priv, brick=4, progress=False)
    cam = hevr.Camera.orbit(ev, width=3, height=3)
    with pytest.raises(hevr.ForeignClusterError, match="render_frame"):
        hevr.render_frame(ev, cam, priv, client=joined, progress=False)


def test_a_cluster_object_made_here_keeps_working(tcp_cluster, keypair256, tmp_path):
    pub, priv = keypair256
    with Client(tcp_cluster, set_as_default=False) as client:  # the README's Client(LocalCluster(...))
        assert client.cluster is tcp_cluster
        ev = hevr.encrypt_volume(
            hevr.phantom(4), str(tmp_path / "c.zarr"), priv, brick=4, progress=False, client=client
        )
        frame = hevr.render_frame(ev, hevr.Camera.orbit(ev, width=3, height=3), priv, client=client, progress=False)
    assert frame.image.shape[:2] == (3, 3)


# -- the command line ---------------------------------------------------------------------------
def test_cli_own_cluster_needs_a_scheduler():
    from hevr.cli.cluster import dask_client
    from hevr.cli.util import UsageError

    with pytest.raises(UsageError, match="--own-cluster"):
        with dask_client(None, 1, own=True):
            pass  # pragma: no cover


def test_cli_own_cluster_declares_the_joined_scheduler(tcp_cluster):
    from hevr.cli.cluster import dask_client

    with dask_client(tcp_cluster.scheduler_address, own=True) as client:
        assert client.cluster is None and _dask.is_own_cluster(client)
