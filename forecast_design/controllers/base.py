"""The force controller's one interface, the options every linear kind shares, and the law that runs.

A force controller (experiment format, section "Force controllers") maps the force
reference ``tau_r`` and the measured spring torque ``tau_s`` to its output ``u`` [N m]; the
motor command is ``u`` plus the compensator's estimate. Every kind is a frozen dataclass
deriving from :class:`Controller` and registered by its format ``kind`` (see
:mod:`forecast_design.controllers`), the way pysindy's feature libraries share one base
class. Each kind knows

* its continuous law (:meth:`Controller.feedback_tf`: the ``C(s)`` the loop analysis uses,
  ``u = C_r(s) tau_r - C(s) tau_s``, and :meth:`Controller.reference_tf`: ``C_r(s)``);
* its difference equation at a rate (:meth:`Controller.discrete_law` -> :class:`DiscreteLaw`),
  which the simulator, the Python program reference, the C export and the firmware run;
* its ``[controller]`` table (:meth:`Controller.to_mapping`, ``from_mapping``), its
  command-line spelling (:meth:`Controller.spelling`) and a label.

The law that runs
-----------------
A :class:`DiscreteLaw` is a sum of channels, each a discrete filter on one signal
(``error`` = tau_r - tau_s, ``tau_r`` or ``tau_s``), plus for a PID an integrator with
anti-windup, then the output saturation ``u_min <= u <= u_max``::

    u_lin = sum_i H_i(z) source_i
    x_k   = x_(k-1) + b0 e_k + b1 e_(k-1)          (integrator, if any; H_I(z) = (b0 z + b1)/(z - 1))
    u     = sat(u_lin + x_k)
    clamping:          if u was clipped and e_k pushes further into the limit, the integrator
                       holds (x_k = x_(k-1)); u stays the clipped value
    back-calculation:  x_k += (T / T_t) (u - (u_lin + x_k))

so ``u = C_r(z) tau_r - C(z) tau_s`` while nothing saturates, with
``C(z) = sum(error) + H_I - sum(tau_s)`` and ``C_r(z) = sum(error) + H_I + sum(tau_r)``.
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Mapping

import numpy as np

from ..errors import ExperimentFormatError, ParameterError
from ..lti import RationalTF
from ..limits import check_number, check_physical

if TYPE_CHECKING:   # discrete (numba) loads when a law is asked for, not with the package
    from ..discrete import DiscreteTF

__all__ = [
    "Controller",
    "LinearController",
    "DiscreteLaw",
    "LawChannel",
    "IntegratorLaw",
    "DISCRETIZATIONS",
    "DERIVATIVE_ON",
    "ANTI_WINDUP",
    "LAW_SOURCES",
    "format_number",
    "parse_number",
    "controller_table",
]

#: The format's ``discretization`` values (backward Euler is the default of ``pd`` and ``pid``,
#: Tustin of ``tf``).
DISCRETIZATIONS = ("backward-euler", "tustin", "tustin-prewarp", "zoh", "matched")
#: Where a PD/PID takes its derivative: ``error`` (the format's law) or ``measurement`` (on -tau_s).
DERIVATIVE_ON = ("error", "measurement")
#: PID anti-windup schemes (need ``u_min``/``u_max``; back-calculation needs ``T_t``).
ANTI_WINDUP = ("none", "clamping", "back-calculation")
#: Signals a law's channel filters: e = tau_r - tau_s, the reference, the measured spring torque.
LAW_SOURCES = ("error", "tau_r", "tau_s")

# A number as a user writes it: no underscores (float("5_0") is 50), no inf/nan, no hex.
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


def parse_number(text: str, what: str) -> float:
    """A finite decimal number from a command-line field, strictly (``5_0``, ``inf``, ``0x1p3`` refused).

    Parameters
    ----------
    text : str
        The field.
    what : str
        How to name it in the error (e.g. ``"controller 'pd:5:x' field 2"``).

    Returns
    -------
    float
        The number.
    """
    t = str(text).strip()
    if not _NUMBER.match(t):
        raise ParameterError(f"{what}: {text!r} is not a decimal number", name="controller", value=text)
    value = float(t)
    if not math.isfinite(value):
        raise ParameterError(f"{what}: {text!r} is out of range", name="controller", value=text)
    return value


def format_number(value: float) -> str:
    """The shortest text that reads back to ``value`` exactly (``5`` for 5.0, ``0.1``, ``1e-05``)."""
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


@dataclass(frozen=True, slots=True)
class LawChannel:
    """One additive term of a controller's output: a discrete filter on one signal.

    Parameters
    ----------
    source : str
        One of :data:`LAW_SOURCES`.
    tf : DiscreteTF
        The filter [N m/N m].
    name : str
        A C identifier fragment (``"pd"``, ``"d_meas"``, ``"ff"``).
    """

    source: str
    tf: "DiscreteTF"
    name: str


@dataclass(frozen=True, slots=True)
class IntegratorLaw:
    """A PID's integrator as it runs: ``x_k = x_(k-1) + b0 e_k + b1 e_(k-1)`` with anti-windup.

    Parameters
    ----------
    b0, b1 : float
        Increment weights: ``I/s`` discretised with the controller's method is
        ``(b0 z + b1)/(z - 1)`` [N m/N m].
    anti_windup : str
        One of :data:`ANTI_WINDUP`.
    back_gain : float
        ``T / T_t`` for back-calculation, else 0 [-].
    """

    b0: float
    b1: float
    anti_windup: str
    back_gain: float = 0.0

    def tf(self, dt: float) -> RationalTF:
        """The integrator's linear transfer function ``(b0 z + b1)/(z - 1)`` (``dt`` [s]) [N m/N m]."""
        return RationalTF((self.b0, self.b1), (1.0, -1.0), dt=dt, name="I")


