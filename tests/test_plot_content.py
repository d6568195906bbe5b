"""What the plots draw (facts about artists, not pixels) and the quantities computed for them."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from forecast_design.errors import ParameterError
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design, environment_preset


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


# --- Fig. 6 -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fig6_rows():
    from forecast_design.reproduce import fig6_table

    return fig6_table()


def _disk_patches(fig):
    """{(env, observer, w_q): patch} of the half-disk axes (patches carry 'env|observer|w_q' gids)."""
    from matplotlib.patches import Patch

    out = {}
    for ax in fig.axes:
        for p in ax.patches:
            gid = p.get_gid()
            if gid and isinstance(p, Patch) and not hasattr(p, "get_height"):
                out[tuple(gid.split("|"))] = p
    return out


def _bars(fig):
    out = {}
    for ax in fig.axes:
        for p in ax.patches:
            if hasattr(p, "get_height") and p.get_gid():
                out[tuple(p.get_gid().split("|"))] = p
    return out


def test_fig6_every_observer_and_cutoff_is_its_own_artist_with_the_same_colour_in_both_panels(fig6_rows):
    from matplotlib.colors import to_rgb

    from forecast_design.plotting.margins import figure_fig6

    fig = figure_fig6(fig6_rows)
    disks, bars = _disk_patches(fig), _bars(fig)
    stable = [r for r in fig6_rows if r.stable]
    assert len(disks) == len(stable)                              # one half-disk per stable row
    assert len(bars) == len([r for r in stable if r.observer != "none"])
    # within an observer every cutoff has its own (colour, line style); across observers the hues differ
    for obs in ("ea-fob", "lo-dob", "ld-dob"):
        looks = {(to_rgb(p.get_edgecolor()), str(p.get_linestyle())) for (env, o, _), p in disks.items()
                 if o == obs and env == "soft"}
        assert len(looks) == 3
    # same colour and line style for the same observer and cutoff in both environments and in the bars
    for (env, obs, wq), p in disks.items():
        other = disks.get(("stiff" if env == "soft" else "soft", obs, wq))
        if other is not None:
            assert to_rgb(other.get_edgecolor()) == to_rgb(p.get_edgecolor())
            assert other.get_linestyle() == p.get_linestyle()
        if obs != "none":
            assert to_rgb(bars[(env, obs, wq)].get_edgecolor()) == to_rgb(p.get_edgecolor())
    # bar lengths are the disk margins
    for r in stable:
        if r.observer != "none":
            assert bars[(r.environment, r.observer, str(r.w_q_hz))].get_width() == pytest.approx(r.disk_margin)
    # the figure legend: the plant plus one entry per observer and cutoff (blank padding aside)
    labels = [t.get_text() for t in fig.legends[0].get_texts() if t.get_text()]
    assert labels.count("plant") == 1
    for obs in ("EA-FOB", "LO-DOB", "LD-DOB"):
        assert sorted(lab for lab in labels if lab.startswith(obs + " ")) == [f"{obs} {f} Hz" for f in (1, 10, 5)]


def test_fig6_unstable_row_has_no_disk_and_is_named_in_the_bars(fig6_rows):
    from forecast_design.plotting.margins import figure_fig6

    fig = figure_fig6(fig6_rows)
    unstable = [r for r in fig6_rows if not r.stable]
    assert [(r.environment, r.observer, r.w_q_hz) for r in unstable] == [("stiff", "ld-dob", 10.0)]
    assert ("stiff", "ld-dob", "10.0") not in _disk_patches(fig)
    stiff_bars = [ax for ax in fig.axes if ax.get_xlabel().startswith("disk margin")][1]
    assert "unstable" in [t.get_text() for t in stiff_bars.texts]


# --- the Q trade-off ---------------------------------------------------------------------------


@pytest.mark.parametrize("observer", ["ea-fob", "lo-dob", "ld-dob"])
def test_tradeoff_curve_passes_through_the_tuners_own_answer(observer):
    from forecast_design.tuning.tradeoff import cutoff_tradeoff
    from forecast_design.tuning import tune_q, worst_case_ratio

    result = tune_q(observer, "soft,stiff")
    tr = cutoff_tradeoff(observer, "soft,stiff", chosen=result, points=12)
    i = tr.at(result.w_q_hz)
    assert tr.w_q_hz[i] == result.w_q_hz
    assert tr.worst_ratio[i] == pytest.approx(result.worst_ratio, rel=1e-12)
    assert tr.binding_environment[i] == result.worst_environment
    # and everywhere else it is the public worst-case ratio of the same set
    for k in (0, 5, len(tr.w_q_hz) - 1):
        ratio, env = worst_case_ratio(Compensator(kind=observer, w_q_hz=float(tr.w_q_hz[k])), "soft,stiff")
        assert tr.worst_ratio[k] == pytest.approx(ratio, rel=1e-12) and tr.binding_environment[k] == env
    # feasible below the answer only where the tuner says so: nothing above it in the band passes
    above = tr.w_q_hz > result.w_q_hz * 1.02
    assert not np.any(tr.worst_ratio[above] >= result.min_ratio)


def test_friction_rejection_is_one_minus_q_with_an_exact_nominal_plant():
    # EA-FOB's nominal plant is P without d_m: with d_m = 0 it is exact, R = 1 - Q, and the
    # 2nd-order Butterworth's |1 - Q(j w)| = 1/sqrt(2) at w^2 = (sqrt(5) - 2) w_q^2.
    from forecast_design.symbolic import compensator_q_tf
    from forecast_design.tuning.tradeoff import friction_rejection, rejection_bandwidth_hz

    base = Design(environment=environment_preset("stiff"))
    design = dataclasses.replace(base, testbed=dataclasses.replace(base.testbed, d_m=0.0))
    comp = Compensator(kind="ea-fob", w_q_hz=7.0)
    w = np.logspace(-2, 4, 3000)
    R = friction_rejection(design, comp, w)
    np.testing.assert_allclose(R, 1.0 - compensator_q_tf(comp)(1j * w), rtol=1e-8, atol=1e-12)
    bw = rejection_bandwidth_hz(w, R)
    assert bw == pytest.approx(math.sqrt(math.sqrt(5.0) - 2.0) * 7.0, rel=2e-3)


@pytest.mark.parametrize("kind,env,believed", [("lo-dob", "soft", "soft"), ("motor-fob", "stiff", "soft"),
                                               ("ld-dob", "stiff", "stiff")])
def test_friction_rejection_equals_the_loop_equations_solved_directly(kind, env, believed):
    # Independent route: solve tau_m = -C tau_s + G_m tau_m + G_s tau_s + G_theta theta,
    # tau_s = P (tau_m - tau_f), theta = P_theta (tau_m - tau_f) per frequency, with and without the observer.
    from forecast_design.loops import force_loop
    from forecast_design.symbolic import motor_angle_tf
    from forecast_design.tuning.tradeoff import friction_rejection

    true = Design(environment=environment_preset(env))
    bel = Design(environment=environment_preset(believed))
    comp = Compensator(kind=kind, w_q_hz=4.0)
    ctrl = PD(P=5.0, D=0.1)
    loop = force_loop(true, comp, controller=ctrl, believed=bel)
    w = np.logspace(-1, 3, 60)
    s = 1j * w
    P, Pt, C = loop.P(s), motor_angle_tf(true)(s), ctrl.P + ctrl.D * s
    f = loop.filters
    Gm, Gs, Gt = f.from_tau_m(s), f.from_tau_s(s), f.from_theta(s)
    # unknowns (tau_m, tau_s, theta) with tau_f = 1
    ratio = np.empty(w.size, complex)
    for i in range(w.size):
        A = np.array([[1 - Gm[i], C[i] - Gs[i], -Gt[i]], [-P[i], 1, 0], [-Pt[i], 0, 1]])
        with_obs = np.linalg.solve(A, np.array([0, -P[i], -Pt[i]]))[1]
        without = -P[i] / (1 + C[i] * P[i])
        ratio[i] = with_obs / without
    np.testing.assert_allclose(friction_rejection(true, comp, w, controller=ctrl, believed=bel), ratio,
                               rtol=1e-7)


def test_tradeoff_plot_draws_each_observer_once_with_the_chosen_cutoff():
    from forecast_design.plotting.style import observer_colour
    from forecast_design.plotting.tuning import figure_tradeoff
    from forecast_design.tuning.tradeoff import cutoff_tradeoff
    from forecast_design.tuning import tune_q

    result = tune_q("lo-dob", "soft,stiff")
    trs = [cutoff_tradeoff("lo-dob", "soft,stiff", chosen=result, points=8),
           cutoff_tradeoff("ea-fob", "soft,stiff", points=8)]
    fig = figure_tradeoff(trs)
    ax_r, ax_b = fig.axes
    by_gid = {line.get_gid(): line for ax in (ax_r, ax_b) for line in ax.lines if line.get_gid()}
    for tr in trs:
        ratio, bw = by_gid[f"ratio|{tr.observer}"], by_gid[f"bandwidth|{tr.observer}"]
        np.testing.assert_array_equal(ratio.get_ydata(), tr.worst_ratio)
        np.testing.assert_array_equal(bw.get_ydata(), tr.rejection_bandwidth_hz)
        assert ratio.get_color() == bw.get_color() == observer_colour(tr.observer)   # one colour per observer
    (x,), (y,) = by_gid["chosen|lo-dob"].get_data()
    assert x == result.w_q_hz and y == pytest.approx(result.worst_ratio, rel=1e-12)
    assert "chosen|ea-fob" not in by_gid
    assert any(line.get_ydata()[0] == 0.9 for line in ax_r.lines)                    # the min-ratio line
    notes = " ".join(t.get_text() for t in ax_r.texts)
    assert f"binding: {result.worst_environment}" in notes
    assert "[Hz]" in ax_b.get_xlabel() and "[Hz]" in ax_b.get_ylabel()


def test_tradeoff_rejects_bad_arguments():
    from forecast_design.tuning.tradeoff import cutoff_tradeoff

    with pytest.raises(ParameterError, match="observer"):
        cutoff_tradeoff("sfm")
    with pytest.raises(ParameterError, match="band"):
        cutoff_tradeoff("ea-fob", band_hz=(5.0, 1.0))
    with pytest.raises(ParameterError, match="points"):
        cutoff_tradeoff("ea-fob", points=1)


def test_cli_tune_q_plot_writes_png_and_tradeoff_json(tmp_path, capsys):
    from forecast_design.cli import main

    out, js = tmp_path / "tq.png", tmp_path / "tq.json"
    assert main(["tune-q", "--observer", "ld-dob", "--plot", str(out), "--json", str(js)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = json.loads(js.read_text())
    tr = data["tradeoff"]
    i = tr["w_q_hz"].index(data["w_q_hz"])
    assert tr["worst_ratio"][i] == pytest.approx(data["worst_ratio"], rel=1e-12)
    assert tr["binding_environment"][i] == data["worst_environment"]
    assert len(tr["rejection_bandwidth_hz"]) == len(tr["w_q_hz"])


# --- run --reference: help, parser and the reference signals agree ------------------------------


def test_run_help_quotes_the_parsers_syntax_and_each_form_is_the_named_reference_signal(capsys):
    from forecast_design.cli import main
    from forecast_design.runtime.protocol import REFERENCE_SYNTAX, parse_reference
    from forecast_design.simulation import references as refs

    with pytest.raises(SystemExit):
        main(["run", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert REFERENCE_SYNTAX in help_text and "FREQ" not in help_text
    t = np.linspace(0.0, 3.0, 601)
    # sine:AMP:PERIOD is a period [s]: 0.5 s is 2 Hz
    np.testing.assert_allclose(parse_reference("sine:0.2:0.5").signal()(t),
                               refs.Sine(amplitude=0.2, frequency_hz=2.0)(t), atol=1e-15)
    np.testing.assert_allclose(parse_reference("square:0.2:0.5").signal()(t),
                               refs.Square(high=0.2, low=-0.2, period_s=0.5)(t), atol=1e-15)
    np.testing.assert_allclose(parse_reference("step:0.3:1.5").signal()(t), refs.Step(amplitude=0.3, t0=1.5)(t))
    with pytest.raises(ParameterError, match="sine:AMP:PERIOD"):
        parse_reference("sine:0.2")


# --- diagnosis plots: computed in gap.views, drawn by plotting.gap ------------------------------


@pytest.fixture(scope="module")
def coulomb_diagnosis():
    from forecast_design import effects as fx
    from forecast_design.gap import diagnose
    from forecast_design.simulation import references as refs
    from forecast_design.simulation import simulate

    design = Design.nominal("exp-soft", controller=PD())
    ref = refs.Multisine(amplitudes=(0.8, 0.5, 0.3), frequencies_hz=(0.4, 1.3, 3.1), phases_rad=(0.0, 1.0, 2.0))
    res = simulate(design, reference=ref, duration_s=6.0, effects=(fx.Coulomb(F_c=0.1),), seed=1,
                   closed_loop=True, initial_angle=0.4)
    d = diagnose(res.to_experiment())
    assert str(d.effect) == "coulomb"
    return d


@pytest.fixture
def captured(monkeypatch):
    """Figures the diagnosis plots draw, kept open instead of written."""
    import forecast_design.plotting.gap as gp

    figs = []
    monkeypatch.setattr(gp, "save_figure", lambda fig, path, **kw: figs.append(fig) or path)
    return figs


def test_views_coherence_and_response_equal_scipy(coulomb_diagnosis):
    from scipy import signal

    from forecast_design.gap.locate import empirical_response
    from forecast_design.gap.views import diagnosis_views

    v = diagnosis_views(coulomb_diagnosis)
    exp = coulomb_diagnosis.data.experiment
    f, coh = signal.coherence(exp.signals.tau_m, exp.signals.tau_s, fs=exp.rate_hz, nperseg=1024)
    keep = np.isin(f, v.response.f_hz)
    np.testing.assert_array_equal(f[keep], v.response.f_hz)
    np.testing.assert_allclose(v.response.coherence, coh[keep], rtol=1e-10, atol=1e-14)
    f2, measured, _ = empirical_response(coulomb_diagnosis.data)
    np.testing.assert_allclose(v.response.measured, measured[np.isin(f2, v.response.f_hz)], rtol=1e-12)
    # every low-coherence bin lies in a greyed band, and no coherent bin does
    bands = v.response.low_bands_hz()
    inside = np.array([any(a <= fk <= b for a, b in bands) for fk in v.response.f_hz])
    np.testing.assert_array_equal(inside, v.response.low)


def test_spectrum_plot_puts_coherence_beside_the_response_and_greys_low_coherence(coulomb_diagnosis, captured,
                                                                                   tmp_path):
    from forecast_design.gap.views import diagnosis_views
    from forecast_design.plotting.gap import plot_residual_spectrum

    threshold = float(np.median(diagnosis_views(coulomb_diagnosis).response.coherence))
    v = diagnosis_views(coulomb_diagnosis, coherence_threshold=threshold)    # some bins either side
    assert v.response.low.any() and not v.response.low.all()
    plot_residual_spectrum(v, tmp_path / "s.png")
    fig = captured[0]
    response_ax = next(ax for ax in fig.axes if any(line.get_gid() == "nominal" for line in ax.lines))
    coherence_ax = next(ax for ax in fig.axes if any(line.get_gid() == "coherence" for line in ax.lines))
    b1, b2 = response_ax.get_position(), coherence_ax.get_position()
    assert b1.y0 == pytest.approx(b2.y0) and b1.x1 <= b2.x0          # side by side, same row
    for ax in (response_ax, coherence_ax):
        assert sum(p.get_gid() == "low-coherence" for p in ax.patches) == len(v.response.low_bands_hz())
    low = next(line for line in response_ax.lines if line.get_gid() == "measured|low")
    np.testing.assert_array_equal(low.get_xdata(), v.response.f_hz[v.response.low])


def test_every_diagnosis_plot_draws_before_wherever_it_draws_after(coulomb_diagnosis, captured, tmp_path):
    from forecast_design.gap.views import diagnosis_views
    from forecast_design.plotting import gap as gp

    v = diagnosis_views(coulomb_diagnosis)
    for plot in (gp.plot_residual_time, gp.plot_residual_spectrum, gp.plot_residual_operating,
                 gp.plot_before_after, gp.plot_replay):
        plot(v, tmp_path / "x.png")
    for fig in captured:
        gids = {line.get_gid() for ax in fig.axes for line in ax.lines if line.get_gid()}
        afters = {g.split("|", 1)[1] if "|" in g else "" for g in gids if g.startswith("after")}
        assert afters, "each plot shows the verdict effect"
        for key in afters:
            assert ("before|" + key if key else "before") in gids
        colours = {line.get_gid().split("|")[0]: line.get_color() for ax in fig.axes for line in ax.lines
                   if line.get_gid() and line.get_gid().split("|")[0] in ("before", "after")}
        assert colours == {"before": gp.BEFORE_COLOUR, "after": gp.AFTER_COLOUR}


def test_an_equation_at_rounding_level_is_not_drawn(coulomb_diagnosis, captured, tmp_path):
    # Replace the environment equation's residuals by rounding-level noise: the views drop it,
    # the plots draw only the motor equation and say what they left out.
    from forecast_design.gap.views import diagnosis_views
    from forecast_design.plotting.gap import plot_before_after, plot_residual_time

    d = coulomb_diagnosis
    m = d.data.t.size
    noise = 1e-17 * np.random.default_rng(0).standard_normal(m)

    def quiet(fit):
        r = np.array(fit.residual, copy=True)
        r[m:2 * m] = noise
        return dataclasses.replace(fit, residual=r)

    fits = dict(d.fits)
    fits["coulomb"] = quiet(fits["coulomb"])
    d2 = dataclasses.replace(d, baseline=quiet(d.baseline), fits=fits)
    v = diagnosis_views(d2)
    assert v.equations == ("motor",) and set(v.dropped) == {"environment"}
    assert diagnosis_views(d).equations == ("motor", "environment")     # the real residual is drawn
    plot_residual_time(v, tmp_path / "t.png")
    plot_before_after(v, tmp_path / "b.png")
    for fig in captured:
        assert [ax.get_ylabel().split()[0] for ax in fig.axes] == ["motor"]
        assert "environment" in " ".join(t.get_text() for t in fig.texts)


# --- units follow the log --------------------------------------------------------------------------


def _axis_csv(path, position_col, force_col):
    # a rigid axis with viscous 2 and Coulomb 0.5 friction, mass 1.5, driven by a slow sine
    t = np.arange(0.0, 20.0, 1e-3)
    x = 0.3 * np.sin(2 * np.pi * 0.25 * t) + 0.1 * np.sin(2 * np.pi * 0.9 * t)
    v = np.gradient(x, t)
    a = np.gradient(v, t)
    f = 1.5 * a + 2.0 * v + 0.5 * np.tanh(v / 1e-3)
    rows = "\n".join(f"{ti:.17g},{xi:.17g},{fi:.17g}" for ti, xi, fi in zip(t, x, f))
    path.write_text(f"t_s,{position_col},{force_col}\n{rows}\n")
    return path


@pytest.mark.parametrize("position,force,prismatic", [("qm_m", "force_N", True), ("theta_rad", "tau_m_N_m", False),
                                                      ("pos", "force_N", True), ("pos", "f", False)])
def test_axis_kind_follows_the_column_units(tmp_path, position, force, prismatic):
    from forecast_design.friction.logs import load_axis_csv

    log = load_axis_csv(_axis_csv(tmp_path / "a.csv", position, force), time="t_s", position=position, force=force)
    assert log.prismatic is prismatic
    assert load_axis_csv(tmp_path / "a.csv", time="t_s", position=position, force=force,
                         prismatic=not prismatic).prismatic is (not prismatic)


def test_parameter_units_are_dimensionally_consistent():
    # force = viscous * velocity = coulomb = inertia * acceleration, in either kind of axis
    from forecast_design.friction.logs import axis_units, parameter_unit

    for prismatic, expected in ((True, {"viscous": "N s/m", "coulomb": "N", "inertia": "kg",
                                        "stribeck_velocity": "m/s", "sigma0": "N/m", "sin1": "N"}),
                                (False, {"viscous": "N m s/rad", "coulomb": "N m", "inertia": "kg m^2",
                                         "stribeck_velocity": "rad/s", "sigma0": "N m/rad", "offset": "N m"})):
        assert {k: parameter_unit(k, prismatic) for k in expected} == expected
        u = axis_units(prismatic)
        assert parameter_unit("viscous", prismatic) == f"{u['force']} s/{u['position']}"


def test_identify_on_a_prismatic_log_labels_and_prints_n_and_m(tmp_path, capsys, monkeypatch):
    import forecast_design.plotting.friction as pf
    from forecast_design.cli import main

    figs = []
    monkeypatch.setattr(pf, "save_figure", lambda fig, path, **kw: figs.append(fig) or path)
    csv = _axis_csv(tmp_path / "lin.csv", "qm_m", "force_N")
    args = ["identify", "--csv", str(csv), "--time", "t_s", "--position", "qm_m", "--force", "force_N",
            "--model", "sfm", "--estimate-inertia", "--plot", str(tmp_path / "f.png")]
    assert main(args + ["--json", "-"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["units"] == {"inertia": "kg", "viscous": "N s/m", "coulomb": "N"}
    assert data["params"]["viscous"] == pytest.approx(2.0, rel=0.05)
    labels = {ax.get_xlabel() for ax in figs[0].axes} | {ax.get_ylabel() for ax in figs[0].axes}
    assert "velocity [m/s]" in labels and "friction [N]" in labels and not any("rad" in x for x in labels)
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "N s/m" in out and "N m" not in out


# --- plots at a glance (issue 26): shared checks on what a reader sees --------------------------


def _drawn(fig):
    """Lay the figure out and draw it once (legends and constrained layout get their final places)."""
    if not hasattr(fig.canvas, "get_renderer"):          # a figure the plot closed after writing it
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def _assert_inside_figure(fig, artists, what):
    renderer = _drawn(fig)
    box = fig.bbox
    for a in artists:
        ext = a.get_window_extent(renderer)
        assert (ext.x0 >= box.x0 - 1 and ext.y0 >= box.y0 - 1 and ext.x1 <= box.x1 + 1
                and ext.y1 <= box.y1 + 1), f"{what} {a} at {ext} leaves the figure {box}"


def _assert_no_empty_axes_and_units(fig):
    """Every axes draws something and labels its numeric axes with a unit in brackets (an axis whose
    tick labels are names, like the bars of Fig. 6, or hidden, needs none)."""
    import re

    _drawn(fig)
    for ax in fig.axes:
        assert ax.lines or ax.patches or ax.collections or ax.images, f"empty axes {ax.get_title()!r}"
        for label, ticks in ((ax.get_xlabel(), ax.get_xticklabels()), (ax.get_ylabel(), ax.get_yticklabels())):
            shown = [t.get_text() for t in ticks if t.get_text() and t.get_visible()]
            named = any(re.search("[A-Za-z]{2}", t) for t in shown)
            if label or (shown and not named):    # hidden ticks (a shared axis below) need no label
                assert re.search(r"\[[^\]]+\]", label), f"axis label without a unit: {label!r} ({ax.get_title()!r})"


def _legend_texts(fig):
    return [t.get_text() for leg in fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
            for t in leg.get_texts() if t.get_text()]


@pytest.fixture
def kept(monkeypatch):
    """Figures the CLI's plots draw, kept open instead of written: {module name: [figures]}."""
    import importlib

    figs = {}
    for name in ("bode", "margins", "simulation"):
        mod = importlib.import_module(f"forecast_design.plotting.{name}")
        for writer in ("save_figure", "write_figure"):
            if hasattr(mod, writer):
                monkeypatch.setattr(mod, writer,
                                    lambda fig, path, _n=name, **kw: figs.setdefault(_n, []).append(fig) or path)
    return figs


