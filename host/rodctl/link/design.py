"""The design a board runs: which parameter file its firmware's gains came from, and SETs checked against it.

    params, source = design_params(session, args)   # (None, "unknown") when no candidate matches
    apply_settings(session, ["swing_amplitude=0.03"], args, out=say)
"""

from __future__ import annotations

from typing import Callable

from rodctl.link.session import Session, parse_assignment


def design_flags(args) -> list[str]:
    """The --params and --set words that name the design the user gave (unquoted), for a command to suggest."""
    return ((["--params", args.params] if getattr(args, "params", None) else [])
            + [w for o in getattr(args, "overrides", None) or () for w in ("--set", o)])


def given_design(args) -> str | None:
    """How the user named a design with --params / --set, or None when they named none."""
    if args is None or not (getattr(args, "params", None) or getattr(args, "overrides", None)):
        return None
    label = args.params or "defaults"
    if args.overrides:
        label += " with " + " ".join(f"--set {o}" for o in args.overrides)
    return label


def design_mismatch(session: Session, args, source: str) -> str | None:
    """A warning when --params / --set named a design the board does not run (design_params found `source`), else
    None: the run goes on with the board's own design, which a user arming with --params believed was theirs."""
    given = given_design(args)
    if given is None or source == given:
        return None
    import shlex

    header = bytes(session.hello.header_sha256).hex()[:12]
    runs = f"is the design of {source}" if source != "unknown" else "matches no parameter file this command knows"
    return (f"the board does not run the design of {given}: its header {header} {runs}, and that design runs "
            f"(the log names it); to run yours: rodctl flash {shlex.join(design_flags(args))}")


def design_params(session: Session, args=None):
    """(Params, source) the firmware's gains came from, matched by the HELLO's header hash."""
    from rodctl.logs.metadata import identify_params
    from rodctl.paths import shown

    cands = []
    label = given_design(args)
    if label is not None:
        from rodgains.params import load_params

        cands.append((load_params(args.params, args.overrides), label))
    dev = getattr(session.ser, "device", None)  # sim://: the virtual board knows its parameters
    if dev is not None and getattr(dev, "params", None) is not None:
        from rodgains.params import DEFAULT_PARAMS

        over = "".join(f" --set {o}" for o in getattr(dev, "overrides", ()))
        cands.append((dev.params, f"{shown(dev.params_path or DEFAULT_PARAMS)}{over} (sim://)"))
    return identify_params(bytes(session.hello.header_sha256).hex(), cands)


def apply_settings(s: Session, assignments: list[str], args=None, *, out: Callable[[str], None],
                   kept: bool = False) -> None:
    """SET every NAME=VALUE (all or none) and say to `out` what the board reports; `kept`: a SAVE_RIG follows,
    so the rig settings are not said to last only until the board resets."""
    parsed = [parse_assignment(a) for a in assignments]  # all names and numbers checked before anything is sent
    names = [setting.name for setting, _ in parsed]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:  # which value would the user mean? the board would keep the last, and both were printed as it
        from rodgains.errors import InputError

        raise InputError(f"{', '.join(twice)} given more than once; give each setting once")
    params, _ = design_params(s, args)  # for the catch angle's range (the balance angle limit)
    now = s.set_all(parsed, design_params=params)  # every value range-checked, then all applied or none
    for setting, value in parsed:
        lasts = "" if kept and setting.hello_field == "rig" else " (until the board resets)"
        out(f"{setting.name} = {setting.format(now[setting.name])}{lasts}")
