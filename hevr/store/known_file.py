"""The known-stores file itself: its path, its MACs, hardened reading, a parsed copy cached per
process, and locked atomic writing (the rules: :mod:`hevr.store.known`).

Reading refuses, naming the file and never with a raw exception: a symbolic link (it would be
silently replaced by the next write), anything but a regular file (a FIFO is opened with
``O_NONBLOCK`` and refused before a byte is read), a file or folder that another user owns or that
anyone may write (``known_hosts``' rule: the file is what protects the key holder), a file over
:data:`MAX_BYTES` (refused unread) and one that does not parse (nesting too deep for the parser
included). A file parsed once is kept, keyed by ``(st_dev, st_ino, st_mtime_ns, st_size)`` of the
opened file, so a render's look-up costs an ``open`` and an ``fstat``, not a parse.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import hashlib
import json
import logging
import os
import re
import stat
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.files import file_kind, write_atomic
from ..crypto.mac import PREFIX, check_tag, derive_key, mac
from ..crypto.tags import tag_key_of
from ..errors import FileSystemError, NotRegularFileError, ParameterError, VerificationError

__all__ = [
    "FORMAT",
    "KnownFile",
    "KnownStore",
    "MAX_BYTES",
    "MAX_RETIRED",
    "entry_mac",
    "known_key",
    "known_stores_path",
    "load",
    "locked",
    "parse",
    "read_file",
    "signed_by",
    "store_file",
    "verify_entries",
]

log = logging.getLogger(__name__)
FORMAT = "hevr-known-stores"
VERSION = 2
MAX_BYTES = 32 << 20  # some 80 000 stores; a bigger file is refused unread
MAX_RETIRED = 64  # retired ids kept per name (the newest)
MAC_PREFIX = PREFIX
_MAC = re.compile(r"hmac-sha256:[0-9a-f]{64}")
_FIELDS = ("store_id", "digest", "verifiable", "fingerprint", "recorded", "retired", "accepted_untagged")
_CACHE: dict[str, tuple[tuple, KnownFile]] = {}
_LOCK = threading.Lock()
_WARNED_V1: set = set()


@dataclass(frozen=True)
class KnownStore:
    """What the key holder recorded of the store under a name. ``mac`` empty: an unsigned entry
    (read from a version-1 file), used only to refuse."""

    store_id: str
    digest: str
    verifiable: bool
    fingerprint: str
    recorded: str = ""
    retired: tuple = ()  # ids of the stores that were under this name before (replaced by the owner)
    accepted_untagged: bool = False  # a store without tags the key holder accepted explicitly
    mac: str = ""

    @property
    def signed(self) -> bool:
        return bool(self.mac)

    def fields(self) -> dict[str, Any]:
        """The entry as the file holds it, without its MAC."""
        return {
            "store_id": self.store_id,
            "digest": self.digest,
            "verifiable": bool(self.verifiable),
            "fingerprint": self.fingerprint,
            "recorded": self.recorded,
            "retired": list(self.retired),
            "accepted_untagged": bool(self.accepted_untagged),
        }


@dataclass
class KnownFile:
    """A parsed known-stores file: MAC'd entries, unsigned ones (version 1), and look-up tables."""

    path: Path
    signed: dict[str, KnownStore] = field(default_factory=dict)
    unsigned: dict[str, KnownStore] = field(default_factory=dict)
    by_id: dict[str, list[str]] = field(default_factory=dict)  # store id -> the names it is current under
    retired: dict[str, tuple[str, str]] = field(default_factory=dict)  # retired id -> (name, current id)
    checked: set = field(default_factory=set)  # the MAC keys every entry of whose fingerprint was checked

    def __post_init__(self) -> None:
        for table in (self.unsigned, self.signed):  # a signed entry's retired ids win for the name
            for name, e in table.items():
                self.by_id.setdefault(e.store_id, []).append(name)
                for old in e.retired:
                    self.retired[old] = (name, e.store_id)

    def entries(self, name: str) -> list[KnownStore]:
        """What is recorded under ``name``: its signed entry, then its unsigned one, if any."""
        return [e for e in (self.signed.get(name), self.unsigned.get(name)) if e is not None]


def known_stores_path() -> Path:
    """The known-stores file (:mod:`hevr.store.known`)."""
    env = os.environ.get("HEVR_KNOWN_STORES")
    if env:
        return Path(env).expanduser()
    config = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(config) / "hevr" / "known_stores.json"


def known_key(private_key: Any) -> bytes:
    """K = HMAC-SHA256(k, "hevr-known-stores-v2"), k the private key's tag PRF key."""
    return derive_key(tag_key_of(private_key).prf_key, b"hevr-known-stores-v2")


def entry_mac(key: bytes, name: str, entry: KnownStore) -> str:
    """HMAC-SHA256(K, canonical JSON of ``[name, entry without mac]``).

    >>> e = KnownStore("0123456789abcdef", "sha256:00", True, "ab")
    >>> m = entry_mac(bytes(32), "v.zarr", e)
    >>> m.startswith("hmac-sha256:"), m == entry_mac(bytes(32), "w.zarr", e)
    (True, False)
    """
    return mac(key, [name, entry.fields()])