def test_tf_plot_has_one_panel_per_environment_a_colour_per_plant_and_a_legend_inside(kept, tmp_path, capsys):
    from matplotlib.colors import to_rgb

    from forecast_design.cli import main
    from forecast_design.plotting.style import PLANT_KINDS
    from forecast_design.params import Testbed

    envs = ["soft", "stiff", "fig7", "exp-soft", "locked", "link-only"]
    assert main(["tf", "--env", ",".join(envs), "--plot", str(tmp_path / "tf.png")]) == 0
    (fig,) = kept["bode"]
    lines = {line.get_gid(): line for ax in fig.axes for line in ax.lines if line.get_gid()}
    # every environment has its magnitude and phase panel with the four plants, named in its title
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == [f"environment {e}" for e in envs]
    for env in envs:
        for kind in PLANT_KINDS:
            assert f"mag|{env}|{kind}" in lines and f"phase|{env}|{kind}" in lines
    # one look per plant kind, the same in every panel, and four different looks
    looks = {kind: {(to_rgb(lines[f"{p}|{e}|{kind}"].get_color()), str(lines[f"{p}|{e}|{kind}"].get_linestyle()))
                    for e in envs for p in ("mag", "phase")} for kind in PLANT_KINDS}
    assert all(len(v) == 1 for v in looks.values()) and len({next(iter(v)) for v in looks.values()}) == 4
    # the nominal plants are drawn above the true plant (P underneath, never hiding EA)
    assert all(lines[f"mag|soft|{k}"].get_zorder() > lines["mag|soft|P"].get_zorder() for k in ("EA", "LO", "LD"))
    # a real fact in the locked panel: DC gain 1 (0 dB) and the resonance at sqrt(k / J_m) [rad/s]
    tb = Testbed()
    mag = lines["mag|locked|P"]
    f, m = mag.get_xdata(), mag.get_ydata()
    assert m[0] == pytest.approx(0.0, abs=1e-3)
    assert f[np.argmax(m)] == pytest.approx(math.sqrt(tb.k / tb.J_m) / (2 * math.pi), rel=0.01)
    # one figure legend names the four plants; it lies inside the figure
    labels = _legend_texts(fig)
    assert len(labels) == 4 and all(any(s in lab for lab in labels) for s in ("P", "EA", "LO", "LD"))
    _assert_inside_figure(fig, fig.legends, "legend")
    _assert_no_empty_axes_and_units(fig)
    assert fig._suptitle is not None and "nominal plants" in fig._suptitle.get_text()


