"""Plain-CSV axis logs (time, position, force columns) for users' own data."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ExperimentFormatError
from ..experiment_io import clip, read_csv_table, read_regular_file

__all__ = ["AxisLog", "load_axis_csv", "axis_units", "parameter_unit", "prismatic_from_columns"]


def axis_units(prismatic: bool) -> dict[str, str]:
    """Units of an axis' quantities: N, m, m/s for a prismatic (linear) axis such as the EMPS
    benchmark; N m, rad, rad/s for a rotary one such as the SEA's motor.

    Parameters
    ----------
    prismatic : bool
        A linear axis.

    Returns
    -------
    dict
        ``force``, ``position``, ``velocity``, ``acceleration``, ``inertia`` unit strings.
    """
    if prismatic:
        return {"force": "N", "position": "m", "velocity": "m/s", "acceleration": "m/s^2", "inertia": "kg"}
    return {"force": "N m", "position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2",
            "inertia": "kg m^2"}


def parameter_unit(name: str, prismatic: bool) -> str:
    """Unit of a fitted friction parameter on a prismatic or rotary axis.

    Parameters
    ----------
    name : str
        Parameter name as :mod:`forecast_design.friction` gives it (``viscous``, ``coulomb``,
        ``inertia``, ``stribeck_velocity``, ``sigma0``, ``sin1``, ...).
    prismatic : bool
        A linear axis (N, m) instead of a rotary one (N m, rad).

    Returns
    -------
    str
        The unit, e.g. ``'N s/m'`` for ``viscous`` on a prismatic axis.
    """
    u = axis_units(prismatic)
    f, x, v = u["force"], u["position"], u["velocity"]
    if name == "inertia":
        return u["inertia"]
    if name.startswith("viscous") or name == "sigma2":
        return f"{f} s/{x}"
    if name == "stribeck_velocity":
        return v
    if name == "sigma0":
        return f"{f}/{x}"
    if name == "sigma1":
        return f"{f} s/{x}"
    return f    # coulomb, static, offset, harmonics: forces


def prismatic_from_columns(position: str, force: str) -> bool:
    """Whether column names say the axis is prismatic: a position in ``_m``/``_mm`` or a force in ``_N``.

    Parameters
    ----------
    position, force : str
        Column names; the experiment format puts the unit last (``qm_m``, ``force_N``,
        ``theta_rad``, ``tau_m_N_m``).

    Returns
    -------
    bool
        True for metres or newtons (not newton metres).
    """
    pos = position.lower()
    return pos.endswith(("_m", "_mm")) or (force.endswith("_N") and not force.endswith("_N_m"))


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
    prismatic : bool
        A linear axis: position [m], force [N] (units follow the log in plots and printouts).
    """

    t: np.ndarray
    position: np.ndarray
    force: np.ndarray
    rate_hz: float
    source: str
    prismatic: bool = False


def load_axis_csv(path: str | os.PathLike[str], *, time: str, position: str, force: str,
                  rate_hz: float | None = None, scale_force: float = 1.0,
                  prismatic: bool | None = None, max_samples: int | None = None) -> AxisLog:
    """Read time, position and force columns from a CSV file with a header row.

    Parameters
    ----------
    path : str or path-like
        The CSV file (comma separated, one header row; a regular file). Read by the
        toolbox's one CSV reader (:func:`forecast_design.experiment_io.read_csv_table`):
        a byte-order mark, CRLF line ends and blank lines at the end are accepted; every
        row has the header's number of fields and the three named columns hold numbers
        (other columns are not read). The file is memory-mapped; about 24 bytes per row.
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
    prismatic : bool, optional
        A linear axis (N, m) rather than a rotary one (N m, rad); default: from the column
        names' unit suffixes (:func:`prismatic_from_columns`, e.g. EMPS' ``qm_m``, ``force_N``).
    max_samples : int, optional
        Most rows accepted, checked before the file is parsed (default
        ``experiment_io.DEFAULT_MAX_SAMPLES``).

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
    wanted = {"time": time, "position": position, "force": force}
    header, columns = read_csv_table(read_regular_file(p, label, mapped=True), label, required=(),
                                     usecols=wanted.values(), max_rows=max_samples, reader="identify")
    for role, name in wanted.items():
        if name not in header:
            raise ExperimentFormatError(
                f"{label}: {role} column '{name}' missing; columns are: {clip(', '.join(header))}",
                path=label, key=name)
    out = {role: columns[name] for role, name in wanted.items()}
    # The first non-finite value over the three columns, naming its line (header = line 1).
    bad = [(int(idx[0]), role) for role, a in out.items() if (idx := np.flatnonzero(~np.isfinite(a))).size]
    if bad:
        i, role = min(bad)
        raise ExperimentFormatError(f"{label}: line {i + 2}: column '{wanted[role]}' is {float(out[role][i])!r}",
                                    path=label, key=wanted[role])
    t = out["time"]
    if t.size < 2:
        raise ExperimentFormatError(f"{label}: need at least 2 rows, got {t.size}", path=label, key=time)
    dts = np.diff(t)
    bad = np.flatnonzero(dts <= 0)
    if bad.size:
        raise ExperimentFormatError(
            f"{label}: line {bad[0] + 3}: column '{time}' not strictly increasing "
            f"({float(t[bad[0] + 1])!r} after {float(t[bad[0]])!r})", path=label, key=time)
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
                f"{label}: line {worst + 3}: column '{time}' steps by {float(dts[worst])!r} s, expected "
                f"1/rate_hz = {1.0 / rate!r} s", path=label, key=time)
    force_arr = out["force"] * float(scale_force)
    arrays = {}
    for name, a in (("t", t), ("position", out["position"]), ("force", force_arr)):
        a.flags.writeable = False
        arrays[name] = a
    return AxisLog(t=arrays["t"], position=arrays["position"], force=arrays["force"], rate_hz=rate,
                   source=label,
                   prismatic=prismatic_from_columns(position, force) if prismatic is None else bool(prismatic))
