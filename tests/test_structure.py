"""Structural checks that keep the package layout true (standard library only: ast, pathlib).

* no import cycle among hevr modules;
* no module longer than MAX_LINES;
* no import statement inside a function body, except of an optional dependency; and no import
  by name (importlib, ``__import__``) outside the modules in LAZY_IMPORTERS;
* no docstring or comment in hevr/ pointing to a file outside the repository;
* the module paths from before the crypto/volume/store/rendering/cli layout, and from before
  the rendering rooms (geometry, planning, pipeline, reference), appear only in CHANGELOG.md;
* ``hevr/rendering`` keeps its entry points on its floor and everything else in its rooms;
* ``hevr.__all__`` is the public contract, and every name in it imports.

Each failure lists every offender (module, line, function or cycle), not just the first.
"""

from __future__ import annotations

import ast
import io
import re
import subprocess
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "hevr"
THIS = Path(__file__).resolve()

MAX_LINES = 450

# Imports that may stay inside a function body: optional dependencies (extras, notebook and
# GPU packages) and modules whose import is slow and needed on one path only.
OPTIONAL_IMPORTS = frozenset(
    {
        "phe",
        "matplotlib",
        "nibabel",
        "pydicom",
        "fsspec",
        "cupy",
        "bokeh",
        "ipywidgets",
        "anywidget",
        "traitlets",
        "IPython",
        "nbformat",
        "nbclient",
        "jupytext",
        "tqdm",
        "starlette",  # hevr serve's extra
        "uvicorn",
    }
)  # optional extras only: required dependencies (distributed, pillow, zarr, ...) are imported at the top

# The only modules that import by name (importlib, __import__), and why. Everything else imports at
# its top; a lazy import is an entry in one of hevr.core.lazy's tables (hevr.__init__'s re-exports, the
# CLI's table of commands), not a call hidden in a function body.
LAZY_IMPORTERS = {
    "hevr.core.lazy": "PEP 562 re-exports and the CLI's 'module:function' table: start-up time (issue 29)",
    "hevr.volume._optional": "optional dependencies (nibabel, pydicom, ...) named in one message",
}

# Module paths that no longer exist since the layout change (see CHANGELOG.md): the flat
# modules hevr/<name>.py. Packages with one of these names exist now (store, volume, cli), so
# for them only the file form and attributes the new package does not have are old.
OLD_MODULES = (
    "_paillier",
    "_primes",
    "_owner",
    "keys",
    "keyfile",
    "encoding",
    "number",
    "_mpzbytes",
    "io",
    "_nrrd",
    "density",
    "_volmeta",
    "camera",
    "modes",
    "sampling",
    "weights",
    "planner",
    "kernel",
    "mapreduce",
    "_finish",
    "renderer",
    "plain",
)
OLD_FUNCTION_MODULES = ("phantom",)  # hevr.phantom( is the public function; hevr.phantom.x was the module
NOW_PACKAGES = ("store", "volume", "cli")
OLD_NAMES_ALLOWED_IN = frozenset({"CHANGELOG.md"})

# hevr/rendering's rooms (issue 39): each holds these modules, and its __init__ names them in the
# order the data flows. The floor keeps the entry points only; hevr.rendering.<module> of a
# module now in a room is an old path (see CHANGELOG.md).
RENDERING_ROOMS = {
    "geometry": (
        "coordinates",
        "camera",
        "views",
        "plane",
        "plane_grid",
        "rays",
        "footprint",
        "weights",
        "group_weights",
    ),
    "planning": ("modes", "request", "planner", "bounds"),
    "pipeline": ("kernel", "_segments", "maps", "graph", "reduce", "finishing", "sums", "sums_file", "cache", "stream"),
    "reference": ("plain",),
    "packed": (
        "request",
        "shear",
        "plan",
        "graph",
        "image",
        "sliced",
        "planes",
        "plane_image",
        "verified",
        "files",
        "colour",
        "colour_render",
    ),
}
RENDERING_FLOOR = ("__init__", "encrypted", "slices", "view", "verify", "verification", "tag_betas")

