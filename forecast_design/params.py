"""Immutable parameter values: testbed, environment, controller, compensator, design.

Field names are the symbols of the experiment format (``J_m``, ``k_e``,
``w_q_hz``...), so a TOML section maps 1:1 onto a dataclass.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

from .controllers import Controller, resolve_controller
from .errors import ExperimentFormatError, ParameterError
from .limits import check_limit, check_number, check_physical

__all__ = [
    "Testbed",
    "Environment",
    "critically_damped",
    "Compensator",
    "Design",
    "TABLE1_LINK",
    "ENVIRONMENT_PRESETS",
    "COMPENSATOR_KINDS",
    "Q_FAMILIES",
    "OBSERVER_KINDS",
    "BREAK_POINTS",
    "environment_preset",
    "require_design",
    "resolve_design",
]

#: Compensator kinds: the experiment format's list plus the motor-side FOB.
COMPENSATOR_KINDS = ("none", "sfm", "ea-fob", "lo-dob", "ld-dob", "motor-fob")
#: Kinds built on a Q-filtered nominal-plant inverse.
OBSERVER_KINDS = ("ea-fob", "lo-dob", "ld-dob", "motor-fob")
#: Q-filter families (see :func:`forecast_design.symbolic.q_filter`).
Q_FAMILIES = ("butterworth", "binomial")
#: Where a force loop is broken for its loop transfer function L.
BREAK_POINTS = ("controller", "plant-input")
#: Boards the firmware export targets.
BOARDS = ("nucleo-f446re",)
#: ESCON set-value paths: the DAC (PA4, analog set value) or a PWM timer (PA6, PWM set value).
OUTPUT_STAGES = ("dac", "pwm")


_number = check_number


def _from_mapping(cls, mapping: Mapping[str, Any], *, section: str, source: str | None,
                  required: tuple[str, ...], ignore: tuple[str, ...] = ()):
    """Build ``cls`` from a TOML-like mapping, rejecting unknown and missing keys.

    Errors are ExperimentFormatError naming ``source`` (a file) and the key.
    """
    where = f"{source}: " if source else ""
    if not isinstance(mapping, Mapping):
        raise ExperimentFormatError(
            f"{where}[{section}] must be a table, got {type(mapping).__name__}",
            path=source, key=section,
        )
    names = {f.name for f in dataclasses.fields(cls)}
    for key in mapping:
        if key not in names and key not in ignore:
            raise ExperimentFormatError(
                f"{where}[{section}] unknown key '{key}'; allowed: {', '.join(sorted(names | set(ignore)))}",
                path=source, key=f"{section}.{key}",
            )
    for key in required:
        if key not in mapping:
            raise ExperimentFormatError(
                f"{where}[{section}] missing required key '{key}'", path=source, key=f"{section}.{key}"
            )
    kwargs = {k: v for k, v in mapping.items() if k in names}
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        message = str(exc)
        if not message.startswith(f"[{section}] "):
            message = f"[{section}] {message}"
        raise ExperimentFormatError(
            f"{where}{message}", path=source, key=f"{section}.{exc.name}"
        ) from None


def _named_parameters(cls):
    """Make a parameter dataclass refuse an unknown, missing or positional argument with the project's
    one-line ParameterError naming it (and the nearest field: ``w_q`` -> ``w_q_hz``), not a raw TypeError."""
    init = cls.__init__
    fields = dataclasses.fields(cls)
    names = [f.name for f in fields]
    required = [f.name for f in fields if f.default is dataclasses.MISSING
                and f.default_factory is dataclasses.MISSING]

    @functools.wraps(init)
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if args:
            raise ParameterError(f"{cls.__name__}() takes keyword arguments only ({', '.join(names)}), got "
                                 f"{len(args)} positional: {args!r:.60}", name=names[0], value=args)
        for key in kwargs:
            if key not in names:
                near = [n for n in names if n.startswith(key)] or difflib.get_close_matches(key, names, n=1, cutoff=0.5)
                hint = f"; did you mean {near[0]}?" if near else ""
                raise ParameterError(f"{cls.__name__}() has no parameter '{key}'{hint} (its parameters: "
                                     f"{', '.join(names)})", name=key, value=kwargs[key])
        missing = [key for key in required if key not in kwargs]
        if missing:
            raise ParameterError(f"{cls.__name__}() needs {', '.join(missing)}", name=missing[0])
        init(self, **kwargs)

    cls.__init__ = __init__
    return cls


@_named_parameters
@dataclass(frozen=True, slots=True, kw_only=True)
class Testbed:
    """Nominal series elastic actuator (experiment format section ``[testbed]``).

    Defaults are the Forecast testbed of the paper's Table 1.
    """

    __test__ = False  # the name starts with "Test": keep pytest from collecting it

    J_m: float = 0.133  # motor reflected inertia        [kg m^2]
    d_m: float = 0.3    # motor viscous friction         [N m s/rad]
    k: float = 58.0     # series spring stiffness        [N m/rad]
    # the SEA's link, the default of every environment that sets none (None: not given; environments
    # then keep their own link, Table 1's by default)
    J_l: float | None = None  # link inertia                   [kg m^2]
    d_l: float | None = None  # link damping                   [N m s/rad]

    def __post_init__(self) -> None:
        object.__setattr__(self, "J_m", _number("[testbed]", "J_m", self.J_m, positive=True))
        object.__setattr__(self, "d_m", _number("[testbed]", "d_m", self.d_m))
        object.__setattr__(self, "k", _number("[testbed]", "k", self.k, positive=True))
        for name in ("J_m", "d_m", "k"):   # documented plausible ranges (limits.PHYSICAL_RANGES)
            check_physical("[testbed]", name, getattr(self, name))
        if (self.J_l is None) != (self.d_l is None):
            given, missing = ("J_l", "d_l") if self.d_l is None else ("d_l", "J_l")
            raise ParameterError(f"[testbed] {given} given without {missing}: give the link's J_l [kg m^2] and "
                                 "d_l [N m s/rad] together", name=missing, value=None)
        if self.J_l is not None:
            for name in ("J_l", "d_l"):
                object.__setattr__(self, name, _number("[testbed]", name, getattr(self, name)))
                check_physical("[testbed]", name, getattr(self, name))

    @property
    def link(self) -> tuple[float, float] | None:
        """The link ``(J_l [kg m^2], d_l [N m s/rad])`` this testbed carries, or None when it carries none."""
        return None if self.J_l is None else (self.J_l, self.d_l)

    def spring_torque(self, theta: Any, q: Any) -> Any:
        """The spec's spring equation ``tau_s = k (theta - q)`` [N m] (the logger's derived column).

        Parameters
        ----------
        theta, q : float or ndarray
            Motor and environment angles [rad] (q = 0 for a locked output).

        Returns
        -------
        float or ndarray
            Spring torque [N m].
        """
        return self.k * (theta - q)

    @classmethod
    def nominal(cls) -> "Testbed":
        """The paper's Table 1 testbed (J_m 0.133 kg m^2, d_m 0.3 N m s/rad, k 58 N m/rad)."""
        return cls()

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], *, source: str | None = None,
                     link: bool = False) -> "Testbed":
        """Build from a ``[testbed]`` table; unknown or missing keys are errors.

        Parameters
        ----------
        mapping : Mapping
            The table: ``J_m`` [kg m^2], ``d_m`` [N m s/rad], ``k`` [N m/rad].
        source : str, optional
            The file, for messages.
        link : bool
            Also accept the link ``J_l`` [kg m^2] and ``d_l`` [N m s/rad] (testbed files and
            scenarios); False for the experiment format, whose ``[testbed]`` has the three keys
            only and whose ``[environment]`` carries the link.

        Returns
        -------
        Testbed
            The testbed.
        """
        if not link and isinstance(mapping, Mapping):
            for key in ("J_l", "d_l"):
                if key in mapping:
                    where = f"{source}: " if source else ""
                    raise ExperimentFormatError(
                        f"{where}[testbed] unknown key '{key}'; allowed: J_m, d_m, k (an experiment's link is "
                        "in its [environment])", path=source, key=f"testbed.{key}")
        return _from_mapping(cls, mapping, section="testbed", source=source, required=("J_m", "d_m", "k"))

    def to_mapping(self) -> dict[str, float]:
        """The experiment format's ``[testbed]`` table (J_m, d_m, k; the link goes with each environment)."""
        return {"J_m": self.J_m, "d_m": self.d_m, "k": self.k}


