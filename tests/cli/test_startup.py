"""Start-up of the command line (issue 29, item 8): what a command imports before it works.

Checked by the modules a fresh interpreter holds after the command, never by a time (the
times are in ``benchmarks/startup.py``): ``import hevr``, ``hevr --version`` and ``hevr --help``
import none of the data path's dependencies (not even numpy); ``hevr info KEY`` imports the key
code (gmpy2, numpy) but no Zarr, Dask or distributed. And the table of commands behind the lazy
parser (:data:`hevr.cli.parser.COMMANDS`) names real functions, each building the same
subparser alone as in the whole parser.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hevr.cli.parser import COMMANDS, build_parser
from hevr.core.lazy import resolve

# The data path's dependencies: half a second of imports together.
HEAVY = ("zarr", "numcodecs", "dask", "distributed", "fsspec", "PIL", "tifffile", "pydicom", "nibabel", "scipy")
# hevr's own heavy subpackages (each imports some of HEAVY).
HEAVY_HEVR = (
    "hevr.volume",
    "hevr.store",
    "hevr.image",
    "hevr.rendering.encrypted",
    "hevr.runtime.scheduler",
    "hevr.backends",
)
NOTHING = HEAVY + HEAVY_HEVR + ("numpy", "gmpy2", "hevr.crypto")

PROBE = """\
import json, sys
argv = json.loads(sys.argv[1])
code = None
if argv is None:
    import hevr
else:
    from hevr.cli.main import main
    code = main(argv)
print("PROBE" + json.dumps({"code": code, "modules": sorted(sys.modules)}), file=sys.stderr)
"""


def _probe(argv: list[str] | None, cwd) -> tuple[int | None, str, set[str]]:
    """Run ``hevr ARGV`` (or ``import hevr`` for None) in a fresh interpreter: exit code,
    stdout, and the names of the modules it left imported."""
    out = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(argv)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    line = next((x for x in out.stderr.splitlines() if x.startswith("PROBE")), None)
    assert line is not None, out.stderr[-3000:]
    doc = json.loads(line[len("PROBE") :])
    return doc["code"], out.stdout, set(doc["modules"])


def _imported(modules: set[str], names) -> list[str]:
    """Which of ``names`` (packages: any of their submodules too) are among ``modules``."""
    return sorted(n for n in names if any(m == n or m.startswith(n + ".") for m in modules))


@pytest.fixture(scope="module")
def keys(tmp_path_factory, keypair256):
    d = tmp_path_factory.mktemp("startup")
    pub, priv = keypair256
    priv.save(d / "key.json")
    pub.save(d / "key.pub.json")
    priv.save(d / "phe.json", format="phe")
    return d


@pytest.mark.parametrize(
    "argv, shows",
    [
        (None, ""),
        (["--version"], "hevr "),
        (["--help"], "usage: hevr"),
    ],
)
def test_import_version_and_help_import_nothing_heavy(tmp_path, argv, shows):
    code, out, modules = _probe(argv, tmp_path)
    assert code in (None, 0) and shows in out
    assert not _imported(modules, NOTHING), f"{argv or 'import hevr'} imported {_imported(modules, NOTHING)}"


@pytest.mark.parametrize(
    "name, fmt", [("key.json", "hevr"), ("key.pub.json", "hevr"), ("phe.json", "python-paillier (pheutil)")]
)
def test_info_of_a_key_imports_no_data_path(keys, name, fmt):
    code, out, modules = _probe(["info", name], keys)
    assert code == 0 and "fingerprint:" in out and f"format:      {fmt}" in out
    assert not _imported(modules, HEAVY + HEAVY_HEVR), _imported(modules, HEAVY + HEAVY_HEVR)


def test_help_of_the_light_commands_imports_no_data_path(tmp_path):
    for name in ("keygen", "convert-key", "info", "upgrade-store", "bench"):
        code, out, modules = _probe([name, "--help"], tmp_path)
        assert code == 0 and out.startswith(f"usage: hevr {name}")
        assert not _imported(modules, HEAVY + HEAVY_HEVR), (name, _imported(modules, HEAVY + HEAVY_HEVR))


def test_render_help_imports_no_zarr(tmp_path):
    code, out, modules = _probe(["render", "--help"], tmp_path)
    assert code == 0 and out.startswith("usage: hevr render")
    heavy = ("zarr", "distributed", "fsspec", "hevr.store", "hevr.rendering.encrypted")
    assert not _imported(modules, heavy), _imported(modules, heavy)


def test_a_command_imports_its_modules_when_it_runs(tmp_path):
    """The other side: the handler's modules do get imported (here keygen's key generation)."""
    code, _, modules = _probe(["keygen", "--bits", "256", "--out", "k.json", "-q"], tmp_path)
    assert code == 0 and (tmp_path / "k.pub.json").is_file()
    assert {"hevr.cli.keys", "hevr.crypto.keys"} <= modules and not _imported(modules, ("zarr", "distributed"))


# -- the table behind the lazy parser ----------------------------------------------------------


def test_every_command_names_real_functions():
    names = [c.name for c in COMMANDS]
    assert len(set(names)) == len(names)
    sub = next(a for a in build_parser(())._actions if a.dest == "command")
    assert list(sub.choices) == names  # hevr --help lists every command, in the table's order
    for c in COMMANDS:
        assert callable(resolve(c.arguments, "hevr.cli")), c
        assert callable(resolve(c.handler, "hevr.cli")), c


def _subparser(parser, name: str):
    return next(a for a in parser._actions if a.dest == "command").choices[name]


@pytest.mark.parametrize("name", [c.name for c in COMMANDS])
def test_a_command_built_alone_is_the_command_of_the_whole_parser(name):
    """main() builds only the command it runs: that subparser is the one of the full parser."""
    alone, full = _subparser(build_parser({name}), name), _subparser(build_parser(), name)
    assert alone.format_help() == full.format_help()
    assert [a.option_strings or a.dest for a in alone._actions] == [a.option_strings or a.dest for a in full._actions]
    others = [c.name for c in COMMANDS if c.name != name]
    assert all(not _subparser(build_parser({name}), o)._actions[1:] for o in others)  # only -h: not built
