"""Controllers given as transfer functions: ``C(s)`` (kind ``tf``) and ``C(z)`` (kind ``discrete``).

Coefficients are in descending powers, python-control's and MATLAB's order. A ``tf``
controller must be proper and is discretised (Tustin by default); a ``discrete`` one runs as
given at the control rate, so it has no continuous law: the continuous loop analysis refuses
it and the sampled analysis uses it exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

from ..errors import ParameterError
from ..lti import RationalTF
from ..limits import check_number
from .base import DiscreteLaw, LawChannel, LinearController, _coefficients, format_number, parse_number

__all__ = ["TFController", "DiscreteController"]

_OPTION_KEYS = ("feedforward", "u_min", "u_max")


def _polynomial_text(coeffs: tuple[float, ...]) -> str:
    return ",".join(format_number(c) for c in coeffs)


def _parse_num_den(cls: type, positional: list[str], options: Mapping[str, str], owner: str) -> dict[str, Any]:
    """``NUM/DEN`` (comma-separated coefficients) and the kind's ``key=value`` fields."""
    if len(positional) != 1 or positional[0].count("/") != 1:
        raise ParameterError(f"{owner}: expected {cls.kind}:NUM/DEN with comma-separated coefficients (descending "
                             "powers), e.g. tf:0.5,10/0.01,1", name="controller", value=owner)
    num_text, den_text = positional[0].split("/")
    kwargs = LinearController.parse_fields.__func__(cls, [], options, owner)
    kwargs["num"] = tuple(parse_number(c, f"{owner} coefficient") for c in num_text.split(","))
    kwargs["den"] = tuple(parse_number(c, f"{owner} coefficient") for c in den_text.split(","))
    return kwargs


def _check_rational(owner: str, num: tuple[float, ...], den: tuple[float, ...], variable: str) -> RationalTF:
    """num/den as a RationalTF: a non-zero leading den coefficient, not all-zero, proper."""
    if den[0] == 0.0:
        raise ParameterError(f"{owner} den[0] = 0: the leading denominator coefficient (highest power of "
                             f"{variable}) must be non-zero", name="den", value=list(den))
    if all(c == 0.0 for c in den):
        raise ParameterError(f"{owner} den is zero", name="den", value=list(den))
    tf = RationalTF(num, den, name="C_F")
    if tf.relative_degree < 0:
        raise ParameterError(f"{owner} C({variable}) = num/den is improper (numerator degree {len(tf.num) - 1} > "
                             f"denominator degree {len(tf.den) - 1}); a force controller must be proper "
                             "(use kind pd/pid for an unfiltered derivative)", name="num", value=list(num))
    return tf


@dataclass(frozen=True, slots=True, kw_only=True)
class TFController(LinearController):
    """``u = C(s) e`` with ``C(s) = num(s)/den(s)`` proper (format kind ``tf``).

    Parameters
    ----------
    num, den : tuple of float
        Coefficients in descending powers of s [N m/N m]; ``den[0] != 0``, proper.
    discretization : str
        Default ``tustin`` (the format's).
    prewarp_hz, feedforward, u_min, u_max
        See :class:`~forecast_design.controllers.base.LinearController`.

    Examples
    --------
    >>> c = TFController(num=(0.5, 10.0), den=(0.01, 1.0))          # a lead: 10 (0.05 s + 1)/(0.01 s + 1)
    >>> c.spelling()
    'tf:0.5,10/0.01,1'
    >>> float(abs(c.feedback_tf()(0j)))
    10.0
    """

    kind: ClassVar[str] = "tf"
    keys: ClassVar[tuple[str, ...]] = ("num", "den", "discretization", "prewarp_hz", *_OPTION_KEYS)
    required: ClassVar[tuple[str, ...]] = ("num", "den")

    num: tuple[float, ...]
    den: tuple[float, ...]
    discretization: str = "tustin"

    def __post_init__(self) -> None:
        owner = "[controller]"
        object.__setattr__(self, "num", _coefficients(owner, "num", self.num))
        object.__setattr__(self, "den", _coefficients(owner, "den", self.den))
        _check_rational(owner, self.num, self.den, "s")
        self._check_options()

    @classmethod
    def parse_fields(cls, positional: list[str], options: Mapping[str, str], owner: str) -> dict[str, Any]:
        """``tf:NUM/DEN[:key=value...]``."""
        return _parse_num_den(cls, positional, options, owner)

    def feedback_tf(self) -> RationalTF:
        """``C(s)`` [N m/N m]."""
        return RationalTF(self.num, self.den, name="C_F")

    def reference_tf(self) -> RationalTF:
        """``C(s) + feedforward`` [N m/N m]."""
        return (self.feedback_tf() + self.feedforward).named("C_r") if self.feedforward else \
            self.feedback_tf().named("C_r")

    def discrete_law(self, rate_hz: float) -> DiscreteLaw:
        """``C(s)`` discretised at ``rate_hz`` [Hz] on the error, with the feed-forward and saturation.

        Parameters
        ----------
        rate_hz : float
            Control rate [Hz].

        Returns
        -------
        DiscreteLaw
            One ``error`` channel.
        """
        law = self._discretize(self.feedback_tf(), rate_hz, "C_F")
        return self._options_law(rate_hz, [LawChannel("error", law, "ctl")])

    def spelling(self) -> str:
        """``tf:NUM/DEN[:key=value...]`` with comma-separated coefficients."""
        return f"tf:{_polynomial_text(self.num)}/{_polynomial_text(self.den)}" + self._options_spelling("tustin")


