"""hevr.runtime.scheduler: the one-time warning when the key holder is a Dask client of another machine's scheduler."""

from __future__ import annotations

import types
import warnings

import pytest

from hevr.runtime import scheduler as _dask


def _client(address):
    return types.SimpleNamespace(scheduler=types.SimpleNamespace(address=address))


def test_remote_scheduler_warns_once_naming_connect():
    with pytest.warns(UserWarning, match=r"hevr\.connect") as rec:
        _dask.warn_if_remote(_client("tcp://10.20.30.40:8786"))
    assert "10.20.30.40" in str(rec[0].message) and "hevr.own_cluster" in str(rec[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _dask.warn_if_remote(_client("tcp://10.20.30.40:8786"))  # once per scheduler
        _dask.warn_if_remote(_client("inproc://192.168.1.1/1/2"))  # only this process reaches an inproc address
        _dask.warn_if_remote(None)
    # a loopback address may be an ssh tunnel to another party's cluster: not trusted by its spelling
    for tunnel in ("tcp://127.0.0.1:8786", "tcp://localhost:1", "tcp://[::1]:8786", "tls://scheduler.example.org:8786"):
        with pytest.warns(UserWarning, match="did not start"):
            _dask.warn_if_remote(_client(tunnel))


def test_render_on_a_local_cluster_does_not_warn(cluster, keypair256, tmp_path):
    import hevr

    ev = hevr.encrypt_volume(hevr.phantom(6), str(tmp_path / "v.zarr"), keypair256[1], brick=6, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        hevr.render(ev, hevr.Camera.orbit(ev, width=4, height=4), client=cluster, progress=False)


def _interrupt_main_in(seconds: float) -> None:
    """A real SIGINT to the main thread after ``seconds`` (as a terminal's Ctrl-C)."""
    import signal
    import threading

    main = threading.main_thread().ident
    threading.Timer(seconds, lambda: signal.pthread_kill(main, signal.SIGINT)).start()


def test_ctrl_c_stops_the_running_tasks_of_the_threaded_scheduler():
    """Issue 39, item 5: the pool was waited for until its running tasks ended (13 s for a
    brick); a task that checks hevr.runtime.cancel now stops at its next check."""
    import time

    import dask

    from hevr.runtime import cancel

    def long_task(i):
        end = time.monotonic() + 30
        while time.monotonic() < end:
            cancel.check()
            time.sleep(0.01)
        return i

    _interrupt_main_in(0.5)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        _dask.compute([dask.delayed(long_task)(i) for i in range(2)], progress=False)
    assert time.monotonic() - t0 < 3
    assert cancel.stopped()
    assert _dask.compute([dask.delayed(lambda: 7)()], progress=False) == [7]  # a new job runs again
    assert not cancel.stopped()


@pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")
def test_an_interrupted_encryption_stops_within_a_second_and_resumes(tmp_path, keypair256, monkeypatch):
    """encrypt_volume stops soon after Ctrl-C, though its one brick needs seconds (each batch of
    values slowed to 0.2 s here); resume=True finishes the store, and it decrypts to the volume."""
    import time

    import numpy as np

    import hevr
    from hevr.crypto.keys import PublicKey

    pub, priv = keypair256
    slow = PublicKey.encrypt_array

    def encrypt_array(self, values, **kw):
        time.sleep(0.2)
        return slow(self, values, **kw)

    monkeypatch.setattr(PublicKey, "encrypt_array", encrypt_array)
    vol = hevr.phantom(12)
    path = str(tmp_path / "v.zarr")
    _interrupt_main_in(0.5)
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        hevr.encrypt_volume(vol, path, pub, brick=12, progress=False)  # 27 batches of 64: > 5.4 s
    assert time.monotonic() - t0 < 2.5
    with pytest.raises(hevr.IncompleteStoreError, match="resume=True"):
        hevr.open_volume(path)
    ev = hevr.encrypt_volume(vol, path, priv, brick=12, progress=False, resume=True)
    img = hevr.render_slice(ev, hevr.Plane.axial(ev, 5), progress=False)
    assert np.array_equal(img.decrypt(priv), vol[5])


def test_a_workers_steps_are_one_event_a_quarter_second_and_none_lost(cluster):
    """Issue 49: a task's steps inside batched_steps reach the client as one worker event per
    STEP_INTERVAL (0.25 s) and the rest when the block ends, not one per batch: the 147,000
    events of a 72 MiB volume cost the scheduler's time and, while it fell behind, the workers'
    memory. The sum is exact: the client's display counts every step."""
    import time

    import dask

    from hevr.runtime import cancel

    def task():
        with cancel.batched_steps():
            for _ in range(100):
                cancel.add_steps(3)
                time.sleep(0.005)  # 0.5 s or more of steps: 2-3 events and the rest
        return 1

    before = len(cluster.get_events(cancel.TOPIC))
    assert _dask.compute([dask.delayed(task, pure=False)()], client=cluster, progress=False) == [1]
    events = [msg for _, msg in cluster.get_events(cancel.TOPIC)[before:]]
    assert sum(events) == 300 and 1 <= len(events) < 25, events  # 2-4 measured; one per batch: 100


def test_workers_of_asks_the_scheduler_and_works_with_an_identity_without_arguments():
    """workers_of lists the cluster's workers; a scheduler of distributed < 2025.4, whose identity()
    takes no n_workers (and lists every worker), is asked without it."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, processes=False, threads_per_worker=1, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            assert len(_dask.workers_of(client)) == 2
            real = cluster.scheduler.handlers["identity"]
            asked = []

            def old_identity():  # the signature of distributed < 2025.4
                asked.append(True)
                return real()

            cluster.scheduler.handlers["identity"] = old_identity
            try:
                assert sorted(_dask.workers_of(client)) == sorted(cluster.scheduler.workers)
            finally:
                cluster.scheduler.handlers["identity"] = real
            assert asked
