"""Issue 24, items 2 and 6 (stores): of several concurrent creators of one store exactly one
wins and its store is intact, the others get StoreExistsError; concurrent overwrites never mix
two stores; a store being written is neither resumed twice nor swapped out; names near the
filesystem's limit stay overwritable; filesystem refusals are FileSystemError naming the store
and the operation; a local path with an unknown ``scheme://`` is a ParameterError."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import hevr
import hevr.store.creation as creation
import hevr.store.exclusive as exclusive
from hevr.store.exclusive import lock_store

SHAPE, BRICK = (4, 4, 3), 2


def _vol(i: int) -> np.ndarray:
    return np.full(SHAPE, i, np.uint8)


def _value(ev, priv) -> set[int]:
    """The distinct plaintext values of a (fully verified) store."""
    ev = hevr.open_volume(ev.path if hasattr(ev, "path") else ev, verify="full")
    out = set()
    for idx in np.ndindex(*ev.grid):
        out |= set(int(v) for v in priv.decrypt_array(ev.read_brick(idx)))
    return out


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def _race(n: int, target, *args) -> list:
    """Run ``target(i, *args)`` in ``n`` threads released at once; each result or exception."""
    barrier = threading.Barrier(n)
    out: list = [None] * n

    def run(i: int) -> None:
        barrier.wait()
        try:
            out[i] = target(i, *args)
        except BaseException as exc:  # noqa: BLE001 - collected and checked by the test
            out[i] = exc

    threads = [threading.Thread(target=run, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


def _check_one_winner(results: list, path, priv) -> None:
    winners = [i for i, r in enumerate(results) if isinstance(r, hevr.EncryptedVolume)]
    others = [r for r in results if not isinstance(r, hevr.EncryptedVolume)]
    assert len(winners) == 1, results
    assert all(isinstance(r, hevr.StoreExistsError) for r in others), [
        (type(r).__name__, str(r)[-300:]) for r in others
    ]
    assert _value(path, priv) == {winners[0] + 1}  # the winner's own volume, every digest checked
    assert hevr.open_volume(path).meta.store_id == results[winners[0]].meta.store_id


def test_concurrent_creators_in_threads_one_wins(tmp_path, keypair256):
    pub, priv = keypair256
    for rnd in range(6):
        path = tmp_path / f"v{rnd}.zarr"
        results = _race(
            4, lambda i, path=path: hevr.encrypt_volume(_vol(i + 1), path, pub, brick=BRICK, progress=False)
        )
        _check_one_winner(results, path, priv)
        assert _hidden(tmp_path) == []  # the losers left nothing behind


def test_concurrent_creators_of_a_memory_url_one_wins(keypair256):
    pub, priv = keypair256
    for rnd in range(4):
        url = f"memory://hevr-test-exclusive-{os.getpid()}-{rnd}/v.zarr"
        results = _race(4, lambda i, url=url: hevr.encrypt_volume(_vol(i + 1), url, pub, brick=BRICK, progress=False))
        _check_one_winner(results, url, priv)


_CREATOR = textwrap.dedent("""
    import os, sys, time, warnings
    import numpy as np
    import hevr
    key, path, go, i = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pub = hevr.load_key(key).public_key
    while not os.path.exists(go):
        time.sleep(0.001)
    try:
        hevr.encrypt_volume(np.full((4, 4, 3), i, np.uint8), path, pub, brick=2, progress=False)
        print("WON")
    except hevr.StoreExistsError as exc:
        print("LOST", exc)