# The public names, as in hevr/__init__.py when the layout changed. A change here is a change
# of the public contract (docs/api-contract.md): make it on purpose.
PUBLIC_API = (
    "generate_keypair",
    "PublicKey",
    "PrivateKey",
    "load_key",
    "EncryptedNumber",
    "encrypt_volume",
    "phantom",
    "sample_scan",
    "Camera",
    "render_plain",
    "render",
    "render_frame",
    "Frame",
    "Colouring",
    "RaySums",
    "clear_cache",
    "recolour",
    "load_sums",
    "SavedSums",
    "Viewer",
    "Plane",
    "render_slice",
    "render_slice_plain",
    "build_pyramid",
    "EncryptedImage",
    "load_image",
    "save_png",
    "to_uint8",
    "error_bound",
    "encode_density",
    "normalize_density",
    "PHANTOM_LEVELS",
    "load_volume",
    "read_scan",
    "Scan",
    "save_volume",
    "open_volume",
    "EncryptedVolume",
    "upgrade_store",
    "encode",
    "decode",
    "BASE",
    "HevrError",
    "ParameterError",
    "InvalidKeyError",
    "KeyMismatchError",
    "PlaintextOverflowError",
    "RenderPlanError",
    "StoreError",
    "StoreExistsError",
    "IncompleteStoreError",
    "CorruptStoreError",
    "CorruptVolumeError",
    "IntegrityError",
    "VerificationError",
    "VolumeFormatError",
    "MissingDependencyError",
    "MissingFileError",
    "MemoryLimitError",
    "ExistingFileError",
    "NotRegularFileError",
    "FileSystemError",
    "InsecureKeyWarning",
    "KeyFilePermissionWarning",
    "connect",
    "RemoteError",  # hevr serve's key holder (issue 37)
    "RemoteTimeoutError",
    "RemoteConnectError",
    "RemoteBusyError",
    "RemoteUnauthorisedError",  # typed remote
    "RemoteNotFoundError",
    "RemoteRefusedError",
    "RemoteAnswerError",  # failures (issue 48)
    "known_stores",
    "trust_store",  # the key holder's known stores (issue 38)
    "export_known_stores",
    "import_known_stores",  # portable, MAC'd known stores (issue 47)
    "own_cluster",
    "ForeignClusterError",  # the Dask path only on the key holder's own cluster (issue 47)
    "Expect",
    "FrameProof",
    "proof_of",
    "FrameMovedWarning",  # what a verified frame proves (issue 47)
    "VIEWS",
    "MODALITY_RANGES",
    "TF_PRESETS",
    "modality_range",
    "range_hint",
    "tf_preset",
    "window_density",
    "PackedImage",  # a packed store's frame (issue 45)
)
API_MD = ROOT / "docs" / "api-contract.md"  # the public contract, shipped with the repository

# Text in a docstring or comment that points outside the repository.
OUTSIDE_PATTERNS = (
    (re.compile(r"(?<!\.)\.\./"), "a path relative to a parent folder ('../')"),
    (re.compile(r"(?<![\w.])shared/"), "the workspace's shared/ folder"),
    (re.compile(r"/work/"), "an absolute workspace path"),
    (re.compile(r"(?<![\w.:/~-])/(?:home|Users|root|mnt|opt|srv|tmp|var|usr|etc)/"), "an absolute path"),
    (re.compile(r"(?<![\w])~/"), "a path in someone's home folder"),
    (re.compile(r"\b[A-Za-z]:\\\\"), "a Windows drive path"),
)