#: The Forecast testbed's link (J_l [kg m^2], d_l [N m s/rad]): an Environment's default link.
TABLE1_LINK = (0.0018, 0.35)


@_named_parameters
@dataclass(frozen=True, slots=True, kw_only=True)
class Environment:
    """Environment E(s) = J s^2 + d s + k_e with J = J_e + J_l, d = d_e + d_l.

    With ``locked=True`` the output is held (q == 0, k_e -> infinity) and the
    numeric values are ignored by the models.
    """

    J_e: float            # environment inertia            [kg m^2]
    d_e: float            # environment damping            [N m s/rad]
    k_e: float            # environment stiffness          [N m/rad]
    J_l: float | None = None   # link inertia (None: TABLE1_LINK)    [kg m^2]
    d_l: float | None = None   # link damping (None: TABLE1_LINK)    [N m s/rad]
    locked: bool = False  # output locked, q == 0
    #: The link was given (not left on Table 1's): a testbed's own link then does not replace it.
    #: Inferred when None; kept through ``dataclasses.replace`` unless the link changes.
    link_given: bool | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        given = self.link_given
        if given is not None and not isinstance(given, bool):
            raise ParameterError(f"[environment] link_given must be true, false or unset, got {given!r}",
                                 name="link_given", value=given)
        if given is None:
            given = self.J_l is not None or self.d_l is not None
        if self.J_l is None:
            object.__setattr__(self, "J_l", TABLE1_LINK[0])
        if self.d_l is None:
            object.__setattr__(self, "d_l", TABLE1_LINK[1])
        if not given and (self.J_l, self.d_l) != TABLE1_LINK:
            given = True        # replace(env, J_l=...) of a defaulted environment
        object.__setattr__(self, "link_given", bool(given))
        for name in ("J_e", "d_e", "k_e", "J_l", "d_l"):
            object.__setattr__(self, name, _number("[environment]", name, getattr(self, name)))
            check_physical("[environment]", name, getattr(self, name))
        if not isinstance(self.locked, bool):
            raise ParameterError(
                f"[environment] locked must be true or false, got {self.locked!r}",
                name="locked", value=self.locked,
            )
        if not self.locked and self.J == 0.0 and self.d == 0.0 and self.k_e == 0.0:
            raise ParameterError(
                "[environment] J_e + J_l, d_e + d_l and k_e are all 0: E(s) = 0 transmits no force; "
                "set locked = true for a held output",
                name="J_e", value=0.0,
            )
        if not self.locked and self.J == 0.0:
            raise ParameterError(
                "[environment] J_e + J_l = 0: the output has no inertia (the link alone has J_l); "
                "give J_l (e.g. 0.0018) or set locked = true", name="J_l", value=0.0,
            )

    @property
    def J(self) -> float:
        """Total output inertia J = J_e + J_l [kg m^2]."""
        return self.J_e + self.J_l

    @property
    def d(self) -> float:
        """Total output damping d = d_e + d_l [N m s/rad]."""
        return self.d_e + self.d_l

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], *, source: str | None = None) -> "Environment":
        """Build from an ``[environment]`` table; unknown or missing keys are errors."""
        return _from_mapping(cls, mapping, section="environment", source=source,
                             required=("J_e", "d_e", "k_e", "J_l", "d_l"))

    def to_mapping(self) -> dict[str, Any]:
        """The ``[environment]`` table."""
        return {"J_e": self.J_e, "d_e": self.d_e, "k_e": self.k_e,
                "J_l": self.J_l, "d_l": self.d_l, "locked": self.locked}


