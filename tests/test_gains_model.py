"""The rod model and its linearization against the paper's eqs. (15)-(17) and a numerical Jacobian."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rodgains.buckling import (bessel_zero_minus_third, buckling_margins, clamped_ratio, greenhill_length,
                               nlink_critical_length, tip_mass_factor)
from rodgains.der_model import DERModel
from rodgains.linearize import linearize_upright, numerical_jacobian, paper_Ab, paper_Ag, paper_linearization
from rodgains.params import load_params
from rodgains.rod_model import RodModel

# Eq. (16) and (17) typed in from the paper for N = 5.
PAPER_AB_N5 = np.array([
    [-2, 3, -1, 0, 0],
    [3, -6, 4, -1, 0],
    [-1, 4, -6, 4, -1],
    [0, -1, 4, -6, 3],
    [0, 0, -1, 5, -4],
], dtype=float)
PAPER_AG_N5 = np.array([
    [4.5, -3.5, 0, 0, 0],
    [-4.5, 7.0, -2.5, 0, 0],
    [0, -3.5, 5.0, -1.5, 0],
    [0, 0, -2.5, 3.0, -0.5],
    [0, 0, 0, -1.5, 1.5],
])


def bare_rod(edges=5, **sets):
    """Table I rod without the motor: the paper's model."""
    overrides = [f"rod.edges={edges}", "motor.design_includes_motor=false"] + [f"{k}={v}" for k, v in sets.items()]
    return RodModel.from_params(load_params(overrides=overrides), design=True)


def test_printed_band_matrices_match_the_paper_for_n5():
    assert np.array_equal(paper_Ab(5), PAPER_AB_N5)
    assert np.array_equal(paper_Ag(5), PAPER_AG_N5)


def test_closed_form_linearization_equals_eq15_for_table_I():
    rod = bare_rod(5)
    A, B = linearize_upright(rod)
    Ap, Bp = paper_linearization(rod)
    assert np.allclose(A, Ap, rtol=1e-12, atol=1e-9 * np.abs(A).max())
    assert np.allclose(B, Bp, rtol=1e-12)
    # B = 1/(m l^2) is about 5e4 for the 20 g edge (physics notes)
    assert B[5, 0] == pytest.approx(1 / (rod.m * rod.l**2))
    assert 4.5e4 < B[5, 0] < 5.5e4


def test_nonlinear_jacobian_reproduces_eq15_with_the_gravity_misprint_fixed():
    """With sin(theta_i) in eq. (10) the numerical Jacobian of the nonlinear model is eq. (15)."""
    rod = bare_rod(5)
    An, Bn = numerical_jacobian(rod)
    Ap, Bp = paper_linearization(rod)
    assert np.max(np.abs(An - Ap)) / np.max(np.abs(Ap)) < 1e-7
    assert np.max(np.abs(Bn - Bp)) / np.max(np.abs(Bp)) < 1e-7


@pytest.mark.parametrize("N", [2, 3, 8, 20])
def test_closed_form_matches_numerical_jacobian_for_any_N_with_motor(N):
    p = load_params(overrides=[f"rod.edges={N}"])
    rod = RodModel.from_params(p, design=True)
    assert rod.J > 0 and rod.b > 0
    A, B = linearize_upright(rod)
    An, Bn = numerical_jacobian(rod)
    assert np.max(np.abs(A - An)) / np.max(np.abs(A)) < 1e-7
    assert np.max(np.abs(B - Bn)) / np.max(np.abs(B)) < 1e-7


def test_motor_inertia_slows_the_first_edge():
    with_motor = RodModel.from_params(load_params(), design=True)
    bare = bare_rod(5)
    _, Bm = linearize_upright(with_motor)
    _, Bb = linearize_upright(bare)
    # J G^2 = 5e-7 * 20.4^2 = 2.08e-4 kg m^2, about 11 first-edge inertias
    assert Bm[5, 0] < Bb[5, 0] / 10


