"""Opening an encrypted volume store and reading its bricks as ciphertexts.

A store is a location (:mod:`hevr.store.paths`): a path or fsspec URL and its
``storage_options``. The handle keeps both, so the Dask tasks it is pickled into reach the same
store; the options (object-store credentials, never hevr key material) stay out of its ``repr``
and of every message. A brick is read and checked by :mod:`hevr.store.brick_read`.
"""

from __future__ import annotations

import logging
import os
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from ..backends import Backend
from ..core.validate import check_brick_index, check_choice
from ..crypto.keys import PublicKey
from ..crypto.records import record_width
from ..errors import (
    CorruptStoreError,
    IncompleteStoreError,
    MissingFileError,
)
from ..runtime.scheduler import active_client
from ..volume.pyramid import check_level, level_origin
from .brick_read import read_batches, read_records
from .digests import written
from .layout import (
    CRC_BYTES,
    array_layout,
    brick_slices,
    check_arrays,
    check_chunk_files,
    check_chunk_objects,
    check_document,
    check_documents,
    check_level_layout,
    store_array,
)
from .metadata import VolumeMetadata
from .paths import (
    check_reachable,
    check_storage_options,
    interrupted_swaps,
    is_local,
    normalise,
    store_exists,
    zarr_store,
)
from .resident import Residency, load_residency
from .verify import check_brick

log = logging.getLogger(__name__)

__all__ = ["EncryptedVolume", "open_volume", "brick_slices", "array_layout", "CRC_BYTES"]


