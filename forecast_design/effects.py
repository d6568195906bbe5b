"""Unmodelled effects: the spec's vocabulary (``Effect``) and one parameter value per effect.

The simulator takes a sequence of these parameter values (``effects=``) and
the sim-to-real diagnosis names an :class:`Effect`, so the two share one
vocabulary: exactly the words of the experiment format's table
"Unmodelled effects".

Conventions (plant equations of the experiment format)::

    J_m theta'' = tau_m,eff - tau_s - tau_frc
    tau_s       = k (theta - q)            (backlash: k * deadzone(theta - q))
    J q'' + d q' + k_e q = tau_s           (locked: q == 0)

``tau_frc`` always contains the nominal viscous term ``d_m theta'``; the
friction effects add to it. ``theta`` in the angle-dependent terms is the
absolute motor angle (see ``initial_angle`` of the simulator).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, Mapping, Sequence

from .errors import ParameterError
from .params import Environment, check_number

__all__ = [
    "Effect",
    "EffectParams",
    "NoEffect",
    "Coulomb",
    "Stiction",
    "PositionFriction",
    "Cogging",
    "Backlash",
    "Delay",
    "TorqueGain",
    "EnvironmentMismatch",
    "EFFECT_CLASSES",
    "effect_from_mapping",
    "effects_to_mappings",
]


class Effect(StrEnum):
    """One word of the spec's unmodelled-effect vocabulary."""

    NONE = "none"
    COULOMB = "coulomb"
    STICTION = "stiction"
    POSITION_FRICTION = "position_friction"
    COGGING = "cogging"
    BACKLASH = "backlash"
    DELAY = "delay"
    TORQUE_GAIN = "torque_gain"
    ENVIRONMENT_MISMATCH = "environment_mismatch"


_num = check_number


def _harmonics(owner: str, name: str, values: Any) -> tuple[float, ...]:
    if isinstance(values, (int, float)) and not isinstance(values, bool):
        values = (values,)
    if isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        raise ParameterError(f"{owner} {name} must be a list of numbers, got {values!r}", name=name, value=values)
    return tuple(_num(owner, f"{name}[{i}]", v, nonneg=False) for i, v in enumerate(values))


def _pair(owner: str, a: tuple[float, ...], b: tuple[float, ...]) -> None:
    if len(a) != len(b):
        raise ParameterError(
            f"{owner} a and b must have the same length (one pair per harmonic), got {len(a)} and {len(b)}",
            name="b", value=b,
        )


class _EffectBase:
    """Shared mapping helpers (``to_mapping`` / ``from_mapping``)."""

    effect: ClassVar[Effect]

    def to_mapping(self) -> dict[str, Any]:
        """A TOML/JSON-ready table: ``{"effect": <word>, <field>: <value>, ...}``."""
        out: dict[str, Any] = {"effect": str(self.effect)}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if isinstance(value, Environment):
                value = value.to_mapping()
            elif isinstance(value, tuple):
                value = list(value)
            if value is not None:
                out[f.name] = value
        return out

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], *, source: str | None = None):
        """Build from a table written by :meth:`to_mapping`; unknown keys are errors.

        Parameters
        ----------
        mapping : Mapping
            Field values, optionally with ``effect`` (must match this class).
        source : str, optional
            File name for error messages.

        Returns
        -------
        EffectParams
            The parameter value.
        """
        return effect_from_mapping({"effect": str(cls.effect), **mapping}, source=source)


@dataclass(frozen=True, slots=True, kw_only=True)
class NoEffect(_EffectBase):
    """Nothing beyond the nominal model (sensor noise and quantisation only)."""

    effect: ClassVar[Effect] = Effect.NONE


@dataclass(frozen=True, slots=True, kw_only=True)
class Coulomb(_EffectBase):
    """Coulomb friction ``F_c sign(theta')`` opposing motor velocity.

    Notes
    -----
    The sign is regularised as ``clip(theta' / v_reg, -1, 1)`` so that the
    plant right-hand side is Lipschitz: for ``|theta'| >= v_reg`` the torque
    is exactly ``F_c sign(theta')``; below it the term is a steep viscous
    damper of slope ``F_c / v_reg`` (a slow creep instead of perfect
    sticking). The simulator checks that the slope keeps RK4 stable.
    """

    effect: ClassVar[Effect] = Effect.COULOMB
    F_c: float = 0.4      # Coulomb friction level              [N m]
    v_reg: float = 1e-3   # sign() regularisation velocity      [rad/s]

    def __post_init__(self) -> None:
        object.__setattr__(self, "F_c", _num("coulomb", "F_c", self.F_c))
        object.__setattr__(self, "v_reg", _num("coulomb", "v_reg", self.v_reg, positive=True))


