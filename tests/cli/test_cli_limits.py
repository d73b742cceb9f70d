"""The command line refuses impossible work at once: one ``hevr: error:`` line naming the
option, exit 2 (a usage error, whether argparse or the planner refuses it), and no cluster
started for a render that would be refused anyway."""

from __future__ import annotations

import time
import warnings

import dask
import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.cli.options import MAX_PHANTOM, MAX_WORKERS
from hevr.cli.render_options import size_type
from hevr.rendering.planning.planner import MAX_PIXELS_KEY

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def run(capsys, *argv: object) -> tuple[int, str, float]:
    t0 = time.perf_counter()
    code = main([str(a) for a in argv])
    seconds = time.perf_counter() - t0
    _, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("hevr: error:"), err
    return code, lines[0], seconds


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        pub, _ = hevr.generate_keypair(128)
    path = tmp_path_factory.mktemp("clilim") / "v.zarr"
    pub.save(path.parent / "k.pub.json")
    hevr.encrypt_volume(np.zeros((6, 6, 6), np.uint8), path, pub, brick=3, progress=False)
    return path


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["render", "v.zarr", "--out", "f.hevr", "--size", "16384x16384"], "--size: expected WIDTHxHEIGHT of at most"),
        (["render", "v.zarr", "--out", "f.hevr", "--size", "1x100000000"], "--size"),
        (["render", "v.zarr", "--out", "f.hevr", "--size", "١٥٠x١٥٠"], "--size"),
        (["demo", "--image", "20000x20000"], "--image"),
        (["demo", "--size", str(MAX_PHANTOM + 1)], "--size: expected a phantom edge"),
        (["encrypt", "phantom:8", "--key", "k", "--out", "o", "--brick", "100000"], "--brick: expected a brick edge"),
        (["encrypt", "phantom:8", "--key", "k", "--out", "o", "--brick", "2,2,5000"], "--brick"),
        (["encrypt", "phantom:8", "--key", "k", "--out", "o", "--workers", str(MAX_WORKERS + 1)], "--workers"),
        (["encrypt", "phantom:8", "--key", "k", "--out", "o", "--digits", "1000"], "--digits: expected an integer"),
        (
            ["encrypt", "phantom:8", "--key", "k", "--out", "o", "--digits", "31"],
            "--digits: expected an integer in [0, 30]",
        ),
        (["encrypt", "phantom:8", "--key", "k", "--out", "o", "--vector-dims", "100000"], "--vector-dims: expected"),
    ],
)
def test_absurd_options_are_usage_errors(capsys, argv, needle):
    code, line, seconds = run(capsys, *argv)
    assert code == 2 and needle in line and seconds < 1.0


def test_size_cap_follows_the_config():
    assert size_type("10x10") == (10, 10) and size_type("7") == (7, 7)
    with dask.config.set({MAX_PIXELS_KEY: 100}):
        assert size_type("10x10") == (10, 10)
        with pytest.raises(Exception, match="at most 100 pixels"):
            size_type("11x10")


@pytest.mark.parametrize("spec", ["phantom:100000", "phantom:3", "phantom:٨"])
def test_absurd_phantom_is_refused_before_allocating(capsys, tmp_path, store, spec):
    key = store.parent / "k.pub.json"
    code, line, seconds = run(capsys, "encrypt", spec, "--key", key, "--out", tmp_path / "o.zarr")
    assert code == 2 and line.startswith("hevr: error: INPUT: expected phantom:N with an integer N in [4, 1024]")
    assert seconds < 1.0


@pytest.mark.parametrize(
    "extra, needle",
    [(["--step", "1e-9"], "--step: expected at most"), (["--step", "1e-300"], "--step: expected at most")],
)
def test_render_refuses_before_starting_a_cluster(capsys, tmp_path, store, extra, needle):
    code, line, seconds = run(
        capsys, "render", store, "--out", tmp_path / "f.hevr", "--workers", "2", "--size", "32x32", *extra
    )
    assert code == 2 and needle in line
    assert seconds < 1.0  # a 2-worker LocalCluster alone takes longer to start
    assert not (tmp_path / "f.hevr").exists()


@pytest.mark.parametrize("cores", [2, 1, None])
def test_workers_far_above_the_cores_are_refused(capsys, monkeypatch, cores):
    """--workers 1000 on 2 cores was accepted and never finished: the message says what is
    allowed and what the machine has."""
    from hevr.cli import options

    monkeypatch.setattr(options.os, "cpu_count", lambda: cores)
    limit = 4 * (cores or 1)
    assert options.workers_type(str(limit)) == limit and options.workers_type("0") == 0
    code, line, seconds = run(capsys, "encrypt", "phantom:8", "--key", "k", "--out", "o", "--workers", "1000")
    has = {2: "this machine has 2 CPU cores", 1: "this machine has 1 CPU core", None: "its core count is unknown"}
    assert code == 2 and seconds < 1.0
    assert line == (
        f"hevr: error: argument --workers: expected at most {limit} worker processes (0: none; 4 per "
        f"CPU core, and {has[cores]}), got '1000' (see 'hevr encrypt --help')"
    ), line
    code, line, _ = run(capsys, "encrypt", "phantom:8", "--key", "k", "--out", "o", "--workers", str(limit + 1))
    assert code == 2 and f"expected at most {limit} worker processes" in line
