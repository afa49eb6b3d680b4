"""What an identification leaves behind: the parameter file with the identified values, and the figure."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rodgains.atomic_file import replacing
from rodgains.params import CHANGED_NOTE

from rodctl.ident.fit import FIT_PARAMS, FitResult, validation_text, with_values


def written_values(res: FitResult) -> tuple[dict[str, float], dict[str, str]]:
    """(values to write, comment per parameter): identified values where they are identifiable and
    physical; the nominal value, with the reason, where not (never a silent write)."""
    values, notes = {}, {}
    for fp in FIT_PARAMS:
        if fp.name not in res.fitted:
            continue
        v, ci = res.values[fp.name], res.ci95[fp.name]
        if fp.name in res.out_of_range:
            values[fp.name] = res.nominal[fp.name]
            notes[fp.name] = f"NOT WRITTEN: fit gave {res.out_of_range[fp.name]}; kept nominal"
        elif not res.identifiable[fp.name]:
            values[fp.name] = res.nominal[fp.name]
            notes[fp.name] = f"not identifiable ({res.why[fp.name]}); kept nominal, fit gave {v:.4g}"
        else:
            values[fp.name] = v
            notes[fp.name] = f"identified {v:.4g} +- {ci:.2g} {fp.unit} (95 %)"
    return values, notes


def identified_params(params, res: FitResult):
    """params with the values parameter_file writes."""
    return with_values(params, written_values(res)[0])


def _identified_comment(line: str) -> str:
    """The default file's comment on a line identify rewrote, its source tag ([T1], "[T]: about 1.5 x ...")
    replaced: the description up to its unit stays, the source is now this rig."""
    if "#" not in line:
        return line
    value, comment = line.split("#", 1)
    comment = CHANGED_NOTE.sub("", comment, count=1)  # identify names the source itself
    unit_end = comment.find("]")
    what = comment[:unit_end + 1].rstrip() if unit_end >= 0 else comment.rstrip()
    return f"{value}#{what}   [rodctl identify]"


def written_params(params, res: FitResult, compensation=None):
    """The parameters parameter_file writes: params with the identified values and the chosen
    compensation (and shaft weight)."""
    out = identified_params(params, res)
    if compensation is not None:
        chosen = compensation.params["lqr"]
        out = out.with_overrides(f"lqr.friction_compensation={chosen['friction_compensation']!r}",
                                 f"lqr.q_shaft_angle={chosen['q_shaft_angle']!r}")
    return out


def parameter_file(params, res: FitResult, log_digests: list[tuple[str, str]], compensation=None,
                   verdict: list[str] = ()) -> str:
    """A complete parameter file: params with the identified values, each commented with its interval,
    headed by the SHA-256 of every log the values came from. compensation: the friction compensation
    chosen for the identified rig (rodctl.ident.compensation.Choice), written with what chose it;
    verdict: the lines of the verdict on the written design (rodctl.ident.verdict), in the header."""
    _, notes = written_values(res)
    text = written_params(params, res, compensation).to_toml()
    # Comments go on the lines of the keys that carry each fitted value (the scale lives in k_t and k_e).
    keys = {fp.name: ([fp.key] if fp.key else ["motor.torque_constant", "motor.back_emf_constant"]) for fp in FIT_PARAMS}
    rewritten = {k for name, ks in keys.items() if name in notes for k in ks}
    if compensation is not None:
        rewritten.add("lqr.friction_compensation")
        if compensation.best.shaft_weight is not None:
            rewritten.add("lqr.q_shaft_angle")
    lines, section = [], None
    for line in text.splitlines():
        head = line.split("#", 1)[0].strip()
        if head.startswith("[") and head.endswith("]"):
            section = head[1:-1].strip()
        elif "=" in head and section:
            key = f"{section}.{head.split('=', 1)[0].strip()}"
            if key in rewritten:
                line = _identified_comment(line)
            for name, ks in keys.items():
                if key in ks and name in notes:
                    what = notes[name] if name != "torque_constant_scale" else f"torque-constant scale: {notes[name]}"
                    line = f"{line}\n# ^ rodctl identify: {what}"
            if key == "lqr.friction_compensation" and compensation is not None:
                line += "".join(f"\n# ^ {c}" for c in compensation.comment_lines())
            if key == "lqr.q_shaft_angle" and compensation is not None and compensation.best.shaft_weight is not None:
                line += f"\n# ^ {compensation.weight_comment(params['lqr']['q_shaft_angle'])}"
        lines.append(line)
    head = ["# Identified by `rodctl identify` (output-error fit against the project's C plant).",
            f"# Validation on held-out data (theta_1): {validation_text(res.validation_fit_pct)}; "
            f"residual {res.rms_counts:.2f} encoder counts RMS.",
            "# Logs (SHA-256):"]
    head += [f"#   {digest}  {name}" for name, digest in log_digests]
    head += [f"# {line}" for line in verdict]
    return "\n".join(head + [""] + lines) + "\n"


def figure(res: FitResult, path: str | Path) -> Path:
    """Measured against simulated theta_1 for every record, and the residual in encoder counts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(res.theta_meas)
    fig, axes = plt.subplots(2, n, figsize=(max(4.2 * n, 6.4), 5.2), squeeze=False, sharex="col")  # one record: the title fits
    count = 2 * math.pi / res.counts_per_rev
    for j, (m, s, k, name) in enumerate(zip(res.theta_meas, res.theta_sim, res.split, res.record_names)):
        t = np.arange(len(m)) * res.period
        a, b = axes[0, j], axes[1, j]
        a.plot(t, np.degrees(m), lw=1.0, label="measured (encoder)")
        a.plot(t, np.degrees(s), lw=1.0, ls="--", label="simulated (identified)")
        a.axvspan(t[k] if k < len(t) else t[-1], t[-1], color="0.9", label="held out")
        a.set_title(name if len(name) <= 34 else name[:15] + "..." + name[-16:], fontsize=10)  # a long log name
        b.plot(t, (m - s) / count, lw=0.6, color="C3")
        b.axvspan(t[k] if k < len(t) else t[-1], t[-1], color="0.9")
        b.set_xlabel("time [s]")
        if j == 0:
            a.set_ylabel("theta_1 [deg]")
            b.set_ylabel("residual [counts]")
            a.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"rodctl identify: validation on held-out data: {validation_text(res.validation_fit_pct)}")
    fig.tight_layout()
    path = Path(path)
    with replacing(path) as tmp:  # whole or not at all, as the parameter file beside it
        fig.savefig(tmp, dpi=110, format=path.suffix.lstrip(".").lower() or "png")
    plt.close(fig)
    return path
