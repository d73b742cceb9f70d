"""Resident volumes: decoded bricks held in the workers' memory across frames.

``ev = hevr.open_volume(path).persist()`` reads every brick once (Zarr read, digest check,
bytes -> the backend's integers) into worker memory; every later frame's map tasks take
their brick from there and do no store read and no conversion. Without ``persist`` a render
streams its bricks from the store, as before. Both give the identical image.

Placement. On a ``distributed`` client, below :data:`BATCH_BITS`-bit keys the bricks in raster
order are cut into N runs of about equal bytes, run ``w`` loaded on worker ``w`` (the brick whose
bytes straddle the middle of the cumulative total ``w·T/N`` decides by its midpoint): each worker
holds one slab of whole bricks. A slab is one box, so a worker that maps all its bricks in one
task (:func:`hevr.rendering.pipeline.maps.map_group`) generates only the samples of rays inside its slab.
From :data:`BATCH_BITS` on (one map task per brick) brick ``i`` goes to worker ``i mod N``, which
spreads each worker's bricks over the whole image. Placement is a loose restriction: if a worker
dies, any worker recomputes the brick from the store. Each :class:`ResidentBrick` reports its true
size to Dask, so the scheduler
runs a brick's map task where the brick lives (moving a brick costs far more than its
task's output). On a single machine (no client) the bricks stay in this process.

Memory. A resident ciphertext costs the backend's :meth:`~hevr.backends.base.Backend.residue_bytes`:
for ``cpu`` a gmpy2 ``mpz`` and its list slot, ``40 + 8·ceil(W/8) + 8`` bytes for W-byte
records (560 at a 2048-bit key, 64 at 64 bits). A
resident volume of V voxels and C stored channels (1 scalar + k vector components + k gradient
components) holds
``V·C`` of them; each worker holds the bricks assigned to it, at most
``ceil(bricks/N)·brick voxels·C`` ciphertexts. :func:`plan_residency` states this before
anything is loaded and refuses (``MemoryLimitError``) when a worker's share would exceed the
fraction ``hevr.limits.resident-memory`` (Dask config, default 0.5) of its memory limit
(on a single machine: of the memory available now). Where the backend keeps residues on a GPU
(``cuda``: :attr:`hevr.backends.base.Backend.residence` is ``"device"``) the bricks are in the
GPU's memory, in Montgomery form, and the share is of each worker's device memory (its total
on a cluster, what is free now on a single machine), counting what a frame needs beside the
bricks there (:meth:`~hevr.backends.base.Backend.frame_bytes`: for ``cuda`` one joined copy of
them and the kernels' scratch); such bricks are always placed in slabs and mapped one task per
worker (:func:`batched`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import dask
import numpy as np
import psutil

from ..backends import get_backend, resolve_backend_name
from ..core.validate import check_choice
from ..crypto.tags import data_channel
from ..errors import MemoryLimitError, ParameterError
from ..runtime.scheduler import workers_of
from .layout import array_slices

log = logging.getLogger(__name__)

__all__ = [
    "ResidentBrick",
    "Residency",
    "batched",
    "load_brick",
    "load_residency",
    "plan_residency",
    "RESIDENT_MEMORY_KEY",
]

RESIDENT_MEMORY_KEY = "hevr.limits.resident-memory"
# Below this key size a render maps a worker's resident bricks in one task
# (hevr.rendering.encrypted, config hevr.render.resident-batch "auto"), so they are placed in slabs.
BATCH_BITS = 1024
DEFAULT_RESIDENT_MEMORY = 0.5


class ResidentBrick:
    """The decoded ciphertexts of one brick, per channel, in the backend's form.

    Opaque to Dask (it is not traversed when passed to a task) and sized truthfully
    (``__sizeof__``: the host memory it holds), so the scheduler keeps work where the brick is.
    ``nbytes`` is the residues' memory wherever they are; on a GPU (``device``) that is device
    memory, which Dask's memory manager must not count as its own (it would spill the brick to
    disk to free host memory it never took): such a brick's ``__sizeof__`` is its host side only.
    The price: the scheduler then sees moving one as cheap. A frame maps each worker's device
    bricks in one task, which goes where all of them are; should work stealing still move one,
    the brick travels as numpy limbs (pickled) and the thief uploads it for each frame: the same
    image, more slowly.
    """

    __slots__ = ("index", "batches", "nbytes", "device")

    HOST_SIDE = 4096  # bytes of Python objects around a device brick's arrays

    def __init__(self, index: tuple[int, int, int], batches: dict[str, Any], nbytes: int, device: bool = False) -> None:
        self.index, self.batches, self.nbytes, self.device = index, batches, int(nbytes), bool(device)

    def channel(self, name: str) -> Any:
        """One batch (``scalar``) or the k batches (``vector``, ``gradient``) of this brick."""
        return self.batches[name]

    def __sizeof__(self) -> int:
        return self.HOST_SIDE if self.device else self.nbytes

    def __repr__(self) -> str:
        where = " on the device" if self.device else ""
        return f"ResidentBrick({self.index}, channels={sorted(self.batches)}, {self.nbytes} bytes{where})"


def batched(bits: int, backend: str) -> bool:
    """Whether a render maps each worker's resident bricks in one task (config ``"auto"``), which
    places them in slabs: below :data:`BATCH_BITS`-bit keys, and always where the backend keeps
    residues on a GPU, whose frame is then a few large launches over all of a worker's bricks
    rather than a small launch per brick.

    >>> batched(64, "cpu"), batched(2048, "cpu"), batched(2048, "cuda")
    (True, False, True)
    """
    return int(bits) < BATCH_BITS or get_backend(backend).residence == "device"


def _device_memory(backend: str) -> tuple[int, int] | None:
    """(free, total) device bytes of ``backend`` here (run on each worker by :func:`plan_residency`)."""
    return get_backend(backend).memory()


def residue_bytes(width: int, backend: str | None = "cpu") -> int:
    """Bytes one ciphertext of ``width`` record bytes takes resident in ``backend``'s form
    (:meth:`hevr.backends.base.Backend.residue_bytes`).

    >>> residue_bytes(512), residue_bytes(16)
    (560, 64)
    """
    return get_backend(backend).residue_bytes(width)


def load_brick(ev: Any, index: tuple[int, int, int], channels: tuple[str, ...], backend: str) -> ResidentBrick:
    """Read, check and convert one brick's channels (a Dask task on the worker that keeps it)."""
    be = get_backend(backend)
    batches = {ch: ev.read_brick(index, ch, backend=be) for ch in channels}
    n_cts = sum(len(b) if data_channel(ch) == "scalar" else sum(len(x) for x in b) for ch, b in batches.items())
    return ResidentBrick(
        (index[0], index[1], index[2]),
        batches,
        n_cts * be.residue_bytes(ev.meta.ciphertext_bytes),
        device=be.residence == "device",
    )


