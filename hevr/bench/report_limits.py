"""A benchmark run against its limits: the machine's own arithmetic floors, the Paillier primitives,
and python-paillier used naively.

The floors are the quickest one bare ``a*b % n²`` and one owner-side mask took anywhere in the run;
renders and encryptions are read as multiples of them.
"""

from __future__ import annotations

from .report_cells import DASH, lookup, number, times


def floors(doc: dict) -> dict[int, dict[str, float]]:
    """Per key size, the best (smallest) time of one bare ``a*b % n²`` and of one owner-side mask
    over every measurement of it in the run: single measurements on a shared machine vary by up
    to 2×, and a floor is the quickest the machine did it."""
    out: dict[int, dict[str, float]] = {}

    def put(bits: int, kind: str, value: float | None) -> None:
        if value:
            d = out.setdefault(int(bits), {})
            d[kind] = min(d.get(kind, value), value)

    for key, cell in doc["cells"].items():
        if not isinstance(cell, dict):
            continue
        if key.startswith("micro.crypto."):
            for r in cell["rows"]:
                put(cell["bits"], "mulmod", r["bare_s"])
        elif key.startswith("micro.kernel."):
            put(cell["bits"], "mulmod", cell["mulmod_s"])
        elif "bits" in cell:
            put(cell["bits"], "mulmod", cell.get("mulmod_s"))
            put(cell["bits"], "mask", cell.get("fixed_base_s"))
    return out


