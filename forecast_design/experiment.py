"""Experiments: the TOML + CSV pair of the forecast-experiment/1 format, in memory and on disk."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from .errors import ExperimentFormatError, ParameterError
from .experiment_io import FORMAT, OPTIONAL_COLUMNS, REQUIRED_COLUMNS, SPEC_COLUMNS as _SPEC_COLUMNS
from .experiment_io import check_rate as _check_rate
from .experiment_io import data_name, read_experiment_files, write_experiment_files
from .experiment_io import one_line as _one_line
from .params import Design

__all__ = [
    "FORMAT",
    "REQUIRED_COLUMNS",
    "OPTIONAL_COLUMNS",
    "RATE_TOLERANCE",
    "LOCKED_Q_TOLERANCE",
    "Signals",
    "Experiment",
    "load_experiment",
    "save_experiment",
    "experiment_from_arrays",
]

#: Allowed relative deviation of one time step (and of the mean step) from 1/rate_hz [-].
#: Wide enough for float jitter in real logs (EMPS: ~2e-5), narrow enough to catch a
#: dropped sample (100 %) or a wrong rate in the TOML.
RATE_TOLERANCE = 0.01
#: Largest |q| accepted when the environment is locked (the spec: q is all zeros) [rad].
LOCKED_Q_TOLERANCE = 1e-9


class _Adopt:
    """A column a loader hands over to :class:`Signals` (it keeps no other use of it): kept without a copy."""

    __slots__ = ("array",)

    def __init__(self, array: np.ndarray) -> None:
        self.array = array


def _readonly(name: str, values: Any) -> np.ndarray:
    """A read-only 1-D float64 copy of ``values`` (an adopted float64 column: itself); errors name the column."""
    if isinstance(values, _Adopt):
        arr = values.array
        if isinstance(arr, np.ndarray) and arr.dtype == np.float64 and arr.ndim == 1:
            arr.flags.writeable = False
            return arr
        values = arr
    if np.iscomplexobj(values):   # float64 would drop the imaginary part with a mere warning
        raise ExperimentFormatError(f"signal '{name}' must be real, got complex values", key=name)
    try:
        arr = np.array(values, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise ExperimentFormatError(
            f"signal '{name}' must be numeric: {_one_line(exc)}", key=name
        ) from None
    if arr.ndim != 1:
        raise ExperimentFormatError(
            f"signal '{name}' must be a 1-D array, got shape {arr.shape}", key=name
        )
    arr.flags.writeable = False
    return arr


def _check_column_name(name: Any) -> str:
    if not isinstance(name, str) or not name or name != name.strip():
        raise ExperimentFormatError(
            f"extra column name must be a non-empty string without surrounding blanks, got {name!r}",
            key=str(name),
        )
    if any(ch in name for ch in ',"\r\n'):
        raise ExperimentFormatError(
            f"extra column name {name!r} contains a comma, quote or line break", key=name
        )
    if name in _SPEC_COLUMNS:
        raise ExperimentFormatError(
            f"extra column name '{name}' is a spec column; pass it as the '{name}' field", key=name
        )
    return name


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Signals:
    """Sampled signals of one experiment, one read-only 1-D float64 array per CSV column.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, strictly increasing [s].
    tau_m : array_like, shape (n,)
        Motor torque command, held from ``t[i]`` until ``t[i+1]`` [N m].
    theta : array_like, shape (n,)
        Motor angle [rad].
    q : array_like, shape (n,)
        Environment/joint angle (all zeros when locked) [rad].
    tau_s : array_like, shape (n,), optional
        Spring torque [N m]. ``None`` until an :class:`Experiment` derives it as
        ``k (theta - q)``.
    tau_r : array_like, shape (n,), optional
        Force reference [N m].
    extra : Mapping[str, array_like], optional
        Further CSV columns, kept in order.
    tau_s_derived : bool
        True when ``tau_s`` was computed from ``theta`` and ``q`` rather than measured;
        a derived ``tau_s`` is not written back to CSV.

    Notes
    -----
    Arrays are copied and marked read-only (``flags.writeable == False``).
    Equality compares every array exactly (``np.array_equal``) and the column order.
    """

    t: np.ndarray
    tau_m: np.ndarray
    theta: np.ndarray
    q: np.ndarray
    tau_s: np.ndarray | None = None
    tau_r: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    tau_s_derived: bool = False

    __hash__ = None  # arrays are not hashable; equality is by value

    def __post_init__(self) -> None:
        for name in _SPEC_COLUMNS:
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _readonly(name, value))
            elif name in REQUIRED_COLUMNS:
                raise ExperimentFormatError(f"signal '{name}' is required", key=name)
        if not isinstance(self.extra, Mapping):
            raise ExperimentFormatError(
                f"extra must be a mapping of column name to array, got {type(self.extra).__name__}",
                key="extra",
            )
        extra = {_check_column_name(k): _readonly(k, v) for k, v in self.extra.items()}
        object.__setattr__(self, "extra", MappingProxyType(extra))
        if not isinstance(self.tau_s_derived, bool):
            raise ExperimentFormatError(
                f"tau_s_derived must be true or false, got {self.tau_s_derived!r}", key="tau_s_derived"
            )
        n = self.t.shape[0]
        for name, arr in self.columns(include_derived=True).items():
            if arr.shape[0] != n:
                raise ExperimentFormatError(
                    f"signal '{name}' has {arr.shape[0]} samples but 't' has {n}", key=name
                )

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Signals):
            return NotImplemented
        if self.tau_s_derived != other.tau_s_derived:
            return False
        mine, theirs = self.columns(include_derived=True), other.columns(include_derived=True)
        return list(mine) == list(theirs) and all(
            np.array_equal(mine[k], theirs[k]) for k in mine
        )

    def __repr__(self) -> str:
        names = ", ".join(self.columns(include_derived=True))
        return f"Signals(n={len(self)}, columns=[{names}], tau_s_derived={self.tau_s_derived})"

    def columns(self, *, include_derived: bool = False) -> dict[str, np.ndarray]:
        """The signals in CSV column order.

        Parameters
        ----------
        include_derived : bool
            Include ``tau_s`` when it was derived rather than measured.

        Returns
        -------
        dict[str, numpy.ndarray]
            ``t``, ``tau_m``, ``theta``, ``q``, then ``tau_s`` and ``tau_r`` when
            present, then the extra columns in their order. Units as the fields.
        """
        out = {name: getattr(self, name) for name in REQUIRED_COLUMNS}
        if self.tau_s is not None and (include_derived or not self.tau_s_derived):
            out["tau_s"] = self.tau_s
        if self.tau_r is not None:
            out["tau_r"] = self.tau_r
        out.update(self.extra)
        return out

    def slice(self, start: int, stop: int) -> "Signals":
        """Samples ``start`` to ``stop - 1`` as new Signals.

        Parameters
        ----------
        start, stop : int
            Python slice bounds on the sample index [-].

        Returns
        -------
        Signals
            The sliced signals (copies), same columns and ``tau_s_derived`` flag.
        """
        cut = slice(start, stop)
        return Signals(
            **{name: None if getattr(self, name) is None else getattr(self, name)[cut]
               for name in _SPEC_COLUMNS},
            extra={k: v[cut] for k, v in self.extra.items()},
            tau_s_derived=self.tau_s_derived,
        )


# --- validation shared by the loader and the in-memory constructors -------------------


@dataclass(frozen=True, slots=True)
class _Origin:
    """How validation messages name things: the CSV file and lines, or sample indices."""

    prefix: str = ""                     # "run01.csv: " or ""
    rate_label: str = "rate_hz"          # what to call the declared rate
    locked_label: str = "locked = true"  # what to call the lock flag
    path: str | None = None              # ExperimentFormatError.path
    first_line: int | None = None        # CSV line of sample 0 (header is line 1)

    def at(self, index: int) -> str:
        if self.first_line is None:
            return f"sample {index}"
        return f"line {index + self.first_line}"

    def error(self, message: str, key: str) -> ExperimentFormatError:
        return ExperimentFormatError(_one_line(f"{self.prefix}{message}"), path=self.path, key=key)


def _check_samples(columns: Mapping[str, np.ndarray], rate_hz: float, locked: bool, origin: _Origin) -> None:
    """Apply the format's rules on the sample values; raise naming the line/sample."""
    t = columns["t"]
    n = t.shape[0]
    if n == 0:
        raise origin.error("no samples; an experiment needs at least one row", key="t")
    first_bad: tuple[int, str] | None = None
    for name, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size and (first_bad is None or bad[0] < first_bad[0]):
            first_bad = (int(bad[0]), name)
    if first_bad is not None:
        i, name = first_bad
        raise origin.error(
            f"{origin.at(i)}: column '{name}' is {float(columns[name][i])!r}; expected a finite number",
            key=name,
        )
    if n >= 2:
        step = np.diff(t)
        bad = np.flatnonzero(step <= 0.0)
        if bad.size:
            i = int(bad[0]) + 1
            raise origin.error(
                f"{origin.at(i)}: t = {float(t[i])!r} s is not greater than t = {float(t[i - 1])!r} s of "
                f"{origin.at(i - 1)}; t must be strictly increasing", key="t",
            )
        period = 1.0 / rate_hz
        mean_step = float(t[-1] - t[0]) / (n - 1)
        if abs(mean_step - period) > RATE_TOLERANCE * period:
            raise origin.error(
                f"column 't' has a mean step of {mean_step:.9g} s ({1.0 / mean_step:.9g} Hz) but "
                f"{origin.rate_label} = {rate_hz:.9g} Hz; they differ by more than "
                f"{RATE_TOLERANCE:.0%}", key="t",
            )
        bad = np.flatnonzero(np.abs(step - period) > RATE_TOLERANCE * period)
        if bad.size:
            i = int(bad[0]) + 1
            raise origin.error(
                f"{origin.at(i)}: t step of {float(step[i - 1]):.9g} s deviates from "
                f"1/{origin.rate_label} = {period:.9g} s by more than {RATE_TOLERANCE:.0%} "
                f"of the period; rows must be uniformly spaced", key="t",
            )
    if locked:
        bad = np.flatnonzero(np.abs(columns["q"]) > LOCKED_Q_TOLERANCE)
        if bad.size:
            i = int(bad[0])
            raise origin.error(
                f"{origin.at(i)}: q = {float(columns['q'][i])!r} rad but {origin.locked_label} requires "
                f"q == 0 (|q| <= {LOCKED_Q_TOLERANCE:g} rad)", key="q",
            )