# -- the package's modules and their imports ---------------------------------------------------


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES: dict[str, Path] = {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}
PACKAGES = {name for name, p in MODULES.items() if p.name == "__init__.py"}


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST):
    """Every Import / ImportFrom node, skipping ``if TYPE_CHECKING:`` bodies (not their else)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
            continue
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))


def _resolve_from(module: str, node: ast.ImportFrom) -> str | None:
    """The absolute module a ``from X import ...`` reads from (None when it leaves the package)."""
    if node.level == 0:
        return node.module
    base = module.split(".") if module in PACKAGES else module.split(".")[:-1]
    if node.level - 1 > len(base):
        return None
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _edges(module: str, tree: ast.AST) -> dict[str, int]:
    """hevr modules ``module`` imports -> first line. ``from pkg import name`` goes to
    ``pkg.name`` when that is a submodule, else to ``pkg``. Importing ``a.b.c`` first runs
    the ``__init__`` of the packages ``a.b`` on the way, so those are edges too — except the
    packages ``module`` itself lives in, which are already (being) imported when it runs."""
    out: dict[str, int] = {}
    own = {".".join(module.split(".")[:i]) for i in range(1, module.count(".") + 2)}

    def add(target: str, line: int) -> None:
        parts = target.split(".")
        for i in range(1, len(parts)):
            parent = ".".join(parts[:i])
            if parent in PACKAGES and parent not in own:
                out.setdefault(parent, line)
        if target in MODULES and target != module:
            out.setdefault(target, line)

    for node in _imports(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name, node.lineno)
        else:
            src = _resolve_from(module, node)
            if src is None:
                continue
            for alias in node.names:
                sub = f"{src}.{alias.name}"
                add(sub if sub in MODULES else src, node.lineno)
    return out


GRAPH: dict[str, dict[str, int]] = {m: _edges(m, _parse(p)) for m, p in MODULES.items()}


def _strongly_connected(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Tarjan's algorithm (iterative): the components with more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    comps: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        comps.append(sorted(comp))
    return comps


def _one_cycle(graph: dict[str, dict[str, int]], comp: list[str]) -> list[str]:
    """A shortest cycle through the first module of a strongly connected component."""
    members = set(comp)
    start = comp[0]
    prev: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v]):
                if w not in members:
                    continue
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(prev[path[-1]])
                    return [start] + path[::-1][1:] + [start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return comp  # pragma: no cover - a component always has a cycle


def _describe_cycle(cycle: list[str]) -> str:
    steps = [cycle[0]]
    for a, b in zip(cycle, cycle[1:]):
        steps.append(f"-> {b} ({_rel(MODULES[a])}:{GRAPH[a][b]})")
    return " ".join(steps)


# -- the checks ----------------------------------------------------------------------------------


def test_the_scan_sees_the_package():
    """Guard for the checks below: they look at the real modules and real edges."""
    assert {"hevr", "hevr.crypto.keys", "hevr.rendering.pipeline.kernel", "hevr.store.reader"} <= set(MODULES)
    assert "hevr.crypto.records" in GRAPH["hevr.store.reader"]  # from ..crypto.records import ...
    assert "hevr.store.metadata" in GRAPH["hevr.store.reader"]  # from .metadata import ...
    assert "hevr.errors" in GRAPH["hevr.store.reader"]  # from ..errors import ...
    tree = ast.parse(
        "from . import records\nfrom .. import errors, __version__\nimport hevr.crypto.keys\n"
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..image import EncryptedImage\n"
    )
    assert _edges("hevr.crypto.paillier", tree) == {
        "hevr.crypto.records": 1,
        "hevr.errors": 2,
        "hevr": 2,
        "hevr.crypto.keys": 3,
    }
    assert _strongly_connected({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [["a", "b", "c"]]


def test_no_import_cycle():
    cycles = [_describe_cycle(_one_cycle(GRAPH, comp)) for comp in _strongly_connected(GRAPH)]
    assert not cycles, "import cycles among hevr modules:\n" + "\n".join(cycles)


def test_no_module_is_too_long():
    long = [
        f"{_rel(p)}: {n} lines"
        for p in MODULES.values()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    ]
    assert not long, f"modules over {MAX_LINES} lines:\n" + "\n".join(sorted(long))


class _FunctionImports(ast.NodeVisitor):
    def __init__(self) -> None:
        self.scope: list[str] = []
        self.found: list[tuple[int, str, str]] = []

    def _scoped(self, node, is_function: bool) -> None:
        self.scope.append(node.name + ("()" if is_function else ""))
        self.generic_visit(node)
        self.scope.pop()

    def visit_ClassDef(self, node: ast.ClassDef) -> None:
        self._scoped(node, False)

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        self._scoped(node, True)

    visit_AsyncFunctionDef = visit_FunctionDef

    def _check(self, node, tops: list[str]) -> None:
        if any(s.endswith("()") for s in self.scope) and not all(t in OPTIONAL_IMPORTS for t in tops):
            self.found.append((node.lineno, ".".join(self.scope), ast.unparse(node)))

    def visit_Import(self, node: ast.Import) -> None:
        self._check(node, [a.name.split(".")[0] for a in node.names])

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        self._check(node, ["." if node.level else (node.module or "").split(".")[0]])


def test_no_import_inside_functions_except_optional_dependencies():
    found = []
    for path in MODULES.values():
        v = _FunctionImports()
        v.visit(_parse(path))
        found += [f"{_rel(path)}:{line} in {where}: {stmt}" for line, where, stmt in v.found]
    assert not found, (
        "imports inside function bodies (move them to the top of the module, or add the package to "
        "OPTIONAL_IMPORTS if it is an optional dependency):\n" + "\n".join(found)
    )


def _imports_by_name(tree: ast.AST):
    """(line, text) of every import by name: ``import importlib``, ``from importlib import …``,
    ``__import__(…)``."""
    for node in ast.walk(tree):
        by_name = (
            (isinstance(node, ast.Import) and any(a.name.split(".")[0] == "importlib" for a in node.names))
            or (
                isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] == "importlib"
            )
            or (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "__import__")
        )
        if by_name:
            yield node.lineno, ast.unparse(node)


def test_imports_by_name_only_in_the_lazy_modules():
    """Importing by name would get round the rule above; it has one home (LAZY_IMPORTERS)."""
    assert set(LAZY_IMPORTERS) <= set(MODULES), f"LAZY_IMPORTERS names no module: {set(LAZY_IMPORTERS) - set(MODULES)}"
    seen = ast.parse(
        "import importlib.util\nfrom importlib import import_module\nm = __import__('os')\nfrom . import x"
    )
    assert [line for line, _ in _imports_by_name(seen)] == [1, 2, 3]  # guard: the scan sees all three forms
    found = [
        f"{_rel(path)}:{line}: {text}"
        for name, path in MODULES.items()
        if name not in LAZY_IMPORTERS
        for line, text in _imports_by_name(_parse(path))
    ]
    assert not found, (
        "imports by name outside LAZY_IMPORTERS (import at the top of the module, or name the "
        "object in one of hevr.core.lazy's tables):\n" + "\n".join(found)
    )


def _docstrings_and_comments(path: Path):
    """(line, text) of every docstring and comment of one module."""
    text = path.read_text(encoding="utf-8")
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (
                body
                and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)
            ):
                yield body[0].lineno, body[0].value.value
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string


def test_outside_path_patterns():
    """Guard for the check below: what it flags and what it lets through."""

    def flags(s):
        return [why for rx, why in OUTSIDE_PATTERNS if rx.search(s)]

    for bad in (
        "see ../shared/API.md",
        "the data in /work/shared/data",
        "from /home/me/vol.raw",
        "shared/API.md",
        "~/keys/key.json",
        "C:\\\\data",
    ):
        assert flags(bad), bad
    for ok in (
        "docs/format.md",
        "hevr/store/writer.py",
        "https://github.com/x/y",
        "10/3",
        "n/3",
        "0o600",
        "Σ_k/(n·K)",
        "dask.distributed",
        "[0, 1]/255",
        "a.shared/b",
        "found nothing at .../missing.json",
    ):
        assert not flags(ok), ok


def test_no_docstring_or_comment_points_outside_the_repository():
    found = []
    for path in MODULES.values():
        for line, text in _docstrings_and_comments(path):
            for i, row in enumerate(text.splitlines()):
                for rx, why in OUTSIDE_PATTERNS:
                    if rx.search(row):
                        found.append(f"{_rel(path)}:{line + i}: {why}: {row.strip()}")
    assert not found, "docstrings/comments pointing outside the repository:\n" + "\n".join(found)


# -- old module paths ---------------------------------------------------------------------------


def _package_names(pkg: str) -> set[str]:
    """What ``hevr.<pkg>.<name>`` can be now: submodules and names bound in the package __init__."""
    if not (PKG / pkg / "__init__.py").is_file():
        return set()
    names = {
        p.stem if p.name != "__init__.py" else p.parent.name
        for p in (PKG / pkg).iterdir()
        if p.suffix == ".py" or (p / "__init__.py").exists()
    }
    for node in _parse(PKG / pkg / "__init__.py").body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                names |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
    return names


def _old_path_patterns() -> list[tuple[re.Pattern, str]]:
    alt = "|".join(re.escape(m) for m in OLD_MODULES)
    pats = [
        (re.compile(rf"\bhevr\.(?:{alt})\b"), "old module"),
        (re.compile(rf"\bhevr/(?:{alt}|phantom|store|volume|cli)\.py\b"), "old file"),
        (re.compile(r"\bhevr[./]_cli_\w+"), "old CLI module"),
    ]
    moved = "|".join(re.escape(m) for room in RENDERING_ROOMS.values() for m in room)
    pats += [
        (re.compile(rf"(?<![\w])rendering[./](?:{moved})(?![\w/])"), "old rendering module (now in a room)"),
        (
            re.compile(rf"\bfrom\s+(?:hevr|\.+)\.?rendering\s+import\s+\(?\s*(?:{moved})\b"),
            "old rendering module (now in a room)",
        ),
    ]
    for m in OLD_FUNCTION_MODULES:
        pats.append(
            (
                re.compile(rf"\bhevr\.{m}\.(?=[A-Za-z_])|\bfrom\s+hevr\.{m}\s+import\b|\bimport\s+hevr\.{m}\b"),
                f"old module hevr.{m} (the function hevr.{m}() is fine)",
            )
        )
    for pkg in NOW_PACKAGES:
        known = _package_names(pkg)
        unknown = rf"(?!(?:{'|'.join(sorted(map(re.escape, known)))})\b)\w+" if known else r"\w+"
        pats.append(
            (
                re.compile(rf"\bhevr\.{pkg}\.{unknown}|\bfrom\s+hevr\.{pkg}\s+import\s+\(?\s*{unknown}"),
                f"name the package hevr.{pkg} does not have (old module hevr/{pkg}.py)",
            )
        )
    return pats


def test_old_path_patterns():
    """Guard for the check below: old forms are caught, the new layout is not."""
    pats = _old_path_patterns()

    def hits(s):
        return [why for rx, why in pats if rx.search(s)]

    for old in (
        "from hevr.keys import PublicKey",
        "import hevr.mapreduce",
        "hevr._paillier.raw_encrypt",
        "hevr/renderer.py",
        "hevr/store.py",
        "hevr/volume.py",
        "hevr/cli.py",
        "hevr._cli_demo",
        "hevr/_cli_sheet.py",
        "hevr.phantom.PHANTOM_LEVELS",
        "from hevr.phantom import phantom",
        "monkeypatch.setattr('hevr.store._encrypt_brick', f)",
        "from hevr.cli import build_parser",
        "hevr.volume.EncryptedVolume",
        "hevr.io.load_volume",
        "hevr.number.encode",
        "`hevr.kernel`",
        "hevr.modes.make_spec",
        "hevr.rendering.camera",
        "from ..rendering.plain import x",
        "hevr/rendering/maps.py",
        "from hevr.rendering import maps",
        "hevr.rendering._segments.to_host",
        "from .rendering.stream import render_frame",
        "patch('hevr.rendering.kernel.plan_products')",
    ):
        assert hits(old), old
    for new in (
        "hevr.phantom(100)",
        "hevr.phantom",
        "see hevr.phantom.",
        "hevr.crypto.keys",
        "hevr/crypto/keys.py",
        "hevr.store.writer",
        "hevr.store.reader.open_volume",
        "from hevr.store import writer",
        "hevr.store.open_volume",
        "hevr/store/reader.py",
        "hevr.volume.phantom.PHANTOM_LEVELS",
        "hevr.volume.density",
        "hevr.cli.main",
        "from hevr.cli.main import main",
        "hevr.render(ev, cam)",
        "hevr.Camera.orbit",
        "hevr.rendering.pipeline.kernel",
        "hevr.render_plain",
        "hevr.kernel_micro",
        "hevr.bench.kernel_micro",
        "hevr.encode(x)",
        "hevr.iodine",
        "hevr.errors",
        "hevr.rendering.geometry.camera",
        "hevr/rendering/pipeline/maps.py",
        "from hevr.rendering import Plane",
        "from hevr.rendering.pipeline import maps",
        "tests/rendering/test_camera.py",
        "rendering.plainly",
        "from .rendering.reference.plain import render_plain",
        "hevr.rendering.encrypted",
    ):
        assert not hits(new), new


def _text_files() -> list[Path]:
    """Tracked and untracked-but-not-ignored files (git), or every file outside build folders."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-co", "--exclude-standard", "-z"],
            cwd=ROOT,
            capture_output=True,
            check=True,
            timeout=60,
        ).stdout
        files = [ROOT / f for f in out.decode().split("\0") if f]
    except (OSError, subprocess.SubprocessError):
        skip = {".git", ".venv", "venv", "build", "dist", "__pycache__", ".pytest_cache", ".hypothesis"}
        files = [
            p
            for p in ROOT.rglob("*")
            if not (set(p.relative_to(ROOT).parts) & skip) and not any(part.endswith(".egg-info") for part in p.parts)
        ]
    return [f for f in files if f.is_file() and f.resolve() != THIS]