def _fig6_frames_by_env(fig):
    """{env: [axes drawing its half-disks]} (patches carry 'env|observer|w_q' gids)."""
    out = {}
    for ax in fig.axes:
        envs = {p.get_gid().split("|")[0] for p in ax.patches if p.get_gid() and not hasattr(p, "get_height")}
        for env in envs:
            out.setdefault(env, []).append(ax)
    return out


def test_fig6_every_disk_is_whole_in_a_frame_and_ea_fob_shows_above_the_plant(fig6_rows):
    from forecast_design.margins import disk_center_radius
    from forecast_design.plotting.margins import figure_fig6

    fig = figure_fig6(fig6_rows)
    frames = _fig6_frames_by_env(fig)
    assert set(frames) == {"soft", "stiff"}
    # every stable disk lies whole inside one frame of its environment: its real-axis extent and top
    for r in (r for r in fig6_rows if r.stable):
        c, rad, exterior = disk_center_radius(r.disk_margin)
        assert not exterior

        def holds(ax):
            (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
            return x0 <= c - rad and c + rad <= x1 and rad <= y1

        assert any(holds(ax) for ax in frames[r.environment]), f"{r.environment} {r.observer} {r.w_q_hz}"
    # no "beyond the frame" notes; the soft set spans 0.02 .. 99: a frame near f = 1 beside the whole one
    assert not any("beyond" in t.get_text() for ax in fig.axes for t in ax.texts)
    assert len(frames["soft"]) == 2 and len(frames["stiff"]) == 1
    near = frames["soft"][1]
    assert near.get_xlim()[1] < 10.0 and near.get_title().startswith("near f = 1")
    # the EA-FOB disks are drawn above the plant's, and carry markers on their arcs at their own angles
    for env, axes in frames.items():
        ax = axes[0]
        patches = {p.get_gid(): p for p in ax.patches if p.get_gid()}
        plant = patches[f"{env}|none|None"]
        for wq in ("1.0", "5.0", "10.0"):
            assert patches[f"{env}|ea-fob|{wq}"].get_zorder() > plant.get_zorder()
        markers = {line.get_gid(): line for line in ax.lines if (line.get_gid() or "").startswith("marker|")}
        ea = [markers[f"marker|{env}|ea-fob|{wq}"] for wq in ("1.0", "5.0", "10.0")]
        assert all(m.get_zorder() > plant.get_zorder() and m.get_marker() == "o" for m in ea)
        # the markers sit on their disk's boundary, and no two disks put a marker at the same angle
        places = []
        for gid, m in markers.items():
            _, _, obs, wq = gid.split("|")
            r = next(r for r in fig6_rows if r.environment == env and r.observer == obs and str(r.w_q_hz) == wq)
            c, rad, _ = disk_center_radius(r.disk_margin)
            np.testing.assert_allclose(np.hypot(m.get_xdata() - c, m.get_ydata()), rad, rtol=1e-9)
            places += np.round(np.arctan2(m.get_ydata(), m.get_xdata() - c), 3).tolist()
        assert len(places) == len(set(places)) >= 3 * len(ea)
    # the legend names the plant and every observer and cutoff, inside the figure; axes labelled with units
    labels = _legend_texts(fig)
    assert "plant" in labels and sum(lab.startswith(("EA-FOB", "LO-DOB", "LD-DOB")) for lab in labels) == 9
    _assert_inside_figure(fig, fig.legends, "legend")
    _assert_no_empty_axes_and_units(fig)


def test_margins_plot_names_the_loop_and_labels_the_minimum_at_the_disk_margin(kept, tmp_path, capsys):
    from forecast_design.cli import main

    args = ["margins", "--controller", "pid:6:20:0.05:0.002", "--compensator", "ea-fob", "--w-q-hz", "7",
            "--env", "exp-soft", "--plot", str(tmp_path / "m.png"), "--json", str(tmp_path / "m.json")]
    assert main(args) == 0
    data = json.loads((tmp_path / "m.json").read_text())
    (fig,) = kept["margins"]
    title = fig._suptitle.get_text()
    for part in ("environment exp-soft", "EA-FOB", "w_q = 7 Hz", "PID P=6 I=20 D=0.05", "continuous"):
        assert part in title, (part, title)
    # the minimum of alpha(f) is the exact disk margin, marked there and labelled with its value and frequency
    ax_a = next(ax for ax in fig.axes if any(line.get_gid() == "alpha" for line in ax.lines))
    curve = next(line for line in ax_a.lines if line.get_gid() == "alpha")
    (fx,), (ay,) = next(line for line in ax_a.lines if line.get_gid() == "disk-margin").get_data()
    fc = data["frequency_rad_s"] / (2 * math.pi)
    assert ay == pytest.approx(data["disk_margin"], rel=1e-12) and fx == pytest.approx(fc, rel=1e-12)
    assert np.min(curve.get_ydata()) >= data["disk_margin"] * (1 - 1e-9)            # nothing below the margin
    assert np.min(curve.get_ydata()) == pytest.approx(data["disk_margin"], rel=1e-3)  # and the grid reaches it
    note = " ".join(t.get_text() for t in ax_a.texts)
    assert "minimum" in note and f"{data['disk_margin']:.3f}" in note and f"{fc:.3g} Hz" in note
    # the frequency of the minimum is marked on every frequency axis
    assert sum(any(line.get_gid() == "disk-margin-frequency" for line in ax.lines) for ax in fig.axes) == 3
    _assert_inside_figure(fig, [ax.get_legend() for ax in fig.axes if ax.get_legend()] + [fig._suptitle], "legend")
    _assert_no_empty_axes_and_units(fig)


def test_margins_plot_of_a_sampled_loop_with_a_believed_environment_says_so(kept, tmp_path, capsys):
    from forecast_design.cli import main

    assert main(["margins", "--compensator", "lo-dob", "--env", "stiff", "--believed", "locked", "--sampled",
                 "--plot", str(tmp_path / "m.png")]) in (0, 1)
    title = kept["margins"][0]._suptitle.get_text()
    for part in ("environment stiff (observer believes locked)", "LO-DOB", "controller PD", "sampled at 2000 Hz"):
        assert part in title, (part, title)


def test_simulate_plot_says_what_ran_and_draws_the_motion_it_wrote(kept, tmp_path, capsys):
    from forecast_design.cli import main
    from forecast_design.experiment import load_experiment

    src = Path(__file__).resolve().parents[1] / "forecast_design" / "data" / "example_scenario.toml"
    text = src.read_text().replace("duration_s = 8.0", "duration_s = 2.0")
    scenario = tmp_path / "my_scenario.toml"
    scenario.write_text(text)
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "run.toml"), "--plot", str(tmp_path / "r.png")]) == 0
    (fig,) = kept["simulation"]
    title = fig._suptitle.get_text()
    assert "my_scenario" not in title and str(tmp_path) not in title                # what ran, not the file
    for part in ("Fig. 7 (EA-FOB side)", "environment k_e = 100 N m/rad", "controller PD P=5 D=0.1",
                 "compensator EA-FOB at w_q = 10 Hz"):
        assert part in " ".join(title.split()), (part, title)
    lines = {line.get_gid(): (ax, line) for ax in fig.axes for line in ax.lines if line.get_gid()}
    assert set(lines) == {"tau_r", "tau_s", "tau_frc", "tau_frc_hat", "theta", "q", "omega", "v"}
    # the motion panels draw the log it wrote (motor and environment angle) and the truth's velocities
    exp = load_experiment(tmp_path / "run.toml")
    np.testing.assert_array_equal(lines["theta"][1].get_ydata(), exp.signals.theta)
    np.testing.assert_array_equal(lines["q"][1].get_ydata(), exp.signals.q)
    assert lines["theta"][0].get_ylabel() == "angle [rad]" and lines["omega"][0].get_ylabel() == "velocity [rad/s]"
    # the velocity is the angle's derivative (finite differences of the drawn angle, to the encoder's resolution)
    t = lines["theta"][1].get_xdata()
    dtheta = np.gradient(lines["theta"][1].get_ydata(), t)
    omega = lines["omega"][1].get_ydata()
    assert np.corrcoef(dtheta, omega)[0, 1] > 0.95
    _assert_inside_figure(fig, [ax.get_legend() for ax in fig.axes] + [fig._suptitle], "legend/title")
    _assert_no_empty_axes_and_units(fig)