def _derived_tau_s(design: Design, theta: np.ndarray, q: np.ndarray) -> np.ndarray:
    # The spec's spring equation: tau_s = k (theta - q). Non-finite inputs are reported
    # by the sample checks that follow, not as numpy warnings here.
    with np.errstate(all="ignore"):
        return design.testbed.spring_torque(theta, q)


@dataclass(frozen=True, slots=True, kw_only=True)
class Experiment:
    """One testbed or simulated run: the nominal design, the sampling rate and the signals.

    Parameters
    ----------
    design : Design
        Nominal testbed and environment, and the controller and compensator
        that ran (``None`` for open-loop runs).
    rate_hz : float
        Sampling rate of the rows [Hz].
    signals : Signals
        The sampled signals. When ``signals.tau_s`` is absent (or marked derived) it is
        set to ``k (theta - q)`` with ``k`` from ``design`` [N m].
    description : str
        Free text.
    data : str, optional
        CSV file name as written in the TOML ``data`` key (relative to the TOML file);
        not part of equality.
    source : pathlib.Path, optional
        TOML file the experiment was loaded from; not part of equality.

    Raises
    ------
    ExperimentFormatError
        If the signals break a rule of the format (non-finite values, t not strictly
        increasing or not uniform at ``1/rate_hz``, nonzero ``q`` when locked...).
    """

    design: Design
    rate_hz: float
    signals: Signals
    description: str = ""
    data: str | None = field(default=None, compare=False)
    source: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.design, Design):
            raise ParameterError(f"design must be a Design, got {type(self.design).__name__}",
                                 name="design", value=self.design)
        if not isinstance(self.signals, Signals):
            raise ParameterError(f"signals must be Signals, got {type(self.signals).__name__}",
                                 name="signals", value=self.signals)
        if not isinstance(self.description, str):
            raise ParameterError(f"description must be a string, got {self.description!r}",
                                 name="description", value=self.description)
        if self.data is not None and (not isinstance(self.data, str) or not self.data):
            raise ParameterError(f"data must be a non-empty string or None, got {self.data!r}",
                                 name="data", value=self.data)
        if self.source is not None:
            object.__setattr__(self, "source", Path(self.source))
        rate = _check_rate(self.rate_hz, label="rate_hz", path=None)
        object.__setattr__(self, "rate_hz", rate)
        sig = self.signals
        if sig.tau_s is None or sig.tau_s_derived:
            # Recomputed even when already derived, so tau_s always follows this design's k.
            sig = dataclasses.replace(sig, tau_s=_derived_tau_s(self.design, sig.theta, sig.q),
                                      tau_s_derived=True)
            object.__setattr__(self, "signals", sig)
        _check_samples(sig.columns(include_derived=False), rate, self.design.environment.locked, _Origin())

    @property
    def dt(self) -> float:
        """Sampling period 1/rate_hz [s]."""
        return 1.0 / self.rate_hz

    @property
    def n_samples(self) -> int:
        """Number of rows [-]."""
        return len(self.signals)

    @property
    def duration(self) -> float:
        """Time covered by the rows, n_samples * dt [s] (each row holds for one period)."""
        return self.n_samples * self.dt

    def declared(self) -> dict[str, Any]:
        """What the log declares, for JSON: its nominal model (:meth:`Design.to_mapping`), ``rate_hz`` [Hz] and
        ``duration_s`` [s]."""
        return {**self.design.to_mapping(), "rate_hz": self.rate_hz, "duration_s": self.duration}

    def window(self, t0: float | None = None, t1: float | None = None) -> "Experiment":
        """The rows with ``t0 <= t < t1`` as a new experiment.

        Parameters
        ----------
        t0 : float, optional
            Start time, inclusive; ``None`` for the first row [s].
        t1 : float, optional
            End time, exclusive; ``None`` for past the last row [s].

        Returns
        -------
        Experiment
            Same design, rate and description; ``data`` and ``source`` are cleared
            because the rows no longer match a file.

        Raises
        ------
        ParameterError
            If ``t1 <= t0`` or no row falls in the window.
        """
        t = self.signals.t
        start = 0 if t0 is None else int(np.searchsorted(t, t0, side="left"))
        stop = len(t) if t1 is None else int(np.searchsorted(t, t1, side="left"))
        if t0 is not None and t1 is not None and not t1 > t0:
            raise ParameterError(f"window needs t1 > t0 [s], got t0 = {t0!r}, t1 = {t1!r}",
                                 name="t1", value=t1)
        if stop <= start:
            raise ParameterError(
                f"window [{t0!r}, {t1!r}) s holds no samples; the log covers "
                f"[{float(t[0])!r}, {float(t[-1])!r}] s", name="t0", value=t0,
            )
        return dataclasses.replace(self, signals=self.signals.slice(start, stop), data=None, source=None)

    def replace_signals(self, **columns: Any) -> "Experiment":
        """A copy with some signals replaced.

        Parameters
        ----------
        **columns : array_like or None
            Any of ``t``, ``tau_m``, ``theta``, ``q``, ``tau_s``, ``tau_r`` (shape (n,),
            units as in :class:`Signals`) or ``extra`` (a mapping). ``tau_s=None``
            makes ``tau_s`` derived; ``tau_s=array`` makes it measured.

        Returns
        -------
        Experiment
            The new experiment, validated like a loaded one.

        Raises
        ------
        ParameterError
            If a keyword is not a signal name.
        """
        allowed = _SPEC_COLUMNS + ("extra",)
        for name in columns:
            if name not in allowed:
                raise ParameterError(
                    f"unknown signal '{name}'; allowed: {', '.join(allowed)}", name=name, value=None
                )
        changes = dict(columns)
        if "tau_s" in changes:
            changes["tau_s_derived"] = changes["tau_s"] is None
        return dataclasses.replace(self, signals=dataclasses.replace(self.signals, **changes))

    def to_mapping(self, *, data: str | None = None) -> dict[str, Any]:
        """The TOML file's content as nested dicts.

        Parameters
        ----------
        data : str, optional
            Value of the ``data`` key; defaults to ``self.data``.

        Returns
        -------
        dict
            Keys ``format``, ``description`` (when not empty), ``data``, ``sampling``,
            ``testbed``, ``environment`` and, when present, ``controller`` and
            ``compensator``.

        Raises
        ------
        ParameterError
            If neither ``data`` nor ``self.data`` is set.
        """
        data = self.data if data is None else data
        if not data:
            raise ParameterError("the experiment has no CSV name; pass data='run.csv'",
                                 name="data", value=data)
        out: dict[str, Any] = {"format": FORMAT}
        if self.description:
            out["description"] = self.description
        out["data"] = data
        out["sampling"] = {"rate_hz": self.rate_hz}
        out["testbed"] = self.design.testbed.to_mapping()
        out["environment"] = self.design.environment.to_mapping()
        if self.design.controller is not None:
            out["controller"] = self.design.controller.to_mapping()
        if self.design.compensator is not None:
            out["compensator"] = self.design.compensator.to_mapping()
        return out

    def summary(self) -> dict[str, Any]:
        """A JSON-ready overview (for ``forecast-design`` verbs that inspect a log).

        Returns
        -------
        dict
            ``source``, ``description``, ``rate_hz`` [Hz], ``n_samples``, ``t_start_s`` [s],
            ``duration_s`` [s], ``columns`` (CSV order),
            ``tau_s_derived``, ``locked``, ``has_controller``, ``compensator`` (kind or None),
            ``design`` (TOML tables).
        """
        mapping = self.to_mapping(data=self.data or "-")
        return {
            "source": None if self.source is None else str(self.source),
            "description": self.description,
            "rate_hz": self.rate_hz,
            "n_samples": self.n_samples,
            "t_start_s": float(self.signals.t[0]),
            "duration_s": self.duration,
            "columns": list(self.signals.columns()),
            "tau_s_derived": self.signals.tau_s_derived,
            "locked": self.design.environment.locked,
            "has_controller": self.design.controller is not None,
            "compensator": None if self.design.compensator is None else self.design.compensator.kind,
            "design": {k: mapping[k] for k in ("testbed", "environment", "controller", "compensator")
                       if k in mapping},
        }


