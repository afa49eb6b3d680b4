"""The verdict at the end of `rodctl identify`: does the design written for the identified rig do its
job on that rig, and what to try if not.

    from rodctl.ident.verdict import judge
    v = judge(params_written, cases="matrix")   # the matrix on the identified rig's faithful plant
    print("\\n".join(v.lines("my_rod.toml")))     # READY / NOT READY, the figures, what to try next

A fit can be excellent and the design still miss its goals on the rig it describes: an
identification is only done when the written file has been judged on it. The judgement is the one
`rodctl robustness --params FILE` makes: the firmware designed from the written file, run on the
file's own faithful plant (its identified gearbox play and encoder zero included), with the same
pass rules. READY means both nominal goals met (balance within 1 deg by 1.5 s, swing-up caught
and within 1 deg 2 s later) and at least MIN_PASS_SHARE of the in-range runs passed (the cases that
are not a documented known failure and leave the rod short of its buckling length).
"""

from __future__ import annotations

from dataclasses import dataclass

from rodgains.params import Params

# The gearbox play above which the play, not the weights, is the first thing to name when a nominal
# goal is missed: at 0.5 deg the default rod already ends 2 to 3 deg off upright (docs/control.md) [deg].
PLAY_FIRST_DEG = 0.3
# A rod this near its clamped buckling length (and short of it), without the tip IMU, is told about the IMU:
# there the encoder barely sees the slow bend, and the IMU with a design for the rod holds what base-only cannot
# (docs/sensors.md: rig B at 0.983 x, 20 of 78 runs base-only, 51 with the IMU; E -15 % at 0.994 x held; both
# past 1 x once the IMU's own mass is on them) [-].
NEAR_BUCKLING = 0.97


@dataclass(frozen=True)
class Verdict:
    cases: str  # the matrix case set judged
    passed: int
    runs: int
    in_range_passed: int
    in_range_runs: int
    nominal: dict  # task -> the nominal run's row (settle_s, final_dev_deg, passed, ...)
    buckling_ratio: float  # the rod above the hub over its clamped buckling length [-]
    play_deg: float  # the identified gearbox play between the encoder and the rod (Params.encoder_play_deg) [deg]
    tip_imu: bool  # the design reads the tip IMU (sensors.tip_imu)
    failed: tuple[str, ...]  # "case/task" of every in-range run that failed
    straightest_deg: float = 0.0  # the rod's straightest static shape's largest deviation (curved at rest) [deg]

    @property
    def nominal_met(self) -> bool:
        return bool(self.nominal) and all(r.get("passed") for r in self.nominal.values())

    @property
    def in_range_share(self) -> float:
        return self.in_range_passed / self.in_range_runs if self.in_range_runs else 1.0

    @property
    def ready(self) -> bool:
        from rodctl.sim.matrix import MIN_PASS_SHARE

        return self.nominal_met and self.in_range_share >= MIN_PASS_SHARE

    def nominal_text(self, task: str) -> str:
        from rodctl.sim.matrix import BALANCE_SETTLE_GOAL_S, SETTLE_DEG, SWINGUP_SETTLE_GOAL_S

        r = self.nominal.get(task)
        if r is None:
            return f"{task}: not run"
        goal = BALANCE_SETTLE_GOAL_S if task == "balance" else SWINGUP_SETTLE_GOAL_S
        after = "after arming" if task == "balance" else "after the catch"
        if r.get("fault"):
            return f"{task}: FAULT (reason {r.get('fault_reason')}): goal missed"
        if task == "swingup" and r.get("caught_at_s") is None:
            return f"{task}: never caught: goal missed"
        end = r.get("final_dev_deg")
        end_text = f", ends {end:.1f} deg off upright" if end is not None else ""
        s = r.get("settle_s")
        if r.get("passed"):
            return f"{task}: within {SETTLE_DEG:g} deg {s:.2f} s {after} (goal {goal:g} s): met"
        settled = f"within {SETTLE_DEG:g} deg {s:.2f} s {after}" if s is not None else f"never within {SETTLE_DEG:g} deg"
        return f"{task}: {settled}{end_text} (goal {goal:g} s): MISSED"

    def next_steps(self, out: str) -> list[str]:
        """What to try, most structural first."""
        from rodctl.sim.matrix import ROBUST_BAND_DEG

        steps = []
        if self.buckling_ratio >= 1.0 and self.tip_imu:  # what the IMU is for: it holds rods past the length
            steps.append(f"the rod is {self.buckling_ratio:.3f} x its clamped buckling length with the tip IMU's mass: "
                         "it bends over whenever the shaft holds still and stands only while the shaft moves under it; "
                         "the matrix labels those runs (^) and does not count them (docs/sensors.md, longest rod)")
        elif self.buckling_ratio >= 1.0:
            steps.append(f"the rod is {self.buckling_ratio:.3f} x its clamped buckling length: it bends over whenever "
                         "the shaft holds still, and no gains change that; use a shorter or stiffer rod")
        if self.straightest_deg > ROBUST_BAND_DEG:
            steps.append(f"the rod is curved at rest: its straightest static shape upright is {self.straightest_deg:.2f} "
                         f"deg off, past the {ROBUST_BAND_DEG:g} deg band, and no gains change that; use a straighter rod "
                         "(docs/control.md, \"A rod curved at rest\")")
        if not self.nominal_met and self.play_deg >= PLAY_FIRST_DEG:
            steps.append(f"the gearbox's play ({self.play_deg:.2f} deg identified) lies between the motor's "
                         "encoder and the rod, which leans on a flank the encoder cannot see: measure the rod side "
                         "(an encoder on the output shaft, encoder.location = \"output\"), or a gearbox with less "
                         "play (docs/control.md)")
        if not self.ready and NEAR_BUCKLING <= self.buckling_ratio < 1.0 and not self.tip_imu:
            steps.append(f"the rod is {self.buckling_ratio:.3f} x its clamped buckling length, where the motor's "
                         "encoder barely sees its slow bend: a tip IMU (sensors.tip_imu = true) sees it, and this "
                         "near buckling the design needs the rod's modulus within about 2 %, as identified "
                         "(docs/sensors.md)")
        if not self.ready:
            steps.append(f"see which runs fail and how: rodctl robustness --params {out}")
            steps.append(f"search the weights for this rig: rodctl tune --params {out} --out tuned.toml")
        else:
            steps.append(f"watch it first: rodctl sim --params {out}; then: rodctl flash --params {out}")
        return steps

    def lines(self, out: str) -> list[str]:
        from rodctl.sim.matrix import MIN_PASS_SHARE

        head = "READY" if self.ready else "NOT READY"
        why = []
        if not self.nominal_met:
            why.append("a nominal goal missed")
        if self.in_range_share < MIN_PASS_SHARE:
            why.append(f"{100 * self.in_range_share:.0f} % of the in-range runs passed, under "
                       f"{100 * MIN_PASS_SHARE:.0f} %")
        text = [f"verdict: {head}" + (f": {'; '.join(why)}" if why else "")
                + f" (the design in {out} on the identified rig, gearbox included)",
                f"  matrix ({self.cases}): {self.passed}/{self.runs} runs passed; "
                + (f"in range {self.in_range_passed}/{self.in_range_runs} ({100 * self.in_range_share:.0f} %, needed "
                   f"{100 * MIN_PASS_SHARE:.0f} %)" if self.in_range_runs else "none in range")]
        text += [f"  nominal {self.nominal_text(t)}" for t in ("balance", "swingup")]
        if self.failed and not self.ready:
            shown = ", ".join(self.failed[:8]) + (f" and {len(self.failed) - 8} more" if len(self.failed) > 8 else "")
            text.append(f"  in-range runs that failed: {shown}")
        text += [f"  next: {s}" for s in self.next_steps(out)]
        return text


