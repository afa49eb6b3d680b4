"""docs/reference/cli.md: every rodctl command and option, from the argparse parsers themselves."""

from __future__ import annotations

import argparse
import os

from rodctl.docsgen import banner

WIDTH = 100  # usage lines are wrapped at this many columns, whatever the terminal


def _escape(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _help(action: argparse.Action) -> str:
    text = action.help or ""
    if "%" in text:
        text = text % {"default": action.default, "prog": "", "metavar": action.metavar}
    return _escape(text)


def _flags(action: argparse.Action) -> str:
    if not action.option_strings:
        return f"`{action.metavar or action.dest}`"
    meta = ""
    if action.nargs != 0:
        meta = " " + (action.metavar if isinstance(action.metavar, str) else action.dest.upper())
    return ", ".join(f"`{s}{meta}`" for s in action.option_strings)


def _commands():
    from rodctl.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    return parser, [(name, helps.get(name, ""), p) for name, p in sub.choices.items()]


def page() -> str:
    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH)  # argparse wraps usage at the terminal's width
    try:
        parser, commands = _commands()
        body = ["# Command reference", "",
                "Every `rodctl` command and option, generated from the command-line parsers themselves "
                "(`rodctl COMMAND --help` prints the same). Errors are one line with a non-zero exit status: "
                "2 for bad input, 1 for a board, link or tool that failed, 3 for a design the generator "
                "refuses; `RODCTL_DEBUG=1` adds a traceback.", "",
                "| command | what it does |", "|---|---|"]
        body += [f"| [`rodctl {n}`](#rodctl-{n}) | {_escape(h or '')} |" for n, h, _ in commands]
        for name, _, p in commands:
            body += ["", f"## rodctl {name}", ""]
            if p.description:
                body += [p.description, ""]
            body += ["```", p.format_usage().strip(), "```", ""]
            rows = [a for a in p._actions if not isinstance(a, argparse._HelpAction) and a.help != argparse.SUPPRESS]
            if rows:
                body += ["| argument | meaning |", "|---|---|"]
                body += [f"| {_flags(a)} | {_help(a)} |" for a in rows]
    finally:
        if before is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = before
    text = "\n".join(body) + "\n"
    return banner("the command-line parsers (host/rodctl/cli/)", text) + text
