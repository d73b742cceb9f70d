"""Issue 15: an axial slice of the 2048-bit paper phantom at the volume's own grid (100²) and at
150², streamed and resident, render and end to end (client decryption included).

Usage::

    python benchmarks/slice_native.py WORKDIR OUT.json    # WORKDIR of benchmarks/beyond.py (key.json, scalar.zarr)
"""

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from distributed import Client, LocalCluster

import hevr

warnings.simplefilter("ignore")
if __name__ == "__main__":
    work, out = Path(sys.argv[1]), sys.argv[2]
    priv = hevr.load_key(work / "key.json")
    vol = hevr.phantom(100)
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as c, Client(c) as cl:
        ev = hevr.open_volume(work / "scalar.zarr")
        rows = []
        for resident in (False, True):
            src = ev.persist(client=cl) if resident else ev
            if resident:
                src.resident.wait()
            for size in (100, 150):
                plane = hevr.Plane.axial(ev, 50) if size == 100 else hevr.Plane.axial(ev, 50, width=150, height=150)
                for _rep in range(3):
                    hevr.clear_cache()
                    t = time.perf_counter()
                    img = hevr.render_slice(src, plane, cache=False, progress=False)
                    r = time.perf_counter() - t
                    arr = img.decrypt(priv)
                    tot = time.perf_counter() - t
                    assert np.abs(arr - hevr.render_slice_plain(vol, plane)).max() < 1e-9
                    rows.append(
                        {
                            "resident": resident,
                            "image": size,
                            "render_s": round(r, 3),
                            "end_to_end_s": round(tot, 3),
                            "ciphertexts": img.n_ciphertexts,
                        }
                    )
                    print(rows[-1], flush=True)
        Path(out).write_text(json.dumps(rows, indent=1) + "\n")
