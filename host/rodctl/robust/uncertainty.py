"""Seeded Monte Carlo plants from the `[uncertainty]` table of the parameter file.

A draw perturbs the simulated plant only; the design (and so the SIL library) stays the one for
the nominal parameters, which is what happens on a real rig whose parameters are known within
tolerances. Draws are made in the calling process from `numpy.random.default_rng(seed)` in a fixed
key order and travel to the workers as exact `section.key=value` overrides (repr of the float),
so a seed gives the same plants on a laptop pool and on a Dask cluster.

Distributions (each key of `[uncertainty]`, 0 or 1 switches one off):
- `*_rel = r`: the parameter times U(1 - r, 1 + r);
- `*_factor = f`: the parameter times exp(U(-ln f, ln f)), i.e. log-uniform from /f to xf;
- `delay_periods_max = n`: an extra control delay drawn uniformly from 0..n periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rodgains.params import SCHEMA, Params

# [uncertainty] key: (distribution, parameters it scales). The torque constant and the back-EMF
# constant are one number in SI units for a DC motor, so they move together.
DRAWN: dict[str, tuple[str, tuple[str, ...]]] = {
    "youngs_modulus_rel": ("rel", ("rod.youngs_modulus",)),
    "density_rel": ("rel", ("rod.density",)),
    "length_rel": ("rel", ("rod.length",)),
    "rod_damping_factor": ("factor", ("rod.damping",)),
    "viscous_friction_factor": ("factor", ("motor.viscous_friction",)),
    "coulomb_friction_rel": ("rel", ("motor.coulomb_friction",)),
    "rotor_inertia_rel": ("rel", ("motor.rotor_inertia",)),
    "torque_constant_rel": ("rel", ("motor.torque_constant", "motor.back_emf_constant")),
    "supply_voltage_rel": ("rel", ("driver.supply_voltage",)),
}


@dataclass(frozen=True)
class Draw:
    """One Monte Carlo plant: overrides for the plant and the extra delay [periods]."""

    index: int
    overrides: tuple[str, ...]  # "section.key=value", exact floats
    delay_periods: int
    factors: dict  # [uncertainty] key -> the multiplier drawn (1.0 when switched off), for the JSON

    @property
    def name(self) -> str:
        return f"draw-{self.index:03d}"


def _exists(name: str) -> bool:
    section, key = name.split(".")
    return key in SCHEMA.get(section, {})


def draws(params: Params, samples: int | None = None, seed: int | None = None,
          plant: Params | None = None) -> list[Draw]:
    """`samples` plants drawn with `seed` (defaults: the table's `samples` and `seed`).
    plant: the true rod whose values the draws scale, when it is not params' own (`--plant`); the
    ranges, samples and seed stay params' [uncertainty] table."""
    u = params["uncertainty"]
    base = params if plant is None else plant
    samples = u["samples"] if samples is None else int(samples)
    seed = u["seed"] if seed is None else int(seed)
    rng = np.random.default_rng(seed)
    out = []
    for i in range(samples):
        overrides, factors = [], {}
        # Every key consumes its random number even when switched off, so switching one range off
        # leaves the other keys' draws unchanged.
        for key, (kind, names) in DRAWN.items():
            x = rng.uniform(-1.0, 1.0)
            width = u[key]
            if kind == "rel":
                f = 1.0 + width * x
            else:
                f = math.exp(math.log(width) * x) if width > 1.0 else 1.0
            factors[key] = f
            if f == 1.0:
                continue
            for name in names:
                if not _exists(name):
                    continue
                section, k = name.split(".")
                overrides.append(f"{name}={base[section][k] * f!r}")
        n = u["delay_periods_max"]
        delay = min(int(rng.uniform(0.0, 1.0) * (n + 1)), n)
        out.append(Draw(i, tuple(overrides), delay, factors))
    return out