class EncryptedVolume:
    """A read-only handle on an encrypted volume store.

    Holds only the location (path and ``storage_options``) and public metadata, so it pickles
    cheaply into Dask tasks; the Zarr arrays are opened lazily wherever the handle is used.
    """

    written_now: dict[str, int]  # set by encrypt_volume on the handle it returns: what that call encrypted

    def __init__(
        self,
        path: str,
        meta: VolumeMetadata,
        level: int = 0,
        base: VolumeMetadata | None = None,
        storage_options: dict[str, Any] | None = None,
    ) -> None:
        self.path = str(path)
        self.storage_options = check_storage_options(storage_options)  # never in repr or messages
        self.meta = meta
        self.level = int(level)  # pyramid level: 0 is the volume itself (hevr.store.pyramid)
        self.base = base if level else None  # level 0's metadata, for a level's view
        self.resident: Residency | None = None  # set on the handle persist() returns

    @property
    def prefix(self) -> str:
        """Where this level's arrays live in the group: ``""``, or ``"levels/<level>/"``."""
        return f"levels/{self.level}/" if self.level else ""

    @property
    def _level0(self) -> VolumeMetadata:
        """Level 0's metadata: this volume's, or a level's view's ``base``."""
        return self.base if self.base is not None else self.meta

    @property
    def origin(self) -> tuple[float, float, float]:
        """World position of voxel (0, 0, 0)'s centre: the origin, or a level's offset."""
        return level_origin(self._level0.spacing, self.level) if self.level else (0.0, 0.0, 0.0)

    @property
    def levels(self) -> int:
        """Complete pyramid levels above this volume (0 without a pyramid; 0 for a level's view)."""
        if self.level:
            return 0
        done = 0
        for info in self.meta.levels:
            if not info.complete:
                break
            done += 1
        return done

    def at_level(self, level: int) -> EncryptedVolume:
        """A read-only view of pyramid level ``level`` as a volume of its own (its shape,
        spacing, exponents and arrays; :meth:`hevr.EncryptedVolume.origin` says where it sits);
        level 0 is this volume. Renders take it through ``hevr.render(..., level=)``."""
        base = self._level0
        so = self.storage_options
        ev0 = self if not self.level else EncryptedVolume(self.path, base, storage_options=so)
        level = check_level(level, ev0.levels)
        if level == 0:
            return EncryptedVolume(self.path, base, storage_options=so)
        view = EncryptedVolume(self.path, base.level_meta(level), level, base, storage_options=so)
        check_level_layout(view)
        return view

    def _plain(self) -> EncryptedVolume:
        """The same volume (and level) without residency."""
        return EncryptedVolume(self.path, self.meta, self.level, self.base, self.storage_options)

    # -- public metadata -----------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        return self.meta.shape

    @property
    def spacing(self) -> tuple[float, float, float]:
        return self.meta.spacing

    @property
    def frame(self) -> str | None:
        """``"RAS"`` when the input recorded patient geometry (the store is in RAS+, so the
        camera's anatomical views apply), else ``None`` (axes as the input stored them)."""
        return self.meta.patient.get("frame")

    @property
    def patient_origin(self) -> tuple[float, float, float] | None:
        """World position (mm, RAS+) of voxel (0, 0, 0) as the input file recorded it, or ``None``."""
        return self.meta.patient.get("origin")

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
    def layout(self) -> str:
        """``"voxel"`` (one ciphertext per voxel) or ``"packed"`` (S voxels per ciphertext along
        ``packing.axis``: :mod:`hevr.store.packing`; rendered by :mod:`hevr.rendering.packed`)."""
        return self.meta.layout

    @property
    def packing(self) -> Any:
        """The :class:`~hevr.store.packing.PackingInfo` of a packed store, else None."""
        return self.meta.packing

    @property
    def has_scalar(self) -> bool:
        return self.meta.scalar is not None

    @property
    def vector_dims(self) -> int | None:
        return self.meta.vector.dims if self.meta.vector is not None else None

    @property
    def has_gradient(self) -> bool:
        """Whether the store holds the gradient channel g·e(d) (``encrypt_volume(..., gradient=True)``,
        :mod:`hevr.volume.gradient`): what ``hevr.render(..., gradient=True)`` reads."""
        return self.meta.gradient is not None

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
        if self.has_gradient:
            ch.append(f"gradient[{self.vector_dims}]")
        res = f", resident={'+'.join(self.resident.channels)}" if self.resident is not None else ""
        packed = (
            f", layout=packed[{self.packing.slots}x{self.packing.slot_bits} bits, axis {self.packing.axis}]"
            if self.packing is not None
            else ""
        )
        return (
            f"EncryptedVolume({self.path!r}, shape={self.shape}, brick={self.brick}, "
            f"channels={'+'.join(ch)}{packed}, key={self.meta.fingerprint[:16]}…{res})"
        )

    def __getstate__(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "meta": self.meta,
            "level": self.level,
            "base": self.base,  # never the bricks
            "storage_options": self.storage_options,
        }

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.path, self.meta = state["path"], state["meta"]
        self.storage_options = state.get("storage_options")
        self.level, self.base = state.get("level", 0), state.get("base")
        self.resident = None

    # -- residency -------------------------------------------------------------------------
    def persist(self, channels: Any = None, *, client: Any = None, backend: str | None = None) -> EncryptedVolume:
        """Keep this volume's decoded bricks in worker memory for the frames to come.

        Parameters
        ----------
        channels : str or sequence of str, optional
            ``"scalar"``, ``"vector"`` and/or ``"gradient"``; default: every stored channel.
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
        check_reachable(self.path, client)
        out = self._plain()
        out.resident = load_residency(self, self._plain(), channels, backend, client)
        return out

    # -- bricks --------------------------------------------------------------------------
    def brick_indices(self) -> list[tuple[int, int, int]]:
        return [(int(z), int(y), int(x)) for z, y, x in np.ndindex(*self.grid)]

    def brick_slices(self, index: tuple[int, int, int]) -> tuple[slice, slice, slice]:
        self._check_index(index)
        return brick_slices(self.meta, index)

    def brick_shape(self, index: tuple[int, int, int]) -> tuple[int, int, int]:
        z, y, x = self.brick_slices(index)
        return z.stop - z.start, y.stop - y.start, x.stop - x.start

    def _check_index(self, index: Any) -> None:
        check_brick_index(index, self.grid, "index")

    def read_brick_bytes(self, index: tuple[int, int, int], channel: str = "scalar", verify: bool = True) -> np.ndarray:
        """Raw ciphertext records of one brick: (bz, by, bx, W) (``scalar``) or (k, bz, by, bx, W)
        (``vector``, ``gradient``).

        With ``verify`` (the default) the brick's digest (:mod:`hevr.store.digests`) must
        match the one its writer recorded; a mismatch raises :class:`hevr.CorruptStoreError`
        naming the brick. Zarr's crc32c codec checks the chunk file itself in any case.
        """
        return read_records(self, index, channel, verify)

    def read_brick(
        self,
        index: tuple[int, int, int],
        channel: str = "scalar",
        check: bool = True,
        backend: str | Backend | None = None,
    ) -> Any:
        """Ciphertexts of one brick in the backend's form, converted once: one batch (scalar)
        or k batches (vector, gradient). For the default ``cpu`` backend a batch is a list of mpz.

        With ``check`` (the default; ``False`` is for forensics only) the brick's digest must
        match and every ciphertext must lie in (0, n²); a violation raises
        :class:`hevr.CorruptStoreError` naming the brick; the backend checks its converted
        batch (:meth:`~hevr.backends.base.Backend.first_out_of_range`), the same rule for all.
        """
        return read_batches(self, index, channel, check, backend)

    def verify(self, coprime: bool = True) -> None:
        """Read every brick and check every ciphertext (digest, range, and coprimality with n);
        the first damaged brick raises :class:`hevr.CorruptStoreError` naming it. To name every
        damaged brick (in Dask tasks on a cluster) use :func:`hevr.store.verify.verify_bricks`."""
        for idx in self.brick_indices():
            problems = check_brick(self, idx, coprime)
            if problems:
                raise CorruptStoreError(f"{self.path}: {problems[0]}")


def open_volume(
    path: str | os.PathLike[str], verify: str = "quick", *, storage_options: dict[str, Any] | None = None
) -> EncryptedVolume:
    """Open an encrypted volume store.

    Parameters
    ----------
    path : str or Path
        A local path or an fsspec URL (``file://`` is the local path; ``s3://bucket/v.zarr``, …).
    verify : {"quick", "full", "none"}
        ``quick`` checks metadata, completeness and that every chunk exists with a plausible
        size (local stores: each file's; object stores: one listing of every array's
        objects), for level 0 and every complete pyramid level; ``full``
        additionally reads every ciphertext of every level and checks 0 < c < n² and
        gcd(c, n) = 1.
    storage_options : dict, optional
        Options of the URL's fsspec filesystem (endpoint, credentials, …), kept by the handle for
        the tasks that read the store (never shown in its repr or in messages).

    Raises
    ------
    CorruptStoreError, IncompleteStoreError
        Naming what is wrong and where.
    """
    check_choice("verify", verify, ("quick", "full", "none"))
    so = check_storage_options(storage_options)
    path = normalise(path)  # absolute: workers may run in another working directory
    if not is_local(path) and not store_exists(path, so):
        raise MissingFileError("path", "an encrypted volume store", path)
    if is_local(path) and not Path(path).exists():
        left = interrupted_swaps(path)
        hint = (
            (
                f" (an interrupted overwrite left {', '.join(Path(q).name for q in left)} beside it: rename "
                f"one of them to {Path(path).name})"
            )
            if left
            else ""
        )
        raise MissingFileError("path", "an encrypted volume store" + hint, path)
    check_document(path, "")  # a FIFO there would block Zarr's open
    try:
        group = zarr.open_group(zarr_store(path, so, read_only=True), mode="r")
        attrs = dict(group.attrs)
    except Exception as exc:
        raise CorruptStoreError(f"{path}: not a Zarr v3 group ({type(exc).__name__}: {exc})") from None
    meta = VolumeMetadata.from_dict(attrs.get("hevr"), where=path)
    if not meta.complete:
        try:
            missing = int((~written(store_array(group, "done")[...])).sum())
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
        raise CorruptStoreError(
            f"{path}: ciphertext_bytes is {meta.ciphertext_bytes}, expected {w_expected} for this key"
        )
    check_documents(path, meta, so)
    check_arrays(path, group, meta)
    if verify != "none":
        check_chunk_files(path, meta) if is_local(path) else check_chunk_objects(path, meta, "", so)
    ev = EncryptedVolume(path, meta, storage_options=so)
    levels = [ev.at_level(level) for level in range(1, ev.levels + 1)] if verify != "none" else []  # their layout
    if verify == "full":
        for view in [ev, *levels]:
            view.verify()
    return ev