def critically_damped(k_e: float, J_e: float) -> float:
    """Critical damping d_e = 2 sqrt(k_e J_e) of an environment [N m s/rad].

    Section 5: "d_e is set to reach a critically damped environment" (with the
    environment's own inertia J_e, as the presets use it).

    Parameters
    ----------
    k_e : float
        Environment stiffness [N m/rad].
    J_e : float
        Environment inertia [kg m^2].

    Returns
    -------
    float
        The damping [N m s/rad].
    """
    return 2.0 * math.sqrt(k_e * J_e)


#: Named environments. ``soft``/``stiff``: Section 5 (critically damped d_e);
#: ``fig7``: Section 6 tuning environment (d_e critically damped too, a choice:
#: the paper gives none); ``exp-soft``: Section 7 (d_e as in the format's example);
#: ``locked``: q == 0; ``link-only``: the bare link, E = J_l s^2 + d_l s.
ENVIRONMENT_PRESETS: Mapping[str, Environment] = {
    "soft": Environment(J_e=1e-3, d_e=critically_damped(0.1, 1e-3), k_e=0.1),
    "stiff": Environment(J_e=0.1, d_e=critically_damped(100.0, 0.1), k_e=100.0),
    "fig7": Environment(J_e=1.0, d_e=critically_damped(100.0, 1.0), k_e=100.0),
    "exp-soft": Environment(J_e=1e-3, d_e=0.063, k_e=5.0),
    # The link values stay in the locked preset: the plant ignores them (q == 0) but the
    # LD-DOB's nominal plant is the link's, whatever the output is attached to.
    "locked": Environment(J_e=0.0, d_e=0.0, k_e=0.0, locked=True),
    "link-only": Environment(J_e=0.0, d_e=0.0, k_e=0.0),
}


