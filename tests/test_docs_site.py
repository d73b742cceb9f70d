"""The documentation site (docs/, built by Sphinx: docs/conf.py) cannot drift from the code.

* every name of ``hevr.__all__`` is documented in the API reference (docs/reference/api.rst);
* every ``hevr ...`` command in a console or shell block of the site's pages and of the README
  parses with the command's own parser (:func:`hevr.cli.parser.build_parser`): a renamed or removed
  option fails here, naming the page and line;
* every Python example written as a doctest (``>>>`` in a fenced block) on the site runs and
  prints what the page says; every other Python block parses, and every ``hevr.NAME`` in a Python
  block (README too) is a public name;
* every page of the root toctree exists.

Building the site itself (warnings as errors) is .ci/run's step; ``test_the_site_builds`` (slow)
does the same into a temporary folder when Sphinx is installed (``pip install -e '.[docs]'``).
"""

from __future__ import annotations

import ast
import doctest
import io
import pkgutil
import re
import shlex
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

import hevr
from hevr.cli.parser import build_parser, join_negative_values, value_options

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GENERATED = ("_build", "_generated")


def _pages() -> list[Path]:
    """The site's Markdown pages (not the build's output)."""
    return sorted(p for p in DOCS.rglob("*.md") if not set(p.relative_to(DOCS).parts) & set(GENERATED))


FENCE = re.compile(r"^(?P<indent> *)(?P<fence>`{3,}|~{3,})\s*(?P<info>[^\n`]*)$")


def fenced_blocks(text: str) -> list[tuple[str, int, list[str]]]:
    """(info string, line number of the first content line, content lines) of every fenced code
    block of a Markdown text.

    >>> fenced_blocks("a\\n```console\\n$ hevr --help\\n```\\n")
    [('console', 3, ['$ hevr --help'])]
    """
    out = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, info, start = m["fence"], m["info"].strip(), i + 1
        j = start
        while j < len(lines) and not (
            lines[j].strip().startswith(fence[0] * len(fence)) and lines[j].strip().strip(fence[0]) == ""
        ):
            j += 1
        out.append((info, start + 1, lines[start:j]))
        i = j + 1
    return out


SHELL = {"console", "bash", "sh", "shell", "shell-session", "zsh"}
OPERATORS = {"|", "||", "&&", ";", "&", ">", ">>", "<", "2>", "2>&1", "&>", "1>"}


def hevr_commands(lines: list[str], start: int, console: bool) -> list[tuple[int, list[str]]]:
    """(line number, argv after ``hevr``) of every ``hevr`` command of a shell block: a line of it
    (``$ `` prompted in a console block; there an unprompted line is output), continuation lines
    joined, each command of a ``&&``/``|``/``;`` chain, ``hevr`` or a path ending in ``/hevr``;
    a variable the block sets (``S3="--storage-option ..."``) expanded as the shell would.

    >>> hevr_commands(["$ hevr render v.zarr --out f.hevr \\\\", "    --size 8x8  # small", "out"], 1, True)
    [(1, ['render', 'v.zarr', '--out', 'f.hevr', '--size', '8x8'])]
    >>> hevr_commands(["pip install . && .venv/bin/hevr demo --out d | tail -1"], 5, False)
    [(5, ['demo', '--out', 'd'])]
    >>> hevr_commands(['Q="-q --force"', "hevr demo $Q --out ${OUT}"], 1, False)
    [(2, ['demo', '-q', '--force', '--out', '${OUT}'])]
    """
    out = []
    env: dict[str, str] = {}
    i = 0
    while i < len(lines):
        number, line = start + i, lines[i]
        i += 1
        text = line.strip()
        if console:
            if not text.startswith("$ "):
                continue
            text = text[2:]
        while text.endswith("\\") and i < len(lines):
            text = text[:-1] + " " + lines[i].strip().removeprefix("> ")
            i += 1
        try:
            words = shlex.split(text, comments=True)
        except ValueError:
            words = text.split()
        settings = words[1:] if words[:1] == ["export"] else words
        if settings and all(ASSIGNMENT.fullmatch(w) for w in settings):
            env.update(w.split("=", 1) for w in settings)
            continue
        command: list[str] = []
        for word in [*words, ";"]:
            if word in OPERATORS or re.fullmatch(r"\d?>>?\S*", word):
                if command:
                    argv = _after_hevr(command)
                    if argv is not None:
                        out.append((number, _expand(argv, env)))
                command = []
                if word not in {"|", "||", "&&", ";", "&"}:
                    command = ["<redirect>"]  # the rest until the next operator is not a command
            elif command != ["<redirect>"] or word in OPERATORS:
                command.append(word)
    return out


ASSIGNMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*=.*")


def _expand(argv: list[str], env: dict[str, str]) -> list[str]:
    """``$NAME`` and ``${NAME}`` words of variables the block set, split as the shell splits them."""
    out: list[str] = []
    for word in argv:
        m = re.fullmatch(r"\$(?:\{(\w+)\}|(\w+))", word)
        name = m and (m[1] or m[2])
        out += shlex.split(env[name]) if name in env else [word]
    return out


def _after_hevr(words: list[str]) -> list[str] | None:
    """The arguments of a command whose program is hevr (after ``VAR=value`` settings)."""
    k = 0
    while k < len(words) and ASSIGNMENT.fullmatch(words[k]):
        k += 1
    if k < len(words) and (words[k] == "hevr" or words[k].endswith("/hevr")):
        return _unbracket(words[k + 1 :])
    if words[k : k + 3] in (["python", "-m", "hevr"], ["python3", "-m", "hevr"]) or (
        len(words) > k + 2 and words[k].endswith("/python") and words[k + 1 : k + 3] == ["-m", "hevr"]
    ):
        return _unbracket(words[k + 3 :])
    return None


def _unbracket(argv: list[str]) -> list[str]:
    """A usage's optional part, ``[--cafile ca.pem]``, taken: the option is checked too.

    >>> _unbracket(["render", "[--cafile", "ca.pem]", "[-q]"])
    ['render', '--cafile', 'ca.pem', '-q']
    """
    return [
        w[1:] if w.startswith("[") and not w.startswith("[[") else w
        for w in (w[:-1] if w.endswith("]") and not w.endswith("]]") and "[" not in w[1:] else w for w in argv)
    ]


def _documented_commands() -> list[tuple[str, int, list[str]]]:
    found = []
    for page in [*_pages(), ROOT / "README.md"]:
        text = page.read_text(encoding="utf-8")
        for info, start, lines in fenced_blocks(text):
            lang = info.split()[0].lower() if info else ""
            if lang not in SHELL:
                continue
            for number, argv in hevr_commands(lines, start, console=lang in {"console", "shell-session"}):
                found.append((str(page.relative_to(ROOT)), number, argv))
    return found


COMMANDS = _documented_commands()


def test_the_pages_show_commands():
    """The collection above finds what the pages show (a broken fence parser would pass vacuously)."""
    assert len(COMMANDS) >= 10, COMMANDS
    assert {argv[0] for _, _, argv in COMMANDS if argv} >= {"keygen", "encrypt", "render", "decrypt"}


@pytest.mark.parametrize(("page", "line", "argv"), COMMANDS, ids=[f"{p}:{n}" for p, n, _ in COMMANDS])
def test_every_documented_command_parses(page, line, argv):
    """``hevr ARGS`` as the page writes it is accepted by ``hevr``'s parser (placeholders such as
    ``KEY.json`` are values like any other; ``--help`` exits 0)."""
    parser = build_parser()
    argv = join_negative_values(argv, value_options(parser))
    err = io.StringIO()
    try:
        with redirect_stderr(err), redirect_stdout(io.StringIO()):
            parser.parse_args(argv)
    except SystemExit as exc:
        if exc.code not in (0, None):
            pytest.fail(f"{page}:{line}: `hevr {shlex.join(argv)}` does not parse: {err.getvalue().strip()}")


def test_every_public_name_is_in_the_api_reference():
    text = (DOCS / "reference" / "api.rst").read_text(encoding="utf-8")
    documented = set(re.findall(r"^\.\. auto(?:function|class|exception|data)::\s+(\S+)", text, re.M))
    assert set(hevr.__all__) - documented == set(), "add these to docs/reference/api.rst"
    assert documented - set(hevr.__all__) == set(), "no longer public: remove from docs/reference/api.rst"


