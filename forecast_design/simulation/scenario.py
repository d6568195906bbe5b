"""Scenario files: what to simulate (nominal model + truth + reference + options) in one TOML.

Format ``forecast-scenario/1``: the experiment format's nominal-model
sections, plus the hidden truth, the reference and the simulation options::

    format = "forecast-scenario/1"
    description = "Fig. 7: LuGre, PD 5/0.1, EA-FOB 10 Hz"   # optional

    [sampling]
    rate_hz = 2000.0                 # control rate [Hz]

    [testbed]                        # nominal SEA, as in the experiment format, optionally with its
    J_m = 0.133                      # link J_l, d_l (the default of the environment); or, instead
    d_m = 0.3                        # of the table, testbed = "mysea.toml" (a testbed file beside
    k = 58.0                         # the scenario, inline "k=40", "table1")

    [environment]                    # nominal environment, as in the experiment format; or a string
    J_e = 1.0
    d_e = 20.0
    k_e = 100.0
    J_l = 0.0018
    d_l = 0.35
    locked = false

    [controller]                     # optional: present = closed-loop force control; any kind of
    kind = "pd"                      # the experiment format (pd, pid, tf, discrete), with its keys:
    P = 5.0                          # T_f, derivative_on, discretization, feedforward, u_min, u_max...
    D = 0.1

    [compensator]                    # optional; as in the experiment format (q_family, q_order, q_damping)
    kind = "ea-fob"
    w_q_hz = 10.0

    [sfm]                            # required iff compensator kind = "sfm": identified parameters
    viscous = 0.4                    # viscous, coulomb, offset, sin<i>, cos<i>, coulomb_sin<i>, ...
    coulomb = 0.4

    [truth]                          # optional: the hardware beyond the nominal model
    initial_angle = 0.0              # absolute motor angle at theta = 0 [rad]
    include_nominal_viscous = true   # d_m omega is part of the true friction

    [truth.torque_sensor]            # optional: tau_s read by a torque sensor, not derived from the encoders
    noise_std_N_m = 0.002            # white noise [N m]
    gain = 1.0                       # scale of the reading [-]
    offset_N_m = 0.0                 # zero of the reading [N m]

    [[truth.effects]]                # one table per effect; words of the spec's vocabulary
    effect = "stiction"              # fields as in forecast_design.effects (defaults: Table 2)
    F_s = 0.5

    [[truth.effects]]
    effect = "environment_mismatch"
    k_e_scale = 1.5                  # or a [truth.effects.environment] table

    [variability]                    # optional: run-to-run variability between repetitions
    repetitions = 10                 # runs of the scenario [-]
    initial_angle = "random"         # "random": uniform in [0, 2 pi) per repetition; "fixed": [truth]'s
    viscous_drift = 0.0              # relative change of the viscous friction per repetition [-]
    backlash_position = "fixed"      # "random": the backlash effect starts anywhere in its play
    seed = 0                         # seed of the initial angles

    [reference]                      # force reference (closed loop) or torque profile (open loop)
    kind = "square"                  # constant | step | square | sine | multisine | chirp | ramp | piecewise_linear
    high = 1.0
    low = -1.0
    period_s = 2.0

    [simulation]
    duration_s = 4.0                 # required [s]
    substeps = 10                    # RK4 steps per period
    seed = 0                         # process-noise seed
    encoder_counts = 2000000         # 0: exact angles
    encoder_jitter_counts = 0.0      # [counts]: white noise before the encoders' quantiser
    process_noise_std = 0.001        # [N m]
    torque_limit = 10.0              # [N m]; omit for none
    velocity_cutoff_hz = 50.0        # SFM velocity filter [Hz]
    sfm_deadband = 0.0               # [rad/s]
    step_timeout_s = 10.0            # [s]: a controller written as code that hangs longer is a fault

The controller's discretisation, derivative filter and derivative placement are keys of its
``[controller]`` table (``discretization``, ``T_f``, ``derivative_on``), as in a log: what the
scenario says is what runs and what the simulated log records.

Unknown keys are errors; a missing required key names the key and the file.
Omitted optional keys take the defaults of :func:`~.run.simulate`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from ..effects import Backlash, PositionFriction, Stiction, effect_from_mapping, effects_to_mappings
from ..environments import document_design
from ..errors import ExperimentFormatError, ParameterError
from ..compensators import friction_feedforward
from ..controllers import PAPER_PD, controller_from_mapping
from ..params import Compensator, Design
from ..limits import check_limit, check_physical
from .references import reference_from_mapping
from .plant import TorqueSensor
from .run import MAX_ENCODER_JITTER_COUNTS, SimulationResult, save_simulation, simulate

__all__ = ["SCENARIO_FORMAT", "Repetition", "Scenario", "Variability", "load_scenario", "scenario_from_mapping", "run_scenario"]

#: The ``format`` string of scenario files.
SCENARIO_FORMAT = "forecast-scenario/1"

_TOP = ("format", "description", "sampling", "testbed", "environment", "controller", "compensator", "sfm",
        "truth", "variability", "reference", "simulation")
_SIM_KEYS = {
    "duration_s": float, "substeps": int, "seed": int, "encoder_counts": int, "encoder_jitter_counts": float,
    "process_noise_std": float,
    "torque_limit": float, "velocity_cutoff_hz": float, "sfm_deadband": float, "step_timeout_s": float,
}
#: Former [simulation] keys that now belong to the controller: where they went.
_MOVED = {"derivative_cutoff_hz": "T_f (the derivative filter's time constant [s])",
          "derivative_on": "derivative_on", "method": "discretization"}


@dataclass(frozen=True, slots=True, kw_only=True)
class Variability:
    """Run-to-run variability of the virtual testbed between repetitions (paper Section 2, Figs. 2c and 3).

    The hardware's friction depends on the motor angle (Oldham-coupling misalignment): the
    :class:`~forecast_design.effects.Stiction` effect's static level ``F_s(theta)`` (``F_s_a``,
    ``F_s_b``) and Stribeck velocity ``v_s(theta)`` (``v_s_a``, ``v_s_b``), the
    :class:`~forecast_design.effects.PositionFriction` ripple and cogging. Each repetition
    starts from its own absolute motor angle, so each sees its own stiction level and
    Stribeck curve, as the testbed did from each initial position. A slow drift (e.g. the
    lubricant warming up) changes the viscous friction from one repetition to the next. The
    couplings' play (a :class:`~forecast_design.effects.Backlash` effect) can start at a
    different place inside the gap in each repetition (``backlash_position``).

    Attributes
    ----------
    repetitions : int
        Runs of the scenario [-] (>= 1).
    initial_angle : str
        ``"random"``: repetition ``i`` starts at ``initial_angles(n)[i]``, uniform in
        [0, 2 pi); ``"fixed"``: every repetition at the scenario's ``[truth] initial_angle``.
    viscous_drift : float
        Relative change of the viscous friction per repetition [-]: repetition ``i`` has the
        stiction's ``sigma2`` (and the position friction's mean level) times
        ``1 + viscous_drift * i`` (> -1 / (repetitions - 1) so that it stays positive).
    backlash_position : str
        ``"fixed"``: the backlash effect's own ``position`` in every repetition; ``"random"``:
        repetition ``i`` starts at ``backlash_positions()[i]``, uniform in [-1, 1] (anywhere
        between the two flanks of the play).
    seed : int
        Seed of the initial angles (and of the backlash positions).
    """

    repetitions: int = 1
    initial_angle: str = "random"
    viscous_drift: float = 0.0
    seed: int = 0
    backlash_position: str = "fixed"

    def __post_init__(self) -> None:
        if isinstance(self.repetitions, bool) or not isinstance(self.repetitions, int) or self.repetitions < 1:
            raise ParameterError(f"variability repetitions must be an integer >= 1, got {self.repetitions!r}",
                                 name="repetitions", value=self.repetitions)
        check_limit("repetitions", "repetitions", self.repetitions)   # before any array of them is made
        if self.initial_angle not in ("random", "fixed"):
            raise ParameterError(f"variability initial_angle must be 'random' or 'fixed', got "
                                 f"{self.initial_angle!r}", name="initial_angle", value=self.initial_angle)
        d = self.viscous_drift
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(d) or \
                1.0 + d * (self.repetitions - 1) <= 0.0:
            raise ParameterError(f"variability viscous_drift must be a number keeping 1 + drift * i > 0 for "
                                 f"every repetition, got {d!r}", name="viscous_drift", value=d)
        object.__setattr__(self, "viscous_drift", float(d))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ParameterError(f"variability seed must be an integer, got {self.seed!r}", name="seed",
                                 value=self.seed)
        if self.backlash_position not in ("random", "fixed"):
            raise ParameterError(f"variability backlash_position must be 'random' or 'fixed', got "
                                 f"{self.backlash_position!r}", name="backlash_position",
                                 value=self.backlash_position)

    def initial_angles(self, fixed: float = 0.0) -> np.ndarray:
        """Absolute motor angle of each repetition [rad], shape (repetitions,).

        Parameters
        ----------
        fixed : float
            The angle of every repetition when ``initial_angle == "fixed"`` [rad].
        """
        if self.initial_angle == "fixed":
            return np.full(self.repetitions, float(fixed))
        return np.random.default_rng(self.seed).uniform(0.0, 2.0 * math.pi, self.repetitions)

    def backlash_positions(self) -> np.ndarray:
        """Start of each repetition inside the backlash play [-], uniform in [-1, 1], shape (repetitions,).

        Drawn from ``numpy.random.default_rng([seed, 1])``, a stream independent of the initial angles.
        """
        return np.random.default_rng([self.seed, 1]).uniform(-1.0, 1.0, self.repetitions)

    def effects_of(self, effects: tuple, index: int) -> tuple:
        """The hardware's effects in repetition ``index``: viscous levels drifted (:attr:`viscous_drift`),
        the backlash's start inside its play drawn (:attr:`backlash_position`).

        Parameters
        ----------
        effects : tuple
            Effect parameter values of the scenario's truth.
        index : int
            Repetition [-], 0-based.
        """
        if self.backlash_position == "random":
            pos = float(self.backlash_positions()[index])
            effects = tuple(dataclasses.replace(e, position=pos) if isinstance(e, Backlash) else e for e in effects)
        if self.viscous_drift == 0.0 or index == 0:
            return tuple(effects)
        scale = 1.0 + self.viscous_drift * index
        out = []
        for e in effects:
            if isinstance(e, Stiction):
                e = dataclasses.replace(e, sigma2=e.sigma2 * scale)
            elif isinstance(e, PositionFriction):
                e = dataclasses.replace(e, F_c=e.F_c * scale, a=tuple(x * scale for x in e.a),
                                        b=tuple(x * scale for x in e.b))
            out.append(e)
        return tuple(out)

    def to_mapping(self) -> dict[str, Any]:
        """The ``[variability]`` table."""
        return {"repetitions": self.repetitions, "initial_angle": self.initial_angle,
                "viscous_drift": self.viscous_drift, "backlash_position": self.backlash_position, "seed": self.seed}


@dataclass(frozen=True, slots=True)
class Repetition:
    """What one repetition of a scenario changes (:meth:`Scenario.repetition`).

    Attributes
    ----------
    effects : tuple
        The repetition's effects (drifted by ``[variability]``).
    seed : int
        Process-noise seed.
    initial_angle : float
        Absolute motor angle at theta = 0 [rad].
    description : str
        Free text of the repetition's experiment.
    """

    effects: tuple
    seed: int
    initial_angle: float
    description: str


@dataclass(frozen=True, slots=True)
class Scenario:
    """A parsed scenario: everything :func:`~.run.simulate` needs.

    Attributes
    ----------
    design : Design
        Nominal model (+ controller/compensator).
    rate_hz : float
        Control rate [Hz].
    closed_loop : bool
        True when the file has a ``[controller]``.
    reference : Reference
        Force reference or torque profile.
    effects : tuple
        Effect parameter values.
    options : dict
        Keyword arguments for :func:`~.run.simulate` (duration, substeps, seed, ...).
    description : str
        Free text.
    source : str or None
        The file it came from.
    variability : Variability or None
        Run-to-run variability (``[variability]``); None: one run.
    notes : tuple of str
        Defaults the file left to the toolbox (e.g. a critically damped d_e), said to the user.
    """

    design: Design
    rate_hz: float
    closed_loop: bool
    reference: Any
    effects: tuple
    options: Mapping[str, Any] = field(default_factory=dict)
    description: str = ""
    source: str | None = None
    variability: Variability | None = None
    notes: tuple[str, ...] = field(default=(), compare=False)

    @property
    def repetition_count(self) -> int:
        """Runs of the scenario: its ``[variability]`` repetitions, or 1 without one."""
        return 1 if self.variability is None else self.variability.repetitions

    def repetition(self, index: int = 0) -> Repetition:
        """What repetition ``index`` of the scenario changes: the one rule :meth:`run` and
        :func:`~.batch.simulate_batch` (through :func:`~.batch.scenario_runs`) follow.

        Repetition ``i`` starts at the ``i``-th initial angle of :class:`Variability`, with its
        drifted effects and process-noise seed ``seed + i``; without ``[variability]`` only
        repetition 0 exists: the scenario's own effects, seed and initial angle.

        Raises
        ------
        ParameterError
            If ``index`` is not in ``0 .. repetition_count - 1``.
        """
        opts = self.options
        seed, angle0 = int(opts.get("seed", 0)), float(opts.get("initial_angle", 0.0))
        v = self.variability
        if v is None:
            if isinstance(index, bool) or index != 0:
                raise ParameterError("the scenario has no [variability]: only repetition 0", name="repetition",
                                     value=index)
            return Repetition(effects=tuple(self.effects), seed=seed, initial_angle=angle0,
                              description=self.description)
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < v.repetitions:
            raise ParameterError(f"repetition must be in 0..{v.repetitions - 1}, got {index!r}",
                                 name="repetition", value=index)
        index = int(index)
        return Repetition(effects=tuple(v.effects_of(self.effects, index)), seed=seed + index,
                          initial_angle=float(v.initial_angles(opts.get("initial_angle", 0.0))[index]),
                          description=f"{self.description} (repetition {index})".strip())

    def run(self, repetition: int = 0) -> SimulationResult:
        """Simulate the scenario (:func:`~.run.simulate`), repetition ``repetition`` of its variability
        (:meth:`repetition`)."""
        rep = self.repetition(repetition)
        opts = {**self.options, "seed": rep.seed, "initial_angle": rep.initial_angle}
        with self.naming_errors():
            return simulate(self.design, reference=self.reference, effects=rep.effects, rate_hz=self.rate_hz,
                            closed_loop=self.closed_loop, description=rep.description, **opts)

    @contextlib.contextmanager
    def naming_errors(self) -> Iterator[None]:
        """Within the block, a ``ParameterError`` of the simulation (an unstable RK4 step for this plant, a
        value no load check covers) names the scenario file first, as every scenario error does.

        Yields
        ------
        None
        """
        try:
            yield
        except ParameterError as exc:
            if not self.source or str(exc).startswith(f"{self.source}: "):
                raise
            raise ExperimentFormatError(f"{self.source}: {exc}", path=self.source, key=exc.name) from None

    def runs(self) -> list[SimulationResult]:
        """Every repetition of the scenario (one run without ``[variability]``)."""
        return [self.run(i) for i in range(self.repetition_count)]

    def with_friction(self, friction: Mapping[str, float]) -> Scenario:
        """The scenario with an ``sfm`` compensator running on identified friction.

        Parameters
        ----------
        friction : Mapping[str, float]
            Identified SFM parameters as :mod:`forecast_design.friction` names them (``viscous``
            [N m s/rad], ``coulomb``, ``offset``, ``sin<i>``, ``cos<i>``, ``coulomb_sin<i>``,
            ``coulomb_cos<i>`` [N m]), e.g. the ``params`` of ``identify --json``.

        Returns
        -------
        Scenario
            A copy whose compensator is ``Compensator(kind="sfm", friction=friction)`` (replacing a
            scenario's own ``[sfm]`` parameters; keeping its Q settings, which the SFM ignores).

        Raises
        ------
        ParameterError
            When the scenario's compensator is an observer (``ea-fob``...) rather than none or
            ``sfm``, or a parameter name or value is not one of the SFM's.
        """
        comp = self.design.compensator
        if comp is not None and comp.kind not in ("none", "sfm"):
            raise ParameterError(f"identified friction drives an 'sfm' compensator, but the scenario's compensator is "
                                 f"{comp.kind!r}; set [compensator] kind = \"sfm\" (or none) to use it",
                                 name="friction", value=comp.kind)
        friction_feedforward(friction, self.rate_hz)       # names and values, as for a [sfm] table
        base = comp if comp is not None else Compensator(kind="sfm")
        new = Compensator(kind="sfm", w_q_hz=base.w_q_hz, q_family=base.q_family, q_order=base.q_order,
                          friction=dict(friction))
        options = {k: v for k, v in self.options.items() if k != "sfm_params"}
        return dataclasses.replace(self, design=dataclasses.replace(self.design, compensator=new), options=options)

    def to_mapping(self) -> dict[str, Any]:
        """The scenario as a TOML-ready mapping (round-trips through :func:`scenario_from_mapping`)."""
        out: dict[str, Any] = {"format": SCENARIO_FORMAT}
        if self.description:
            out["description"] = self.description
        out["sampling"] = {"rate_hz": self.rate_hz}
        testbed = self.design.testbed
        out["testbed"] = {**testbed.to_mapping(), **({"J_l": testbed.J_l, "d_l": testbed.d_l} if testbed.link else {})}
        out["environment"] = self.design.environment.to_mapping()
        if self.closed_loop:
            ctrl = self.design.controller or PAPER_PD
            out["controller"] = ctrl.scenario_mapping() if ctrl.is_code else ctrl.to_mapping()
        comp = self.design.compensator
        if comp is not None:
            out["compensator"] = {k: v for k, v in comp.to_mapping().items() if k != "friction"}   # friction: [sfm]
        opts = dict(self.options)
        sfm = opts.pop("sfm_params", None)
        if sfm is None and comp is not None and comp.friction:
            sfm = comp.friction_params
        if sfm is not None:
            out["sfm"] = dict(sfm)
        truth: dict[str, Any] = {}
        for key in ("initial_angle", "include_nominal_viscous"):
            if key in opts:
                truth[key] = opts.pop(key)
        sensor = opts.pop("torque_sensor", None)
        if sensor is not None:
            truth["torque_sensor"] = sensor.to_mapping()
        if self.effects:
            truth["effects"] = effects_to_mappings(self.effects)
        if truth:
            out["truth"] = truth
        if self.variability is not None:
            out["variability"] = self.variability.to_mapping()
        out["reference"] = self.reference.to_mapping()
        sim = {k: v for k, v in opts.items() if not (k == "torque_limit" and math.isinf(v))}
        if sim.get("encoder_counts", 1) is None:
            sim["encoder_counts"] = 0
        out["simulation"] = sim
        return out


def _table(doc: Mapping[str, Any], key: str, prefix: str, source: str | None, *, required: bool):
    if key not in doc:
        if required:
            raise ExperimentFormatError(f"{prefix}missing required table [{key}]", path=source, key=key)
        return None
    value = doc[key]
    if not isinstance(value, Mapping):
        raise ExperimentFormatError(f"{prefix}[{key}] must be a table, got {value!r}", path=source, key=key)
    return value


def _typed(value: Any, kind: type, prefix: str, key: str, source: str | None) -> Any:
    if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if kind is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if kind is str and isinstance(value, str):
        return value
    raise ExperimentFormatError(f"{prefix}[simulation] {key} must be {kind.__name__}, got {value!r}",
                                path=source, key=f"simulation.{key}")


def scenario_from_mapping(doc: Mapping[str, Any], *, source: str | None = None) -> Scenario:
    """Validate a scenario mapping (a parsed TOML document).

    Parameters
    ----------
    doc : Mapping
        The document (see the module docstring for the format).
    source : str, optional
        File name for error messages.

    Returns
    -------
    Scenario
        The parsed scenario.

    Raises
    ------
    ExperimentFormatError
        Unknown or missing keys, wrong types or invalid values, naming the
        file and the key.
    """
    prefix = f"{source}: " if source else ""
    for key in doc:
        if key not in _TOP:
            raise ExperimentFormatError(f"{prefix}unknown key '{key}'; allowed: {', '.join(_TOP)}",
                                        path=source, key=key)
    if "format" not in doc:
        raise ExperimentFormatError(f"{prefix}missing required key 'format' (= \"{SCENARIO_FORMAT}\")",
                                    path=source, key="format")
    if doc["format"] != SCENARIO_FORMAT:
        raise ExperimentFormatError(f"{prefix}format must be \"{SCENARIO_FORMAT}\", got {doc['format']!r}",
                                    path=source, key="format")
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise ExperimentFormatError(f"{prefix}description must be a string", path=source, key="description")
    sampling = _table(doc, "sampling", prefix, source, required=True)
    for key in sampling:
        if key != "rate_hz":
            raise ExperimentFormatError(f"{prefix}[sampling] unknown key '{key}'; allowed: rate_hz",
                                        path=source, key=f"sampling.{key}")
    if "rate_hz" not in sampling:
        raise ExperimentFormatError(f"{prefix}[sampling] missing required key 'rate_hz'", path=source,
                                    key="sampling.rate_hz")
    rate = sampling["rate_hz"]
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (rate > 0) or not math.isfinite(rate):
        raise ExperimentFormatError(f"{prefix}[sampling] rate_hz must be > 0 [Hz], got {rate!r}", path=source,
                                    key="sampling.rate_hz")
    try:
        check_physical("[sampling]", "rate_hz", float(rate))
    except ParameterError as exc:
        raise ExperimentFormatError(f"{prefix}{exc}", path=source, key="sampling.rate_hz") from None
    if "testbed" not in doc:
        raise ExperimentFormatError(f"{prefix}missing required table [testbed]", path=source, key="testbed")
    testbed, environment, notes = document_design(doc, source)
    ctrl_table = _table(doc, "controller", prefix, source, required=False)
    controller = None if ctrl_table is None else controller_from_mapping(
        ctrl_table, source=source, rate_hz=rate, base=Path(source).parent if source else None)
    comp_table = _table(doc, "compensator", prefix, source, required=False)
    compensator = None
    if comp_table is not None:
        compensator = Compensator.from_mapping(comp_table, source=source)
    options: dict[str, Any] = {}
    sfm = _table(doc, "sfm", prefix, source, required=False)
    kind = compensator.kind if compensator is not None else "none"
    if kind == "sfm" and sfm is None:
        raise ExperimentFormatError(f"{prefix}compensator kind 'sfm' needs a [sfm] table of identified parameters",
                                    path=source, key="sfm")
    if sfm is not None:
        if kind != "sfm":
            raise ExperimentFormatError(f"{prefix}[sfm] given but the compensator kind is {kind!r}", path=source,
                                        key="sfm")
        try:
            friction_feedforward(sfm, float(rate))
        except ParameterError as exc:
            raise ExperimentFormatError(f"{prefix}[sfm] {exc}", path=source, key=f"sfm.{exc.name}") from None
        options["sfm_params"] = {k: float(v) for k, v in sfm.items()}
    effects: list[Any] = []
    truth = _table(doc, "truth", prefix, source, required=False)
    if truth is not None:
        for key, value in truth.items():
            if key == "effects":
                if not isinstance(value, list):
                    raise ExperimentFormatError(f"{prefix}[truth] effects must be an array of tables "
                                                "([[truth.effects]])", path=source, key="truth.effects")
                effects = [effect_from_mapping(e, source=source, where=f"truth.effects[{i}]")
                           for i, e in enumerate(value)]
                words = [str(getattr(e, "effect", type(e).__name__)) for e in effects]
                for word in dict.fromkeys(w for w in words if words.count(w) > 1):
                    raise ExperimentFormatError(f"{prefix}[truth] effect '{word}' is given {words.count(word)} "
                                                "times; give each effect once", path=source, key="truth.effects")
            elif key == "initial_angle":
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ExperimentFormatError(f"{prefix}[truth] initial_angle must be a number [rad]",
                                                path=source, key="truth.initial_angle")
                options["initial_angle"] = float(value)
            elif key == "include_nominal_viscous":
                if not isinstance(value, bool):
                    raise ExperimentFormatError(f"{prefix}[truth] include_nominal_viscous must be true or false",
                                                path=source, key="truth.include_nominal_viscous")
                options["include_nominal_viscous"] = value
            elif key == "torque_sensor":
                options["torque_sensor"] = _torque_sensor(value, prefix, source)
            else:
                raise ExperimentFormatError(f"{prefix}[truth] unknown key '{key}'; allowed: effects, initial_angle, "
                                            "include_nominal_viscous, torque_sensor", path=source, key=f"truth.{key}")
    variability = None
    var_table = _table(doc, "variability", prefix, source, required=False)
    if var_table is not None:
        allowed = ("repetitions", "initial_angle", "viscous_drift", "backlash_position", "seed")
        for key in var_table:
            if key not in allowed:
                raise ExperimentFormatError(f"{prefix}[variability] unknown key '{key}'; allowed: "
                                            f"{', '.join(allowed)}", path=source, key=f"variability.{key}")
        try:
            variability = Variability(**dict(var_table))
        except ParameterError as exc:
            raise ExperimentFormatError(f"{prefix}[variability] {exc}", path=source,
                                        key=f"variability.{exc.name}") from None
    reference = reference_from_mapping(_table(doc, "reference", prefix, source, required=True), source=source)
    sim = _table(doc, "simulation", prefix, source, required=True)
    for key, value in sim.items():
        if key in _MOVED:
            raise ExperimentFormatError(f"{prefix}[simulation] {key} belongs to the controller now: set "
                                        f"{_MOVED[key]} in [controller]", path=source, key=f"simulation.{key}")
        if key not in _SIM_KEYS:
            raise ExperimentFormatError(f"{prefix}[simulation] unknown key '{key}'; allowed: {', '.join(_SIM_KEYS)}",
                                        path=source, key=f"simulation.{key}")
        options[key] = _typed(value, _SIM_KEYS[key], prefix, key, source)
    if "duration_s" not in sim:
        raise ExperimentFormatError(f"{prefix}[simulation] missing required key 'duration_s'", path=source,
                                    key="simulation.duration_s")
    _check_simulation(options, float(rate), prefix, source)
    design = Design(testbed=testbed, environment=environment,
                    controller=controller, compensator=compensator)
    return Scenario(design=design, rate_hz=float(rate), closed_loop=controller is not None, reference=reference,
                    effects=tuple(effects), options=options, description=description, source=source,
                    variability=variability, notes=notes)


def _torque_sensor(value: Any, prefix: str, source: str | None) -> TorqueSensor:
    """A ``[truth.torque_sensor]`` table: ``noise_std_N_m``, ``gain``, ``offset_N_m`` (each optional)."""
    where = "truth.torque_sensor"
    if not isinstance(value, Mapping):
        raise ExperimentFormatError(f"{prefix}[{where}] must be a table, got {value!r}", path=source, key=where)
    allowed = ("noise_std_N_m", "gain", "offset_N_m")
    for key in value:
        if key not in allowed:
            raise ExperimentFormatError(f"{prefix}[{where}] unknown key '{key}'; allowed: {', '.join(allowed)}",
                                        path=source, key=f"{where}.{key}")
    try:
        return TorqueSensor(**dict(value))
    except ParameterError as exc:
        raise ExperimentFormatError(f"{prefix}[{where}] {exc}", path=source, key=f"{where}.{exc.name}") from None


def _check_simulation(options: Mapping[str, Any], rate: float, prefix: str, source: str | None) -> None:
    """Bounds of the ``[simulation]`` options (docs/reliability.md): nothing that hangs, overflows or aliases."""
    def fail(key: str, message: str) -> ExperimentFormatError:
        return ExperimentFormatError(f"{prefix}[simulation] {key} {message}", path=source, key=f"simulation.{key}")

    if "encoder_counts" in options and not options["encoder_counts"] >= 0:
        raise fail("encoder_counts", f"must be an integer >= 0 [counts/rev] (0: exact angles), got "
                                     f"{options['encoder_counts']!r}")
    if options.get("encoder_jitter_counts", 0.0) > 0 and not options.get("encoder_counts", 1):
        raise fail("encoder_jitter_counts", "needs encoder_counts > 0 (a jitter before the quantiser of exact angles "
                                            "has no count)")
    nyquist = rate / 2.0
    bounds = {"duration_s": (0.0, None, False), "process_noise_std": (0.0, 100.0, True),
              "encoder_jitter_counts": (0.0, MAX_ENCODER_JITTER_COUNTS, True),
              "torque_limit": (0.0, None, False), "sfm_deadband": (0.0, None, True),
              "step_timeout_s": (0.0, None, False),
              "velocity_cutoff_hz": (0.0, nyquist, False)}
    for key, (lo, hi, closed) in bounds.items():
        v = options.get(key)
        if v is None or (key == "torque_limit" and v == math.inf):
            continue
        ok = math.isfinite(v) and (v >= lo if closed else v > lo)
        if hi is not None:
            ok = ok and (v < hi if key.endswith("_hz") else v <= hi)
        if not ok:
            where = f"{'>=' if closed else '>'} {lo:g}"
            if hi is not None:
                where += f" and {'<' if key.endswith('_hz') else '<='} {hi:g}"
            extra = " (Nyquist, rate_hz / 2)" if key.endswith("_hz") else ""
            raise fail(key, f"must be {where}{extra}, got {v!r}")
    try:
        for key in ("substeps", "seed"):
            if key in options:
                check_limit(key, key, options[key])
        if "duration_s" in options:
            check_limit(f"duration_s x rate_hz = {options['duration_s'] * rate:.3g} samples", "simulation_samples",
                        max(1, int(min(options["duration_s"] * rate, 2**62))))
    except ParameterError as exc:
        raise ExperimentFormatError(f"{prefix}[simulation] {exc}", path=source,
                                    key=f"simulation.{exc.name}") from None


def load_scenario(path: str | os.PathLike[str]) -> Scenario:
    """Read and validate a scenario TOML file.

    Parameters
    ----------
    path : str or os.PathLike
        The scenario file.

    Returns
    -------
    Scenario
        The parsed scenario.

    Raises
    ------
    ExperimentFormatError
        Invalid TOML or any rule of the format (naming file and key).
    """
    from ..experiment_io import read_toml

    p = Path(path)
    doc, _ = read_toml(p, "scenario file")   # size, nesting, UTF-8 (with or without BOM) checked there
    return scenario_from_mapping(doc, source=str(p))


def run_scenario(path: str | os.PathLike[str], out: str | os.PathLike[str]) -> dict[str, Path]:
    """Simulate a scenario file and write the run (the ``simulate`` CLI verb).

    Parameters
    ----------
    path : str or os.PathLike
        Scenario TOML.
    out : str or os.PathLike
        Experiment TOML to write (``RUN.toml``; also ``RUN.csv``,
        ``RUN.truth.json``, ``RUN.truth.csv``).

    Returns
    -------
    dict of str to pathlib.Path
        Paths written (see :func:`~.run.save_simulation`).
    """
    result = load_scenario(path).run()
    return save_simulation(result, out)