""")


@pytest.mark.slow
def test_concurrent_creators_in_processes_one_wins(tmp_path, keypair256):
    pub, priv = keypair256
    priv.save(tmp_path / "key.json")
    for rnd in range(3):
        path, go = tmp_path / f"v{rnd}.zarr", tmp_path / f"go{rnd}"
        procs = [
            subprocess.Popen(
                [sys.executable, "-c", _CREATOR, str(tmp_path / "key.json"), str(path), str(go), str(i + 1)],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for i in range(3)
        ]
        time.sleep(1.0)  # the imports
        go.touch()
        outs = [p.communicate(timeout=120) for p in procs]
        assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
        won = [i for i, (out, _) in enumerate(outs) if out.startswith("WON")]
        assert len(won) == 1 and sum(out.startswith("LOST") for out, _ in outs) == 2, outs
        assert _value(path, priv) == {won[0] + 1}
        assert _hidden(tmp_path) == []


def test_concurrent_overwrites_never_mix_two_stores(tmp_path, keypair256):
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(9), path, pub, brick=BRICK, progress=False)
    for _ in range(3):
        results = _race(
            3, lambda i: hevr.encrypt_volume(_vol(i + 1), path, pub, brick=BRICK, progress=False, overwrite=True)
        )
        ok = [i for i, r in enumerate(results) if isinstance(r, hevr.EncryptedVolume)]
        assert ok and all(isinstance(r, hevr.StoreExistsError) for i, r in enumerate(results) if i not in ok), results
        final = hevr.open_volume(path)
        assert final.meta.store_id in {results[i].meta.store_id for i in ok}  # one of the successful runs'
        winner = next(i for i in ok if results[i].meta.store_id == final.meta.store_id)
        assert _value(path, priv) == {winner + 1}
        assert _hidden(tmp_path) == []


def test_a_store_being_written_is_neither_resumed_nor_replaced(tmp_path, keypair256):
    pub, _ = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    before = hevr.open_volume(path).meta.store_id
    with lock_store(path):  # what a running encrypt_volume holds
        for kw in ({"resume": True}, {"overwrite": True}):
            with pytest.raises(hevr.StoreExistsError, match="being written by another run"):
                hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False, **kw)
    assert hevr.open_volume(path).meta.store_id == before
    assert _hidden(tmp_path) == []


def test_the_loser_of_the_final_rename_leaves_nothing(tmp_path, keypair256, monkeypatch):
    """The claim itself: a store appears at the path between the check and the rename."""
    pub, _ = keypair256
    path = tmp_path / "v.zarr"
    real = exclusive.rename_noreplace

    def late(src, dst):
        if Path(dst) == path:
            os.mkdir(path)  # another creator won just now
        return real(src, dst)

    monkeypatch.setattr("hevr.store.creation.rename_noreplace", late)
    with pytest.raises(hevr.StoreExistsError, match="created by another run at the same time"):
        hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    assert os.listdir(path) == [] and _hidden(tmp_path) == []


def test_rename_noreplace_without_renameat2(tmp_path, monkeypatch):
    monkeypatch.setattr(exclusive, "_RENAMEAT2", None)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "f").write_text("x")
    exclusive.rename_noreplace(tmp_path / "a", tmp_path / "b")
    assert (tmp_path / "b" / "f").read_text() == "x"
    (tmp_path / "c").mkdir()
    with pytest.raises(FileExistsError):
        exclusive.rename_noreplace(tmp_path / "c", tmp_path / "b")
    assert (tmp_path / "c").is_dir() and (tmp_path / "b" / "f").exists()


def test_a_name_near_the_limit_is_created_and_overwritten(tmp_path, keypair256):
    pub, priv = keypair256
    path = tmp_path / ("v" * 245 + ".zarr")  # 250 bytes: the temporary siblings get a hashed stem
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    ev = hevr.encrypt_volume(_vol(2), path, pub, brick=BRICK, progress=False, overwrite=True)
    assert _value(ev, priv) == {2}
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


@pytest.mark.parametrize("text", ["x://y", "dir/a://b.zarr", "S3://bucket/v.zarr"])
def test_a_path_with_an_unknown_scheme_is_a_parameter_error(tmp_path, keypair256, monkeypatch, text):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(hevr.ParameterError, match=r"^path: expected a local path or an fsspec URL .*no protocol"):
        hevr.encrypt_volume(_vol(1), text, keypair256[0], brick=BRICK, progress=False)
    with pytest.raises(hevr.ParameterError, match=r"^path: "):
        hevr.open_volume(text)
    assert list(tmp_path.iterdir()) == []


def test_a_read_only_filesystem_is_named_when_creating(tmp_path, keypair256, monkeypatch):
    def refuse(path, *a, **k):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    monkeypatch.setattr(exclusive.os, "mkdir", refuse)
    with pytest.raises(hevr.FileSystemError) as err:
        hevr.encrypt_volume(_vol(1), tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False)
    assert err.value.errno == errno.EROFS and isinstance(err.value, OSError)
    assert str(err.value).startswith("creating the store ") and str(err.value).endswith("Read-only file system (EROFS)")


def test_a_full_disk_inside_the_tasks_is_a_filesystem_error(tmp_path, keypair256, monkeypatch):
    """ENOSPC raised while a task writes a chunk: one FileSystemError, no value of the volume."""
    import zarr.storage._local as local

    real = local._put

    def full(path, value, exclusive=False):
        if "/c/" in str(path):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, value, exclusive)

    monkeypatch.setattr(local, "_put", full)
    vol = np.full(SHAPE, 217, np.uint8)
    with pytest.raises(hevr.FileSystemError) as err:
        hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False)
    assert err.value.errno == errno.ENOSPC
    assert "writing a brick of the store" in str(err.value) and "(ENOSPC)" in str(err.value)
    assert "217" not in str(err.value).replace(str(tmp_path), "")


@pytest.mark.parametrize("where", ["not_a_dir", "too_long"])
def test_impossible_local_paths_are_filesystem_errors(tmp_path, keypair256, where):
    (tmp_path / "file.txt").write_text("x")
    path = tmp_path / "file.txt" / "v.zarr" if where == "not_a_dir" else tmp_path / ("v" * 300)
    with pytest.raises(hevr.FileSystemError) as err:
        hevr.encrypt_volume(_vol(1), path, keypair256[0], brick=BRICK, progress=False)
    assert err.value.errno == (errno.ENOTDIR if where == "not_a_dir" else errno.ENAMETOOLONG)
    assert str(path) in str(err.value)


def _open_fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc/self/fd")
def test_a_failing_lock_leaks_no_descriptor_and_no_folder(tmp_path, monkeypatch):
    """flock refused by the filesystem (an errno that is not 'no locks here'): the descriptors
    opened for the lock are closed and the fresh temporary folder is removed."""

    def refuse(fd, op):
        raise OSError(errno.EIO, "Input/output error")

    store = tmp_path / "s"
    store.mkdir()
    before = _open_fds()
    monkeypatch.setattr(exclusive.fcntl, "flock", refuse)
    with pytest.raises(OSError, match="Input/output error"):
        lock_store(store)
    with pytest.raises(OSError, match="Input/output error"):
        exclusive.locked_folder(tmp_path / "v.zarr", "tmp")
    monkeypatch.undo()
    assert _open_fds() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


def test_a_creator_never_takes_the_path_that_a_swap_has_just_emptied(tmp_path, keypair256, monkeypatch):
    """Between a swap's two renames the path is missing for an instant: a creator that looked
    then (and found nothing) must not put its store there while the old one is aside (it
    would be lost: the swap could not put either store back). The creator's final rename
    waits for the folder's swap lock, then finds the path taken."""
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol(1), path, pub, brick=BRICK, progress=False)
    aside = tmp_path / ".v.zarr.aside"
    waiting, box = threading.Event(), {}
    real = exclusive.swap_lock

    def swap_lock(p):
        waiting.set()
        return real(p)

    monkeypatch.setattr(creation, "swap_lock", swap_lock, raising=False)

    def create():
        try:
            box["result"] = hevr.encrypt_volume(_vol(2), path, pub, brick=BRICK, progress=False)
        except BaseException as exc:  # noqa: BLE001 - checked below
            box["result"] = exc

    with real(path):  # a swap, between its two renames
        path.rename(aside)
        t = threading.Thread(target=create, daemon=True)
        t.start()
        for _ in range(1200):
            if waiting.is_set() or not t.is_alive():
                break
            time.sleep(0.1)
        assert not path.exists(), "the creator put its store where the swapped-out store belongs"
        aside.rename(path)  # the swap puts a store back
    t.join(120)
    assert isinstance(box.get("result"), hevr.StoreExistsError), box
    assert _value(path, priv) == {1}
    assert _hidden(tmp_path) == []