def from_rows(rows: list[dict], params: Params, cases: str) -> Verdict:
    """The verdict on matrix rows (one per case and task) of the design `params` on its own rig."""
    from rodgains.buckling import clamped_ratio

    from rodctl.sim.matrix import KNOWN_FAILURES, buckled, past_band

    in_range = [r for r in rows if (r["case"], r["task"]) not in KNOWN_FAILURES and not buckled(r) and not past_band(r)]
    failed = tuple(f"{r['case']}/{r['task']}" for r in in_range if not r.get("passed"))
    nominal = {r["task"]: r for r in rows if r["case"] == "nominal"}
    return Verdict(cases=cases, passed=sum(1 for r in rows if r.get("passed")), runs=len(rows),
                   in_range_passed=len(in_range) - len(failed), in_range_runs=len(in_range), nominal=nominal,
                   buckling_ratio=clamped_ratio(params),
                   play_deg=params.encoder_play_deg, tip_imu=params["sensors"]["tip_imu"],
                   failed=failed, straightest_deg=max((r.get("straightest_deg") or 0.0 for r in nominal.values()), default=0.0))


def judge(params: Params, cases: str = "matrix", *, runner=None, jobs: int | None = None,
          progress: bool = True) -> Verdict:
    """Run the matrix case set `cases` ("none" counts as "nominal": the goals are always judged) with
    the design of `params` on params' own faithful plant. runner: a rodctl.robust.execute.Runner to
    reuse (default: a local one with `jobs` workers)."""
    from rodctl.robust import score as S
    from rodctl.robust.execute import Runner

    cases = "nominal" if cases == "none" else cases
    units = S.units(params, cases=cases, samples=0)
    if runner is not None:
        return from_rows(runner.run(units, desc="verdict"), params, cases)
    with Runner(jobs=jobs, progress=progress) as own:
        return from_rows(own.run(units, desc="verdict"), params, cases)
