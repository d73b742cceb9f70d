"""The tokens file over time: a running server re-reads it when it changes (:class:`TokenFile`),
and ``hevr serve --new-token NAME --tokens FILE`` adds an entry to it (:func:`add_token`).

Who may write it. Whoever may write the tokens file may grant themselves a token, so one policy
(:func:`read_tokens_file`, on the opened file's ``fstat``) holds at the server's start, at every
re-read and in :func:`add_token`: a regular file of at most 64 KiB, owned by the server's user
or by root, that neither its group nor others may write. A symbolic link is followed and its
target checked (a Kubernetes Secret mounted as a volume is a link into a ``..data`` folder of
root's, mode 0644 by default: accepted), except by :func:`add_token`, which refuses one (it
would replace the link, not its target), as it refuses a folder its group or others may write
(they could replace the file).

Rotation and revocation without a restart. :class:`TokenFile` stands where a
:class:`~hevr.serve.tokens.TokenTable` does (:meth:`TokenFile.lookup`); before a look-up it
``stat``\\ s the file, at most once a second (:class:`~hevr.serve.file_watch.FileWatch`), and
reads it again when its inode, size or modification time changed, or at once after ``SIGHUP``
(:meth:`TokenFile.reread`). A file that does not parse, breaks the policy, or is gone keeps the
table in force and logs an error (once per version of the file): a server never falls back to
serving without tokens. A removed entry's token is refused from the next look-up on; a file
whose list is empty (``"tokens": []``) revokes every token (each request a 401, logged as a
warning), though a server does not start on one.

Adding a token. :func:`add_token` writes the file through a temporary sibling (mode 0600,
``fsync``, ``os.replace``, the folder ``fsync``\\ ed) under a lock on the folder, so a server
reading it sees the old file or the new one, never half of one. The entries already there are
kept byte for byte: the new entry is inserted after the last one.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import re
import stat
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ..core.files import file_kind, fs_errors
from ..core.siblings import held_lock, temp_sibling
from ..errors import FileSystemError, HevrError, MissingFileError, ParameterError
from ..remote.protocol import MAX_BODY, parse_json
from .file_watch import CHECK_SECONDS, FileWatch, is_missing
from .tokens import DEFAULT_CONCURRENT, Token, TokenTable, hash_token, new_token

log = logging.getLogger("hevr.serve")

__all__ = ["CHECK_SECONDS", "TokenFile", "add_token", "check_tokens_stat", "read_tokens_file"]

_TOKENS_LIST = re.compile(r'"tokens"\s*:\s*\[')


def _refuse(path: Path, what: str) -> ParameterError:
    return ParameterError(
        f"--tokens: expected a tokens file that only you (or root) own and may write, at {path}, got {what}"
    )


def check_tokens_stat(path: str | os.PathLike, st: os.stat_result, kind: str = "file") -> None:
    """The policy of the module docstring on ``st`` (the ``fstat`` of the opened ``path``; ``kind``
    "folder": the folder :func:`add_token` writes in): a :class:`~hevr.ParameterError` naming
    what is wrong. Root's files and folders pass: root may write any of them anyway.

    >>> import os, types
    >>> st = types.SimpleNamespace(st_uid=os.geteuid(), st_mode=0o100664)
    >>> check_tokens_stat("t.json", st)
    Traceback (most recent call last):
    ...
    hevr.errors.ParameterError: --tokens: expected a tokens file that only you (or root) own and may write, \
