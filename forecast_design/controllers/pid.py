"""PD and PID force controllers (experiment format kinds ``pd`` and ``pid``).

``u = P e + I/s e + D s/(T_f s + 1) e`` with ``e = tau_r - tau_s``; with
``derivative_on = "measurement"`` the derivative term acts on ``-tau_s`` instead of ``e``
(no kick at a reference step). The default discretisation is backward Euler, so an
unfiltered derivative (``T_f = 0``) runs as ``D (e_k - e_(k-1)) rate_hz``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from ..errors import ParameterError
from ..lti import RationalTF
from ..limits import check_number, check_physical
from .base import (
    ANTI_WINDUP,
    DERIVATIVE_ON,
    DiscreteLaw,
    IntegratorLaw,
    LawChannel,
    LinearController,
    format_number,
)

__all__ = ["PD", "PID"]

_OPTION_KEYS = ("discretization", "prewarp_hz", "feedforward", "u_min", "u_max")


def _gain(owner: str, name: str, value: Any) -> float:
    return check_physical(owner, name, check_number(owner, name, value))


def _derivative_tf(D: float, T_f: float) -> RationalTF:
    """``D s / (T_f s + 1)`` (improper ``D s`` when ``T_f = 0``) [N m s/N m]."""
    return RationalTF((D, 0.0), (T_f, 1.0) if T_f > 0.0 else (1.0,), name="C_D")


@dataclass(frozen=True, slots=True, kw_only=True)
class PD(LinearController):
    """PD force controller ``u = P e + D s/(T_f s + 1) e`` (format kind ``pd``).

    Parameters
    ----------
    P : float
        Proportional gain [N m/N m].
    D : float
        Derivative gain [N m s/N m].
    T_f : float
        Derivative filter time constant [s] (0: unfiltered).
    derivative_on : str
        ``error`` (default) or ``measurement``.
    discretization : str
        Default ``backward-euler`` (the format's).
    prewarp_hz, feedforward, u_min, u_max
        See :class:`~forecast_design.controllers.base.LinearController`.

    Examples
    --------
    >>> c = PD(P=5.0, D=0.1)
    >>> c.spelling(), c.feedback_tf().num
    ('pd:5:0.1', (0.1, 5.0))
    >>> c.discrete_law(2000.0).feedback_tf().num     # backward Euler: 5 + 0.1 (1 - 1/z) 2000
    (205.0, -200.0)
    """

    kind: ClassVar[str] = "pd"
    keys: ClassVar[tuple[str, ...]] = ("P", "D", "T_f", "derivative_on", *_OPTION_KEYS)
    required: ClassVar[tuple[str, ...]] = ("P", "D")
    positional: ClassVar[tuple[tuple[str, ...], tuple[str, ...]]] = (("P", "D"), ("T_f",))

    P: float = 5.0
    D: float = 0.1
    T_f: float = 0.0
    derivative_on: str = "error"
    discretization: str = "backward-euler"

    def __post_init__(self) -> None:
        owner = "[controller]"
        for name in ("P", "D", "T_f"):
            object.__setattr__(self, name, _gain(owner, name, getattr(self, name)))
        if self.derivative_on not in DERIVATIVE_ON:
            raise ParameterError(f"{owner} derivative_on must be one of {', '.join(DERIVATIVE_ON)}, "
                                 f"got {self.derivative_on!r}", name="derivative_on", value=self.derivative_on)
        self._check_options()
        if self.D and not self.T_f and self.discretization != "backward-euler":
            raise ParameterError(f"{owner} an unfiltered derivative (T_f = 0) runs only with discretization "
                                 f"'backward-euler' ({self.discretization} would put a pole at z = -1 or none at "
                                 "all): give T_f > 0 [s]", name="T_f", value=self.T_f)

    # the I/s part: none for a PD
    def _integral(self) -> float:
        return 0.0

    def _proportional_tf(self) -> RationalTF:
        """``P`` (+ ``I/s``): the part that always acts on the error."""
        I = self._integral()
        return RationalTF((self.P, I), (1.0, 0.0), name="C_PI") if I else RationalTF((self.P,), (1.0,), name="C_P")

    def feedback_tf(self) -> RationalTF:
        """``P (+ I/s) + D s/(T_f s + 1)`` [N m/N m] (improper when ``T_f = 0`` and ``D > 0``)."""
        total = self._proportional_tf() + _derivative_tf(self.D, self.T_f) if self.D else self._proportional_tf()
        return total.named("C_F")

    def reference_tf(self) -> RationalTF:
        """``C(s)`` (derivative on the error) or ``P (+ I/s)`` (on the measurement), plus the feed-forward."""
        base = self.feedback_tf() if self.derivative_on == "error" else self._proportional_tf()
        return (base + self.feedforward).named("C_r") if self.feedforward else base.named("C_r")

    def _integrator(self, rate_hz: float) -> IntegratorLaw | None:
        return None

    def discrete_law(self, rate_hz: float) -> DiscreteLaw:
        """The PD (PID) difference equation at ``rate_hz`` [Hz] (module docstring).

        Parameters
        ----------
        rate_hz : float
            Control rate [Hz].

        Returns
        -------
        DiscreteLaw
            ``error`` channel ``P + D-term`` (derivative on the error) or ``P`` plus a ``tau_s``
            channel ``-D-term`` (on the measurement); a PID's integrator separately, with its
            anti-windup; the feed-forward and the saturation.
        """
        p_part = RationalTF((self.P,), (1.0,))
        d_part = _derivative_tf(self.D, self.T_f) if self.D else None
        if self.derivative_on == "error":
            main = p_part + d_part if d_part is not None else p_part
            channels = [LawChannel("error", self._discretize(main, rate_hz, "C_F"), "ctl")]
        else:
            channels = [LawChannel("error", self._discretize(p_part, rate_hz, "C_P"), "ctl")]
            if d_part is not None:
                channels.append(LawChannel("tau_s", self._discretize(-d_part, rate_hz, "C_D"), "d_meas"))
        return self._options_law(rate_hz, channels, self._integrator(rate_hz))

    def spelling(self) -> str:
        """``pd:P:D[:T_f][:key=value...]``."""
        head = f"{self.kind}:{format_number(self.P)}:{self._middle()}{format_number(self.D)}"
        if self.T_f:
            head += f":{format_number(self.T_f)}"
        extra = ":derivative_on=measurement" if self.derivative_on == "measurement" else ""
        return head + self._pid_spelling() + extra + self._options_spelling("backward-euler")

    def _middle(self) -> str:
        return ""

    def _pid_spelling(self) -> str:
        return ""


@dataclass(frozen=True, slots=True, kw_only=True)
class PID(PD):
    """PID force controller ``u = P e + I/s e + D s/(T_f s + 1) e`` (format kind ``pid``).

    Parameters
    ----------
    P : float
        Proportional gain [N m/N m].
    I : float
        Integral gain [1/s].
    D : float
        Derivative gain [N m s/N m] (default 0).
    T_f : float
        Derivative filter time constant [s] (0: unfiltered).
    anti_windup : str
        ``none`` (default), ``clamping`` (conditional integration) or ``back-calculation``
        (needs ``T_t``); both need ``u_min`` and ``u_max``.
    T_t : float or None
        Back-calculation tracking time constant [s].
    derivative_on, discretization, prewarp_hz, feedforward, u_min, u_max
        As for :class:`PD`.

    Examples
    --------
    >>> c = PID(P=6.0, I=20.0, D=0.05, T_f=0.002)
    >>> c.spelling()
    'pid:6:20:0.05:0.002'
    >>> law = c.discrete_law(2000.0)
    >>> law.integrator.b0, law.integrator.b1          # backward Euler: I T e_k
    (0.01, 0.0)
    """

    kind: ClassVar[str] = "pid"
    keys: ClassVar[tuple[str, ...]] = ("P", "I", "D", "T_f", "anti_windup", "T_t", "derivative_on", *_OPTION_KEYS)
    required: ClassVar[tuple[str, ...]] = ("P", "I", "D")
    positional: ClassVar[tuple[tuple[str, ...], tuple[str, ...]]] = (("P", "I", "D"), ("T_f",))

    I: float = 0.0
    D: float = 0.0
    anti_windup: str = "none"
    T_t: float | None = None

    def __post_init__(self) -> None:
        PD.__post_init__(self)
        owner = "[controller]"
        object.__setattr__(self, "I", _gain(owner, "I", self.I))
        if self.anti_windup not in ANTI_WINDUP:
            raise ParameterError(f"{owner} anti_windup must be one of {', '.join(ANTI_WINDUP)}, "
                                 f"got {self.anti_windup!r}", name="anti_windup", value=self.anti_windup)
        if self.anti_windup != "none" and (self.u_min is None or self.u_max is None):
            raise ParameterError(f"{owner} anti_windup = {self.anti_windup!r} needs u_min and u_max [N m]",
                                 name="anti_windup", value=self.anti_windup)
        if self.anti_windup == "back-calculation":
            if self.T_t is None:
                raise ParameterError(f"{owner} anti_windup = 'back-calculation' needs T_t [s]", name="T_t", value=None)
            object.__setattr__(self, "T_t", check_physical(owner, "T_t", check_number(owner, "T_t", self.T_t,
                                                                                      positive=True)))
        elif self.T_t is not None:
            raise ParameterError(f"{owner} T_t applies to anti_windup = 'back-calculation', not "
                                 f"{self.anti_windup!r}", name="T_t", value=self.T_t)

    def _integral(self) -> float:
        return self.I

    def _integrator(self, rate_hz: float) -> IntegratorLaw | None:
        if not self.I:
            return None
        d = self._discretize(RationalTF((self.I,), (1.0, 0.0)), rate_hz, "C_I")
        # every method maps I/s to (b0 z + b1)/(z - 1): the accumulator the anti-windup acts on
        b0, b1 = d.num[-2], d.num[-1]
        back = (1.0 / rate_hz) / self.T_t if self.anti_windup == "back-calculation" else 0.0
        return IntegratorLaw(float(b0), float(b1), self.anti_windup, back)

    def _middle(self) -> str:
        return f"{format_number(self.I)}:"

    def _pid_spelling(self) -> str:
        out = ""
        if self.anti_windup != "none":
            out += f":anti_windup={self.anti_windup}"
        if self.T_t is not None:
            out += f":T_t={format_number(self.T_t)}"
        return out