def test_old_module_paths_only_in_changelog():
    pats = _old_path_patterns()
    found = []
    for f in _text_files():
        if f.relative_to(ROOT).as_posix() in OLD_NAMES_ALLOWED_IN:
            continue
        blob = f.read_bytes()
        if b"\0" in blob[:8192]:
            continue
        try:
            text = blob.decode("utf-8")
        except UnicodeDecodeError:
            continue
        for i, line in enumerate(text.splitlines(), 1):
            for rx, why in pats:
                for m in rx.finditer(line):
                    found.append(f"{_rel(f)}:{i}: {m.group(0)!r} ({why})")
    assert not found, "old module paths outside CHANGELOG.md:\n" + "\n".join(found)


def test_changelog_exists_and_names_the_move():
    changelog = ROOT / "CHANGELOG.md"
    assert changelog.is_file(), "CHANGELOG.md is missing (it should record the old -> new module paths)"
    text = changelog.read_text(encoding="utf-8")
    for pkg in ("crypto", "volume", "store", "rendering", "cli"):
        assert f"hevr/{pkg}/" in text or f"hevr.{pkg}" in text, f"CHANGELOG.md does not mention hevr.{pkg}"


def test_the_rendering_rooms():
    """hevr/rendering is a floor of entry points and five rooms that follow the data path."""
    rendering = PKG / "rendering"
    floor = sorted(p.stem for p in rendering.glob("*.py"))
    assert floor == sorted(RENDERING_FLOOR), (
        f"modules on hevr/rendering's floor: {floor}, expected {sorted(RENDERING_FLOOR)}"
    )
    rooms = sorted(p.name for p in rendering.iterdir() if p.is_dir() and (p / "__init__.py").is_file())
    assert rooms == sorted(RENDERING_ROOMS), f"rooms of hevr/rendering: {rooms}, expected {sorted(RENDERING_ROOMS)}"
    wrong = []
    for room, modules in RENDERING_ROOMS.items():
        held = sorted(p.stem for p in (rendering / room).glob("*.py") if p.name != "__init__.py")
        if held != sorted(modules):
            wrong.append(f"hevr/rendering/{room}/ holds {held}, expected {sorted(modules)}")
        doc = ast.get_docstring(_parse(rendering / room / "__init__.py")) or ""
        at = [doc.find(f"``{m}``") for m in modules]
        if -1 in at or at != sorted(at):
            wrong.append(f"hevr/rendering/{room}/__init__.py's docstring does not name {list(modules)} in this order")
    assert not wrong, "\n".join(wrong)