at t.json, got a file your group may write (mode 0664): whoever writes it may grant themselves a token; chmod go-w it
    """
    path = Path(path)
    want = stat.S_ISDIR if kind == "folder" else stat.S_ISREG
    if not want(st.st_mode):
        raise _refuse(path, file_kind(st.st_mode))
    if st.st_uid not in (os.geteuid(), 0):
        raise _refuse(path, f"a {kind} owned by another user (uid {st.st_uid})")
    if st.st_mode & 0o022:
        who = "anyone" if st.st_mode & 0o002 else "your group"
        raise _refuse(
            path,
            f"a {kind} {who} may write (mode {stat.S_IMODE(st.st_mode):04o}): whoever writes it may "
            "grant themselves a token; chmod go-w it",
        )


def read_tokens_file(path: str | os.PathLike, *, follow_links: bool = True) -> tuple[bytes, tuple]:
    """(bytes, stat key) of the tokens file ``path``, the policy (:func:`check_tokens_stat`) and
    the size checked on the opened file before a byte is read; a symbolic link is followed
    (``follow_links``) or refused.

    Raises
    ------
    MissingFileError
        Nothing at ``path`` (a link to nothing included).
    ParameterError
        A file the policy refuses, or over 64 KiB.
    FileSystemError
        Any other failure to read it.
    """
    path = Path(path)
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow_links else os.O_NOFOLLOW)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise MissingFileError("tokens", "a tokens file (JSON)", path) from None
    except OSError as exc:
        if not follow_links and (exc.errno == errno.ELOOP or path.is_symlink()):
            raise _refuse(path, "a symbolic link (replacing it would replace the link, not its target)") from None
        raise FileSystemError(exc.errno, "reading the tokens file", path, exc.strerror) from None
    try:
        st = os.fstat(fd)
        check_tokens_stat(path, st)
        if st.st_size > MAX_BODY:
            raise _refuse(path, f"{st.st_size} bytes, more than the {MAX_BODY} a server reads")
        os.set_blocking(fd, True)
        with fs_errors("reading the tokens file", path), os.fdopen(os.dup(fd), "rb") as fh:
            raw = fh.read(MAX_BODY + 1)
    finally:
        os.close(fd)
    return raw, (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def _table(raw: bytes, path: Path, empty: bool = False) -> TokenTable:
    return TokenTable.from_dict(parse_json(raw, f"tokens {path}"), f"--tokens {path}", empty=empty)


class TokenFile:
    """The tokens of ``--tokens FILE``, re-read when the file changes (module docstring).

    Parameters
    ----------
    path : str or Path
        The tokens file; read now (its errors are raised: a server does not start on a file the
        policy refuses, one that does not parse, nor one without tokens).
    interval : float
        Seconds between two looks at the file (default :data:`CHECK_SECONDS`).
    clock : callable
        The monotonic clock (tests pass their own).
    """

    def __init__(
        self, path: str | Path, *, interval: float = CHECK_SECONDS, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.path = Path(path)
        raw, key = read_tokens_file(self.path)
        self.table = _table(raw, self.path)
        self._watch = FileWatch(self.path, interval=interval, clock=clock, key=key)
        self._lock = threading.Lock()
        self._asked = False

    @property
    def tokens(self) -> tuple:
        """The entries in force."""
        return self.table.tokens

    def __repr__(self) -> str:
        return f"TokenFile({str(self.path)!r}, {len(self.table.tokens)} tokens)"

    def reread(self) -> None:
        """Read the file again at the next look-up, changed or not (``SIGHUP``; safe in a signal
        handler: it only sets a flag)."""
        self._asked = True

    def lookup(self, presented: str | None) -> Token | None:
        """:meth:`TokenTable.lookup` on the table in force, after :meth:`refresh`."""
        self.refresh()
        return self.table.lookup(presented)

    def refresh(self) -> bool:
        """Look at the file (at most once per ``interval``, unless :meth:`reread` asked) and read
        it again if it changed; True if a new table is in force."""
        w = self._watch
        if not self._asked and w.clock() - w.checked < w.interval:
            return False
        if not self._lock.acquire(blocking=False):
            return False  # another thread is reading it
        try:
            asked, self._asked = self._asked, False
            key = w.look(force=asked)
            if key is None:
                return False
            if is_missing(key):
                self._fail(key, f"cannot be read ({os.strerror(key[1])})")
                return False
            try:
                raw, key = read_tokens_file(self.path)
                table = _table(raw, self.path, empty=True)
            except (HevrError, OSError, ValueError) as exc:  # whatever it is, the table in force stays
                self._fail(key, str(exc) if isinstance(exc, HevrError) else f"{type(exc).__name__}: {exc}")
                return False
            old = {t.name for t in self.table.tokens}
            new = {t.name for t in table.tokens}
            self.table = table
            w.accept(key)
            log.warning(
                "tokens: read %s again%s: %d tokens in force (added: %s; removed: %s)",
                self.path,
                " (SIGHUP)" if asked else "",
                len(table.tokens),
                ", ".join(sorted(new - old)) or "none",
                ", ".join(sorted(old - new)) or "none",
            )
            if not table.tokens:
                log.warning("tokens: %s lists no tokens: every request is refused (401) until one is added", self.path)
            return True
        finally:
            self._lock.release()

    def _fail(self, key: tuple, why: str) -> None:
        if self._watch.fail(key):
            log.error("tokens: %s: %s; the %d tokens read before stay in force", self.path, why, len(self.table.tokens))


# -- adding an entry ----------------------------------------------------------------------------
def _read_own(path: Path) -> bytes | None:
    """The bytes of the tokens file at ``path`` (None: there is none), the policy checked on the
    opened file, a symbolic link refused."""
    try:
        return read_tokens_file(path, follow_links=False)[0]
    except MissingFileError:
        if path.is_symlink():
            raise _refuse(path, "a symbolic link to nothing") from None
        return None


def _appended(text: str, entry: dict) -> str:
    """``text`` (a tokens file) with ``entry`` after its last entry, every other byte kept; the
    new line indented as the first entry is."""
    m = _TOKENS_LIST.search(text)
    if m is None:
        return text
    start = m.end() - 1
    try:
        _, end = json.JSONDecoder().raw_decode(text, start)
    except ValueError:
        return text
    last = end - 2
    while text[last].isspace():
        last -= 1
    first = start + 1
    while text[first].isspace():
        first += 1
    gap = text[start + 1 : first]
    indent = gap.rsplit("\n", 1)[1] if "\n" in gap else " " * (first - text.rfind("\n", 0, first) - 1)
    return text[: last + 1] + ",\n" + indent + json.dumps(entry) + text[last + 1 :]


def _write(path: Path, data: bytes, replace: bool) -> None:
    """``data`` at ``path``, mode 0600, through an fsync'ed temporary sibling: replacing the file
    (``replace``) or created where there is none (an exclusive link)."""
    tmp = temp_sibling(path, "tmp")
    with fs_errors("writing the tokens file", path):
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
        try:
            try:
                os.fchmod(fd, 0o600)
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                os.fsync(fd)
            finally:
                os.close(fd)
            if replace:
                os.replace(tmp, path)
            else:
                try:
                    os.link(tmp, path)
                except FileExistsError:
                    raise _refuse(path, "a file that appeared while the entry was written; run it again") from None
                os.unlink(tmp)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        with contextlib.suppress(OSError):  # the rename itself on disk (not every filesystem opens folders)
            dfd = os.open(path.parent, os.O_RDONLY | os.O_CLOEXEC)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)


def add_token(
    path: str | Path, name: str, stores: Sequence[str] = ("*",), concurrent: int = DEFAULT_CONCURRENT
) -> tuple[str, dict]:
    """Add a fresh token named ``name`` to the tokens file ``path`` (created, mode 0600, if there
    is none); returns (the token, its entry). The token is not written anywhere: give it to its
    holder and forget it (the file keeps its SHA-256).

    Raises
    ------
    ParameterError
        A bad name, store or ``concurrent``; a name already in the file; a file the module
        docstring refuses, or one that does not parse.
    """
    path = Path(path)
    token = new_token()
    entry = {"name": name, "sha256": hash_token(token), "stores": list(stores), "concurrent": concurrent}
    (new,) = TokenTable.from_dict({"version": 1, "tokens": [entry]}, "--new-token").tokens
    folder = path.parent if str(path.parent) else Path(".")
    try:
        check_tokens_stat(folder, os.stat(folder), "folder")
    except FileNotFoundError:
        raise ParameterError(f"--tokens: expected a file in an existing folder, got {path}") from None
    with held_lock(folder):
        raw = _read_own(path)
        if raw is None:
            text = '{"version": 1,\n "tokens": [' + json.dumps(entry) + "]}\n"
            old: tuple = ()
        else:
            old = TokenTable.from_dict(parse_json(raw, f"tokens {path}"), f"--tokens {path}").tokens
            if any(t.name == name for t in old):
                raise ParameterError(
                    f"--new-token: expected a name not yet in {path}, got {name!r} (remove its entry "
                    "first to give it a new token)"
                )
            text = _appended(raw.decode("utf-8"), entry)
        data = text.encode("utf-8")
        try:
            ok = len(data) <= MAX_BODY and TokenTable.from_dict(parse_json(data, "new")).tokens == (*old, new)
        except ParameterError:
            ok = False
        if not ok:
            raise ParameterError(
                f"--tokens: could not add the entry to {path} keeping every other byte (at most "
                f"{MAX_BODY} bytes and 256 tokens); add it by hand: {json.dumps(entry)}"
            )
        _write(path, data, replace=raw is not None)
    return token, entry
