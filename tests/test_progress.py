"""hevr's one progress mechanism: the right display for where it runs, driven the same way by
the local schedulers (a Dask callback) and by a distributed client (completed futures)."""

from __future__ import annotations

import io
import logging

import dask
import pytest

from hevr.runtime import progress as _progress
from hevr.runtime import scheduler as _dask
from hevr.runtime.progress import Progress, TaskCounter, sink_kind


def _tasks(k: int):
    return [dask.delayed(lambda i: i * i, pure=True)(i) for i in range(k)]


def test_not_a_terminal_gives_a_few_log_lines_and_no_carriage_returns(capsys, caplog):
    caplog.set_level(logging.INFO, logger="hevr.progress")
    assert sink_kind() == "log"  # pytest's captured stderr is not a TTY
    assert _dask.compute(_tasks(40), desc="job") == [i * i for i in range(40)]
    lines = [r.getMessage() for r in caplog.records if r.name == "hevr.progress"]
    assert 2 <= len(lines) <= 5, lines
    assert lines[-1].startswith("job: 40/40 tasks")
    assert "\r" not in capsys.readouterr().err


def test_progress_false_is_silent(capsys, caplog):
    caplog.set_level(logging.INFO, logger="hevr.progress")
    _dask.compute(_tasks(5), progress=False)
    assert not [r for r in caplog.records if r.name == "hevr.progress"]
    assert capsys.readouterr().err == ""


def test_terminal_bar_redraws_one_line_and_ends_it(monkeypatch):
    err = io.StringIO()
    err.isatty = lambda: True  # type: ignore[method-assign]
    monkeypatch.setattr(_progress.sys, "stderr", err)
    assert sink_kind() == "terminal"
    bar = Progress(3, "enc")
    for _ in range(3):
        bar.update()
    bar.close()
    text = err.getvalue()
    assert text.startswith("\renc [") and text.endswith("3/3 tasks, 0.0 s\x1b[K\n") and text.count("\n") == 1


def test_notebook_widget(monkeypatch):
    pytest.importorskip("ipywidgets")
    shown = []
    monkeypatch.setattr(_progress, "_in_jupyter", lambda: True)
    monkeypatch.setattr("IPython.display.display", lambda w: shown.append(w))
    assert sink_kind() == "widget"
    bar = Progress(0, "render")
    with TaskCounter(bar):  # the local scheduler's callback sets the total when the graph starts
        dask.compute(*_tasks(6))
    (box,) = shown
    progress_bar, label = box.children
    assert progress_bar.max == 6 and progress_bar.value == 6 and progress_bar.bar_style == "success"
    assert label.value.startswith("6/6 tasks")


def test_distributed_counts_futures(cluster, caplog):
    caplog.set_level(logging.INFO, logger="hevr.progress")
    assert _dask.compute(_tasks(8), client=cluster, desc="dist") == [i * i for i in range(8)]
    lines = [r.getMessage() for r in caplog.records if r.name == "hevr.progress"]
    assert lines and lines[-1].startswith("dist: 8/8 tasks")


def test_a_failing_job_closes_its_display(monkeypatch):
    err = io.StringIO()
    err.isatty = lambda: True  # type: ignore[method-assign]
    monkeypatch.setattr(_progress.sys, "stderr", err)

    def boom(i):
        raise RuntimeError("task failed")

    with pytest.raises(RuntimeError, match="task failed"):
        _dask.compute([dask.delayed(boom)(1), dask.delayed(boom)(2)], desc="bad")
    assert err.getvalue().endswith(" failed\n")


def test_a_failing_job_on_a_cluster_is_not_shown_as_a_success(monkeypatch, cluster):
    pytest.importorskip("ipywidgets")
    shown = []
    monkeypatch.setattr(_progress, "_in_jupyter", lambda: True)
    monkeypatch.setattr("IPython.display.display", lambda w: shown.append(w))

    def boom(i):
        raise RuntimeError("task failed")

    with pytest.raises(RuntimeError, match="task failed"):
        _dask.compute([dask.delayed(boom)(1), dask.delayed(lambda: 2)()], client=cluster, desc="bad")
    (box,) = shown
    assert box.children[0].bar_style == "danger"


def _stepping(k: int, per: int, pause: float = 0.0):
    import time

    from hevr.runtime import cancel

    def task(i):
        for _ in range(per):
            cancel.add_steps(1)
            time.sleep(pause)
        return i

    return [dask.delayed(task, pure=False)(i) for i in range(k)]


def test_finer_steps_show_a_moving_rate_and_time_left(caplog):
    """Issue 39, item 10: encryption showed progress once per brick; the steps inside a task
    (its ciphertexts) now move the display, with a rate and the time left, off a terminal too."""
    caplog.set_level(logging.INFO, logger="hevr.progress")
    assert _dask.compute(_stepping(2, 50), desc="enc", steps=100, unit="ciphertexts") == [0, 1]
    lines = [r.getMessage() for r in caplog.records if r.name == "hevr.progress"]
    assert 5 <= len(lines) <= 12, lines  # a tenth at a time, though there are only 2 tasks
    assert lines[-1].startswith("enc: 100/100 ciphertexts") and "ciphertexts/s" in lines[-1]
    assert any("s left" in line for line in lines[1:-1]), lines


def test_finer_steps_come_from_distributed_workers(cluster, caplog):
    caplog.set_level(logging.INFO, logger="hevr.progress")
    _dask.compute(_stepping(2, 40, pause=0.03), client=cluster, desc="enc", steps=80, unit="ciphertexts")
    lines = [r.getMessage() for r in caplog.records if r.name == "hevr.progress"]
    assert lines[-1].startswith("enc: 80/80 ciphertexts"), lines
    counts = [int(line.split("/")[0].split()[-1].replace(",", "")) for line in lines]
    assert any(0 < c < 80 for c in counts), lines  # worker events arrived while the tasks ran