@dataclass(frozen=True, slots=True)
class DiscreteLaw:
    """What a controller runs each period at ``rate_hz`` (module docstring).

    Parameters
    ----------
    rate_hz : float
        Control rate [Hz].
    channels : tuple of LawChannel
        Linear terms, summed in order.
    integrator : IntegratorLaw or None
        A PID's integrator with its anti-windup.
    u_min, u_max : float
        Output saturation [N m] (-inf/inf: none).
    controller : Controller
        What this law realises (provenance).
    """

    rate_hz: float
    channels: tuple[LawChannel, ...]
    integrator: IntegratorLaw | None
    u_min: float
    u_max: float
    controller: "Controller"

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return 1.0 / self.rate_hz

    def _sum(self, signs: Mapping[str, float]) -> RationalTF:
        total = RationalTF((0.0,), (1.0,), dt=self.dt)
        for ch in self.channels:
            sign = signs[ch.source]
            if sign:
                total = total + sign * ch.tf.to_rational()
        if self.integrator is not None:
            total = total + self.integrator.tf(self.dt)
        return total

    def feedback_tf(self) -> RationalTF:
        """``C(z)`` with ``u = C_r(z) tau_r - C(z) tau_s`` (no saturation): what the loop analysis sees [N m/N m]."""
        return self._sum({"error": 1.0, "tau_r": 0.0, "tau_s": -1.0}).named("C_F")

    def reference_tf(self) -> RationalTF:
        """``C_r(z)``: the reference's path to ``u`` (no saturation) [N m/N m]."""
        return self._sum({"error": 1.0, "tau_r": 1.0, "tau_s": 0.0}).named("C_r")


