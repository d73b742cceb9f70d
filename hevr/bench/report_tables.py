"""The paper's Tables 1-3 redone from a benchmark run: X-ray, bytes on disk, transfer function.

Every cell reads ``ours / paper (paper ÷ ours ×)`` where the run's setting is the paper's case
(100³ voxels, 150² pixels); otherwise ours alone.
"""

from __future__ import annotations

from . import paper
from .report_cells import DASH, compare, lookup, megabytes, number, plain_column


def table1(doc: dict) -> list[str]:
    c, s = doc["cells"], doc["setting"]
    bits = s["t1_bits"]
    pc = s["paper_case"]
    lines = [
        "## Table 1 — X-ray: encrypt, render, decrypt (seconds)",
        "",
        "Without obfuscation the mask r^n is skipped (`unsafe_no_obfuscation=True`): not secure, shown only "
        "because the paper shows it. One encryption per key and mask serves both samplings (the paper "
        "timed it twice), so the nearest and trilinear encrypt rows repeat the same number.",
        "",
        "| sampling | mask | stage | plain | " + " | ".join(f"{b} bit" for b in bits) + " |",
        "|---|---|---|---:|" + "---:|" * len(bits),
    ]
    for sampling in ("nearest", "trilinear"):
        for obf, tag in ((False, "plain"), (True, "obf")):
            for stage, field in (("encrypt", "seconds"), ("render", "seconds"), ("decrypt", "decrypt_s")):
                key = "encrypt" if stage == "encrypt" else sampling
                row = []
                for b in bits:
                    ours = lookup(c, f"t1.{b}.{tag}.{key}", field)
                    theirs = paper.TABLE1[sampling][obf][stage].get(b) if pc else None
                    row.append(compare(ours, theirs))
                plain = (
                    DASH
                    if stage != "render"
                    else plain_column(
                        c, [f"t1.{b}.obf.{sampling}" for b in bits], paper.PLAIN1[sampling] if pc else None
                    )
                )
                lines.append(
                    f"| {sampling} | {'with' if obf else 'without'} | {stage} | {plain} | " + " | ".join(row) + " |"
                )
    errs = [
        (b, t, sp, lookup(c, f"t1.{b}.{t}.{sp}"))
        for b in bits
        for t in ("plain", "obf")
        for sp in ("nearest", "trilinear")
    ]
    bad = [f"{b}/{t}/{sp}" for b, t, sp, cell in errs if cell and not cell["within_bound"]]
    adj = sorted(
        {
            f"{b} bit: precision {cell['params']['precision']}, digits {cell['params']['digits']}"
            for b, _t, _sp, cell in errs
            if cell and cell["params"] != {"precision": 4, "digits": 3}
        }
    )
    refused = [
        f"{b}/{t}/{sp}"
        for b, t, sp, _ in errs
        if isinstance(c.get(f"t1.{b}.{t}.{sp}"), dict) and "refused" in c[f"t1.{b}.{t}.{sp}"]
    ]
    lines += [
        "",
        "Every decrypted image was compared with `render_plain`: "
        + ("all within `error_bound`." if not bad else f"OUTSIDE the bound: {', '.join(bad)}.")
        + (
            f" Reduced precision where the planner refused the default (4 reciprocal digits, 3 weight digits): "
            f"{'; '.join(adj)}."
            if adj
            else ""
        )
        + (f" Refused outright: {', '.join(refused)}." if refused else ""),
        "The plain column is `render_plain` (numpy, one core).",
        "",
    ]
    return lines


