"""Reference signals (force references, or open-loop torque profiles) as functions of time.

Every reference is a frozen dataclass with a ``kind`` (its scenario-file
name), ``__call__(t) -> ndarray`` (vectorised, t in [s], value in [N m])
and ``to_mapping``; :func:`reference_from_mapping` reads them back with
the strict unknown/missing-key rules of the experiment format.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from ..errors import ExperimentFormatError, ParameterError
from ..params import check_number

__all__ = [
    "Constant",
    "Step",
    "Square",
    "Sine",
    "Multisine",
    "Chirp",
    "Ramp",
    "PiecewiseLinear",
    "REFERENCE_KINDS",
    "reference_from_mapping",
]


def _f(owner: str, name: str, value: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    return check_number(owner, name, value, positive=positive, nonneg=nonneg)


def _floats(owner: str, name: str, values: Any) -> tuple[float, ...]:
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise ParameterError(f"{owner} {name} must be a list of numbers, got {values!r}", name=name, value=values)
    return tuple(_f(owner, f"{name}[{i}]", v) for i, v in enumerate(values))


class _Ref:
    kind: ClassVar[str]

    def to_mapping(self) -> dict[str, Any]:
        """The ``[reference]`` table: ``kind`` plus the fields."""
        out: dict[str, Any] = {"kind": self.kind}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    def sample(self, n: int, rate_hz: float, t0: float = 0.0) -> np.ndarray:
        """Values at ``t0 + k / rate_hz``, k = 0..n-1 [N m]."""
        return np.asarray(self(t0 + np.arange(n) / rate_hz), dtype=float)


@dataclass(frozen=True, slots=True, kw_only=True)
class Constant(_Ref):
    """``value`` for all t."""

    kind: ClassVar[str] = "constant"
    value: float = 0.0   # [N m]

    def __post_init__(self) -> None:
        object.__setattr__(self, "value", _f("constant", "value", self.value))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m]."""
        return np.full(np.shape(t), self.value)


@dataclass(frozen=True, slots=True, kw_only=True)
class Step(_Ref):
    """``offset`` before ``t0``, ``offset + amplitude`` from ``t0`` on."""

    kind: ClassVar[str] = "step"
    amplitude: float = 0.2   # [N m]
    t0: float = 0.0          # step time [s]
    offset: float = 0.0      # [N m]

    def __post_init__(self) -> None:
        for n in ("amplitude", "t0", "offset"):
            object.__setattr__(self, n, _f("step", n, getattr(self, n)))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m]."""
        t = np.asarray(t, dtype=float)
        return self.offset + self.amplitude * (t >= self.t0)


@dataclass(frozen=True, slots=True, kw_only=True)
class Square(_Ref):
    """Square wave between ``low`` and ``high``, starting high at ``t0`` (``low`` before).

    High for the first ``duty`` fraction of each ``period_s``.
    """

    kind: ClassVar[str] = "square"
    high: float = 1.0        # [N m]
    low: float = -1.0        # [N m]
    period_s: float = 2.0    # [s]
    duty: float = 0.5        # high fraction of a period [-]
    t0: float = 0.0          # start [s]

    def __post_init__(self) -> None:
        for n in ("high", "low", "t0"):
            object.__setattr__(self, n, _f("square", n, getattr(self, n)))
        object.__setattr__(self, "period_s", _f("square", "period_s", self.period_s, positive=True))
        duty = _f("square", "duty", self.duty)
        if not 0.0 < duty < 1.0:
            raise ParameterError(f"square duty must be in (0, 1), got {duty!r}", name="duty", value=duty)
        object.__setattr__(self, "duty", duty)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m]."""
        t = np.asarray(t, dtype=float)
        phase = np.mod(t - self.t0, self.period_s) / self.period_s
        return np.where((t >= self.t0) & (phase < self.duty), self.high, self.low)


