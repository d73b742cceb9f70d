"""The pipeline block of ``hevr bench``: frame time against workers, the serial part, a model.

A frame on a cluster is serial client work, then a task graph on N workers, then serial
client work again::

    T(N) = S_before + makespan(graph, N) + S_after

* ``S_before``: client time from the call to the first task's start (rays, plan, footprints,
  graph building, submission, scheduling latency); ``S_after``: from the last task's end
  to the image (gathering, assembly). Both are measured in the traced frame.
* ``makespan``: the graph is recorded from the scheduler (every task and its
  dependencies) and each task's compute time from the task stream; the model replays it
  on N simulated workers with list scheduling (a free worker takes the ready task with the
  longest path to the end of the graph) and a per-task overhead ``o`` fitted so that the
  replay on the traced run's own N workers matches its measured span.
* The tail: how long the graph runs after the last map task ends (merges and finishing
  that could not overlap the map phase).

The model ignores data transfer (all tasks here are compute-bound big-integer arithmetic;
transfers appear in ``o``) and assumes workers like the traced ones. Efficiency is
``T(1) / (N·T(N))``.
"""

from __future__ import annotations

import heapq
import time
from collections import defaultdict
from typing import Any

from distributed import get_task_stream
from distributed.diagnostics.plugin import SchedulerPlugin

from ..rendering.encrypted import render
from ..runtime.scheduler import workers_of

__all__ = ["trace_frame", "simulate", "predict"]

PLUGIN = "hevr-graph-recorder"


class GraphRecorder(SchedulerPlugin):
    """Records every task's dependencies when it starts processing."""

    name = PLUGIN

    def __init__(self) -> None:
        self.deps: dict[str, list[str]] = {}
        self.scheduler: Any = None

    async def start(self, scheduler: Any) -> None:
        self.scheduler = scheduler

    def transition(self, key: Any, start: str, finish: str, *args: Any, **kwargs: Any) -> None:
        if finish == "processing" and self.scheduler is not None:
            ts = self.scheduler.tasks.get(key)
            if ts is not None:
                self.deps[str(key)] = [str(d.key) for d in ts.dependencies]


def _take_deps(dask_scheduler: Any = None) -> dict:
    plugin = dask_scheduler.plugins.get(PLUGIN)
    return dict(plugin.deps) if plugin is not None else {}


def _kind(key: str) -> str:
    for k in ("map", "part", "merge", "finish", "brick"):
        if f"hevr-{k}" in key:
            return k
    return "other"


def trace_frame(client: Any, ev: Any, camera: Any, **kw: Any) -> dict:
    """Render one frame (``cache=False``) and record its graph, task times and serial parts."""
    client.register_plugin(GraphRecorder(), name=PLUGIN)
    try:
        with get_task_stream(client) as ts:
            t0 = time.time()
            img = render(ev, camera, cache=False, client=client, progress=False, **kw)
            t1 = time.time()
        deps = client.run_on_scheduler(_take_deps)
    finally:
        client.unregister_scheduler_plugin(PLUGIN)
    dur: dict[str, float] = {}
    first, last, last_map = float("inf"), 0.0, 0.0
    for rec in ts.data:
        key = str(rec["key"])
        comp = [s for s in rec["startstops"] if s["action"] == "compute"]
        if not comp:
            continue
        dur[key] = sum(s["stop"] - s["start"] for s in comp)
        first, last = min(first, comp[0]["start"]), max(last, comp[-1]["stop"])
        if _kind(key) == "map":
            last_map = max(last_map, comp[-1]["stop"])
    deps = {k: [d for d in v if d in dur] for k, v in deps.items() if k in dur}
    by_kind: dict[str, list[float]] = defaultdict(list)
    for k, d in dur.items():
        by_kind[_kind(k)].append(d)
    n_workers = len(workers_of(client))
    # Task times come from the workers' clocks (the same clock on one machine; a cluster's are
    # offset-corrected by distributed): a few ms of skew can make the serial parts slightly negative.
    return {
        "wall": t1 - t0,
        "workers": n_workers,
        "serial_before": max(0.0, first - t0),
        "serial_after": max(0.0, t1 - last),
        "span": last - first,
        "tail": last - last_map,
        "busy": sum(dur.values()),
        "tasks": len(dur),
        "kinds": {k: {"n": len(v), "sum": sum(v), "max": max(v)} for k, v in sorted(by_kind.items())},
        "durations": dur,
        "deps": deps,
        "image_stats": {k: v for k, v in img.stats.items() if k != "seconds"},
    }


def simulate(deps: dict[str, list[str]], dur: dict[str, float], n_workers: int, overhead: float = 0.0) -> float:
    """Makespan of the task graph on ``n_workers`` by list scheduling (longest path first).

    >>> simulate({"a": [], "b": [], "c": ["a", "b"]}, {"a": 1.0, "b": 2.0, "c": 1.0}, 2)
    3.0
    >>> simulate({"a": [], "b": [], "c": ["a", "b"]}, {"a": 1.0, "b": 2.0, "c": 1.0}, 1)
    4.0
    """
    children: dict[str, list[str]] = defaultdict(list)
    waiting = {k: len(v) for k, v in deps.items()}
    for k, v in deps.items():
        for d in v:
            children[d].append(k)
    cost = {k: dur[k] + overhead for k in deps}
    level: dict[str, float] = {}
    for k in deps:  # iterative longest path to a sink
        stack = [k]
        while stack:
            x = stack[-1]
            if x in level:
                stack.pop()
                continue
            todo = [c for c in children[x] if c not in level]
            if todo:
                stack.extend(todo)
                continue
            level[x] = cost[x] + max((level[c] for c in children[x]), default=0.0)
            stack.pop()
    ready = [(-level[k], k) for k, n in waiting.items() if n == 0]
    heapq.heapify(ready)
    running: list[tuple[float, str]] = []
    now, free = 0.0, n_workers
    while ready or running:
        while ready and free:
            _, k = heapq.heappop(ready)
            heapq.heappush(running, (now + cost[k], k))
            free -= 1
        now, k = heapq.heappop(running)
        free += 1
        for c in children[k]:
            waiting[c] -= 1
            if waiting[c] == 0:
                heapq.heappush(ready, (-level[c], c))
    return now


def predict(trace: dict, workers: list[int]) -> dict:
    """Frame time and efficiency for each N in ``workers`` from one traced frame."""
    deps, dur, n0 = trace["deps"], trace["durations"], trace["workers"]
    lo, hi = 0.0, max(trace["span"], 0.0)  # the makespan grows with the overhead: bisect
    if simulate(deps, dur, n0) < trace["span"]:
        for _ in range(30):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if simulate(deps, dur, n0, mid) < trace["span"] else (lo, mid)
    overhead = lo
    serial = trace["serial_before"] + trace["serial_after"]
    t = {n: serial + simulate(deps, dur, n, overhead) for n in sorted(set(workers) | {1})}
    return {
        "overhead_per_task": overhead,
        "serial": serial,
        "frame": {str(n): t[n] for n in workers},
        "efficiency": {str(n): t[1] / (n * t[n]) for n in workers},
    }