def table2(doc: dict) -> list[str]:
    c, s = doc["cells"], doc["setting"]
    bits = sorted({int(k.split(".")[1]) for k in c if k.startswith("t2.")})
    if not bits:
        return []
    pc = s["paper_case"]
    lines = [
        "## Table 2 — bytes on disk (MB = 10⁶ bytes)",
        "",
        "Ours is the size of the ciphertext chunk files in the Zarr store (the whole store adds a few kB of "
        "JSON metadata); cells read `ours / paper`.",
        "",
        "| encoding | plain (8 bit) | " + " | ".join(f"{b} bit" for b in bits) + " |",
        "|---|---:|" + "---:|" * len(bits),
    ]
    size = s["size"]
    for dims in (1, 2, 3, 4):
        row = []
        for b in bits:
            ours = lookup(c, f"t2.{b}.{dims}", "ciphertext_bytes")
            theirs = paper.TABLE2[dims].get(b) if pc else None
            row.append(f"{megabytes(ours)} / {megabytes(theirs)}" if theirs else megabytes(ours))
        plain = size**3 * dims
        lines.append(f"| {'scalar' if dims == 1 else f'{dims} dim'} | {megabytes(plain)} | " + " | ".join(row) + " |")
    srcs = sorted(
        {
            f"{b} bit {('scalar' if d == 1 else f'{d}-dim')}"
            for b in bits
            for d in (1, 2, 3, 4)
            if (lookup(c, f"t2.{b}.{d}", "source") or "").startswith("unobf")
        }
    )
    if srcs:
        lines += [
            "",
            "Written without the mask only to count bytes (same layout, seconds instead of hours): "
            + ", ".join(srcs)
            + ".",
        ]
    return lines + [""]


def table3(doc: dict) -> list[str]:
    c, s = doc["cells"], doc["setting"]
    bits = s["t3_bits"]
    pc = s["paper_case"]
    lines = [
        "## Table 3 — transfer function: encrypt, render, decrypt (seconds)",
        "",
        "Nearest sampling, the nodes of the paper's Fig. 6(d) (blue 0, yellow 0.293, green — `lime`, "
        "#00ff00 — 0.664, purple 1; the first k for k colours), RGB output packed for the client.",
        "",
        "| encoding | colours | stage | plain | " + " | ".join(f"{b} bit" for b in bits) + " |",
        "|---|---|---|---:|" + "---:|" * len(bits),
    ]
    for dims in s["dims"]:
        row = [
            compare(lookup(c, f"t3.{b}.{dims}.encrypt", "seconds"), paper.TABLE3_ENCRYPT[dims].get(b) if pc else None)
            for b in bits
        ]
        lines.append(f"| {dims} dim | | encrypt | {DASH} | " + " | ".join(row) + " |")
        for k in range(1, dims + 1):
            for stage, field, table in (
                ("render", "seconds", paper.TABLE3_RENDER),
                ("decrypt", "decrypt_s", paper.TABLE3_DECRYPT),
            ):
                row = [
                    compare(lookup(c, f"t3.{b}.{dims}.{k}", field), table[(dims, k)].get(b) if pc else None)
                    for b in bits
                ]
                plain = (
                    DASH
                    if stage != "render"
                    else plain_column(c, [f"t3.{b}.{dims}.{k}" for b in bits], paper.PLAIN3[(dims, k)] if pc else None)
                )
                lines.append(f"| {dims} dim | {k} | {stage} | {plain} | " + " | ".join(row) + " |")
    g = lookup(c, f"goal.tf4_trilinear.{s.get('goal_bits')}")
    if g:
        lines += [
            "",
            f"4-dim, 4 colours, trilinear at {s['goal_bits']} bits: render {number(g['seconds'])} s, "
            f"decrypt {number(g['decrypt_s'])} s (the paper gives no trilinear transfer-function figures).",
        ]
    client = [(b, lookup(c, f"client.{b}.tf4")) for b in bits if lookup(c, f"client.{b}.tf4")]
    if client:  # the same 4-dim, 4-colour frame, coloured on the client (hevr's default)
        lines += [
            "",
            'Coloured on the client (`finish="client"`, the default; the rows above are the paper\'s '
            "server-side finishing), 4-dim, 4 colours, end to end (request → decrypted image, decryption "
            "included): "
            + ", ".join(f"{b} bit {number(v['seconds'])} s ({v['ciphertexts']} ciphertexts)" for b, v in client)
            + ".",
        ]
    return lines + [""]