class Controller(ABC):
    """A force controller: ``u`` [N m] from ``tau_r`` and ``tau_s`` (module docstring).

    Subclasses are frozen dataclasses with a class attribute ``kind`` (the format's word),
    registered with :func:`forecast_design.controllers.register_controller`.
    """

    __slots__ = ()
    kind: ClassVar[str]
    #: Keys of the ``[controller]`` table (besides ``kind``), in the order they are written.
    keys: ClassVar[tuple[str, ...]] = ()
    #: Keys that must be present.
    required: ClassVar[tuple[str, ...]] = ()
    #: True when the format gives the controller's equations (not ``other``).
    has_equations: ClassVar[bool] = True
    #: True for a controller given as code (it runs as written: :mod:`forecast_design.controllers.code`).
    is_code: ClassVar[bool] = False
    #: Command-line positional fields: (required keys, optional keys), e.g. (("P", "D"), ("T_f",)).
    positional: ClassVar[tuple[tuple[str, ...], tuple[str, ...]]] = ((), ())
    #: Keys whose values are words, not numbers (the rest parse as numbers).
    word_keys: ClassVar[tuple[str, ...]] = ("discretization", "derivative_on", "anti_windup", "name")

    @classmethod
    def parse_fields(cls, positional: list[str], options: Mapping[str, str], owner: str) -> dict[str, Any]:
        """Keyword arguments from a spelling's ``:``-separated fields (``parse_controller`` calls it).

        Parameters
        ----------
        positional : list of str
            The fields before any ``key=value``.
        options : Mapping[str, str]
            The ``key=value`` fields.
        owner : str
            How to name the spelling in errors.

        Returns
        -------
        dict
            The constructor's keyword arguments.
        """
        need, optional = cls.positional
        if len(positional) < len(need) or len(positional) > len(need) + len(optional):
            form = ":".join([cls.kind, *need] + [f"[{k}]" for k in optional])
            raise ParameterError(f"{owner}: expected {form}[:key=value...]", name="controller", value=owner)
        kwargs: dict[str, Any] = {key: parse_number(text, f"{owner} {key}")
                                  for key, text in zip(need + optional, positional)}
        for key, text in options.items():
            if key not in cls.keys:
                raise ParameterError(f"{owner}: key '{key}' does not belong to kind '{cls.kind}'; its keys: "
                                     f"{', '.join(cls.keys)}", name="controller", value=key)
            if key in kwargs:
                raise ParameterError(f"{owner}: key '{key}' given twice", name="controller", value=key)
            kwargs[key] = text if key in cls.word_keys else parse_number(text, f"{owner} {key}")
        return kwargs

    @abstractmethod
    def feedback_tf(self) -> RationalTF:
        """Continuous ``C(s)`` with ``u = C_r tau_r - C tau_s``, the loop analysis's controller [N m/N m]."""

    @abstractmethod
    def reference_tf(self) -> RationalTF:
        """Continuous ``C_r(s)``: the reference's path to ``u`` [N m/N m]."""

    @abstractmethod
    def discrete_law(self, rate_hz: float) -> DiscreteLaw:
        """The difference equation that runs at ``rate_hz`` [Hz]."""

    @abstractmethod
    def spelling(self) -> str:
        """The command-line spelling (``pd:5:0.1``), read back by ``parse_controller``."""

    @property
    def label(self) -> str:
        """A short human label naming the kind and every key that is set (``PD P=5 D=0.1``).

        Numbers are shown to 4 significant digits (``T_f=0.0007958``) for titles and text; the
        exact values are in :meth:`spelling` and :meth:`to_mapping`, which the JSON outputs carry.
        """
        parts = []
        for key, value in self.to_mapping().items():
            if key == "kind":
                continue
            if isinstance(value, (list, tuple)):
                text = "[" + " ".join(f"{float(v):.4g}" for v in value) + "]"
            elif isinstance(value, float):
                text = f"{value:.4g}"
            else:
                text = str(value)
            parts.append(f"{key}={text}")
        return " ".join([self.kind.upper(), *parts])

    @property
    def is_continuous(self) -> bool:
        """True when the law is given in s (and discretised to run); False for ``discrete``."""
        return True

    def to_mapping(self) -> dict[str, Any]:
        """The ``[controller]`` table: ``kind`` then every key whose value is not the default."""
        out: dict[str, Any] = {"kind": self.kind}
        defaults = type(self).__dataclass_fields__      # type: ignore[attr-defined]
        for key in self.keys:
            value = getattr(self, key)
            f = defaults[key]
            if key not in self.required and value == f.default:
                continue
            if value is None:
                continue
            out[key] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], *, source: str | None = None) -> "Controller":
        """Build from a ``[controller]`` table of this kind; unknown or missing keys are errors naming the file.

        Parameters
        ----------
        mapping : Mapping
            The table (``kind`` may be present).
        source : str, optional
            The file, for messages.

        Returns
        -------
        Controller
            The controller.
        """
        kwargs = controller_table(cls, mapping, source=source)
        try:
            return cls(**kwargs)
        except ParameterError as exc:
            where = f"{source}: " if source else ""
            message = str(exc)
            if not message.startswith("[controller]"):
                message = f"[controller] {message}"
            raise ExperimentFormatError(f"{where}{message}", path=source,
                                        key=f"controller.{exc.name}" if exc.name else "controller") from None

    def to_control(self, rate_hz: float | None = None):
        """The controller as a ``control.TransferFunction``: ``C(s)``, or ``C(z)`` at ``rate_hz`` [Hz].

        Parameters
        ----------
        rate_hz : float, optional
            Give it for the discrete law that runs at this rate (required for ``discrete``).

        Returns
        -------
        control.TransferFunction
            The feedback path ``C`` (``u = C_r tau_r - C tau_s``).
        """
        tf = self.feedback_tf() if rate_hz is None else self.discrete_law(rate_hz).feedback_tf()
        return tf.to_control()


