"""``{hevr-cli}``: the reference of the ``hevr`` command line, generated at build time from the
argument parser itself (:func:`hevr.cli.parser.build_parser`), so the page cannot drift from it.

For ``hevr`` and every command (and a command's own actions, ``hevr known list``...): the
one-line help, the usage line, the description, the options (grouped as ``--help`` groups them,
with their help texts, defaults expanded) and the examples of the epilog.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator

from docutils import nodes
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

WIDTH = "100"  # argparse's usage lines wrap at $COLUMNS


def _paragraphs(text: str) -> list[nodes.Node]:
    """``text`` (a RawDescriptionHelpFormatter description or epilog, whose layout is kept):
    blocks of plain lines become paragraphs, a block with indented lines (examples) a literal
    block, its heading line (``examples:``) a paragraph of its own."""
    out: list[nodes.Node] = []
    for block in text.strip("\n").split("\n\n"):
        lines = block.rstrip().splitlines()
        if not lines:
            continue
        if any(line.startswith((" ", "\t")) for line in lines):
            head = []
            while lines and not lines[0].startswith((" ", "\t")):
                head.append(lines.pop(0))
            if head:
                out.append(nodes.paragraph(text=" ".join(head)))
            code = "\n".join(lines)
            out.append(nodes.literal_block(code, code, language="text"))
        else:
            out.append(nodes.paragraph(text=" ".join(line.strip() for line in lines)))
    return out


def _invocation(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    return parser._get_formatter()._format_action_invocation(action)  # noqa: SLF001 - argparse's own words


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if not action.help:
        return ""
    return " ".join(parser._get_formatter()._expand_help(action).split())  # noqa: SLF001


def section_id(prog: str) -> str:
    """The anchor of a command's section: ``hevr known list`` -> ``cli-hevr-known-list``."""
    return nodes.make_id("cli-" + prog)


def _option_list(parser: argparse.ArgumentParser, actions: list[argparse.Action]) -> nodes.Node:
    """A definition list: each option's invocation (``--out FRAME.hevr``) and help; a command
    (sub-parser) links to its own section."""
    dl = nodes.definition_list(classes=["hevr-cli-options"])
    for action in actions:
        if action.help == argparse.SUPPRESS:
            continue
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for choice in action._choices_actions:  # noqa: SLF001 - each sub-command's help line
                item = nodes.definition_list_item()
                term = nodes.term()
                ref = nodes.reference("", "", internal=True, refid=section_id(f"{parser.prog} {choice.dest}"))
                ref += nodes.literal(text=choice.dest)
                term += ref
                item += term
                item += nodes.definition("", nodes.paragraph(text=choice.help or ""))
                dl += item
            continue
        item = nodes.definition_list_item()
        term = nodes.term()
        term += nodes.literal(text=_invocation(parser, action))
        item += term
        item += nodes.definition("", nodes.paragraph(text=_help(parser, action)))
        dl += item
    return dl


def _subcommands(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser, str]]:
    for action in parser._actions:  # noqa: SLF001
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            helps = {c.dest: c.help or "" for c in action._choices_actions}  # noqa: SLF001
            for name, sub in action.choices.items():
                yield name, sub, helps.get(name, "")


class HevrCli(SphinxDirective):
    """``{hevr-cli}``: no argument; the whole command line."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from hevr.cli import parser as cli_parser

        self.env.note_dependency(cli_parser.__file__)
        old = os.environ.get("COLUMNS")
        os.environ["COLUMNS"] = WIDTH
        try:
            parser = cli_parser.build_parser()
            return self._section(parser, "hevr", "", top=True)[0].children[1:]
        finally:
            if old is None:
                os.environ.pop("COLUMNS", None)
            else:
                os.environ["COLUMNS"] = old

    def _section(self, parser: argparse.ArgumentParser, prog: str, oneline: str, top: bool = False) -> list[nodes.Node]:
        sid = section_id(prog)
        section = nodes.section(ids=[sid], names=[nodes.fully_normalize_name(prog)])
        title = nodes.title()
        title += nodes.literal(text=prog)
        section += title
        self.state.document.note_implicit_target(section, section)
        if oneline:
            section += nodes.paragraph(text=oneline[:1].upper() + oneline[1:] + ".")
        usage = parser.format_usage().strip()
        usage = usage[len("usage: ") :] if usage.startswith("usage: ") else usage
        section += nodes.literal_block(usage, usage, language="text", classes=["hevr-cli-usage"])
        if parser.description:
            section.extend(_paragraphs(parser.description))
        for group in parser._action_groups:  # noqa: SLF001 - the groups --help prints
            actions = [a for a in group._group_actions if a.help != argparse.SUPPRESS]  # noqa: SLF001
            if not actions:
                continue
            commands = all(isinstance(a, argparse._SubParsersAction) for a in actions)  # noqa: SLF001
            rubric = nodes.rubric(text="Commands" if commands else (group.title or "options").capitalize())
            section += rubric
            if group.description:
                section += nodes.paragraph(text=" ".join(group.description.split()))
            section += _option_list(parser, actions)
        if parser.epilog:
            section += nodes.rubric(text="Examples" if not top else "Notes")
            section.extend(_paragraphs(parser.epilog))
        subs = list(_subcommands(parser))
        for name, sub, helpline in subs:
            section.extend(self._section(sub, f"{prog} {name}", helpline))
        return [section]


def setup(app: Sphinx) -> dict:
    app.add_directive("hevr-cli", HevrCli)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
