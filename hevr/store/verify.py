"""The full check of a store: read every brick back and check every ciphertext.

What ``open_volume(path, verify="full")`` and ``hevr info STORE --verify`` do, beyond the quick
check that opening a store always makes (metadata, documents, chunk sizes): each brick of each
channel, at level 0 and at every complete pyramid level, is read (Zarr's crc32c of the chunk
file), its digest compared with the one its writer recorded (:mod:`hevr.store.digests`: a
flipped bit, a truncated, swapped or foreign chunk), and every ciphertext must lie in
(0, n²) and be coprime to n (one gcd per brick: gcd(∏ c mod n, n) = 1 iff every c is a unit).

One task per brick returns only the problems it found (a few short strings), so memory stays
at one brick per running task whatever the size of the store: Dask tasks on the active
``distributed`` client, else a loop in this process, one brick after another. Every damaged
brick is named, not just the first.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import dask
import gmpy2

from ..crypto.tags import data_channel
from ..errors import CorruptStoreError
from ..runtime.scheduler import active_client, compute
from .paths import check_reachable

log = logging.getLogger(__name__)

__all__ = ["BrickProblem", "VerifyReport", "check_brick", "verify_bricks"]


@dataclass(frozen=True)
class BrickProblem:
    """One damaged brick of one channel: where it is, and the reader's message, which names
    the brick, its channel and level, and what is wrong (without the store's path)."""

    level: int
    index: tuple[int, int, int]
    channel: str
    reason: str

    def __str__(self) -> str:
        return self.reason


@dataclass
class VerifyReport:
    """What :func:`verify_bricks` found: ``bricks`` read (every level together; a brick holds
    every stored channel) and the ``problems`` (empty: the store is intact)."""

    bricks: int
    problems: list[BrickProblem] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def damaged(self) -> list[tuple[int, tuple[int, int, int]]]:
        """The damaged bricks as (level, index), each once, in order."""
        return list(dict.fromkeys((p.level, p.index) for p in self.problems))


def _reason(exc: CorruptStoreError, path: str) -> str:
    """The message of a brick's read error without the store path it starts with."""
    text = str(exc)
    return text[len(path) + 2 :] if text.startswith(path + ": ") else text


def check_brick(ev: Any, index: tuple[int, int, int], coprime: bool = True) -> list[BrickProblem]:
    """Read brick ``index`` of every channel of the volume (or level view) ``ev`` and return
    its problems (none: it is intact); reading errors other than damage propagate."""
    index = (int(index[0]), int(index[1]), int(index[2]))
    out = []
    for ch in ev.meta.channel_names:
        try:
            res = ev.read_brick(index, ch, backend="cpu")  # digest and range; the gcd below works on mpz
            if coprime:
                n = ev.public_key.n
                for cts in [res] if data_channel(ch) == "scalar" else res:
                    prod = gmpy2.mpz(1)
                    for c in cts:
                        prod = prod * c % n
                    if gmpy2.gcd(prod, n) != 1:
                        lv = f" of level {ev.level}" if ev.level else ""
                        raise CorruptStoreError(
                            f"{ev.path}: brick {index} of channel {ch!r}{lv} holds a ciphertext not coprime to n"
                        )
        except CorruptStoreError as exc:
            out.append(BrickProblem(ev.level, index, ch, _reason(exc, ev.path)))
    return out


def verify_bricks(
    ev: Any, *, client: Any = None, coprime: bool = True, levels: bool = True, progress: bool = False
) -> VerifyReport:
    """Read every brick of ``ev`` (and, with ``levels``, of every complete pyramid level) and
    check it (module docstring).

    Parameters
    ----------
    ev : EncryptedVolume
        An opened store (``open_volume(path, verify="none")`` is enough: this reads it all).
    client : distributed.Client, optional
        Default: the active client; one task per brick there, else one brick after another here.
    coprime : bool
        Also check that every ciphertext is a unit mod n.
    levels : bool
        Also the complete pyramid levels.
    progress : bool
        Show progress (:mod:`hevr.runtime.progress`).

    Returns
    -------
    VerifyReport
        How many bricks were read and every damaged brick of every channel.
    """
    views = [ev]
    if levels and not ev.level:
        views += [ev.at_level(level) for level in range(1, ev.levels + 1)]
    jobs = [(view, idx) for view in views for idx in view.brick_indices()]
    client = active_client(client)
    if client is not None:
        check_reachable(ev.path, client)
        tasks = [dask.delayed(check_brick, pure=False)(view._plain(), idx, coprime) for view, idx in jobs]
        found = compute(tasks, client=client, progress=progress, desc="verify")
    else:
        found = [check_brick(view, idx, coprime) for view, idx in jobs]
    report = VerifyReport(len(jobs), [p for problems in found for p in problems])
    log.info("verified %s: %d bricks read, %d damaged", ev.path, report.bricks, len(report.damaged))
    return report
