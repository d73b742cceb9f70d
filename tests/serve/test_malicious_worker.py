"""A malicious server operator's cluster cannot reach the key holder's process.

The attack that took the private key through the local Dask path: a worker plugin of a few lines
answers every data request with an object whose unpickling runs code. Here the same plugin runs on
the cluster behind ``hevr serve``; the code does run — in the server's process, the cluster's
client — and the key holder, who talks to the server only through :mod:`hevr.remote`, gets a clean
:class:`hevr.HevrError` or a correct image, with ``pickle`` refused in its process throughout.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import hevr
from hevr.remote import connect

CLUSTER = textwrap.dedent('''
    import sys, time
    from distributed import Client, LocalCluster
    from distributed.diagnostics.plugin import WorkerPlugin

    MARK = sys.argv[1]

    class Evil:
        """Unpickling it runs code: it appends the unpickling process's pid to MARK."""
        def __reduce__(self):
            return (exec, ("import os\\nopen(%r, 'a').write(str(os.getpid()) + '\\\\n')" % MARK,))

    class Plugin(WorkerPlugin):
        def setup(self, worker):
            from distributed.core import Status
            from distributed.protocol import to_serialize

            async def get_data(comm, keys=(), who=None, serializers=None):
                await comm.write({"status": "OK", "data": {k: to_serialize(Evil()) for k in keys}},
                                 serializers=serializers)
                try:
                    await comm.read(deserializers=serializers)
                except Exception:
                    pass
                return Status.dont_reply

            worker.handlers["get_data"] = get_data

    if __name__ == "__main__":
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
        client.register_plugin(Plugin())
        print(cluster.scheduler_address, flush=True)
        sys.stdin.read()  # until the test closes our stdin
        client.close()
        cluster.close()
''')


@pytest.fixture
def hostile(tmp_path, served_store):
    from _serving import hevr_serve

    script = tmp_path / "cluster.py"
    script.write_text(CLUSTER)
    mark = tmp_path / "pwned"
    proc = subprocess.Popen(
        [sys.executable, str(script), str(mark)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        address = proc.stdout.readline().strip()
        assert address.startswith("tcp://"), address
        with hevr_serve(str(served_store.dir / "v.zarr"), "--scheduler", address) as (url, server, lines):
            yield url, mark, server, lines
    finally:
        proc.stdin.close()
        proc.wait(30)


def test_a_malicious_cluster_never_runs_code_in_the_key_holder(served_store, hostile, monkeypatch):
    served = served_store
    url, mark, server, lines = hostile
    from _serving import refuse_unpickling

    ran_here = refuse_unpickling(monkeypatch)
    rv = connect(url, timeout=120).open(served.ev.meta.store_id)
    outcomes = []
    for az in (11,):
        cam = hevr.Camera.orbit(rv, azimuth=az, width=10, height=10)
        try:
            img = hevr.render(rv, cam, sampling="trilinear", progress=False)
            arr = img.decrypt(served.priv)  # a correct image, verified
            ref = hevr.render_plain(served.vol, cam, sampling="trilinear")
            assert (np.abs(arr - ref) <= hevr.error_bound(served.ev, cam, sampling="trilinear")).all()
            outcomes.append("image")
        except hevr.HevrError as exc:
            outcomes.append(type(exc).__name__)
    assert not ran_here
    assert mark.exists(), "the attack never ran: the test would prove nothing"
    pids = {int(x) for x in mark.read_text().split()}
    assert os.getpid() not in pids  # it ran on the server side only
    # a lie caught by the key holder: the client's checks (RemoteAnswerError), the server's own check of
    # the store (RemoteError: 500), or the frame's verification at decryption
    assert set(outcomes) <= {"image", "RemoteError", "RemoteAnswerError", "IntegrityError", "VerificationError"}, (
        outcomes
    )