@dataclass(frozen=True, slots=True, kw_only=True)
class Stiction(_EffectBase):
    """Stiction with Stribeck decay and bristle dynamics: the LuGre model.

    Defaults are the paper's Table 2.

    Notes
    -----
    LuGre (Canudas de Wit et al. 1995), with ``v = theta'``::

        g(v)   = F_c + (F_s(theta) - F_c) exp(-(v / v_s)^2)
        z'     = v - sigma0 |v| z / g(v)
        tau    = sigma0 z + sigma1 z' + sigma2 v

    At constant velocity the steady state is the Stribeck curve
    ``g(v) sign(v) + sigma2 v``. ``F_s(theta) = F_s + sum_i a_i sin(i theta)
    + b_i cos(i theta)`` makes the static level depend on the motor angle
    (paper Section 2, Fig. 2c); empty ``F_s_a``/``F_s_b`` give a constant
    ``F_s``. Likewise ``v_s(theta) = v_s exp(sum_i c_i sin(i theta) + d_i cos(i theta))``
    (``v_s_a`` = c, ``v_s_b`` = d, harmonics of ``ln v_s``, so ``v_s`` stays > 0)
    makes the Stribeck curve's width depend on the angle: a wide curve is a
    strong negative damping at low speed (stick-slip), a narrow one a sharp
    breakaway.
    """

    effect: ClassVar[Effect] = Effect.STICTION
    F_s: float = 0.5        # static friction level                [N m]
    F_c: float = 0.4        # Coulomb friction level               [N m]
    sigma2: float = 0.1     # viscous friction (added to d_m)      [N m s/rad]
    v_s: float = 0.01       # Stribeck velocity                    [rad/s]
    sigma1: float = 0.6     # bristle damping                      [N m s/rad]
    sigma0: float = 260.0   # bristle stiffness                    [N m/rad]
    F_s_a: tuple[float, ...] = ()  # sin(i theta) harmonics of F_s [N m]
    F_s_b: tuple[float, ...] = ()  # cos(i theta) harmonics of F_s [N m]
    v_s_a: tuple[float, ...] = ()  # sin(i theta) harmonics of ln v_s [-]
    v_s_b: tuple[float, ...] = ()  # cos(i theta) harmonics of ln v_s [-]

    def __post_init__(self) -> None:
        for name in ("F_s", "sigma2", "sigma1"):
            object.__setattr__(self, name, _num("stiction", name, getattr(self, name)))
        for name in ("F_c", "v_s", "sigma0"):
            object.__setattr__(self, name, _num("stiction", name, getattr(self, name), positive=True))
        a = _harmonics("stiction", "F_s_a", self.F_s_a)
        b = _harmonics("stiction", "F_s_b", self.F_s_b)
        _pair("stiction F_s_", a, b)
        object.__setattr__(self, "F_s_a", a)
        object.__setattr__(self, "F_s_b", b)
        va = _harmonics("stiction", "v_s_a", self.v_s_a)
        vb = _harmonics("stiction", "v_s_b", self.v_s_b)
        _pair("stiction v_s_", va, vb)
        object.__setattr__(self, "v_s_a", va)
        object.__setattr__(self, "v_s_b", vb)
        spread = sum(abs(x) for x in a) + sum(abs(x) for x in b)
        if self.F_s - spread <= 0.0:
            raise ParameterError(
                f"stiction F_s - sum(|F_s_a| + |F_s_b|) must be > 0 (g(v) > 0), got {self.F_s - spread!r}",
                name="F_s", value=self.F_s,
            )
        if self.F_s < self.F_c:   # the format's vocabulary: static friction above the Coulomb level
            raise ParameterError(f"stiction F_s must be >= F_c (static friction above the Coulomb level), got "
                                 f"F_s = {self.F_s!r} < F_c = {self.F_c!r}", name="F_s", value=self.F_s)


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionFriction(_EffectBase):
    """Friction whose magnitude depends on the motor angle (shaft misalignment).

    ``tau = sign(theta') (F_c + sum_i a_i sin(i theta) + b_i cos(i theta))``,
    harmonics i = 1..len(a). The magnitude must stay >= 0 (a friction never
    adds energy), so ``F_c >= sum(|a_i| + |b_i|)``. The sign is regularised as
    in :class:`Coulomb`.
    """

    effect: ClassVar[Effect] = Effect.POSITION_FRICTION
    F_c: float = 0.4                 # mean magnitude                 [N m]
    a: tuple[float, ...] = (0.05,)   # sin(i theta) harmonics         [N m]
    b: tuple[float, ...] = (0.0,)    # cos(i theta) harmonics         [N m]
    v_reg: float = 1e-3              # sign() regularisation          [rad/s]

    def __post_init__(self) -> None:
        object.__setattr__(self, "F_c", _num("position_friction", "F_c", self.F_c))
        object.__setattr__(self, "v_reg", _num("position_friction", "v_reg", self.v_reg, positive=True))
        a = _harmonics("position_friction", "a", self.a)
        b = _harmonics("position_friction", "b", self.b)
        _pair("position_friction", a, b)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        spread = sum(abs(x) for x in a) + sum(abs(x) for x in b)
        if spread > self.F_c + 1e-15:
            raise ParameterError(
                f"position_friction F_c must be >= sum(|a_i| + |b_i|) = {spread!r} so the magnitude "
                f"stays >= 0, got F_c = {self.F_c!r}",
                name="F_c", value=self.F_c,
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class Cogging(_EffectBase):
    """Angle-dependent torque independent of the direction of motion.

    ``tau = sum_i a_i sin(i theta) + b_i cos(i theta)``, i = 1..len(a),
    entering the plant like friction (``J_m theta'' = ... - tau``).
    """

    effect: ClassVar[Effect] = Effect.COGGING
    a: tuple[float, ...] = (0.05,)   # sin(i theta) harmonics   [N m]
    b: tuple[float, ...] = (0.0,)    # cos(i theta) harmonics   [N m]

    def __post_init__(self) -> None:
        a = _harmonics("cogging", "a", self.a)
        b = _harmonics("cogging", "b", self.b)
        _pair("cogging", a, b)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)


