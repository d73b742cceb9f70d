"""The key holder's known stores: what it has trusted before, like SSH's ``known_hosts`` (issues 38, 47).

The tags and the owner's MAC prove that a frame is the render of *the store whose id the metadata
states*; they cannot say that it is the store the key holder meant. A server holding several
verifiable stores of one key (other patients, an older version of this one) could serve another
under the same name, or serve the store with its tags stripped so that renders quietly go
unverified. So the key holder remembers, per name (a local path, an fsspec URL, or a store on
``hevr serve``: ``<server>/v1/stores/<id>``):

    name → (store id, digest of the owner-bound metadata, verifiable, key fingerprint, retired ids)

When. Only with the private key, and only for a store the key holder has reason to trust: when it
encrypts the store (:func:`hevr.encrypt_volume` with the private key), when the check of a frame
whose seed this process drew has passed (:func:`record_verified`, called by every decryption that
checks a verification record: the frame proves that the store under that name is the one its
metadata states), and when it accepts a store explicitly (:func:`trust_store`,
``hevr render --key K --trust-store``: the owner re-encrypted it, or it has no tags). Never from an
unverified first answer: a server that alters its first answer would otherwise have its store
recorded and the honest one refused afterwards (issue 47).

Refusing needs no key. Renders (:func:`hevr.render`, :func:`hevr.render_slice`,
:func:`hevr.render_frame`, unless ``verify=False``) call :func:`check_known`, which only reads:
it refuses (:class:`hevr.VerificationError`, before anything is rendered) another store id under a
known name, a store without tags under a name recorded verifiable, changed metadata, and a store
whose id the owner has retired (replaced under some name); a stamped frame of a retired store is
refused at decryption (:func:`retired_by`).

The file: ``$HEVR_KNOWN_STORES``, else ``known_stores.json`` in the ``hevr`` folder of
``$XDG_CONFIG_HOME`` (default: ``.config`` in the home folder), mode 0600 in a 0700 folder,
replaced atomically under an ``flock``; JSON, one entry a line::

    {"format": "hevr-known-stores", "version": 2,
     "stores": {name: {"store_id", "digest", "verifiable", "fingerprint", "recorded", "retired",
                       "accepted_untagged", "mac"}, ...},
     "unsigned": {name: {...}, ...}}

Each entry of ``stores`` carries ``mac = HMAC-SHA256(K, canonical JSON of [name, entry without
mac])`` (canonical: ``sort_keys``, no spaces, ASCII), ``K = HMAC-SHA256(k, "hevr-known-stores-v2")``
with ``k`` the private key's tag PRF key (:func:`hevr.crypto.tags.tag_key_of`), and ``fingerprint``
names the key it belongs to. Without the key (at render time) entries are used only to refuse;
with it (recording, :func:`trust_store`, :func:`import_known_stores`, :func:`accepted_untagged`)
every entry of that key's fingerprint is MAC-checked first, and an edited or forged one is a
:class:`hevr.VerificationError` naming the file and the entry. ``unsigned`` holds the entries of a
version-1 file (no MACs; read with a warning): they refuse, never accept, and give way to a MAC'd
entry under the same name. The MAC makes the file portable: :func:`export_known_stores` on one
machine and :func:`import_known_stores` on another carry re-encryptions (retired ids) across, so
that an old stamped frame is refused there too. It holds no secret (ids, digests of public
metadata) but says which stores this user renders, so it stays private; the file handling and its
refusals (symbolic links, FIFOs, other owners, world-writable files or folders, size, deep
nesting): :mod:`hevr.store.known_file`.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from pathlib import Path
from typing import Any

from ..core.files import write_atomic
from ..errors import FileSystemError, HevrError, ParameterError, VerificationError
from .authenticity import authenticated_fields, check_metadata_mac, metadata_digest
from .known_file import (
    MAX_RETIRED,
    KnownStore,
    document,
    known_stores_path,
    load,
    locked,
    signed_by,
    store_file,
    verify_entries,
)
from .known_merge import merge_entry

__all__ = [
    "KnownStore",
    "accepted_untagged",
    "check_known",
    "export_known_stores",
    "import_known_stores",
    "known_stores",
    "known_stores_path",
    "known_verifiable",
    "record_quietly",
    "record_verified",
    "retired_by",
    "trust_store",
]

log = logging.getLogger(__name__)


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _of_meta(base: Any, **kw: Any) -> KnownStore:
    return KnownStore(
        store_id=base.store_id,
        digest=metadata_digest(authenticated_fields(base.to_dict())),
        verifiable=bool(base.tags),
        fingerprint=base.fingerprint,
        recorded=_now(),
        **kw,
    )


def _base(ev: Any) -> Any:
    return ev.base if ev.level else ev.meta  # level 0's metadata: the store's


def _need_key(private_key: Any, what: str) -> None:
    if private_key is None or not hasattr(private_key, "p"):
        raise ParameterError(
            f"private_key: expected the key holder's PrivateKey ({what}: each entry of the known "
            "stores is MAC'd under it, so that an edited or forged entry is caught), got "
            f"{type(private_key).__name__}"
        )


def known_stores(path: str | os.PathLike[str] | None = None) -> dict[str, KnownStore]:
    """The stores recorded in the known-stores file (none if it does not exist): each name's MAC'd
    entry, else its unsigned one (``entry.signed`` says which). A damaged, insecure or linked file is
    a :class:`hevr.ParameterError` naming it (never silently forgotten: it is what protects you)."""
    kf = load(Path(path) if path is not None else None)
    return {**kf.unsigned, **kf.signed}


def check_known(ev: Any) -> KnownStore | None:
    """Refuse (:class:`hevr.VerificationError`) a store that is not the one recorded under its
    name, whose owner-bound metadata changed, or whose id the owner retired; records nothing.
    Returns what is recorded under its name (None: nothing)."""
    kf = load()
    entry, name = _of_meta(_base(ev)), str(ev.path)
    where = f"in {kf.path}"
    olds = kf.entries(name)
    if not olds:
        replaced = kf.retired.get(entry.store_id)
        if replaced is not None and replaced[1] != entry.store_id:  # an old version, moved to a new name
            raise VerificationError(
                f"{name}: the store {entry.store_id} is one the owner replaced with the store "
                f"{replaced[1]} at {replaced[0]} (recorded {where}): an old version served?; if "
                "you mean it, accept it with hevr.trust_store(volume, private_key) or hevr render "
                "--key K --trust-store; nothing was rendered"
            )
        for other in kf.by_id.get(entry.store_id, ()):
            if any(e.store_id == entry.store_id and e.digest != entry.digest for e in kf.entries(other)):
                raise VerificationError(
                    f"store {entry.store_id}: its metadata differ from what was recorded for it "
                    f"under {other} {where}: altered metadata; nothing was rendered"
                )
        return None
    for old in olds:
        how = (
            f"(recorded {old.recorded or 'earlier'} {where}; if the owner re-encrypted or replaced it, accept it "
            "with hevr.trust_store(volume, private_key) or hevr render --key K --trust-store)"
        )
        if old.store_id != entry.store_id:
            raise VerificationError(
                f"{name}: expected the store {old.store_id}, got the store {entry.store_id}: "
                f"another store, or another version of it, is under this name {how}; nothing "
                "was rendered"
            )
        if old.verifiable and not entry.verifiable:
            raise VerificationError(
                f"{name}: expected the verifiable store {old.store_id} (recorded with tags), got "
                f"it without tags: they were stripped, so that renders would go unverified "
                f"{how}; nothing was rendered"
            )
        if old.digest != entry.digest or old.fingerprint != entry.fingerprint:
            raise VerificationError(
                f"{name}: the store's metadata (shape, spacing, channels, exponents, value range, "
                f"key or tags) are not the ones recorded {how}; nothing was rendered"
            )
    return olds[0]


def _record(name: str, entry: KnownStore, private_key: Any, replace: bool) -> KnownStore:
    """Record ``entry`` under ``name``, MAC'd (every entry of the key checked first). Without
    ``replace`` an entry already there is kept (returned) unless it is an unsigned one of the same
    store, which the MAC'd entry succeeds; with it, another store there is retired."""
    with locked(known_stores_path()):
        kf = load()
        verify_entries(kf, private_key)
        old, unsigned = kf.signed.get(name), kf.unsigned.get(name)
        if not replace:
            keep = old or (unsigned if unsigned is not None and unsigned.store_id != entry.store_id else None)
            if keep is not None:
                return keep
        retired: list[str] = []
        for e in (unsigned, old):
            if e is not None:
                retired += list(e.retired) + ([e.store_id] if e.store_id != entry.store_id else [])
        retired = [x for x in dict.fromkeys(retired) if x != entry.store_id][-MAX_RETIRED:]
        new = signed_by(private_key, name, dataclasses.replace(entry, retired=tuple(retired)))
        store_file(kf, {**kf.signed, name: new}, {k: v for k, v in kf.unsigned.items() if k != name}, private_key)
    log.info(
        "known stores: %s recorded as the store %s (%s) in %s",
        name,
        new.store_id,
        "verifiable" if new.verifiable else "without tags",
        kf.path,
    )
    return new


