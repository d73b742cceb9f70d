"""The on-disk cache of the host builds of the kernel sources, and the bounded compiler run.

A host build (:func:`hevr.backends.cuda.host.build_library`) is compiled once per machine and
kept in ``$TMPDIR/hevr-kernels-<uid>``. What is loaded from there is checked first, because a
damaged library kills the process that loads it (a truncated one raises SIGBUS, no message):

* the folder is used only when it is a real folder (not a symlink, which is never followed),
  owned by this user and writable by no one else; otherwise — a file, a FIFO, a symlink,
  another user's folder — the build goes to a throwaway private folder, removed once loaded;
* each library ``<key>.so`` has its SHA-256 beside it (``<key>.sha256``), written only after a
  successful build; a library is loaded only when it is a regular file matching that digest,
  and anything else there (truncated, altered, no digest, a folder or a FIFO) is removed and
  rebuilt. A library that does not load is removed too, so a compiler's garbage never stays;
* the files are private (0600, the folder 0700) whatever the umask;
* the compiler runs in its own process group, for at most ``hevr.limits.compile-seconds``
  seconds (Dask config; ``DASK_HEVR__LIMITS__COMPILE_SECONDS``; default
  :data:`DEFAULT_COMPILE_SECONDS`): past that the whole group is killed and
  :class:`~hevr.errors.MissingDependencyError` names the compiler and the limit (``"auto"``
  then renders with ``cpu``).
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import hmac
import logging
import os
import secrets
import shutil
import signal
import stat
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from ...core.limits import _limit
from ...errors import MissingDependencyError

log = logging.getLogger(__name__)

__all__ = ["COMPILE_SECONDS_KEY", "DEFAULT_COMPILE_SECONDS", "compile_seconds", "load"]

COMPILE_SECONDS_KEY = "hevr.limits.compile-seconds"
DEFAULT_COMPILE_SECONDS = 120  # a build takes seconds; a stuck compiler must not hang a render
_MAX_COMPILE_SECONDS = 86_400
_DIGEST = ".sha256"
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)


def compile_seconds() -> int:
    """The time limit of one compiler run, in seconds (``hevr.limits.compile-seconds``, 1 to 86,400).

    >>> import dask
    >>> with dask.config.set({"hevr.limits.compile-seconds": 30}):
    ...     compile_seconds()
    30
    """
    return _limit(COMPILE_SECONDS_KEY, DEFAULT_COMPILE_SECONDS, _MAX_COMPILE_SECONDS)


def load(main: Path, key: str, cc: str, flags: Sequence[str]) -> ctypes.CDLL:
    """The library ``key`` built from ``main`` with ``cc`` and ``flags``: from the cache when it
    is there and intact, else built (into the cache when the cache is usable) and loaded.

    Raises
    ------
    MissingDependencyError
        The compiler cannot be run, fails, outlives its time limit, writes no library or one that
        does not load.
    """
    folder = _shared_folder()
    if folder is not None:
        lib = folder / f"{key}.so"
        try:
            if not _intact(lib):
                _build(main, lib, cc, flags)
            return _open(lib, cc)
        except MissingDependencyError:
            raise
        except OSError as exc:  # the cache itself failed (full, removed under us, ...): build aside
            log.warning("kernel cache %s unusable (%s); building %s in a private folder", folder, exc, key)
    with tempfile.TemporaryDirectory(prefix="hevr-kernels-") as aside:  # created 0700
        lib = Path(aside) / f"{key}.so"
        _build(main, lib, cc, flags)
        return _open(lib, cc)  # a loaded library survives its file's removal


def _shared_folder() -> Path | None:
    """``$TMPDIR/hevr-kernels-<uid>`` when it is this user's alone (created 0700 if missing), else None."""
    if not hasattr(os, "getuid"):  # pragma: no cover - no owners to check: never share a folder
        return None
    folder = Path(tempfile.gettempdir()) / f"hevr-kernels-{os.getuid()}"
    try:
        with contextlib.suppress(FileExistsError):
            folder.mkdir(mode=0o700)
        st = os.lstat(folder)
    except OSError as exc:
        log.warning("kernel cache %s unusable (%s); building in a private folder", folder, exc)
        return None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022:
        what = (
            "a symlink"
            if stat.S_ISLNK(st.st_mode)
            else "not a folder"
            if not stat.S_ISDIR(st.st_mode)
            else "not this user's alone"
        )
        log.warning("kernel cache %s is %s; building in a private folder", folder, what)
        return None
    return folder