@dataclass(frozen=True, slots=True, kw_only=True)
class Sine(_Ref):
    """``offset + amplitude sin(2 pi frequency_hz (t - t0) + phase_rad)`` for t >= t0, offset before."""

    kind: ClassVar[str] = "sine"
    amplitude: float = 0.5      # [N m]
    frequency_hz: float = 1.0   # [Hz]
    phase_rad: float = 0.0      # [rad]
    offset: float = 0.0         # [N m]
    t0: float = 0.0             # [s]

    def __post_init__(self) -> None:
        for n in ("amplitude", "phase_rad", "offset", "t0"):
            object.__setattr__(self, n, _f("sine", n, getattr(self, n)))
        object.__setattr__(self, "frequency_hz", _f("sine", "frequency_hz", self.frequency_hz, nonneg=True))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m]."""
        t = np.asarray(t, dtype=float)
        x = self.amplitude * np.sin(2.0 * np.pi * self.frequency_hz * (t - self.t0) + self.phase_rad)
        return self.offset + np.where(t >= self.t0, x, 0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class Multisine(_Ref):
    """``offset + sum_i amplitudes[i] sin(2 pi frequencies_hz[i] t + phases_rad[i])``.

    Empty ``phases_rad`` selects Schroeder phases ``-pi i (i - 1) / N``
    (i = 1..N), which keep the crest factor low.
    """

    kind: ClassVar[str] = "multisine"
    amplitudes: tuple[float, ...] = (0.2, 0.2, 0.2)        # [N m]
    frequencies_hz: tuple[float, ...] = (0.5, 2.0, 8.0)    # [Hz]
    phases_rad: tuple[float, ...] = ()                     # [rad]
    offset: float = 0.0                                    # [N m]

    def __post_init__(self) -> None:
        a = _floats("multisine", "amplitudes", self.amplitudes)
        f = _floats("multisine", "frequencies_hz", self.frequencies_hz)
        p = _floats("multisine", "phases_rad", self.phases_rad)
        if len(a) != len(f) or (p and len(p) != len(a)) or not a:
            raise ParameterError("multisine amplitudes, frequencies_hz (and phases_rad if given) need the same "
                                 f"non-zero length, got {len(a)}, {len(f)}, {len(p)}", name="amplitudes", value=a)
        object.__setattr__(self, "amplitudes", a)
        object.__setattr__(self, "frequencies_hz", f)
        object.__setattr__(self, "phases_rad", p)
        object.__setattr__(self, "offset", _f("multisine", "offset", self.offset))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m]."""
        t = np.asarray(t, dtype=float)
        n = len(self.amplitudes)
        phases = self.phases_rad or tuple(-math.pi * i * (i - 1) / n for i in range(1, n + 1))
        out = np.full(t.shape, self.offset)
        for a, f, p in zip(self.amplitudes, self.frequencies_hz, phases):
            out = out + a * np.sin(2.0 * np.pi * f * t + p)
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class Chirp(_Ref):
    """Swept sine from ``f0_hz`` to ``f1_hz`` over ``duration_s`` (then held at ``f1_hz``).

    ``method``: ``linear`` or ``logarithmic`` frequency sweep (the phase of
    :func:`scipy.signal.chirp`), amplitude ``amplitude`` around ``offset``.
    """

    kind: ClassVar[str] = "chirp"
    amplitude: float = 0.5      # [N m]
    f0_hz: float = 0.1          # [Hz]
    f1_hz: float = 20.0         # [Hz]
    duration_s: float = 10.0    # [s]
    method: str = "logarithmic"
    offset: float = 0.0         # [N m]

    def __post_init__(self) -> None:
        for n in ("amplitude", "offset"):
            object.__setattr__(self, n, _f("chirp", n, getattr(self, n)))
        for n in ("f0_hz", "f1_hz", "duration_s"):
            object.__setattr__(self, n, _f("chirp", n, getattr(self, n), positive=True))
        if self.method not in ("linear", "logarithmic"):
            raise ParameterError(f"chirp method must be linear or logarithmic, got {self.method!r}",
                                 name="method", value=self.method)

    def phase(self, t: np.ndarray) -> np.ndarray:
        """Instantaneous phase [rad] at times ``t`` [s] (0 at t = 0, d/dt = 2 pi f(t))."""
        t = np.asarray(t, dtype=float)
        T, f0, f1 = self.duration_s, self.f0_hz, self.f1_hz
        tc = np.clip(t, 0.0, T)
        if self.method == "linear" or f0 == f1:
            ph = 2.0 * np.pi * (f0 * tc + 0.5 * (f1 - f0) * tc**2 / T)
        else:
            beta = T / math.log(f1 / f0)
            ph = 2.0 * np.pi * f0 * beta * (np.power(f1 / f0, tc / T) - 1.0)
        return ph + 2.0 * np.pi * f1 * np.maximum(t - T, 0.0)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m] (``offset`` for t < 0)."""
        t = np.asarray(t, dtype=float)
        return self.offset + self.amplitude * np.where(t >= 0.0, np.sin(self.phase(t)), 0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class Ramp(_Ref):
    """``offset + slope (t - t0)`` for t >= t0 (``offset`` before), clipped to +-``limit``."""

    kind: ClassVar[str] = "ramp"
    slope: float = 0.1          # [N m/s]
    t0: float = 0.0             # [s]
    offset: float = 0.0         # [N m]
    limit: float = math.inf     # |value| bound [N m]

    def __post_init__(self) -> None:
        for n in ("slope", "t0", "offset"):
            object.__setattr__(self, n, _f("ramp", n, getattr(self, n)))
        if not (isinstance(self.limit, (int, float)) and self.limit > 0):
            raise ParameterError(f"ramp limit must be > 0, got {self.limit!r}", name="limit", value=self.limit)
        object.__setattr__(self, "limit", float(self.limit))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m]."""
        t = np.asarray(t, dtype=float)
        return np.clip(self.offset + self.slope * np.maximum(t - self.t0, 0.0), -self.limit, self.limit)

    def to_mapping(self) -> dict[str, Any]:
        """The ``[reference]`` table (``limit`` omitted when infinite: TOML has inf but JSON has not)."""
        out = _Ref.to_mapping(self)
        if math.isinf(self.limit):
            del out["limit"]
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class PiecewiseLinear(_Ref):
    """Linear interpolation through ``(times_s[i], values[i])``, held flat outside.

    Useful for open-loop torque profiles (ramps, trapezoids, staircases).
    """

    kind: ClassVar[str] = "piecewise_linear"
    times_s: tuple[float, ...] = (0.0, 1.0)   # strictly increasing [s]
    values: tuple[float, ...] = (0.0, 0.0)    # [N m]

    def __post_init__(self) -> None:
        ts = _floats("piecewise_linear", "times_s", self.times_s)
        vs = _floats("piecewise_linear", "values", self.values)
        if len(ts) != len(vs) or len(ts) < 1 or any(b <= a for a, b in zip(ts, ts[1:])):
            raise ParameterError("piecewise_linear times_s must be strictly increasing and as long as values",
                                 name="times_s", value=ts)
        object.__setattr__(self, "times_s", ts)
        object.__setattr__(self, "values", vs)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Value at times ``t`` [s] -> [N m]."""
        return np.interp(np.asarray(t, dtype=float), self.times_s, self.values)


#: Reference classes by ``kind``.
REFERENCE_KINDS: Mapping[str, type] = {
    c.kind: c for c in (Constant, Step, Square, Sine, Multisine, Chirp, Ramp, PiecewiseLinear)
}


def reference_from_mapping(mapping: Mapping[str, Any], *, source: str | None = None, where: str = "reference"):
    """Build a reference from its table ``{"kind": ..., <field>: ...}``.

    Parameters
    ----------
    mapping : Mapping
        The table; omitted fields take their defaults.
    source : str, optional
        File name for error messages.
    where : str
        Table name for error messages.

    Returns
    -------
    Reference
        One of :data:`REFERENCE_KINDS`.

    Raises
    ------
    ExperimentFormatError
        Missing/unknown ``kind``, unknown key or invalid value (naming file and key).
    """
    prefix = f"{source}: " if source else ""
    if not isinstance(mapping, Mapping):
        raise ExperimentFormatError(f"{prefix}[{where}] must be a table", path=source, key=where)
    if "kind" not in mapping:
        raise ExperimentFormatError(f"{prefix}[{where}] missing required key 'kind'; one of "
                                    f"{', '.join(REFERENCE_KINDS)}", path=source, key=f"{where}.kind")
    kind = mapping["kind"]
    if kind not in REFERENCE_KINDS:
        raise ExperimentFormatError(f"{prefix}[{where}] kind must be one of {', '.join(REFERENCE_KINDS)}, got {kind!r}",
                                    path=source, key=f"{where}.kind")
    cls = REFERENCE_KINDS[kind]
    names = [f.name for f in dataclasses.fields(cls)]
    for key in mapping:
        if key != "kind" and key not in names:
            raise ExperimentFormatError(f"{prefix}[{where}] unknown key '{key}' for kind '{kind}'; allowed: "
                                        f"{', '.join(names)}", path=source, key=f"{where}.{key}")
    try:
        return cls(**{k: v for k, v in mapping.items() if k != "kind"})
    except (ParameterError, TypeError) as exc:
        raise ExperimentFormatError(f"{prefix}[{where}] {exc}", path=source, key=where) from None
