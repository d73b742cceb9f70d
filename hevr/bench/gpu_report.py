"""The GPU proof's report: ``gpu.md`` from the results ``hevr bench --gpu`` gathered (``gpu.json``).

One section per step of :mod:`hevr.bench.gpu` that ran, each a table; the last line is the verdict.
"""

from __future__ import annotations

from typing import Any


def markdown(res: dict[str, Any]) -> str:
    """``gpu.md``: a section per step found in ``res``, then the verdict."""
    m = res["machine"]
    head = f"Backend `{res['backend']}`; {m['date']}, commit {m.get('commit')}, {m['cpu']} ({m['cores']} cores)."
    lines = [f"# hevr bench --gpu: {res['device']}", "", head, ""]
    if "identity" in res:
        lines += [
            "## Operations against cpu (bit-identical?)",
            "",
            "| bits | " + " | ".join(k for k in res["identity"][0] if k not in ("bits", "values")) + " |",
            "|---|" + "---|" * (len(res["identity"][0]) - 2),
        ]
        for row in res["identity"]:
            lines.append(
                f"| {row['bits']} | "
                + " | ".join("yes" if v else "**NO**" for k, v in row.items() if k not in ("bits", "values"))
                + " |"
            )
        lines.append("")
    if "render" in res:
        lines += [
            "## Renders against cpu (streamed; resident: median of 3 frames, this process)",
            "",
            "| case | size | key bits | identical | within bound | s | resident s | cpu s (workers) |",
            "|---|---:|---:|---|---|---:|---:|---:|",
        ]
        lines += [
            f"| {r['case']} | {r['size']}³ | {r['bits']} | {'yes' if r['identical'] else '**NO**'} | "
            f"{'yes' if r['within_bound'] else '**NO**'} | {r['seconds']:.2f} | {r['resident_seconds']:.3f} | "
            f"{r['cpu_seconds']:.2f} ({r['cpu_workers']}) |"
            for r in res["render"]
        ]
        lines.append("")
    if "throughput" in res:
        lines += [
            "## Throughput at 2048-bit keys (4096-bit products), end to end through ray_products",
            "",
            "| what | rows × 64 | per s | cpu, one core, per s | × one core | goal per s |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for label, r in res["throughput"].items():
            unit = "products_per_s" if label == "products" else "pairs_per_s"
            lines.append(
                f"| {label} | {r['rows']} | {r[unit]:.3g} | {r['cpu_' + unit]:.3g} | "
                f"{r['speedup_vs_one_core']:.3g} | {r['goal']:.1g} |"
            )
        lines.append("")
        staged = {k: r for k, r in res["throughput"].items() if "stages_s" in r}
        if staged:
            lines += [
                (
                    "Where one call's time goes (seconds; a quick run times an eighth of the rows): the plan's "
                    "arrays on the host, the launcher with them on the host (uploads, kernels, counts back), the "
                    "kernels with them on the device:"
                ),
                "",
                "| what | end to end | plan | launch | kernels | kernels alone, per s |",
                "|---|---:|---:|---:|---:|---:|",
            ]
            for label, r in staged.items():
                st, unit = r["stages_s"], "products_per_s" if label == "products" else "pairs_per_s"
                rate = r.get("kernels_" + unit)
                lines.append(
                    f"| {label} | {r['seconds']:.3g} | {st['plan']:.3g} | {st['launch']:.3g} | "
                    f"{st['kernels']:.3g} | {f'{rate:.3g}' if rate else '-'} |"
                )
            lines.append("")
    if res.get("experiments"):
        lines += [
            "## Experiments in the kernel source (compiled in with -D), kernels alone",
            "",
            "| experiment | identical to cpu | products per s | pairs per s |",
            "|---|---|---:|---:|",
        ]
        base = {
            u: r.get("kernels_" + u)
            for r, u in (
                (res.get("throughput", {}).get("products", {}), "products_per_s"),
                (res.get("throughput", {}).get("pairs", {}), "pairs_per_s"),
            )
        }
        lines.append(f"| (default) | yes | {base['products_per_s'] or 0:.3g} | {base['pairs_per_s'] or 0:.3g} |")
        for name, r in res["experiments"].items():
            lines.append(
                f"| {name} | {'yes' if r['identical'] else '**NO**'} | {r['products_per_s'] or 0:.3g} | "
                f"{r['pairs_per_s'] or 0:.3g} |"
            )
        lines.append("")
    if "encryption" in res:
        e = res["encryption"]
        lines += [
            "## Owner-side encryption (owner.cuh)",
            "",
            "| key bits | values | per s | cpu, one core, per s | × one core | 100³ at this rate | goal | exact |",
            "|---:|---:|---:|---:|---:|---:|---:|---|",
            (
                f"| {e['bits']} | {e['values']} | {e['values_per_s']:.3g} | {e['cpu_values_per_s']:.3g} | "
                f"{e['speedup_vs_one_core']:.3g} | {e['volume_100_s']:.3g} s | {e['goal_volume_100_s']:g} s | "
                f"{'yes' if e['exact'] else '**NO**'} |"
            ),
            "",
        ]
    if "encryption_skipped" in res:
        lines += ["## Owner-side encryption (owner.cuh)", "", f"Skipped: {res['encryption_skipped']}.", ""]
    lines.append(
        f"Result: **{'all identical' if res.get('ok') else 'MISMATCH' if res.get('ok') is False else 'incomplete'}**."
    )
    return "\n".join(lines) + "\n"
