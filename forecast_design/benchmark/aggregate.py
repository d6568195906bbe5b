"""Aggregation (per environment and over the set: mean, best, worst) and the tidy result table.

The table has one row per run (``kind = "run"``), one per environment and statistic
(``kind = "environment"``: mean, best and worst over the repetitions; the ``mean``
row's repeatability is the cell's mean pairwise cross-correlation; ``se`` is the mean's
standard error over the repetitions' draw of initial angles: std / sqrt(n) of the runs, the
jackknife for the repeatability, 0 for the disk margin of the one loop) and one per set and
statistic (``kind = "set"``: mean, best and worst over the environments of their
per-environment means, and ``se`` = sqrt(sum se_e^2) / n_e, the standard error of that mean;
``which`` names the best or worst environment) for every
controller, compensator and reference: the Forecast methodology's average, best-case
and worst-case performance over a whole set of environments (Section 2). "Best" is the
largest repeatability, bandwidth and disk margin and the smallest MAE, rise time,
overshoot, settling time and |steady-state error|.

Flags: ``stable`` (run and environment rows) is the cell's (:func:`~.runner.cell_stable`), ``passive`` its
load-independent coupled-stability flag (:func:`~.runner.cell_passive`);
``settled`` is the run's (step references; an environment row's is True when every run settled);
``unsettled_runs`` counts the step runs without a settling time (environment rows: the cell's;
set rows: those of the environments aggregated). A cell that is not stable keeps its run and
environment rows (flagged) but is left out of its set rows, whose ``excluded_cells`` counts them:
one unstable loop's error cannot pass for the set's performance.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..errors import OutputError

from .metrics import HIGHER_IS_BETTER, INDICATOR_DEFINITIONS, METRICS, xcorr_se_from_per_run
from ..fileio import atomic_open, atomic_write, verify_manifest
from .runner import CellResult, _jsonable

__all__ = ["result_rows", "result_table", "write_tables", "summary", "read_results", "COLUMNS", "LABELS",
           "ENV_COLUMNS", "FLAG_COLUMNS", "STATISTICS"]

#: Label columns of a cell.
LABELS = ("controller", "compensator", "environment", "reference")
#: Environment parameter columns [SI].
ENV_COLUMNS = ("J_e", "d_e", "k_e", "J_l", "d_l", "locked")
#: Flag and count columns (see the module docstring).
FLAG_COLUMNS = ("stable", "passive", "settled", "unsettled_runs", "excluded_cells")
#: Every column of the table, in order.
COLUMNS = ("kind", "statistic", *LABELS, "repetition", "initial_angle_rad", "which", *ENV_COLUMNS, *FLAG_COLUMNS,
           *METRICS)


def _score(metric: str, values: np.ndarray) -> np.ndarray:
    """Larger is better."""
    if metric in HIGHER_IS_BETTER:
        return values
    if metric == "steady_state_error_N_m":
        return -np.abs(values)
    return -values


def _pick(metric: str, values: Sequence[float], best: bool) -> tuple[float, int | None]:
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    if not np.any(ok):
        return math.nan, None
    s = np.where(ok, _score(metric, v), -np.inf if best else np.inf)
    i = int(np.argmax(s) if best else np.argmin(s))
    return float(v[i]), i


#: Statistics of the ``environment`` and ``set`` rows.
STATISTICS = ("mean", "se", "best", "worst")


def _standard_error(metric: str, values: Sequence[float]) -> float:
    """Standard error of a cell's mean of ``metric`` over its repetitions (NaN below 2 finite runs)."""
    v = np.asarray(values, dtype=float)
    if metric == "repeatability":
        return xcorr_se_from_per_run(v)       # the runs' mean correlations: a U-statistic's jackknife
    v = v[np.isfinite(v)]
    if v.size < 2:
        return math.nan
    if np.ptp(v) == 0.0:        # one value (the loop's disk margin): exactly no spread, not round-off
        return 0.0
    return float(np.std(v, ddof=1) / math.sqrt(v.size))


def _settled_flags(runs: Sequence[Mapping[str, Any]]) -> tuple[bool | None, int | None]:
    """(every step run settled, how many did not) of a cell; (None, None) when no run is a scored step."""
    flags = [r.get("settled") for r in runs]
    scored = [f for f in flags if f is not None]
    if not scored:
        return None, None
    return all(scored), sum(1 for f in scored if not f)


