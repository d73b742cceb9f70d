"""Opening an encrypted volume store and reading its bricks as ciphertexts."""

from __future__ import annotations

import functools
import json
import logging
import os
from functools import cached_property
from pathlib import Path
from typing import Any

import dask
import gmpy2
import numpy as np
import zarr

from .._dask import active_client
from .._validate import check_brick_index, check_choice
from ..backends import Backend, get_backend
from ..crypto.keys import PublicKey
from ..crypto.records import record_width
from ..errors import (
    CorruptStoreError,
    IncompleteStoreError,
    MissingFileError,
    ParameterError,
)
from .digests import DIGEST_BYTES, brick_digest, digest_hex, written
from .metadata import VolumeMetadata
from .paths import (
    document_digest,
    interrupted_swaps,
    is_local,
    normalise,
    read_document,
)
from .resident import Residency, load_brick, plan_residency

log = logging.getLogger(__name__)

__all__ = ["EncryptedVolume", "open_volume", "brick_slices", "array_layout", "CRC_BYTES"]

CRC_BYTES = 4  # Zarr's crc32c codec appends 4 bytes to every chunk


def array_layout(meta: VolumeMetadata) -> dict[str, tuple[tuple[int, ...], tuple[int, ...]]]:
    """``{array name: (shape, chunk shape)}`` of every array a store of ``meta`` has; the
    ``done`` array holds one digest per channel per brick (:mod:`hevr.store.digests`)."""
    w, out = meta.ciphertext_bytes, {}
    if meta.scalar is not None:
        out["scalar"] = (meta.shape + (w,), meta.brick + (w,))
    if meta.vector is not None:
        k = meta.vector.dims
        out["vector"] = ((k,) + meta.shape + (w,), (k,) + meta.brick + (w,))
    nch = len(meta.channel_names)
    out["done"] = (meta.grid + (nch, DIGEST_BYTES), (1, 1, 1, nch, DIGEST_BYTES))
    return out


def brick_slices(meta: VolumeMetadata, index: tuple[int, int, int]) -> tuple[slice, slice, slice]:
    """Array slices (z, y, x) of the voxels owned by brick ``index``."""
    return tuple(slice(i * b, min((i + 1) * b, s)) for i, b, s in zip(index, meta.brick, meta.shape))  # type: ignore[return-value]


@functools.lru_cache(maxsize=64)
def _array(path: str, store_id: str, name: str) -> Any:
    """One store array, opened once per process (a render task reads one brick of it; opening
    parses its metadata). Keyed by ``store_id`` too: a store replaced at the same path has
    another id, so a stale handle is never used; open_volume checks the documents each time."""
    return zarr.open_array(f"{path}/{name}", mode="r")


