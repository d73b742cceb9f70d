"""The ciphertexts of one brick: its mantissas encrypted in small batches.

Between two batches an interrupted job stops (:mod:`hevr.runtime.cancel`: Ctrl-C ends ``hevr encrypt``
within a batch, not a brick) and a progress display of this process counts the values done, so
it moves while a brick is encrypted, not only when a brick is written.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..runtime import cancel, stats

__all__ = ["BATCH", "encrypt_components"]

# Values encrypted between two checks for an interrupt (and progress steps) on the CPU: under a
# second on the public-key path at 2048 bits, 0.1 s on the owner's. Accelerator backends take a component whole.
BATCH = 64


def encrypt_components(
    be: Any, key: Any, q: Sequence[Any] | np.ndarray, shape: tuple[int, ...], width: int, unsafe: bool
) -> np.ndarray:
    """(k, bz, by, bx, W) records of the k rows of mantissas ``q`` (a (k, voxels) array, or a
    list of lists), encrypted in batches of :data:`BATCH` on the CPU: between two an
    interrupted job stops (:func:`hevr.runtime.cancel.check`) and a progress display of this process
    moves (:func:`hevr.runtime.cancel.add_steps`)."""
    out = np.empty((len(q),) + shape + (width,), dtype=np.uint8)
    with cancel.batched_steps():  # on a worker: one event every 0.25 s, not one per batch
        for j, row in enumerate(q):
            cancel.check()
            if be.name != "cpu":  # one batch (an accelerator's); its own type of result
                with stats.timed("encrypt.crypto", len(row)):
                    cts = be.encrypt(key, row, unsafe_no_obfuscation=unsafe)
                cancel.add_steps(len(row))
            else:
                cts = []
                for lo in range(0, len(row), BATCH):
                    cancel.check()
                    part = row[lo : lo + BATCH]
                    with stats.timed("encrypt.crypto", len(part)):
                        cts.extend(be.encrypt(key, part, unsafe_no_obfuscation=unsafe))
                    cancel.add_steps(len(part))
            out[j] = be.to_bytes(cts, width).reshape(shape + (width,))
    return out