def result_rows(cells: Iterable[CellResult]) -> list[dict[str, Any]]:
    """The tidy rows (see the module docstring) of a benchmark's cells.

    Parameters
    ----------
    cells : iterable of CellResult
        From :func:`~.runner.run_benchmark`.

    Returns
    -------
    list of dict
        Rows with the keys :data:`COLUMNS` (NaN or None where not applicable).
    """
    cells = list(cells)
    rows: list[dict[str, Any]] = []
    env_means: dict[tuple, list[tuple[str, dict[str, float], dict[str, float]]]] = {}
    excluded: dict[tuple, int] = {}
    for c in cells:
        env = {k: c.environment.get(k) for k in ENV_COLUMNS}
        base = {**{k: c.labels[k] for k in LABELS}, **env, "stable": c.stable, "passive": c.passive}
        for r in c.runs:
            rows.append({"kind": "run", "statistic": "value", **base, "repetition": int(r["repetition"]),
                         "initial_angle_rad": float(r["initial_angle_rad"]), "which": None,
                         "settled": r.get("settled"), **{m: float(r[m]) for m in METRICS}})
        settled, unsettled = _settled_flags(c.runs)
        per_env = {}
        for stat in STATISTICS:
            row = {"kind": "environment", "statistic": stat, **base, "repetition": None,
                   "initial_angle_rad": math.nan, "which": None, "settled": settled, "unsettled_runs": unsettled}
            for m in METRICS:
                vals = [float(r[m]) for r in c.runs]
                if stat == "mean":
                    finite = [v for v in vals if math.isfinite(v)]
                    row[m] = float(np.mean(finite)) if finite else math.nan
                elif stat == "se":
                    row[m] = _standard_error(m, vals)
                else:
                    row[m] = _pick(m, vals, stat == "best")[0]
            if stat == "mean":
                row["repeatability"] = float(c.repeatability)
            per_env[stat] = row
            rows.append(row)
        group = (c.labels["controller"], c.labels["compensator"], c.labels["reference"])
        excluded.setdefault(group, 0)
        env_means.setdefault(group, [])
        if c.stable is False:          # flagged above, kept out of the set's aggregates (counted)
            excluded[group] += 1
        else:
            env_means[group].append((c.labels["environment"], per_env["mean"], per_env["se"]))
    for (ctrl, comp, ref), items in env_means.items():
        counts = [r["unsettled_runs"] for _, r, _ in items if r["unsettled_runs"] is not None]
        for stat in STATISTICS:
            row = {"kind": "set", "statistic": stat, "controller": ctrl, "compensator": comp,
                   "environment": "(set)", "reference": ref, "repetition": None, "initial_angle_rad": math.nan,
                   "which": None, **dict.fromkeys(ENV_COLUMNS), "stable": None, "passive": None, "settled": None,
                   "unsettled_runs": sum(counts) if counts else None, "excluded_cells": excluded[(ctrl, comp, ref)]}
            which = []
            for m in METRICS:
                vals = [r[m] for _, r, _ in items]
                if stat == "mean":
                    finite = [v for v in vals if math.isfinite(v)]
                    row[m] = float(np.mean(finite)) if finite else math.nan
                elif stat == "se":
                    # the environments' means are independent draws: the variance of their mean
                    ses = [se[m] for _, r, se in items if math.isfinite(r[m])]
                    row[m] = float(math.sqrt(sum(x * x for x in ses)) / len(ses)) \
                        if ses and all(math.isfinite(x) for x in ses) else math.nan
                else:
                    row[m], i = _pick(m, vals, stat == "best")
                    if i is not None:
                        which.append(f"{m}={items[i][0]}")
            row["which"] = "; ".join(which) if which else None
            rows.append(row)
    return [{k: r.get(k) for k in COLUMNS} for r in rows]