def test_energy_is_conserved_without_damping_or_input():
    rod = bare_rod(5, **{"rod.damping": 0.0})
    q0 = np.concatenate([np.linspace(2.4, 2.9, 5), np.zeros(5)])
    sol = solve_ivp(lambda t, q: rod.f(q, 0.0), (0, 1.0), q0, method="DOP853", rtol=1e-10, atol=1e-12)
    E0, E1 = rod.energy(q0), rod.energy(sol.y[:, -1])
    assert abs(E1 - E0) < 1e-7 * abs(E0) + 1e-9


def test_greenhill_length_for_table_I_is_154_mm():
    p = load_params()
    assert bessel_zero_minus_third() == pytest.approx(1.8663, abs=1e-4)
    assert greenhill_length(p) == pytest.approx(0.154, abs=0.001)
    # the paper's printed eq. (23) (factors swapped) would give 0.158 m only by its own misprint
    assert greenhill_length(p) < 0.155  # so the Table I rod is just beyond the continuum limit


def test_the_rod_above_the_hub_reaches_its_clamped_buckling_length_at_the_margins():
    """Table I's rod: 14.5 cm above the 10 mm hub against Greenhill's 15.40 cm, so 0.941 x. Each margin alone
    (E -16.6 %, rho +19.9 %, length +5.8 %) brings that ratio to exactly 1."""
    p = load_params()
    assert clamped_ratio(p) == pytest.approx(0.145 / greenhill_length(p), rel=1e-12)
    assert clamped_ratio(p) == pytest.approx(0.9413, abs=1e-4)
    m = buckling_margins(p)
    assert (m["youngs_modulus"], m["density"], m["length"]) == pytest.approx((-0.166, 0.199, 0.058), abs=1e-3)
    for key in ("youngs_modulus", "density", "length"):
        edge = p.with_overrides(f"rod.{key}={p['rod'][key] * (1 + m[key])!r}")
        assert clamped_ratio(edge) == pytest.approx(1.0, abs=1e-9), key
    assert clamped_ratio(p.with_overrides("rod.gravity=0.0")) == 0.0  # nothing buckles without weight


def test_the_tip_imu_s_mass_shortens_the_clamped_buckling_length():
    """2 g at the tip of Table I's 100 g rod: a point load far out weighs about three times its share, so the
    rod above the hub goes from 0.941 to 0.960 x, and E -15 % (0.994 x bare) is past it. The margins bring the
    ratio to 1 with the IMU on: E's alone scales the whole load; rho's and the length's are solved for."""
    bare = load_params()
    p = bare.with_overrides("sensors.tip_imu=true")
    assert tip_mass_factor(bare) == 1.0
    assert tip_mass_factor(p) == pytest.approx(1.0198, abs=2e-4)
    assert clamped_ratio(p) == pytest.approx(0.9599, abs=2e-4)
    assert clamped_ratio(p.with_overrides("rod.youngs_modulus=504050.0")) > 1.0 > \
        clamped_ratio(bare.with_overrides("rod.youngs_modulus=504050.0"))
    assert clamped_ratio(p.with_overrides("sensors.imu_mass=0.0")) == pytest.approx(clamped_ratio(bare), rel=1e-9)
    m = buckling_margins(p)
    assert (m["youngs_modulus"], m["density"], m["length"]) == pytest.approx((-0.116, 0.139, 0.040), abs=1e-3)
    for key in ("youngs_modulus", "density", "length"):
        edge = p.with_overrides(f"rod.{key}={p['rod'][key] * (1 + m[key])!r}")
        assert clamped_ratio(edge) == pytest.approx(1.0, abs=1e-6), key


def test_the_margins_of_an_imu_far_from_the_tip_are_found():
    """The length margin tried shorter rods as parameter files, which refuse an IMU on the model's clamped edge:
    `gains --report` and identify stopped on a valid rig (the IMU 5 cm from the tip at 4 edges) with that error."""
    p = load_params(overrides=["sensors.tip_imu=true", "sensors.imu_from_tip=0.05", "rod.edges=4"])
    m = buckling_margins(p)
    assert 0.94 < clamped_ratio(p) < 0.96 and 0.0 < m["length"] < 0.058  # nearer the hub it weighs less
    assert clamped_ratio(p.with_overrides(f"rod.length={p['rod']['length'] * (1 + m['length'])!r}",
                                          plausible=False)) == pytest.approx(1.0, abs=1e-6)


