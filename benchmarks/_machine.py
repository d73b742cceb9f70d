"""Describe the machine a benchmark ran on (appended to benchmarks/history.md)."""

from __future__ import annotations

import datetime
import os
import platform


def machine() -> str:
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import gmpy2

    return (
        f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC · {cpu} · {os.cpu_count()} cores · "
        f"{platform.system()} {platform.release()} · Python {platform.python_version()} · gmpy2 {gmpy2.version()}"
    )


def append(section: str) -> None:
    path = os.path.join(os.path.dirname(__file__), "history.md")
    new = not os.path.exists(path)
    with open(path, "a") as fh:
        if new:
            fh.write("# Benchmark results\n\nEvery section was appended by the script named in its heading.\n\n")
        fh.write(section.rstrip() + "\n\n")