class EncryptedVolume:
    """A read-only handle on an encrypted volume store.

    Holds only the path and public metadata, so it pickles cheaply into Dask tasks; the
    Zarr arrays are opened lazily wherever the handle is used.
    """

    def __init__(self, path: str, meta: VolumeMetadata) -> None:
        self.path = str(path)
        self.meta = meta
        self.resident: Residency | None = None  # set on the handle persist() returns

    # -- public metadata -----------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        return self.meta.shape

    @property
    def spacing(self) -> tuple[float, float, float]:
        return self.meta.spacing

    @property
    def brick(self) -> tuple[int, int, int]:
        return self.meta.brick

    @property
    def grid(self) -> tuple[int, int, int]:
        return self.meta.grid

    @cached_property
    def public_key(self) -> PublicKey:
        return PublicKey(int(self.meta.n))

    @property
    def has_scalar(self) -> bool:
        return self.meta.scalar is not None

    @property
    def vector_dims(self) -> int | None:
        return self.meta.vector.dims if self.meta.vector is not None else None

    @property
    def value_range(self) -> tuple[float, float]:
        return self.meta.value_range

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self.meta.dtype)

    def __repr__(self) -> str:
        ch = ["scalar"] if self.has_scalar else []
        if self.vector_dims:
            ch.append(f"vector[{self.vector_dims}]")
        res = f", resident={'+'.join(self.resident.channels)}" if self.resident is not None else ""
        return (f"EncryptedVolume({self.path!r}, shape={self.shape}, brick={self.brick}, "
                f"channels={'+'.join(ch)}, key={self.meta.fingerprint[:16]}…{res})")

    def __getstate__(self) -> dict:
        return {"path": self.path, "meta": self.meta}  # never the resident bricks

    def __setstate__(self, state: dict) -> None:
        self.path, self.meta = state["path"], state["meta"]
        self.resident = None

    # -- residency -------------------------------------------------------------------------
    def persist(self, channels: Any = None, *, client: Any = None, backend: str | None = None) -> EncryptedVolume:
        """Keep this volume's decoded bricks in worker memory for the frames to come.

        Parameters
        ----------
        channels : str or sequence of str, optional
            ``"scalar"`` and/or ``"vector"``; default: every stored channel.
        client : distributed.Client, optional
            Default: the active client; without one the bricks stay in this process.
        backend : str, optional
            The renders' backend (:func:`hevr.backends.resolve_backend_name`).

        Returns
        -------
        EncryptedVolume
            A new handle whose renders take their bricks from memory (``.resident`` says
            where and how many bytes; :mod:`hevr.store.resident`). Like Dask's ``persist``
            it returns at once on a cluster (``.resident.wait()`` blocks until loaded).

        Raises
        ------
        MemoryLimitError
            A worker's share would exceed ``hevr.limits.resident-memory`` of its memory.
        """
        client = active_client(client)
        channels, backend, place, share = plan_residency(self, channels, backend, client)
        plain = EncryptedVolume(self.path, self.meta)
        if client is None:
            bricks = dict(zip(place, dask.compute(*[dask.delayed(load_brick, pure=False)(plain, idx, channels, backend)
                                                    for idx in place])))
        else:
            tag = f"{self.meta.store_id}-{'+'.join(channels)}-{backend}"
            bricks = {idx: client.submit(load_brick, plain, idx, channels, backend, workers=[w],
                                         allow_other_workers=True, pure=False,
                                         key=f"hevr-brick-{tag}-{idx[0]}-{idx[1]}-{idx[2]}")
                      for idx, w in place.items()}
        out = EncryptedVolume(self.path, self.meta)
        out.resident = Residency(channels, backend, bricks, client, sum(share.values()), share)
        return out

    # -- bricks --------------------------------------------------------------------------
    def brick_indices(self) -> list[tuple[int, int, int]]:
        return [tuple(int(i) for i in idx) for idx in np.ndindex(*self.grid)]  # type: ignore[misc]

    def brick_slices(self, index: tuple[int, int, int]) -> tuple[slice, slice, slice]:
        self._check_index(index)
        return brick_slices(self.meta, index)

    def brick_shape(self, index: tuple[int, int, int]) -> tuple[int, int, int]:
        return tuple(s.stop - s.start for s in self.brick_slices(index))  # type: ignore[return-value]

    def _check_index(self, index: Any) -> None:
        check_brick_index(index, self.grid, "index")

    def read_brick_bytes(self, index: tuple[int, int, int], channel: str = "scalar",
                         verify: bool = True) -> np.ndarray:
        """Raw ciphertext records of one brick: (bz, by, bx, W) or (k, bz, by, bx, W).

        With ``verify`` (the default) the brick's digest (:mod:`hevr.store.digests`) must
        match the one its writer recorded; a mismatch raises :class:`hevr.CorruptStoreError`
        naming the brick. Zarr's crc32c codec checks the chunk file itself in any case.
        """
        if channel not in ("scalar", "vector"):
            raise ParameterError(f"channel: expected 'scalar' or 'vector', got {channel!r}")
        if channel not in self.meta.channel_names:
            raise ParameterError(f"channel: this store has no {channel} channel")
        sl = self.brick_slices(index)
        index = tuple(int(i) for i in index)
        try:
            arr = _array(self.path, self.meta.store_id, channel)
            data = np.asarray(arr[sl if channel == "scalar" else (slice(None),) + sl])
            stored = np.asarray(_array(self.path, self.meta.store_id, "done")[index]) if verify else None
        except Exception as exc:
            raise CorruptStoreError(
                f"{self.path}: brick {index} of channel {channel!r} cannot be read ({type(exc).__name__}: {exc})"
            ) from None
        if verify:
            want = stored[self.meta.channel_names.index(channel)]
            if not want.any():
                raise CorruptStoreError(f"{self.path}: brick {index} of channel {channel!r} has no digest "
                                        "(its marker is missing: the brick was never finished or was removed)")
            got = brick_digest(self.meta.store_id, channel, index, data)
            if got != want.tobytes():
                raise CorruptStoreError(
                    f"{self.path}: brick {index} of channel {channel!r}: digest mismatch (recorded "
                    f"{digest_hex(want)}…, computed {digest_hex(got)}…): the chunk was corrupted, truncated, "
                    "swapped with another brick or copied from another store"
                )
        return data

    def read_brick(self, index: tuple[int, int, int], channel: str = "scalar", check: bool = True,
                   backend: str | Backend | None = None):
        """Ciphertexts of one brick in the backend's form, converted once: one batch (scalar)
        or k batches (vector). For the default ``cpu`` backend a batch is a list of mpz.

        With ``check`` (the default; ``False`` is for forensics only) the brick's digest must
        match and every ciphertext must lie in (0, n²); a violation raises
        :class:`hevr.CorruptStoreError` naming the brick; the backend checks its converted
        batch (:meth:`~hevr.backends.base.Backend.first_out_of_range`), the same rule for all.
        """
        be = get_backend(backend)
        data = self.read_brick_bytes(index, channel, verify=check)
        parts = [data] if channel == "scalar" else list(data)
        batches = [be.from_bytes(d) for d in parts]
        if check:
            n2 = int(self.public_key.nsquare)
            for part, batch in zip(parts, batches):
                i = be.first_out_of_range(batch, n2)
                if i is not None:
                    what = ">= n²" if part.reshape(-1, part.shape[-1])[i].any() else "zero (missing data)"
                    raise CorruptStoreError(
                        f"{self.path}: brick {tuple(index)} of channel {channel!r}: ciphertext {i} is {what}"
                    )
        return batches[0] if channel == "scalar" else batches

    def verify(self, coprime: bool = True) -> None:
        """Read every brick and check every ciphertext (range, and coprimality with n)."""
        n = self.public_key.n
        channels = (["scalar"] if self.has_scalar else []) + (["vector"] if self.vector_dims else [])
        for idx in self.brick_indices():
            for ch in channels:
                res = self.read_brick(idx, ch, backend="cpu")  # the gcd test below works on mpz
                lists = [res] if ch == "scalar" else res
                if coprime:
                    for cts in lists:
                        # one gcd per brick: gcd(prod c mod n, n) = 1 iff every c is a unit
                        prod = gmpy2.mpz(1)
                        for c in cts:
                            prod = prod * c % n
                        if gmpy2.gcd(prod, n) != 1:
                            raise CorruptStoreError(
                                f"{self.path}: brick {idx} of channel {ch!r} holds a ciphertext not coprime to n"
                            )


