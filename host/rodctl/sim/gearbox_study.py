"""What the gearbox between the encoder and the rod does, measured on the faithful plant.

    python -m rodctl.sim.gearbox_study [--figure docs/img/plant-gearbox.png]

Two measurements (docs/plant.md "The gearbox", docs/control.md "Finding upright"):
- the play seen from the encoder: the rod hanging, a slow torque sine; the motor side crosses the gap
  at every reversal before it meets the rod, so the encoder's angle against the rod's hub traces the
  backlash (what `rodctl identify` fits);
- the lean it leaves: the firmware balancing from 30 deg, the largest link deviation at the end against
  the gap's width, for the design without the set-point trim, the default (with it) and the default
  with the encoder on the output shaft instead of the motor.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from rodgains.params import Params, load_params

BACKLASH_DEG = (0.0, 0.25, 0.5, 1.0, 2.0, 3.0)
VARIANTS = (  # label, design overrides, plant overrides
    ("no set-point trim", ("trim.time_constant=0.0",), ()),
    ("default (trim)", (), ()),
    ("default, encoder on the output shaft", (), ('encoder.location="output"',)),
)
REVERSAL_TORQUE_NM = 0.015
REVERSAL_HZ = 0.25


def reversal(p: Params, seconds: float = 6.0) -> dict[str, np.ndarray]:
    """The rod hanging at rest, a 15 mN m torque sine at 0.25 Hz on the motor: time [s], torque [N m],
    the motor side's and the hub's angles [rad] every 1 ms."""
    from rodctl.sim.plant import faithful_plant

    pl = faithful_plant(p, input_mode="torque", at_rest=False)
    pl.set_state(np.zeros(pl.N))
    n = int(round(seconds / 1e-3))
    t = np.arange(n) * 1e-3
    u = REVERSAL_TORQUE_NM * np.sin(2 * math.pi * REVERSAL_HZ * t)
    motor, hub = np.empty(n), np.empty(n)
    for k in range(n):
        motor[k], hub[k] = pl.motor_state()[0], pl.state()[0][0]
        pl.advance(float(u[k]), 1e-3)
    return {"time": t, "torque": u, "motor": motor, "hub": hub}


def lean_table(p: Params, backlash=BACKLASH_DEG) -> dict[str, list[float]]:
    """Variant label -> the largest link deviation over the last 0.5 s of the balance from 30 deg [deg],
    one per backlash width."""
    from rodctl.sim import matrix

    out = {}
    for label, design, plant in VARIANTS:
        q = p.with_overrides(*design) if design else p
        out[label] = [matrix.run_case(q, matrix.Case("gap", "gap", plant + (f"gearbox.backlash_deg={b}",)),
                                      "balance")["final_dev_deg"] for b in backlash]
    return out


def figure(p: Params, path: str, table: dict[str, list[float]] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rev = reversal(p)
    table = table if table is not None else lean_table(p)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    a.plot(rev["time"], np.degrees(rev["motor"] - rev["hub"]), label="motor side minus hub")
    a.plot(rev["time"], 1e3 * rev["torque"] / 15.0 * 0.5 * p["gearbox"]["backlash_deg"], lw=0.8, ls="--",
           label="motor torque (15 mN m = half the gap)")
    a.set_xlabel("time [s]")
    a.set_ylabel("[deg]")
    a.set_title(f"{p['gearbox']['backlash_deg']:g} deg of play: the rod hanging, a slow torque sine; the\n"
                "motor side crosses the gap at every reversal before it meets the rod", fontsize=9)
    a.legend(fontsize=8, loc="lower left")
    a.grid(True, alpha=0.3)
    for label, lean in table.items():
        b.plot(BACKLASH_DEG, lean, marker="o", label=label)
    b.axhline(3.0, color="k", lw=0.8, ls="--")
    b.text(2.1, 3.15, "matrix band (3 deg)", fontsize=8)
    b.axhline(1.0, color="k", lw=0.8, ls=":")
    b.text(2.1, 0.6, "nominal goal (1 deg)", fontsize=8)
    b.set_xlabel("gearbox backlash [deg]")
    b.set_ylabel("largest link deviation, last 0.5 s [deg]")
    b.set_title("balance from 30 deg, the boot zero half a count off", fontsize=10)
    b.legend(fontsize=8, loc="upper left")
    b.grid(True, alpha=0.3)
    fig.tight_layout()
    from rodgains.atomic_file import replacing

    with replacing(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rodctl.sim.gearbox_study", description=__doc__.split("\n")[0])
    ap.add_argument("--figure", metavar="PNG", help="write the two panels to this file")
    a = ap.parse_args(argv)
    p = load_params()
    table = lean_table(p)
    print("largest link deviation at the end of the balance from 30 deg [deg]; backlash " +
          ", ".join(f"{b:g}" for b in BACKLASH_DEG) + " deg")
    for label, lean in table.items():
        print(f"  {label:40s} " + "  ".join(f"{x:6.2f}" for x in lean))
    if a.figure:
        figure(p, a.figure, table)
        print(f"wrote {a.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