def test_simulate_plot_of_an_uncompensated_run_draws_no_estimate(kept, tmp_path, capsys):
    from forecast_design.cli import main

    src = Path(__file__).resolve().parents[1] / "forecast_design" / "data" / "example_scenario.toml"
    text = src.read_text().replace("duration_s = 8.0", "duration_s = 1.0").replace('kind = "ea-fob"\nw_q_hz = 10.0\nq_family = "butterworth"\nq_order = 2', 'kind = "none"')
    text = text.replace('description = "Fig. 7 (EA-FOB side): LuGre Table 2, PD 5/0.1, EA-FOB 10 Hz, stiff environment"',
                        'description = ""')
    scenario = tmp_path / "plain.toml"
    scenario.write_text(text)
    assert main(["simulate", str(scenario), "--out", str(tmp_path / "run.toml"), "--plot", str(tmp_path / "r.png")]) == 0
    (fig,) = kept["simulation"]
    gids = {line.get_gid() for ax in fig.axes for line in ax.lines}
    assert "tau_frc_hat" not in gids and "tau_frc" in gids
    title = fig._suptitle.get_text()
    assert title.startswith("plain.toml") and "no compensator" in title


def test_readme_shows_every_picture_the_script_draws_and_each_is_small():
    import ast
    import re

    root = Path(__file__).resolve().parents[1]
    readme = (root / "README.md").read_text()
    shown = re.findall(r"!\[[^\]]+\]\((docs/images/[^)]+\.png)\)", readme)
    script = ast.parse((root / "tools" / "readme_images.py").read_text())
    pictures = next(node.value for node in script.body if isinstance(node, ast.Assign)
                    and getattr(node.targets[0], "id", "") == "PICTURES")
    drawn = [f"docs/images/{entry.elts[0].value}" for entry in pictures.elts]
    assert sorted(shown) == sorted(drawn) and len(set(shown)) == len(shown) >= 8
    for rel in shown:
        data = (root / rel).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) < 150_000, rel
        width = int.from_bytes(data[16:20], "big")
        assert 600 <= width <= 1100, (rel, width)
    # the first two commands stay at the top
    assert readme.split("```sh\n", 1)[1].startswith("bash tools/setup.sh && .venv/bin/forecast-design pipeline")


