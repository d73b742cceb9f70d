"""Reading one brick of a store, checked: its ciphertext records, their digest against the one the
writer recorded (:mod:`hevr.store.digests`), and each ciphertext in (0, n²) once converted to the
backend's form. :class:`hevr.EncryptedVolume`'s ``read_brick_bytes`` and ``read_brick`` are these.

A task process opens each array once (:func:`open_array`, a small LRU keyed by the store's id).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import TYPE_CHECKING, Any

import numpy as np
import zarr

from ..backends import Backend, get_backend
from ..core.validate import check_brick_index
from ..crypto.tags import data_channel
from ..errors import CorruptStoreError, ParameterError
from .digests import brick_digest, digest_hex
from .layout import array_slices, check_document, check_entry, chunk_key
from .metadata import CHANNELS
from .paths import zarr_store

if TYPE_CHECKING:
    from .reader import EncryptedVolume

__all__ = ["open_array", "read_batches", "read_records"]

_ARRAYS: OrderedDict[tuple[str, str, str, str], zarr.Array[Any]] = OrderedDict()
_ARRAYS_LOCK = threading.Lock()
_ARRAYS_SIZE = 64


def open_array(path: str, store_id: str, name: str, storage_options: dict[str, Any] | None = None) -> zarr.Array[Any]:
    """One store array, opened once per process (a render task reads one brick of it; opening
    parses its metadata). Keyed by ``store_id`` too: a store replaced at the same path has
    another id, so a stale handle is never used; open_volume checks the documents each time.
    The options enter the key as their ``repr`` (they need not be hashable), kept only here."""
    key = (path, store_id, name, repr(sorted((storage_options or {}).items())))
    with _ARRAYS_LOCK:
        if key in _ARRAYS:
            _ARRAYS.move_to_end(key)
            return _ARRAYS[key]
    check_document(path, name)  # a FIFO in its place would block Zarr's open
    arr = zarr.open_array(zarr_store(path, storage_options, read_only=True), path=name, mode="r")
    with _ARRAYS_LOCK:
        _ARRAYS[key] = arr
        while len(_ARRAYS) > _ARRAYS_SIZE:
            _ARRAYS.popitem(last=False)
    return arr


def read_records(ev: EncryptedVolume, index: tuple[int, int, int], channel: str, verify: bool) -> np.ndarray:
    """:meth:`hevr.EncryptedVolume.read_brick_bytes`: the records of brick ``index`` of ``channel``,
    their digest checked with ``verify``."""
    if not isinstance(channel, str) or data_channel(channel) not in CHANNELS:
        raise ParameterError(
            f"channel: expected 'scalar', 'vector' or 'gradient' (or its tag channel '<channel>_tag'), got {channel!r}"
        )
    if channel not in ev.meta.channel_names:
        raise ParameterError(f"channel: this store has no {channel} channel")
    check_brick_index(index, ev.grid, "index")
    sl = array_slices(ev.meta, index)  # a packed store's records: pack units along its axis
    index = (int(index[0]), int(index[1]), int(index[2]))
    where = f"brick {index} of channel {channel!r}" + (f" of level {ev.level}" if ev.level else "")
    for name in (channel, "done") if verify else (channel,):  # a FIFO there would block Zarr's read
        what = f"the chunk of {where}" if name == channel else f"the digest marker of {where}"
        check_entry(ev.path, f"{ev.prefix}{name}/{chunk_key(name, index)}", what)
    try:
        so = ev.storage_options
        arr = open_array(ev.path, ev.meta.store_id, ev.prefix + channel, so)
        data = np.asarray(arr[sl if data_channel(channel) == "scalar" else (slice(None),) + sl])
        stored = np.asarray(open_array(ev.path, ev.meta.store_id, ev.prefix + "done", so)[index]) if verify else None
    except Exception as exc:
        why = (
            "its chunk fails its crc32c check: the file was damaged"
            if "checksum" in str(exc).lower()
            else f"{type(exc).__name__}: {exc}"
        )
        raise CorruptStoreError(f"{ev.path}: {where} cannot be read ({why})") from None
    if stored is not None:
        want = stored[ev.meta.channel_names.index(channel)]
        if not want.any():
            raise CorruptStoreError(
                f"{ev.path}: {where} has no digest (its marker is missing: the brick was never finished or was removed)"
            )
        got = brick_digest(ev.meta.store_id, ev.prefix + channel, index, data)
        if got != want.tobytes():
            raise CorruptStoreError(
                f"{ev.path}: {where}: digest mismatch (recorded "
                f"{digest_hex(want)}…, computed {digest_hex(got)}…): the chunk was corrupted, truncated, "
                "swapped with another brick or copied from another store"
            )
    return data


def read_batches(
    ev: EncryptedVolume, index: tuple[int, int, int], channel: str, check: bool, backend: str | Backend | None
) -> Any:
    """:meth:`hevr.EncryptedVolume.read_brick`: the brick's records (``ev.read_brick_bytes``)
    converted to ``backend``'s form, each ciphertext in (0, n²) with ``check``."""
    be = get_backend(backend)
    data = ev.read_brick_bytes(index, channel, verify=check)
    parts = [data] if data_channel(channel) == "scalar" else list(data)
    batches = [be.from_bytes(d) for d in parts]
    if check:
        n2 = int(ev.public_key.nsquare)
        for part, batch in zip(parts, batches):
            i = be.first_out_of_range(batch, n2)
            if i is not None:
                what = ">= n²" if part.reshape(-1, part.shape[-1])[i].any() else "zero (missing data)"
                lv = f" of level {ev.level}" if ev.level else ""
                raise CorruptStoreError(
                    f"{ev.path}: brick {tuple(index)} of channel {channel!r}{lv}: ciphertext {i} is {what}"
                )
    return batches[0] if data_channel(channel) == "scalar" else batches
