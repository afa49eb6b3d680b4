"""The scenario table of docs/scenarios.md (`rodctl sim --all --table`): a row per run of every scenario,
replaced between its markers."""

from __future__ import annotations

from pathlib import Path

from rodgains.atomic_file import atomic_write
from rodgains.errors import InputError

TABLE_BEGIN = "<!-- BEGIN scenario table: regenerate with `rodctl sim --all --figures docs/img --table docs/scenarios.md` -->"
TABLE_END = "<!-- END scenario table -->"


def table_markdown(outcomes) -> str:
    from rodctl.sim.figures import fmt
    from rodctl.sim.scenarios import SCENARIOS

    rows = ["| scenario | paper | run | plant | settle to 1 deg [s] | overshoot [deg] | peak torque [N m] | "
            "swing-up [s] | estimate error RMS [deg] | final [deg] | result |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for o in outcomes:
        s = SCENARIOS[o.name]
        if s.expect_pass is None:
            verdict = "pass" if o.passed else "fail (near the band: docs/control.md)"
        elif o.passed == s.expect_pass:
            verdict = "pass" if o.passed else "**fail** (documented below)"
        else:
            verdict = ("pass" if o.passed else "**fail**") + " (unexpected)"
        plants = {tr.label: (tr.plant or "paper's model") for tr in o.traces}
        for i, (label, m) in enumerate(o.metrics.items()):
            rows.append(f"| {o.name if i == 0 else ''} | {s.paper if i == 0 else ''} | {label} | {plants.get(label, '')} | "
                        f"{fmt(m['settle_s'])} | "
                        f"{fmt(m['overshoot_deg'], 1)} | {fmt(m['peak_torque_Nm'], 3)} | {fmt(m['swingup_s'])} | "
                        f"{fmt(m['est_rms_deg'])} | {fmt(m['final_dev_deg'])} | {verdict if i == 0 else ''} |")
    groups: dict[str, list[str]] = {}  # one line per distinct criterion (27 robust-* share one)
    for o in outcomes:
        groups.setdefault(o.criterion, []).append(f"`{o.name}`")
    crit = "\n".join(f"- {', '.join(names)}: {c}." for c, names in groups.items())
    return "\n".join(rows) + "\n\nPass criteria:\n\n" + crit + "\n"


def check_markers(readme: Path, text: str) -> None:
    """InputError unless the page's `text` holds both of the table's markers."""
    if TABLE_BEGIN not in text or TABLE_END not in text:
        raise InputError(f"{readme}: no scenario-table markers ({TABLE_BEGIN!r} ... {TABLE_END!r}) to replace")


def replace_table(readme: Path, table: str) -> None:
    text = readme.read_text() if readme.exists() else ""
    check_markers(readme, text)
    start = text.index(TABLE_BEGIN)
    end = text.index(TABLE_END) + len(TABLE_END)
    atomic_write(readme, text[:start] + f"{TABLE_BEGIN}\n{table}{TABLE_END}" + text[end:])
