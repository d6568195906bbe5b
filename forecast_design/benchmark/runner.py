"""Run a benchmark: every cell on the virtual testbed through the executor, results cached by their inputs.

A cell (one controller, compensator, environment and reference) is one coarse task:
its ``repetitions`` runs (one :func:`~forecast_design.simulation.batch.simulate_batch` call)
plus the frictionless expected response, simulated where the executor puts it
(:func:`run_cell`, deterministic by seed: repetition ``i`` starts from the
``i``-th initial angle of :class:`~forecast_design.simulation.scenario.Variability`
and draws process noise with seed ``seed + 1 + i``, the same in every cell, so cells
differ only by what is benchmarked). Finished cells are stored as
``OUT/cells/<key>.json`` (metrics) and ``<key>.npz`` (the traces at the full control rate, so every
indicator can be recomputed from them); the key hashes every input
(:meth:`~.spec.BenchmarkSpec.cell_key`), so a rerun computes only missing or changed cells.
:func:`run_benchmark` returns the cells with every ``trace_step``-th sample of their traces
(at most :data:`TRACE_POINTS` per trace, for plots: the memory of a large benchmark stays bounded);
:func:`write_traces` writes the full-rate traces of the stored cells as one Parquet file.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import multiprocessing
import os
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..errors import ParameterError
from ..limits import check_limit
from ..executor import Executor, LocalExecutor
from ..fileio import atomic_open, atomic_write
from ..params import Compensator, Design
from ..reproduce import identify_extended_sfm
from ..simulation import Chirp, simulate
from ..simulation.batch import BatchRun, simulate_batch
from ..simulation.plant import stable_substeps
from ..simulation.scenario import Variability
from .metrics import METRICS, pairwise_xcorr, repeatability_per_run, sampled_loop_margin, step_metrics, \
    tracking_bandwidth_hz
from .spec import BenchmarkSpec, Cell

__all__ = ["CellResult", "run_cell", "run_benchmark", "write_traces", "TRACE_POINTS", "TRACE_COLUMNS"]

#: Samples at most per trace that :func:`run_benchmark` keeps in memory for the plots [-]
#: (the files hold every sample).
TRACE_POINTS = 1000


@dataclasses.dataclass(frozen=True, slots=True)
class CellResult:
    """Metrics and traces of one cell.

    Attributes
    ----------
    key : str
        Hash of the cell's inputs.
    labels : dict
        ``controller``, ``compensator``, ``environment``, ``reference``.
    environment : dict
        The environment's parameters (``J_e``, ``d_e``, ``k_e``, ``J_l``, ``d_l``, ``locked``).
    runs : tuple of dict
        Per repetition: ``repetition``, ``initial_angle_rad`` and the :data:`~.metrics.METRICS`.
    repeatability : float
        Mean pairwise cross-correlation of the repetitions [-].
    disk_margin : float
        The loop's disk margin [-].
    t, tau_s, expected, tau_r : ndarray
        Traces: times [s], tau_s per repetition (rows), the frictionless expected response and
        the reference [N m]; every ``trace_step``-th sample of the run.
    stable : bool or None
        The cell's sampled loop is nominally stable and nothing diverged (None: no linear model
        and nothing diverged).
    trace_step : int
        Samples of the run per sample of the traces held here [-] (1: full rate).
    """

    key: str
    labels: Mapping[str, str]
    environment: Mapping[str, Any]
    runs: tuple
    repeatability: float
    disk_margin: float
    t: np.ndarray
    tau_s: np.ndarray
    expected: np.ndarray
    tau_r: np.ndarray
    stable: bool | None = None
    trace_step: int = 1
    passive: bool | None = None

    def thinned(self, points: int = TRACE_POINTS) -> "CellResult":
        """This cell with at most about `points` samples per trace (every n-th sample; ``trace_step`` says n).

        Parameters
        ----------
        points : int
            Samples to keep per trace at most [-].
        """
        step = max(1, int(math.ceil(self.t.size / points)))
        if step == 1:
            return self
        sl = slice(None, None, step)
        return dataclasses.replace(self, t=self.t[sl], tau_s=self.tau_s[:, sl], expected=self.expected[sl],
                                   tau_r=self.tau_r[sl], trace_step=self.trace_step * step)

    def to_mapping(self) -> dict[str, Any]:
        """Metrics without traces (the ``cells/<key>.json`` file)."""
        return {"key": self.key, "labels": dict(self.labels), "environment": dict(self.environment),
                "runs": [dict(r) for r in self.runs], "repeatability": self.repeatability,
                "disk_margin": self.disk_margin, "stable": self.stable, "trace_step": self.trace_step,
                "passive": self.passive}

    def save(self, folder: Path) -> None:
        """Write ``<key>.npz`` then ``<key>.json`` (the JSON last: its presence marks a finished cell).

        The JSON records the key and the SHA-256 of the ``.npz``, so :meth:`load` reuses a cell only
        when both files are the ones this key wrote.
        """
        import io

        buffer = io.BytesIO()
        np.savez(buffer, t=self.t, tau_s=self.tau_s, expected=self.expected, tau_r=self.tau_r)
        traces = buffer.getvalue()
        atomic_write(folder / f"{self.key}.npz", traces)
        doc = {**self.to_mapping(), "npz_sha256": hashlib.sha256(traces).hexdigest()}
        atomic_write(folder / f"{self.key}.json", json.dumps(_jsonable(doc), indent=1, allow_nan=False) + "\n")

    @classmethod
    def load(cls, folder: Path, key: str) -> "CellResult | None":
        """The stored cell with this key, or None if absent, unreadable, not this key's or not intact.

        A cell is reused only when its JSON names this key and its ``.npz`` has the SHA-256 the JSON
        records: a swapped, truncated or edited file is recomputed, never reused (and never a
        ``BadZipFile`` traceback).
        """
        try:
            doc = json.loads((folder / f"{key}.json").read_text(encoding="utf-8"))
            traces = (folder / f"{key}.npz").read_bytes()
            if not isinstance(doc, dict) or doc.get("key") != key \
                    or doc.get("npz_sha256") != hashlib.sha256(traces).hexdigest():
                return None
            import io

            with np.load(io.BytesIO(traces)) as npz:
                arrays = {k: npz[k] for k in ("t", "tau_s", "expected", "tau_r")}
            runs = tuple({k: (math.nan if v is None and k != "settled" else v) for k, v in r.items()}
                         for r in doc["runs"])
            stable, passive = doc["stable"], doc.get("passive")
            if any(v is not None and not isinstance(v, bool) for v in (stable, passive)):
                return None
            return cls(key=key, labels=doc["labels"], environment=doc["environment"], runs=runs,
                       repeatability=_num(doc["repeatability"]), disk_margin=_num(doc["disk_margin"]), stable=stable,
                       trace_step=int(doc["trace_step"]), passive=passive, **arrays)
        except Exception:     # noqa: BLE001 - any damage (BadZipFile, EOFError, KeyError, TypeError...) means recompute
            return None


def _num(x: Any) -> float:
    return math.nan if x is None else float(x)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


#: The :func:`~.metrics.step_metrics` a step reference adds to a run's metrics.
_STEP_KEYS = ("rise_time_s", "overshoot_percent", "settling_time_s", "steady_state_error_N_m", "settled")
#: Run keys that a run not scored (diverged, faulted) keeps.
_KEPT = ("diverged_at_s", "disk_margin", "expected_diverged_at_s")


def _expected_response(design: Design, reference: Any, duration_s: float, rate_hz: float):
    """The frictionless expected response: the design's controller (its own law) on its nominal plant, no
    compensator, no nominal viscous friction, no noise, exact encoders (simulated and recorded cells)."""
    return simulate(dataclasses.replace(design, compensator=Compensator(kind="none")), reference=reference,
                    duration_s=duration_s, rate_hz=rate_hz, include_nominal_viscous=False, process_noise_std=0.0,
                    encoder_counts=None, description="benchmark: frictionless expected response")


def _run_metrics(tau_s: np.ndarray, expected: np.ndarray, repeatability: float, margin: float) -> dict[str, Any]:
    """One run's :data:`~.metrics.METRICS`: repeatability, MAE and disk margin; the rest NaN until filled
    (``settled`` None: not a step, or not scored)."""
    m: dict[str, Any] = {**dict.fromkeys(METRICS, math.nan), "settled": None}
    m.update(repeatability=float(repeatability), mae_N_m=float(np.mean(np.abs(tau_s - expected))),
             disk_margin=margin)
    return m


def run_cell(task: tuple) -> CellResult:
    """Simulate one cell's repetitions and its frictionless expected response; compute the metrics.

    Parameters
    ----------
    task : tuple
        ``(key, cell, spec, sfm_params)``: the cell, the benchmark (hardware, seed,
        repetitions) and the identified SFM parameters (None without an SFM).

    Returns
    -------
    CellResult
        Metrics and decimated traces.
    """
    key, cell, spec, sfm_params = task
    design = Design(testbed=spec.testbed, environment=cell.environment, controller=cell.controller,
                    compensator=cell.compensator)
    var = Variability(repetitions=spec.repetitions, viscous_drift=spec.viscous_drift, seed=spec.seed)
    angles = var.initial_angles()
    expected = _expected_response(design, cell.reference, cell.duration_s, spec.rate_hz)
    sfm = cell.compensator.kind == "sfm"
    # the repetitions as one batch (each run bit-equal to `simulate` with the same arguments); in a
    # worker process the executor's processes already fill the cores, so the batch takes one thread
    # a user's SEA may need more RK4 substeps than the default 10 against the same hardware
    substeps = max(stable_substeps(design, var.effects_of(spec.effects, i), rate_hz=spec.rate_hz)
                   for i in range(len(angles)))
    batch = simulate_batch([BatchRun(design=design, effects=var.effects_of(spec.effects, i), seed=spec.seed + 1 + i,
                                     initial_angle=float(a)) for i, a in enumerate(angles)],
                           duration_s=cell.duration_s, reference=cell.reference, rate_hz=spec.rate_hz,
                           substeps=substeps,
                           threads=1 if multiprocessing.parent_process() is not None else None,
                           sfm_params=sfm_params if sfm else None, sfm_deadband=spec.sfm_deadband if sfm else 0.0)
    runs = list(batch.results())
    tau = np.array([r.tau_s for r in runs])
    t = runs[0].t
    per_run_rep = repeatability_per_run(tau)
    dm = sampled_loop_margin(design, design.compensator if not sfm else design.with_friction(sfm_params).compensator,
                             spec.rate_hz)
    margin = math.nan if dm is None else float(dm.alpha)
    chirp = isinstance(cell.reference, Chirp)
    rows = []
    expected_diverged = expected.diverged_at_s is not None
    for i, (r, a) in enumerate(zip(runs, angles)):
        row: dict[str, Any] = {"repetition": i, "initial_angle_rad": float(a)}
        m = _run_metrics(r.tau_s, expected.tau_s, per_run_rep[i], margin)
        # a run (or the frictionless reference) that left every physical range scores nothing:
        # its time is kept, and the CLI says so and exits 1 (the loop is unstable there)
        at = r.diverged_at_s
        m["diverged_at_s"] = math.nan if at is None else at
        if expected_diverged:
            m["mae_N_m"] = math.nan
            m["expected_diverged_at_s"] = expected.diverged_at_s
        if chirp:
            m["bandwidth_hz"] = tracking_bandwidth_hz(r.tau_r, r.tau_s, spec.rate_hz, cell.reference.f0_hz,
                                                      cell.reference.f1_hz)
        else:
            sm = step_metrics(t, r.tau_s, amplitude=cell.reference.amplitude, t0=cell.reference.t0)
            m.update({k: sm[k] for k in _STEP_KEYS})
        if at is not None:
            _unscored(m)
        # a controller written as code that failed stopped its run (zero torque from then on), or the
        # expected response's: nothing of the run is scored, the fault is kept
        fault = r.fault or expected.fault
        if fault is not None:
            _unscored(m)
            m["controller_fault_at_s"] = fault["t_s"]
            row["controller_fault"] = ("expected response: " if r.fault is None else "") + fault["reason"]
        row.update(m)
        rows.append(row)
    clean = [i for i, r in enumerate(runs) if r.fault is None]   # a faulted run's zero torque is no repetition
    repeatability = pairwise_xcorr(tau) if len(clean) == len(runs) else (
        pairwise_xcorr(tau[clean]) if len(clean) >= 2 else math.nan)
    diverged = expected_diverged or any(r.diverged_at_s is not None for r in runs)
    return CellResult(key=key, labels=cell.labels, environment=cell.environment.to_mapping(), runs=tuple(rows),
                      repeatability=repeatability, disk_margin=margin, t=np.array(t), tau_s=tau,
                      expected=np.array(expected.tau_s), tau_r=np.array(runs[0].tau_r),
                      stable=cell_stable(dm, diverged), passive=cell_passive(design, spec.rate_hz))


def cell_passive(design: Design, rate_hz: float) -> bool | None:
    """The cell's load-independent flag: is its force-controlled SEA stable with every passive environment?

    :func:`forecast_design.passivity.analyse_passivity` of the cell's controller and compensator (the
    compensator believing the cell's environment), port at the link's end; None where it does not
    apply (a controller written as code without a linearisation, a locked output as the belief,
    an SFM whose friction is not carried).

    Parameters
    ----------
    design : Design
        The cell's testbed, environment, controller and compensator.
    rate_hz : float
        Control rate [Hz] (a discrete controller's continuous equivalent).

    Returns
    -------
    bool or None
        ``passive`` of the port.
    """
    from ..errors import ForecastError
    from ..passivity import analyse_passivity

    if design.controller is not None and not design.controller.has_equations:
        return None
    try:
        return bool(analyse_passivity(design, design.compensator, controller=design.controller,
                                      rate_hz=rate_hz).passive)
    except ForecastError:
        return None


def cell_stable(margin: Any, diverged: bool) -> bool | None:
    """The ``stable`` flag of a cell: its loop's nominal stability, False when something diverged.

    Parameters
    ----------
    margin : DiskMargin or None
        :func:`~.metrics.sampled_loop_margin` (None: no linear model of the controller).
    diverged : bool
        A run or the frictionless expected response left every physical range.

    Returns
    -------
    bool or None
        None when the loop cannot be analysed and nothing diverged.
    """
    if diverged:
        return False
    return None if margin is None else bool(margin.stable)


def _unscored(m: dict[str, Any]) -> None:
    """Blank a run's indicators (it diverged or faulted); its times and the loop's margin are kept."""
    m.update({k: math.nan for k in m if k not in _KEPT})
    m["settled"] = None


def run_benchmark(spec: BenchmarkSpec, *, out: str | os.PathLike[str] | None = None, executor: Executor | None = None,
                  progress: Callable[[int, int], None] | None = None,
                  sfm_params: Mapping[str, float] | None = None) -> tuple[list[CellResult], dict[str, Any]]:
    """Run every cell of a benchmark (those not already stored under ``out``).

    Parameters
    ----------
    spec : BenchmarkSpec
        What to run.
    out : path, optional
        Result folder; finished cells are read from and written to ``out/cells``.
    executor : Executor, optional
        Where cells run (:func:`forecast_design.executor.make_executor`); default: this process.
    progress : callable, optional
        ``progress(done, total)`` over the cells to compute.
    sfm_params : Mapping, optional
        The SFM's identified friction; default: identified on a simulated open-loop run of
        the same hardware (:func:`forecast_design.reproduce.identify_extended_sfm`).

    Returns
    -------
    cells : list of CellResult
        In :meth:`~.spec.BenchmarkSpec.cells` order, their traces thinned to about
        :data:`TRACE_POINTS` samples (``trace_step``; the full-rate ones are in ``out/cells``).
    info : dict
        ``computed`` and ``reused`` cell counts, the SFM parameters and the executor.
    """
    if not isinstance(spec, BenchmarkSpec):
        raise ParameterError("run_benchmark needs a BenchmarkSpec", name="spec", value=type(spec).__name__)
    cells: list[Cell] = spec.cells()
    for c in cells:     # one cell is one batch: bounded before any is simulated (or identified)
        check_limit(f"benchmark cell of {spec.repetitions} repetitions x {c.duration_s:g} s at {spec.rate_hz:g} Hz",
                    "batch_samples", spec.repetitions * max(1, round(c.duration_s * spec.rate_hz)))
    if sfm_params is None and any(c.compensator.kind == "sfm" for c in cells):
        sfm_params, _, _ = identify_extended_sfm(spec.effects, seed=spec.seed, testbed=spec.testbed)
    sfm = None if sfm_params is None else {k: float(v) for k, v in sfm_params.items()}
    folder = None if out is None else Path(out) / "cells"
    keys = [spec.cell_key(c, sfm) for c in cells]
    found: dict[str, CellResult] = {}
    if folder is not None:
        for k in keys:
            stored = CellResult.load(folder, k)
            if stored is not None:
                found[k] = stored.thinned()
    todo = [(k, c, spec, sfm) for k, c in zip(keys, cells) if k not in found]
    ex = executor or LocalExecutor(1)
    # rounds of a few tasks per worker: each round's cells are stored before the next starts,
    # so an interrupted run keeps what it finished
    step = max(4, 4 * ex.workers)
    for start in range(0, len(todo), step):
        chunk = todo[start:start + step]
        report = None if progress is None else (lambda d, n, s=start: progress(s + d, len(todo)))
        for res in ex.map(run_cell, chunk, progress=report):
            if folder is not None:
                res.save(folder)          # full rate on disk, a thinned copy in memory
            found[res.key] = res.thinned()
    info = {"cells": len(cells), "computed": len(todo), "reused": len(cells) - len(todo), "sfm_params": sfm,
            **ex.describe()}
    return [found[k] for k in keys], info


#: Columns of ``traces.parquet``: the cell's labels, the repetition, then t [s] and tau_r, tau_s and the
#: frictionless expected response tau_s_expected [N m], one row per sample at the control rate.
TRACE_COLUMNS = ("controller", "compensator", "environment", "reference", "repetition", "t", "tau_r", "tau_s",
                 "tau_s_expected")


def write_traces(cells: list[CellResult], path: str | os.PathLike[str], store: str | os.PathLike[str] | None = None
                 ) -> dict[str, Any]:
    """Write every run's trace as one Parquet file (:data:`TRACE_COLUMNS`), a cell at a time.

    Parameters
    ----------
    cells : list of CellResult
        The benchmark's cells (their labels and keys).
    path : path
        The Parquet file to write (atomically).
    store : path, optional
        The ``cells`` folder holding each cell's full-rate traces (``<key>.npz``); a cell not found
        there is written with the traces it holds.

    Returns
    -------
    dict
        ``trace_step``: samples of the run per written sample (1: the full control rate), and
        ``rows`` written.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = pa.schema([*((name, pa.dictionary(pa.int32(), pa.string())) for name in TRACE_COLUMNS[:4]),
                        ("repetition", pa.int32()), *((name, pa.float64()) for name in TRACE_COLUMNS[5:])])
    steps, rows = set(), 0
    with atomic_open(Path(path)) as fh, pq.ParquetWriter(fh, schema) as writer:
        for c in cells:
            full = None if store is None else CellResult.load(Path(store), c.key)
            full = full if full is not None else c
            steps.add(full.trace_step)
            m, n = full.tau_s.shape
            cols = {name: pa.DictionaryArray.from_arrays(pa.array(np.zeros(m * n, dtype=np.int32)),
                                                         pa.array([str(full.labels[name])]))
                    for name in TRACE_COLUMNS[:4]}
            cols.update(repetition=pa.array(np.repeat(np.arange(m, dtype=np.int32), n)),
                        t=pa.array(np.tile(full.t, m)), tau_r=pa.array(np.tile(full.tau_r, m)),
                        tau_s=pa.array(full.tau_s.reshape(-1)), tau_s_expected=pa.array(np.tile(full.expected, m)))
            writer.write_table(pa.table(cols, schema=schema))
            rows += m * n
    return {"trace_step": max(steps) if steps else 1, "rows": rows}