def record_verified(verification: Any, private_key: Any) -> KnownStore | None:
    """Record the store of a frame whose check has just passed (its seed drawn in this process,
    ``verification.known_name`` the name it was rendered under) unless its name is recorded
    already; None when there is nothing to record. A file that cannot be written is a warning
    (the frame stands); a forged entry or an insecure file is an error."""
    name = getattr(verification, "known_name", "")
    if not name or not getattr(verification, "drawn_here", False) or verification.meta is None:
        return None
    kf = load()
    verify_entries(kf, private_key)
    entry = _of_meta(verification.meta)
    old = kf.signed.get(name)
    if old is not None:
        if (old.store_id, old.digest, old.fingerprint) != (entry.store_id, entry.digest, entry.fingerprint):
            log.warning(
                "known stores: %s was recorded as another store (%s) while the store %s rendered; not "
                "recorded (hevr.trust_store accepts it)",
                name,
                old.store_id,
                entry.store_id,
            )
        return old
    try:
        return _record(name, entry, private_key, replace=False)
    except (OSError, FileSystemError) as exc:
        log.warning("known stores: could not record %s in %s (%s)", name, known_stores_path(), exc)
        return None


def record_quietly(ev: Any, private_key: Any = None, replace: bool = False) -> None:
    """Record ``ev`` with the owner's key (its encryption), saying in a warning — not failing the
    caller — when the file cannot be written; without the private key nothing is recorded (the
    entry must be MAC'd)."""
    if private_key is None or not hasattr(private_key, "p"):
        log.debug("known stores: %s not recorded (encrypted with the public key)", ev.path)
        return
    try:
        _record(str(ev.path), _of_meta(_base(ev)), private_key, replace)
    except (OSError, HevrError) as exc:
        log.warning("known stores: could not record %s in %s (%s)", ev.path, known_stores_path(), exc)