def result_table(cells: Iterable[CellResult]):
    """:func:`result_rows` as a pandas DataFrame (columns :data:`COLUMNS`).

    Parameters
    ----------
    cells : iterable of CellResult
        The benchmark's cells.
    """
    import pandas as pd

    df = pd.DataFrame(result_rows(cells), columns=list(COLUMNS))
    df["repetition"] = df["repetition"].astype("Int64")
    for col in ("locked", "stable", "passive", "settled"):
        df[col] = df[col].astype("boolean")
    for col in ("unsettled_runs", "excluded_cells"):
        df[col] = df[col].astype("Int64")
    for col in ("J_e", "d_e", "k_e", "J_l", "d_l", "initial_angle_rad", *METRICS):
        df[col] = df[col].astype(float)
    return df


def write_tables(df, out: str | os.PathLike[str]) -> dict[str, Path]:
    """Write the table as ``results.parquet`` (pyarrow) and ``results.csv`` (atomically).

    Parameters
    ----------
    df : pandas.DataFrame
        From :func:`result_table`.
    out : path
        The result folder.

    Returns
    -------
    dict of str to Path
        ``parquet`` and ``csv``.
    """
    folder = Path(out)
    paths = {"parquet": folder / "results.parquet", "csv": folder / "results.csv"}
    with atomic_open(paths["parquet"]) as fh:
        df.to_parquet(fh, engine="pyarrow", index=False)
    atomic_write(paths["csv"], df.to_csv(index=False, float_format="%.17g"))
    return paths


def summary(rows: Sequence[Mapping[str, Any]], spec: Mapping[str, Any], info: Mapping[str, Any]) -> dict[str, Any]:
    """JSON summary: the benchmark, how it ran, and the set-level rows (mean, best, worst).

    Parameters
    ----------
    rows : sequence of dict
        :func:`result_rows`.
    spec : Mapping
        :meth:`~.spec.BenchmarkSpec.to_mapping`.
    info : Mapping
        From :func:`~.runner.run_benchmark` (cells computed/reused, executor, SFM).
    """
    sets = [r for r in rows if r["kind"] == "set"]
    envs = [r for r in rows if r["kind"] == "environment" and r["statistic"] == "mean"]
    doc = {"format": "forecast-benchmark/1", "benchmark": dict(spec), "run": dict(info),
           "indicators": dict(INDICATOR_DEFINITIONS),
           "flags": {"unstable_cells": [{k: r[k] for k in LABELS} for r in envs if r["stable"] is False],
                     "unsettled_runs": sum(r["unsettled_runs"] or 0 for r in envs),
                     "step_runs": sum(1 for r in rows if r["kind"] == "run" and r["settled"] is not None)},
           "set": [{k: r[k] for k in ("controller", "compensator", "reference", "statistic", "which",
                                      "unsettled_runs", "excluded_cells", *METRICS)} for r in sets],
           "environments": [{k: r[k] for k in (*LABELS, "stable", "passive", "settled", "unsettled_runs", *METRICS)}
                            for r in envs]}
    return _jsonable(doc)


def write_summary(doc: Mapping[str, Any], out: str | os.PathLike[str]) -> Path:
    """Write ``summary.json`` atomically."""
    return atomic_write(Path(out) / "summary.json", json.dumps(doc, indent=2, allow_nan=False) + "\n")


def read_results(out: str | os.PathLike[str]) -> tuple[dict[str, Any], Any]:
    """Read a benchmark's result folder, checked to be one complete set.

    Parameters
    ----------
    out : path
        The folder ``forecast-design benchmark --out`` wrote.

    Returns
    -------
    summary : dict
        ``summary.json``.
    table : pandas.DataFrame
        ``results.parquet`` (the rows of :func:`result_rows`).

    Raises
    ------
    OutputError
        One line when the folder is not one complete set: ``MANIFEST.sha256`` missing (a run
        was interrupted while swapping its files in, or the folder was never written) or a
        member differing from it (:func:`forecast_design.fileio.verify_manifest`).
    """
    import pandas as pd

    members = verify_manifest(out)
    for name in ("summary.json", "results.parquet"):
        if name not in members:
            raise OutputError(f"{Path(out) / name}: not in the folder's manifest: not a benchmark result folder",
                              path=str(Path(out) / name))
    doc = json.loads(members["summary.json"].read_text(encoding="utf-8"))
    return doc, pd.read_parquet(members["results.parquet"], engine="pyarrow")

