"""The benchmark's Markdown report: what ran, the set-level table, per-environment tables, plots."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..fileio import atomic_write
from .metrics import INDICATOR_DEFINITIONS, METRICS

__all__ = ["markdown_report", "write_report"]

_SHORT = {"repeatability": "x-corr", "mae_N_m": "MAE [N m]", "rise_time_s": "rise [s]",
          "overshoot_percent": "overshoot [%]", "settling_time_s": "settling [s]",
          "steady_state_error_N_m": "ss error [N m]", "bandwidth_hz": "bandwidth [Hz]", "disk_margin": "disk margin",
          "stable": "stable", "unsettled_runs": "unsettled runs", "excluded_cells": "unstable cells left out"}


def _flag(x: Any) -> str:
    return "-" if x is None else ("yes" if x else "**NO**")


def _fmt(x: Any) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


def _table(rows: Sequence[Mapping[str, Any]], keys: Sequence[str], metrics: Sequence[str]) -> list[str]:
    head = [*keys, *(_SHORT.get(m, m) for m in metrics)]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        out.append("| " + " | ".join(_flag(r.get(k)) if k == "stable" else _fmt(r.get(k))
                                     for k in (*keys, *metrics)) + " |")
    return out


def _flags(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The report's warnings: unstable cells (left out of the set rows) and runs that did not settle."""
    envs = [r for r in rows if r["kind"] == "environment" and r["statistic"] == "mean"]
    bad = [r for r in envs if r.get("stable") is False]
    unsettled = sum(r.get("unsettled_runs") or 0 for r in envs)
    steps = sum(1 for r in rows if r["kind"] == "run" and r.get("settled") is not None)
    out = []
    if bad:
        out += [f"**Warning: {len(bad)} unstable cell(s)** (sampled loop unstable or a run diverged), flagged "
                "`stable = false` and left out of the set rows (`excluded_cells`):", "",
                *(f"- {r['controller']} + {r['compensator']} in {r['environment']} ({r['reference']}), disk margin "
                  f"{_fmt(r.get('disk_margin'))}" for r in bad), ""]
    if steps:
        out += [f"{unsettled} of {steps} step runs did not settle (no settling time; `settled = false`, counted in "
                "`unsettled_runs`).", ""]
    return out


def markdown_report(rows: Sequence[Mapping[str, Any]], spec: Mapping[str, Any], info: Mapping[str, Any],
                    plots: Mapping[str, str] | None = None) -> str:
    """The report text.

    Parameters
    ----------
    rows : sequence of dict
        The tidy rows (:func:`~.aggregate.result_rows`).
    spec : Mapping
        :meth:`~.spec.BenchmarkSpec.to_mapping`.
    info : Mapping
        How it ran (:func:`~.runner.run_benchmark`).
    plots : Mapping, optional
        Caption -> relative path of each plot to link.

    Returns
    -------
    str
        Markdown.
    """
    used = [m for m in METRICS if any(isinstance(r.get(m), float) and math.isfinite(r[m]) for r in rows)]
    lines = ["# Force-control benchmark over an environment set", "",
             f"Controllers {', '.join(spec['controllers'])}; compensators {', '.join(spec['compensators'])}; "
             f"{len(spec['environments'])} environments; references {', '.join(spec['references'])}; "
             + (f"recorded runs from `{spec['runs']}` ({info.get('runs', 0)} experiments, grouped into cells by "
                f"their TOML's environment, controller, compensator and recorded reference). "
                if spec.get("runs") else
                f"{spec['repetitions']} repetitions per cell, each from its own random motor angle (seed "
                f"{spec['seed']}). ")
             + f"Ran {info.get('computed', 0)} cells, reused {info.get('reused', 0)} finished ones "
             f"({info.get('executor', 'local')}, {info.get('workers', 1)} workers).", "",
             "Indicators (A = the reference step; percentages and the settling band are relative to |A|, so "
             "one run that ends near zero cannot dominate a set):", "",
             *(f"- {name}: {text}" for name, text in INDICATOR_DEFINITIONS.items()), "",
             *_flags(rows),
             *([" ".join(f"Controller `{label}` is {model}." for label, model in spec["controller_models"].items()
                         if model.startswith("code")), ""]
               if any(m.startswith("code") for m in spec.get("controller_models", {}).values()) else []),
             "Statistics: mean over the repetitions (per environment) or over the environments' means (set); "
             "se = that mean's standard error over the draw of initial angles (std/sqrt(n) of the runs, the "
             "jackknife for the repeatability; over the set sqrt(sum se^2)/n); best and worst.", "",
             "## Over the set (mean, se, best, worst over the environments)", ""]
    sets = [r for r in rows if r["kind"] == "set"]
    lines += _table(sets, ("controller", "compensator", "reference", "statistic"),
                    ["excluded_cells", "unsettled_runs", *used])
    lines += ["", "## Per environment (means over the repetitions; stable **NO**: flagged, not in the set rows)", ""]
    envs = [r for r in rows if r["kind"] == "environment" and r["statistic"] == "mean"]
    lines += _table(envs, ("controller", "compensator", "reference", "environment", "k_e"),
                    ["stable", "unsettled_runs", *used])
    if plots:
        lines += ["", "## Plots", ""]
        for caption, rel in plots.items():
            lines += [f"### {caption}", "", f"![{caption}]({rel})", ""]
    lines += ["", "Files: `results.parquet` / `results.csv` (one row per run, per environment statistic and per "
              "set statistic; column `kind`), `traces.parquet` (every run's t, tau_r, tau_s and the expected "
              "tau_s at " + (f"every {info['trace_step']}th sample of " if info.get("trace_step", 1) != 1 else "")
              + "the control rate: the indicators recompute from it), `summary.json`, `cells/` (per-cell results "
              "keyed by their inputs: a rerun skips them)."]
    return "\n".join(lines) + "\n"


def write_report(text: str, out: str | os.PathLike[str]) -> Path:
    """Write ``report.md`` atomically.

    Parameters
    ----------
    text : str
        :func:`markdown_report`.
    out : path
        The result folder.
    """
    return atomic_write(Path(out) / "report.md", text)
