"""What a check step found: PASS, FAIL or SKIP, what was measured, and the fix."""

from __future__ import annotations

import shlex
from dataclasses import asdict, dataclass, field

PASS, FAIL, SKIP = "PASS", "FAIL", "SKIP"


@dataclass
class Result:
    step: str  # identity, loop, driver, encoder, motor, heartbeat
    status: str  # PASS | FAIL | SKIP
    measured: str  # what was seen, with units
    fix: str = ""  # what to do (FAIL), or why it was skipped (SKIP)
    values: dict = field(default_factory=dict)  # the numbers behind `measured` (for --json)

    def line(self) -> str:
        """One line: status, step, what was measured, the fix."""
        text = f"{self.status} {self.step:<9} {self.measured}"
        if self.fix:
            text += f". {'Fix' if self.status == FAIL else 'Why'}: {self.fix}"
        return text


@dataclass
class Report:
    port: str
    params: str  # the parameter file the board was compared with
    results: list[Result] = field(default_factory=list)
    fixes: dict = field(default_factory=dict)  # wiring signs measured wrong: {name: the right sign}
    stored: dict = field(default_factory=dict)  # what --fix stored on the board (HELLO afterwards)

    def add(self, r: Result) -> Result:
        self.results.append(r)
        return r

    def of(self, step: str) -> Result | None:
        return next((r for r in self.results if r.step == step), None)

    @property
    def failed(self) -> list[Result]:
        return [r for r in self.results if r.status == FAIL]

    @property
    def passed(self) -> bool:
        return not self.failed

    def summary(self) -> str:
        n = {s: sum(r.status == s for r in self.results) for s in (PASS, FAIL, SKIP)}
        head = f"check: {n[PASS]} passed, {n[FAIL]} failed, {n[SKIP]} skipped"
        if n[FAIL]:
            return head + ": fix the FAIL lines above, then run `rodctl check` again"
        if n[SKIP]:
            return head + ": the skipped steps are unproven; run them with a hand at the rod (without --yes)"
        return head + f": the rig is wired right; next, `rodctl identify --port {shlex.quote(self.port)}`"

    def to_json(self) -> dict:
        return {"port": self.port, "params": self.params, "passed": self.passed,
                "results": [asdict(r) for r in self.results], "sign_fixes": self.fixes, "stored": self.stored}