def experiment_from_arrays(design: Design, rate_hz: float, t: Any, tau_m: Any, theta: Any, q: Any,
                           tau_s: Any = None, tau_r: Any = None,
                           extra: Mapping[str, Any] | None = None,
                           description: str = "") -> Experiment:
    """Build an experiment from arrays, validated like a loaded file.

    Parameters
    ----------
    design : Design
        Nominal design (and controller/compensator that ran).
    rate_hz : float
        Sampling rate [Hz]; ``t`` must step by ``1/rate_hz`` within 1 %.
    t : array_like, shape (n,)
        Sample times [s].
    tau_m : array_like, shape (n,)
        Motor torque command [N m].
    theta : array_like, shape (n,)
        Motor angle [rad].
    q : array_like, shape (n,)
        Environment angle; zeros when ``design.environment.locked`` [rad].
    tau_s : array_like, shape (n,), optional
        Measured spring torque; derived as ``k (theta - q)`` when omitted [N m].
    tau_r : array_like, shape (n,), optional
        Force reference [N m].
    extra : Mapping[str, array_like], optional
        Further columns, kept in order.
    description : str
        Free text.

    Returns
    -------
    Experiment
        The experiment (``data`` and ``source`` unset).

    Raises
    ------
    ExperimentFormatError
        On any rule of the format, naming the signal and the sample index.

    Examples
    --------
    >>> import numpy as np
    >>> from forecast_design.params import Design
    >>> t = np.arange(4) / 1000.0
    >>> exp = experiment_from_arrays(Design.nominal("locked"), 1000.0, t, 0 * t, 0.01 + 0 * t, 0 * t)
    >>> exp.signals.tau_s_derived, float(exp.signals.tau_s[0])
    (True, 0.58)
    """
    signals = Signals(t=t, tau_m=tau_m, theta=theta, q=q, tau_s=tau_s, tau_r=tau_r,
                      extra={} if extra is None else extra)
    return Experiment(design=design, rate_hz=rate_hz, signals=signals, description=description)