def _chunk_files_ok(path: str, meta: VolumeMetadata) -> None:
    """Local stores: every brick chunk (and digest marker) exists and has exactly the expected size."""
    root = Path(path)
    for name, (_, chunks) in array_layout(meta).items():
        expected = int(np.prod(chunks)) + CRC_BYTES
        lead = (0, 0) if name == "done" else (0,)
        for idx in np.ndindex(*meta.grid):
            key = "/".join(str(i) for i in ((0,) if name == "vector" else ()) + tuple(idx) + lead)
            f = root / name / "c" / key
            brick = tuple(int(i) for i in idx)
            where = "the digest markers 'done'" if name == "done" else f"channel {name!r}"
            if not f.exists():
                raise CorruptStoreError(f"{path}: missing chunk for brick {brick} in {where}")
            size = f.stat().st_size
            if size != expected:
                raise CorruptStoreError(f"{path}: chunk of brick {brick} in {where} is truncated "
                                        f"or padded ({size} bytes, expected {expected})")


_GROUP_KEYS = {"attributes": None, "zarr_format": 3, "node_type": "group", "consolidated_metadata": None}


def _check_documents(path: str, meta: VolumeMetadata) -> None:
    """Every byte of every metadata document counts (Zarr itself tolerates a misspelt key):
    each array's ``zarr.json`` must have the digest recorded in the checksummed ``hevr``
    attribute, and the group's ``zarr.json`` holds nothing but what hevr wrote."""
    try:
        doc = json.loads(read_document(path, ""))
        for name, want in meta.arrays.items():
            try:
                got = document_digest(path, name)
            except FileNotFoundError:
                raise CorruptStoreError(f"{path}: " + (f"channel {name!r} is declared but its array is missing"
                                        if name != "done" else "the digest array 'done' is missing")) from None
            if got != want:
                raise CorruptStoreError(f"{path}: the metadata document of array {name!r} was modified or "
                                        "corrupted (digest mismatch)")
    except (OSError, ValueError) as exc:
        raise CorruptStoreError(f"{path}: a metadata document cannot be read ({type(exc).__name__}: {exc})") from None
    extra = set(doc) - set(_GROUP_KEYS)
    wrong = [k for k, v in _GROUP_KEYS.items() if k != "attributes" and doc.get(k, v) != v]
    if extra or wrong or set(doc.get("attributes", {})) != {"hevr"}:
        raise CorruptStoreError(f"{path}: the group's zarr.json has unexpected content "
                                f"({sorted(extra) + wrong or 'attributes other than hevr'})")


