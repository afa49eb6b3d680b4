"""What the tip IMU changes, measured on the faithful plant (docs/sensors.md).

    python -m rodctl.sim.imu_study

For the base-only design and the design with the tip IMU, on the faithful plant of each case: balance from
30 deg and swing-up, each run 12 s, then over its last 6 s the links' largest deviation from upright (mean
and peak: with gearbox play the rod does not settle, it cycles, so one final instant says little), the
estimate's error and the torque's RMS once balanced.
"""

from __future__ import annotations

import argparse

import numpy as np

from rodgains.params import load_params

CASES = (  # name, plant overrides (matrix.scaled_overrides syntax)
    ("nominal (1 deg of play)", ()),
    ("no gearbox play", ("gearbox.backlash_deg=0.0",)),
    ("3 deg of play", ("gearbox.backlash_deg=3.0",)),
    ("E -15 %", ("rod.youngs_modulus*=0.85",)),
    ("rho +15 %", ("rod.density*=1.15",)),
    ("E -15 %, no play", ("rod.youngs_modulus*=0.85", "gearbox.backlash_deg=0.0")),
)
SECONDS = 12.0
WINDOW_S = 6.0


def run(design_p, plant_p, task: str) -> dict[str, float]:
    from rodctl.sim import matrix
    from rodctl.sim.scenarios import resample_edges

    log = matrix.simulate(design_p, plant_p, task, seconds=SECONDS)
    t = log["time"]
    w = t > t[-1] - WINDOW_S
    bal = w & (log["mode"] == matrix.MODE_BALANCE)
    n = log["controller_edges"]
    mean, peak = matrix.tail_deviation_deg(log, WINDOW_S)
    out = {"mean_deg": mean, "peak_deg": peak, "fault": bool((log["mode"] == matrix.MODE_FAULT).any())}
    if bal.any():
        err = log["est"][bal, :n] - resample_edges(log["theta"][bal], n, log["plant_bounds"])
        err = np.mod(err + np.pi, 2 * np.pi) - np.pi
        out["est_rms_deg"] = float(np.degrees(np.sqrt(np.mean(err**2))))
        out["torque_rms_mNm"] = float(1e3 * np.sqrt(np.mean(log["torque"][bal] ** 2)))
    else:
        out["est_rms_deg"] = out["torque_rms_mNm"] = float("nan")
    return out


def table(progress=print) -> list[str]:
    from rodctl.sim import matrix

    rows = ["| case | design | balance: mean / peak [deg] | swing-up: mean / peak [deg] | estimate error [deg RMS] "
            "| torque [mN m RMS] |", "|---|---|---|---|---|---|"]
    for name, plant_ov in CASES:
        for label, design in (("base only", load_params()), ("tip IMU", load_params(overrides=["sensors.tip_imu=true"]))):
            plant = matrix.apply_overrides(design, plant_ov)
            b, s = run(design, plant, "balance"), run(design, plant, "swingup")
            cell = lambda r: f"{r['mean_deg']:.2f} / {r['peak_deg']:.2f}" + (" FAULT" if r["fault"] else "")  # noqa: E731
            rows.append(f"| {name} | {label} | {cell(b)} | {cell(s)} | {b['est_rms_deg']:.2f} | {b['torque_rms_mNm']:.1f} |")
            progress(rows[-1])
    return rows


def main(argv=None) -> int:
    argparse.ArgumentParser(prog="python -m rodctl.sim.imu_study", description=__doc__.split("\n\n")[0]).parse_args(argv)
    rows = table(progress=lambda r: None)
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
