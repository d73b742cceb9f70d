"""Converting a format-1 store (no integrity digests) into a new format-2 store.

Version 1 stores carry no checksum and no brick digests, so hevr no longer opens them.
``hevr upgrade-store OLD NEW`` (or :func:`upgrade_store`) copies every brick, unchanged,
into a new store at another path: one Dask task per brick reads the old chunks, checks
that every record lies in (0, n²), writes the new chunks (with crc32c) and then the
brick's digests. The old store is left as it was; no key is needed, since ciphertexts are
copied, not re-encrypted. The copy can only be as sound as the old store: verify it
(``open_volume(NEW, verify="full")``) and, where the plaintext is still at hand,
re-encrypting is the stronger choice.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import logging
import os
from pathlib import Path
from typing import Any

import dask
import numpy as np
import zarr

from ..backends import get_backend
from ..core.files import os_error
from ..core.siblings import held_lock, temp_sibling
from ..crypto.keys import PublicKey
from ..errors import (
    CorruptStoreError,
    IncompleteStoreError,
    MissingFileError,
    ParameterError,
    StoreExistsError,
)
from ..runtime.scheduler import compute
from .creation import create_store
from .digests import brick_digest, marker
from .exclusive import rename_noreplace, swap_lock
from .layout import check_document, check_entry, chunk_key, store_array
from .metadata import VolumeMetadata
from .paths import is_local, normalise, store_exists, token
from .reader import EncryptedVolume, brick_slices, open_volume
from .replacing import remove_tree

log = logging.getLogger(__name__)

__all__ = ["upgrade_store"]


def _old_metadata(src: str) -> VolumeMetadata:
    if is_local(src) and not Path(src).exists():
        raise MissingFileError("src", "an encrypted volume store", src)
    check_document(src, "")  # a FIFO in place of zarr.json would block Zarr's open
    try:
        attrs = dict(zarr.open_group(src, mode="r").attrs)
    except Exception as exc:  # noqa: BLE001 - any failure to open is a corrupt store
        raise CorruptStoreError(f"{src}: not a Zarr v3 group ({type(exc).__name__}: {exc})") from None
    meta = VolumeMetadata.from_dict(attrs.get("hevr"), where=src, accept_v1=True)
    if meta.version != 1:
        raise ParameterError(f"src: expected a format-1 store, got format {meta.version} (nothing to upgrade)")
    if not meta.complete:
        raise IncompleteStoreError(f"{src}: the format-1 store is incomplete; only complete stores are upgraded")
    if PublicKey(int(meta.n)).fingerprint != meta.fingerprint:
        raise CorruptStoreError(f"{src}: the stored key fingerprint does not match the stored modulus n")
    return meta


def _copy_brick(src: str, dst: str, index: tuple[int, int, int], meta_dict: dict[str, Any]) -> tuple[int, int, int]:
    """One task: copy one brick's records of every channel, checked, then write its digests."""
    meta = VolumeMetadata.from_dict(meta_dict)
    be = get_backend("cpu")
    n2 = int(meta.n) ** 2
    sl = brick_slices(meta, index)
    group = zarr.open_group(dst, mode="r+")
    digests = []
    for name in meta.channel_names:
        key = sl if name == "scalar" else (slice(None),) + sl
        check_document(src, name)  # a FIFO in place of a document or a chunk would block Zarr's read
        check_entry(src, f"{name}/{chunk_key(name, index)}", f"the chunk of brick {index} in channel {name!r}")
        try:
            data = np.asarray(zarr.open_array(f"{src}/{name}", mode="r")[key])
        except Exception as exc:  # noqa: BLE001 - whatever a damaged chunk raises, name the brick
            raise CorruptStoreError(
                f"{src}: brick {index} of channel {name!r} cannot be read ({type(exc).__name__}: {exc})"
            ) from None
        flat = data.reshape(-1, data.shape[-1])
        bad = be.first_out_of_range(be.from_bytes(flat), n2)
        if bad is not None:
            raise CorruptStoreError(f"{src}: brick {index} of channel {name!r}: ciphertext {bad} is not in (0, n²)")
        store_array(group, name)[key] = data
        digests.append(brick_digest(meta.store_id, name, index, data))
    store_array(group, "done")[index] = marker(digests)
    return index


def upgrade_store(
    src: str | os.PathLike[str], dst: str | os.PathLike[str], *, client: Any = None, progress: bool = True
) -> EncryptedVolume:
    """Copy the format-1 store ``src`` into a new format-2 store ``dst`` (module docstring).

    Parameters
    ----------
    src : str or Path
        A complete format-1 store; it is only read.
    dst : str or Path
        Where the new store goes; must not exist (:class:`hevr.StoreExistsError`, checked
        before any work and again, atomically, when the finished store is put there).
    client : distributed.Client, optional
        Defaults to the active client, else Dask's default scheduler.
    progress : bool
        Progress bar on stderr.

    Returns
    -------
    EncryptedVolume
        The new store, opened.

    Notes
    -----
    Locally the new store is built in a hidden sibling ``.NAME.hevr-new-…`` (locked while it
    is written, removed if the upgrade fails) and moved to ``dst`` only when complete, by a
    rename that never replaces anything (``renameat2(RENAME_NOREPLACE)``, else an exclusive
    ``mkdir`` claim): of two upgrades (or an upgrade and any other writer) into one path exactly
    one wins, and nothing already at ``dst`` is ever touched. An object store has no atomic create
    of a prefix: there ``dst`` is checked before the store is created in place, and a writer that
    creates it in between is not detected.
    """
    src, dst = normalise(src), normalise(dst)
    old = _old_metadata(src)
    if store_exists(dst):
        raise StoreExistsError(f"dst: {dst} already exists; choose a new path for the upgraded store")
    meta = dataclasses.replace(old, version=2, store_id=token() + token(), complete=False)
    build = str(temp_sibling(dst, "new")) if is_local(dst) else dst
    meta = create_store(build, meta)
    meta_dict = meta.to_dict()
    task = dask.delayed(_copy_brick, pure=False)
    tasks = [
        task(src, build, idx, meta_dict, dask_key_name=f"hevr-upgrade-{idx[0]}-{idx[1]}-{idx[2]}-{token()}")
        for idx in (tuple(int(i) for i in ix) for ix in np.ndindex(*meta.grid))
    ]
    try:
        with held_lock(build) if is_local(build) else contextlib.nullcontext():
            compute(tasks, client=client, progress=progress, desc="upgrade")
            zarr.open_group(build, mode="r+").attrs["hevr"] = dataclasses.replace(meta, complete=True).to_dict()
        if build != dst:
            _move_new(build, dst)
    except BaseException:
        log.warning("upgrade of %s failed; removing the partial new store %s", src, build)
        remove_tree(build)
        raise
    log.info("upgraded %s (format 1) to %s (format 2)", src, dst)
    return open_volume(dst)


def _move_new(build: str, dst: str) -> None:
    """Put the finished local store ``build`` at ``dst`` only if nothing is there: one rename
    that never replaces (:func:`hevr.store.exclusive.rename_noreplace`), under the folder's
    swap lock (never in the instant an overwrite's swap has moved an old store aside)."""
    try:
        with swap_lock(dst):
            rename_noreplace(build, dst)
    except OSError as exc:
        if exc.errno in (errno.EEXIST, errno.ENOTEMPTY):
            raise StoreExistsError(
                f"dst: {dst} already exists (created while the upgrade ran); choose a new path for the upgraded store"
            ) from None
        raise os_error(exc, "moving the upgraded store to", dst) from None