def _doctest_pages() -> list[Path]:
    return [p for p in _pages() if ">>>" in p.read_text(encoding="utf-8")]


@pytest.mark.filterwarnings("ignore::hevr.errors.InsecureKeyWarning")  # the pages' small demo keys
@pytest.mark.parametrize("page", _doctest_pages(), ids=lambda p: str(p.relative_to(DOCS)))
def test_the_pages_doctests_run(page, tmp_path, monkeypatch):
    """Each page's ``>>>`` examples, block after block in one namespace, in a scratch folder."""
    monkeypatch.chdir(tmp_path)
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    globs: dict = {"__name__": "__docs__"}
    report = io.StringIO()
    name = str(page.relative_to(ROOT))
    ran = 0
    for _info, start, lines in fenced_blocks(page.read_text(encoding="utf-8")):
        if not any(line.lstrip().startswith(">>>") for line in lines):
            continue
        test = parser.get_doctest("\n".join(lines) + "\n", globs, name, str(page), start - 1)
        runner.run(test, out=report.write, clear_globs=False)
        globs = test.globs  # DocTest copies its namespace: the next block goes on from this one
        ran += len(test.examples)
    results = runner.summarize(verbose=False)
    assert ran > 0
    assert results.failed == 0, report.getvalue()


def _python_blocks() -> list[tuple[str, int, list[str]]]:
    found = []
    for page in [*_pages(), ROOT / "README.md"]:
        for info, start, lines in fenced_blocks(page.read_text(encoding="utf-8")):
            if info.split()[:1] in (["python"], ["py"], ["pycon"]):
                found.append((str(page.relative_to(ROOT)), start, lines))
    return found


def test_the_pages_python_sketches_are_python():
    """A Python block that is not a doctest (a sketch that needs a cluster, a server or a scan) is
    not run, but it is Python: it parses."""
    sketches = [(p, n, lines) for p, n, lines in _python_blocks() if not any(">>>" in line for line in lines)]
    bad = []
    for page, start, lines in sketches:
        try:
            ast.parse("\n".join(lines))
        except SyntaxError as exc:
            bad.append(f"{page}:{start + (exc.lineno or 1) - 1}: {exc.msg}")
    assert bad == []


def test_the_pages_python_names_are_public():
    """Every ``hevr.NAME`` a Python block of the pages or the README uses is a public name (or a
    subpackage): a renamed or removed name fails here, naming the page and line."""
    known = set(hevr.__all__) | {m.name for m in pkgutil.iter_modules(hevr.__path__)} | {"__version__"}
    unknown = [
        f"{page}:{start + i}: hevr.{name}"
        for page, start, lines in _python_blocks()
        for i, line in enumerate(lines)
        for name in re.findall(r"(?<![\w.])hevr\.([A-Za-z_]\w*)", line)
        if name not in known
    ]
    assert len(_python_blocks()) > 10 and unknown == []


def test_every_toctree_page_exists():
    """The root toctree's entries are pages (the prose pages included)."""
    index = (DOCS / "index.md").read_text(encoding="utf-8")
    entries = []
    for info, _, lines in fenced_blocks(index):
        if info.startswith("{toctree}"):
            entries += [line.strip() for line in lines if line.strip() and not line.lstrip().startswith(":")]
    assert "reference/api" in entries and "benchmarks" in entries
    missing = [e for e in entries if not any((DOCS / (e + s)).exists() for s in (".md", ".rst"))]
    assert missing == []


@pytest.mark.slow
def test_the_site_builds(tmp_path):
    """The whole site, warnings as errors (what .ci/run does; the test extra installs Sphinx)."""
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-W",
            "--keep-going",
            "-q",
            "-b",
            "html",
            "-d",
            str(tmp_path / "doctrees"),
            str(DOCS),
            str(tmp_path / "html"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-5000:]
    for page in (
        "index.html",
        "reference/api.html",
        "reference/cli.html",
        "reference/protocol.html",
        "benchmarks.html",
    ):
        assert (tmp_path / "html" / page).stat().st_size > 0, page