def _intact(lib: Path) -> bool:
    """Whether ``lib`` is a regular file matching the digest beside it; anything else there is removed."""
    try:
        st = os.lstat(lib)
    except FileNotFoundError:
        return False
    if stat.S_ISREG(st.st_mode):
        digest = _read_small(lib.with_suffix(_DIGEST))
        fd = os.open(lib, os.O_RDONLY | _NOFOLLOW | _NONBLOCK)
        with os.fdopen(fd, "rb") as fh:
            data = fh.read()
        if digest is not None and hmac.compare_digest(hashlib.sha256(data).hexdigest(), digest):
            return True
        log.warning("kernel cache: %s does not match its digest (truncated or altered); rebuilding it", lib)
    else:
        log.warning("kernel cache: %s is not a regular file; replacing it", lib)
    _discard(lib)
    return False


def _read_small(path: Path) -> str | None:
    """The text of a small regular file, or None (missing, not regular, too long, not ASCII)."""
    try:
        fd = os.open(path, os.O_RDONLY | _NOFOLLOW | _NONBLOCK)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            return None
        raw = fh.read(128)
    try:
        return raw.decode("ascii").strip()
    except UnicodeDecodeError:
        return None


def _discard(lib: Path) -> None:
    """Remove a cached library and its digest (a folder in their place too)."""
    for path in (lib, lib.with_suffix(_DIGEST)):
        try:
            if stat.S_ISDIR(os.lstat(path).st_mode):
                shutil.rmtree(path)
            else:
                os.unlink(path)
        except FileNotFoundError:
            pass


def _build(main: Path, lib: Path, cc: str, flags: Sequence[str]) -> None:
    """Compile ``main`` into ``lib`` (private, its digest beside it), through a temporary name."""
    tmp = lib.with_name(f".{lib.stem}-{os.getpid()}-{secrets.token_hex(4)}")
    out, dig = tmp.with_suffix(".so"), tmp.with_suffix(_DIGEST)
    try:
        _run(cc, [*flags, str(main), "-o", str(out)], main.name)
        try:
            st = os.lstat(out)
        except FileNotFoundError:
            st = None
        if st is None or not stat.S_ISREG(st.st_mode) or st.st_size == 0:
            raise MissingDependencyError(
                f"compiler: expected {cc} to write a library for {main.name}, it exited 0 without one"
            )
        os.chmod(out, 0o600)  # private whatever the umask (the compiler creates it 0777 & ~umask)
        digest = hashlib.sha256(out.read_bytes()).hexdigest()
        fd = os.open(dig, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o600)
        with os.fdopen(fd, "w", encoding="ascii") as fh:
            fh.write(digest + "\n")
        if os.path.lexists(lib):
            _discard(lib)  # a folder in its place would refuse the rename
        os.replace(out, lib)
        os.replace(dig, lib.with_suffix(_DIGEST))
        log.info("built %s with %s", lib, cc)
    finally:
        for path in (out, dig):
            with contextlib.suppress(OSError):
                os.unlink(path)


def _run(cc: str, args: Sequence[str], name: str) -> None:
    """Run the compiler in its own process group within the time limit; kill the group past it."""
    limit = compile_seconds()
    try:
        proc = subprocess.Popen(
            [cc, *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            errors="replace",
            start_new_session=True,
        )
    except OSError as exc:
        raise MissingDependencyError(f"compiler: expected a C compiler at {cc}, got {exc.strerror}") from None
    try:
        _, err = proc.communicate(timeout=limit)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        raise MissingDependencyError(
            f"compiler: expected {cc} to build {name} within {limit} s "
            f"({COMPILE_SECONDS_KEY}), it had not finished; stopped it"
        ) from None
    except BaseException:  # an interrupt: no compiler left behind
        _kill_group(proc)
        raise
    if proc.returncode != 0:
        raise MissingDependencyError(f"compiler: {cc} could not build {name}: {(err or '').strip()[:500]}")


def _kill_group(proc: subprocess.Popen) -> None:
    """Kill the compiler and everything it started (its process group), then reap it."""
    try:
        if hasattr(os, "killpg"):
            os.killpg(proc.pid, signal.SIGKILL)  # proc is not reaped yet: its pid (the group's id) is still ours
        else:  # pragma: no cover - Windows
            proc.kill()
    except ProcessLookupError:
        pass
    for pipe in (proc.stdout, proc.stderr):  # a child that left the group may still hold them: do not wait on it
        if pipe is not None:
            pipe.close()
    proc.wait()


def _open(lib: Path, cc: str) -> ctypes.CDLL:
    """Load ``lib``; one that does not load is removed (never left cached)."""
    try:
        return ctypes.CDLL(str(lib))
    except OSError as exc:
        _discard(lib)
        raise MissingDependencyError(f"compiler: expected a loadable library from {cc}, got {exc}") from None
