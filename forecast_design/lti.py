"""RationalTF: the numeric value a symbolic transfer function evaluates to."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from . import polynomials as poly
from .errors import ParameterError

__all__ = ["RationalTF"]


def _trim(coeffs: Sequence[float]) -> tuple[float, ...]:
    return tuple(float(c) for c in poly.trim(coeffs))


@dataclass(frozen=True, slots=True)
class RationalTF:
    """A rational transfer function with real coefficients.

    Parameters
    ----------
    num, den : sequence of float
        Coefficients in descending powers of s (or z). Leading zeros are dropped.
    dt : float or None
        Sample period [s]; ``None`` for continuous time.
    name : str
        A label, e.g. ``"P"`` or ``"P_n^EA"``.

    Notes
    -----
    There is deliberately no operator algebra: symbolic algebra happens in
    sympy, numeric interconnection in python-control (``tf.to_control()``).
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    dt: float | None = None
    name: str = ""

    def __post_init__(self) -> None:
        for label in ("num", "den"):
            value = getattr(self, label)
            try:
                coeffs = _trim(np.atleast_1d(np.asarray(value, dtype=float)))
            except (TypeError, ValueError):
                coeffs = ()
            if not coeffs or not all(map(math.isfinite, coeffs)) or isinstance(value, (str, bytes)):
                raise ParameterError(f"RationalTF {self.name!r}: {label} must be a non-empty sequence of finite "
                                     f"real numbers, got {value!r:.80}", name=label, value=value)
            object.__setattr__(self, label, coeffs)
        if self.den == (0.0,):
            raise ParameterError(f"RationalTF {self.name!r}: the denominator is zero", name="den", value=self.den)
        if self.dt is not None and not (isinstance(self.dt, (int, float)) and math.isfinite(self.dt) and self.dt > 0):
            raise ParameterError(f"RationalTF {self.name!r}: dt must be None or a sample period > 0 [s], "
                                 f"got {self.dt!r:.80}", name="dt", value=self.dt)

    def normalized(self) -> "RationalTF":
        """Same TF with the denominator's leading coefficient equal to 1."""
        lead = self.den[0]
        return RationalTF(tuple(c / lead for c in self.num), tuple(c / lead for c in self.den),
                          self.dt, self.name)

    def __call__(self, s: complex | np.ndarray) -> complex | np.ndarray:
        """Evaluate at complex ``s`` (or ``z``)."""
        return np.polyval(self.num, s) / np.polyval(self.den, s)

    def freqresp(self, w_rad_s: np.ndarray) -> np.ndarray:
        """Complex frequency response at angular frequencies ``w_rad_s`` [rad/s]."""
        w = np.asarray(w_rad_s, dtype=float)
        x = 1j * w if self.dt is None else np.exp(1j * w * self.dt)
        return self(x)

    def poles(self) -> np.ndarray:
        """Roots of the denominator."""
        return np.roots(self.den)

    def zeros(self) -> np.ndarray:
        """Roots of the numerator."""
        return np.roots(self.num)

    def dcgain(self) -> float:
        """Zero-frequency gain (s = 0 or z = 1); inf at a pole there."""
        x = 0.0 if self.dt is None else 1.0
        d = np.polyval(self.den, x)
        n = np.polyval(self.num, x)
        if d == 0.0:
            return float("inf") if n != 0.0 else float("nan")
        return float(n / d)

    @property
    def relative_degree(self) -> int:
        """deg(den) - deg(num)."""
        return (len(self.den) - 1) - (len(self.num) - 1)

    def to_control(self):
        """The same TF as a ``control.TransferFunction``."""
        import control

        return control.tf(list(self.num), list(self.den), 0 if self.dt is None else self.dt)

    @classmethod
    def from_control(cls, sys, name: str = "") -> "RationalTF":
        """A SISO ``control.TransferFunction`` or ``control.StateSpace`` as a RationalTF.

        Parameters
        ----------
        sys : control.TransferFunction or control.StateSpace
            SISO system (``dt`` 0/None: continuous; ``True`` is refused: the period is needed).
        name : str
            Label (default: the system's own name).

        Returns
        -------
        RationalTF
            The same transfer function.
        """
        import control

        if isinstance(sys, control.StateSpace):
            sys = control.ss2tf(sys)
        if not isinstance(sys, control.TransferFunction):
            raise ParameterError(f"expected a RationalTF, control.TransferFunction or control.StateSpace, "
                                 f"got {type(sys).__name__}", name="L", value=sys)
        if sys.ninputs != 1 or sys.noutputs != 1:
            raise ParameterError(f"only SISO systems are supported, got {sys.noutputs}x{sys.ninputs}",
                                 name="L", value=sys)
        dt = sys.dt
        if dt is True:
            raise ParameterError("discrete system with unspecified period (dt=True): give its sample time",
                                 name="dt", value=dt)
        num, den = sys.num[0][0], sys.den[0][0]
        return cls(tuple(num), tuple(den), None if not dt else float(dt), name or str(sys.name or ""))

    def to_scipy(self):
        """The same TF as ``scipy.signal.TransferFunction`` (or dlti for discrete time)."""
        from scipy import signal

        if self.dt is None:
            return signal.TransferFunction(self.num, self.den)
        return signal.TransferFunction(self.num, self.den, dt=self.dt)

    def to_mapping(self) -> dict:
        """Coefficients normalised to a monic denominator, poles and DC gain (for JSON)."""
        tf = self.normalized()
        return {
            "num": list(tf.num),
            "den": list(tf.den),
            "poles": [[float(p.real), float(p.imag)] for p in sorted(tf.poles(), key=lambda p: (p.real, p.imag))],
            "dc_gain": tf.dcgain(),
        }