def controller_table(cls: type, mapping: Mapping[str, Any], *, source: str | None) -> dict[str, Any]:
    """Check a ``[controller]`` table against a kind's keys; return its keyword arguments.

    Parameters
    ----------
    cls : type
        The controller class (``keys``, ``required``, ``kind``).
    mapping : Mapping
        The table.
    source : str, optional
        The file, for messages.

    Returns
    -------
    dict
        The table without ``kind``, lists as tuples.
    """
    where = f"{source}: " if source else ""
    if not isinstance(mapping, Mapping):
        raise ExperimentFormatError(f"{where}[controller] must be a table, got {type(mapping).__name__}",
                                    path=source, key="controller")
    kind = mapping.get("kind", cls.kind)
    if kind != cls.kind:
        raise ExperimentFormatError(f"{where}[controller] kind must be {cls.kind!r}, got {kind!r}",
                                    path=source, key="controller.kind")
    for key in mapping:
        if key != "kind" and key not in cls.keys:
            raise ExperimentFormatError(
                f"{where}[controller] key '{key}' does not belong to kind '{cls.kind}'; "
                f"its keys: {', '.join(cls.keys)}", path=source, key=f"controller.{key}")
    for key in cls.required:
        if key not in mapping:
            raise ExperimentFormatError(f"{where}[controller] missing required key '{key}' (kind '{cls.kind}')",
                                        path=source, key=f"controller.{key}")
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in mapping.items() if k != "kind"}