def _check_arrays(path: str, group: Any, meta: VolumeMetadata) -> None:
    """Every array the metadata implies exists with exactly the layout hevr writes: shape,
    chunk shape, uint8, fill value 0, codecs ``bytes`` + ``crc32c``, no attributes."""
    for name, (shape, chunks) in array_layout(meta).items():
        try:  # a missing array was named by _check_documents already
            arr = group[name]
        except Exception as exc:
            raise CorruptStoreError(f"{path}: array {name!r} cannot be opened ({type(exc).__name__}: {exc})") from None
        codecs = [c.to_dict().get("name") for c in arr.metadata.codecs] if hasattr(arr.metadata, "codecs") else None
        got = (tuple(arr.shape), tuple(arr.chunks), str(arr.dtype), arr.metadata.fill_value, codecs, dict(arr.attrs))
        want = (shape, chunks, "uint8", 0, ["bytes", "crc32c"], {})
        if got != want or getattr(arr.metadata, "dimension_names", None) is not None:
            labels = ("shape", "chunks", "dtype", "fill_value", "codecs", "attributes")
            diff = "; ".join(f"{lab} {g!r} (expected {w!r})" for lab, g, w in zip(labels, got, want) if g != w)
            raise CorruptStoreError(f"{path}: array {name!r} has {diff or 'dimension names'}, inconsistent with the metadata")


def open_volume(path: str | os.PathLike, verify: str = "quick") -> EncryptedVolume:
    """Open an encrypted volume store.

    Parameters
    ----------
    path : str or Path
    verify : {"quick", "full", "none"}
        ``quick`` checks metadata, completeness and (for local stores) that every chunk
        exists with the exact size; ``full`` additionally reads every ciphertext and
        checks 0 < c < n² and gcd(c, n) = 1.

    Raises
    ------
    CorruptStoreError, IncompleteStoreError
        Naming what is wrong and where.
    """
    check_choice("verify", verify, ("quick", "full", "none"))
    path = normalise(path)  # absolute: workers may run in another working directory
    if is_local(path) and not Path(path).exists():
        left = interrupted_swaps(path)
        hint = (f" (an interrupted overwrite left {', '.join(Path(q).name for q in left)} beside it: rename "
                f"one of them to {Path(path).name})") if left else ""
        raise MissingFileError("path", "an encrypted volume store" + hint, path)
    try:
        group = zarr.open_group(path, mode="r")
        attrs = dict(group.attrs)
    except Exception as exc:
        raise CorruptStoreError(f"{path}: not a Zarr v3 group ({type(exc).__name__}: {exc})") from None
    meta = VolumeMetadata.from_dict(attrs.get("hevr"), where=path)
    if not meta.complete:
        try:
            missing = int((~written(group["done"][...])).sum())
        except Exception:
            missing = meta.n_bricks
        raise IncompleteStoreError(
            f"{path}: store is incomplete ({missing} of {meta.n_bricks} bricks missing); "
            "finish it with encrypt_volume(..., resume=True)"
        )
    if PublicKey(int(meta.n)).fingerprint != meta.fingerprint:
        raise CorruptStoreError(f"{path}: the stored key fingerprint does not match the stored modulus n")
    w_expected = record_width(int(meta.n))
    if meta.ciphertext_bytes != w_expected:
        raise CorruptStoreError(f"{path}: ciphertext_bytes is {meta.ciphertext_bytes}, expected {w_expected} for this key")
    _check_documents(path, meta)
    _check_arrays(path, group, meta)
    if verify != "none" and "://" not in path:
        _chunk_files_ok(path, meta)
    ev = EncryptedVolume(path, meta)
    if verify == "full":
        ev.verify()
    return ev