# --- files (the reading and writing live in experiment_io) ---------------------------


def load_experiment(path: str | os.PathLike[str], *, max_samples: int | None = None,
                    reader: str = "this command") -> Experiment:
    """Read an experiment (TOML + CSV) and check it against the format.

    Parameters
    ----------
    path : str or os.PathLike
        The TOML file. Its ``data`` key names the CSV file, relative to the TOML's folder.
    max_samples : int, optional
        Most samples accepted, checked from the file's size and line breaks before the CSV is
        parsed (default ``experiment_io.DEFAULT_MAX_SAMPLES``, 2**24; each CLI verb states its own,
        ``limits.COMPUTATION_LIMITS``).
    reader : str
        Who reads the log (named in the message of ``max_samples``).

    Returns
    -------
    Experiment
        The experiment; ``source`` is ``path`` and ``data`` the ``data`` key. When the CSV
        has no ``tau_s`` column, ``signals.tau_s = k (theta - q)`` [N m] and
        ``signals.tau_s_derived`` is True.

    Raises
    ------
    ExperimentFormatError
        On any violation of the format, with a one-line message that names the file
        and the key, column or CSV line (the header is line 1).

    Notes
    -----
    Sampling checks: every step of ``t`` and the mean step must lie within
    ``RATE_TOLERANCE`` (1 %) of ``1/rate_hz``; with ``locked = true``, ``|q|`` must not
    exceed ``LOCKED_Q_TOLERANCE`` (1e-9 rad). The files are read by
    :func:`forecast_design.experiment_io.read_experiment_files` (regular files only; a
    columnar reader, about 140 bytes of memory per sample, linear; see that module for the
    accepted CSV dialect). A CSV whose checksum differs from the one its TOML records
    (an interrupted save, a hand edit) is an error naming both files.
    """
    files = read_experiment_files(path, max_samples=max_samples, reader=reader)
    toml_label = str(files.toml_path)
    origin = _Origin(prefix=f"{files.csv_label}: ", rate_label=f"[sampling] rate_hz of {toml_label}",
                     locked_label=f"locked = true in {toml_label}", path=files.csv_label, first_line=2)
    columns = files.columns
    # The reader's columns are handed over: Signals keeps them (read-only) without a copy.
    signals = Signals(
        **{name: (_Adopt(columns[name]) if name in columns else None) for name in _SPEC_COLUMNS},
        extra={name: _Adopt(columns[name]) for name in files.names if name not in _SPEC_COLUMNS},
    )
    try:  # Experiment applies the sample rules once; a failure is reported again naming CSV lines
        return Experiment(design=files.design, rate_hz=files.rate_hz, signals=signals,
                          description=files.description, data=files.data, source=files.toml_path)
    except ExperimentFormatError:
        _check_samples(columns, files.rate_hz, files.design.environment.locked, origin)
        raise