@dataclass(frozen=True, slots=True, kw_only=True)
class DiscreteController(LinearController):
    """``u = C(z) e`` with ``C(z) = num(z)/den(z)``, run as given at the control rate (format kind ``discrete``).

    Parameters
    ----------
    num, den : tuple of float
        Coefficients in descending powers of z [N m/N m]; ``den[0] != 0``, causal (proper).
    rate_hz : float or None
        The rate the coefficients are for [Hz]: the run's ``[sampling] rate_hz``, which the
        ``[controller]`` table does not repeat (not written by :meth:`to_mapping`). ``None``:
        whatever rate it is run at. A law asked at another rate is refused.
    feedforward, u_min, u_max
        See :class:`~forecast_design.controllers.base.LinearController` (no discretization).

    Examples
    --------
    >>> c = DiscreteController(num=(205.0, -200.0), den=(1.0, 0.0), rate_hz=2000.0)   # PD 5/0.1, backward Euler
    >>> c.discrete_law(2000.0).feedback_tf().num
    (205.0, -200.0)
    """

    kind: ClassVar[str] = "discrete"
    keys: ClassVar[tuple[str, ...]] = ("num", "den", *_OPTION_KEYS)
    required: ClassVar[tuple[str, ...]] = ("num", "den")

    num: tuple[float, ...]
    den: tuple[float, ...]
    rate_hz: float | None = None
    discretization: str = "tustin"   # unused: the law is already discrete (not a key of this kind)

    @classmethod
    def parse_fields(cls, positional: list[str], options: Mapping[str, str], owner: str) -> dict[str, Any]:
        """``discrete:NUM/DEN[:rate_hz=R][:key=value...]``."""
        options = dict(options)
        rate = options.pop("rate_hz", None)
        kwargs = _parse_num_den(cls, positional, options, owner)
        if rate is not None:
            kwargs["rate_hz"] = parse_number(rate, f"{owner} rate_hz")
        return kwargs

    def __post_init__(self) -> None:
        owner = "[controller]"
        object.__setattr__(self, "num", _coefficients(owner, "num", self.num))
        object.__setattr__(self, "den", _coefficients(owner, "den", self.den))
        _check_rational(owner, self.num, self.den, "z")
        if self.discretization != "tustin" or self.prewarp_hz is not None:
            raise ParameterError(f"{owner} takes no discretization: its coefficients are already discrete",
                                 name="discretization", value=self.discretization)
        if self.rate_hz is not None:
            object.__setattr__(self, "rate_hz", check_number(owner, "rate_hz", self.rate_hz, positive=True))
        self._check_options()

    @property
    def is_continuous(self) -> bool:
        """False: the law is given in z."""
        return False

    def _no_continuous(self) -> ParameterError:
        return ParameterError(f"controller {self.spelling()} is discrete (C(z) at the control rate): it has no "
                              "continuous law; analyse the sampled loop (--sampled, at its rate)",
                              name="controller", value=self.kind)

    def feedback_tf(self) -> RationalTF:
        """Refused: a discrete controller has no ``C(s)`` (use :meth:`discrete_law`)."""
        raise self._no_continuous()

    def reference_tf(self) -> RationalTF:
        """Refused: a discrete controller has no ``C_r(s)``."""
        raise self._no_continuous()

    def at_rate(self, rate_hz: float) -> "DiscreteController":
        """This controller bound to the run's rate [Hz] (a loaded table learns it from ``[sampling]``)."""
        import dataclasses

        return dataclasses.replace(self, rate_hz=float(rate_hz))

    def discrete_law(self, rate_hz: float) -> DiscreteLaw:
        """``C(z)`` on the error as given, with the feed-forward and saturation.

        Parameters
        ----------
        rate_hz : float
            Control rate [Hz]; must equal ``rate_hz`` of the controller when that is set.

        Returns
        -------
        DiscreteLaw
            One ``error`` channel.
        """
        if self.rate_hz is not None and not math.isclose(rate_hz, self.rate_hz, rel_tol=1e-9):
            raise ParameterError(f"controller {self.spelling()} is designed for {format_number(self.rate_hz)} Hz, "
                                 f"asked to run at {format_number(rate_hz)} Hz", name="rate_hz", value=rate_hz)
        from ..discrete import DiscreteTF

        law = DiscreteTF.from_z(self.num, self.den, rate_hz, "C_F")
        return self._options_law(rate_hz, [LawChannel("error", law, "ctl")])

    def spelling(self) -> str:
        """``discrete:NUM/DEN[:rate_hz=R][:key=value...]``."""
        rate = f":rate_hz={format_number(self.rate_hz)}" if self.rate_hz is not None else ""
        return f"discrete:{_polynomial_text(self.num)}/{_polynomial_text(self.den)}" + rate + \
            self._options_spelling("tustin")