@dataclass
class Residency:
    """Where a resident volume's bricks live and what they cost.

    Attributes
    ----------
    channels : tuple of str
        The resident channels; a render of another channel streams it from the store.
    backend : str
        The backend whose form the bricks are held in.
    bricks : dict
        Brick index -> ``distributed.Future`` (on a client) or :class:`ResidentBrick`.
    client : distributed.Client or None
    nbytes : int
        Total bytes held, all workers together.
    worker_bytes : dict
        Worker address (``"local"`` on a single machine) -> bytes assigned to it.
    """

    channels: tuple[str, ...]
    backend: str
    bricks: dict
    client: Any
    nbytes: int
    worker_bytes: dict = field(default_factory=dict)

    def usable(self, channel: str, backend: str, client: Any) -> bool:
        """Whether a render of ``channel`` with ``backend`` on ``client`` can use these bricks."""
        return (
            bool(self.bricks)
            and channel in self.channels
            and backend == self.backend
            and (client is self.client)
            and (client is None or client.status == "running")
        )

    def wait(self) -> None:
        """Block until every brick is loaded (re-raises a brick's read error)."""
        if self.client is not None:
            self.client.gather(list(self.bricks.values()))

    def release(self) -> None:
        """Drop the bricks from memory (their futures are released)."""
        self.bricks.clear()
        self.worker_bytes.clear()
        self.nbytes = 0


def _slabs(bricks: list, cost: dict, workers: list) -> dict:
    """Brick -> worker: runs of raster order of about equal cost (see the module docstring).

    >>> _slabs([0, 1, 2, 3], {0: 8, 1: 8, 2: 1, 3: 1}, ["a", "b"])
    {0: 'a', 1: 'b', 2: 'b', 3: 'b'}
    """
    total = sum(cost[b] for b in bricks) or 1
    place, before = {}, 0
    for b in bricks:
        mid = before + cost[b] / 2
        place[b] = workers[min(len(workers) - 1, int(mid * len(workers) / total))]
        before += cost[b]
    return place


def _memory_fraction() -> float:
    frac = dask.config.get(RESIDENT_MEMORY_KEY, DEFAULT_RESIDENT_MEMORY)
    try:
        frac = float(frac)
    except (TypeError, ValueError):
        frac = -1.0
    if not 0.0 < frac <= 1.0:
        raise ParameterError(f"{RESIDENT_MEMORY_KEY}: expected a fraction in (0, 1], got {frac!r}")
    return frac


