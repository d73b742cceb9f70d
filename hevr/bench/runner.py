"""Run a benchmark setting block by block, saving raw numbers after every cell.

A block (one key size of Table 1, one of Table 3, the micro-benchmarks, ...) is the unit of
resumption: ``resume=True`` skips blocks the JSON records as done, so a stopped two-hour
``--paper`` run continues where it was. Markdown and the plot are regenerated after each
block, so partial results are always readable.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..core.files import read_regular, write_atomic
from ..errors import ExistingFileError, MissingDependencyError, ParameterError
from ..paper import TF_NODES
from ..volume.phantom import phantom
from . import cases, measure
from .crypto_micro import crypto_micro
from .kernel_micro import kernel_micro
from .pipeline import predict
from .report import write_report
from .settings import SETTINGS, BenchSettings, block_names

log = logging.getLogger(__name__)

BLOCK_KINDS = ("micro", "t1", "t3", "t2", "naive", "scaling", "pipeline")


class Results:
    """The raw-numbers JSON of one run: ``{"setting", "machine", "cells", "blocks_done"}``.

    A fresh run creates it exclusively: an existing results file (or the markdown and plot of
    the setting, :func:`outputs`) is a :class:`hevr.ExistingFileError` unless ``overwrite``;
    ``resume`` continues the one there. From then on the run owns these files and rewrites
    them (atomically) after every cell."""

    def __init__(self, path: Path, settings: BenchSettings, resume: bool, overwrite: bool = False) -> None:
        self.path = path
        doc = None
        self._replace = overwrite or (resume and path.exists())
        if not self._replace:
            for p in outputs(path.parent, settings.name):
                if p.exists() or p.is_symlink():
                    raise ExistingFileError("out", p)
        if resume and path.exists():
            doc = json.loads(read_regular(path, "resume", "the results of an earlier run"))  # never a FIFO
            if doc.get("setting", {}).get("name") != settings.name:
                raise ParameterError(
                    f"resume: {path} holds a {doc.get('setting', {}).get('name')!r} run, not {settings.name!r}"
                )
        if doc is None:
            doc = {
                "setting": settings.to_dict(),
                "machine": measure.machine(),
                "cells": {},
                "blocks_done": [],
                "block_seconds": {},
            }
        doc.setdefault("machines", []).append(measure.machine())  # one entry per (re)start
        self.doc = doc
        self.save()

    @property
    def cells(self) -> dict[str, Any]:
        return self.doc["cells"]

    def put(self, key: str, value: Any) -> None:
        self.cells[key] = value
        self.save()

    def save(self) -> None:
        write_atomic(
            self.path,
            json.dumps(self.doc, indent=1, sort_keys=True) + "\n",
            overwrite=self._replace,
            name="out",
            doing="writing the benchmark results",
        )
        self._replace = True  # this run's own file from now on


def outputs(out: Path, name: str) -> list[Path]:
    """The files a run of the setting ``name`` writes into ``out``: results JSON, markdown, plot."""
    return [
        out / f"results-{name}.json",
        out / ("RESULTS.md" if name == "paper" else f"RESULTS-{name}.md"),
        out / f"scaling-{name}.png",
    ]


def _at_bits(block: Callable[..., None], bits: int) -> Callable[..., None]:
    """``block`` at one key size: called as the other blocks are, ``fn(ctx, results, settings)``."""

    def fn(ctx: Any, r: Any, s: BenchSettings) -> None:
        block(ctx, r, s, bits)

    return fn


def _blocks(s: BenchSettings) -> list[tuple[str, str, Callable[..., None]]]:
    """(name, kind, function) in the run order of :func:`block_names`."""
    fns: dict[str, Callable[..., None]] = {"micro": _micro, "naive": _naive, "scaling": _scaling, "pipeline": _pipeline}
    table = {"t1": _table1, "t3": _table3, "t2": _table2_extra}
    out = []
    for name, kind in block_names(s):
        fn = fns.get(kind) or _at_bits(table[kind], int(name.split(".")[1]))
        out.append((name, kind, fn))
    return out


def _micro(ctx: cases.Context, r: Results, s: BenchSettings) -> None:
    for bits in s.micro_bits:
        r.put(f"micro.crypto.{bits}", crypto_micro(bits, s.micro_n))
    r.put(f"micro.kernel.{s.kernel_bits}", kernel_micro(s.kernel_bits, s.kernel_quick))


def _table1(ctx: cases.Context, r: Results, s: BenchSettings, bits: int) -> None:
    vol = phantom(s.size)
    _pub, priv, keygen_s = ctx.keypair(bits)
    r.put(f"keygen.{bits}", keygen_s)
    for obf in (False, True):
        tag = "obf" if obf else "plain"
        path = ctx.work / f"t1-{bits}-{tag}.zarr"
        ev, cell = cases.encrypt_case(ctx, vol, priv, path, obfuscate=obf)
        r.put(f"t1.{bits}.{tag}.encrypt", cell)
        if obf:
            r.put(f"t2.{bits}.1", {k: cell[k] for k in ("ciphertext_bytes", "store_bytes")} | {"source": "table 1"})
        for sampling in ("nearest", "trilinear"):
            r.put(f"t1.{bits}.{tag}.{sampling}", cases.render_case(ctx, ev, vol, priv, sampling=sampling))
        if obf and bits == s.workers_bits and ctx.workers.own:
            with measure.workers(1) as one:
                sub = cases.Context(one, ctx.work, ctx.brick, ctx.image, ctx.progress, ctx.keys)
                r.put("scale.workers.1", cases.render_case(sub, ev, vol, priv, sampling="trilinear"))
        cases.remove(path)


def _table3(ctx: cases.Context, r: Results, s: BenchSettings, bits: int) -> None:
    vol = phantom(s.size)
    _pub, priv, _ = ctx.keypair(bits)
    for dims in s.dims:
        path = ctx.work / f"t3-{bits}-{dims}.zarr"
        ev, cell = cases.encrypt_case(ctx, vol, priv, path, dims=dims)
        r.put(f"t3.{bits}.{dims}.encrypt", cell)
        r.put(f"t2.{bits}.{dims}", {k: cell[k] for k in ("ciphertext_bytes", "store_bytes")} | {"source": "table 3"})
        for k in range(1, dims + 1):
            r.put(f"t3.{bits}.{dims}.{k}", cases.render_case(ctx, ev, vol, priv, mode="tf", nodes=TF_NODES[:k]))
        if dims == 4:  # beside the paper's way: the same frame coloured on the client, end to end
            r.put(
                f"client.{bits}.tf4", cases.render_case(ctx, ev, vol, priv, mode="tf", nodes=TF_NODES, finish="client")
            )
        if bits == s.goal_bits and dims == 4:
            r.put(
                f"goal.tf4_trilinear.{bits}",
                cases.render_case(ctx, ev, vol, priv, mode="tf", sampling="trilinear", nodes=TF_NODES),
            )
        cases.remove(path)


def _table2_extra(ctx: cases.Context, r: Results, s: BenchSettings, bits: int) -> None:
    """Bytes on disk for encodings not encrypted for Table 3: written without the random mask
    (seconds instead of an hour; the layout and sizes do not depend on the mask)."""
    vol = phantom(s.size)
    _pub, priv, _ = ctx.keypair(bits)
    for dims in (1,) + tuple(s.dims):
        if f"t2.{bits}.{dims}" in r.cells:
            continue
        path = ctx.work / f"t2-{bits}-{dims}.zarr"
        _ev, cell = cases.encrypt_case(ctx, vol, priv, path, dims=dims, obfuscate=False)
        r.put(
            f"t2.{bits}.{dims}",
            {k: cell[k] for k in ("ciphertext_bytes", "store_bytes")} | {"source": "unobfuscated, for Table 2 only"},
        )
        cases.remove(path)


def _naive(ctx: cases.Context, r: Results, s: BenchSettings) -> None:
    r.put("naive.phe", cases.naive_phe_case(s.naive_size, s.naive_image, s.naive_bits))
    r.put("naive.hevr", cases.hevr_small_case(ctx, s.naive_size, s.naive_image, s.naive_bits))


def _scaling(ctx: cases.Context, r: Results, s: BenchSettings) -> None:
    _pub, priv, _ = ctx.keypair(s.scaling_bits)
    for size in s.scaling_sizes:
        vol = phantom(size)
        path = ctx.work / f"scale-{size}.zarr"
        ev, cell = cases.encrypt_case(ctx, vol, priv, path, brick=max(2, -(-size // 4)))
        r.put(f"scale.size.{size}.encrypt", cell)
        for sampling in ("nearest", "trilinear"):
            r.put(f"scale.size.{size}.{sampling}", cases.render_case(ctx, ev, vol, priv, sampling=sampling))
        cases.remove(path)


def _pipeline(ctx: cases.Context, r: Results, s: BenchSettings) -> None:
    """Resident X-ray nearest frames on 1 … cores workers (and 2·cores, oversubscribed), each
    traced; the model (:mod:`hevr.bench.pipeline`) fitted on the largest run that is not
    oversubscribed predicts 1 … 64 workers."""
    vol = phantom(s.size)
    _pub, priv, _ = ctx.keypair(s.pipeline_bits)
    path = ctx.work / "pipeline.zarr"
    ev, _cell = cases.encrypt_case(ctx, vol, priv, path)
    cores = os.cpu_count() or 1
    counts = sorted({1, 2, cores, 2 * cores}) if ctx.workers.own else [ctx.workers.n_workers]
    best = None
    for n in counts:
        with measure.workers(n) if ctx.workers.own else contextlib.nullcontext(ctx.workers) as w:
            tr = cases.pipeline_case(w, ev, ctx.camera(ev.shape))
        tr["oversubscribed"] = n > cores
        r.put(f"pipeline.{n}", {k: v for k, v in tr.items() if k not in ("durations", "deps")})
        if not tr["oversubscribed"]:
            best = tr
    if best is not None:
        r.put("pipeline.model", predict(best, [1, 2, 4, 8, 16, 32, 64]) | {"from_workers": best["workers"]})
    cases.remove(path)


def run_bench(
    setting: str | BenchSettings = "quick",
    out: str | Path = ".",
    *,
    resume: bool = False,
    only: tuple[str, ...] | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    work: str | Path | None = None,
    progress: bool = False,
    overwrite: bool = False,
    log_line: Callable[[str], None] = lambda _: None,
) -> Path:
    """Run the benchmark ``setting`` and write ``RESULTS*.md``, ``results-*.json`` and the
    scaling plot into ``out``. Returns the markdown path. Files of an earlier run of the
    setting there are continued with ``resume=True``, replaced with ``overwrite=True``, and
    otherwise refused before anything is measured (:class:`hevr.ExistingFileError`)."""

    s = SETTINGS[setting] if isinstance(setting, str) else setting
    if only is not None:
        bad = sorted(set(only) - set(BLOCK_KINDS))
        if bad:
            raise ParameterError(f"only: expected some of {', '.join(BLOCK_KINDS)}, got {', '.join(bad)}")
    if only is None or {"micro", "naive"} & set(only):
        try:
            import phe  # noqa: F401
        except ImportError:
            raise MissingDependencyError(
                "hevr bench compares with python-paillier: pip install phe (or "
                "'hevr[test]'), or leave out the micro and naive blocks with --only"
            ) from None
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results = Results(out / f"results-{s.name}.json", s, resume, overwrite)
    scratch = Path(work) if work else Path(tempfile.mkdtemp(prefix=f"hevr-bench-{s.name}-"))
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        with measure.workers(workers, scheduler) as w:
            ctx = cases.Context(w, scratch, s.brick, s.image, progress)
            for name, kind, fn in _blocks(s):
                if (only is not None and kind not in only) or name in results.doc["blocks_done"]:
                    continue
                log_line(f"[{time.strftime('%H:%M:%S')}] {name} …")
                t0 = time.perf_counter()
                fn(ctx, results, s)
                results.doc["block_seconds"][name] = time.perf_counter() - t0
                results.doc["blocks_done"].append(name)
                results.save()
                md = write_report(results.doc, out)
                log_line(f"[{time.strftime('%H:%M:%S')}] {name} done in {time.perf_counter() - t0:.1f} s → {md}")
    finally:  # stores can be gigabytes; a resumed block re-encrypts anyway
        if not work:
            cases.remove(scratch)
    return write_report(results.doc, out)


def rewrite_report(setting: str, out: str | Path) -> Path:
    """Rewrite the markdown and plot of ``setting`` from ``out/results-<setting>.json`` only."""

    path = Path(out) / f"results-{setting}.json"
    if not path.is_file():
        raise ParameterError(f"out: expected {path} from an earlier run, found none")
    return write_report(json.loads(read_regular(path, "out", "the results of an earlier run")), Path(out))