# -- the public API ----------------------------------------------------------------------------


def test_all_names_import_from_hevr():
    import hevr

    missing = [name for name in hevr.__all__ if not hasattr(hevr, name)]
    assert not missing, f"in hevr.__all__ but not importable from hevr: {missing}"
    namespace: dict = {}
    exec("from hevr import *", namespace)
    assert set(hevr.__all__) <= set(namespace)
    dup = sorted({n for n in hevr.__all__ if hevr.__all__.count(n) > 1})
    assert not dup, f"listed twice in hevr.__all__: {dup}"


def test_all_is_the_public_contract():
    import hevr

    added = sorted(set(hevr.__all__) - set(PUBLIC_API))
    removed = sorted(set(PUBLIC_API) - set(hevr.__all__))
    assert not added and not removed, f"hevr.__all__ changed: added {added}, removed {removed}"


def test_names_used_in_api_md_are_public():
    """API.md does not list __all__ as a block; every ``hevr.<name>`` it uses must be in it."""
    import hevr

    used = set(re.findall(r"\bhevr\.([A-Za-z_]\w*)", API_MD.read_text(encoding="utf-8")))
    assert used, "API.md mentions no hevr.<name>"
    assert used <= set(hevr.__all__), f"API.md uses names hevr.__all__ lacks: {sorted(used - set(hevr.__all__))}"