def signed_by(private_key: Any, name: str, entry: KnownStore) -> KnownStore:
    """``entry`` with its MAC under the key."""
    return dataclasses.replace(entry, mac=entry_mac(known_key(private_key), name, entry))


def verify_entries(kf: KnownFile, private_key: Any, where: str | None = None) -> None:
    """Check the MAC of every signed entry of the key's fingerprint (once per parsed file and key);
    :class:`hevr.VerificationError` names the file and the first entry that fails."""
    key, fp = known_key(private_key), private_key.public_key.fingerprint
    mark = hashlib.sha256(key).digest()  # not the key itself
    if mark in kf.checked:
        return
    for name, e in kf.signed.items():
        if e.fingerprint == fp and not check_tag(entry_mac(key, name, e), e.mac):
            raise VerificationError(
                f"known stores: the entry {name!r} in {where or kf.path} does not carry the key holder's MAC: it was "
                "edited, forged or copied from another file; nothing is trusted from it (remove that entry, or the "
                "file, and trust your stores again)"
            )
    kf.checked.add(mark)


def _bad(p: Path, what: str) -> ParameterError:
    return ParameterError(f"known stores: expected the key holder's known-stores file at {p}, got {what}")


def _check_owner(p: Path, st: os.stat_result, kind: str, writable_bits: int) -> None:
    if st.st_uid != os.getuid() and not (kind == "folder" and st.st_uid == 0):
        raise _bad(
            p,
            f"a {kind} owned by another user (uid {st.st_uid}); another user could edit what protects "
            "you: make it yours (chown) or set HEVR_KNOWN_STORES to a file of your own",
        )
    if st.st_mode & writable_bits:
        who = "anyone" if st.st_mode & 0o002 else "your group"
        raise _bad(
            p,
            f"a {kind} {who} may write (mode {stat.S_IMODE(st.st_mode):04o}); another user could edit what "
            "protects you: chmod go-w it",
        )


def read_file(p: Path, *, strict: bool = True, known: tuple | None = None) -> tuple[tuple, bytes | None] | None:
    """``(stat key, bytes)`` of the file ``p`` (bytes None when the stat key is ``known``, the
    cached copy's), or None if it does not exist; every refusal of the module docstring (``strict``: the owner, mode
    and symbolic-link checks too, for the key holder's own file)."""
    if strict:
        try:
            _check_owner(p.parent, os.stat(p.parent), "folder", 0o002)
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise FileSystemError(exc.errno, "reading the known-stores folder", p.parent, exc.strerror) from None
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (os.O_NOFOLLOW if strict else 0)
    try:
        fd = os.open(p, flags)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if strict and (exc.errno == errno.ELOOP or p.is_symlink()):
            raise _bad(
                p,
                "a symbolic link (to {}); hevr reads and replaces only a regular file there, so point "
                "HEVR_KNOWN_STORES at the file itself".format(os.readlink(p) if p.is_symlink() else "?"),
            ) from None
        if exc.errno in (errno.ENXIO, errno.EOPNOTSUPP):  # a socket
            raise NotRegularFileError("known stores", "the key holder's known-stores file", p, "a socket") from None
        raise FileSystemError(exc.errno, "reading the known-stores file", p, exc.strerror) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise NotRegularFileError("known stores", "the key holder's known-stores file", p, file_kind(st.st_mode))
        if strict:
            _check_owner(p, st, "file", 0o022)
        if st.st_size > MAX_BYTES:
            raise _bad(p, f"{st.st_size} bytes, more than the {MAX_BYTES} read (refused unread)")
        key = (st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size)
        if key == known:
            return key, None
        os.set_blocking(fd, True)
        try:
            with os.fdopen(os.dup(fd), "rb") as fh:
                return key, fh.read(MAX_BYTES + 1)
        except OSError as exc:
            raise FileSystemError(exc.errno, "reading the known-stores file", p, exc.strerror) from None
    finally:
        os.close(fd)


_ALL = frozenset(_FIELDS) | {"mac"}
_V1 = frozenset({"store_id", "digest", "verifiable", "fingerprint"})


def _entry(name: Any, e: Any, signed: bool) -> KnownStore:
    """One entry, every field's type checked (a few µs: 50 000 entries parse in well under a second)."""
    if type(name) is not str or type(e) is not dict:
        raise ValueError(f"entry {str(name)[:60]!r} is not an object")
    keys = e.keys()
    if (keys != _ALL) if signed else not (_V1 <= keys <= _ALL):
        raise ValueError(
            f"entry {name[:60]!r} has the fields {sorted(keys)[:10]}, expected {sorted(_ALL if signed else _V1)}"
        )
    sid, digest, fp, rec = e["store_id"], e["digest"], e["fingerprint"], e.get("recorded", "")
    retired, untagged, mac = e.get("retired", []), e.get("accepted_untagged", False), e.get("mac", "")
    if (
        type(sid) is not str
        or type(digest) is not str
        or type(fp) is not str
        or type(rec) is not str
        or type(e["verifiable"]) is not bool
        or type(untagged) is not bool
        or type(retired) is not list
        or any(type(x) is not str for x in retired)
        or (signed and (type(mac) is not str or not _MAC.fullmatch(mac)))
    ):
        raise ValueError(f"entry {name[:60]!r} has a field of the wrong type")
    return KnownStore(
        sid, digest, e["verifiable"], fp, rec, tuple(retired), untagged if signed else False, mac if signed else ""
    )