def trust_store(ev: Any, private_key: Any = None, *, untagged: bool = False) -> KnownStore:
    """Record the store ``ev`` under its name, MAC'd under ``private_key``, replacing whatever was
    recorded there (the owner re-encrypted it, or moved another store there): accepted explicitly.

    A verifiable store's metadata must carry the owner's MAC. Under a key whose policy requires
    tags (``private_key.require_tags``) a store without tags is refused unless ``untagged=True``,
    which records it with ``accepted_untagged`` (:func:`accepted_untagged`).
    """
    _need_key(private_key, "trust_store")
    base = _base(ev)
    if private_key.public_key.fingerprint != base.fingerprint:
        raise ParameterError(
            f"private_key: expected the private key of the store (fingerprint "
            f"{base.fingerprint[:16]}…), got one of fingerprint "
            f"{private_key.public_key.fingerprint[:16]}…"
        )
    if base.tags and not check_metadata_mac(private_key, authenticated_fields(base.to_dict()), base.auth):
        raise VerificationError(
            f"{ev.path}: expected the owner's MAC over the store's metadata, got "
            f"{'none' if not base.auth else 'one that does not match'}: altered metadata; not "
            "trusted"
        )
    if not base.tags and getattr(private_key, "require_tags", False) and not untagged:
        raise VerificationError(
            f"{ev.path}: the key requires tags (require_tags) and the store {base.store_id} has "
            "none, so its frames cannot be verified; if it is a store made with the public key "
            "that you accept as it is, pass untagged=True (hevr render --trust-store --untagged); "
            "not trusted"
        )
    return _record(
        str(ev.path), _of_meta(base, accepted_untagged=bool(untagged and not base.tags)), private_key, replace=True
    )


