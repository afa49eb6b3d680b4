"""The check's sequence: every step in order, each reported as it ends."""

from __future__ import annotations

from typing import Callable

from rodctl.check.results import Report, Result
from rodctl.check.steps import STEPS, Context
from rodctl.link.session import hello_settings


def run_check(session, params, label: str, user, *, say: Callable[[str], None] = print,
              report: Callable[[Result], None] = lambda r: None, flash_hint: str = "rodctl flash") -> Report:
    """Run every step against the board behind `session`, compared with the design of `params`.

    say(text): what a step is about to do; report(result): each result as it comes. The board is
    left DISARMED (the session disarms on close as always)."""
    ctx = Context(session, params, label, user, say=say, flash_hint=flash_hint)
    rep = Report(port=session.port, params=label)
    for step in STEPS:
        report(rep.add(step(ctx)))
    rep.fixes = sign_fixes(ctx)
    return rep


def sign_fixes(ctx: Context) -> dict[str, int]:
    """The wiring signs the check measured wrong: {setting name: the sign that makes it right}. Only
    what was measured unambiguously (the hand's turn fixes the encoder's sign, and only then do the
    pulses tell the motor's)."""
    now = hello_settings(ctx.session.hello)
    out = {}
    if ctx.encoder_reversed:
        out["encoder_sign"] = -int(now["encoder_sign"])
    if ctx.motor_reversed:
        out["motor_sign"] = -int(now["motor_sign"])
    return out


def store_signs(session, fixes: dict[str, int]) -> dict[str, float]:
    """SET each sign, then SAVE_RIG; returns the signs the board reports afterwards (HELLO)."""
    for name, sign in fixes.items():
        session.set(name, float(sign))
    return session.save_rig()
