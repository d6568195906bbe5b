"""RationalTF: the numeric value a symbolic transfer function evaluates to."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from . import polynomials as poly
from .errors import ParameterError

__all__ = ["RationalTF"]


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
    The algebra is python-control's (``*``, ``+``, ``-``, ``/``, :meth:`feedback`) with one
    difference that the loop analysis relies on: nothing is ever cancelled. A product or a
    feedback keeps every factor of its operands, so a mode hidden by a pole-zero cancellation
    (an unstable observer mode cancelled in L, say) stays in the characteristic polynomial
    ``feedback().den``; :meth:`minreal` cancels on request. Both operands must be continuous,
    or discrete with the same ``dt``; a number is a static gain.

    Examples
    --------
    >>> C = RationalTF((0.1, 5.0), (1.0,), name="C")          # P + D s
    >>> P = RationalTF((58.0,), (0.133, 0.3, 58.0), name="P")
    >>> [round(c, 12) for c in (C * P).feedback().den]         # den + num, nothing cancelled
    [0.133, 6.1, 348.0]
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    dt: float | None = None
    name: str = ""

    def __post_init__(self) -> None:
        for label in ("num", "den"):
            value = getattr(self, label)
            try:
                arr = np.atleast_1d(np.asarray(value, dtype=float))
                nz = np.flatnonzero(arr)
                arr = arr[nz[0]:] if nz.size else arr[-1:]
                ok = arr.ndim == 1 and arr.size > 0 and bool(np.isfinite(arr).all())
                coeffs = tuple(arr.tolist()) if ok else ()
            except (TypeError, ValueError):
                coeffs = ()
            if not coeffs or isinstance(value, (str, bytes)):
                raise ParameterError(f"RationalTF {self.name!r}: {label} must be a non-empty sequence of finite "
                                     f"real numbers, got {value!r:.80}", name=label, value=value)
            object.__setattr__(self, label, coeffs)
        if self.den == (0.0,):
            raise ParameterError(f"RationalTF {self.name!r}: the denominator is zero", name="den", value=self.den)
        if self.dt is not None and not (isinstance(self.dt, (int, float)) and math.isfinite(self.dt) and self.dt > 0):
            raise ParameterError(f"RationalTF {self.name!r}: dt must be None or a sample period > 0 [s], "
                                 f"got {self.dt!r:.80}", name="dt", value=self.dt)

    # --- algebra (python-control's operators, no cancellation) ---------------------------------

    def _coerce(self, other: "RationalTF | float") -> "RationalTF":
        if isinstance(other, RationalTF):
            if (self.dt is None) != (other.dt is None) or (self.dt is not None and self.dt != other.dt):
                raise ParameterError(f"RationalTF {self.name!r} (dt {self.dt}) and {other.name!r} (dt {other.dt}) "
                                     "are not on the same time base", name="dt", value=other.dt)
            return other
        if isinstance(other, (int, float, np.integer, np.floating)) and not isinstance(other, bool) \
                and math.isfinite(other):
            return RationalTF((float(other),), (1.0,), self.dt)
        raise ParameterError(f"RationalTF {self.name!r}: cannot combine with {type(other).__name__} {other!r:.60}",
                             name="other", value=other)

    def __mul__(self, other: "RationalTF | float") -> "RationalTF":
        o = self._coerce(other)
        return RationalTF(poly.mul(self.num, o.num), poly.mul(self.den, o.den), self.dt)

    __rmul__ = __mul__

    def __add__(self, other: "RationalTF | float") -> "RationalTF":
        o = self._coerce(other)
        return RationalTF(poly.add(poly.mul(self.num, o.den), poly.mul(o.num, self.den)),
                          poly.mul(self.den, o.den), self.dt)

    __radd__ = __add__

    def __neg__(self) -> "RationalTF":
        return RationalTF(tuple(-c for c in self.num), self.den, self.dt, self.name)

    def __sub__(self, other: "RationalTF | float") -> "RationalTF":
        return self + (-self._coerce(other))

    def __rsub__(self, other: "RationalTF | float") -> "RationalTF":
        return self._coerce(other) + (-self)

    def inv(self) -> "RationalTF":
        """``1 / self`` (den / num) [-]; refused for the zero TF."""
        if self.num == (0.0,):
            raise ParameterError(f"RationalTF {self.name!r} is zero: it has no inverse", name="num", value=self.num)
        return RationalTF(self.den, self.num, self.dt)

    def __truediv__(self, other: "RationalTF | float") -> "RationalTF":
        return self * self._coerce(other).inv()

    def __rtruediv__(self, other: "RationalTF | float") -> "RationalTF":
        return self._coerce(other) * self.inv()

    def feedback(self, other: "RationalTF | float" = 1.0, sign: int = -1) -> "RationalTF":
        """Closed loop ``self / (1 - sign self other)`` (negative feedback by default), nothing cancelled.

        Parameters
        ----------
        other : RationalTF or float
            The feedback path H (default 1: unity feedback).
        sign : int
            -1 (negative feedback, python-control's default) or +1.

        Returns
        -------
        RationalTF
            ``G d_H / (d_G d_H - sign n_G n_H)``; its denominator is the characteristic
            polynomial of the loop with every mode of G and H kept.
        """
        if sign not in (-1, 1):
            raise ParameterError(f"feedback sign must be -1 or +1, got {sign!r}", name="sign", value=sign)
        h = self._coerce(other)
        return RationalTF(poly.mul(self.num, h.den),
                          poly.add(poly.mul(self.den, h.den), -sign * poly.mul(self.num, h.num)), self.dt)

    def minreal(self, rtol: float = 1e-7) -> "RationalTF":
        """Remove pole-zero pairs that coincide to ``rtol`` (python-control's ``minreal``, on request).

        Parameters
        ----------
        rtol : float
            Relative distance under which a zero cancels a pole [-].

        Returns
        -------
        RationalTF
            The reduced TF with the same leading-coefficient ratio and name.
        """
        if self.num == (0.0,) or len(self.den) == 1 or len(self.num) == 1:
            return self
        zeros = list(np.roots(self.num))
        keep_p = []
        for p in np.roots(self.den):
            best = None
            for i, z in enumerate(zeros):
                if abs(z - p) <= rtol * max(1.0, abs(p)) and (best is None or abs(z - p) < abs(zeros[best] - p)):
                    best = i
            if best is None:
                keep_p.append(p)
            else:
                zeros.pop(best)
        if len(keep_p) == len(self.den) - 1:
            return self
        num = np.real_if_close(np.poly(zeros)) * self.num[0] if zeros else np.array([self.num[0]])
        den = np.real_if_close(np.poly(keep_p)) * self.den[0] if keep_p else np.array([self.den[0]])
        return RationalTF(tuple(np.real(num)), tuple(np.real(den)), self.dt, self.name)

    def named(self, name: str) -> "RationalTF":
        """The same TF labelled ``name``."""
        return RationalTF(self.num, self.den, self.dt, name)

    @property
    def is_proper(self) -> bool:
        """deg(num) <= deg(den)."""
        return self.relative_degree >= 0

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
