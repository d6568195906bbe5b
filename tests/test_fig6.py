"""Tests for the Fig. 6 table (forecast_design.reproduce.fig6_table) and the margin plots."""

from __future__ import annotations

import json

import numpy as np
import pytest

from forecast_design.analysis import (
    disk_gain_margin,
    disk_margin,
    disk_margin_curve,
    disk_phase_margin_deg,
)
from forecast_design.errors import ParameterError
from forecast_design.lti import RationalTF
# shared helpers of the disk-margin tests
from test_margins import (ATOL_DENSE, RTOL_GRID, SEILER_L, SLACK,
                          _control_grid_alpha, _delta_of, _grid_alpha, _refined_alpha)


# ---------------------------------------------------------------------------------------------
# Fig. 6 (needs forecast_design.loops.continuous.force_loop)
# ---------------------------------------------------------------------------------------------



@pytest.fixture(scope="module")
def fig6_rows():
    from forecast_design.reproduce import fig6_table

    return fig6_table()


def _row(rows, env, obs, wq=None):
    (r,) = [r for r in rows if r.environment == env and r.observer == obs and r.w_q_hz == wq]
    return r


def test_fig6_table_shape_and_json_keys(fig6_rows):
    assert len(fig6_rows) == 2 * (1 + 3 * 3)
    keys = {"environment", "observer", "w_q_hz", "disk_margin", "gain_margin_db",
            "phase_margin_deg", "frequency_rad_s", "stable"}
    for r in fig6_rows:
        m = r.to_mapping()
        assert keys <= set(m)       # the old keys stay; the keys every verb shares (issue 13) are added
        assert m["alpha"] == m["disk_margin"] and m["compensator"] == m["observer"] and m["skew"] == 0.0
        if m["frequency_rad_s"] is not None:
            assert m["frequency_hz"] == pytest.approx(m["frequency_rad_s"] / (2 * np.pi), rel=1e-15)
            assert m["phase_margins_deg"] == [-m["phase_margin_deg"], m["phase_margin_deg"]]
        json.dumps(m, allow_nan=False)


@pytest.mark.parametrize("env", ["soft", "stiff"])
@pytest.mark.parametrize("wq", [1.0, 5.0, 10.0])
def test_fig6_ea_fob_within_two_percent_of_plant_alone(fig6_rows, env, wq):
    plant = _row(fig6_rows, env, "none")
    ea = _row(fig6_rows, env, "ea-fob", wq)
    assert plant.stable and ea.stable
    assert ea.disk_margin == pytest.approx(plant.disk_margin, rel=0.02)


def test_fig6_lo_dob_disk_margin_decreases_with_cutoff_in_soft(fig6_rows):
    a = [_row(fig6_rows, "soft", "lo-dob", wq).disk_margin for wq in (1.0, 5.0, 10.0)]
    assert a[0] > a[1] > a[2]


def test_fig6_ld_dob_unstable_at_10_hz_in_stiff(fig6_rows):
    r = _row(fig6_rows, "stiff", "ld-dob", 10.0)
    assert not r.stable and r.disk_margin == 0.0


def test_fig6_disk_margins_agree_with_python_control_grid():
    from forecast_design.params import Compensator, Design
    from forecast_design.loops import force_loop

    for env, comp in [("soft", None), ("stiff", Compensator(kind="lo-dob", w_q_hz=5.0)),
                      ("soft", Compensator(kind="ea-fob", w_q_hz=10.0))]:
        loop = force_loop(Design.nominal(env), comp)
        assert loop.stable
        dm = disk_margin(loop.L, closed_loop_stable=loop.stable)
        dm_grid = _control_grid_alpha(loop.L, 0.0, dm.frequency_rad_s, 1e-3, 1e5)
        assert dm.alpha <= dm_grid + SLACK
        assert dm.alpha == pytest.approx(dm_grid, rel=RTOL_GRID)


def test_fig6_every_stable_row_matches_refined_dense_grid(fig6_rows):
    from forecast_design.params import Compensator, Design
    from forecast_design.loops import force_loop

    for r in fig6_rows:
        if not r.stable:
            continue
        comp = None if r.w_q_hz is None else Compensator(kind=r.observer, w_q_hz=r.w_q_hz)
        L = force_loop(Design.nominal(r.environment), comp).L
        alpha_grid, _ = _grid_alpha(L, np.logspace(-3, 5, 8001), 0.0)
        assert r.disk_margin <= alpha_grid + SLACK, r
        assert r.disk_margin == pytest.approx(_refined_alpha(L, 0.0, 1e-3, 1e5), abs=ATOL_DENSE), r


# ---------------------------------------------------------------------------------------------
# Plots (forecast_design.plotting.margins)
# ---------------------------------------------------------------------------------------------


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def test_disk_upper_boundary_runs_from_gamma_max_to_gamma_min_in_upper_half():
    from forecast_design.plotting.margins import disk_upper_boundary

    for alpha, sigma in [(0.4581, 0.0), (1.2, 0.5), (0.9, -0.7)]:
        f = disk_upper_boundary(alpha, sigma, 101)
        lo, hi = disk_gain_margin(alpha, sigma)
        assert f[0].real == pytest.approx(hi, rel=1e-12) and f[-1].real == pytest.approx(lo, rel=1e-12)
        assert np.all(f.imag >= -1e-12)
        np.testing.assert_allclose(np.abs(_delta_of(f, sigma)), alpha, rtol=1e-12)


