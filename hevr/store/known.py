"""The key holder's known stores: what it has trusted before, like SSH's ``known_hosts`` (issue 38).

The tags and the owner's MAC prove that a frame is the render of *the store whose id the metadata
states*; they cannot say that it is the store the key holder meant. A server holding several
verifiable stores of one key (other patients, an older version of this one) could serve another
under the same name, or serve the store with its tags stripped so that renders quietly go
unverified. So the key holder remembers, per name (a local path, an fsspec URL, or a store on
``hevr serve``: ``<server>/v1/stores/<id>``):

    name → (store id, digest of the owner-bound metadata, verifiable, key fingerprint)

recorded when the key holder encrypts a store (:func:`hevr.encrypt_volume`) and on the first
render it asks for under a name it has not seen (trust on first use). Later renders
(:func:`hevr.render`, :func:`hevr.render_slice`, :func:`hevr.render_frame`, unless ``verify=False``)
refuse, with :class:`hevr.VerificationError` and before anything is rendered, a store whose id or
metadata differ from what was recorded under its name; a store recorded as verifiable must verify
(``verify=None`` then means True). Accept a store explicitly (the owner re-encrypted it) with
:func:`trust_store` or ``hevr render --trust-store``.

The file: ``$HEVR_KNOWN_STORES``, else ``known_stores.json`` in the ``hevr`` folder of
``$XDG_CONFIG_HOME`` (default: ``.config`` in the home folder); JSON ``{"format": "hevr-known-stores",
"version": 1, "stores": {name: {...}}}``, mode 0600 in a 0700 folder, replaced atomically under an ``flock``. It holds no secret (ids,
digests of public metadata) but says which stores this user renders, so it stays private.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import json
import logging
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterator

from .._files import read_regular, write_atomic
from ..errors import HevrError, ParameterError, VerificationError
from .authenticity import authenticated_fields, metadata_digest

__all__ = ["KnownStore", "check_known", "known_stores", "known_stores_path", "record_quietly", "retired_by",
           "trust_store"]

log = logging.getLogger(__name__)
FORMAT = "hevr-known-stores"
MAX_BYTES = 16 << 20  # a file of some 50 000 stores; a bigger one is refused unread


@dataclass(frozen=True)
class KnownStore:
    """What the key holder recorded of the store under a name."""

    store_id: str
    digest: str
    verifiable: bool
    fingerprint: str
    recorded: str = ""
    retired: tuple = ()  # ids of the stores that were under this name before (replaced by the owner)


def known_stores_path() -> Path:
    """The known-stores file (module docstring)."""
    env = os.environ.get("HEVR_KNOWN_STORES")
    if env:
        return Path(env).expanduser()
    config = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(config) / "hevr" / "known_stores.json"


def _name(ev: Any) -> str:
    return str(ev.path)


def _entry(ev: Any) -> KnownStore:
    base = ev.base if ev.level else ev.meta  # level 0's metadata: the store's
    return KnownStore(store_id=base.store_id, digest=metadata_digest(authenticated_fields(base.to_dict())),
                      verifiable=bool(base.tags), fingerprint=base.fingerprint,
                      recorded=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))


def known_stores(path: str | os.PathLike | None = None) -> dict[str, KnownStore]:
    """The stores recorded in the known-stores file (none if it does not exist); a damaged file is
    a :class:`hevr.ParameterError` naming it (never silently forgotten: it is what protects you)."""
    p = Path(path) if path is not None else known_stores_path()
    if not p.exists():
        return {}
    raw = read_regular(p, "known stores", "the key holder's known-stores file", limit=MAX_BYTES)
    try:
        doc = json.loads(raw.decode("utf-8"))
        if not (isinstance(doc, dict) and doc.get("format") == FORMAT and doc.get("version") == 1
                and isinstance(doc.get("stores"), dict)):
            raise ValueError("not a known-stores document of version 1")
        return {str(name): KnownStore(**{k: e[k] for k in ("store_id", "digest", "verifiable", "fingerprint")},
                                      recorded=str(e.get("recorded", "")),
                                      retired=tuple(str(x) for x in e.get("retired", ())))
                for name, e in doc["stores"].items()}
    except (ValueError, TypeError, KeyError, UnicodeDecodeError) as exc:
        raise ParameterError(f"known stores: expected the key holder's known-stores file at {p}, got one that "
                             f"cannot be read ({type(exc).__name__}: {str(exc)[:80]}); repair or remove it (and "
                             "re-trust your stores)") from None


@contextlib.contextmanager
def _locked(p: Path) -> Iterator[None]:
    p.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    fd = os.open(p.parent / (p.name + ".lock"), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _record(ev: Any, entry: KnownStore, replace: bool) -> None:
    p = known_stores_path()
    with _locked(p):
        stores = known_stores(p)
        old = stores.get(_name(ev))
        if not replace and old is not None:
            return
        if old is not None and old.store_id != entry.store_id:  # the owner replaced it: its frames are old
            entry = dataclasses.replace(entry, retired=tuple(dict.fromkeys(old.retired + (old.store_id,)))[-64:])
        elif old is not None:
            entry = dataclasses.replace(entry, retired=old.retired)
        stores[_name(ev)] = entry
        doc = {"format": FORMAT, "version": 1,
               "stores": {k: dict(asdict(v), retired=list(v.retired)) for k, v in sorted(stores.items())}}
        write_atomic(p, json.dumps(doc, indent=1) + "\n", mode=0o600, name="known stores",
                     doing="recording a known store")
    log.info("known stores: %s recorded as the store %s (%s) in %s", _name(ev), entry.store_id,
             "verifiable" if entry.verifiable else "without tags", p)


def retired_by(store_id: str) -> tuple[str, str] | None:
    """(name, current store id) if ``store_id`` was under a name the owner has since given to
    another store (its frames are of an old version), else None."""
    try:
        stores = known_stores()
    except HevrError:
        return None
    return next(((name, e.store_id) for name, e in stores.items() if store_id in e.retired), None)


def record_quietly(ev: Any, entry: KnownStore | None = None, replace: bool = False) -> None:
    """Record ``ev`` (first use, or its encryption), saying in a warning — not failing the caller —
    when the file cannot be written (a read-only home)."""
    try:
        _record(ev, entry or _entry(ev), replace)
    except (OSError, HevrError) as exc:
        log.warning("known stores: could not record %s in %s (%s); it will be trusted again on its next use",
                    _name(ev), known_stores_path(), exc)


def trust_store(ev: Any) -> KnownStore:
    """Record the store ``ev`` under its name, replacing whatever was recorded there (the owner
    re-encrypted it, or moved another store there): accepted explicitly."""
    entry = _entry(ev)
    _record(ev, entry, replace=True)
    return entry


def check_known(ev: Any) -> KnownStore | None:
    """Refuse (:class:`hevr.VerificationError`) a store that is not the one recorded under its
    name, or whose owner-bound metadata changed; record a store under a new name (first use).
    Returns what was recorded before (None: first use)."""
    entry, stores = _entry(ev), known_stores()
    name, old = _name(ev), stores.get(_name(ev))
    if old is None:
        same_id = [n for n, e in stores.items() if e.store_id == entry.store_id and e.digest != entry.digest]
        if same_id:
            raise VerificationError(f"store {entry.store_id}: its metadata differ from what was recorded for it under "
                                    f"{same_id[0]} in {known_stores_path()}: altered metadata; nothing was rendered")
        record_quietly(ev, entry)
        return None
    how = (f"(recorded {old.recorded or 'earlier'} in {known_stores_path()}; if the owner re-encrypted or replaced "
           "it, accept it with hevr.trust_store(volume) or hevr render --trust-store)")
    if old.store_id != entry.store_id:
        raise VerificationError(f"{name}: expected the store {old.store_id}, got the store {entry.store_id}: another "
                                f"store, or another version of it, is under this name {how}; nothing was rendered")
    if old.verifiable and not entry.verifiable:
        raise VerificationError(f"{name}: expected the verifiable store {old.store_id} (recorded with tags), got it "
                                f"without tags: they were stripped, so that renders would go unverified {how}; "
                                "nothing was rendered")
    if old.digest != entry.digest or old.fingerprint != entry.fingerprint:
        raise VerificationError(f"{name}: the store's metadata (shape, spacing, channels, exponents, value range, "
                                f"key or tags) are not the ones recorded {how}; nothing was rendered")
    return old
