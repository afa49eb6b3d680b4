"""Who does what a step needs a hand for: a person at the rig, nobody (--yes), or the virtual hand."""

from __future__ import annotations

import sys


class Person:
    """A person at the rig, asked on the terminal."""

    has_hand = True
    no_hand = "nobody pressed Enter (the input ended): run the check from a terminal at the rod"

    def __init__(self, stdin=None, out=None):
        self.stdin = stdin or sys.stdin
        self.out = out or sys.stderr

    def do(self, instruction: str, session) -> bool:
        """The instruction was shown; True once the person presses Enter, False when nobody can (end of input)."""
        print("  press Enter, then do it", file=self.out, flush=True)
        return self.stdin.readline() != ""


class Nobody:
    """--yes: no questions; a step that needs a hand is skipped."""

    has_hand = False
    no_hand = "--yes asks nobody: run the check without --yes at the rod and press Enter"

    def do(self, instruction: str, session) -> bool:
        return False


class VirtualHand:
    """sim://: the virtual board's own hand turns the rod (rodctl.sim.device.VirtualDevice.hand_turn)."""

    has_hand = True
    no_hand = ""  # it always turns the rod
    TURN_S = 2.0  # out and back [s]

    def __init__(self, device):
        self.device = device

    def do(self, instruction: str, session) -> bool:
        self.device.hand_turn(90.0, self.TURN_S)
        return True


def user_for(session, yes: bool):
    """The virtual hand on a sim:// board that has one; otherwise a person, or nobody with --yes."""
    dev = getattr(session.ser, "device", None)
    if dev is not None and getattr(getattr(dev, "faults", None), "hand", False):
        return VirtualHand(dev)
    return Nobody() if yes else Person()