def require_design(value: Any, what: str) -> "Design":
    """``value`` if it is a :class:`Design`, else a one-line ParameterError (not a raw AttributeError later).

    Parameters
    ----------
    value : object
        The candidate.
    what : str
        The function receiving it, for the message.

    Returns
    -------
    Design
        ``value``.
    """
    if not isinstance(value, Design):
        hint = f" (e.g. Design.nominal({value!r}))" if isinstance(value, str) else ""
        raise ParameterError(f"{what} needs a Design{hint}, got {type(value).__name__} {value!r:.60}",
                             name="design", value=value)
    return value


def environment_preset(name: str) -> Environment:
    """Return the named environment preset.

    Parameters
    ----------
    name : str
        One of ``soft``, ``stiff``, ``fig7``, ``exp-soft``, ``locked``, ``link-only``.

    Returns
    -------
    Environment
        The preset.

    Raises
    ------
    ParameterError
        If the name is unknown (the message lists the known names).
    """
    try:
        return ENVIRONMENT_PRESETS[name]
    except KeyError:
        raise ParameterError(
            f"unknown environment '{name}'; known: {', '.join(ENVIRONMENT_PRESETS)}",
            name="environment", value=name,
        ) from None


@_named_parameters
@dataclass(frozen=True, slots=True, kw_only=True)
class Compensator:
    """Friction compensator / disturbance observer: the value of a ``[compensator]`` table.

    ``q_family``, ``q_order`` and ``q_damping`` choose the Q filter (our choice where the
    paper is silent; default 2nd-order Butterworth); the format's table carries them when
    they differ from the defaults. An ``sfm`` carries its identified ``friction``
    (``[compensator.friction]``). What each kind does (its filters, its feed-forward) is its
    strategy's: :func:`forecast_design.compensators.compensator_strategy`.
    """

    kind: str = "none"             # none | sfm | ea-fob | lo-dob | ld-dob | motor-fob
    w_q_hz: float = 10.0           # Q(s) cutoff                   [Hz]
    q_family: str = "butterworth"  # butterworth | binomial
    q_order: int = 2               # Q(s) order                    [-]
    q_damping: float | None = None  # 2nd-order Q damping ratio; None = the family's own [-]
    # identified friction of an 'sfm' compensator, (name, value) pairs as forecast_design.friction
    # names them (viscous [N m s/rad], coulomb, offset, sin<i>, cos<i> [N m], the asymmetric and
    # Stribeck names); a Mapping is accepted
    friction: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        friction = self.friction.items() if isinstance(self.friction, Mapping) else self.friction
        try:
            pairs = tuple(sorted((str(k), _number("[compensator] friction", str(k), v, nonneg=False))
                                 for k, v in friction))
        except (TypeError, ValueError):
            raise ParameterError(f"[compensator] friction must map parameter names to numbers, got {self.friction!r}",
                                 name="friction", value=self.friction) from None
        object.__setattr__(self, "friction", pairs)
        if pairs and self.kind != "sfm":
            raise ParameterError(f"[compensator] friction parameters apply to kind 'sfm', not {self.kind!r}",
                                 name="friction", value=dict(pairs))
        if self.kind not in COMPENSATOR_KINDS:
            raise ParameterError(
                f"[compensator] kind must be one of {', '.join(COMPENSATOR_KINDS)}, got {self.kind!r}",
                name="kind", value=self.kind,
            )
        object.__setattr__(self, "w_q_hz", _number("[compensator]", "w_q_hz", self.w_q_hz, positive=True))
        check_physical("[compensator]", "w_q_hz", self.w_q_hz)
        if self.q_family not in Q_FAMILIES:
            raise ParameterError(
                f"[compensator] q_family must be one of {', '.join(Q_FAMILIES)}, got {self.q_family!r}",
                name="q_family", value=self.q_family,
            )
        if isinstance(self.q_order, bool) or not isinstance(self.q_order, int) or self.q_order < 1:
            raise ParameterError(
                f"[compensator] q_order must be an integer >= 1, got {self.q_order!r}",
                name="q_order", value=self.q_order,
            )
        check_limit("[compensator] q_order", "q_order", self.q_order)

        if self.q_damping is not None:
            object.__setattr__(self, "q_damping",
                               _number("[compensator]", "q_damping", self.q_damping, positive=True))
            if self.q_order != 2:
                raise ParameterError(
                    f"[compensator] q_damping applies to a 2nd-order Q only, got q_order = {self.q_order}",
                    name="q_damping", value=self.q_damping,
                )

    @property
    def is_observer(self) -> bool:
        """True for the Q-filtered observers (EA-FOB, LO-DOB, LD-DOB, motor FOB)."""
        return self.kind in OBSERVER_KINDS

    @property
    def friction_params(self) -> dict[str, float] | None:
        """The identified friction of an ``sfm`` compensator as a dict, or None when it carries none."""
        return dict(self.friction) if self.friction else None

    def require_friction(self) -> dict[str, float]:
        """The identified friction an ``sfm`` compensator runs on [N m s/rad, N m].

        Raises
        ------
        ParameterError
            When the compensator carries none (an SFM needs identified parameters).
        """
        if not self.friction:
            raise ParameterError("compensator 'sfm' needs identified friction (viscous, coulomb[, offset, sin<i>, "
                                 "cos<i>]): give friction= (e.g. from identify --json)", name="friction", value=None)
        return dict(self.friction)

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], *, source: str | None = None) -> "Compensator":
        """Build from a ``[compensator]`` table (experiment format).

        Observer kinds take ``w_q_hz`` and optionally ``q_family``, ``q_order``, ``q_damping``;
        ``sfm`` takes a ``[compensator.friction]`` sub-table of identified parameters; other keys
        are errors naming the file and the key.

        Parameters
        ----------
        mapping : Mapping
            The table.
        source : str, optional
            The file, for messages.

        Returns
        -------
        Compensator
            The compensator.
        """
        where = f"{source}: " if source else ""
        if not isinstance(mapping, Mapping):
            raise ExperimentFormatError(f"{where}[compensator] must be a table, got {type(mapping).__name__}",
                                        path=source, key="compensator")
        kind = mapping.get("kind", "none")
        allowed = ("kind", *_OBSERVER_KEYS) if kind in OBSERVER_KINDS else \
            ("kind", "friction") if kind == "sfm" else ("kind",)
        for key in mapping:
            if key not in allowed:
                raise ExperimentFormatError(
                    f"{where}[compensator] key '{key}' does not belong to kind {kind!r}; its keys: "
                    f"{', '.join(allowed)}", path=source, key=f"compensator.{key}")
        if "friction" in mapping and not isinstance(mapping["friction"], Mapping):
            raise ExperimentFormatError(f"{where}[compensator] friction must be a table [compensator.friction]",
                                        path=source, key="compensator.friction")
        return _from_mapping(cls, mapping, section="compensator", source=source, required=())

    def to_mapping(self) -> dict[str, Any]:
        """The ``[compensator]`` table of the experiment format (non-default Q keys, the SFM's friction)."""
        out: dict[str, Any] = {"kind": self.kind}
        if self.is_observer:
            out["w_q_hz"] = self.w_q_hz
            if self.q_family != "butterworth":
                out["q_family"] = self.q_family
            if self.q_order != 2:
                out["q_order"] = self.q_order
            if self.q_damping is not None:
                out["q_damping"] = self.q_damping
        if self.friction:
            out["friction"] = dict(self.friction)
        return out

    @property
    def label(self) -> str:
        """A short label: ``ea-fob 10 Hz``, ``sfm``, ``none``."""
        return f"{self.kind} {self.w_q_hz:g} Hz" if self.is_observer else self.kind


