"""The command-line reference page, generated from the argparse parsers themselves.

Every console command of the package (``[project.scripts]``) is listed with each of its
subcommands, argument groups and flags (choices, default, help), so the page cannot drift from
what ``--help`` says.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from ddpc_codegen.cli.main import build_parser
from ddpc_codegen.testbed.vehicle_cli import build_vehicle_parser
from firmware_bridge.cli import build_bridge_parser
from firmware_bridge.proxy.cli import build_proxy_parser
from firmware_bridge.realtime import main as rtcheck_main

__all__ = ["COMMANDS", "parsers", "parser_of", "flags_of", "cli_page"]


class _Captured(Exception):
    def __init__(self, parser: argparse.ArgumentParser) -> None:
        self.parser = parser


def parser_of(main: Callable[[list[str]], Any]) -> argparse.ArgumentParser:
    """The parser a ``main(argv)`` builds, captured when it parses (nothing after that runs)."""
    original = argparse.ArgumentParser.parse_args

    def capture(self, *args, **kwargs):
        raise _Captured(self)

    argparse.ArgumentParser.parse_args = capture
    try:
        main([])
    except _Captured as c:
        return c.parser
    finally:
        argparse.ArgumentParser.parse_args = original
    raise RuntimeError(f"{main.__module__}.{main.__name__} returned without parsing its arguments")


def _codegen() -> argparse.ArgumentParser:
    return build_parser()


def _bridge() -> argparse.ArgumentParser:
    return build_bridge_parser()


def _vehicle() -> argparse.ArgumentParser:
    return build_vehicle_parser()


def _proxy() -> argparse.ArgumentParser:
    return build_proxy_parser()


def _rtcheck() -> argparse.ArgumentParser:
    return parser_of(rtcheck_main)  # builds its parser inside main


# console command -> (where it runs, its parser)
COMMANDS: dict[str, tuple[str, Callable[[], argparse.ArgumentParser]]] = {
    "ddpc-codegen": ("the workstation: simulate, import logs, fit, generate, sweep, demo", _codegen),
    "ddpc-bridge": ("the companion computer: the steering loop over MAVLink", _bridge),
    "ddpc-vehicle": ("the test bed: the simulated PX4-like vehicle endpoint", _vehicle),
    "ddpc-proxy": ("the companion computer: a transparent MAVLink proxy between your app and the vehicle", _proxy),
    "ddpc-rtcheck": ("the companion computer: can this machine hold 200 Hz?", _rtcheck),
}


def parsers() -> dict[str, argparse.ArgumentParser]:
    """Each console command's parser, built fresh."""
    return {name: build() for name, (_, build) in COMMANDS.items()}


def _subcommands(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return {name: sub for a in p._actions if isinstance(a, argparse._SubParsersAction)
            for name, sub in a.choices.items()}


def flags_of(p: argparse.ArgumentParser) -> list[str]:
    """Every option string of ``p`` (``--help`` aside), subcommands excluded."""
    return [s for a in p._actions if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))
            for s in a.option_strings]


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("<", "&lt;").replace("\n", " ")


def _code(text: Any) -> str:
    """A code span inside a table cell: only the pipe needs escaping (a code span shows ``<`` as is)."""
    return "`" + str(text).replace("|", "\\|").replace("\n", " ") + "`"


def _row(p: argparse.ArgumentParser, a: argparse.Action) -> str:
    name = ", ".join(_code(s) for s in a.option_strings) or _code(a.metavar or a.dest)
    if a.choices is not None:
        value = " \\| ".join(_code(c) for c in a.choices)
    elif a.nargs == 0:
        value = "flag"
    else:
        value = _code(a.metavar or a.dest.upper())
    default = "" if a.default in (None, False, argparse.SUPPRESS) or a.nargs == 0 else _code(a.default)
    helptext = p._get_formatter()._expand_help(a) if a.help else ""
    return f"| {name} | {value} | {default} | {_cell(helptext)} |"


def _parser_md(p: argparse.ArgumentParser, title: str, level: int) -> list[str]:
    out = [f"{'#' * level} `{title}`\n"]
    if p.description:
        out.append(_cell(p.description) + "\n")
    out.append("```\n" + p.format_usage().strip() + "\n```\n")
    for group in p._action_groups:
        acts = [a for a in group._group_actions
                if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]
        if not acts:
            continue
        out += [f"**{group.title}**\n", "| argument | value | default | what |", "|---|---|---|---|"]
        out += [_row(p, a) for a in acts] + [""]
    for name, sub in _subcommands(p).items():
        out += _parser_md(sub, f"{title} {name}", level + 1)
    return out


def cli_page() -> str:
    """The command-line reference (Markdown) of every console command."""
    out = ["# Command line\n", "<!-- generated from the argparse parsers while the docs build -->\n",
           "Generated from the parsers themselves while the docs build: what `--help` prints, as tables.\n"]
    for name, (where, build) in COMMANDS.items():
        out += [f"## {name}\n", f"Runs on {where}.\n"] + _parser_md(build(), name, 3)
    return "\n".join(out)