def test_margins_plot_of_an_unstable_loop_marks_no_minimum_and_says_why(kept, tmp_path, capsys):
    # LD-DOB at 10 Hz in the stiff environment is unstable (paper, Fig. 6b: "the disappearance of the dark red disk")
    from forecast_design.cli import main

    assert main(["margins", "--compensator", "ld-dob", "--w-q-hz", "10", "--env", "stiff",
                 "--plot", str(tmp_path / "m.png")]) == 1
    (fig,) = kept["margins"]
    ax_a = next(ax for ax in fig.axes if any(line.get_gid() == "alpha" for line in ax.lines))
    assert not any(line.get_gid() in ("disk-margin", "disk-margin-frequency") for ax in fig.axes for line in ax.lines)
    assert any("UNSTABLE" in t.get_text() for t in ax_a.texts) and "UNSTABLE" in fig._suptitle.get_text()
    _assert_inside_figure(fig, list(ax_a.texts), "note")


def test_diagnosis_and_tradeoff_plots_read_at_a_glance(coulomb_diagnosis, captured, tmp_path):
    from forecast_design.gap.views import diagnosis_views
    from forecast_design.plotting import gap as gp
    from forecast_design.plotting.tuning import figure_tradeoff
    from forecast_design.tuning.tradeoff import cutoff_tradeoff

    v = diagnosis_views(coulomb_diagnosis)
    for plot in (gp.plot_residual_time, gp.plot_residual_spectrum, gp.plot_residual_operating,
                 gp.plot_before_after, gp.plot_replay):
        plot(v, tmp_path / "x.png")
    figs = list(captured) + [figure_tradeoff([cutoff_tradeoff(o, "soft,stiff", points=6)
                                              for o in ("ea-fob", "lo-dob")])]
    for fig in figs:
        titles = [ax.get_title() for ax in fig.axes] + [fig._suptitle.get_text() if fig._suptitle else ""]
        assert any(titles), "a plot without a title"
        legends = fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
        assert legends and all(leg.get_texts() for leg in legends)
        _assert_inside_figure(fig, legends, "legend")
        _assert_no_empty_axes_and_units(fig)


