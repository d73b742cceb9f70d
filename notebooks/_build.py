"""Build the example notebooks from their jupytext sources, executed and with outputs.

Each notebook ``NN_name.ipynb`` in this folder is generated from ``NN_name.py``, a
jupytext *percent* script: ordinary Python that linters and ``py_compile`` accept, where
``# %%`` starts a code cell, ``# %% [markdown]`` a markdown cell (its lines commented
out) and cell tags are cell metadata (``# %% tags=["summary"]``). Edit the ``.py``, then
run::

    python notebooks/_build.py                   # convert, execute and write every notebook
    python notebooks/_build.py 01_quickstart     # only the named ones
    python notebooks/_build.py --check           # exit 1 if a committed .ipynb is stale

The ``.ipynb`` files are committed *with* their outputs (text, tables and the matplotlib
PNGs), so that a code host shows the pictures without running anything. To keep a
rebuild's diff small, cell ids are deterministic (``01-00``, ``01-01``, ...) and
volatile metadata is dropped: execution timestamps, the kernel's version details and the
widget state (random model ids); a widget's output keeps its plain-text form. What still
changes from one build to the next are timings and the temporary folder's random name.

``--check`` does not execute anything: it verifies that each committed notebook's code
and markdown cells (type, source, tags) equal its ``.py`` source, that every code cell
was executed without error, and that no output shows a path of the build machine or a
long number (possible key material).

Execution runs each notebook in a fresh kernel of *this* interpreter: a throw-away
kernelspec named ``python3`` pointing at ``sys.executable`` is put first on
``JUPYTER_PATH`` (with a clean ``IPYTHONDIR``), so a ``python3`` kernelspec of another
Python cannot hijack the run and nothing has to be installed. After the last cell, a
probe run in the same kernel (not written to the notebook) collects the primes of every
private key still alive, and the build fails if any output shows one of them.
``tests/test_notebooks.py`` uses the same functions.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import jupytext
import nbformat

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SOURCE_FORMAT = "py:percent"
CELL_TIMEOUT = 300   # seconds per cell

# Notebook-level metadata of every built notebook (whatever the kernel reported).
NOTEBOOK_METADATA = {
    "jupytext": {"formats": "ipynb,py:percent"},
    "kernelspec": {"display_name": "Python 3 (ipykernel)", "language": "python", "name": "python3"},
    "language_info": {"name": "python"},
}
# Cell metadata that execution adds and a rebuild would change.
VOLATILE_CELL_METADATA = ("execution", "collapsed", "scrolled")
WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"

# Run in the kernel after the last cell: prints the private key numbers (never written).
PROBE_SOURCE = "import _build as _hevr_build\n_hevr_build.print_private_key_numbers()"

# Output text that must not appear in a committed notebook.
LONG_DECIMAL = re.compile(r"\d{25,}")          # a 128-bit prime has 39 digits
LONG_HEX = re.compile(r"[0-9a-fA-F]{32,}")       # ... and 32 hex digits
MACHINE_PATH = re.compile(r"(?<![\w.:/~-])/(?:home|Users|root|mnt|opt|srv|tmp|var|usr|etc|work)/")


def sources() -> dict[str, Path]:
    """The notebook sources in this folder.

    Returns
    -------
    dict of str to Path
        Notebook stem (``"01_quickstart"``) to its jupytext ``.py`` file, sorted.
    """
    return {p.stem: p for p in sorted(HERE.glob("[0-9][0-9]_*.py"))}


def notebook_from_source(path: Path) -> nbformat.NotebookNode:
    """Convert one jupytext percent script into an (unexecuted) notebook.

    Parameters
    ----------
    path : Path
        The ``NN_name.py`` source.

    Returns
    -------
    nbformat.NotebookNode
        A valid nbformat 4.5 notebook with deterministic cell ids ``NN-00``, ``NN-01``, ...
        and the fixed :data:`NOTEBOOK_METADATA`.
    """
    nb = jupytext.read(path, as_version=4, fmt=SOURCE_FORMAT)
    nb.nbformat, nb.nbformat_minor = 4, 5
    nb.metadata = json.loads(json.dumps(NOTEBOOK_METADATA))
    prefix = path.stem.split("_")[0]
    for i, cell in enumerate(nb.cells):
        cell.id = f"{prefix}-{i:02d}"
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    nbformat.validate(nb)
    return nb


def cell_contents(nb: nbformat.NotebookNode) -> list[tuple[str, str, list[str]]]:
    """What ``--check`` compares: the type, source and tags of every cell, in order.

    Parameters
    ----------
    nb : nbformat.NotebookNode
        Any notebook, executed or not.

    Returns
    -------
    list of (str, str, list of str)
        ``(cell_type, source, tags)`` per cell; outputs and ids are ignored.
    """
    return [(c.cell_type, c.source, list(c.get("metadata", {}).get("tags", []))) for c in nb.cells]


@contextlib.contextmanager
def private_kernel() -> Iterator[None]:
    """Make ``python3`` a kernel of this interpreter, with a clean IPython profile.

    Sets ``JUPYTER_PATH``, ``IPYTHONDIR`` and ``JUPYTER_RUNTIME_DIR`` to a temporary folder
    and unsets ``MPLBACKEND`` (so ipykernel picks its inline backend) for the duration;
    the environment is restored afterwards.

    Yields
    ------
    None
    """
    names = ("JUPYTER_PATH", "IPYTHONDIR", "JUPYTER_RUNTIME_DIR", "MPLBACKEND")
    saved = {k: os.environ.get(k) for k in names}
    with tempfile.TemporaryDirectory(prefix="hevr-kernel-") as base:
        spec_dir = Path(base, "data", "kernels", "python3")
        spec_dir.mkdir(parents=True)
        (spec_dir / "kernel.json").write_text(json.dumps({
            "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
            "display_name": "Python 3 (hevr build)",
            "language": "python",
        }))
        os.environ["JUPYTER_PATH"] = str(Path(base, "data"))
        os.environ["IPYTHONDIR"] = str(Path(base, "ipython"))
        os.environ["JUPYTER_RUNTIME_DIR"] = str(Path(base, "runtime"))
        os.environ.pop("MPLBACKEND", None)
        try:
            yield
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


def print_private_key_numbers() -> None:
    """Print, as JSON, the secret numbers of every ``hevr.PrivateKey`` alive in this process.

    Run inside the notebook's kernel by :func:`execute` (the probe); its output is read
    by the build and never written to a notebook. The numbers are *p*, *q* and
    (p-1)(q-1), in decimal.
    """
    from hevr import PrivateKey

    numbers = set()
    for obj in gc.get_objects():
        if isinstance(obj, PrivateKey):
            p, q = int(obj.p), int(obj.q)
            numbers |= {p, q, (p - 1) * (q - 1)}
    print(json.dumps(sorted(str(n) for n in numbers)))


def _output_texts(nb: nbformat.NotebookNode) -> Iterator[tuple[str, str]]:
    """(cell id, text) for every textual output; images and other binary data are skipped."""
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            if out.output_type == "stream":
                yield cell.id, out.text
            elif out.output_type == "error":
                yield cell.id, "\n".join([out.ename, out.evalue, *out.traceback])
            else:
                for mime, value in out.get("data", {}).items():
                    if mime.startswith("text/") or mime.endswith("json"):
                        yield cell.id, value if isinstance(value, str) else json.dumps(value)


def output_problems(nb: nbformat.NotebookNode, secrets: list[str] = ()) -> list[str]:
    """What must not be in a committed notebook's outputs.

    Parameters
    ----------
    nb : nbformat.NotebookNode
        An executed notebook.
    secrets : list of str
        Decimal numbers that must not appear in any form (e.g. a private key's primes);
        each is looked for in decimal and in hexadecimal.

    Returns
    -------
    list of str
        One message per problem: a path of this machine (the repository, the home
        folder, the interpreter's prefix, or an absolute path under /tmp, /home, ...), a
        run of 25+ decimal or 32+ hex digits, or one of ``secrets``. Empty if clean.
    """
    forms = {}
    for s in secrets:
        n = int(s)
        forms.update({s: "a private key number", f"{n:x}": "a private key number (hex)",
                      f"{n:X}": "a private key number (hex)"})
    paths = {str(ROOT), str(Path.home()), sys.prefix, tempfile.gettempdir() + os.sep}
    problems = []
    for cid, text in _output_texts(nb):
        for form, what in forms.items():
            if form in text:
                problems.append(f"cell {cid}: output shows {what}")
        for p in paths:
            if p and p != os.sep and p in text:
                problems.append(f"cell {cid}: output shows the path {p!r} of this machine")
        if m := MACHINE_PATH.search(text):
            problems.append(f"cell {cid}: output shows an absolute path: {text[m.start():m.end() + 30]!r}")
        for rx, what in ((LONG_DECIMAL, "decimal"), (LONG_HEX, "hex")):
            if m := rx.search(text):   # the number itself is not repeated: it may be a secret
                problems.append(f"cell {cid}: output shows a {len(m.group())}-digit {what} number "
                                f"at character {m.start()}")
    return problems


def _clean(nb: nbformat.NotebookNode) -> None:
    """Drop volatile metadata and widget views from an executed notebook, in place."""
    nb.metadata = json.loads(json.dumps(NOTEBOOK_METADATA))
    for cell in nb.cells:
        for key in VOLATILE_CELL_METADATA:
            cell.metadata.pop(key, None)
        if cell.cell_type != "code":
            continue
        outputs = []
        for out in cell.outputs:
            if "data" in out:
                out.data.pop(WIDGET_VIEW, None)   # a random model id; text/plain stays
                if not out.data:
                    continue
            outputs.append(out)
        cell.outputs = outputs


class NotebookOutputError(RuntimeError):
    """An executed notebook's outputs show a secret or a path of this machine."""


def execute(nb: nbformat.NotebookNode, timeout: int = CELL_TIMEOUT) -> nbformat.NotebookNode:
    """Execute a notebook top to bottom in a fresh private kernel and clean its outputs.

    Parameters
    ----------
    nb : nbformat.NotebookNode
        The notebook (modified in place: outputs and execution counts are filled in).
    timeout : int
        Seconds allowed per cell.

    Returns
    -------
    nbformat.NotebookNode
        ``nb``, executed, without volatile metadata.

    Raises
    ------
    nbclient.exceptions.CellExecutionError
        On the first cell that raises.
    NotebookOutputError
        If the probe finds no private key, or an output shows a private key number, a
        long number or a path of this machine.
    """
    from nbclient import NotebookClient

    probe = nbformat.v4.new_code_cell(PROBE_SOURCE)
    probe.id = "probe"
    nb.cells.append(probe)
    client = NotebookClient(nb, timeout=timeout, startup_timeout=120, kernel_name="python3",
                            allow_errors=False, record_timing=False,
                            resources={"metadata": {"path": str(HERE)}})
    # The widget state is recorded (nbclient's Output widget capture needs it) but not
    # kept: _clean resets the notebook metadata.
    try:
        with private_kernel():
            client.execute()
    finally:
        if nb.cells and nb.cells[-1].get("id") == "probe":
            nb.cells.pop()
    stdout = "".join(o.text for o in probe.outputs if o.output_type == "stream" and o.name == "stdout")
    secrets = json.loads(stdout.strip().splitlines()[-1])
    if not secrets:
        raise NotebookOutputError("the probe found no private key in the kernel: nothing to check against")
    _clean(nb)
    problems = output_problems(nb, secrets)
    if problems:
        raise NotebookOutputError("\n".join(problems))
    nbformat.validate(nb)
    return nb


def write(nb: nbformat.NotebookNode, path: Path) -> None:
    """Write a notebook as the committed JSON text (2-space indent, final newline)."""
    path.write_text(nbformat.writes(nb) + "\n", encoding="utf-8")


def check_notebook(stem: str, source: Path) -> list[str]:
    """Problems of one committed notebook against its source (nothing is executed).

    Parameters
    ----------
    stem : str
        Notebook name without extension.
    source : Path
        Its jupytext ``.py`` source.

    Returns
    -------
    list of str
        Empty if the ``.ipynb`` exists, its cells equal the source's, every code cell
        ran without error, and :func:`output_problems` finds nothing.
    """
    path = source.with_suffix(".ipynb")
    if not path.exists():
        return [f"{path.name}: missing (run python notebooks/_build.py {stem})"]
    committed = nbformat.read(path, as_version=4)
    problems = []
    if cell_contents(committed) != cell_contents(notebook_from_source(source)):
        problems.append(f"{path.name}: cells differ from {source.name} (run python notebooks/_build.py {stem})")
    for cell in committed.cells:
        if cell.cell_type != "code":
            continue
        if cell.execution_count is None:
            problems.append(f"{path.name}: cell {cell.id} was not executed")
        errors = [o for o in cell.outputs if o.output_type == "error"]
        if errors:
            problems.append(f"{path.name}: cell {cell.id} raised {errors[0].ename}")
    problems += [f"{path.name}: {p}" for p in output_problems(committed)]
    return problems


def check() -> list[str]:
    """Problems of every committed notebook (see :func:`check_notebook`), and orphans."""
    srcs = sources()
    problems = [p for stem, src in srcs.items() for p in check_notebook(stem, src)]
    for nb_path in sorted(HERE.glob("*.ipynb")):
        if nb_path.stem not in srcs:
            problems.append(f"{nb_path.name}: no {nb_path.stem}.py source")
    return problems


def build(stems: list[str]) -> None:
    """Convert, execute and write the named notebooks (all when ``stems`` is empty)."""
    srcs = sources()
    unknown = sorted(set(stems) - set(srcs))
    if unknown:
        raise SystemExit(f"no such notebook source: {', '.join(unknown)} (have {', '.join(srcs)})")
    for stem in stems or list(srcs):
        t0 = time.perf_counter()
        nb = execute(notebook_from_source(srcs[stem]))
        path = HERE / f"{stem}.ipynb"
        write(nb, path)
        images = sum("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code"
                     for o in c.outputs)
        print(f"wrote {path.relative_to(ROOT)}: {images} images, "
              f"{path.stat().st_size / 1e3:.0f} kB, executed in {time.perf_counter() - t0:.0f} s")


def main(argv: list[str] | None = None) -> int:
    """Command line: build the named notebooks (default all), or ``--check`` them."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("notebooks", nargs="*", help="stems to build, e.g. 01_quickstart (default: all)")
    parser.add_argument("--check", action="store_true",
                        help="verify the committed notebooks against their sources; execute nothing")
    args = parser.parse_args(argv)
    if args.check:
        problems = check()
        for p in problems:
            print(p, file=sys.stderr)
        return 1 if problems else 0
    build(args.notebooks)
    return 0


if __name__ == "__main__":
    sys.exit(main())
