"""The Dask dashboard works with the ``dashboard`` extra (bokeh >= 3.1, also in the test and
notebook extras): its status page is served, not distributed's "needs bokeh" placeholder."""

from __future__ import annotations

import urllib.request

import bokeh
from distributed import Client, LocalCluster
from packaging.version import Version


def test_bokeh_is_recent_enough():
    assert Version(bokeh.__version__) >= Version("3.1.0")


def test_the_dashboard_serves_its_status_page():
    with (
        LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address="127.0.0.1:0") as lc,
        Client(lc, set_as_default=False) as client,
    ):
        assert client.dashboard_link.endswith("/status")
        port = lc.scheduler.http_server.port
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/status", timeout=30) as resp:
            page = resp.read().decode("utf-8", "replace")
            assert resp.status == 200
    assert "bokeh" in page.lower()  # the Bokeh application's page
    assert "pip install" not in page and "requires" not in page.lower()