def test_identify_plot_names_the_model_and_keeps_its_legend_inside(tmp_path, capsys, monkeypatch):
    import forecast_design.plotting.friction as pf
    from forecast_design.cli import main

    figs = []
    monkeypatch.setattr(pf, "save_figure", lambda fig, path, **kw: figs.append(fig) or path)
    csv = _axis_csv(tmp_path / "rot.csv", "theta_rad", "tau_m_N_m")
    assert main(["identify", "--csv", str(csv), "--time", "t_s", "--position", "theta_rad", "--force", "tau_m_N_m",
                 "--model", "sfm", "--estimate-inertia", "--plot", str(tmp_path / "f.png")]) == 0
    (fig,) = figs
    assert "model sfm" in fig._suptitle.get_text() and "%" in fig._suptitle.get_text()
    gids = {line.get_gid(): line for ax in fig.axes for line in ax.lines}
    # measured points are drawn above the model's band, so both show where they agree
    assert gids["measured|velocity"].get_zorder() > gids["estimated|velocity"].get_zorder()
    assert sorted(_legend_texts(fig)) == [r"estimated $\hat\tau_{frc}$ (model)", r"measured $\tau_{frc}$"]
    _assert_inside_figure(fig, fig.legends + [fig._suptitle], "legend/title")
    _assert_no_empty_axes_and_units(fig)


