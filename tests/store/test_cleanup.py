"""Issue 24, item 7: a failed or killed overwrite leaves nothing that later writes keep (the
next write to the path removes temporaries whose writer is gone, never a live one, never the
only copies after an interrupted swap), and the clean-up after a failure waits for the tasks
still writing, so nothing reappears and only the original error escapes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import dask
import numpy as np
import pytest

import hevr
import hevr.store.brick_write as store_mod  # the encryption tasks: where a brick's digest is taken
import hevr.store.upgrade as upgrade_mod
from hevr.core.siblings import held_lock, temp_sibling

SHAPE, BRICK = (4, 4, 6), 2


def _vol(i: int) -> np.ndarray:
    return np.full(SHAPE, i, np.uint8)


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _leftover(path: Path, what: str) -> Path:
    t = temp_sibling(path, what)
    (t / "scalar" / "c").mkdir(parents=True)
    (t / "scalar" / "c" / "0").write_bytes(b"\0" * 1000)
    return t


def test_stale_temporaries_are_removed_by_the_next_write_but_not_live_ones(tmp_path, keypair256):
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    stale = [_leftover(path, w) for w in ("new", "old", "tmp")]
    old_style = tmp_path / ".v.zarr.hevr-new-0123abcd"  # the name earlier versions gave
    old_style.mkdir()
    live = _leftover(path, "new")
    with held_lock(live):  # another overwrite is writing this one right now
        ev = hevr.encrypt_volume(_vol(2), path, pub, brick=BRICK, progress=False, overwrite=True)
    assert _names(tmp_path) == sorted(["v.zarr", live.name])
    assert not any(t.exists() for t in stale) and not old_style.exists()
    assert set(priv.decrypt_array(ev.read_brick((0, 0, 0)))) == {2}


def test_after_an_interrupted_swap_both_stores_are_kept(tmp_path, keypair256):
    """Killed between the two renames: nothing at the path, old and new beside it, complete."""
    pub, _ = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    old = temp_sibling(path, "old")
    path.rename(old)
    new = _leftover(path, "new")
    with pytest.raises(hevr.MissingFileError, match="interrupted overwrite left"):
        hevr.open_volume(path)
    hevr.encrypt_volume(_vol(2), tmp_path / "w.zarr", pub, brick=BRICK, progress=False)  # another path
    assert old.exists() and new.exists()
    old.rename(path)  # the user restores one
    hevr.open_volume(path)


_KILLED = textwrap.dedent("""
    import sys, time, warnings
    import dask, numpy as np
    import hevr, hevr.store.writer as w
    real = w._encrypt_brick
    def slow(*a, **k):
        print("writing", flush=True)
        time.sleep(0.5)
        return real(*a, **k)
    w._encrypt_brick = slow
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pub = hevr.load_key(sys.argv[1]).public_key
    with dask.config.set(scheduler="synchronous"):
        hevr.encrypt_volume(np.zeros((4, 4, 6), np.uint8), sys.argv[2], pub, brick=2, progress=False,
                            overwrite=True)
""")


def test_an_overwrite_killed_with_sigkill_is_cleaned_up_by_the_next_one(tmp_path, keypair256):
    pub, priv = keypair256
    priv.save(tmp_path / "key.json")
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED, str(tmp_path / "key.json"), str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)
    left = [n for n in _names(tmp_path) if n.startswith(".v.zarr.hevr-new-")]
    assert len(left) == 1  # what issue 24 saw: gigabytes at 2048 bits, never removed
    assert set(priv.decrypt_array(hevr.open_volume(path).read_brick((0, 0, 0)))) == {1}
    hevr.encrypt_volume(_vol(3), path, pub, brick=BRICK, progress=False, overwrite=True)
    assert _names(tmp_path) == ["key.json", "v.zarr"]


def _fail_one_while_others_write(monkeypatch, module, delay: float = 0.3) -> set:
    """Inside the tasks, between opening the new store and writing a brick (where the brick's
    digest is taken): brick (0, 0, 0) fails at once, every other one sleeps first. Returns the
    set of bricks whose task is inside that window right now."""
    real = module.brick_digest
    running: set = set()

    def digest(store_id, channel, index, data):
        if tuple(index) == (0, 0, 0):
            raise RuntimeError("brick failed")
        running.add(tuple(index))
        try:
            time.sleep(delay)
            return real(store_id, channel, index, data)
        finally:
            running.discard(tuple(index))

    monkeypatch.setattr(module, "brick_digest", digest)
    return running


def test_a_failed_overwrite_waits_for_the_tasks_in_flight(tmp_path, keypair256, monkeypatch):
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    running = _fail_one_while_others_write(monkeypatch, store_mod)
    with dask.config.set(num_workers=4), pytest.raises(RuntimeError, match="^brick failed$"):
        try:
            hevr.encrypt_volume(_vol(2), path, pub, brick=BRICK, progress=False, overwrite=True)
        finally:
            assert not running  # no task was still writing while the partial store was removed
    time.sleep(0.6)
    assert _names(tmp_path) == ["v.zarr"]
    assert set(priv.decrypt_array(hevr.open_volume(path, verify="full").read_brick((1, 1, 1)))) == {1}


def test_a_failed_overwrite_on_a_cluster_leaves_nothing(tmp_path, keypair256, monkeypatch, cluster):
    pub, _ = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    running = _fail_one_while_others_write(monkeypatch, store_mod, delay=0.1)
    with pytest.raises(RuntimeError, match="^brick failed$"):
        hevr.encrypt_volume(_vol(2), path, pub, brick=BRICK, progress=False, overwrite=True, client=cluster)
    assert not running
    time.sleep(0.3)
    assert _names(tmp_path) == ["v.zarr"]


def test_a_failed_upgrade_waits_for_the_tasks_in_flight(tmp_path, keypair256, monkeypatch):
    from test_upgrade import _v1_store  # the format-1 layout, built as the old writer did

    _v1_store(tmp_path / "old.zarr", keypair256[0], np.zeros((5, 6, 7), np.uint8))
    running = _fail_one_while_others_write(monkeypatch, upgrade_mod)
    with dask.config.set(num_workers=4), pytest.raises(RuntimeError, match="^brick failed$"):
        try:
            hevr.upgrade_store(tmp_path / "old.zarr", tmp_path / "new.zarr", progress=False)
        finally:
            assert not running
    time.sleep(0.6)
    assert _names(tmp_path) == ["old.zarr"]