#: Keys of an observer's ``[compensator]`` table besides ``kind``.
_OBSERVER_KEYS = ("w_q_hz", "q_family", "q_order", "q_damping")


@_named_parameters
@dataclass(frozen=True, slots=True, kw_only=True)
class Design:
    """Everything the nominal model says about one set-up.

    A testbed that carries its link (``Testbed.J_l``, ``d_l``) gives it to an environment that gives
    no link of its own (``Environment.link_given`` false, e.g. a preset): the link belongs to the
    SEA, so a user's testbed never runs with the paper's link by default. An environment that gives
    a link keeps it, even Table 1's. ``environment`` may be a one-member
    :class:`~forecast_design.environments.EnvironmentSet` (e.g. ``resolve_environments("f.toml#name")``).
    """

    testbed: Testbed = field(default_factory=Testbed)
    environment: Environment = field(default_factory=lambda: ENVIRONMENT_PRESETS["soft"])
    controller: Controller | None = None
    compensator: Compensator | None = None

    def __post_init__(self) -> None:
        from .environments import EnvironmentSet   # layer 0 both; imported here, environments imports params

        if isinstance(self.environment, EnvironmentSet):
            object.__setattr__(self, "environment", self.environment.single("Design(environment=...)")[1])
        # a wrong type here would surface much later as a raw AttributeError deep in a model
        for name, kind, optional in (("testbed", Testbed, False), ("environment", Environment, False),
                                     ("controller", Controller, True), ("compensator", Compensator, True)):
            value = getattr(self, name)
            if not (isinstance(value, kind) or (optional and value is None)):
                hint = " (use Design.nominal(NAME) for a preset)" if name == "environment" else ""
                raise ParameterError(f"Design {name} must be a {kind.__name__}{' or None' if optional else ''}, "
                                     f"got {type(value).__name__} {value!r}{hint}", name=name, value=value)
        link, env = self.testbed.link, self.environment
        if link is not None and not env.link_given and link != TABLE1_LINK:
            object.__setattr__(self, "environment", dataclasses.replace(env, J_l=link[0], d_l=link[1]))

    @classmethod
    def nominal(cls, environment: str | Environment = "soft", **kwargs: Any) -> "Design":
        """Table 1 testbed with a named (or given) environment.

        Parameters
        ----------
        environment : str or Environment
            Preset name or an Environment value.
        **kwargs
            ``controller``, ``compensator`` or ``testbed``.

        Returns
        -------
        Design
            The design.
        """
        env = environment_preset(environment) if isinstance(environment, str) else environment
        return cls(environment=env, **kwargs)

    def with_environment(self, environment: str | Environment) -> "Design":
        """A copy with another environment (preset name or value)."""
        env = environment_preset(environment) if isinstance(environment, str) else environment
        return dataclasses.replace(self, environment=env)

    def to_mapping(self) -> dict[str, Any]:
        """What the design assumes, for JSON: ``testbed``, ``environment`` and, when set, ``controller`` and
        ``compensator`` (with its cutoff), each as its own ``to_mapping``."""
        out: dict[str, Any] = {"testbed": self.testbed.to_mapping(), "environment": self.environment.to_mapping()}
        if self.controller is not None:
            out["controller"] = self.controller.to_mapping()
        if self.compensator is not None:
            out["compensator"] = self.compensator.to_mapping()
        return out

    def with_friction(self, friction: Mapping[str, float] | None) -> "Design":
        """A copy whose ``sfm`` compensator carries `friction` (identified parameters); None changes nothing.

        Parameters
        ----------
        friction : Mapping[str, float] or None
            Parameter names as :mod:`forecast_design.friction` gives them (viscous
            [N m s/rad], coulomb, offset, sin<i>, cos<i> [N m]).

        Returns
        -------
        Design
            The design with the friction on its compensator.

        Raises
        ------
        ParameterError
            When the compensator is not ``sfm``.
        """
        if friction is None:
            return self
        comp = self.compensator
        if comp is None or comp.kind != "sfm":
            raise ParameterError(
                f"identified friction given but the compensator is {comp.kind if comp else 'none'!r}; "
                "it applies to 'sfm'", name="friction", value=dict(friction))
        return dataclasses.replace(self, compensator=dataclasses.replace(comp, friction=friction))

    def parameters(self) -> dict[str, float]:
        """Flat numeric parameters for the symbolic models: J_m, d_m, k, J, d, k_e, J_l, d_l."""
        tb, env = self.testbed, self.environment
        return {"J_m": tb.J_m, "d_m": tb.d_m, "k": tb.k, "J": env.J, "d": env.d,
                "k_e": env.k_e, "J_l": env.J_l, "d_l": env.d_l}


