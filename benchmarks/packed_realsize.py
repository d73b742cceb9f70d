"""Issue 46: a real-size packed store at 2048 bits, encrypted and rendered on this machine,
in process and through ``hevr serve``, verified and not.

Usage::

    python benchmarks/packed_realsize.py WORKDIR OUT.json [--shape 150 256 256] [--image 256]
    python benchmarks/packed_realsize.py --project-voxel OUT.json results-packed-2048.json   # per-voxel frames
    python benchmarks/packed_realsize.py --check OUT.json         # the key holder's check at 512² of 512×512×300
    python benchmarks/packed_realsize.py --report OUT.json > RESULTS-packed-realsize.md

Steps (one run, one key, one machine):

* a CT-like volume (int16, 12-bit values 0–4095: a body ellipse of soft tissue, lungs, a spine and
  ribs, noise), spacing 0.8 × 0.8 × 2.0 mm (x, y, z), z (array axis 0) the superior axis;
* the owner encrypts it packed along z with the private key (tags by default): seconds, bytes,
  ciphertexts; and a crop of it twice, with tags and without (``verifiable=False``), for the
  tags' encryption ratio;
* on a 2-worker LocalCluster (1 thread each), for an anterior view and a general view (azimuth 60,
  elevation 10), nearest and bilinear: the frame unverified (render + decryption) and verified
  (render + the tags' round + decryption with the key holder's check), with the check's seconds
  alone, the operations counted, and the picture checked against ``render_plain(..., slices=True)``
  within ``error_bound``;
* ``hevr serve`` of the store (2 workers) and ``hevr.connect``: the verified frames again, each the
  in-process picture exactly;
* the per-voxel store of the same volume, projected: its bytes (one 512-byte ciphertext per voxel)
  and its encryption at the packed run's measured seconds per ciphertext.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import hevr
from hevr.bench.measure import dir_bytes, machine

warnings.simplefilter("ignore")

VIEWS = {"anterior": (90.0, 0.0), "general": (60.0, 10.0)}
SAMPLINGS = ("nearest", "trilinear")
SPACING = (0.8, 0.8, 2.0)  # (x, y, z) mm, as hevr orders spacing


def ct_like(shape: tuple[int, int, int], seed: int = 7) -> np.ndarray:
    """A CT-like int16 volume of 12-bit values (public synthetic data, no patient)."""
    nz, ny, nx = shape
    rng = np.random.default_rng(seed)
    z, y, x = np.meshgrid(np.linspace(-1, 1, nz), np.linspace(-1, 1, ny), np.linspace(-1, 1, nx), indexing="ij")
    vol = np.full(shape, 24.0)  # air
    body = (x / 0.85) ** 2 + (y / 0.62) ** 2 < 1
    vol[body] = 1040.0  # soft tissue
    for cx in (-0.38, 0.38):  # lungs, shorter than the body
        lung = ((x - cx) / 0.28) ** 2 + ((y + 0.05) / 0.4) ** 2 + (z / 0.85) ** 2 < 1
        vol[lung] = 180.0
    spine = (x / 0.09) ** 2 + ((y - 0.45) / 0.09) ** 2 < 1
    vol[spine] = 2100.0
    ribs = body & ((x / 0.8) ** 2 + (y / 0.58) ** 2 > 0.86) & (np.sin(z * 18.0) > 0.6)
    vol[ribs] = 1700.0
    vol += rng.normal(0.0, 20.0, shape)
    return np.clip(vol, 0, 4095).astype(np.int16)


def _frame(ev, cam, sampling, priv, verify) -> tuple[dict, np.ndarray]:
    t = time.perf_counter()
    img = hevr.render(ev, cam, sampling=sampling, verify=verify, progress=False)
    render_s = time.perf_counter() - t
    t1 = time.perf_counter()
    arr = img.decrypt(priv, require_verified=bool(verify))
    dec_s = time.perf_counter() - t1
    row = {
        "render_s": render_s,
        "decrypt_s": dec_s,
        "frame_s": render_s + dec_s,
        "verified": img.verified,
        "ops": img.stats.get("ops"),
        "ciphertexts": img.n_ciphertexts,
        "classes": img.plan.classes,
    }
    row["check_s"] = img.stats.get("check_s")  # the key holder's check alone (verified frames)
    if img.verified and "verify" in img.stats:
        row["verify_ops"] = img.stats["verify"]["ops"]
        row["verify_server_s"] = img.stats["verify"]["server_s"]
    return row, arr


def run(args) -> dict:
    from distributed import Client, LocalCluster

    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    res: dict = {
        "machine": machine(),
        "bits": args.bits,
        "shape": list(args.shape),
        "image": args.image,
        "spacing": list(SPACING),
    }
    t = time.perf_counter()
    pub, priv = hevr.generate_keypair(args.bits)
    res["keygen_s"] = time.perf_counter() - t
    vol = ct_like(tuple(args.shape))
    path = work / "ct-packed.zarr"
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc,
        Client(lc) as client,
    ):
        t = time.perf_counter()
        ev = hevr.encrypt_volume(
            vol,
            path,
            priv,
            spacing=SPACING,
            brick=(64, 64, 64),
            layout="packed",
            overwrite=path.exists(),
            progress=False,
            client=client,
        )
        enc_s = time.perf_counter() - t
        packs = int(np.prod(ev.packing.array_shape(ev.shape)))
        res["encrypt"] = {
            "seconds": enc_s,
            "packs": packs,
            "ciphertexts": 2 * packs,
            "bytes": dir_bytes(path),
            "slots": ev.packing.slots,
            "slot_bits": ev.packing.slot_bits,
            "brick": list(ev.brick),
            "tags": ev.meta.tags,
        }
        print(
            f"encrypted {args.shape} packed: {packs} packs (+ tags), {enc_s:.1f} s, "
            f"{res['encrypt']['bytes'] / 2**20:.1f} MiB",
            flush=True,
        )
        crop = vol[:, : args.shape[1] // 2, : args.shape[2] // 2]
        ratio = {}
        for tags in (False, True):
            p = work / f"crop-{tags}.zarr"
            t = time.perf_counter()
            hevr.encrypt_volume(
                crop,
                p,
                priv,
                spacing=SPACING,
                brick=(64, 64, 64),
                layout="packed",
                verifiable=tags,
                overwrite=p.exists(),
                progress=False,
                client=client,
            )
            ratio["with_tags_s" if tags else "without_tags_s"] = time.perf_counter() - t
        ratio["ratio"] = ratio["with_tags_s"] / ratio["without_tags_s"]
        res["encrypt_tags_ratio"] = {"shape": list(crop.shape), **ratio}
        print(f"tags' encryption ratio on {crop.shape}: {ratio['ratio']:.2f}", flush=True)
        res["frames"] = []
        pictures = {}
        for view, (az, el) in VIEWS.items():
            cam = hevr.Camera.orbit(ev, azimuth=az, elevation=el, width=args.image, height=args.image, parallel=True)
            for sampling in SAMPLINGS:
                plain_row, arr = _frame(ev, cam, sampling, priv, False)
                ver_row, varr = _frame(ev, cam, sampling, priv, True)
                ref = hevr.render_plain(vol, cam, sampling=sampling, spacing=SPACING, slices=True)
                bound = hevr.error_bound(ev, cam, sampling=sampling)
                row = {
                    "view": view,
                    "azimuth": az,
                    "elevation": el,
                    "sampling": sampling,
                    "unverified": plain_row,
                    "verified": ver_row,
                    "same_picture": bool(np.array_equal(arr, varr)),
                    "within_bound": bool((np.abs(arr - ref) <= bound).all()),
                    "frame_ratio": ver_row["frame_s"] / plain_row["frame_s"],
                    "check_s": ver_row["check_s"],
                }
                pictures[(view, sampling)] = varr
                res["frames"].append(row)
                print(
                    f"{view} {sampling}: unverified {plain_row['frame_s']:.1f} s, verified {ver_row['frame_s']:.1f} s "
                    f"({row['frame_ratio']:.2f}x; the key holder's check {row['check_s']:.2f} s), within bound "
                    f"{row['within_bound']}",
                    flush=True,
                )
    res["serve"] = serve_frames(path, ev, priv, args.image, pictures)
    per_ct = enc_s / (2 * packs)
    voxels = int(np.prod(args.shape))
    res["per_voxel_projection"] = {
        "ciphertexts": voxels,
        "bytes": voxels * ev.meta.ciphertext_bytes,
        "encrypt_s_at_packed_rate": voxels * per_ct,
        "note": "one ciphertext per voxel, no tags, at the packed run's seconds per ciphertext",
    }
    return res


def serve_frames(path: Path, ev, priv, image: int, pictures: dict) -> list:
    """The verified frames through ``hevr serve`` (2 workers) and ``hevr.connect``."""
    import re
    import threading

    proc = subprocess.Popen(
        [sys.executable, "-m", "hevr", "serve", str(path), "--workers", "2", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        env={**os.environ},
    )
    url: list = []
    ready = threading.Event()

    def pump():
        for line in proc.stdout:
            m = re.search(r"serving: (https?://\S+)", line)
            if m and not url:
                url.append(m.group(1))
                ready.set()
        ready.set()

    threading.Thread(target=pump, daemon=True).start()
    rows = []
    try:
        if not ready.wait(180) or not url:
            raise RuntimeError("hevr serve did not start")
        server = hevr.connect(url[0], timeout=900)
        rv = server.open(ev.meta.store_id)
        for view, (az, el) in VIEWS.items():
            cam = hevr.Camera.orbit(rv, azimuth=az, elevation=el, width=image, height=image, parallel=True)
            for sampling in SAMPLINGS:
                row, arr = _frame(rv, cam, sampling, priv, True)
                row.update(
                    view=view,
                    sampling=sampling,
                    same_as_in_process=bool(np.array_equal(arr, pictures[(view, sampling)])),
                )
                rows.append(row)
                print(
                    f"serve {view} {sampling}: verified {row['frame_s']:.1f} s, same picture "
                    f"{row['same_as_in_process']}",
                    flush=True,
                )
        server.close()
    finally:
        import signal

        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    return rows


def check_cost(shape: tuple, image: int, bits: int) -> list:
    """The key holder's check of a verified frame at a size too large to encrypt here: the frame's
    plan (public), random values standing in for the decrypted ones, and the same
    :meth:`PackedVerification.check` arithmetic but the one decryption of the aggregate (Σρ·V and
    Σρ·β, timed); a 2048-bit key made here."""
    import secrets as _secrets
    import types

    from hevr.crypto.tags import coefficients_at
    from hevr.rendering.packed import SlicePlan
    from hevr.rendering.packed.verified import PackedVerification
    from hevr.store.packing import choose_packing

    pub, priv = hevr.generate_keypair(bits)
    info = choose_packing(bits, shape, 0, (0, 4095))
    brick = (info.slots * max(1, 64 // info.slots), 64, 64)
    meta = types.SimpleNamespace(
        shape=shape, spacing=SPACING, brick=brick, packing=info, store_id="0" * 16, n=str(int(pub.n))
    )
    rows = []
    for view, (az, el) in VIEWS.items():
        cam = hevr.Camera.orbit(
            shape, azimuth=az, elevation=el, width=image, height=image, parallel=True, spacing=SPACING
        )
        for sampling in SAMPLINGS:
            plan = SlicePlan.build(cam, shape, SPACING, brick, info, sampling)
            v = PackedVerification(aggregate=1, seed=_secrets.token_bytes(32), meta=meta)
            vals = [
                [_secrets.randbelow(int(pub.n)) for _ in range(len(plan.value_ids(t_)))] for t_ in range(plan.n_tiles)
            ]
            t = time.perf_counter()
            s_sum = sum(
                int(r) * x
                for t_, vs in enumerate(vals)
                for r, x in zip(coefficients_at(v.seed, plan.value_ids(t_)).tolist(), vs)
            )
            v.beta_sum(priv, plan)
            rows.append(
                {
                    "view": view,
                    "sampling": sampling,
                    "check_s": time.perf_counter() - t,
                    "values": sum(map(len, vals)),
                    "classes": plan.classes,
                    "s_sum_bits": s_sum.bit_length(),
                }
            )
            print(f"check {shape} {image}² {view} {sampling}: {rows[-1]['check_s']:.2f} s", flush=True)
    return rows


def project_per_voxel(res: dict, measured: dict) -> list:
    """The per-voxel frames of the same cameras, projected: each view's samples (cast here, public
    geometry) × the per-voxel seconds per sample measured in ``measured`` (issue 45's run,
    ``results-packed-2048.json``: its largest size, the same sampling; the general view as the
    general view, the orbit for the anterior one)."""
    from hevr.rendering.geometry.rays import cast_rays

    big = measured["sizes"][max(measured["sizes"], key=int)]
    per = {(f["view"], f["sampling"]): f["voxel"]["frame_s"] / f["voxel"]["samples"] for f in big["frames"]}
    shape = tuple(res["shape"])
    rows = []
    for view, (az, el) in VIEWS.items():
        cam = hevr.Camera.orbit(
            shape,
            azimuth=az,
            elevation=el,
            width=res["image"],
            height=res["image"],
            parallel=True,
            spacing=tuple(res["spacing"]),
        )
        samples = int(cast_rays(cam, shape, tuple(res["spacing"]), 1.0).n_samples.sum())
        for sampling in SAMPLINGS:
            s_per = per[("general" if view == "general" else "orbit", sampling)]
            rows.append({"view": view, "sampling": sampling, "samples": samples, "frame_s": samples * s_per})
    return rows


def report(res: dict) -> str:
    m, e = res["machine"], res["encrypt"]
    shape = "×".join(str(s) for s in reversed(res["shape"]))
    lines = [
        f"# A real-size packed store at {res['bits']} bits (issue 46)",
        "",
        f"{m['date']}, {m['cpu']}, {m['cores']} cores, LocalCluster 2 workers × 1 thread. CT-like volume "
        f"{shape} (x×y×z), int16 12-bit values, spacing {tuple(res['spacing'])} mm (x, y, z), packed along z; "
        f"{res['image']}² parallel frames.",
        "",
        "## Store",
        "",
        "| | packed (with tags) | per-voxel (projected) |",
        "|---|---|---|",
        f"| ciphertexts | {e['ciphertexts']:,} ({e['packs']:,} + as many tags; S = {e['slots']}, K = "
        f"{e['slot_bits']}) | {res['per_voxel_projection']['ciphertexts']:,} (no tags) |",
        f"| bytes | {e['bytes'] / 2**30:.2f} GiB | {res['per_voxel_projection']['bytes'] / 2**30:.1f} GiB |",
        f"| encryption | {e['seconds']:.0f} s | {res['per_voxel_projection']['encrypt_s_at_packed_rate'] / 60:.0f} "
        "min (at the packed run's seconds per ciphertext) |",
        "",
        f"Tags' encryption ratio (crop {'×'.join(map(str, reversed(res['encrypt_tags_ratio']['shape'])))}): "
        f"{res['encrypt_tags_ratio']['with_tags_s']:.1f} s with tags / "
        f"{res['encrypt_tags_ratio']['without_tags_s']:.1f} s without = "
        f"**{res['encrypt_tags_ratio']['ratio']:.2f}×**.",
        "",
        "## Frames in process (render + decryption)",
        "",
        "| view | sampling | unverified | verified | ratio | key holder's check | within bound "
        "| per-voxel (projected, unverified) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    proj = {(p["view"], p["sampling"]): p for p in res.get("per_voxel_frames", [])}
    for r in res["frames"]:
        pv = proj.get((r["view"], r["sampling"]))
        voxel = f"{pv['frame_s']:.0f} s" if pv else "—"
        lines.append(
            f"| {r['view']} | {r['sampling']} | {r['unverified']['frame_s']:.1f} s | "
            f"{r['verified']['frame_s']:.1f} s | {r['frame_ratio']:.2f}× | {r['check_s']:.2f} s | "
            f"{r['within_bound']} | {voxel} |"
        )
    if proj:
        lines += [
            "",
            "Per-voxel frames projected: each camera's samples (cast from the public geometry) × the "
            "per-voxel seconds per sample measured at 128³ in issue 45's run "
            "(`results-packed-2048.json`; the orbit view's for the anterior one).",
        ]
    ratios = [r["frame_ratio"] for r in res["frames"]]
    lines += [
        "",
        f"Issue 46's goals: tags' encryption ≤ 1.5×: {res['encrypt_tags_ratio']['ratio']:.2f}× "
        f"({'met' if res['encrypt_tags_ratio']['ratio'] <= 1.5 else 'missed'}); verified frame ≤ 1.6×: "
        f"{sum(x <= 1.6 for x in ratios)} of {len(ratios)} frames (largest {max(ratios):.2f}×); the key "
        f"holder's check ≤ 2 s: largest {max(r['check_s'] for r in res['frames']):.2f} s.",
    ]
    if "check_real_size" in res:
        c = res["check_real_size"]
        lines += [
            "",
            f"The key holder's check at {c['image']}² of a "
            f"{'×'.join(map(str, reversed(c['shape'])))} store (the plan only, not encrypted: random values, "
            "the same Σρ·V and Σρ·β arithmetic, `--check`): "
            + ", ".join(f"{r['view']} {r['sampling']} {r['check_s']:.2f} s" for r in c["rows"])
            + ".",
        ]
    lines += [
        "",
        "## Frames through `hevr serve` (verified; render + tags' round + decryption)",
        "",
        "| view | sampling | frame | the in-process picture |",
        "|---|---|---|---|",
    ]
    for r in res["serve"]:
        lines.append(f"| {r['view']} | {r['sampling']} | {r['frame_s']:.1f} s | {r['same_as_in_process']} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] == "--report":
        print(report(json.loads(Path(sys.argv[2]).read_text())), end="")
        return
    if len(sys.argv) == 3 and sys.argv[1] == "--check":  # OUT.json: the check at 512² of 512×512×300
        out = Path(sys.argv[2])
        res = json.loads(out.read_text())
        res["check_real_size"] = {
            "shape": [300, 512, 512],
            "image": 512,
            "rows": check_cost((300, 512, 512), 512, res["bits"]),
        }
        out.write_text(json.dumps(res, indent=1))
        return
    if len(sys.argv) == 4 and sys.argv[1] == "--project-voxel":  # OUT.json MEASURED.json: add the projection
        out = Path(sys.argv[2])
        res = json.loads(out.read_text())
        res["per_voxel_frames"] = project_per_voxel(res, json.loads(Path(sys.argv[3]).read_text()))
        out.write_text(json.dumps(res, indent=1))
        return
    ap = argparse.ArgumentParser()
    ap.add_argument("work", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--bits", type=int, default=2048)
    ap.add_argument("--shape", type=int, nargs=3, default=[150, 256, 256])
    ap.add_argument("--image", type=int, default=256)
    args = ap.parse_args()
    res = run(args)
    args.out.write_text(json.dumps(res, indent=1))
    print(report(res))


if __name__ == "__main__":
    main()
