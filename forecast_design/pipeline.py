"""The main job: derive -> tune -> simulate -> identify -> diagnose -> export, into a report folder."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .fileio import atomic_write

__all__ = ["PipelineResult", "run_pipeline"]


@dataclass(frozen=True, slots=True)
class PipelineResult:
    """What the pipeline wrote.

    Attributes
    ----------
    out_dir : Path
        The report folder.
    steps : dict
        Per step: ``{"seconds": float, "files": [...], "summary": {...}}``.
    """

    out_dir: Path
    steps: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {"out_dir": str(self.out_dir), "steps": self.steps}


def _dump(path: Path, obj: Any) -> None:
    atomic_write(path, json.dumps(obj, indent=2, allow_nan=True) + "\n")


def _derive(out: Path) -> dict[str, Any]:
    from .params import Design
    from .plotting.bode import plot_bode
    from .symbolic import transfer_functions

    tfs = {name: transfer_functions(Design.nominal(name)) for name in ("soft", "stiff", "exp-soft", "locked")}
    _dump(out / "tf.json", {name: t.to_mapping() for name, t in tfs.items()})
    plot_bode([(f"P ({name})", t.P.tf) for name, t in tfs.items()]
              + [(f"P_n^{key} (stiff)", getattr(tfs["stiff"], key).tf) for key in ("EA", "LO", "LD")],
              out / "bode.png", title="Force plant P in four environments and the nominal plants")
    stiff_poles = ", ".join(f"{abs(p):.1f}" for p in sorted(tfs["stiff"].P.tf.poles(), key=abs)[::2])
    return {"files": ["tf.json", "bode.png"],
            "text": ("P(s) = tau_s/tau_m derived from the SEA equations in four environments (unit DC gain in "
                     f"each); in the stiff environment its pole pairs lie at |s| = {stiff_poles} rad/s. "
                     "The Bode plot overlays the nominal plants of the three observers."),
            "summary": {name: {"dc_gain": t.P.tf.dcgain(), "order": len(t.P.tf.den) - 1} for name, t in tfs.items()}}


def _tune(out: Path) -> dict[str, Any]:
    from .reproduce import fig6_table
    from .plotting.margins import plot_fig6
    from .tuning import tune_q

    rows = fig6_table()
    _dump(out / "fig6.json", [r.to_mapping() for r in rows])
    plot_fig6(rows, out / "fig6.png")
    tuned = {obs: tune_q(obs, "soft,stiff", min_ratio=0.9, band_hz=(0.5, 30.0)).to_mapping()
             for obs in ("ea-fob", "lo-dob", "ld-dob")}
    _dump(out / "tune_q.json", tuned)
    unstable = [f"{r.observer} at {r.w_q_hz:g} Hz in {r.environment}" for r in rows if not r.stable]
    plant = {r.environment: r.disk_margin for r in rows if r.observer == "none"}
    ea_dev = max(abs(r.disk_margin / plant[r.environment] - 1) for r in rows if r.observer == "ea-fob")
    return {"files": ["fig6.json", "fig6.png", "tune_q.json"],
            "text": (f"Disk margins of Fig. 6: the EA-FOB stays within {100 * ea_dev:.1f} % of the plant's own margin; "
                     f"unstable: {', '.join(unstable) or 'none'}. Largest Q cutoff keeping 90 % of the plant's "
                     "disk margin in both environments (0.5-30 Hz): "
                     + ", ".join(f"{obs} {r['w_q_hz']:.3g} Hz" + (f" (on the {r['at_bound']})" if r["at_bound"] else "")
                                 for obs, r in tuned.items()) + "."),
            # a cutoff on the band's end is the band's, not the tuning's answer: said with it
            "summary": {obs: {key: r[key] for key in ("w_q_hz", "at_bound", "worst_ratio", "feasible")}
                        for obs, r in tuned.items()}}


def _simulate(out: Path) -> dict[str, Any]:
    from .plotting.simulation import plot_fig7
    from .reproduce import reproduce_fig7

    fig7 = reproduce_fig7()
    _dump(out / "fig7.json", fig7.to_mapping())
    plot_fig7(fig7, out / "fig7.png")
    return {"files": ["fig7.json", "fig7.png"],
            "text": (f"LuGre friction (Table 2), PD 5/0.1, 1 N m square wave: friction-estimate MAE "
                     f"{fig7.mae_friction_sfm:.3f} N m with the SFM and {fig7.mae_friction_eafob:.3f} N m with the "
                     "EA-FOB at 10 Hz (paper: 0.35 and 0.02). fig7.json explains the open choices."),
            "summary": {"mae_friction_sfm": fig7.mae_friction_sfm, "mae_friction_eafob": fig7.mae_friction_eafob}}


def _identification_log(seed: int = 5):
    """A simulated Forecast run with angle-dependent friction, turning through several revolutions."""
    from .effects import PositionFriction
    from .params import Design
    from .simulation import simulate
    from .simulation.references import Multisine

    truth = PositionFriction(F_c=0.4, a=(0.05, 0.02), b=(0.03, 0.0))
    run = simulate(Design.nominal("link-only"), effects=[truth], duration_s=20.0, closed_loop=False, seed=seed,
                   reference=Multisine(amplitudes=(1.5, 0.3), frequencies_hz=(0.2, 3.0), offset=0.8),
                   description="open-loop multisine, angle-dependent friction (identification run)")
    return truth, run


def _identify(out: Path) -> dict[str, Any]:
    from .experiment import save_experiment
    from .friction import fit_data, identify
    from .plotting.friction import plot_friction_fit

    truth, run = _identification_log()
    log = run.to_experiment()
    save_experiment(log, out / "identification_run.toml")
    fit = identify(log, "position-friction", harmonics=2)
    _dump(out / "identify.json", fit.to_mapping())
    plot_friction_fit(fit, fit_data(fit, log), out / "identify.png")
    params = fit.to_mapping()["params"]
    return {"files": ["identification_run.toml", "identify.json", "identify.png"],
            "text": (f"Position-dependent friction identified from a 20 s simulated open-loop log: mean level "
                     f"{params['coulomb']:.3f} N m (true {truth.F_c}), first harmonics {params['coulomb_sin1']:.3f}/"
                     f"{params['coulomb_cos1']:.3f} N m (true {truth.a[0]}/{truth.b[0]}), viscous "
                     f"{params['viscous']:.3f} N m s/rad (nominal d_m 0.3); hold-out fit "
                     f"{fit.to_mapping()['fit_percent']['holdout']:.1f} %."),
            "summary": {"params": fit.to_mapping()["params"], "truth": truth.to_mapping(),
                        "fit_percent": fit.to_mapping()["fit_percent"]}}


def _diagnose(out: Path) -> dict[str, Any]:
    from .effects import Cogging
    from .experiment import load_experiment, save_experiment
    from .gap import diagnose
    from .reporting import write_report
    from .params import Design
    from .simulation import simulate
    from .simulation.references import Multisine

    # A log whose TOML holds only the nominal model while the "hardware" cogs: the effect is withheld.
    run = simulate(Design.nominal("link-only"), effects=[Cogging(a=(0.08, 0.0, 0.03), b=(0.0, 0.04, 0.0))],
                   duration_s=20.0, closed_loop=False, seed=11,
                   reference=Multisine(amplitudes=(1.2, 0.3), frequencies_hz=(0.15, 2.5), offset=0.7))
    # Diagnose the file as a user would, so the report names it.
    log = load_experiment(save_experiment(run.to_experiment(), out / "diagnose_run.toml"))
    diagnosis = diagnose(log)
    write_report(diagnosis, log, out / "diagnosis")
    verdict = diagnosis.to_mapping()["verdict"]
    return {"files": ["diagnose_run.toml", "diagnosis/report.md", "diagnosis/diagnosis.json"],
            "text": (f"A log whose hardware cogs (withheld from its TOML) is diagnosed blind: verdict "
                     f"'{verdict['effect']}', held-out gap {verdict['gap_before']:.4g} -> {verdict['gap_after']:.4g} "
                     f"N m ({100 * verdict['reduction']:.0f} % smaller). The full report with plots is in "
                     "diagnosis/report.md."),
            "summary": {"withheld_effect": "cogging", "verdict": verdict["effect"],
                        "reduction": verdict["reduction"]}}


def _export(out: Path) -> dict[str, Any]:
    from .export.c import export_controller
    from .tuning import tune_q

    # the cutoff is tuned for the environment set the controller is exported for (not soft/stiff's)
    env = "exp-soft"
    tuning = tune_q("ea-fob", env, min_ratio=0.9, band_hz=(0.5, 30.0))
    tuned = tuning.w_q_hz
    _dump(out / "export_tune_q.json", tuning.to_mapping())
    result = export_controller(out_dir=out / "export", controller="pd:5:0.1", compensator="ea-fob",
                               env=env, w_q_hz=tuned)
    return {"files": ["export/fd_controller.h", "export/fd_controller.c", "export_tune_q.json"],
            "text": (f"PD 5/0.1 + EA-FOB at {tuned:.3g} Hz, the cutoff tuned for the {env} environment it is "
                     f"exported for (worst disk-margin ratio {tuning.worst_ratio:.3f} >= 0.9 of the plant's own), "
                     "Tustin at 2 kHz, emitted as C99 (float32 delta-operator sections); "
                     "`forecast-design export --check-arm` runs it on an emulated Cortex-M4."),
            "summary": {"w_q_hz": tuned, "environment": env, "worst_ratio": tuning.worst_ratio,
                        "sha256": result.digest}}


_STEPS: list[tuple[str, str, Callable[[Path], dict[str, Any]]]] = [
    ("derive", "Symbolic transfer functions (eqs. 2-8)", _derive),
    ("tune", "Disk margins (Fig. 6) and Q-cutoff tuning", _tune),
    ("simulate", "Virtual testbed: SFM vs EA-FOB friction estimation (Fig. 7)", _simulate),
    ("identify", "Friction identification from a simulated Forecast log", _identify),
    ("diagnose", "Sim-to-real gap of a log with a withheld effect (cogging)", _diagnose),
    ("export", "C99 export of PD + EA-FOB at the tuned cutoff", _export),
]


def run_pipeline(out_dir: str | Path = "report", *, progress: Callable[[str], None] | None = None) -> PipelineResult:
    """Run every step on the bundled defaults and write a Markdown report with plots.

    Parameters
    ----------
    out_dir : str or Path
        Report folder (created).
    progress : callable, optional
        Called with each step's name before it runs.

    Returns
    -------
    PipelineResult
        Files and summaries per step; ``out_dir/index.md`` links them all.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = PipelineResult(out)
    lines = ["# forecast_design report", ""]
    for name, title, step in _STEPS:
        if progress:
            progress(name)
        start = time.perf_counter()
        info = step(out)
        info["seconds"] = round(time.perf_counter() - start, 3)
        result.steps[name] = info
        lines += [f"## {name}: {title}", "", info.pop("text", ""), "", f"({info['seconds']} s)", ""]
        for f in info["files"]:
            lines.append(f"![{f}]({f})" if f.endswith(".png") else f"- [{f}]({f})")
        lines += ["", "```json", json.dumps(info["summary"], indent=2), "```", ""]
    atomic_write(out / "index.md", "\n".join(lines))
    _dump(out / "summary.json", result.to_mapping())
    return result