def test_nlink_critical_length_converges_to_continuum():
    p = load_params(overrides=["rod.edges=5"])  # Table I's N
    lc = greenhill_length(p)
    l5 = nlink_critical_length(p)
    l20 = nlink_critical_length(p, edges=20)
    l200 = nlink_critical_length(p, edges=200)
    assert l5 == pytest.approx(0.1697, abs=5e-4)
    assert l5 > l20 > l200 > lc
    assert l200 == pytest.approx(lc, rel=0.01)


def test_clamped_rod_buckles_exactly_at_the_model_critical_length():
    """The clamped linearization (edge 1 fixed) loses stability at nlink_critical_length."""
    p = load_params()
    lcrit = nlink_critical_length(p)

    def max_clamped_eig(L):
        """Edge 1 held at pi: M_r z'' + D_r z' + K_r z = 0 over edges 2..N."""
        rod = RodModel.from_params(p.with_overrides(f"rod.length={L}", "motor.design_includes_motor=false"))
        M = rod.m * rod.l**2 * rod.staircase[1:, 1:]
        K = (rod.EI / rod.l) * rod.laplacian[1:, 1:] - rod.m * rod.g * rod.l * np.diag(rod.mass_below[1:])
        D = rod.d * rod.laplacian[1:, 1:]
        n = rod.N - 1
        A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, D)]])
        return np.linalg.eigvals(A).real.max()

    assert max_clamped_eig(0.99 * lcrit) < 0
    assert max_clamped_eig(1.01 * lcrit) > 0


def test_der_agrees_with_inextensible_rod_when_edges_barely_stretch():
    p = load_params(overrides=["rod.edges=4"])
    rod = RodModel.from_params(p, design=False)
    der = DERModel.from_params(p)
    th0 = np.full(4, 5 * np.pi / 6)
    q0, qd0 = der.from_angles(th0, np.zeros(4))
    n = der.size

    def der_f(t, s):
        return np.concatenate([s[n:], der.accel(s[:n], s[n:], 0.0)])

    T = 0.3
    s = solve_ivp(der_f, (0, T), np.concatenate([q0, qd0]), method="Radau", rtol=1e-8, atol=1e-10).y[:, -1]
    r = solve_ivp(lambda t, q: rod.f(q, 0.0), (0, T), np.concatenate([th0, np.zeros(4)]),
                  method="Radau", rtol=1e-9, atol=1e-11).y[:, -1]
    th_der, _ = der.to_angles(s[:n], s[n:])
    # the rod falls by tens of degrees in 0.3 s; the two models stay within 0.5 deg
    assert np.degrees(np.abs(r[:4] - th0).max()) > 10
    assert np.degrees(np.abs(th_der - r[:4]).max()) < 0.5


def test_the_guards_batched_rods_follow_the_rod_model():
    """The large-signal guard integrates its rods side by side (large_signal._Family, eq. 13 batched); each
    rod's rates must be RodModel.f's, here for rods differing in base inertia and damping, far from upright."""
    from rodgains.large_signal import _Family

    p = load_params()
    rods = [RodModel.from_params(q, design=True).kelvin_voigt() for q in
            (p, p.with_overrides("motor.rotor_inertia=9e-07"), p.with_overrides("rod.damping=0.0002"))]
    rng = np.random.default_rng(3)
    q = np.pi + 0.6 * rng.standard_normal((3, 2 * rods[0].N))
    tau = np.array([0.05, -0.2, 0.0])
    got = _Family(rods).f(q, tau)
    for i, rod in enumerate(rods):
        want = rod.f(q[i], tau[i])
        assert np.allclose(got[i], want, rtol=1e-10, atol=1e-10 * np.max(np.abs(want))), i