def test_simulate_repetitions_plot_overlays_the_runs_in_one_set_of_panels(kept, tmp_path, capsys):
    from forecast_design.cli import main

    src = Path(__file__).resolve().parents[1] / "forecast_design" / "data" / "example_scenario.toml"
    text = src.read_text().replace("duration_s = 8.0", "duration_s = 0.5")
    scenario = tmp_path / "reps.toml"
    scenario.write_text(text + '\n[variability]\nrepetitions = 5\ninitial_angle = "random"\n')
    assert main(["simulate", str(scenario), "--repetitions", "all", "--out", str(tmp_path / "r.toml"),
                 "--plot", str(tmp_path / "r.png")]) == 0
    (fig,) = kept["simulation"]
    assert len(fig.axes) == 4                                         # not one column per repetition
    gids = [line.get_gid() for ax in fig.axes for line in ax.lines]
    assert sum(g.startswith("tau_s|") for g in gids) == 5 and sum(g.startswith("theta|") for g in gids) == 5
    assert "5 repetitions overlaid" in fig._suptitle.get_text()
    labels = _legend_texts(fig)
    assert len(labels) == len(set(labels)) == 8                       # each signal named once
    _assert_inside_figure(fig, [ax.get_legend() for ax in fig.axes] + [fig._suptitle], "legend/title")
    _assert_no_empty_axes_and_units(fig)


def test_fig7_plot_titles_carry_the_reproductions_maes_and_its_legends_fit(kept, tmp_path, capsys):
    from forecast_design.cli import main

    assert main(["reproduce", "fig7", "--json", str(tmp_path / "f7.json"), "--plot", str(tmp_path / "f7.png")]) == 0
    data = json.loads((tmp_path / "f7.json").read_text())
    fig = kept["simulation"][-1]
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == [f"SFM (friction MAE {data['mae_friction_sfm']:.3f} N m)",
                      f"EA-FOB (friction MAE {data['mae_friction_eafob']:.3f} N m)"]
    # the paper's layout: forces over friction, no motion rows; each estimate named after its compensator
    assert len(fig.axes) == 4
    assert {"$\\hat\\tau_{frc}$ SFM", "$\\hat\\tau_{frc}$ EA-FOB"} <= set(_legend_texts(fig))
    _assert_inside_figure(fig, [ax.get_legend() for ax in fig.axes], "legend")
    _assert_no_empty_axes_and_units(fig)