def plan_residency(ev: Any, channels: Any, backend: Any, client: Any) -> tuple[tuple[str, ...], str, dict, dict]:
    """Check a persist request; return channels, backend, brick -> worker and worker -> bytes.

    Raises :class:`hevr.MemoryLimitError` before anything is loaded when a worker's share
    would exceed ``hevr.limits.resident-memory`` of its memory limit.
    """
    stored = tuple(ev.meta.data_channels)  # tag channels are always streamed (hevr.rendering.verify)
    if channels is None:
        channels = stored
    elif isinstance(channels, str):
        channels = (channels,)
    elif not isinstance(channels, (list, tuple)):
        raise ParameterError(
            f"channels: expected 'scalar', 'vector', 'gradient' or a list of them, got {type(channels).__name__}"
        )
    channels = tuple(dict.fromkeys(check_choice("channels", c, stored) for c in channels))
    if not channels:
        raise ParameterError(f"channels: expected some of {list(stored)}, got none")
    backend = resolve_backend_name(backend, int(ev.public_key.n).bit_length(), client=client)
    per_ct = residue_bytes(ev.meta.ciphertext_bytes, backend)
    be = get_backend(backend)
    device = be.residence == "device"  # then the share is of each worker's GPU memory
    k = sum(ev.meta.components(c) for c in channels)
    bricks = ev.brick_indices()
    # records per brick: its voxels, or a packed store's packs (S voxels each)
    cost = {idx: int(np.prod([s.stop - s.start for s in array_slices(ev.meta, idx)])) * k * per_ct for idx in bricks}
    if client is not None:
        info = workers_of(client)  # not scheduler_info(): it may say none under load
        workers = sorted(info)
        if not workers:
            raise ParameterError("client: expected a cluster with workers, got none")
        limits = {w: info[w].get("memory_limit") or psutil.virtual_memory().total for w in workers}
        if device:  # a GPU worker's total device memory (one worker per GPU: docs/operator/deploy.md)
            got = client.run(_device_memory, backend, workers=workers)
            limits = {w: got[w][1] if got.get(w) else limits[w] for w in workers}
    else:
        workers = ["local"]
        here = be.memory() if device else None
        limits = {"local": here[0] if here else psutil.virtual_memory().available}
    if batched(int(ev.public_key.n).bit_length(), backend):
        place = _slabs(bricks, cost, workers)
    else:  # mapped one task per brick: spread evenly over the image (measured 4 % faster at 2048 bits)
        place = {idx: workers[i % len(workers)] for i, idx in enumerate(bricks)}
    share = {w: 0 for w in workers}
    for idx, w in place.items():
        share[w] += cost[idx]
    frac = _memory_fraction()
    for w in workers:
        frame = be.frame_bytes(share[w])  # what a frame takes beside the bricks, where they live
        if share[w] + frame > frac * limits[w]:
            raise MemoryLimitError(
                f"persist: expected at most {frac:g} of worker {w}'s {'device ' if device else ''}memory "
                f"({frac * limits[w] / 2**20:.1f} MiB), "
                f"got {share[w] / 2**20:.1f} MiB of resident bricks ({per_ct} bytes per ciphertext, "
                f"channels {'+'.join(channels)})"
                + (f" and {frame / 2**20:.1f} MiB a frame needs beside them" if frame else "")
                + f"; add workers, persist fewer channels, or raise {RESIDENT_MEMORY_KEY}"
            )
    log.info(
        "persist %s: %d bricks, %s, %.1f MiB in all, at most %.1f MiB per worker%s",
        ev.path,
        len(bricks),
        "+".join(channels),
        sum(share.values()) / 2**20,
        max(share.values()) / 2**20,
        " (device memory)" if device else "",
    )
    return channels, backend, place, share


def load_residency(ev: Any, plain: Any, channels: Any, backend: Any, client: Any) -> Residency:
    """:meth:`hevr.EncryptedVolume.persist`: plan the bricks' places (:func:`plan_residency`), then
    load each brick of ``plain`` (``ev`` without residency) there: in this process without a
    client (one Dask task per brick), else one future per brick on its worker."""
    channels, backend, place, share = plan_residency(ev, channels, backend, client)
    bricks: dict[tuple[int, int, int], Any]
    if client is None:
        loads = [dask.delayed(load_brick, pure=False)(plain, idx, channels, backend) for idx in place]
        bricks = dict(zip(place, dask.compute(*loads)))
    else:
        tag = f"{ev.meta.store_id}-{'+'.join(channels)}-{backend}"
        bricks = {
            idx: client.submit(
                load_brick,
                plain,
                idx,
                channels,
                backend,
                workers=[w],
                allow_other_workers=True,
                pure=False,
                key=f"hevr-brick-{tag}-{idx[0]}-{idx[1]}-{idx[2]}",
            )
            for idx, w in place.items()
        }
    return Residency(channels, backend, bricks, client, sum(share.values()), share)
