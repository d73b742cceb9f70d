"""Issue 16: what the tooth store occupies, with edge bricks padded (codecs bytes + crc32c, the
format before) and without padding (bytes + zstd + crc32c, now), and what zstd costs on read.

Both stores hold the same kind of ciphertexts of the shared tooth (103 × 94 × 161, uint8) in
32³ bricks; the "before" store is written with the old codec chain by this script. Reads of the
two stores alternate in one process (5 rounds), so the ratio is measured under the same load.

Usage::

    python benchmarks/storage.py KEY.json OUT.json [TOOTH.nhdr]
"""

import json
import sys
import time
import warnings
from pathlib import Path
from unittest import mock

import numpy as np
from zarr.codecs import Crc32cCodec

import hevr
from hevr.store import writer

warnings.simplefilter("ignore")


def du(p: Path) -> int:
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())


def read_all(ev) -> float:
    t = time.perf_counter()
    for idx in ev.brick_indices():
        ev.read_brick_bytes(idx, "scalar")
    return time.perf_counter() - t


if __name__ == "__main__":
    key, out = hevr.load_key(sys.argv[1]), Path(sys.argv[2])
    tooth = sys.argv[3] if len(sys.argv) > 3 else str(Path(__file__).resolve().parents[2] / "shared/data/tooth.nhdr")
    vol, spacing = hevr.load_volume(tooth)
    work = out.parent / "storage-work"
    work.mkdir(exist_ok=True)
    rows, evs = {}, {}
    for label in ("before", "after"):
        legacy = mock.patch.object(writer, "compressors", lambda name: [Crc32cCodec()])
        with legacy if label == "before" else mock.MagicMock():
            t = time.perf_counter()
            ev = hevr.encrypt_volume(
                vol, work / f"{label}.zarr", key, spacing=spacing, brick=32, overwrite=True, progress=False
            )
            enc = time.perf_counter() - t
        cipher = int(np.prod(vol.shape)) * key.public_key.ciphertext_bytes
        store = du(Path(ev.path))
        rows[label] = {
            "store_bytes": store,
            "ciphertext_bytes": cipher,
            "overhead": (store - cipher) / cipher,
            "scalar_array_bytes": du(Path(ev.path) / "scalar"),
            "encrypt_s": enc,
        }
        evs[label] = ev
    reads = {k: [] for k in evs}
    for _ in range(5):
        for k in evs:
            reads[k].append(read_all(hevr.open_volume(evs[k].path)))
    opens = {k: [] for k in evs}
    for _ in range(3):
        for k in evs:
            t = time.perf_counter()
            hevr.open_volume(evs[k].path)
            opens[k].append(time.perf_counter() - t)
    for k in evs:
        rows[k]["read_all_bricks_s"] = sorted(reads[k])
        rows[k]["open_quick_s"] = min(opens[k])
    sys.path.insert(0, str(Path(__file__).parent))
    from _machine import machine

    res = {
        "machine": machine(),
        "key_bits": key.public_key.bits,
        "shape_zyx": list(vol.shape),
        "brick": 32,
        "bricks": len(evs["after"].brick_indices()),
        "rows": rows,
    }
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res, indent=1))
