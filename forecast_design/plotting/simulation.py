"""Plots of simulated runs: torque tracking and friction estimate vs truth (the paper's Fig. 7 layout)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from ..errors import ParameterError
from . import _pyplot, write_figure
from .style import observer_label

__all__ = ["run_title", "plot_simulation", "plot_step_responses", "plot_fig7", "plot_table3"]


def _items(results) -> list[tuple[str, object]]:
    items = list(results.items()) if isinstance(results, Mapping) else [tuple(r) for r in results]
    if not items:
        raise ParameterError("plot needs at least one simulation result", name="results", value=results)
    return items


def run_title(result, *, source: str | None = None) -> str:
    """What a simulated run was: its description, environment, controller and compensator.

    Parameters
    ----------
    result : SimulationResult
        The run (its ``description`` and ``design``; the true environment from its truth).
    source : str, optional
        Used when the run has no description (e.g. the scenario's file name).

    Returns
    -------
    str
        Three lines: the description, ``environment ...``, ``controller ...; compensator ...``.
    """
    env = result.truth.environment
    env_text = "locked output" if env.locked else (f"k_e = {env.k_e:g} N m/rad, J_e = {env.J_e:g} kg m^2, "
                                                   f"d_e = {env.d_e:.3g} N m s/rad")
    ctrl = result.design.controller
    comp = result.design.compensator
    comp_text = ("no compensator" if comp is None or comp.kind == "none" else
                 f"compensator {observer_label(comp.kind)}" + (f" at w_q = {comp.w_q_hz:g} Hz" if comp.is_observer
                                                                else ""))
    head = (result.description or source or "simulated run").strip()
    loop = (f"controller {ctrl.label} at {result.rate_hz:g} Hz" if ctrl is not None else "open loop")
    return f"{head}\nenvironment {env_text}\n{loop}; {comp_text}"


def _draw_run(column, r, sel, *, motion: bool, first: bool, gid: str, alpha: float) -> None:
    """One run's signals into a column of axes (forces, friction[, angle, velocity]); legend labels
    only when ``first`` (overlaid runs share one legend)."""

    def lab(text: str) -> str:
        return text if first else "_nolegend_"

    t = r.t
    top, bottom = column[0], column[1]
    if r.tau_r is not None:
        top.plot(t[sel], r.tau_r[sel], color="0.6", lw=1.5, label=lab(r"$\tau_r$ reference"), gid=f"tau_r{gid}")
    top.plot(t[sel], r.tau_s[sel], color="k", lw=1.0, alpha=alpha, label=lab(r"$\tau_s$ spring (measured)"),
             gid=f"tau_s{gid}")
    bottom.plot(t[sel], r.truth.tau_frc[sel], color="tab:red", lw=1.0, alpha=alpha, label=lab(r"$\tau_{frc}$ true"),
                gid=f"tau_frc{gid}")
    comp = r.design.compensator
    if comp is not None and comp.kind != "none":
        bottom.plot(t[sel], r.tau_frc_hat[sel], color="tab:blue", lw=1.0, ls="--", alpha=alpha,
                    label=lab(r"$\hat\tau_{frc}$ " + observer_label(comp.kind)), gid=f"tau_frc_hat{gid}")
    if motion:
        ang, vel = column[2], column[3]
        ang.plot(t[sel], r.theta[sel], color="tab:purple", lw=1.0, alpha=alpha, label=lab(r"$\theta$ motor"),
                 gid=f"theta{gid}")
        ang.plot(t[sel], r.q[sel], color="tab:olive", lw=1.0, ls="--", alpha=alpha, label=lab(r"$q$ environment"),
                 gid=f"q{gid}")
        vel.plot(t[sel], r.truth.omega[sel], color="tab:purple", lw=0.9, alpha=alpha,
                 label=lab(r"$\dot\theta$ motor (true)"), gid=f"omega{gid}")
        vel.plot(t[sel], r.truth.v[sel], color="tab:olive", lw=0.9, ls="--", alpha=alpha,
                 label=lab(r"$\dot q$ environment (true)"), gid=f"v{gid}")


def plot_simulation(results: Mapping[str, object] | Sequence[tuple[str, object]], path: str | Path | None = None,
                    *, t_range: tuple[float, float] | None = None, title: str | None = None,
                    motion: bool = True, overlay: bool = False):
    """Torque tracking, true and estimated friction, and the motion of simulated runs (Fig. 7 and more).

    Parameters
    ----------
    results : Mapping[str, SimulationResult] or sequence of (label, SimulationResult)
        The runs, e.g. ``{"SFM": r_sfm, "EA-FOB": r_eafob}``.
    path : str or Path, optional
        Write the figure there (PNG by suffix); otherwise just return it.
    t_range : (float, float), optional
        Time window [s].
    title : str, optional
        Figure title, e.g. :func:`run_title` of the run.
    motion : bool
        Add the motion panels: motor angle theta and environment angle q [rad], motor and
        environment velocity [rad/s] (the simulator's truth).
    overlay : bool
        Draw every run into the same panels (repetitions of one scenario) instead of one column
        per run.

    Returns
    -------
    matplotlib.figure.Figure
        The figure. One run (or ``overlay``): forces on the left, motion on the right. Lines carry
        gids ``"tau_r"``, ``"tau_s"``, ``"tau_frc"``, ``"tau_frc_hat"``, ``"theta"``, ``"q"``,
        ``"omega"``, ``"v"`` (overlaid: suffixed ``"|LABEL"``).
    """
    plt = _pyplot()

    import textwrap

    items = _items(results)
    one = overlay or len(items) == 1
    single = motion and one                      # forces on the left, motion on the right
    nrows = 2 if single or not motion else 4
    ncols = 2 if single else (1 if one else len(items))
    width = 5.4 * ncols + 0.4
    fig, grid = plt.subplots(nrows, ncols, sharex=True, squeeze=False,
                             figsize=(width, 2.6 * nrows + (1.0 if title else 0.3)), layout="constrained")
    panels = [list(grid.T.ravel())] if one else [list(grid[:, c]) for c in range(ncols)]
    for k, (label, r) in enumerate(items):
        sel = slice(None) if t_range is None else (r.t >= t_range[0]) & (r.t <= t_range[1])
        column = panels[0 if one else k]
        _draw_run(column, r, sel, motion=motion, first=k == 0 or not overlay,
                  gid=f"|{label}" if overlay else "", alpha=0.55 if overlay and len(items) > 1 else 1.0)
        if not one or not title:
            column[0].set_title(str(label), fontsize="medium")
    for column in panels:
        column[0].set_ylabel("torque [N m]")
        column[1].set_ylabel("friction [N m]")
        if motion:
            column[2].set_ylabel("angle [rad]")
            column[3].set_ylabel("velocity [rad/s]")
        for ax in column:
            if ax in grid[-1]:
                ax.set_xlabel("t [s]")
            ax.grid(True, alpha=0.3)
            ax.legend(loc="best", fontsize=7, framealpha=0.85)
    if title:
        chars = int(width * 13)     # about what a line of the medium font holds per inch of figure
        fig.suptitle("\n".join(textwrap.fill(line, chars) for line in title.splitlines()), fontsize="medium")
    if path is not None:
        write_figure(fig, path, dpi=120)
    return fig


def plot_step_responses(groups: Mapping[str, Sequence[object]], path: str | Path | None = None, *,
                        expected: Mapping[str, object] | None = None):
    """Overlaid spring-torque responses per group (the paper's Figs. 10-12 layout).

    Parameters
    ----------
    groups : Mapping[str, sequence of SimulationResult]
        One panel per key, each with its repetitions overlaid.
    path : str or Path, optional
        Write the figure there.
    expected : Mapping[str, SimulationResult], optional
        Frictionless response per key, drawn red dashed.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    plt = _pyplot()

    if not groups:
        raise ParameterError("plot_step_responses needs at least one group", name="groups", value=groups)
    fig, axes = plt.subplots(1, len(groups), squeeze=False, figsize=(4.5 * len(groups), 3.5))
    for ax, (label, runs) in zip(axes[0], groups.items()):
        for r in runs:
            ax.plot(r.t, r.tau_s, lw=0.8, alpha=0.8)
        if expected is not None and label in expected:
            e = expected[label]
            ax.plot(e.t, e.tau_s, "r--", lw=1.2, label="frictionless")
            ax.legend(loc="lower right", fontsize=8)
        ax.set_title(str(label))
        ax.set_xlabel("t [s]")
        ax.set_ylabel(r"$\tau_s$ [N m]")
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    if path is not None:
        write_figure(fig, path, dpi=120)
    return fig


def plot_fig7(result, path: str | Path | None = None):
    """The paper's Fig. 7 from :func:`forecast_design.reproduce.reproduce_fig7`.

    Left SFM, right EA-FOB; top tau_r (grey) and tau_s (black) [N m], bottom
    the true friction (red) and its estimate (blue dashed) [N m], with each
    run's friction-estimate MAE in the title.

    Parameters
    ----------
    result : Fig7Result
        The reproduction (its ``runs``).
    path : str or Path, optional
        Write the figure there (PNG by suffix).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    runs = getattr(result, "runs", None)
    if not runs or "sfm" not in runs or "ea-fob" not in runs:
        raise ParameterError("plot_fig7 needs a Fig7Result with its runs (from reproduce_fig7)", name="result",
                             value=type(result).__name__)
    fig = plot_simulation({f"SFM (friction MAE {result.mae_friction_sfm:.3f} N m)": runs["sfm"],
                           f"EA-FOB (friction MAE {result.mae_friction_eafob:.3f} N m)": runs["ea-fob"]},
                          motion=False)
    for ax in fig.axes:
        ax.title.set_fontsize(9)
    if path is not None:
        write_figure(fig, path, dpi=120)
    return fig


def plot_table3(result, path: str | Path | None = None):
    """Step responses like the paper's Figs. 10-12, from :func:`forecast_design.reproduce.reproduce_table3`.

    One row per compensator (PD, PD + SFM, PD + EA-FOB), one column per
    environment; the ten responses tau_s [N m] overlaid, the frictionless
    PD response red dashed, each panel titled with its x-corr [-] and MAE [N m].

    Parameters
    ----------
    result : Table3Result
        The reproduction (its ``responses`` and ``expected``).
    path : str or Path, optional
        Write the figure there.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    plt = _pyplot()

    responses = getattr(result, "responses", None)
    if not responses:
        raise ParameterError("plot_table3 needs a Table3Result with its responses (from reproduce_table3)",
                             name="result", value=type(result).__name__)
    envs = list(dict.fromkeys(env for env, _ in responses))
    kinds = list(dict.fromkeys(kind for _, kind in responses))
    names = {"none": "PD", "sfm": "PD + SFM", "ea-fob": "PD + EA-FOB"}
    fig, axes = plt.subplots(len(kinds), len(envs), sharex=True, squeeze=False,
                             figsize=(4.8 * len(envs), 2.6 * len(kinds)))
    for j, env in enumerate(envs):
        for i, kind in enumerate(kinds):
            ax = axes[i, j]
            for r in responses[(env, kind)]:
                ax.plot(r.t, r.tau_s, lw=0.8, alpha=0.8)
            e = result.expected.get(env)
            if e is not None:
                ax.plot(e.t, e.tau_s, "r--", lw=1.2, label="frictionless PD")
                ax.legend(loc="lower right", fontsize=7)
            row = result.row(env, kind)
            ax.set_title(f"{env}: {names.get(kind, kind)}  x-corr {row.xcorr:.2f}, MAE {row.mae:.3f} N m",
                         fontsize=9)
            ax.set_ylabel(r"$\tau_s$ [N m]")
            ax.grid(True, alpha=0.3)
        axes[-1, j].set_xlabel("t [s]")
    fig.tight_layout()
    if path is not None:
        write_figure(fig, path, dpi=120)
    return fig