# -- the test tree -----------------------------------------------------------------------------


def test_test_module_basenames_are_unique():
    """tests/ has no __init__.py files, so pytest's default (prepend) import mode imports each
    test module by its basename: two tests/**/test_x.py would collide."""
    tests = ROOT / "tests"
    if any(tests.rglob("__init__.py")):
        pytest.skip("the test folders are packages: basenames may repeat")
    seen: dict[str, list[str]] = {}
    for p in sorted(tests.rglob("test_*.py")):
        seen.setdefault(p.name, []).append(_rel(p))
    dup = {name: paths for name, paths in seen.items() if len(paths) > 1}
    assert not dup, f"test module basenames used twice: {dup}"


# -- the house: hevr's floor and rooms (issue 49) ----------------------------------------------------

# hevr/'s floor: the package's entry, the command's entry, and the farm-level modules every layer
# and every user reads (the errors, colour on the client, the paper's settings). Everything else is in
# a room named for its concept (core/, runtime/ and the data path's subpackages).
FLOOR = ("__init__", "__main__", "colour", "errors", "paper")


def test_the_floor_holds_no_private_module():
    floor = sorted(p.stem for p in PKG.glob("*.py"))
    assert floor == sorted(FLOOR), f"modules on hevr/'s floor: {floor}, expected {sorted(FLOOR)}"
    private_rooms = sorted(
        p.name for p in PKG.iterdir() if p.is_dir() and p.name.startswith("_") and p.name != "__pycache__"
    )
    assert not private_rooms, f"private subpackages on hevr/'s floor: {private_rooms}"


def test_mypys_strict_modules_are_the_public_modules():
    """pyproject.toml's strict mypy override names exactly the modules hevr/__init__.py re-exports from."""
    import tomllib

    import hevr

    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    strict = [o for o in config["tool"]["mypy"]["overrides"] if o.get("disallow_untyped_defs")]
    assert len(strict) == 1, "expected one strict override in [tool.mypy]"
    listed = set(strict[0]["module"])
    public = {"hevr"} | {"hevr" + m for m in hevr._LAZY}
    public = {"hevr.viewer.widget" if m == "hevr.viewer" else m for m in public}
    assert listed == public, f"strict list: missing {sorted(public - listed)}, extra {sorted(listed - public)}"
