"""What the integrity checks cost, on the paper case (100³ phantom, 150² image, 2048-bit key,
2-worker LocalCluster, brick 25).

    python benchmarks/integrity.py --dir DIR [--rounds 8] [--trilinear-rounds 2]

Builds DIR/scalar.zarr and DIR/key.json once (owner-path encryption, ~7 min on 2 cores), then
alternates, round by round, renders with the store checks on (as shipped: each brick's digest,
hevr/store/digests.py, against its marker) and off (the digest comparison patched out on every worker), for
nearest and trilinear X-ray, and client decryptions with the plaintext range checks on and
off (patched out). The crc32c of every chunk is part of Zarr's codec and cannot be switched
off on one store; its cost is measured separately over the store's bytes. Render times on a
small shared machine vary by ±10 % from run to run, more than the checks cost, so the script
also measures, with little noise, the CPU time of reading every brick with and without the
digest check in one process. The decrypted images of both arms must be identical. Appends a section to
benchmarks/history.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from _machine import append, machine  # noqa: E402

import hevr  # noqa: E402
from hevr.backends.cpu import CpuBackend  # noqa: E402
from hevr.image import encrypted as image_mod  # noqa: E402

_REAL_UNPACK = image_mod._unpack_checked
_REAL_RANGE = CpuBackend.first_out_of_range


def _unpack_unchecked(plain, need, pack_bits, per_pack, bound):
    """The unpacking as it was before the checks: digits only, nothing compared."""
    if per_pack == 1:
        return plain, None
    vals, digit = [], (1 << pack_bits) - 1
    for m in plain:
        for _ in range(per_pack):
            vals.append(m & digit)
            m >>= pack_bits
    return vals[:need], None


def _set_decrypt_checks(on: bool) -> None:
    """In the client: the shipped plaintext and ciphertext range checks, or none."""
    image_mod._unpack_checked = _REAL_UNPACK if on else _unpack_unchecked
    CpuBackend.first_out_of_range = _REAL_RANGE if on else (lambda self, values, nsquare: None)


def _set_store_checks(on: bool) -> int:
    """Runs on each worker: the shipped read, or the same read without the digest check.
    The shipped method is kept on the module the first time (a pickled reference to it would
    resolve to whatever the class holds when it arrives). Returns how many reads skipped it."""
    from hevr.store import reader

    cls = reader.EncryptedVolume
    if not hasattr(reader, "_bench_shipped_read"):
        reader._bench_shipped_read = cls.read_brick_bytes
        reader._bench_skipped = 0
    shipped = reader._bench_shipped_read

    def unchecked(self, index, channel="scalar", verify=True):
        reader._bench_skipped += 1
        return shipped(self, index, channel, verify=False)

    cls.read_brick_bytes = shipped if on else unchecked
    return reader._bench_skipped


def _build(folder: Path, client) -> None:
    if (folder / "scalar.zarr").exists():
        return
    folder.mkdir(parents=True, exist_ok=True)
    pub, priv = hevr.generate_keypair(2048)
    priv.save(folder / "key.json")
    t = time.perf_counter()
    hevr.encrypt_volume(hevr.phantom(100), folder / "scalar.zarr", priv, brick=25, client=client, progress=False)
    print(f"built {folder / 'scalar.zarr'} in {time.perf_counter() - t:.0f} s", flush=True)


def _crc_seconds(store: Path) -> float:
    import google_crc32c

    files = [f for f in (store / "scalar" / "c").rglob("*") if f.is_file()]
    blobs = [f.read_bytes() for f in files]
    t = time.perf_counter()
    for b in blobs:
        google_crc32c.value(b)
    return time.perf_counter() - t


def _read_cost(ev, repeats: int) -> tuple[float, float]:
    """CPU seconds to read every brick once with and without the digest check (this
    process, alternating per brick, best of ``repeats``): the check's cost per render."""
    on = off = 0.0
    for idx in ev.brick_indices():
        best = {True: float("inf"), False: float("inf")}
        for r in range(repeats):
            for verify in (True, False) if r % 2 == 0 else (False, True):
                t = time.process_time()
                ev.read_brick_bytes(idx, "scalar", verify=verify)
                best[verify] = min(best[verify], time.process_time() - t)
        on, off = on + best[True], off + best[False]
    return on, off


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dir", type=Path, required=True)
    ap.add_argument("--rounds", type=int, default=8, help="rounds of nearest renders (default 8)")
    ap.add_argument("--trilinear-rounds", type=int, default=2, help="rounds of trilinear renders (default 2)")
    ap.add_argument("--build-only", action="store_true")
    args = ap.parse_args(argv)
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster, Client(cluster) as client:
        _build(args.dir, client)
        if args.build_only:
            return
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            priv = hevr.load_key(args.dir / "key.json")
        ev = hevr.open_volume(args.dir / "scalar.zarr")
        cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=150, height=150)
        times: dict = {}
        images: dict = {}
        for r in range(args.rounds):
            for sampling in ("nearest", "trilinear") if r < args.trilinear_rounds else ("nearest",):
                for on in (True, False) if r % 2 == 0 else (False, True):
                    client.run(_set_store_checks, on)
                    t = time.perf_counter()
                    img = hevr.render(ev, cam, sampling=sampling, cache=False, progress=False, client=client)
                    times.setdefault(("render", sampling, on), []).append(time.perf_counter() - t)
                    for check in (
                        (True, False, True, False, True, False)
                        if r % 2 == 0
                        else (False, True, False, True, False, True)
                    ):
                        _set_decrypt_checks(check)
                        t = time.perf_counter()
                        pix = img.decrypt(priv)
                        times.setdefault(("decrypt", sampling, check), []).append(time.perf_counter() - t)
                        images.setdefault(sampling, pix)
                        assert np.array_equal(images[sampling], pix), "checks changed the image"
                    _set_decrypt_checks(True)
                skipped = client.run(_set_store_checks, True)
                print(
                    f"round {r + 1} (reads without digest check so far: {skipped}): "
                    + ", ".join(f"{k[0]}/{k[1]}/{'on' if k[2] else 'off'} {v[-1]:.2f}s" for k, v in times.items()),
                    flush=True,
                )
        crc = _crc_seconds(args.dir / "scalar.zarr")
        read_on, read_off = _read_cost(ev, 5)
    med = {k: statistics.median(v) for k, v in times.items()}
    lines = ["| step | checks on s (median) | checks off s (median) | overhead |", "|---|---:|---:|---:|"]
    for what in ("render", "decrypt"):
        for sampling in ("nearest", "trilinear"):
            on, off = med[(what, sampling, True)], med[(what, sampling, False)]
            lines.append(f"| {what} {sampling} | {on:.2f} | {off:.2f} | {100 * (on / off - 1):+.1f} % |")
    text = "\n".join(lines)
    print(text)
    append(
        f"## Integrity checks: cost on the paper case (issue 12)\n\nMachine: {machine()}\n\n"
        f"100³ phantom, 2048-bit key, owner-encrypted, brick 25, 150² px X-ray, 2-worker LocalCluster "
        f"(1 thread each); {args.rounds} rounds of nearest and {args.trilinear_rounds} of trilinear renders, "
        "arms alternated within each round, images identical in "
        f"both arms. Store checks = each brick's digest (on every read); decrypt checks = "
        f"the plaintext range checks of EncryptedImage (one core, the client).\n\n{text}\n\n"
        f"crc32c (Zarr codec, always on) over all {ev.meta.n_bricks} scalar chunks "
        f"({ev.meta.n_bricks * 25**3 * ev.meta.ciphertext_bytes / 1e6:.0f} MB): {crc:.2f} s of CPU in one "
        f"process, i.e. about {crc / 2:.2f} s of wall time spread over 2 workers.\n\n"
        f"Reading all {ev.meta.n_bricks} bricks once in one process (best of 5 per brick, CPU time): "
        f"{read_on:.3f} s with the digest check, {read_off:.3f} s without; the check costs "
        f"{read_on - read_off:.3f} s of CPU per render, "
        f"i.e. {100 * (read_on - read_off) / (2 * med[('render', 'nearest', True)]):.1f} % "
        f"of the 2 workers' time in a nearest render and "
        f"{100 * (read_on - read_off) / (2 * med[('render', 'trilinear', True)]):.1f} % in a trilinear one.\n"
    )


if __name__ == "__main__":
    main()
