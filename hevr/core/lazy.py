"""Lazy imports, in one place: a package's re-exports (PEP 562) and ``"module:attribute"`` names.

Why
---
``import hevr`` used to import every subpackage, and with them Zarr, Dask, distributed, numpy and
Pillow: half a second before any code ran, on every ``hevr`` command, ``--version`` and
``--help`` included. Most uses need a small part of that (a key file needs gmpy2 and json), so
the package and the command line name what they export and import it on first use:

* :func:`attach` gives a package a module-level ``__getattr__`` and ``__dir__`` (PEP 562) that
  import the submodule holding a public name when the name is first read, and keep the value in
  the package's namespace, so the second read is an ordinary attribute. ``__all__``, ``from hevr
  import *``, ``hevr.render``, pickling (which names a function or class by its defining module,
  never by the package), ``hevr.store.writer`` after a bare ``import hevr``, and the ``if
  TYPE_CHECKING:`` imports that static tools and IDEs read are unchanged.
* :func:`resolve` turns ``".keys:cmd_keygen"`` into the object: the command line's table of
  commands (:data:`hevr.cli.parser.COMMANDS`) names each command's argument builder and handler
  this way, so that a command's modules are imported only when that command runs.

Why not simply import inside functions: an ``import`` statement in a function body is refused
by ``tests/test_structure.py`` (except of optional dependencies), so that where a module's
dependencies come from stays visible at its top. Lazy imports are data instead — tables of names
that a test checks to resolve — and this module is the only one that imports by name (besides
:mod:`hevr.volume._optional`, for optional dependencies; the same test checks that too).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections.abc import Callable, Iterable, Mapping
from typing import Any

__all__ = ["attach", "exported", "resolve"]


def exported(table: Mapping[str, Iterable[str]]) -> dict[str, str]:
    """``{submodule: names}`` -> ``{name: submodule}``; a name listed twice is an error.

    >>> exported({".a": ("x", "y"), ".b": ("z",)})
    {'x': '.a', 'y': '.a', 'z': '.b'}
    """
    out: dict[str, str] = {}
    for module, names in table.items():
        for name in names:
            if name in out:
                raise ValueError(f"{name!r} is exported from both {out[name]!r} and {module!r}")
            out[name] = module
    return out


def attach(package: str, table: Mapping[str, Iterable[str]]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of a package whose public names live in submodules.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    table : mapping of str to iterable of str
        Submodule (relative to ``package``, e.g. ``".crypto.keys"``) -> the names it exports.

    Returns
    -------
    __getattr__, __dir__ : callable
        Assign them at the package's top level (PEP 562). ``__getattr__(name)`` imports the
        submodule, stores the attribute in the package's namespace and returns it; a submodule's
        own name (``hevr.store``, ``hevr.rendering.pipeline.kernel``) imports that submodule, which the
        eager imports of before had done; any other name raises :class:`AttributeError` as
        usual. ``__dir__()`` lists the package's namespace and every exported name.

    Notes
    -----
    A name in ``table`` should not also be a submodule of ``package``: once that submodule is
    imported, the import system binds the module under the name, and ``__getattr__`` is no
    longer asked (``hevr.volume.phantom`` is both; ``hevr.phantom`` is not).
    """
    where = exported(table)

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is not None:
            value = getattr(importlib.import_module(module, package), name)
            vars(sys.modules[package])[name] = value  # the next read is an ordinary attribute
            return value
        if not name.startswith("__") and importlib.util.find_spec(f"{package}.{name}") is not None:
            return importlib.import_module(f"{package}.{name}")  # hevr.store.writer after a bare ``import hevr``
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return __getattr__, __dir__


def resolve(ref: str, package: str | None = None) -> Any:
    """The object that ``"package.module:attribute"`` names, importing the module if needed.

    A module written ``".module"`` is relative to ``package``, as in :func:`importlib.import_module`.

    >>> resolve("hevr.paper:PAPER_SIZE"), resolve(".paper:PAPER_IMAGE", "hevr")
    (100, 150)
    >>> resolve("hevr.paper").__name__
    'hevr.paper'
    """
    module, _, attribute = ref.partition(":")
    obj = importlib.import_module(module, package)
    return getattr(obj, attribute) if attribute else obj
