"""Writing the encrypted volume store (``encrypt_volume``): Zarr v3 bricks of Paillier ciphertexts.

Layout (format ``hevr-encrypted-volume`` version 2, documented in ``docs/format.md``)::

    vol.zarr/
      zarr.json            group; attribute "hevr" = VolumeMetadata.to_dict() (checksummed)
      scalar/              uint8 (nz, ny, nx, W), chunks (bz, by, bx, W)      [optional]
      vector/              uint8 (k, nz, ny, nx, W), chunks (k, bz, by, bx, W) [optional]
      gradient/            uint8 (k, nz, ny, nx, W), chunks (k, bz, by, bx, W) [optional: g·e(d),
                           hevr.volume.gradient; needs vector, k more ciphertexts per voxel]
      done/                uint8 (gz, gy, gx, C, 32), chunks (1, 1, 1, C, 32): per brick,
                           the digest of each of its C channels (hevr.store.digests)

W is the ciphertext width in bytes (2·bits/8); every ciphertext is a big-endian record,
uncompressed, and every chunk ends in Zarr's crc32c. One chunk holds all of one brick's
bytes, and each encryption task writes only its own brick's chunks and then its own digest
marker, so no two tasks ever write the same chunk.

Nothing is lost: every input is checked (integer magnitudes against the key included)
before the disk is touched, and ``overwrite=True`` writes the new store beside the old one
and swaps the two only once the new one is complete, so a failure leaves the old store
intact. ``resume=True`` is refused for another input volume (:mod:`hevr.store.journal`).

>>> import tempfile, os, warnings, numpy as np, hevr
>>> with warnings.catch_warnings():
...     warnings.simplefilter("ignore")
...     pub, priv = hevr.generate_keypair(128)
>>> vol = np.arange(27, dtype=np.uint8).reshape(3, 3, 3)
>>> path = os.path.join(tempfile.mkdtemp(), "v.zarr")
>>> ev = hevr.encrypt_volume(vol, path, priv, brick=2, progress=False)
>>> ev.shape, ev.grid
((3, 3, 3), (2, 2, 2))
>>> priv.decrypt_array(ev.read_brick((1, 1, 1)))
[26]
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import dask
import dask.array
import numpy as np
import zarr

from ..backends import check_backend, resolve_backend_name
from ..core.files import fs_errors
from ..crypto.keys import PrivateKey, PublicKey
from ..errors import ParameterError, StoreError, StoreExistsError
from ..runtime.scheduler import active_client, check_encryption_client, compute
from ..volume import gradient as grad
from .authenticity import authenticate
from .brick_write import write_brick
from .creation import new_store, resume_target
from .digests import written
from .exclusive import lock_store, remove_leftovers
from .journal import check_journal, input_digests, remove_journal, write_journal
from .known import record_quietly
from .layout import array_slices, store_array
from .metadata import VolumeMetadata
from .packed_levels import build_pyramid, encrypt_levels, plan_levels, prepare_levels
from .paths import (
    check_reachable,
    check_storage_options,
    interrupted_swaps,
    is_local,
    normalise,
    store_exists,
    token,
    zarr_store,
)
from .reader import EncryptedVolume, open_volume
from .replacing import check_replaceable, remove_tree, swap
from .store_plan import plan_store

log = logging.getLogger(__name__)

__all__ = ["encrypt_volume", "open_volume", "EncryptedVolume"]


def _encrypt_brick(
    block: np.ndarray,
    path: str,
    index: tuple[int, int, int],
    meta_dict: dict[str, Any],
    key: Any,
    unsafe_no_obfuscation: bool,
    backend: str = "cpu",
    halo: grad.Halo | None = None,
    m_max: float = 0.0,
    storage_options: dict[str, Any] | None = None,
) -> tuple[int, int, int]:
    """One task: encrypt one plaintext brick and write its chunks, then its digest marker.

    With the gradient channel ``block`` carries a one-voxel ``halo`` of its neighbours
    (:mod:`hevr.volume.gradient`) and ``m_max`` is the whole volume's max |∇d| (owner side only).
    An ``OSError`` (disk full, read-only filesystem, …) becomes :class:`hevr.FileSystemError`
    naming the store and the reason only (never a value of the brick)."""
    with fs_errors("writing a brick of the store", path):
        return write_brick(
            block, path, index, meta_dict, key, unsafe_no_obfuscation, backend, halo, m_max, storage_options
        )


def encrypt_volume(
    vol: Any,
    path: str | Path,
    key: PublicKey | PrivateKey,
    *,
    spacing: Sequence[float] | None = None,
    brick: int | Sequence[int] = 32,
    scalar: bool = True,
    vector_dims: int | None = None,
    value_range: Sequence[float] | None = None,
    digits: int | None = None,
    vector_digits: int = 3,
    gradient: bool = False,
    overwrite: bool = False,
    resume: bool = False,
    progress: bool = True,
    client: Any = None,
    unsafe_no_obfuscation: bool = False,
    backend: str | None = None,
    storage_options: dict[str, Any] | None = None,
    verifiable: bool | None = None,
    layout: str = "voxel",
    pack_axis: int | str | None = None,
    levels: int = 0,
) -> EncryptedVolume:
    """Encrypt a 3-D volume brick by brick into a Zarr v3 store, one Dask task per brick.

    Parameters
    ----------
    vol : array_like (numpy, numpy memmap or dask array), shape (nz, ny, nx), or a Scan
        A :class:`hevr.Scan` (from :func:`hevr.read_scan`) brings its spacing and, when its
        file recorded patient geometry, its frame and origin (``ev.frame``, ``ev.patient_origin``).
    path : str or Path
        Target store: a local path or an fsspec URL (``file://`` is local; ``memory://`` not on a cluster).
    key : PublicKey or PrivateKey
        A private key selects the owner-side fast path (same ciphertext distribution); it is
        shipped to the Dask workers that encrypt, so it is used only on a cluster this process
        started or declared its own (:func:`hevr.own_cluster`), else
        :class:`hevr.ForeignClusterError` before anything is written (docs/security.md); on
        another party's cluster pass the public key.
    spacing : 3 floats, optional
        Voxel spacing in world order (sx, sy, sz); default the Scan's, else (1, 1, 1).
    brick : int or 3 ints
        Brick shape in array order; one Zarr chunk per brick.
    scalar : bool
        Store the scalar channel (X-ray).
    vector_dims : int, optional
        Also store the paper's k-dimensional density encoding (Alg. 4), k >= 2.
    value_range : (lo, hi), optional
        Density normalisation range. Integer dtypes default to the dtype's full range.
    digits : int, optional
        Decimal digits kept for float volumes (default 3). Integer volumes are exact.
    vector_digits : int
        Decimal digits of each encoded vector component (default 3).
    gradient : bool
        Also store the gradient channel g·e(d) (:mod:`hevr.volume.gradient`): the encoding
        scaled by each voxel's normalised gradient magnitude (central differences on the
        plaintext, in world units, over the whole volume), for ``hevr.render(...,
        gradient=True)``. Needs ``vector_dims``; same k and ``vector_digits``; costs k more
        ciphertexts per voxel (as much again as the vector channel) and one more read of the
        plaintext (the whole volume's max ``|∇d|``, which stays with the owner).
    overwrite, resume : bool
        Replace an existing store, or finish an interrupted run (only missing bricks).
    progress : bool
        Show a progress bar on stderr.
    client : distributed.Client, optional
        Defaults to the active client, else Dask's default scheduler.
    unsafe_no_obfuscation : bool
        NOT SECURE; only for reproducing the paper's "without obfuscation" benchmarks.
    backend : str, optional
        Arithmetic backend of the encrypting workers (:mod:`hevr.backends`); default: the
        Dask config key ``hevr.backend``, else ``"auto"``, which encrypts on ``cpu`` (no
        backend encrypts in kernels yet).
    storage_options : dict, optional
        Options of the URL's fsspec filesystem (endpoint, credentials, …; :mod:`hevr.store.paths`).
    verifiable : bool, optional
        Also store a tag channel ``<c>_tag`` beside every channel: per voxel (per packed
        ciphertext) and component E(α·m + β_v), with α and the PRF key of β derived from the private key
        (:mod:`hevr.crypto.tags`), so that renders can be checked against a lying server
        (:mod:`hevr.rendering.verify`). Needs the private key; twice the ciphertexts and about
        twice the encryption time. Default (None): True for a packed store encrypted with the
        private key (opt out with False), and for any store encrypted with a private key whose policy
        is that every store of it carries tags (``require_tags``, the default of new keys: False is
        refused then), False otherwise.
    layout : {"voxel", "packed"}
        ``"voxel"``: one ciphertext per voxel (every render, slice and pyramid works). ``"packed"``:
        S voxels along ``pack_axis`` in one ciphertext (:mod:`hevr.store.packing`; S and the slot
        width from the key, the value range and the shape, recorded in the metadata): about S
        times fewer ciphertexts, bytes and encryption time, rendered as parallel projections
        slice by slice (:mod:`hevr.rendering.packed`; views along the packing axis, perspective
        cameras, slices and the pyramid need a per-voxel store). The scalar channel, and with
        ``vector_dims`` the vector channel packed alike (same S and K, for transfer-function and
        emphasis frames: :mod:`hevr.rendering.packed.colour`); the gradient channel too.
    pack_axis : int or {"z", "y", "x"}, optional
        The packing axis of a packed store, as an array axis (0 = z) or its name; default 0, the
        scan's z axis (the patient's superior axis in RAS+), which serves every view around the body.
    levels : int
        Pyramid levels 1 … ``levels`` (0 to 8): a packed store's encrypted here, with slots of their own
        (:mod:`hevr.store.packed_levels`), a per-voxel store's built by :func:`hevr.build_pyramid`.

    Returns
    -------
    EncryptedVolume
        Its ``written_now`` dict says what this call encrypted: ``bricks`` and ``ciphertexts``
        (with ``resume=True`` only the missing bricks: 0 for a store that was complete).
    """
    if not isinstance(key, (PublicKey, PrivateKey)):
        raise ParameterError(f"key: expected a PublicKey or PrivateKey, got {type(key).__name__}")
    if unsafe_no_obfuscation:
        log.warning("encrypt_volume(unsafe_no_obfuscation=True): the store is NOT secure")
    backend = resolve_backend_name(backend)
    vol, brick_t, meta, levels = plan_store(
        vol,
        key,
        spacing=spacing,
        brick=brick,
        scalar=scalar,
        vector_dims=vector_dims,
        value_range=value_range,
        digits=digits,
        vector_digits=vector_digits,
        gradient=gradient,
        verifiable=verifiable,
        layout=layout,
        pack_axis=pack_axis,
        levels=levels,
    )
    planned = plan_levels(meta, levels) if meta.packing is not None else ()  # the packed levels' slots, before the disk
    path, so = normalise(path), check_storage_options(storage_options)
    check_encryption_client(client, isinstance(key, PrivateKey))  # another party's cluster: before any work
    check_reachable(path, active_client(client))
    check_backend(backend, active_client(client))  # CuPy, a device, a compiler: before the disk is touched
    exists = store_exists(path, so)
    if exists and not (resume or overwrite):
        raise StoreExistsError(
            f"path: {path} already exists; pass overwrite=True to replace it or resume=True to finish it"
        )
    local = is_local(path)
    if local:
        remove_leftovers(path)  # of killed or failed earlier runs (hevr.store.exclusive)
        left = interrupted_swaps(path)
        if left:
            log.warning("an interrupted or failed overwrite left %s beside %s; they are not touched", left, path)
    bricks = [(int(z), int(y), int(x)) for z, y, x in np.ndindex(*meta.grid)]
    with contextlib.ExitStack() as stack:  # the store's lock, held until the store is opened
        if exists and resume:
            if local:
                stack.enter_context(lock_store(path))
            old = resume_target(path, meta, so)
            # a finished store keeps everything built on it since (its pyramid levels)
            meta = authenticate(
                dataclasses.replace(meta, store_id=old.store_id, arrays=old.arrays, levels=old.levels), key
            )
            check_journal(meta.store_id, path, meta.fingerprint, input_digests(vol, brick_t, bricks, client))
            done = written(zarr.open_array(zarr_store(path, so, read_only=True), path="done", mode="r")[...])
            target = path
        else:
            if exists:
                check_replaceable(path, so)
                if local:
                    lock_store(path, hold=False)  # refuse at once to replace a store another run writes now
            meta = authenticate(dataclasses.replace(meta, store_id=token() + token()), key)
            write_journal(meta.store_id, path, meta.fingerprint, input_digests(vol, brick_t, bricks, client))
            try:
                target, meta, lock = new_store(path, meta, so, beside=exists)  # overwrite: beside, then swap
            except BaseException:
                remove_journal(meta.store_id)
                raise
            stack.enter_context(lock)
            done = np.zeros(meta.grid, bool)
        todo = [idx for idx in bricks if not done[idx]]
        log.info("encrypting %d of %d bricks into %s", len(todo), meta.n_bricks, target)
        try:
            meta = prepare_levels(target, meta, planned, key, so)  # a packed store's levels: recorded first
            values = _run(vol, brick_t, todo, target, meta, key, unsafe_no_obfuscation, backend, client, progress, so)
            meta, values = encrypt_levels(
                vol, brick_t, target, meta, key, unsafe_no_obfuscation, backend, client, progress, so, values
            )  # then encrypted: values + the levels' ciphertexts
        except BaseException:
            if target != path:
                log.warning(
                    "encryption failed; removing the partial new store %s, the old store %s is untouched", target, path
                )
                remove_tree(target, so)
            raise
        if target == path:
            ev = open_volume(path, storage_options=so)
        else:
            try:
                old_id, ev = swap(target, path, so, lock=lock, then=lambda: open_volume(path, storage_options=so))
            except StoreExistsError:  # refused before anything moved (another run writes the store now)
                remove_tree(target, so)
                raise
            remove_journal(old_id)  # the replaced store's resume evidence is of no more use
    if ev.meta.store_id != meta.store_id:
        raise StoreExistsError(
            f"path: the store at {path} was created or replaced by another run while this one "
            "wrote it; this run's store is not there"
        )
    if levels and meta.packing is None:  # a packed store's levels were encrypted above
        ev = build_pyramid(ev, levels, client=client, progress=progress, backend=backend)
    ev.written_now = {"bricks": len(todo), "ciphertexts": values}  # this call's share (resume: the missing ones)
    record_quietly(ev, key if isinstance(key, PrivateKey) else None, replace=True)  # the owner's: hevr.store.known
    return ev


def _run(
    vol: Any,
    brick: tuple[int, int, int],
    todo: list[tuple[int, int, int]],
    path: str,
    meta: VolumeMetadata,
    key: Any,
    unsafe_no_obfuscation: bool,
    backend: str,
    client: Any,
    progress: bool,
    storage_options: dict[str, Any] | None = None,
) -> int:
    """Encrypt the bricks ``todo`` into the store at ``path`` (one impure task per brick), then
    mark the store complete once every digest marker is written; returns the ciphertexts written."""
    # A random name: dask's default is a hash of the array's content, which would put a value
    # that confirms a guessed volume into the task graph, the scheduler's logs and dashboard.
    darr = (
        vol
        if isinstance(vol, dask.array.Array)
        else dask.array.from_array(vol, chunks=brick, name=f"hevr-plain-{token()}{token()}")
    )
    darr = darr.rechunk(brick)
    extra: list[dict[str, Any]] = [{} for _ in todo]
    if meta.gradient is not None and todo:
        # bricks with a one-voxel halo of their neighbours (none at the volume's faces), and the
        # whole volume's max |∇d| from a first pass: a task argument, never in a key or the store
        # (the halo blocks' names are hashes of the array's name, random above, not of the data)
        darr = dask.array.overlap.overlap(darr, depth=1, boundary="none")
        blocks = darr.to_delayed()
        m_max = grad.max_gradient_magnitude(
            blocks,
            meta.grid,
            meta.spacing,
            meta.value_range,
            lambda tasks: compute(tasks, client=client, progress=progress, desc="gradient"),
            token() + token(),
        )
        extra = [{"halo": grad.halo_of(idx, meta.grid), "m_max": m_max} for idx in todo]
    else:
        blocks = darr.to_delayed()
    task = dask.delayed(_encrypt_brick, pure=False)
    meta_dict = meta.to_dict()
    tasks = [
        task(
            blocks[idx],
            path,
            idx,
            meta_dict,
            key,
            unsafe_no_obfuscation,
            backend,
            **kw,
            storage_options=storage_options,
            dask_key_name=f"hevr-encrypt-{meta.fingerprint[:8]}-{idx[0]}-{idx[1]}-{idx[2]}-{token()}",
        )
        for idx, kw in zip(todo, extra)
    ]
    per_voxel = sum(c.dims or 1 for c in (meta.scalar, meta.vector, meta.gradient) if c is not None)
    values = sum(int(np.prod([s.stop - s.start for s in array_slices(meta, idx)])) for idx in todo) * per_voxel
    compute(tasks, client=client, progress=progress, desc="encrypt", steps=values, unit="ciphertexts")
    with fs_errors("finishing the store", path):
        group = zarr.open_group(zarr_store(path, storage_options), mode="r+")
        final = written(store_array(group, "done")[...])
        if not final.all():  # pragma: no cover - tasks raise instead
            raise StoreError(f"path: {int((~final).sum())} bricks of {path} are still missing")
        group.attrs["hevr"] = dataclasses.replace(meta, complete=True).to_dict()
    return values
