"""What the GPU proof's steps share (:mod:`hevr.bench.gpu_goals`, :mod:`hevr.bench.gpu_packed`):
rows appended to ``goals.jsonl`` as they are measured, the digest of an encrypted image (the identity
of two backends' frames), the steps' key, and a LocalCluster of single-threaded processes.

>>> import tempfile
>>> out = Path(tempfile.mkdtemp())
>>> append_row(out, {"step": "x", "seconds": 1.5}); read_rows(out)
[{'step': 'x', 'seconds': 1.5}]
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from distributed import Client, LocalCluster

from ..crypto.keyfile import load_key
from ..crypto.keys import generate_keypair
from ..errors import InsecureKeyWarning

__all__ = ["append_row", "bench_key", "image_digest", "local_cluster", "read_rows"]


def append_row(out: Path, row: dict) -> None:
    """One measured row, appended at once (a later step's fault cannot lose it)."""
    with open(out / "goals.jsonl", "a", encoding="utf-8") as f:
        f.write(json.dumps(row, default=str) + "\n")


def read_rows(out: Path) -> list[dict]:
    """The rows of ``out/goals.jsonl`` (none where it is missing)."""
    path = out / "goals.jsonl"
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def image_digest(img: Any) -> str:
    """SHA-256 over an encrypted image's ciphertext records (the identity of two backends' frames)."""
    h = hashlib.sha256()
    for c in img.ciphertexts:
        h.update(np.ascontiguousarray(c).tobytes())
    return h.hexdigest()


def bench_key(work: Path, bits: int = 0) -> Any:
    """The steps' key (``work/key.json``, 0600): loaded where it is, else made with ``bits`` (the
    ``stores`` step's; 0: a missing key is a :class:`FileNotFoundError`)."""
    path = work / "key.json"
    if path.is_file():
        with warnings.catch_warnings():  # the tests' small keys
            warnings.simplefilter("ignore", InsecureKeyWarning)
            return load_key(path)
    if not bits:
        raise FileNotFoundError(f"{path}: no key; run the stores step first")
    with warnings.catch_warnings():  # the tests' small keys: insecure on purpose
        warnings.simplefilter("ignore", InsecureKeyWarning)
        _, priv = generate_keypair(bits)
    priv.save(path)
    return priv


@contextlib.contextmanager
def local_cluster(workers: int) -> Iterator[Any]:
    """A client of a LocalCluster of ``workers`` single-threaded processes (not the default client)."""
    with (
        LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cl,
        Client(cl, set_as_default=False) as client,
    ):
        yield client