def save_experiment(experiment: Experiment, path: str | os.PathLike[str], *,
                    data: str | os.PathLike[str] | None = None,
                    sidecars: Mapping[str | os.PathLike[str], Any] | None = None) -> Path:
    """Write an experiment as TOML + CSV, atomically as a set.

    Parameters
    ----------
    experiment : Experiment
        What to write. A derived ``tau_s`` is not written (it is derived again on load).
    path : str or os.PathLike
        The TOML file to write; folders are created as needed.
    data : str or os.PathLike, optional
        The CSV path, relative to the TOML's folder (an absolute path is made relative).
        Default: the TOML name with suffix ``.csv``.
    sidecars : Mapping[path, content], optional
        Further files written in the same set, before the CSV and the TOML (content as
        :func:`forecast_design.fileio.atomic_write`: text, bytes or chunks).

    Returns
    -------
    pathlib.Path
        The TOML path.

    Notes
    -----
    Values are written with ``%.17g``, so :func:`load_experiment` gives back bit-identical
    arrays. Both files are complete on disk before either replaces an old one, the
    TOML last; the TOML's last line is a comment with the CSV's size and CRC-32, checked
    on load. Temporary files are removed on every failure. ``Compensator.q_family`` and
    ``q_order`` are not part of the format and are not stored.

    Raises
    ------
    OutputError
        If a file cannot be written (the message names it); the old files stay.
    """
    if not isinstance(experiment, Experiment):
        raise ParameterError(f"experiment must be an Experiment, got {type(experiment).__name__}",
                             name="experiment", value=experiment)
    toml_path = Path(path)
    mapping = experiment.to_mapping(data=data_name(toml_path, data))
    return write_experiment_files(toml_path, mapping, experiment.signals.columns(), sidecars)