@dataclass(frozen=True, slots=True, kw_only=True)
class Backlash(_EffectBase):
    """Play in the motor-spring coupling: a dead band of total width ``width_rad``.

    The true spring torque is ``k * dz(theta - q - c)`` with
    ``dz(x) = x - clip(x, -width_rad/2, width_rad/2)`` and the band's centre
    ``c = -position * width_rad / 2``; the encoders still report ``theta`` and
    ``q``, so the measured ``k (theta - q)`` differs. ``position`` is where the
    coupling sits inside its play at the start (theta = q = 0): 0 in the middle
    (``width_rad / 2`` of motor travel to either flank), +1 against the flank
    that transmits positive torque (engaged at once), -1 against the other
    (``width_rad`` of travel before a positive torque is transmitted).
    """

    effect: ClassVar[Effect] = Effect.BACKLASH
    width_rad: float = 1e-3   # total dead-band width      [rad]
    position: float = 0.0     # start inside the play      [-1 .. 1]

    def __post_init__(self) -> None:
        object.__setattr__(self, "width_rad", _num("backlash", "width_rad", self.width_rad))
        pos = _num("backlash", "position", self.position, nonneg=False)
        if not -1.0 <= pos <= 1.0:
            raise ParameterError(f"backlash position must be in [-1, 1] (a flank of the play), got {pos!r}",
                                 name="position", value=pos)
        object.__setattr__(self, "position", pos)


@dataclass(frozen=True, slots=True, kw_only=True)
class Delay(_EffectBase):
    """Pure time delay between the command and the torque at the motor.

    The simulator quantises the delay to its integration substep
    ``1 / (rate_hz * substeps)`` (round to nearest).
    """

    effect: ClassVar[Effect] = Effect.DELAY
    delay_s: float = 1e-3   # command-to-torque delay     [s]

    def __post_init__(self) -> None:
        object.__setattr__(self, "delay_s", _num("delay", "delay_s", self.delay_s))


@dataclass(frozen=True, slots=True, kw_only=True)
class TorqueGain(_EffectBase):
    """The actual motor torque is ``gain`` times the command."""

    effect: ClassVar[Effect] = Effect.TORQUE_GAIN
    gain: float = 0.9   # actual / commanded torque      [-]

    def __post_init__(self) -> None:
        object.__setattr__(self, "gain", _num("torque_gain", "gain", self.gain, positive=True))