# --- design parsing (command-line forms) ------------------------------------------------


def resolve_design(design: Design | None = None, *, controller: Any = None,
                   compensator: Compensator | str | None = None, env: str | None = None,
                   w_q_hz: float | None = None) -> Design:
    """Apply CLI-style overrides to a design (shared by ``export`` and ``run``).

    Parameters
    ----------
    design : Design, optional
        Base (default: Table 1 testbed, ``exp-soft``, the paper's PD, no compensator).
    controller : Controller, str or python-control system, optional
        Anything :func:`~forecast_design.controllers.resolve_controller` takes (``"pd:5:0.1"``...).
    compensator : Compensator or str, optional
        Kind string or a value.
    env : str, optional
        Environment preset name.
    w_q_hz : float, optional
        Q cutoff [Hz].

    Returns
    -------
    Design
        The design with the overrides.
    """
    if design is None:
        design = Design(environment=environment_preset("exp-soft"))
    if env is not None:
        design = design.with_environment(env)
    if controller is not None:
        design = dataclasses.replace(design, controller=resolve_controller(controller))
    elif design.controller is None:
        design = dataclasses.replace(design, controller=resolve_controller(None))
    if isinstance(compensator, str):
        compensator = Compensator(kind=compensator)
    comp = compensator if compensator is not None else (design.compensator or Compensator())
    if w_q_hz is not None:
        comp = dataclasses.replace(comp, w_q_hz=w_q_hz)
    return dataclasses.replace(design, compensator=comp)
