"""The on-disk cache of the host builds (hevr.backends.cuda.kernel_cache): a damaged cache is
rebuilt, never loaded (issue 39, item 1); a stuck compiler is stopped, its whole process group
with it (item 2)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import dask
import pytest

from hevr import MissingDependencyError, backends
from hevr.backends.cuda import host as host_module
from hevr.backends.cuda import kernel_cache

pytestmark = pytest.mark.skipif(not hasattr(os, "getuid") or not hasattr(os, "mkfifo"), reason="POSIX owners, FIFOs")

SOURCE = "int hevr_answer(void) { return 42; }\n"


@pytest.fixture
def tmpdir_cache(monkeypatch, tmp_path):
    """A fresh per-process library table and a temporary directory of its own; returns the
    would-be cache folder and the source to build."""
    monkeypatch.setattr(host_module, "_LIB", {})
    monkeypatch.setattr(kernel_cache.tempfile, "gettempdir", lambda: str(tmp_path))
    src = tmp_path / "answer.c"
    src.write_text(SOURCE)
    return tmp_path / f"hevr-kernels-{os.getuid()}", src


def _build(src: Path, compiler: str | None = None):
    host_module._LIB.clear()
    return host_module.build_library(src, (), compiler)


def _damage(lib: Path, data: bytes) -> None:
    """Put ``data`` at ``lib`` as a new file: this process has the old one mapped, and changing a
    mapped library in place would crash it (the very fault under test)."""
    tmp = lib.with_name("damaged")
    tmp.write_bytes(data)
    os.replace(tmp, lib)


def _script(tmp_path: Path, name: str, body: str) -> str:
    path = tmp_path / name
    path.write_text("#!/bin/sh\n" + textwrap.dedent(body))
    path.chmod(0o755)
    return str(path)


def test_a_truncated_cached_library_is_rebuilt_not_loaded(tmpdir_cache, tmp_path):
    """A truncated library killed the process with SIGBUS on load (exit 135, no message): run in
    a child so that a regression fails this test instead of killing the test run."""
    folder, src = tmpdir_cache
    assert _build(src).hevr_answer() == 42
    (lib,) = folder.glob("answer-*.so")
    assert lib.with_suffix(".sha256").read_text().strip() == __import__("hashlib").sha256(lib.read_bytes()).hexdigest()
    _damage(lib, lib.read_bytes()[: lib.stat().st_size // 2])
    code = (
        "import sys, tempfile; tempfile.gettempdir = lambda: sys.argv[1]\n"
        "from pathlib import Path\nfrom hevr.backends.cuda import host\n"
        "print(host.build_library(Path(sys.argv[2])).hevr_answer())"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path), str(src)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert run.returncode == 0, (run.returncode, run.stderr[-2000:])
    assert run.stdout.strip() == "42"
    assert lib.stat().st_size > 0 and kernel_cache._intact(lib)  # rebuilt in place, intact again


def test_a_cached_library_without_its_digest_is_rebuilt(tmpdir_cache):
    folder, src = tmpdir_cache
    _build(src)
    (lib,) = folder.glob("answer-*.so")
    lib.with_suffix(".sha256").unlink()
    _damage(lib, b"\x7fELF garbage")
    assert _build(src).hevr_answer() == 42
    assert lib.with_suffix(".sha256").exists() and kernel_cache._intact(lib)


def test_a_compiler_that_writes_nothing_is_named(tmpdir_cache, tmp_path):
    folder, src = tmpdir_cache
    cc = _script(tmp_path, "silent-cc", "exit 0\n")
    with pytest.raises(
        MissingDependencyError,
        match=r"compiler: expected .*silent-cc to write a library for "
        r"answer\.c, it exited 0 without one",
    ):
        _build(src, cc)


def test_a_compiler_that_writes_garbage_leaves_nothing_cached(tmpdir_cache, tmp_path):
    folder, src = tmpdir_cache
    cc = _script(
        tmp_path,
        "garbage-cc",
        """\
        while [ "$1" != "-o" ]; do shift; done
        echo garbage > "$2"
        """,
    )
    with pytest.raises(MissingDependencyError, match="compiler: expected a loadable library from .*garbage-cc"):
        _build(src, cc)
    assert list(folder.iterdir()) == []  # the garbage does not stay cached
    assert _build(src).hevr_answer() == 42  # the real compiler builds it afterwards


@pytest.mark.parametrize("kind", ["file", "fifo"])
def test_a_cache_folder_that_is_a_file_or_a_fifo_is_built_around(tmpdir_cache, kind):
    folder, src = tmpdir_cache
    if kind == "file":
        folder.write_text("not a folder")
    else:
        os.mkfifo(folder)
    assert _build(src).hevr_answer() == 42
    assert stat.S_ISREG(os.lstat(folder).st_mode) if kind == "file" else stat.S_ISFIFO(os.lstat(folder).st_mode)


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_a_cached_library_that_is_not_a_file_is_replaced(tmpdir_cache, kind):
    folder, src = tmpdir_cache
    _build(src)
    (lib,) = folder.glob("answer-*.so")
    lib.unlink()
    if kind == "folder":
        lib.mkdir()
    else:
        os.mkfifo(lib)  # reading it to check it would block forever
    assert _build(src).hevr_answer() == 42
    assert stat.S_ISREG(os.lstat(lib).st_mode) and kernel_cache._intact(lib)


def test_a_symlinked_cache_folder_is_not_followed(tmpdir_cache, tmp_path):
    folder, src = tmpdir_cache
    target = tmp_path / "elsewhere"
    target.mkdir(mode=0o700)
    folder.symlink_to(target)
    assert _build(src).hevr_answer() == 42
    assert list(target.iterdir()) == []  # nothing written into, or loaded from, the link's target


def test_the_cached_files_are_private_whatever_the_umask(tmpdir_cache):
    folder, src = tmpdir_cache
    old = os.umask(0)
    try:
        _build(src)
    finally:
        os.umask(old)
    assert stat.S_IMODE(folder.stat().st_mode) & 0o077 == 0
    files = list(folder.iterdir())
    assert len(files) == 2 and all(stat.S_IMODE(f.stat().st_mode) & 0o077 == 0 for f in files)


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="process states read from /proc")
def test_a_stuck_compiler_is_stopped_with_its_children(tmpdir_cache, tmp_path):
    folder, src = tmpdir_cache
    pids = tmp_path / "pids"
    cc = _script(
        tmp_path,
        "stuck-cc",
        f"""\
        sleep 600 &
        echo $! >> {pids}
        echo $$ >> {pids}
        exec sleep 600
        """,
    )
    start = time.monotonic()
    with dask.config.set({"hevr.limits.compile-seconds": 1}):
        with pytest.raises(
            MissingDependencyError,
            match=r"compiler: expected .*stuck-cc to build answer\.c within "
            r"1 s \(hevr\.limits\.compile-seconds\)",
        ):
            _build(src, cc)
    assert time.monotonic() - start < 30
    listed = [int(p) for p in pids.read_text().split()]
    assert len(listed) == 2
    deadline = time.monotonic() + 10
    while any(_alive(p) for p in listed) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in listed)  # no orphaned compiler processes
    assert not any(folder.glob("*.so")) if folder.exists() else True


def test_auto_with_a_stuck_compiler_renders_with_cpu(monkeypatch, tmpdir_cache, tmp_path):
    monkeypatch.setattr(backends, "_COMPILED_OK", [])
    monkeypatch.delitem(backends._INSTANCES, "cuda-host", raising=False)
    monkeypatch.setenv("CC", _script(tmp_path, "stuck-cc", "exec sleep 600\n"))
    start = time.monotonic()
    with dask.config.set({"hevr.limits.compile-seconds": 1}):
        assert backends.resolve_backend_name(None, 64) == "cpu"
    assert time.monotonic() - start < 30


def test_the_compile_limit_is_checked():
    with dask.config.set({"hevr.limits.compile-seconds": 0}), pytest.raises(ValueError, match="compile-seconds"):
        kernel_cache.compile_seconds()
    assert kernel_cache.compile_seconds() == kernel_cache.DEFAULT_COMPILE_SECONDS