def _coefficients(owner: str, name: str, value: Any) -> tuple[float, ...]:
    """A non-empty tuple of finite coefficients (descending powers), leading zeros kept out."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise ParameterError(f"{owner} {name} must be a list of numbers (descending powers), got {value!r:.60}",
                             name=name, value=value)
    out = tuple(check_number(owner, f"{name}[{i}]", v, nonneg=False) for i, v in enumerate(value))
    if not out:
        raise ParameterError(f"{owner} {name} is empty", name=name, value=value)
    if len(out) > 32:
        raise ParameterError(f"{owner} {name} has {len(out)} coefficients; at most 32 (order 31)",
                             name=name, value=len(out))
    return out


def _check_stable_discretisation(owner: str, cont: RationalTF, law: "DiscreteTF") -> None:
    """Refuse a discretisation that puts a pole on or outside the unit circle the continuous law has not."""
    if len(law.den) <= 1:
        return
    zp = np.roots(law.den)
    n_bad_z = int(np.count_nonzero(np.abs(zp) >= 1.0 - 1e-9))
    sp = np.roots(cont.den) if len(cont.den) > 1 else np.zeros(0)
    n_bad_s = int(np.count_nonzero(sp.real >= -1e-12 * np.maximum(1.0, np.abs(sp))))
    if n_bad_z > n_bad_s:
        worst = zp[np.argmax(np.abs(zp))]
        raise ParameterError(
            f"{owner}: the {law.method} discretisation is unstable (pole at z = {complex(worst):.4g}, "
            f"|z| = {abs(worst):.4g}) where the continuous law is not; use another discretization or add a "
            "derivative filter T_f", name="discretization", value=law.method)


@dataclass(frozen=True, slots=True, kw_only=True)
class LinearController(Controller):
    """Options every LTI kind shares: discretisation, static reference feed-forward, saturation.

    Parameters
    ----------
    discretization : str
        One of :data:`DISCRETIZATIONS` (``discrete`` has none).
    prewarp_hz : float or None
        Prewarp frequency of ``tustin-prewarp`` [Hz].
    feedforward : float
        ``u`` gains ``feedforward * tau_r`` [-].
    u_min, u_max : float or None
        Saturation of ``u`` [N m] (None: none).
    """

    discretization: str = "tustin"
    prewarp_hz: float | None = None
    feedforward: float = 0.0
    u_min: float | None = None
    u_max: float | None = None

    def _check_options(self) -> None:
        owner = "[controller]"
        if self.discretization not in DISCRETIZATIONS:
            raise ParameterError(f"{owner} discretization must be one of {', '.join(DISCRETIZATIONS)}, "
                                 f"got {self.discretization!r}", name="discretization", value=self.discretization)
        if self.prewarp_hz is not None:
            if self.discretization != "tustin-prewarp":
                raise ParameterError(f"{owner} prewarp_hz applies to discretization 'tustin-prewarp', not "
                                     f"{self.discretization!r}", name="prewarp_hz", value=self.prewarp_hz)
            object.__setattr__(self, "prewarp_hz", check_physical(
                owner, "prewarp_hz", check_number(owner, "prewarp_hz", self.prewarp_hz, positive=True)))
        elif self.discretization == "tustin-prewarp":
            raise ParameterError(f"{owner} discretization 'tustin-prewarp' needs prewarp_hz [Hz]",
                                 name="prewarp_hz", value=None)
        object.__setattr__(self, "feedforward", check_physical(
            owner, "feedforward", check_number(owner, "feedforward", self.feedforward, nonneg=False)))
        for key in ("u_min", "u_max"):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, check_physical(owner, key, check_number(owner, key, value,
                                                                                       nonneg=False)))
        if self.u_min is not None and self.u_max is not None and not self.u_min < self.u_max:
            raise ParameterError(f"{owner} u_min = {self.u_min} must be below u_max = {self.u_max} [N m]",
                                 name="u_min", value=self.u_min)

    def _discretize(self, tf: RationalTF, rate_hz: float, name: str) -> "DiscreteTF":
        """``tf`` discretised with this controller's method at ``rate_hz``, refused when unstable."""
        from ..discrete import discretize

        owner = f"controller {self.spelling()}"
        if self.prewarp_hz is not None and not self.prewarp_hz < rate_hz / 2.0:
            raise ParameterError(f"{owner}: prewarp_hz = {self.prewarp_hz:g} Hz is not below the Nyquist "
                                 f"frequency {rate_hz / 2.0:g} Hz", name="prewarp_hz", value=self.prewarp_hz)
        try:
            law = discretize(tf.named(name), rate_hz, self.discretization, self.prewarp_hz)
        except ParameterError as exc:
            raise ParameterError(f"{owner}: {exc}", name="discretization", value=self.discretization) from None
        _check_stable_discretisation(owner, tf, law)
        return law

    def _options_law(self, rate_hz: float, channels: list[LawChannel],
                     integrator: IntegratorLaw | None = None) -> DiscreteLaw:
        """Add the feed-forward channel and the saturation to ``channels``."""
        from ..discrete import DiscreteTF

        if self.feedforward != 0.0:
            channels.append(LawChannel("tau_r", DiscreteTF.from_z((self.feedforward,), (1.0,), rate_hz, "ff"), "ff"))
        return DiscreteLaw(float(rate_hz), tuple(channels), integrator,
                           -math.inf if self.u_min is None else self.u_min,
                           math.inf if self.u_max is None else self.u_max, self)

    def _options_spelling(self, default_discretization: str) -> str:
        """``:key=value`` suffixes for the options that differ from their defaults."""
        parts = []
        if self.discretization != default_discretization:
            parts.append(f"discretization={self.discretization}")
        for key in ("prewarp_hz", "feedforward", "u_min", "u_max"):
            value = getattr(self, key)
            if value is not None and not (key == "feedforward" and value == 0.0):
                parts.append(f"{key}={format_number(value)}")
        return "".join(":" + p for p in parts)
