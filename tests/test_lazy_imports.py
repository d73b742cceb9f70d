"""The lazy re-exports of ``hevr`` and ``hevr.rendering`` (:mod:`hevr.core.lazy`): they behave as the
eager imports of before, and their tables say what their ``if TYPE_CHECKING:`` imports say.

What the command line imports at start-up is checked in ``tests/cli/test_startup.py``.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

import hevr
from hevr.core.lazy import exported

PACKAGES = (
    "hevr",
    "hevr.rendering",
    "hevr.rendering.geometry",
    "hevr.rendering.planning",
    "hevr.rendering.pipeline",
    "hevr.rendering.reference",
)


def _type_checking_imports(package: str) -> dict[str, str]:
    """name -> relative module of the ``from .x import name`` lines under ``if TYPE_CHECKING:``."""
    tree = ast.parse(Path(importlib.import_module(package).__file__).read_text(encoding="utf-8"))
    out: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for imp in node.body:
                assert isinstance(imp, ast.ImportFrom), ast.unparse(imp)
                out.update({a.asname or a.name: "." * imp.level + (imp.module or "") for a in imp.names})
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_the_lazy_table_is_what_static_tools_see(package):
    pkg = importlib.import_module(package)
    table = exported(pkg._LAZY)
    assert table == _type_checking_imports(package)
    assert set(table) == set(pkg.__all__)
    for name, module in table.items():  # each name is the defining module's object
        assert getattr(pkg, name) is getattr(importlib.import_module(module, package), name), name
        assert importlib.util.find_spec(f"{package}.{name}") is None, f"{package}.{name} is a submodule too"


def test_dir_lists_every_public_name():
    assert set(hevr.__all__) <= set(dir(hevr))


def test_unknown_names_are_attribute_errors():
    assert not hasattr(hevr, "no_such_name")
    with pytest.raises(AttributeError, match="'hevr' has no attribute 'no_such_name'"):
        hevr.no_such_name  # noqa: B018
    assert not hasattr(hevr.rendering, "__no_such_dunder__")


FRESH = """\
import pickle, sys
import hevr
assert "hevr.volume" not in sys.modules and "zarr" not in sys.modules
f = hevr.phantom                      # the function, though hevr.volume.phantom is a module
assert callable(f) and f.__module__ == "hevr.volume.phantom", f
import hevr.volume.phantom
assert hevr.phantom is f and "phantom" in vars(hevr)
assert hevr.store.writer.encrypt_volume is hevr.encrypt_volume   # submodules after a bare `import hevr`
assert hevr.rendering.encrypted.render is hevr.render
assert pickle.loads(pickle.dumps(hevr.render)) is hevr.render     # by its defining module
assert b"hevr.rendering.encrypted" in pickle.dumps(hevr.render)
assert pickle.loads(pickle.dumps(hevr.PublicKey)) is hevr.PublicKey
ns = {}
exec("from hevr import *", ns)
assert set(hevr.__all__) <= set(ns)
print("ok")
"""


def test_a_fresh_interpreter_sees_the_eager_behaviour(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", FRESH], cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-3000:]


def test_the_image_package_re_exports_its_modules_names():
    """``hevr.image`` is a package of one-concept modules; its lazy table re-exports the names
    the one-module ``hevr.image`` of before had, each the defining module's object."""
    import hevr.image as image

    table = exported(image._LAZY)
    assert table == _type_checking_imports("hevr.image")
    assert set(image.__all__) <= set(table)
    assert {"_CORRUPT", "_unpack_checked", "_from_blob", "MAGIC", "image_from_bytes"} <= set(table)
    for name, module in table.items():
        assert getattr(image, name) is getattr(importlib.import_module(module, "hevr.image"), name), name
        assert importlib.util.find_spec(f"hevr.image.{name}") is None, f"hevr.image.{name} is a submodule too"
    assert hevr.EncryptedImage is image.EncryptedImage and hevr.load_image is image.load_image
    ns: dict = {}
    exec("from hevr.image import *", ns)
    assert set(image.__all__) <= set(ns)
