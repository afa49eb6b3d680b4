"""docs/reference/sil-abi.md: the firmware core's C ABI as a host shared library, from rod_sil.h."""

from __future__ import annotations

import re
from pathlib import Path

from rodctl.docsgen import banner


def _clean_comment(text: str) -> str:
    lines = [ln.strip().lstrip("*").strip() for ln in text.strip().removeprefix("/*").removesuffix("*/").splitlines()]
    return " ".join(ln for ln in lines if ln)


def entries(header_text: str) -> list[tuple[str, str, list[tuple[str, str]]]]:
    """[(group title, its description, [(declaration, what it does)])] in the header's order: a group
    starts at a `/* ---- title ---- */` comment (text after the dashes describes it); a function's text is the comment before it and the one after it on
    its line."""
    groups: list[tuple[str, str, list[tuple[str, str]]]] = []
    pending = ""
    tokens = re.finditer(r"(/\*.*?\*/)|^ROD_SIL_API\s+(.*?;)[ \t]*(/\*.*?\*/)?", header_text, re.S | re.M)
    started = False
    for m in tokens:
        comment, decl, trailing = m.group(1), m.group(2), m.group(3)
        if comment is not None:
            title = re.match(r"/\*\s*-{3,}\s*(.*?)\s*-{3,}(.*)\*/", comment, re.S)
            if title:
                started = True
                about = _clean_comment("/*" + title.group(2) + "*/") if title.group(2).strip() else ""
                groups.append((title.group(1), about, []))
                pending = ""
            elif started:
                pending = _clean_comment(comment)
            continue
        if not groups:
            continue
        text = " ".join(t for t in (pending, _clean_comment(trailing) if trailing else "") if t)
        groups[-1][2].append((" ".join(decl.split()), text))
        pending = ""
    return groups


def page(header: Path) -> str:
    src = header.read_text()
    intro = [ln.strip().lstrip("*").rstrip() for ln in src.split("*/", 1)[0].removeprefix("/*").splitlines()]
    body = ["# SIL C ABI", "",
            "The firmware core built as a host shared library (`rodctl sil-lib [--params F] [-o PATH]`): the same "
            "`firmware/src/core` sources the Teensy runs, plus `firmware/sil/rod_sil.c`, for any simulator "
            "(MATLAB, Julia, your own). Generated from `firmware/sil/rod_sil.h`.", "",
            "```", *[ln.strip() for ln in intro if ln.strip()], "```", ""]
    for title, about, decls in entries(src):
        body += [f"## {title[0].upper() + title[1:]}", ""] + ([about, ""] if about else [])
        body += ["| function | what it does |", "|---|---|"]
        body += [f"| `{d}` | {t.replace('|', chr(92) + '|')} |" for d, t in decls]
        body.append("")
    text = "\n".join(body)
    return banner("firmware/sil/rod_sil.h", src) + text
