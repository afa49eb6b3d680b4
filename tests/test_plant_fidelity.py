"""Issue 8: the faithful plant: convergence in plant.edges, the hub's clamped length, Coulomb friction."""

import numpy as np
import pytest

from rodgains.params import load_params
from rodctl.sim import convergence as C
from rodctl.sim.plant import Plant, faithful_plant

from host_tools import run_rodctl


@pytest.fixture(scope="module")
def p():
    return load_params()


@pytest.fixture(scope="module")
def study(p):
    """The default model at 10, 20, 40 edges (and the default edges), 1 s tip trajectories."""
    model, n0 = p["plant"]["model"], p["plant"]["edges"]
    edges = sorted({10, 20, 40, n0})
    periods = [C.first_hanging_period(p, model, n) for n in edges]
    tips = [C.tip_trajectory(p, model, n, seconds=1.0) for n in edges]
    return edges, periods, tips


def test_default_plant_is_within_one_percent_of_its_continuum_limit(p, study):
    edges, periods, tips = study
    n0 = p["plant"]["edges"]
    fine = [i for i, n in enumerate(edges) if n in (10, 20, 40)]
    lim, order = C.richardson([periods[i] for i in fine], [10, 20, 40])
    tip_lim, tip_order = C.richardson([tips[i] for i in fine], [10, 20, 40])
    k = edges.index(n0)
    assert abs(periods[k] - lim) / lim <= C.TOLERANCE
    assert np.max(np.linalg.norm(tips[k] - tip_lim, axis=1)) / p["rod"]["length"] <= C.TOLERANCE
    # second order in 1/N (the clamp is at the hub, not half an edge off): the error drops ~4x per doubling
    assert order > 1.7 and tip_order > 1.5


def test_first_hanging_period_converges_to_the_continuum(p):
    """Clamped at the axis (hub_length = 0), the N -> inf period is the uniform cantilever's under gravity."""
    q = p.with_overrides("plant.hub_length=0.0", 'plant.model="inextensible"')
    per = [C.first_hanging_period(q, "inextensible", n) for n in (10, 20, 40)]
    lim, order = C.richardson(per, [10, 20, 40])
    assert abs(per[-1] - lim) / lim < 2e-3 and order > 1.7
    assert 0.440 < lim < 0.460  # continuum about 451 ms (issue 8)


def test_hub_length_not_edges_sets_the_clamped_length(p):
    for n in (5, 10, 40):
        for model in ("inextensible", "der"):
            pl = faithful_plant(p.with_overrides(f'plant.model="{model}"', f"plant.edges={n}"))
            arc = pl.node_arc()
            assert arc[1] == pytest.approx(p["plant"]["hub_length"])  # edge 1 is the hub, whatever N
            assert arc[-1] == pytest.approx(p["rod"]["length"])
            assert np.allclose(np.diff(arc[1:]), (p["rod"]["length"] - arc[1]) / n)
    # the clamp sets the physics: a longer hub shortens the period; N (converged) does not move it
    per = lambda hub, n: C.first_hanging_period(p.with_overrides(f"plant.hub_length={hub}"),  # noqa: E731
                                                p["plant"]["model"], n)
    assert abs(per(0.01, 20) - per(0.01, 40)) / per(0.01, 40) < 0.003
    assert (per(0.01, 20) - per(0.03, 20)) / per(0.01, 20) > 0.03


def test_the_hub_turns_with_the_encoder(p):
    """Edge 1 is the clamped hub: on a rigid gearbox the encoder reads its angle, and it never bends."""
    pl = faithful_plant(p, input_mode="torque", gear=None)
    pl.set_state(np.zeros(pl.N))
    for _ in range(300):
        pl.advance(0.05, 1e-3)
    th, _ = pl.state()
    assert pl.encoder() == pl.encoder_count(th[0])
    assert abs(th[0]) > 0.1 and abs(th[-1] - th[0]) > 0.01  # it swung, and the rod bends beyond the hub


def test_coulomb_friction_holds_the_shaft_below_breakaway(p):
    tc = p["motor"]["coulomb_friction"]

    def turned(torque, coulomb):
        pl = Plant(p, edges=5, hub_length=p["plant"]["hub_length"], coulomb=coulomb, g=0.0)
        pl.set_state(np.zeros(pl.N))
        for _ in range(500):
            pl.advance(torque, 1e-3)
        return pl.state()[0][0]

    assert abs(turned(0.8 * tc, tc)) < 0.02  # creeps less than a degree in 0.5 s
    assert turned(1.5 * tc, tc) > 0.1
    assert turned(0.8 * tc, 0.0) > 0.1  # without the friction the same torque turns it


@pytest.mark.parametrize("override,key", [
    ("plant.edges=1", "plant.edges"), ("plant.edges=100000", "plant.edges"),
    ("plant.hub_length=-0.01", "plant.hub_length"), ("plant.hub_length=0.155", "plant.hub_length"),
    ('plant.model="beam"', "plant.model")])
def test_bad_plant_input_is_one_line_naming_the_key(override, key):
    r = run_rodctl("sim", "--set", override, "--no-plot", "--no-log")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and r.stderr.startswith(f"rodctl: {key}:"), r.stderr


def test_edges_and_plant_options_are_shorthands_for_the_plant_table():
    r = run_rodctl("sim", "--edges", "1", "--no-plot", "--no-log")
    assert r.returncode == 2 and r.stderr.startswith("rodctl: plant.edges:")
    r = run_rodctl("sim", "--plant", "beam", "--no-plot", "--no-log")
    assert r.returncode == 2 and r.stderr.startswith("rodctl: plant.model:")


def test_design_model_stays_the_paper_rod(p):
    """The controller's model is rod.edges equal edges (no hub), whatever the plant table says."""
    from rodgains.design import design

    a = design(p)
    b = design(p.with_overrides("plant.hub_length=0.05", "plant.edges=7", 'plant.model="inextensible"'))
    assert a.N == p["rod"]["edges"]
    assert np.allclose(a.K, b.K) and np.allclose(a.L, b.L)
