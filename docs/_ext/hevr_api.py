"""autodoc for ``hevr``'s lazily re-exported names: a constant's ``#:`` documentation comment is
read from the submodule that defines it (``hevr._LAZY`` names it), not from ``hevr/__init__.py``,
where autodoc would look; the class members autodoc lists are the documented ones only."""

from __future__ import annotations

from typing import Any

from sphinx.application import Sphinx
from sphinx.pycode import ModuleAnalyzer


def _submodule(name: str) -> str | None:
    import hevr

    for module, names in getattr(hevr, "_LAZY", {}).items():
        if name in names:
            return "hevr" + module if module.startswith(".") else module
    return None


def _data_docs(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    if what != "data" or not name.startswith("hevr.") or name.count(".") != 1:
        return
    short = name.split(".", 1)[1]
    inherited = (type(obj).__doc__ or "").strip().splitlines()
    if inherited and [line.strip() for line in lines[: len(inherited)]] == [line.strip() for line in inherited]:
        lines.clear()  # the docstring of the value's type (dict, tuple): not this constant's
    module = _submodule(short)
    if module is None:
        return
    try:
        docs = ModuleAnalyzer.for_module(module).find_attr_docs()
    except Exception:  # noqa: BLE001 - no source: nothing to add
        return
    found = docs.get(("", short))
    if found:
        lines[:] = [*found, *lines]


def setup(app: Sphinx) -> dict:
    app.connect("autodoc-process-docstring", _data_docs, priority=100)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