def test_plot_fig6_writes_png_with_one_panel_per_environment(tmp_path):
    from forecast_design.analysis import MarginRow
    from forecast_design.plotting.margins import plot_fig6

    def row(env, obs, wq, a, stable=True):
        return MarginRow(environment=env, observer=obs, w_q_hz=wq, disk_margin=a,
                         gain_margin_db=disk_gain_margin(a) if stable else (0.0, 0.0),
                         phase_margin_deg=disk_phase_margin_deg(a), frequency_rad_s=10.0, stable=stable)

    rows = [row("soft", "none", None, 1.96), row("soft", "lo-dob", 10.0, 1.03),
            row("soft", "ea-fob", 10.0, 2.0), row("soft", "ld-dob", 10.0, 2.5),   # half-plane, exterior
            row("stiff", "none", None, 1.16), row("stiff", "ld-dob", 5.0, 0.38),
            row("stiff", "ld-dob", 10.0, 0.0, stable=False)]
    from forecast_design.plotting.margins import figure_fig6

    out = plot_fig6(rows, tmp_path / "fig6.png")
    assert _png_size(out)[0] > 0
    titles = [ax.get_title() for ax in figure_fig6(rows).axes]
    # a row of panels per environment (soft: its disk reaching Re f = 99 whole, and a frame near f = 1)
    assert [t.split()[0] for t in titles if t and not t.startswith("near")] == ["soft", "stiff"]
    assert len(figure_fig6(rows[:4]).axes) == 3                          # half-disks twice and alpha bars
    assert len(figure_fig6(rows[4:]).axes) == 2                          # one frame holds every disk
    with pytest.raises(ParameterError):
        plot_fig6([], tmp_path / "none.png")


def test_plot_disk_margin_curve_writes_png(tmp_path):
    from forecast_design.plotting.margins import plot_disk_margin_curve

    w = np.logspace(-2, 2, 200)
    curves = {"L": disk_margin_curve(SEILER_L, w),
              "w_c/s": disk_margin_curve(RationalTF([1.0], [1.0, 0.0]), w)}
    out = plot_disk_margin_curve(curves, tmp_path / "curve.png", title="alpha(w)")
    assert _png_size(out)[0] > 0
    assert plot_disk_margin_curve(curves["L"], tmp_path / "one.png").exists()


def test_fig6_stability_flag_agrees_with_roots_of_loop_polynomials(fig6_rows):
    # ForceLoop.stable comes from the uncancelled characteristic polynomial; our own check
    # uses den(L) + num(L). They agree when L has no hidden cancellation.
    from forecast_design.params import Compensator, Design
    from forecast_design.loops import force_loop

    for r in fig6_rows:
        comp = None if r.w_q_hz is None else Compensator(kind=r.observer, w_q_hz=r.w_q_hz)
        loop = force_loop(Design.nominal(r.environment), comp)
        assert disk_margin(loop.L).stable == r.stable == loop.stable, r


def test_fig6_table_rejects_unknown_observer_and_environment():
    from forecast_design.reproduce import fig6_table

    with pytest.raises(ParameterError, match="observer"):
        fig6_table(observers=("magic",))
    with pytest.raises(ParameterError, match="unknown environment"):
        fig6_table(environments=("mud",), observers=("none",))


def test_fig6_rows_say_what_they_assumed_and_it_is_what_was_analysed():
    """Each row's ``assumed`` names the testbed, environment values, controller and compensator of its disk;
    the loop rebuilt from that record alone by the ``margins`` path gives the row's alpha."""
    from forecast_design.analysis import analyse_loop
    from forecast_design.controllers import controller_from_mapping
    from forecast_design.params import Compensator, Design, Environment, Testbed
    from forecast_design.reproduce import fig6_table

    rows = fig6_table(environments="soft", testbed="k=40", controller="pid:2:3:0.05", w_q_hz=(4.0,),
                      observers=("none", "lo-dob"))
    assert len(rows) == 2
    for row in rows:
        m = row.to_mapping()
        a = m["assumed"]
        assert a["design"]["testbed"]["k"] == 40.0 and a["design"]["controller"]["kind"] == "pid"
        assert a["break_at"] == "controller" and a["loop"] == "continuous"
        d = a["design"]
        comp = Compensator.from_mapping(d["compensator"]) if "compensator" in d else None
        assert (comp is None) == (row.observer == "none") and (comp is None or comp.w_q_hz == 4.0)
        assert (a["q_family"], a["q_order"]) == ((None, None) if comp is None else ("butterworth", 2))
        design = Design(testbed=Testbed.from_mapping(d["testbed"]),
                        environment=Environment.from_mapping(d["environment"]))
        again = analyse_loop(design, comp, controller=controller_from_mapping(d["controller"]))
        assert again.disk.alpha == pytest.approx(m["alpha"], rel=1e-9)