def _vouched(store_id: str, private_key: Any, what: str) -> list[KnownStore]:
    """The MAC-checked entries of ``private_key`` that record the store ``store_id``."""
    _need_key(private_key, what)
    kf = load()
    verify_entries(kf, private_key)
    fp = private_key.public_key.fingerprint
    return [
        e
        for n in kf.by_id.get(store_id, ())
        if (e := kf.signed.get(n)) is not None and e.store_id == store_id and e.fingerprint == fp
    ]


def accepted_untagged(store_id: str, private_key: Any) -> bool:
    """Whether the key holder accepted the store ``store_id`` without tags (:func:`trust_store`
    with ``untagged=True``), by a MAC-checked entry of its key."""
    return any(e.accepted_untagged for e in _vouched(store_id, private_key, "accepted_untagged"))


def known_verifiable(store_id: str, private_key: Any) -> bool:
    """Whether the key holder's record holds the store ``store_id`` as verifiable (encrypted here with
    tags, or verified here before), by a MAC-checked entry of its key: what lets an unverified frame
    of it decrypt under the key's policy (:func:`hevr.image.provenance.check_policy`)."""
    return any(e.verifiable for e in _vouched(store_id, private_key, "known_verifiable"))


def retired_by(store_id: str) -> tuple[str, str] | None:
    """(name, current store id) if ``store_id`` was under a name the owner has since given to
    another store (its frames are of an old version), else None."""
    got = load().retired.get(store_id)
    return got if got is not None and got[1] != store_id else None


def export_known_stores(path: str | os.PathLike[str], private_key: Any, *, overwrite: bool = False) -> int:
    """Write the MAC'd entries of ``private_key``'s stores to ``path`` (mode 0600; an existing file
    only with ``overwrite``), for :func:`import_known_stores` on another machine; returns how many.
    Every entry of the key is MAC-checked first (a forged one: :class:`hevr.VerificationError`)."""
    _need_key(private_key, "export_known_stores")
    kf = load()
    verify_entries(kf, private_key)
    fp = private_key.public_key.fingerprint
    mine = {n: e for n, e in kf.signed.items() if e.fingerprint == fp}
    write_atomic(path, document(mine), mode=0o600, overwrite=overwrite, name="path", doing="exporting the known stores")
    log.info("known stores: %d entries of the key %s… exported to %s", len(mine), fp[:16], path)
    return len(mine)


def import_known_stores(path: str | os.PathLike[str], private_key: Any) -> int:
    """Merge the entries of an exported file into the key holder's (:mod:`hevr.store.known_merge`:
    retired ids are unioned, and a store retired on either side stays retired); returns how many
    names were added or changed. Every entry of the file must be of ``private_key`` and carry its
    MAC, else :class:`hevr.VerificationError` naming the file and the entry, and nothing is merged."""
    _need_key(private_key, "import_known_stores")
    p = Path(path).expanduser()
    other = load(p, strict=False)
    if not other.signed and not other.unsigned and not p.exists():
        raise ParameterError(f"path: expected an exported known-stores file, found nothing at {p}")
    fp = private_key.public_key.fingerprint
    for name, e in {**other.unsigned, **other.signed}.items():
        if not e.signed or e.fingerprint != fp:
            raise VerificationError(
                f"known stores: the entry {name!r} in {p} is not MAC'd under this key (fingerprint "
                f"{fp[:16]}…): {'unsigned' if not e.signed else 'another key'}; nothing imported"
            )
    verify_entries(other, private_key, where=str(p))
    changed = 0
    with locked(known_stores_path()):
        kf = load()
        verify_entries(kf, private_key)
        signed, unsigned = dict(kf.signed), dict(kf.unsigned)
        for name, theirs in other.signed.items():
            mine = signed.get(name) or unsigned.get(name)
            merged = merge_entry(mine, theirs, private_key, name)
            if merged != signed.get(name):
                signed[name] = merged
                unsigned.pop(name, None)
                changed += 1
        if changed:
            store_file(kf, signed, unsigned, private_key)
    log.info("known stores: %d of %d entries of %s merged into %s", changed, len(other.signed), p, kf.path)
    return changed