def limits(doc: dict) -> list[str]:
    c, s = doc["cells"], doc["setting"]
    fl = floors(doc)
    lines = [
        "## Against the limit (measured in the same run)",
        "",
        "The floors are the best time of one bare `a * b % n²` and of one owner-side mask at each key size "
        "over every measurement of them in this run (micro-benchmarks and before every cell). "
        "Renders: *kernel* = core-seconds inside the encrypted kernel per (ray, voxel, component) triple ÷ "
        "one bare `a * b % n²` at that key size (n² has twice the key's bits: 4096 at 2048); "
        "*end to end* = wall seconds × workers per pair ÷ the same; *outside "
        "kernel* = share of the workers' wall time (wall × workers) not spent in the kernel — graph building, "
        "brick reads, plaintext geometry, transfers, merges, finishing, idle. Peak RSS is the largest worker "
        "process's high-water mark during that stage (reset before it"
        + (
            ""
            if all(cell.get("peak_reset", True) for cell in c.values() if isinstance(cell, dict))
            else "; on some workers the reset failed and the peak is since they started"
        )
        + ").",
        "",
        "| render | bits | samples | pairs × components | `a*b % n²` µs | kernel | end to end | outside kernel "
        "| map / merge / finish core-s | peak RSS MB |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    rows = [(f"X-ray {sp}", b, lookup(c, f"t1.{b}.obf.{sp}")) for b in s["t1_bits"] for sp in ("nearest", "trilinear")]
    rows += [
        (f"TF {d}-dim, {d} colours", b, lookup(c, f"t3.{b}.{d}.{d}")) for b in s["t3_bits"] for d in s["dims"][-1:]
    ]
    for name, b, r in rows:
        if not r or not r["pairs"]:
            continue
        mm = fl.get(b, {}).get("mulmod", r["mulmod_s"])
        core = r["seconds"] * r["workers"]
        ph = r["phases_core_s"]
        mp = sum(v for k, v in ph.items() if k.startswith("map."))
        lines.append(
            f"| {name} | {b} | {r['samples']:,} | {r['pairs']:,} | {mm * 1e6:.3f} | "
            f"{r['kernel_core_s'] / r['pairs'] / mm:.2f} | {core / r['pairs'] / mm:.2f} | "
            f"{max(0.0, 1 - r['kernel_core_s'] / core):.0%} | {mp:.2f} / {ph.get('merge', 0):.2f} / "
            f"{ph.get('finish', 0):.2f} | {r['peak_rss'] / 1e6:,.0f} |"
        )
    lines += [
        "",
        "Encryption: per ciphertext, core-seconds (wall × workers ÷ ciphertexts) ÷ one owner-side mask "
        "(two fixed-base table exponentiations mod p² and q² and their CRT); *crypto only* is the time inside "
        "`encrypt_array` (for scalar volumes quantising too) and leaves out byte conversion, Zarr writes "
        "and scheduling.",
        "",
        "| encryption | bits | ciphertexts | wall s | µs·core per ciphertext | one mask µs | ÷ mask "
        "| crypto only ÷ mask | peak RSS MB |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    rows = [("scalar", b, lookup(c, f"t1.{b}.obf.encrypt")) for b in s["t1_bits"]]
    rows += [(f"{d}-dim", b, lookup(c, f"t3.{b}.{d}.encrypt")) for b in s["t3_bits"] for d in s["dims"]]
    for name, b, r in rows:
        if not r or not r.get("fixed_base_s"):
            continue
        mask = fl.get(b, {}).get("mask", r["fixed_base_s"])
        per = r["seconds"] * r["workers"] / r["ciphertexts"]
        lines.append(
            f"| {name} | {b} | {r['ciphertexts']:,} | {number(r['seconds'])} | {per * 1e6:,.0f} | "
            f"{mask * 1e6:,.0f} | {per / mask:.2f} | "
            f"{r['crypto_core_s'] / r['ciphertexts'] / mask:.2f} | {r['peak_rss'] / 1e6:,.0f} |"
        )
    return lines + [""]


def micro(doc: dict) -> list[str]:
    c = doc["cells"]
    lines: list[str] = []
    for key in sorted((k for k in c if k.startswith("micro.crypto.")), key=lambda k: int(k.split(".")[-1])):
        b = key.split(".")[-1]
        if not lines:
            lines = [
                "## Paillier primitives (one core, same process)",
                "",
                "| bits | operation | hevr µs | phe µs | phe ÷ hevr | ÷ bare `a*b % n²` |",
                "|---:|---|---:|---:|---:|---:|",
            ]
        for r in c[key]["rows"]:
            lines.append(
                f"| {b} | {r['name']} | {r['hevr_s'] * 1e6:,.1f} | {r['phe_s'] * 1e6:,.1f} | "
                f"{r['phe_s'] / r['hevr_s']:.2f}× | {r['hevr_s'] / r['bare_s']:.2f} |"
            )
        lines.append(f"| {b} | owner tables, built once per key and process | {c[key]['table_s'] * 1e6:,.0f} | | | |")
    for key in (k for k in c if k.startswith("micro.kernel.")):
        k = c[key]
        lines += [
            "",
            f"Kernel on synthetic per-brick workloads ({k['bits']}-bit key, one `a*b % n²` = "
            f"{k['mulmod_s'] * 1e6:.2f} µs; ratio = time per pair ÷ that):",
            "",
            "| workload | rows | pairs/row | ops/pair | ratio | goal |",
            "|---|---:|---:|---:|---:|---|",
        ]
        for w in k["workloads"]:
            goal = k["goals"].get(w["name"])
            lines.append(
                f"| {w['name']} | {w['rows']:,} | {w['pairs_per_row']:.1f} | {w['ops']:.2f} | "
                f"{w['ratio']:.2f} | {f'≤ {goal}' if goal else DASH} |"
            )
    return lines + [""] if lines else []


def naive(doc: dict) -> list[str]:
    p, h = doc["cells"].get("naive.phe"), doc["cells"].get("naive.hevr")
    if not p or not h:
        return []
    lines = [
        f"## Against python-paillier used naively ({p['size']}³ phantom, {p['image']}² image, {p['bits']}-bit key)",
        "",
        "phe: one `EncryptedNumber` per voxel, per pixel `sum(w * E(v)) * (1/n)` with float weights (phe "
        "aligns the exponents itself), single-threaded, the same ray geometry as hevr. hevr: `encrypt_volume` + "
        "`render` on the benchmark's workers + `EncryptedImage.decrypt` on the client.",
        "",
        "| stage | phe s | hevr s | phe ÷ hevr | max abs error phe / hevr |",
        "|---|---:|---:|---:|---:|",
        f"| encrypt {p['ciphertexts']:,} voxels | {number(p['encrypt_s'])} | {number(h['encrypt']['seconds'])} | "
        f"{times(p['encrypt_s'] / h['encrypt']['seconds'])} | |",
    ]
    for sampling in ("nearest", "trilinear"):
        a, b = p[sampling], h[sampling]
        if "refused" in b:
            continue
        err_a = a.get("max_abs_err_plain", a["max_abs_err"])
        lines.append(
            f"| render {sampling} | {number(a['render_s'])} | {number(b['seconds'])} | "
            f"{times(a['render_s'] / b['seconds'])} | {err_a:.1e} / {b['max_abs_err']:.1e} |"
        )
        lines.append(
            f"| decrypt {sampling} ({a['pixels']} / {b['ciphertexts']} ciphertexts) | {number(a['decrypt_s'])} | "
            f"{number(b['decrypt_s'])} | {times(a['decrypt_s'] / b['decrypt_s'])} | |"
        )
    ref = (
        "both against `render_plain`"
        if "max_abs_err_plain" in p["nearest"]
        else "phe against the same formula in float64 (6-digit weights), hevr against `render_plain`"
    )
    return lines + [
        "",
        f"Errors: {ref}. hevr's times include fixed costs that do not grow with the volume (graph building, "
        "scheduling, starting a few tasks); phe's are all arithmetic.",
        "",
    ]