@dataclass(frozen=True, slots=True, kw_only=True)
class EnvironmentMismatch(_EffectBase):
    """The real environment differs from the declared (nominal) one.

    Either give the true ``environment`` outright, or scale the nominal
    total ``J`` (``J_scale``), ``d`` (``d_scale``) and ``k_e``
    (``k_e_scale``); the scales act on ``J_e``/``J_l`` and ``d_e``/``d_l``
    alike.
    """

    effect: ClassVar[Effect] = Effect.ENVIRONMENT_MISMATCH
    J_scale: float = 1.0     # true J / nominal J         [-]
    d_scale: float = 1.0     # true d / nominal d         [-]
    k_e_scale: float = 1.0   # true k_e / nominal k_e     [-]
    environment: Environment | None = None  # the true environment (overrides the scales)

    def __post_init__(self) -> None:
        for name in ("J_scale", "d_scale", "k_e_scale"):
            object.__setattr__(self, name, _num("environment_mismatch", name, getattr(self, name),
                                                positive=name == "J_scale"))   # J = 0: no inertia at all
        if self.environment is not None and not isinstance(self.environment, Environment):
            if isinstance(self.environment, Mapping):
                object.__setattr__(self, "environment", Environment.from_mapping(self.environment))
            else:
                raise ParameterError(
                    f"environment_mismatch environment must be an Environment or a table, "
                    f"got {self.environment!r}",
                    name="environment", value=self.environment,
                )

    def true_environment(self, nominal: Environment) -> Environment:
        """The environment the simulated hardware really has.

        Parameters
        ----------
        nominal : Environment
            The declared environment.

        Returns
        -------
        Environment
            ``environment`` if given, else the nominal one with scaled
            inertias [kg m^2], dampings [N m s/rad] and ``k_e`` [N m/rad].
        """
        if self.environment is not None:
            return self.environment
        return dataclasses.replace(
            nominal,
            J_e=nominal.J_e * self.J_scale, J_l=nominal.J_l * self.J_scale,
            d_e=nominal.d_e * self.d_scale, d_l=nominal.d_l * self.d_scale,
            k_e=nominal.k_e * self.k_e_scale,
        )


EffectParams = (NoEffect | Coulomb | Stiction | PositionFriction | Cogging | Backlash | Delay
                | TorqueGain | EnvironmentMismatch)

#: The parameter class of every effect word.
EFFECT_CLASSES: Mapping[Effect, type] = {
    cls.effect: cls
    for cls in (NoEffect, Coulomb, Stiction, PositionFriction, Cogging, Backlash, Delay, TorqueGain,
                EnvironmentMismatch)
}


def effect_from_mapping(mapping: Mapping[str, Any], *, source: str | None = None, where: str = "effect"):
    """Build an effect parameter value from ``{"effect": <word>, <field>: <value>, ...}``.

    Parameters
    ----------
    mapping : Mapping
        The table; ``effect`` names the word, the other keys are the fields of
        its class (omitted fields take the defaults).
    source : str, optional
        File name, for error messages.
    where : str
        Location of the table inside the file (e.g. ``truth.effects[2]``).

    Returns
    -------
    EffectParams
        The parameter value.

    Raises
    ------
    ExperimentFormatError
        Unknown effect word, unknown key or invalid value (naming file and key).
    """
    from .errors import ExperimentFormatError

    prefix = f"{source}: " if source else ""
    if not isinstance(mapping, Mapping):
        raise ExperimentFormatError(f"{prefix}[{where}] must be a table, got {mapping!r}", path=source, key=where)
    word = mapping.get("effect")
    try:
        cls = EFFECT_CLASSES[Effect(word)]
    except ValueError:
        raise ExperimentFormatError(
            f"{prefix}[{where}] effect must be one of {', '.join(e.value for e in Effect)}, got {word!r}",
            path=source, key=f"{where}.effect",
        ) from None
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in mapping.items():
        if key == "effect":
            continue
        if key not in names:
            raise ExperimentFormatError(
                f"{prefix}[{where}] unknown key '{key}' for effect '{word}'; allowed: {', '.join(names) or '(none)'}",
                path=source, key=f"{where}.{key}",
            )
        if key == "environment" and isinstance(value, Mapping):
            value = Environment.from_mapping(value, source=source)
        kwargs[key] = value
    try:
        return cls(**kwargs)
    except (ParameterError, TypeError) as exc:
        raise ExperimentFormatError(f"{prefix}[{where}] {exc}", path=source, key=where) from None


def effects_to_mappings(effects: Sequence[Any]) -> list[dict[str, Any]]:
    """``[e.to_mapping() for e in effects]`` (for TOML/JSON).

    Parameters
    ----------
    effects : sequence of EffectParams
        Effect parameter values.

    Returns
    -------
    list of dict
        One table per effect.
    """
    return [e.to_mapping() for e in effects]
