"""Figures read as a researcher reads them (issue 36.8): nothing drawn that is not there (a line across
the +-180 deg wrap), nothing hidden (a legend on the curves, a clipped title or trough), and a colour
key where colour carries meaning."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from rodgains.params import load_params

from rodctl.link import protocol as P
from rodctl.logs import LogWriter, read_log, simulator_metadata
from rodctl.logs.plots import make_figure
from rodctl.sim import figures as SF
from rodctl.sim.scenarios import run_scenario


def _drawn(fig):
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _through_hanging_log(path):
    """The rod turning once through hanging (0 rad, +-180 deg from upright), as straight as a stick."""
    p = load_params()
    w = LogWriter(path, simulator_metadata(p))
    for k in range(2000):
        a = -1.0 + 2.0 * k / 2000  # rad: through hanging at k = 1000
        w.write_telemetry(P.Telemetry(mode=P.Mode.SWING_UP, reason=0, flags=5, n=p.N, encoder_count=0, base_rate=0.0,
                                      torque=0.0, duty=0.0, step_us=50, overruns=0, frames_dropped=0, rx_errors=0,
                                      theta_hat=(a,) * p.N, rate_hat=(0.0,) * p.N), seq=k, time_us=1000 * k)
    w.close()
    return path


def test_edge_angles_break_at_the_wrap_instead_of_drawing_across_the_panel(tmp_path):
    fig = make_figure(*read_log(_through_hanging_log(tmp_path / "turn.csv")))
    edges = [ln for ln in fig.axes[5].lines if ln.get_label().startswith("edge ")]
    assert edges
    for ln in edges:
        y = np.asarray(ln.get_ydata(), float)
        assert np.isnan(y).sum() == 1  # one gap, where the rod passes hanging
        pairs = np.abs(np.diff(y))
        assert np.nanmax(pairs) < 5.0  # neighbours drawn joined are neighbours in angle [deg]


def test_the_estimate_legend_sits_beside_the_curves_not_on_them(tmp_path):
    fig = make_figure(*read_log(_through_hanging_log(tmp_path / "turn.csv")))
    r = _drawn(fig)
    ax = fig.axes[0]
    legend = ax.get_legend().get_window_extent(r)
    assert legend.x0 >= ax.get_window_extent(r).x1  # right of the panel
    assert legend.x1 <= fig.bbox.x1 and not legend.overlaps(fig.axes[4].get_window_extent(r))


@pytest.fixture(scope="module")
def swingup():
    return run_scenario("swingup")


def test_every_title_line_fits_the_figure():
    fig = SF.make_figure(run_scenario("fig4"))  # the longest title: the paper's bare-rod overrides
    r = _drawn(fig)
    box = fig._suptitle.get_window_extent(r)
    assert box.x0 >= fig.bbox.x0 and box.x1 <= fig.bbox.x1, (box, fig.bbox)
    assert "observer.process_noise_torque=0" in fig._suptitle.get_text()  # wrapped, not cut


def test_the_estimate_error_panel_shows_its_whole_trough(swingup):
    fig = SF.make_figure(swingup)
    ax = fig.axes[-1]
    assert ax.get_ylabel() == "estimate - true [deg]"
    y = np.concatenate([np.asarray(ln.get_ydata(), float) for ln in ax.lines])
    lo, hi = ax.get_ylim()
    assert lo <= np.nanmin(y) and np.nanmax(y) <= hi
    r = _drawn(fig)
    assert not ax.get_legend().get_window_extent(r).overlaps(ax.get_window_extent(r).shrunk(1.0, 0.97))


def test_the_robustness_heatmap_has_a_colour_key():
    from rodctl.robust.figures import heatmap_figure

    rows = [{"case": c, "task": t, "passed": c != "b", "settle_s": s, "final_dev_deg": 0.5 * s}
            for t in ("balance", "swingup") for c, s in (("a", 0.5), ("b", 2.0))]
    fig = heatmap_figure(rows, "t")
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 1
    labels = [t.get_text() for t in bars[0].get_xticklabels()]
    assert labels == ["smallest in its column: better", "largest in its column: worse"]
    assert "each metric on its own scale" in bars[0].get_xlabel()
