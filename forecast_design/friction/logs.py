"""Plain-CSV axis logs (time, position, force columns) for users' own data."""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ExperimentFormatError

__all__ = ["AxisLog", "load_axis_csv"]


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisLog:
    """One axis log read from a CSV file.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Sample times [s].
    position : ndarray, shape (n,)
        Position [rad] (or [m]).
    force : ndarray, shape (n,)
        Force, already multiplied by ``scale_force`` [N m] (or [N]).
    rate_hz : float
        Sample rate [Hz].
    source : str
        File the log came from.
    """

    t: np.ndarray
    position: np.ndarray
    force: np.ndarray
    rate_hz: float
    source: str


def load_axis_csv(path: str | os.PathLike[str], *, time: str, position: str, force: str,
                  rate_hz: float | None = None, scale_force: float = 1.0) -> AxisLog:
    """Read time, position and force columns from a CSV file with a header row.

    Parameters
    ----------
    path : str or path-like
        The CSV file (comma separated, one header row).
    time : str
        Name of the time column [s].
    position : str
        Name of the position column [rad] (or [m]).
    force : str
        Name of the force column (multiplied by `scale_force`) [N m] (or [N]).
    rate_hz : float, optional
        Declared sample rate [Hz]; when given, the time steps must match
        ``1 / rate_hz`` within 1 %. Default: 1 / mean time step.
    scale_force : float
        Factor applied to the force column (e.g. a drive gain in [N/V]).

    Returns
    -------
    AxisLog
        The arrays, read-only.

    Raises
    ------
    ExperimentFormatError
        One line naming the file and the column (or line): a missing column,
        a non-numeric or NaN value, or time that is not strictly increasing.
    """
    p = Path(path)
    label = str(p)
    try:
        with p.open(newline="") as fh:
            reader = csv.reader(fh)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise ExperimentFormatError(f"{label}: empty file, expected a header row", path=label,
                                            key="header") from None
            rows = list(reader)
    except OSError as exc:
        raise ExperimentFormatError(f"{label}: cannot read: {exc.strerror or exc}", path=label) from None
    wanted = {"time": time, "position": position, "force": force}
    idx: dict[str, int] = {}
    for role, name in wanted.items():
        if name not in header:
            raise ExperimentFormatError(
                f"{label}: {role} column '{name}' missing; columns are: {', '.join(header)}",
                path=label, key=name)
        idx[role] = header.index(name)
    out = {role: np.empty(len(rows)) for role in wanted}
    for i, row in enumerate(rows):
        line = i + 2
        for role, j in idx.items():
            name = wanted[role]
            try:
                value = float(row[j])
            except (IndexError, ValueError):
                cell = row[j] if j < len(row) else "<missing>"
                raise ExperimentFormatError(
                    f"{label}: line {line}: column '{name}' is not a number: {cell!r}",
                    path=label, key=name) from None
            if not math.isfinite(value):
                raise ExperimentFormatError(f"{label}: line {line}: column '{name}' is {value!r}",
                                            path=label, key=name)
            out[role][i] = value
    t = out["time"]
    if t.size < 2:
        raise ExperimentFormatError(f"{label}: need at least 2 rows, got {t.size}", path=label, key=time)
    dts = np.diff(t)
    bad = np.flatnonzero(dts <= 0)
    if bad.size:
        raise ExperimentFormatError(
            f"{label}: line {bad[0] + 3}: column '{time}' not strictly increasing "
            f"({t[bad[0] + 1]!r} after {t[bad[0]]!r})", path=label, key=time)
    mean_dt = (t[-1] - t[0]) / (t.size - 1)
    if rate_hz is None:
        rate = 1.0 / mean_dt
    else:
        rate = float(rate_hz)
        if not (rate > 0 and math.isfinite(rate)):
            raise ExperimentFormatError(f"{label}: rate_hz must be > 0 [Hz], got {rate_hz!r}", path=label,
                                        key="rate_hz")
        worst = int(np.argmax(np.abs(dts - 1.0 / rate)))
        if abs(dts[worst] - 1.0 / rate) > 0.01 / rate:
            raise ExperimentFormatError(
                f"{label}: line {worst + 3}: column '{time}' steps by {dts[worst]!r} s, expected "
                f"1/rate_hz = {1.0 / rate!r} s", path=label, key=time)
    force_arr = out["force"] * float(scale_force)
    arrays = {}
    for name, a in (("t", t), ("position", out["position"]), ("force", force_arr)):
        a.flags.writeable = False
        arrays[name] = a
    return AxisLog(t=arrays["t"], position=arrays["position"], force=arrays["force"], rate_hz=rate,
                   source=label)