def parse(p: Path, raw: bytes) -> KnownFile:
    """The :class:`KnownFile` of the bytes ``raw`` read from ``p``; a :class:`hevr.ParameterError`
    naming the file for anything else (nesting too deep for the parser too). Version 1's entries
    are read as unsigned (a warning, once per file)."""
    try:
        doc = json.loads(raw.decode("utf-8"))
        if not (
            isinstance(doc, dict)
            and doc.get("format") == FORMAT
            and doc.get("version") in (1, VERSION)
            and isinstance(doc.get("stores"), dict)
            and isinstance(doc.get("unsigned", {}), dict)
        ):
            raise ValueError(f"not a known-stores document of version 1 or {VERSION}")
        if doc["version"] == 1:
            if str(p) not in _WARNED_V1:
                _WARNED_V1.add(str(p))
                log.warning(
                    "known stores: %s is of version 1 (no MACs): its entries are used only to refuse a store, "
                    "never to accept one; each is recorded again, MAC'd, after the next verified render of "
                    "its store (or hevr.trust_store(volume, private_key))",
                    p,
                )
            return KnownFile(p, unsigned={n: _entry(n, e, False) for n, e in doc["stores"].items()})
        return KnownFile(
            p,
            signed={n: _entry(n, e, True) for n, e in doc["stores"].items()},
            unsigned={n: _entry(n, e, False) for n, e in doc.get("unsigned", {}).items()},
        )
    except RecursionError:
        raise _bad(
            p,
            "JSON nested too deeply to read (an attack on the parser?); repair or remove it (and re-trust your stores)",
        ) from None
    except (ValueError, TypeError, KeyError, UnicodeDecodeError) as exc:
        raise _bad(
            p,
            f"one that cannot be read ({type(exc).__name__}: {str(exc)[:100]}); repair or remove it (and "
            "re-trust your stores)",
        ) from None


def load(p: Path | None = None, *, strict: bool = True) -> KnownFile:
    """The parsed known-stores file ``p`` (default: :func:`known_stores_path`), empty if it does
    not exist: from this process's cache while the file is unchanged."""
    p = Path(p) if p is not None else known_stores_path()
    with _LOCK:
        cached = _CACHE.get(str(p)) if strict else None
    got = read_file(p, strict=strict, known=cached[0] if cached else None)
    if got is None:
        return KnownFile(p)
    key, raw = got
    if raw is None and cached is not None:
        return cached[1]
    kf = parse(p, raw or b"")
    if strict:
        with _LOCK:
            _CACHE[str(p)] = (key, kf)
    return kf


@contextlib.contextmanager
def locked(p: Path) -> Iterator[None]:
    """Hold the known-stores file's lock (a ``.lock`` file beside it) while the block runs."""
    try:
        with contextlib.suppress(FileExistsError):
            p.parent.mkdir(mode=0o700, parents=True)
        fd = os.open(p.parent / (p.name + ".lock"), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
    except OSError as exc:
        raise FileSystemError(exc.errno, "locking the known-stores file", p, exc.strerror) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def document(signed: dict[str, KnownStore], unsigned: dict[str, KnownStore] | None = None) -> str:
    """The text of a version-2 file: one entry a line."""

    def lines(table: dict[str, KnownStore], with_mac: bool) -> str:
        return ",\n".join(
            json.dumps(n)
            + ": "
            + json.dumps(dict(e.fields(), **({"mac": e.mac} if with_mac else {})), separators=(",", ":"))
            for n, e in sorted(table.items())
        )

    head = json.dumps({"format": FORMAT, "version": VERSION})[:-1]
    return (
        head
        + ', "stores": {\n'
        + lines(signed, True)
        + '\n}, "unsigned": {\n'
        + lines(unsigned or {}, False)
        + "\n}}\n"
    )


def store_file(
    kf: KnownFile, signed: dict[str, KnownStore], unsigned: dict[str, KnownStore], private_key: Any
) -> KnownFile:
    """Replace the file of ``kf`` (under :func:`locked`, after :func:`load` refused a symbolic link
    there) by these entries, mode 0600; the new file is cached as parsed, its entries of the key
    (checked or signed just now by the caller) as checked."""
    p = kf.path
    write_atomic(p, document(signed, unsigned), mode=0o600, name="known stores", doing="recording a known store")
    new = KnownFile(
        p, signed=dict(signed), unsigned=dict(unsigned), checked={hashlib.sha256(known_key(private_key)).digest()}
    )
    try:
        st = os.stat(p, follow_symlinks=False)
    except OSError:
        return new
    with _LOCK:
        _CACHE[str(p)] = ((st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size), new)
    return new
