"""Opening an encrypted volume store and reading its bricks as ciphertexts."""

from __future__ import annotations

import logging
import os
from functools import cached_property
from pathlib import Path
from typing import Any

import gmpy2
import numpy as np
import zarr

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
from .metadata import VolumeMetadata

log = logging.getLogger(__name__)

__all__ = ["EncryptedVolume", "open_volume", "brick_slices"]


def brick_slices(meta: VolumeMetadata, index: tuple[int, int, int]) -> tuple[slice, slice, slice]:
    """Array slices (z, y, x) of the voxels owned by brick ``index``."""
    return tuple(slice(i * b, min((i + 1) * b, s)) for i, b, s in zip(index, meta.brick, meta.shape))  # type: ignore[return-value]


class EncryptedVolume:
    """A read-only handle on an encrypted volume store.

    Holds only the path and public metadata, so it pickles cheaply into Dask tasks; the
    Zarr arrays are opened lazily wherever the handle is used.
    """

    def __init__(self, path: str, meta: VolumeMetadata) -> None:
        self.path = str(path)
        self.meta = meta

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
        return (f"EncryptedVolume({self.path!r}, shape={self.shape}, brick={self.brick}, "
                f"channels={'+'.join(ch)}, key={self.meta.fingerprint[:16]}…)")

    def __getstate__(self) -> dict:
        return {"path": self.path, "meta": self.meta}

    def __setstate__(self, state: dict) -> None:
        self.path, self.meta = state["path"], state["meta"]

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

    def read_brick_bytes(self, index: tuple[int, int, int], channel: str = "scalar") -> np.ndarray:
        """Raw ciphertext records of one brick: (bz, by, bx, W) or (k, bz, by, bx, W)."""
        if channel not in ("scalar", "vector"):
            raise ParameterError(f"channel: expected 'scalar' or 'vector', got {channel!r}")
        if channel == "scalar" and not self.has_scalar or channel == "vector" and not self.vector_dims:
            raise ParameterError(f"channel: this store has no {channel} channel")
        sl = self.brick_slices(index)
        try:
            arr = zarr.open_array(f"{self.path}/{channel}", mode="r")
            data = arr[sl if channel == "scalar" else (slice(None),) + sl]
        except Exception as exc:
            raise CorruptStoreError(
                f"{self.path}: brick {tuple(index)} of channel {channel!r} cannot be read ({type(exc).__name__}: {exc})"
            ) from None
        return np.asarray(data)

    def read_brick(self, index: tuple[int, int, int], channel: str = "scalar", check: bool = True,
                   backend: str | Backend | None = None):
        """Ciphertexts of one brick in the backend's form, converted once: one batch (scalar)
        or k batches (vector). For the default ``cpu`` backend a batch is a list of mpz.

        With ``check`` every ciphertext must lie in (0, n²); a violation raises
        :class:`hevr.CorruptStoreError` naming the brick; the backend checks its converted
        batch (:meth:`~hevr.backends.base.Backend.first_out_of_range`), the same rule for all.
        """
        be = get_backend(backend)
        data = self.read_brick_bytes(index, channel)
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
    """Local stores: every brick chunk exists and has exactly the expected size."""
    root = Path(path)
    for name, lead in (("scalar", ()), ("vector", (0,))):
        info = getattr(meta, name)
        if info is None:
            continue
        k = info.dims or 1
        expected = int(np.prod(meta.brick)) * meta.ciphertext_bytes * (k if name == "vector" else 1)
        for idx in np.ndindex(*meta.grid):
            key = "/".join(str(i) for i in lead + tuple(idx) + (0,))
            f = root / name / "c" / key
            if not f.exists():
                raise CorruptStoreError(f"{path}: missing chunk for brick {tuple(int(i) for i in idx)} in channel {name!r}")
            size = f.stat().st_size
            if size != expected:
                raise CorruptStoreError(
                    f"{path}: chunk of brick {tuple(int(i) for i in idx)} in channel {name!r} is truncated "
                    f"or padded ({size} bytes, expected {expected})"
                )


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
    path = str(path)
    if "://" not in path:
        if not Path(path).exists():
            raise MissingFileError("path", "an encrypted volume store", path)
        path = str(Path(path).resolve())  # workers may run in another working directory
    try:
        group = zarr.open_group(path, mode="r")
        attrs = dict(group.attrs)
    except Exception as exc:
        raise CorruptStoreError(f"{path}: not a Zarr v3 group ({type(exc).__name__}: {exc})") from None
    meta = VolumeMetadata.from_dict(attrs.get("hevr"), where=path)
    if not meta.complete:
        try:
            done = np.asarray(group["done"][...])
            missing = int((done == 0).sum())
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
    for name in ("scalar", "vector"):
        info = getattr(meta, name)
        if info is None:
            continue
        try:
            arr = group[name]
        except KeyError:
            raise CorruptStoreError(f"{path}: channel {name!r} is declared but its array is missing") from None
        lead = (info.dims,) if name == "vector" else ()
        if tuple(arr.shape) != lead + meta.shape + (meta.ciphertext_bytes,) or arr.dtype != np.uint8:
            raise CorruptStoreError(f"{path}: array {name!r} has shape {arr.shape} / dtype {arr.dtype}, inconsistent with the metadata")
    if verify != "none" and "://" not in path:
        _chunk_files_ok(path, meta)
    ev = EncryptedVolume(path, meta)
    if verify == "full":
        ev.verify()
    return ev
