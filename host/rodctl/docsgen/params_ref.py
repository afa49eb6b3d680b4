"""docs/reference/params.md: every parameter key with its unit, the values it accepts, the range a
testbed's value falls in, its default and what it means, from the schema and default.toml."""

from __future__ import annotations

import re

from rodctl.docsgen import banner


def _comments(toml_text: str) -> dict[str, str]:
    """{section.key: the comment on its line in default.toml} (the description and its source tag)."""
    out, section = {}, None
    for line in toml_text.splitlines():
        head, _, comment = line.partition("#")
        head = head.strip()
        m = re.fullmatch(r"\[([a-z_]+)\]", head)
        if m:
            section = m.group(1)
        elif "=" in head and section:
            out[f"{section}.{head.split('=', 1)[0].strip()}"] = " ".join(comment.split())
    return out


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return f"{v:g}" if isinstance(v, float) else str(v)


def page() -> str:
    from rodgains.params import DEFAULT_PARAMS, PLAUSIBLE, SCHEMA, allowed_text, load_params

    toml_text = DEFAULT_PARAMS.read_text()
    notes = _comments(toml_text)
    defaults = load_params()
    body = ["# Parameter reference", "",
            "Every key of a parameter file, generated from the parameter schema (`gains/rodgains/params.py`) "
            "and the default file (`gains/rodgains/default.toml`, the rod of Table I on the testbed's motor). "
            "Values are SI unless the key ends in `_deg` or `_hz`. Start your own file with "
            "`rodctl params --out my_rod.toml`; override one value anywhere with `--set section.key=value`.", "",
            "- **accepts**: a value outside it is refused, one line, exit 2.",
            "- **plausible**: the range a testbed's value falls in; a value outside it is refused with the unit "
            "it was probably typed in (\"155 m: did you mean 0.155 m?\").",
            "- **optional**: the key may be left out of a file (files written before it existed); its default "
            "then applies, or the value named \"if left out\" where that differs. Every other key is required.",
            "- Source tags in the notes: \\[T1\\] Table I of the paper, \\[P\\] its text, \\[PN\\] the "
            "[physics notes](../physics-notes.md), \\[V\\] vendor data, \\[E\\] an estimate to measure, \\[S\\] chosen in "
            "simulation, \\[T\\] chosen by `rodctl tune`.", ""]
    for section, keys in SCHEMA.items():
        body += [f"## [{section}]", "", "| key | default | unit | accepts | plausible | note |", "|---|---|---|---|---|---|"]
        for key, spec in keys.items():
            name = f"{section}.{key}"
            plaus = PLAUSIBLE.get(name)
            plaus_text = f"{plaus[0]:g} to {plaus[1]:g}" if plaus else ""
            optional = ""
            if spec.default is not None:
                left_out = "" if spec.default == defaults[section][key] else f", {_value(spec.default)} if left out"
                optional = f" (optional{left_out})"
            note = notes.get(name, "").replace("|", "\\|").replace("[", "\\[")  # [T1]: a tag, not a link
            body.append(f"| `{key}`{optional} | {_value(defaults[section][key])} | {spec.unit} | {allowed_text(spec)} | "
                        f"{plaus_text} | {note} |")
        body.append("")
    text = "\n".join(body)
    return banner("gains/rodgains/params.py and gains/rodgains/default.toml", text + toml_text) + text
