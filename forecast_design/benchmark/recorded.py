"""Benchmark recorded runs: a folder of experiments (real or simulated) grouped into cells by their TOML.

``forecast-design benchmark --runs DIR`` in library form. Every ``*.toml`` under the folder
whose ``format`` is the experiment format's (``forecast-experiment/1``) is one run; other TOML
files (scenarios, environment sets) are left alone. Runs are grouped into cells by what their
TOML declares (``[environment]``, ``[controller]``, ``[compensator]``) and by the reference
they recorded (``tau_r``), so a cell holds the repetitions of one benchmark condition, and
each cell gets the indicators of :mod:`.metrics`, exactly as a simulated cell does
(:func:`~.runner.run_cell`):

* ``repeatability``: mean pairwise zero-lag cross-correlation of the runs' ``tau_s`` (Table 3),
  per run its mean correlation with the others; the runs of a cell are cut to the shortest;
* ``mae_N_m``: against the frictionless expected response, the recorded controller on the
  TOML's nominal plant with d_m = 0, no compensator, no noise, driven by the recorded
  ``tau_r`` (the red dashed lines of Figs. 10-12);
* rise time, overshoot, settling time and steady-state error when ``tau_r`` is a step
  (two levels, one jump); NaN otherwise (the bandwidth needs the chirp's band, which an
  experiment does not record: NaN);
* ``disk_margin``: of the declared loop and ``stable`` (:func:`~.metrics.sampled_loop_margin`).

Open-loop runs (no ``[controller]`` or no ``tau_r``) are skipped and counted. A cell's key
hashes its files' bytes, so reruns with ``--out`` reuse unchanged cells.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..controllers import DERIVATIVE_ON, with_derivative_on
from ..environments import resolve_environments
from ..errors import ExperimentFormatError, ParameterError
from ..executor import Executor, LocalExecutor
from ..experiment import load_experiment
from ..experiment_io import FORMAT, parse_toml, read_toml
from ..params import Compensator
from ..limits import limit_of
from .metrics import pairwise_xcorr, sampled_loop_margin, repeatability_per_run, step_metrics
from .runner import _STEP_KEYS, CellResult, _expected_response, _run_metrics, cell_stable
from .spec import compensator_label, controller_label

__all__ = ["find_runs", "group_runs", "recorded_cell", "run_recorded", "step_of"]


def find_runs(folder: str | os.PathLike[str]) -> tuple[list[Path], list[str]]:
    """The experiment TOML files under ``folder`` (recursively, sorted by path), and those that cannot be read.

    Every entry named ``*.toml`` is looked at (symlinked folders are followed once, loops are not):
    a readable TOML whose ``format`` is ``forecast-experiment/1`` is a run; a readable TOML of
    another format (a scenario, an environment set) is left alone; anything else named ``*.toml``
    (binary or truncated text, a directory, a FIFO or device, a dangling link or a link loop) is
    reported, never dropped in silence.

    Parameters
    ----------
    folder : path
        A folder of experiments (``RUN.toml`` + ``RUN.csv`` pairs).

    Returns
    -------
    runs : list of Path
        Files whose ``format`` is ``forecast-experiment/1``.
    unreadable : list of str
        ``"PATH: why"`` of each ``*.toml`` entry that cannot be read.

    Raises
    ------
    ParameterError
        When ``folder`` is not a folder.
    """
    root = Path(folder)
    if not root.is_dir():
        raise ParameterError(f"--runs {os.fspath(folder)}: not a folder of experiments", name="runs",
                             value=os.fspath(folder))
    candidates: list[Path] = []
    unreadable: list[str] = []
    visited: set[tuple[int, int]] = set()
    for here, dirs, files in os.walk(root, followlinks=True):
        info = os.stat(here)
        if (info.st_dev, info.st_ino) in visited:        # a symlinked folder seen before: a loop
            dirs[:] = []
            continue
        visited.add((info.st_dev, info.st_ino))
        dirs.sort()
        for name in dirs:
            if name.endswith(".toml"):
                unreadable.append(f"{Path(here) / name}: a directory, not an experiment file")
        candidates += [Path(here) / name for name in files if name.endswith(".toml")]
    out = []
    for path in sorted(candidates):
        try:
            doc, _ = read_toml(path)
        except ExperimentFormatError as exc:
            unreadable.append(f"{path}: cannot be read: {str(exc).removeprefix(f'{path}: ')}")
            continue
        if doc.get("format") == FORMAT:
            out.append(path)
    return out, sorted(unreadable)


def step_of(tau_r: np.ndarray, rate_hz: float) -> tuple[float, float, float] | None:
    """``(amplitude, t0, offset)`` when ``tau_r`` is one step (two levels, one jump), else None.

    A constant non-zero ``tau_r`` is a step at t = 0 from 0 (the reference before the run).

    Parameters
    ----------
    tau_r : ndarray
        Recorded reference [N m].
    rate_hz : float
        Sample rate [Hz]; ``t0`` is the time of the first sample at the new level [s].
    """
    r = np.asarray(tau_r, dtype=float)
    jumps = np.nonzero(np.diff(r) != 0.0)[0]
    if r.size >= 10 and jumps.size == 0 and r[0] != 0.0:
        return float(r[0]), 0.0, 0.0          # a step at t = 0 from the reference 0 before the run
    if r.size < 10 or jumps.size != 1:
        return None
    i = int(jumps[0]) + 1
    return float(r[i] - r[0]), i / float(rate_hz), float(r[0])


def _reference_label(tau_r: np.ndarray, rate_hz: float) -> str:
    dur = tau_r.size / rate_hz
    step = step_of(tau_r, rate_hz)
    if step is not None:
        amp, t0, offset = step
        extra = "" if t0 == 0.0 and offset == 0.0 else f" (t0 {t0:g} s, offset {offset:g} N m)"
        return f"step:{amp:g}:{dur:g}{extra}"
    digest = hashlib.sha256(np.round(tau_r, 9).tobytes()).hexdigest()[:8]
    return f"recorded:{digest}:{dur:g}"


def group_runs(paths: list[Path]) -> tuple[list[tuple[dict[str, str], tuple[Path, ...]]], list[str]]:
    """Group experiments into cells by environment, controller, compensator and recorded reference.

    Parameters
    ----------
    paths : list of Path
        Experiment TOML files (:func:`find_runs`).

    Returns
    -------
    cells : list of (labels, paths)
        ``labels``: ``controller``, ``compensator``, ``environment``, ``reference``; in order of
        first appearance.
    skipped : list of str
        ``"PATH: why"`` of each run that cannot be benchmarked (open loop, no ``tau_r``).
    """
    groups: dict[str, list[Path]] = {}
    labels: dict[str, dict[str, str]] = {}
    skipped = []
    for path in paths:
        exp = _load_run(path)
        design, tau_r = exp.design, exp.signals.tau_r
        if design.controller is None or tau_r is None:
            skipped.append(f"{path}: open loop (no [controller] or no tau_r column)")
            continue
        comp = design.compensator or Compensator(kind="none")
        lab = {"controller": controller_label(design.controller), "compensator": compensator_label(comp),
               "environment": resolve_environments(design.environment).names[0],
               "reference": _reference_label(np.asarray(tau_r), exp.rate_hz)}
        key = json.dumps([design.testbed.to_mapping(), design.environment.to_mapping(),
                          design.controller.to_mapping(), comp.to_mapping(), exp.rate_hz, lab["reference"]],
                         sort_keys=True, default=str)
        groups.setdefault(key, []).append(path)
        labels.setdefault(key, lab)
    return [(labels[k], tuple(v)) for k, v in groups.items()], skipped


def _load_run(path: Path):
    """One recorded run, at most ``log_samples_benchmark`` samples (checked before its CSV is parsed)."""
    return load_experiment(path, max_samples=limit_of("log_samples_benchmark"), reader="benchmark --runs")


def _cell_key(paths: tuple[Path, ...]) -> str:
    h = hashlib.sha256(b"recorded-cell/2")
    for p in paths:
        exp_toml = Path(p)
        h.update(exp_toml.name.encode())
        h.update(exp_toml.read_bytes())
        doc, _ = read_toml(exp_toml)
        _, _, _, data = parse_toml(doc, str(exp_toml))
        h.update((exp_toml.parent / data).read_bytes())
    return h.hexdigest()[:20]


def recorded_cell(task: tuple) -> CellResult:
    """The indicators of one group of recorded runs (the task of :func:`run_recorded`).

    Parameters
    ----------
    task : tuple
        ``(key, labels, paths[, derivative_on])`` from :func:`group_runs` (``derivative_on``: where
        a recorded PD/PID takes its derivative, overriding its ``[controller]`` table for the expected
        response; default None: the table's).

    Returns
    -------
    CellResult
        As :func:`~.runner.run_cell` gives for a simulated cell; ``initial_angle_rad`` is NaN
        (a recording does not know it).
    """
    key, labels, paths, *rest = task
    derivative_on = rest[0] if rest else None
    exps = [_load_run(p) for p in paths]
    n = min(e.n_samples for e in exps)
    rate = exps[0].rate_hz
    design = exps[0].design
    if derivative_on is not None:
        design = dataclasses.replace(design, controller=with_derivative_on(design.controller, derivative_on))
    comp = design.compensator or Compensator(kind="none")
    tau = np.array([np.asarray(e.signals.tau_s[:n], dtype=float) for e in exps])
    tau_r = np.asarray(exps[0].signals.tau_r[:n], dtype=float)
    t = np.arange(n) / rate
    if design.controller.has_equations:
        sim = _expected_response(design, tau_r, n / rate, rate)
        expected, dm = sim.tau_s, sampled_loop_margin(design, comp, rate)
        margin, diverged = float(dm.alpha), sim.diverged_at_s is not None
    else:   # an 'other' controller: no equations, so no expected response nor margin; the rest goes on
        expected = np.full(n, math.nan)
        margin, dm, diverged = math.nan, None, False
    step = step_of(tau_r, rate)
    per_run = repeatability_per_run(tau) if len(exps) >= 2 else np.full(1, math.nan)
    rows = []
    for i, y in enumerate(tau):
        m = _run_metrics(y, expected, per_run[i], margin)
        if step is not None:
            sm = step_metrics(t, y - step[2], amplitude=step[0], t0=step[1])
            m.update({k: sm[k] for k in _STEP_KEYS})
        rows.append({"repetition": i, "initial_angle_rad": math.nan, "source": str(paths[i]), **m})
    return CellResult(key=key, labels=labels, environment=design.environment.to_mapping(), runs=tuple(rows),
                      repeatability=pairwise_xcorr(tau) if len(exps) >= 2 else math.nan, disk_margin=margin,
                      t=t, tau_s=tau, expected=np.asarray(expected), tau_r=tau_r, stable=cell_stable(dm, diverged))


def run_recorded(folder: str | os.PathLike[str], *, out: str | os.PathLike[str] | None = None,
                 executor: Executor | None = None, progress: Callable[[int, int], None] | None = None,
                 derivative_on: str | None = None) -> tuple[list[CellResult], dict[str, Any]]:
    """Benchmark the recorded runs of a folder of experiments.

    Parameters
    ----------
    folder : path
        The experiments (searched recursively).
    out : path, optional
        Result folder; finished cells are read from and written to ``out/cells``.
    executor : Executor, optional
        Where cells are computed; default: this process.
    progress : callable, optional
        ``progress(done, total)`` over the cells to compute.
    derivative_on : str or None
        Where the recorded PD/PID controllers take their derivative, overriding their
        ``[controller]`` tables (:data:`~forecast_design.controllers.DERIVATIVE_ON`; None: what the
        tables say): sets the frictionless expected response the MAE is measured against.

    Returns
    -------
    cells : list of CellResult
        One per group, in order of first appearance.
    info : dict
        ``runs`` (experiments found), ``cells``, ``computed``, ``reused``, ``skipped`` (why),
        ``unreadable`` (``*.toml`` entries that cannot be read, and why: :func:`find_runs`),
        ``single_run_cells`` (labels of cells with one run: no repeatability) and the executor.

    Raises
    ------
    ParameterError
        A missing folder, or a folder without a closed-loop experiment.
    ExperimentFormatError
        An experiment that does not load (one line naming the file and key or CSV line).
    """
    paths, unreadable = find_runs(folder)
    groups, skipped = group_runs(paths)
    if not groups:
        raise ParameterError(f"--runs {os.fspath(folder)}: no closed-loop experiment (forecast-experiment/1 TOML with "
                             f"[controller] and a tau_r column) found among {len(paths)} experiment(s)",
                             name="runs", value=os.fspath(folder))
    if derivative_on is not None and derivative_on not in DERIVATIVE_ON:
        raise ParameterError(f"--derivative-on must be one of {', '.join(DERIVATIVE_ON)}, got {derivative_on!r}",
                             name="derivative_on", value=derivative_on)
    keys = [_cell_key(p) + ("" if derivative_on is None else f"-{derivative_on}") for _, p in groups]
    store = None if out is None else Path(out) / "cells"
    found: dict[str, CellResult] = {}
    if store is not None:
        for k in keys:
            stored = CellResult.load(store, k)
            if stored is not None:
                found[k] = stored.thinned()
    todo = [(k, lab, p, derivative_on) for k, (lab, p) in zip(keys, groups) if k not in found]
    ex = executor or LocalExecutor(1)
    for res in ex.map(recorded_cell, todo, progress=progress):
        if store is not None:
            res.save(store)           # full rate on disk, a thinned copy in memory
        found[res.key] = res.thinned()
    info = {"runs": len(paths), "cells": len(groups), "computed": len(todo), "reused": len(groups) - len(todo),
            "skipped": skipped, "unreadable": unreadable,
            "single_run_cells": [dict(lab) for lab, p in groups if len(p) < 2],
            **ex.describe()}
    return [found[k] for k in keys], info
