"""hevr's one progress mechanism: a widget in Jupyter, a bar on a terminal, a few log lines otherwise.

Every job that shows progress (encryption, rendering, store upgrades, the benchmarks) goes
through :class:`Progress`; it picks where to draw once, when the job starts:

* **Jupyter** (an IPython kernel is running and ipywidgets is installed): an
  ``ipywidgets.IntProgress`` with a label, displayed in the cell's output and updated in place;
* **a terminal** (stderr is a TTY): one line redrawn with carriage returns, at most five times
  a second, ended by a newline;
* **anything else** (logs, CI, pipes): no drawing at all, only INFO records of the
  ``hevr.progress`` logger at 0, 25, 50, 75 and 100 % (a handful of lines, never ``\\r`` frames);
  a job with finer steps (the ciphertexts of ``encrypt``) at every tenth and at least once a
  minute, each with its rate and the time left. The CLI shows them on stderr.

Jobs on a ``distributed`` client count completed futures (:func:`hevr.runtime.scheduler.compute`); jobs on
Dask's local schedulers count finished graph tasks through a Dask callback
(:class:`TaskCounter`), so the same bar serves both.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from typing import Any

from dask.callbacks import Callback

log = logging.getLogger("hevr.progress")

__all__ = ["Progress", "TaskCounter", "sink_kind"]

_QUARTERS = 4
_LOG_EVERY = 60.0  # seconds between log lines of a long job (besides its tenths)


def _in_jupyter() -> bool:
    """Whether this process is an IPython kernel (a notebook, JupyterLab, VS Code, nbclient)."""
    shell = sys.modules.get("IPython")
    if shell is None or "ipykernel" not in sys.modules:
        return False
    try:
        ip = shell.get_ipython()
    except AttributeError:  # pragma: no cover - a partial IPython
        return False
    return ip is not None and "IPKernelApp" in getattr(ip, "config", {})


def sink_kind() -> str:
    """Where a progress display would go now: ``"widget"``, ``"terminal"`` or ``"log"``.

    >>> sink_kind() in ("widget", "terminal", "log")
    True
    """
    if _in_jupyter():
        try:
            import ipywidgets  # noqa: F401
        except ImportError:
            return "log"
        return "widget"
    return "terminal" if bool(getattr(sys.stderr, "isatty", lambda: False)()) else "log"


class Progress:
    """Progress of one job of ``total`` steps.

    Parameters
    ----------
    total : int
        Steps of the job (tasks). A job of 0 steps shows nothing.
    desc : str
        Short name of the job (``"encrypt"``, ``"render"``).
    enabled : bool
        False: count silently (``progress=False`` of the public functions).
    kind : str, optional
        Force ``"widget"``, ``"terminal"`` or ``"log"``; default :func:`sink_kind`.

    >>> p = Progress(8, "demo", kind="log")
    >>> for _ in range(8):
    ...     p.update()
    >>> p.close()
    >>> p.done, p.closed
    (8, True)
    """

    def __init__(
        self,
        total: int,
        desc: str,
        enabled: bool = True,
        kind: str | None = None,
        *,
        steps: int = 0,
        unit: str = "tasks",
    ) -> None:
        self.total, self.desc = max(0, int(total)), desc
        self.kind = (kind or sink_kind()) if enabled else "off"
        self.done = 0
        self.steps, self.unit, self.steps_done = max(0, int(steps)), unit, 0  # finer steps (:meth:`step`)
        self._lock = threading.Lock()
        self._logged_at = 0.0
        self.closed = False
        self.start = time.perf_counter()
        self._last = 0.0
        self._quarter = -1
        self._widget: Any = None
        self._drawn = False
        self._draw(force=True)

    def _open_widget(self) -> None:
        import ipywidgets as widgets
        from IPython.display import display

        bar = widgets.IntProgress(
            value=0, min=0, max=self.total, description=self.desc, layout=widgets.Layout(width="60%")
        )
        label = widgets.Label(value=f"0/{self.total}")
        self._widget = (bar, label)
        display(widgets.HBox([bar, label]))

    def set_total(self, total: int) -> None:
        """Change the number of steps (a Dask callback learns it when the graph starts)."""
        self.total = max(0, int(total))
        if self._widget is not None:
            self._widget[0].max = self.total
        self._draw(force=True)

    def update(self, k: int = 1) -> None:
        """``k`` more tasks are done (a task that failed counts as done: :meth:`close` says so)."""
        with self._lock:
            self.done += k
            self._draw(force=self.done >= self.total)

    def step(self, k: int = 1) -> None:
        """``k`` more of the job's finer ``steps`` (e.g. ciphertexts) are done; from any thread.
        A job given ``steps`` is shown by them: its rate and the time left move within a task."""
        with self._lock:
            self.steps_done += k
            self._draw()

    def status(self, now: float | None = None) -> str:
        """``done/total unit, elapsed``, and while it runs the rate and the time left.

        >>> p = Progress(4, "enc", kind="off", steps=1000, unit="ciphertexts")
        >>> p.start -= 10; p.step(250)
        >>> p.status(p.start + 10)
        '250/1,000 ciphertexts, 10.0 s, 25 ciphertexts/s, 30 s left'
        """
        el = (time.perf_counter() if now is None else now) - self.start
        done, total, unit = (
            (min(self.steps_done, self.steps), self.steps, self.unit)
            if self.steps
            else (min(self.done, self.total), self.total, "tasks")
        )
        text = f"{done:,}/{total:,} {unit}, {el:.1f} s"
        if done and el > 0 and (self.steps or done < total):
            rate = done / el
            text += f", {_number(rate)} {unit}/s"
            if done < total:
                text += f", {_duration((total - done) / rate)} left"
        return text

    def close(self, failed: bool = False) -> None:
        """End the display (idempotent): the terminal line gets its newline; the widget turns
        green, or red when ``failed`` (or orange when the job stopped early)."""
        if self.closed:
            return
        self._draw(force=True)
        self.closed = True
        if failed and self.kind == "log" and self.total:
            log.info("%s: stopped after %s", self.desc, self.status())
        if self.kind == "terminal" and self._drawn:
            if failed:
                sys.stderr.write(" failed")
            sys.stderr.write("\n")
            sys.stderr.flush()
        if self._widget is not None:
            self._widget[0].bar_style = "danger" if failed else "success" if self.done >= self.total else "warning"

    def _draw(self, force: bool = False) -> None:
        if self.kind == "off" or self.closed or self.total == 0:
            return
        if not self._drawn and self.kind == "widget":
            self._open_widget()
        self._drawn = True
        now = time.perf_counter()
        if self.kind == "log":  # a line at every tenth (a quarter for a job of tasks only), or each minute
            done, total = (self.steps_done, self.steps) if self.steps else (self.done, self.total)
            parts = 10 if self.steps else _QUARTERS
            part = parts * min(done, total) // max(total, 1)
            if part != self._quarter or (self.steps and now - self._logged_at >= _LOG_EVERY and done < total):
                self._quarter, self._logged_at = part, now
                log.info("%s: %s", self.desc, self.status(now))
            return
        if not force and now - self._last < 0.2:
            return
        self._last = now
        if self.kind == "widget":
            bar, label = self._widget
            bar.value = min(self.done, self.total)
            label.value = self.status(now)
            return
        width = 30
        done, total = (self.steps_done, self.steps) if self.steps else (self.done, self.total)
        fill = width * min(done, total) // max(total, 1)
        sys.stderr.write(f"\r{self.desc} [{'#' * fill}{'-' * (width - fill)}] {self.status(now)}\x1b[K")
        sys.stderr.flush()


def _number(x: float) -> str:
    """A rate, 3 significant digits, thousands separated: ``_number(1234.5)`` is ``'1,234'``."""
    return f"{x:,.0f}" if x >= 100 else f"{x:.3g}"


def _duration(seconds: float) -> str:
    """``_duration(75)`` is ``'1 min 15 s'``; ``_duration(7300)`` is ``'2 h 2 min'``."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {s % 3600 // 60} min"


class TaskCounter(Callback):
    """A Dask callback (local schedulers) that drives a :class:`Progress` per finished task.

    >>> import dask
    >>> p = Progress(0, "sum", kind="log")
    >>> with TaskCounter(p):
    ...     dask.compute(dask.delayed(sum)([1, 2]))
    (3,)
    >>> p.total, p.done
    (1, 1)
    """

    def __init__(self, progress: Progress) -> None:
        super().__init__()
        self.progress = progress

    def _start_state(self, dsk: Any, state: dict) -> None:
        total = sum(len(state[k]) for k in ("ready", "waiting", "running", "finished"))
        self.progress.set_total(total)

    def _posttask(self, key: Any, result: Any, dsk: Any, state: dict, worker_id: Any) -> None:
        self.progress.update()

    def _finish(self, dsk: Any, state: dict, errored: bool) -> None:
        self.progress.close(failed=errored)
