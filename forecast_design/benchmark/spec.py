"""What a benchmark runs: controllers, compensators, an environment set, references, repetitions.

The command-line forms (``forecast-design benchmark``)::

    --controller SPEC            any force controller, repeatable: pd:5:0.1 (the paper's), pid:P:I:D[:T_f],
                                 tf:NUM/DEN, discrete:NUM/DEN, or a TOML file with a [controller] table
    --compensator none,sfm,ea-fob[:W_Q_HZ]
    --reference step:AMP[:DURATION_S] | chirp:AMP:F0_HZ:F1_HZ[:DURATION_S]

Each benchmark *cell* is one (controller, compensator, environment, reference)
and holds ``repetitions`` runs; a cell is one task of the executor and its
results are stored under a key derived from every input (:meth:`BenchmarkSpec.cell_key`).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

from ..effects import effects_to_mappings
from ..errors import ParameterError
from ..limits import check_limit
from ..controllers import Controller, parse_controller
from ..params import COMPENSATOR_KINDS, Compensator, Environment, Testbed
from ..reproduce import TABLE3_TRUTH
from ..simulation.references import Chirp, Step

__all__ = ["BenchmarkSpec", "Cell", "parse_controller", "parse_compensators", "parse_reference",
           "reference_label", "DEFAULT_W_Q_HZ", "BENCHMARK_COMPENSATORS"]

#: EA-FOB / DOB cutoff when the compensator names none [Hz] (the paper's 10 Hz).
DEFAULT_W_Q_HZ = 10.0
#: Compensators a benchmark accepts (those the virtual testbed runs in closed loop).
BENCHMARK_COMPENSATORS = COMPENSATOR_KINDS   # every kind the toolbox knows


def _number(text: str, what: str, form: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"{what}: {text!r} is not a number; expected {form}", name=what, value=text) from None
    if not math.isfinite(value):
        raise ParameterError(f"{what}: {text!r} must be finite; expected {form}", name=what, value=text)
    return value


def controller_label(c: Controller) -> str:
    """The controller's command-line spelling (``pd:5:0.1``; read back by :func:`parse_controller`), or a
    code controller's label (``c file.c``, ``python file.py:Class``: its file's name)."""
    return c.label if c.is_code else c.spelling()


def parse_compensators(text: str | Sequence[str]) -> tuple[Compensator, ...]:
    """Comma list of compensator kinds, each optionally ``KIND:W_Q_HZ`` -> compensators.

    Parameters
    ----------
    text : str or sequence of str
        E.g. ``"none,sfm,ea-fob"`` or ``["none", "ea-fob:20"]``.

    Returns
    -------
    tuple of Compensator
        In the given order, without repeats.
    """
    items = [text] if isinstance(text, str) else list(text)
    out: list[Compensator] = []
    for item in items:
        for word in str(item).split(","):
            word = word.strip()
            if not word:
                continue
            kind, _, cut = word.partition(":")
            if kind not in BENCHMARK_COMPENSATORS:
                raise ParameterError(f"--compensator {word!r}: kind must be one of {', '.join(BENCHMARK_COMPENSATORS)}",
                                     name="compensator", value=word)
            w_q = _number(cut, "--compensator", "KIND[:W_Q_HZ]") if cut else DEFAULT_W_Q_HZ
            try:
                comp = Compensator(kind=kind, w_q_hz=w_q) if kind not in ("none", "sfm") else Compensator(kind=kind)
            except ParameterError as exc:
                raise ParameterError(f"--compensator {word!r}: {exc}", name="compensator", value=word) from None
            if comp not in out:
                out.append(comp)
    if not out:
        raise ParameterError("--compensator: no compensator given (e.g. none,sfm,ea-fob)", name="compensator",
                             value=text)
    return tuple(out)


def compensator_label(c: Compensator) -> str:
    """``none``, ``sfm`` or ``KIND:W_Q_HZ`` for observers."""
    return c.kind if c.kind in ("none", "sfm") else f"{c.kind}:{c.w_q_hz:g}"


def parse_reference(text: str, *, duration_s: float = 1.0):
    """``step:AMP[:DURATION_S]`` or ``chirp:AMP:F0_HZ:F1_HZ[:DURATION_S]`` -> (reference, duration [s]).

    Parameters
    ----------
    text : str
        The reference; a chirp is logarithmic from ``F0_HZ`` to ``F1_HZ`` over the run.
    duration_s : float
        Run length of a step when the text gives none [s].

    Returns
    -------
    tuple
        ``(Step | Chirp, duration_s)``.
    """
    form = "step:AMP[:DURATION_S] or chirp:AMP:F0_HZ:F1_HZ[:DURATION_S] (N m, Hz, s)"
    parts = str(text).split(":")
    kind = parts[0].lower()
    nums = [_number(x, "--reference", form) for x in parts[1:]]
    try:
        if kind == "step" and len(nums) in (1, 2):
            dur = nums[1] if len(nums) == 2 else float(duration_s)
            ref = Step(amplitude=nums[0])
        elif kind == "chirp" and len(nums) in (3, 4):
            dur = nums[3] if len(nums) == 4 else 10.0
            if dur <= 0:
                raise ParameterError("duration must be > 0", name="duration_s", value=dur)
            ref = Chirp(amplitude=nums[0], f0_hz=nums[1], f1_hz=nums[2], duration_s=dur, method="logarithmic")
        else:
            raise ParameterError(f"--reference {text!r}: expected {form}", name="reference", value=text)
    except ParameterError as exc:
        if str(exc).startswith("--reference"):
            raise
        raise ParameterError(f"--reference {text!r}: {exc}", name="reference", value=text) from None
    if not (dur > 0 and math.isfinite(dur)):
        raise ParameterError(f"--reference {text!r}: duration must be > 0 [s]", name="reference", value=text)
    if ref.amplitude == 0.0:
        raise ParameterError(f"--reference {text!r}: amplitude must be non-zero", name="reference", value=text)
    return ref, float(dur)


def reference_label(ref: Any, duration_s: float) -> str:
    """The ``--reference`` text of a parsed reference."""
    if isinstance(ref, Chirp):
        return f"chirp:{ref.amplitude:g}:{ref.f0_hz:g}:{ref.f1_hz:g}:{duration_s:g}"
    return f"step:{ref.amplitude:g}:{duration_s:g}"


@dataclass(frozen=True, slots=True)
class Cell:
    """One benchmark cell: a controller and compensator in one environment under one reference."""

    controller: Controller
    compensator: Compensator
    environment_name: str
    environment: Environment
    reference: Any
    duration_s: float

    @property
    def labels(self) -> dict[str, str]:
        """``controller``, ``compensator``, ``environment``, ``reference`` labels (table columns)."""
        return {"controller": controller_label(self.controller), "compensator": compensator_label(self.compensator),
                "environment": self.environment_name, "reference": reference_label(self.reference, self.duration_s)}


@dataclass(frozen=True, slots=True, kw_only=True)
class BenchmarkSpec:
    """A whole benchmark.

    Attributes
    ----------
    controllers : tuple of Controller
        Force controllers under test, any kind with equations (each runs its own law: its
        discretisation, derivative filter and placement, saturation) or written as code
        (:class:`~forecast_design.controllers.PythonController`,
        :class:`~forecast_design.controllers.CController`: it runs as written).
    compensators : tuple of Compensator
        Friction compensators (part of the benchmarking system, paper Section 1).
    environments : tuple of (str, Environment)
        The environment set (names and environments).
    references : tuple of (reference, duration_s)
        Steps and chirps with their run lengths [s].
    repetitions : int
        Runs per cell [-] (>= 2 for the repeatability).
    seed : int
        Seed of the initial angles and the process noise.
    effects : tuple
        The virtual testbed's hardware (default: the Table 3 hardware, angle-dependent
        stiction and Stribeck curve, :data:`~forecast_design.reproduce.TABLE3_TRUTH`).
    viscous_drift : float
        Relative viscous-friction drift per repetition [-]
        (:class:`~forecast_design.simulation.scenario.Variability`).
    sfm_deadband : float
        Dead band of the SFM's sign() [rad/s].
    rate_hz : float
        Control rate [Hz].
    testbed : Testbed
        The SEA under test (default the paper's Table 1); the extended SFM of the ``sfm`` cells
        is identified on it.
    """

    controllers: tuple
    compensators: tuple
    environments: tuple
    references: tuple
    repetitions: int = 10
    seed: int = 0
    effects: tuple = field(default=TABLE3_TRUTH)
    viscous_drift: float = 0.0
    sfm_deadband: float = 0.05
    rate_hz: float = 2000.0
    testbed: Testbed = field(default_factory=Testbed.nominal)

    def __post_init__(self) -> None:
        if isinstance(self.repetitions, bool) or not isinstance(self.repetitions, int) or self.repetitions < 2:
            raise ParameterError(f"--repetitions must be an integer >= 2 (repeatability compares runs), got "
                                 f"{self.repetitions!r}", name="repetitions", value=self.repetitions)
        for name in ("controllers", "compensators", "environments", "references"):
            value = tuple(getattr(self, name))
            if not value:
                raise ParameterError(f"benchmark needs at least one of {name}", name=name, value=value)
            object.__setattr__(self, name, value)
        for c in self.controllers:
            if not isinstance(c, Controller):
                raise ParameterError(f"benchmark controllers must be Controller values, got {type(c).__name__}",
                                     name="controllers", value=c)
            if not c.has_equations and not c.is_code:
                raise c.no_equations("a simulated benchmark")
        spellings = [controller_label(c) for c in self.controllers]
        if len(set(spellings)) != len(spellings):
            raise ParameterError(f"controllers repeated: {', '.join(sorted({x for x in spellings if spellings.count(x) > 1}))}",
                                 name="controllers", value=spellings)
        names = [n for n, _ in self.environments]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ParameterError(f"environment names must be unique, repeated: {', '.join(dup)}",
                                 name="environments", value=dup)
        n_cells = len(self.controllers) * len(self.compensators) * len(self.environments) * len(self.references)
        check_limit(f"benchmark runs ({n_cells} cells x {self.repetitions} repetitions)", "runs",
                    n_cells * self.repetitions)

    def cells(self) -> list[Cell]:
        """Every (controller, compensator, environment, reference), in that nesting order."""
        return [Cell(c, k, name, env, ref, dur) for c in self.controllers for k in self.compensators
                for name, env in self.environments for ref, dur in self.references]

    def hardware(self) -> dict[str, Any]:
        """What every cell shares (part of each cell's key)."""
        return {"effects": effects_to_mappings(self.effects), "repetitions": self.repetitions, "seed": self.seed,
                "viscous_drift": self.viscous_drift, "sfm_deadband": self.sfm_deadband, "rate_hz": self.rate_hz,
                "testbed": self.testbed.to_mapping()}

    def cell_key(self, cell: Cell, sfm_params: dict | None) -> str:
        """Hash of every input of a cell: a stored result with this key is that cell's result."""
        doc = {"cell": cell.labels, "controller": cell.controller.to_mapping(),
               "compensator": cell.compensator.to_mapping(), "environment": cell.environment.to_mapping(),
               "reference": cell.reference.to_mapping(), "duration_s": cell.duration_s, "hardware": self.hardware(),
               "sfm": sfm_params if cell.compensator.kind == "sfm" else None, "version": 5,
               "code": cell.controller.content_digest() if cell.controller.is_code else None}
        text = json.dumps(doc, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:20]

    def to_mapping(self) -> dict[str, Any]:
        """JSON provenance."""
        return {"controllers": [controller_label(c) for c in self.controllers],
                "controller_models": {controller_label(c): c.model if c.is_code else "linear (its equations)"
                                      for c in self.controllers},
                "compensators": [compensator_label(c) for c in self.compensators],
                "environments": {n: e.to_mapping() for n, e in self.environments},
                "references": [reference_label(r, d) for r, d in self.references], **self.hardware()}
