"""Issue 45: packed stores vs per-voxel stores, in one run on the same volume, image, key and workers.

Usage::

    python benchmarks/packed.py WORKDIR OUT.json [--bits 2048] [--sizes 64 128] [--image 128]
    python benchmarks/packed.py --project OUT.json                  # the projection again, from the results
    python benchmarks/packed.py --report OUT.json > RESULTS-packed.md

For each size N (the N³ phantom, uint8, brick 32) on a 2-worker LocalCluster (1 thread each):

* encrypt a per-voxel store and a packed store (owner path): seconds, ciphertexts, bytes on disk;
* for two parallel views — a general one (azimuth 60, elevation 10: the view's shift along the
  packing axis spans every slot class) and one orbiting the packing axis (azimuth 90, elevation
  20: one class, no combine) — and for nearest and bilinear (``trilinear``) sampling: the frame
  end to end (render + the key holder's decryption) on both stores, with the modular operations
  counted (per-voxel: the workers' backend calls, patched in by ``client.run``; packed: the
  image's own counts), the packed frame checked against ``render_plain(..., slices=True)`` within
  ``error_bound``, and the mean absolute difference between the packed frame and the per-voxel
  trilinear frame (fraction of the value range);
* a projection to a 512 × 512 × 300 CT (12-bit values in int16, packed along z at 2048 bits:
  S = 27, K = 37): bytes and encryption time from the measured per-ciphertext costs; per frame
  the operations counted exactly from the plans (packed: every brick's pairs and the combine;
  per-voxel: the rays' samples × the measured operations per sample) and the time from the
  measured seconds per operation of each layout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr.bench.measure import dir_bytes, machine, mulmod_seconds
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.packed import SlicePlan
from hevr.rendering.packed.graph import brick_columns, column_pairs
from hevr.store.packing import choose_packing

warnings.simplefilter("ignore")

VIEWS = {"general": (60.0, 10.0), "orbit": (90.0, 20.0)}
SAMPLINGS = ("nearest", "trilinear")


# -- counting the per-voxel pipeline's operations on the workers --------------------------------
def _install_counter():  # runs on every worker (client.run)
    from hevr.backends import cpu as cpu_mod
    from hevr.backends.base import OpCounter

    be = cpu_mod.CpuBackend
    if getattr(be, "_counting", False):
        return True
    state = {"map": OpCounter(), "merge": 0, "pack": 0}
    ray, seg, pack = be.ray_products, be.segment_products, be.pack

    def ray_products(self, plan, components, nsquare, counter=None):
        mine = OpCounter()  # this call's operations: into the total, and into the caller's counter
        out = ray(self, plan, components, nsquare, mine)
        state["map"].add(mine)
        if counter is not None:
            counter.add(mine)
        return out

    def segment_products(self, values, indptr, k, nsquare):
        ip = np.asarray(indptr)
        state["merge"] += int((len(values) // k - (len(ip) - 1)) * k)
        return seg(self, values, indptr, k, nsquare)

    def pack_(self, terms, exps, pack_bits, per_pack, offset, n):
        J = max(1, per_pack)
        ops = 0
        for s in range(0, len(terms), J):
            rs = [int(r) for r in exps[s : s + J]]
            ops += max(rs[-1].bit_length() - 1, 0) + max(bin(rs[-1]).count("1") - 1, 0)
            ops += sum(pack_bits + bin(r).count("1") for r in rs[:-1]) + (1 if offset else 0)
        state["pack"] += ops
        return pack(self, terms, exps, pack_bits, per_pack, offset, n)

    be.ray_products, be.segment_products, be.pack = ray_products, segment_products, pack_
    be._counting, be._state = True, state
    return True


def _read_counter():
    from hevr.backends import cpu as cpu_mod
    from hevr.backends.base import OpCounter

    st = cpu_mod.CpuBackend._state
    out = {"map": st["map"].modmuls, "merge": st["merge"], "finish": st["pack"]}
    st["map"], st["merge"], st["pack"] = OpCounter(), 0, 0
    return out


def _ops(client) -> dict:
    got = client.run(_read_counter)
    return {k: sum(v[k] for v in got.values()) for k in ("map", "merge", "finish")}


# -- one size -----------------------------------------------------------------------------------
def run_size(client, priv, n: int, image: int, work: Path) -> dict:
    vol = hevr.phantom(n)
    res: dict = {"size": n, "image": image}
    stores = {}
    for layout in ("voxel", "packed"):
        path = work / f"{layout}-{n}.zarr"
        t = time.perf_counter()
        ev = hevr.encrypt_volume(vol, path, priv, brick=32, layout=layout, overwrite=path.exists(), progress=False)
        dt = time.perf_counter() - t
        cts = int(np.prod(ev.packing.array_shape(ev.shape) if ev.packing else ev.shape))
        res[f"encrypt_{layout}"] = {
            "seconds": dt,
            "ciphertexts": cts,
            "bytes": dir_bytes(path),
            "brick": list(ev.brick),
        }
        if ev.packing is not None:
            res["packing"] = {"slots": ev.packing.slots, "slot_bits": ev.packing.slot_bits, "axis": ev.packing.axis}
        stores[layout] = ev
        print(
            f"{n}³ {layout}: {cts} ciphertexts, {dt:.1f} s, {res[f'encrypt_{layout}']['bytes'] / 2**20:.1f} MiB",
            flush=True,
        )
    res["frames"] = []
    for view, (az, el) in VIEWS.items():
        cam = hevr.Camera.orbit(vol.shape, azimuth=az, elevation=el, width=image, height=image, parallel=True)
        pv_tri = None
        for sampling in SAMPLINGS:
            row: dict = {"view": view, "azimuth": az, "elevation": el, "sampling": sampling}
            _ops(client)  # reset
            t = time.perf_counter()
            img = hevr.render(stores["voxel"], cam, sampling=sampling, verify=False, progress=False, cache=False)
            r = time.perf_counter() - t
            arr = img.decrypt(priv)
            row["voxel"] = {
                "render_s": r,
                "frame_s": time.perf_counter() - t,
                "ops": _ops(client),
                "samples": int(cast_rays(cam, vol.shape, (1, 1, 1), 1.0).n_samples.sum()),
            }
            if sampling == "trilinear":
                pv_tri = arr
            t = time.perf_counter()
            pimg = hevr.render(stores["packed"], cam, sampling=sampling, verify=False, progress=False)
            r = time.perf_counter() - t
            parr = pimg.decrypt(priv)
            ref = hevr.render_plain(vol, cam, sampling=sampling, slices=True)
            bound = hevr.error_bound(stores["packed"], cam, sampling=sampling)
            row["packed"] = {
                "render_s": r,
                "frame_s": time.perf_counter() - t,
                "ops": pimg.stats["ops"],
                "classes": pimg.plan.classes,
                "rays": pimg.stats["rays"],
                "within_bound": bool((np.abs(parr - ref) <= bound).all()),
                "max_err": float(np.abs(parr - ref).max()),
            }
            if pv_tri is not None:
                row["packed"]["mad_vs_voxel_trilinear"] = float(np.abs(parr - pv_tri).mean() / 255.0)
            res["frames"].append(row)
            v, p = row["voxel"], row["packed"]
            print(
                f"{n}³ {view} {sampling}: voxel {v['frame_s']:.1f} s {sum(v['ops'].values()):,} ops | packed "
                f"{p['frame_s']:.1f} s {sum(p['ops'][k] for k in ('map', 'merge', 'combine', 'combine_squarings')):,}"
                f" ops | map {v['ops']['map'] / max(p['ops']['map'], 1):.1f}x fewer, frame "
                f"{v['frame_s'] / p['frame_s']:.1f}x",
                flush=True,
            )
    return res


# -- the projection to a real-size CT ----------------------------------------------------------
def packed_ops_of(plan: SlicePlan, shape, brick) -> dict:
    """A real-size packed frame's operations, counted exactly without 2048-bit arithmetic: every
    brick's product plan runs on the CPU backend over a 61-bit modulus (the kernel's choices and its
    counts depend on the weights only, not on the modulus), merges are the partials beyond one per
    accumulator, the combine K·O squarings and O products per value."""
    from gmpy2 import mpz

    from hevr.backends.base import OpCounter
    from hevr.backends.cpu import CpuBackend
    from hevr.rendering.pipeline.kernel import plan_products

    be, counter = CpuBackend(), OpCounter()
    n2 = mpz((1 << 61) - 1)
    grid = tuple(-(-s // b) for s, b in zip(shape, brick))
    pairs = partials = 0
    seen: set = set()
    for column in brick_columns(grid, plan.geometry.principal):  # the render's map tasks
        sizes = [
            int(
                np.prod(
                    [
                        -(-(min((i + 1) * b, s) - i * b) // plan.packing.slots)
                        if ax == plan.packing.axis
                        else min((i + 1) * b, s) - i * b
                        for ax, (i, b, s) in enumerate(zip(idx, brick, shape))
                    ]
                )
            )
            for idx in column
        ]
        keys, local, w = column_pairs(plan, column, sizes)
        if not len(keys):
            continue
        starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
        n_vox = sum(sizes)
        pp = plan_products(np.r_[starts, len(keys)], local, w, n_vox)
        be.ray_products(pp, [[mpz(3 + v) for v in range(n_vox)]], n2, counter)
        pairs += len(keys)
        partials += len(starts)
        seen.update(keys[starts].tolist())
    ni, nj = plan.geometry.size
    n_out = plan.n_blocks * nj
    classes = plan.classes - 1  # O in the docstring
    return {
        "pairs": pairs,
        "map": counter.modmuls,
        "merge": partials - len(seen),
        "combine_squarings": n_out * plan.packing.slot_bits * classes,
        "combine": n_out * classes,
        "decryptions": n_out,
        "rays": ni * nj,
    }


def project(measured: dict, image: int = 512) -> dict:
    shape = (300, 512, 512)
    info = choose_packing(2048, shape, 0, (-1024, 3071))  # 12-bit CT values in int16, packed along z
    brick = (info.slots, 64, 64)
    vox = int(np.prod(shape))
    packs = int(np.prod(info.array_shape(shape)))
    big = measured[max(measured)]  # the largest measured size
    enc_v = big["encrypt_voxel"]["seconds"] / big["encrypt_voxel"]["ciphertexts"]
    enc_p = big["encrypt_packed"]["seconds"] / big["encrypt_packed"]["ciphertexts"]
    b_v = big["encrypt_voxel"]["bytes"] / big["encrypt_voxel"]["ciphertexts"]
    b_p = big["encrypt_packed"]["bytes"] / big["encrypt_packed"]["ciphertexts"]
    out = {
        "shape": list(shape),
        "slots": info.slots,
        "slot_bits": info.slot_bits,
        "image": image,
        "store_bytes": {"voxel": vox * b_v, "packed": packs * b_p},
        "encrypt_s_2_workers": {"voxel": vox * enc_v, "packed": packs * enc_p},
        "frames": [],
    }
    n_big = int(big["size"])
    for view, (az, el) in VIEWS.items():
        cam = hevr.Camera.orbit(shape, azimuth=az, elevation=el, width=image, height=image, parallel=True)
        rays = cast_rays(cam, shape, (1, 1, 1), 1.0)
        samples, hits = int(rays.n_samples.sum()), int((rays.n_samples > 0).sum())
        small = hevr.Camera.orbit(
            (n_big,) * 3, azimuth=az, elevation=el, width=big["image"], height=big["image"], parallel=True
        )
        small_hits = int((cast_rays(small, (n_big,) * 3, (1, 1, 1), 1.0).n_samples > 0).sum())
        for sampling in SAMPLINGS:
            rows = [f for f in big["frames"] if f["view"] == view and f["sampling"] == sampling]
            f = rows[0]
            v_ops_per_sample = sum(f["voxel"]["ops"].values()) / f["voxel"]["samples"]
            # the server's seconds per operation and the key holder's seconds per hit pixel / decrypted value
            v_s_per_op = f["voxel"]["render_s"] / sum(f["voxel"]["ops"].values())
            v_client = (f["voxel"]["frame_s"] - f["voxel"]["render_s"]) / small_hits
            p_ops = f["packed"]["ops"]
            p_total = p_ops["map"] + p_ops["merge"] + p_ops["combine"] + p_ops["combine_squarings"]
            p_s_per_op = f["packed"]["render_s"] / p_total
            small_plan = SlicePlan.build(
                small,
                (n_big,) * 3,
                (1.0, 1.0, 1.0),
                tuple(big["encrypt_packed"]["brick"]),
                choose_packing(2048, (n_big,) * 3, 0, (0, 255)),
                sampling,
            )
            p_client = (f["packed"]["frame_s"] - f["packed"]["render_s"]) / (
                small_plan.n_blocks * small_plan.geometry.size[1]
            )
            plan = SlicePlan.build(cam, shape, (1.0, 1.0, 1.0), brick, info, sampling)
            t = time.perf_counter()
            c = packed_ops_of(plan, shape, brick)
            p_proj = c["map"] + c["merge"] + c["combine"] + c["combine_squarings"]
            v_proj = samples * v_ops_per_sample
            out["frames"].append(
                {
                    "view": view,
                    "sampling": sampling,
                    "samples": samples,
                    "voxel_ops": v_proj,
                    "packed_ops": p_proj,
                    "packed_counts": c,
                    "classes": plan.classes,
                    "voxel_map": samples * f["voxel"]["ops"]["map"] / f["voxel"]["samples"],
                    "packed_map": c["map"],
                    "voxel_s_2_workers": v_proj * v_s_per_op + hits * v_client,
                    "packed_s_2_workers": p_proj * p_s_per_op + c["decryptions"] * p_client,
                    "voxel_client_s": hits * v_client,
                    "packed_client_s": c["decryptions"] * p_client,
                    "count_s": time.perf_counter() - t,
                }
            )
            print(
                f"512x512x300 {view} {sampling}: map {out['frames'][-1]['voxel_map'] / c['map']:.1f}x fewer, "
                f"all ops {v_proj / p_proj:.1f}x fewer",
                flush=True,
            )
    return out


def report(result: dict) -> str:
    """A Markdown summary of a results file (``python benchmarks/packed.py --report OUT.json``)."""
    m = result["machine"]
    lines = [
        f"# Packed vs per-voxel stores at {result['bits']} bits (issue 45)",
        "",
        f"{m['date']}, {m['cpu']}, {m['cores']} cores, {result['workers']}, commit {m.get('commit')}; "
        f"one bare a·b mod n² {result['mulmod_s'] * 1e6:.2f} µs. Frames end to end: render + the key holder's "
        "decryption; operations counted (squarings included, one each).",
        "",
    ]
    for n, r in result["sizes"].items():
        ev, ep = r["encrypt_voxel"], r["encrypt_packed"]
        lines += [
            f"## {n}³ phantom, {r['image']}² parallel camera, S = {r['packing']['slots']}, "
            f"K = {r['packing']['slot_bits']}",
            "",
            "| | per-voxel | packed | ratio |",
            "|---|---|---|---|",
            f"| ciphertexts | {ev['ciphertexts']:,} | {ep['ciphertexts']:,} | "
            f"{ev['ciphertexts'] / ep['ciphertexts']:.1f} |",
            f"| store bytes | {ev['bytes'] / 2**20:.1f} MiB | {ep['bytes'] / 2**20:.2f} MiB | "
            f"{ev['bytes'] / ep['bytes']:.1f} |",
            f"| encryption | {ev['seconds']:.1f} s | {ep['seconds']:.1f} s | {ev['seconds'] / ep['seconds']:.1f} |",
            "",
            "| view | sampling | map ops voxel / packed | all ops voxel / packed | frame voxel / packed "
            "| within bound | vs per-voxel trilinear (MAD) |",
            "|---|---|---|---|---|---|---|",
        ]
        for f in r["frames"]:
            v, p = f["voxel"], f["packed"]
            vo, po = sum(v["ops"].values()), sum(p["ops"][k] for k in ("map", "merge", "combine", "combine_squarings"))
            mad = f"{p['mad_vs_voxel_trilinear'] * 100:.2f} %" if "mad_vs_voxel_trilinear" in p else "—"
            lines.append(
                f"| {f['view']} (az {f['azimuth']:g}, el {f['elevation']:g}) | {f['sampling']} | "
                f"{v['ops']['map']:,} / {p['ops']['map']:,} = {v['ops']['map'] / max(p['ops']['map'], 1):.1f}× | "
                f"{vo:,} / {po:,} = {vo / max(po, 1):.1f}× | {v['frame_s']:.2f} s / {p['frame_s']:.2f} s = "
                f"{v['frame_s'] / p['frame_s']:.1f}× | {p['within_bound']} | {mad} |"
            )
        lines.append("")
    pj = result.get("projection_512x512x300")
    if pj:
        lines += [
            f"## Projection: {'×'.join(map(str, pj['shape'][::-1]))} CT (12-bit values), {pj['image']}² image, "
            f"S = {pj['slots']}, K = {pj['slot_bits']}",
            "",
            f"Store: {pj['store_bytes']['voxel'] / 1e9:.1f} GB per-voxel, {pj['store_bytes']['packed'] / 1e9:.2f} GB "
            f"packed; encryption on these 2 workers {pj['encrypt_s_2_workers']['voxel'] / 3600:.1f} h vs "
            f"{pj['encrypt_s_2_workers']['packed'] / 60:.1f} min (measured per-ciphertext costs × count).",
            "",
            "| view | sampling | map ops voxel / packed | all ops voxel / packed | frame on 2 workers voxel / packed |",
            "|---|---|---|---|---|",
        ]
        for f in pj["frames"]:
            lines.append(
                f"| {f['view']} | {f['sampling']} | {f['voxel_map']:.3g} / {f['packed_map']:.3g} = "
                f"{f['voxel_map'] / f['packed_map']:.1f}× | {f['voxel_ops']:.3g} / {f['packed_ops']:.3g} = "
                f"{f['voxel_ops'] / f['packed_ops']:.1f}× | {f['voxel_s_2_workers']:.0f} s / "
                f"{f['packed_s_2_workers']:.0f} s = {f['voxel_s_2_workers'] / f['packed_s_2_workers']:.1f}× |"
            )
        lines += [
            "",
            "Packed operations are counted exactly for the real-size plan (each column's product plan "
            "run over a small modulus: the same choices and counts); per-voxel ones are the samples of the "
            "real-size camera × the operations per sample measured at the largest size. Seconds: operations × "
            "each layout's measured render seconds per operation at the largest size, plus the key holder's "
            "decryption (per hit pixel, per-voxel; per decrypted value, packed) measured there.",
            "",
        ]
    return "\n".join(lines)


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] == "--report":
        print(report(json.loads(Path(sys.argv[2]).read_text())))
        return
    if len(sys.argv) == 3 and sys.argv[1] == "--project":  # the projection again, from a results file
        out = Path(sys.argv[2])
        result = json.loads(out.read_text())
        result["projection_512x512x300"] = project({int(k): v for k, v in result["sizes"].items()})
        out.write_text(json.dumps(result, indent=1))
        return
    ap = argparse.ArgumentParser()
    ap.add_argument("work", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--bits", type=int, default=2048)
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--image", type=int, default=128)
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    result = {
        "machine": machine(),
        "bits": a.bits,
        "workers": "LocalCluster 2 workers x 1 thread",
        "mulmod_s": mulmod_seconds(a.bits),
    }
    pub, priv = hevr.generate_keypair(a.bits)
    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0") as lc, Client(lc) as client:
        client.run(_install_counter)
        measured = {}
        for n in a.sizes:
            measured[n] = run_size(client, priv, n, a.image, a.work)
            result["sizes"] = {str(k): v for k, v in measured.items()}
            a.out.write_text(json.dumps(result, indent=1))
    result["projection_512x512x300"] = project(measured)
    a.out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result["projection_512x512x300"], indent=1))


if __name__ == "__main__":
    main()
