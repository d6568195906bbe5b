"""Force controllers: one concept, a registry of kinds, and one way to resolve what a user gives.

Kinds (experiment format, section "Force controllers"): :class:`PD` (``pd``), :class:`PID`
(``pid``), :class:`TFController` (``tf``, ``C(s)``), :class:`DiscreteController`
(``discrete``, ``C(z)``) and :class:`OtherController` (``other``, a name only). Every layer
(loops, margins, tuning, simulation, export, firmware, benchmark, CLI) takes a
:class:`Controller` and asks it for its law; a ``control.TransferFunction`` or
``control.StateSpace`` is accepted anywhere a controller is (:func:`resolve_controller`).

Adding a kind: a module with a frozen dataclass deriving from
:class:`~forecast_design.controllers.base.LinearController` (or
:class:`~forecast_design.controllers.base.Controller`), and one :func:`register_controller`
line below; its command-line spelling is read by :func:`parse_controller` through the
class's ``keys`` and ``positional`` fields.

Command-line spelling: ``KIND:positional...[:key=value...]``::

    pd:P:D[:T_f]              pd:5:0.1, pd:5:0.1:0.0008:discretization=tustin:derivative_on=measurement
    pid:P:I:D[:T_f]           pid:6:20:0.05:0.002, pid:8:160:0:u_min=-2:u_max=2:anti_windup=clamping
    tf:NUM/DEN                tf:0.5,10/0.01,1 (comma-separated, descending powers of s)
    discrete:NUM/DEN          discrete:205,-200/1,0[:rate_hz=2000]
    other:NAME                other:my adaptive law
    FILE.py:Class             a controller written in Python (module:Class when importable)
    FILE.c                    a controller written in C (docs/controllers-as-code.md)
    FILE.toml                 a file with a [controller] table (an experiment TOML works too)
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any, Mapping

from ..errors import ExperimentFormatError, ParameterError
from .base import (
    ANTI_WINDUP,
    DERIVATIVE_ON,
    DISCRETIZATIONS,
    LAW_SOURCES,
    Controller,
    DiscreteLaw,
    IntegratorLaw,
    LawChannel,
    LinearController,
    format_number,
    parse_number,
)
from .code import (CController, CodeController, PythonController, code_controller_from_spelling, code_table_with_paths,
                   load_python_class, python_linearisation)
from .linear import DiscreteController, TFController
from .other import OtherController
from .pid import PD, PID

__all__ = [
    "Controller",
    "LinearController",
    "PD",
    "PID",
    "TFController",
    "DiscreteController",
    "OtherController",
    "CodeController",
    "PythonController",
    "CController",
    "load_python_class",
    "python_linearisation",
    "code_table_with_paths",
    "DiscreteLaw",
    "LawChannel",
    "IntegratorLaw",
    "CONTROLLERS",
    "CONTROLLER_KINDS",
    "DISCRETIZATIONS",
    "DERIVATIVE_ON",
    "ANTI_WINDUP",
    "LAW_SOURCES",
    "PAPER_PD",
    "register_controller",
    "controller_from_mapping",
    "parse_controller",
    "resolve_controller",
    "with_derivative_on",
    "controller_tf",
    "controller_law",
    "from_control",
    "format_number",
    "parse_number",
]

#: kind -> class, in the format's order.
CONTROLLERS: dict[str, type] = {}


def register_controller(cls: type) -> type:
    """Register a controller class under its ``kind`` (usable as a decorator).

    Parameters
    ----------
    cls : type
        A :class:`Controller` subclass with a class attribute ``kind``.

    Returns
    -------
    type
        ``cls``.
    """
    if not (isinstance(cls, type) and issubclass(cls, Controller)) or not isinstance(getattr(cls, "kind", None), str):
        raise ParameterError(f"register_controller needs a Controller subclass with a kind, got {cls!r}",
                             name="controller", value=cls)
    CONTROLLERS[cls.kind] = cls
    return cls


for _cls in (PD, PID, TFController, DiscreteController, OtherController, PythonController, CController):
    register_controller(_cls)

#: Every registered kind: the format's and code (``python``, ``c``: scenarios and the command line).
CONTROLLER_KINDS = tuple(CONTROLLERS)

#: The paper's force controller (Sections 6-7): P = 5, D = 0.1, as the format reads ``pd`` with
#: only P and D (unfiltered derivative on the error, backward Euler at the control rate).
PAPER_PD = PD(P=5.0, D=0.1)


def controller_from_mapping(mapping: Mapping[str, Any], *, source: str | None = None,
                            rate_hz: float | None = None, code: bool = True,
                            base: Path | None = None) -> Controller:
    """A ``[controller]`` table as a controller of its ``kind`` (default ``pd``).

    Parameters
    ----------
    mapping : Mapping
        The table.
    source : str, optional
        The file, for one-line errors naming it.
    rate_hz : float, optional
        The run's rate [Hz]: binds a ``discrete`` controller to it.
    code : bool
        Whether the code kinds (``python``, ``c``) are allowed: a scenario may run code; an
        experiment's TOML records it as ``other`` with a name.
    base : Path, optional
        Folder a code controller's relative ``source`` starts from (a scenario's).

    Returns
    -------
    Controller
        The controller.
    """
    where = f"{source}: " if source else ""
    if not isinstance(mapping, Mapping):
        raise ExperimentFormatError(f"{where}[controller] must be a table, got {type(mapping).__name__}",
                                    path=source, key="controller")
    kind = mapping.get("kind", "pd")
    allowed = [k for k, cls in CONTROLLERS.items() if code or not cls.is_code]
    if kind not in allowed:
        raise ExperimentFormatError(f"{where}[controller] kind must be one of {', '.join(allowed)}, "
                                    f"got {kind!r:.40}", path=source, key="controller.kind")
    cls = CONTROLLERS[kind]
    if getattr(cls, "is_code", False):
        mapping = code_table_with_paths(mapping, base)
    controller = cls.from_mapping(mapping, source=source)
    if rate_hz is not None and isinstance(controller, DiscreteController):
        controller = controller.at_rate(rate_hz)
    return controller


def from_control(sys: Any, name: str = "controller") -> Controller:
    """A python-control ``TransferFunction`` or ``StateSpace`` (SISO) as a controller.

    Parameters
    ----------
    sys : control.TransferFunction or control.StateSpace
        Continuous (kind ``tf``, Tustin) or discrete with a sample time (kind ``discrete`` at
        ``1/dt``).
    name : str
        How to name it in errors.

    Returns
    -------
    Controller
        :class:`TFController` or :class:`DiscreteController`.
    """
    from ..lti import RationalTF

    tf = RationalTF.from_control(sys)
    if tf.dt is None:
        try:
            return TFController(num=tf.num, den=tf.den)
        except ParameterError as exc:
            raise ParameterError(f"{name}: {exc}", name="controller", value=str(sys)) from None
    return DiscreteController(num=tf.num, den=tf.den, rate_hz=1.0 / tf.dt)


def _split_options(owner: str, parts: list[str]) -> tuple[list[str], dict[str, str]]:
    positional, options = [], {}
    for part in parts:
        if "=" in part:
            key, _, value = part.partition("=")
            key = key.strip()
            if key in options:
                raise ParameterError(f"{owner}: key '{key}' given twice", name="controller", value=key)
            options[key] = value.strip()
        elif options:
            raise ParameterError(f"{owner}: positional field {part!r} after key=value fields", name="controller",
                                 value=part)
        else:
            positional.append(part)
    return positional, options


def _forms() -> str:
    out = []
    for kind, cls in CONTROLLERS.items():
        if kind in ("tf", "discrete"):
            out.append(f"{kind}:NUM/DEN")
        elif kind == "other":
            out.append("other:NAME")
        elif cls.is_code:
            out.append("FILE.c" if kind == "c" else "FILE.py:Class, module:Class")
        else:
            need, optional = cls.positional
            out.append(":".join([kind, *need] + [f"[{k}]" for k in optional]))
    return ", ".join(out)


def parse_controller(text: str) -> Controller:
    """Parse a command-line controller spelling (module docstring) into a controller.

    ``KIND:positional...[:key=value...]``: the kind's class reads its own fields
    (:meth:`Controller.parse_fields`), so a registered kind is spelled like the built-in ones.

    Parameters
    ----------
    text : str
        ``pd:5:0.1``, ``pid:6:20:0.05:0.002``, ``tf:NUM/DEN``, ``discrete:NUM/DEN``,
        ``other:NAME``, with optional ``:key=value`` fields for the kind's other keys; code:
        ``FILE.py:Class``, ``module:Class``, ``FILE.c`` (a relative file from the working directory).

    Returns
    -------
    Controller
        The controller.

    Raises
    ------
    ParameterError
        One line naming the spelling, the field and the expected form.

    Examples
    --------
    >>> parse_controller("pid:6:20:0.05:0.002").label
    'PID P=6 I=20 D=0.05 T_f=0.002'
    >>> parse_controller("pd:5:0.1:discretization=tustin:T_f=0.001").spelling()
    'pd:5:0.1:0.001:discretization=tustin'
    """
    text = str(text).strip()
    kind, sep, rest = text.partition(":")
    kind = kind.lower()
    owner = f"controller {text!r:.80}"
    code = code_controller_from_spelling(text, kinds=tuple(CONTROLLERS))
    if code is not None:
        return code
    if not sep or kind not in CONTROLLERS:
        raise ParameterError(f"{owner}: expected one of {_forms()} or a TOML file with a [controller] table",
                             name="controller", value=text)
    cls = CONTROLLERS[kind]
    if cls.is_code:
        raise ParameterError(f"{owner}: code is spelled FILE.py:Class, module:Class or FILE.c (no {kind}: prefix)",
                             name="controller", value=text)
    if kind == "other":
        return cls(**cls.parse_fields([rest], {}, owner))
    positional, options = _split_options(owner, rest.split(":"))
    kwargs = cls.parse_fields(positional, options, owner)
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        raise ParameterError(f"{owner}: {exc}", name=exc.name or "controller", value=text) from None


def _from_file(path: Path) -> Controller:
    from ..experiment_io import read_toml_document

    doc = read_toml_document(path)
    table = doc.get("controller")
    if table is None:
        raise ExperimentFormatError(f"{path}: no [controller] table", path=str(path), key="controller")
    rate = doc.get("sampling", {}).get("rate_hz") if isinstance(doc.get("sampling"), Mapping) else None
    rate = rate if isinstance(rate, (int, float)) and not isinstance(rate, bool) and math.isfinite(rate) \
        and rate > 0 else None
    return controller_from_mapping(table, source=str(path), rate_hz=rate, base=path.parent)


def resolve_controller(spec: Any, *, default: Controller | None = None) -> Controller:
    """What a user gives as a controller, resolved once at the boundary.

    Parameters
    ----------
    spec : Controller, str, Mapping, control.TransferFunction, control.StateSpace or None
        A controller; a spelling (``pd:5:0.1``...), the path of a TOML file with a
        ``[controller]`` table, a C file (``FILE.c``) or a Python class (``FILE.py:Class``,
        ``module:Class``); a ``[controller]`` table; a python-control system.
    default : Controller, optional
        Returned for ``None`` (default: :data:`PAPER_PD`).

    Returns
    -------
    Controller
        The controller.

    Raises
    ------
    ParameterError
        For anything else, in one line.
    """
    if spec is None:
        return PAPER_PD if default is None else default
    if isinstance(spec, Controller):
        return spec
    if isinstance(spec, Mapping):
        return controller_from_mapping(spec)
    if isinstance(spec, (str, Path)):
        text = str(spec).strip()
        if text.lower().endswith(".toml") or (isinstance(spec, Path) and text.lower().endswith(".toml")):
            return _from_file(Path(text))
        return parse_controller(text)
    module = type(spec).__module__ or ""
    if module.startswith("control"):
        return from_control(spec)
    raise ParameterError(f"controller must be a Controller, a spelling like pd:5:0.1, a TOML file, a [controller] "
                         f"table or a python-control system, got {type(spec).__name__} {spec!r:.60}",
                         name="controller", value=spec)


def with_derivative_on(controller: Controller, derivative_on: str) -> Controller:
    """A PD/PID with its derivative on ``derivative_on`` (other kinds unchanged: they have no such choice).

    Parameters
    ----------
    controller : Controller
        Any controller.
    derivative_on : str
        ``error`` or ``measurement`` (:data:`DERIVATIVE_ON`).

    Returns
    -------
    Controller
        The controller with the placement changed (a PD/PID), or itself.
    """
    import dataclasses

    if derivative_on not in DERIVATIVE_ON:
        raise ParameterError(f"derivative_on must be one of {', '.join(DERIVATIVE_ON)}, got {derivative_on!r}",
                             name="derivative_on", value=derivative_on)
    if isinstance(controller, PD):
        return dataclasses.replace(controller, derivative_on=derivative_on)
    return controller


@functools.lru_cache(maxsize=256)
def controller_tf(controller: Controller):
    """``controller.feedback_tf()``, computed once per controller value (the loops ask for it per plant).

    Parameters
    ----------
    controller : Controller
        A hashable controller value.

    Returns
    -------
    RationalTF
        Its continuous ``C(s)``.
    """
    return controller.feedback_tf()


@functools.lru_cache(maxsize=256)
def controller_law(controller: Controller, rate_hz: float) -> DiscreteLaw:
    """``controller.discrete_law(rate_hz)``, computed once per controller and rate.

    Parameters
    ----------
    controller : Controller
        A hashable controller value.
    rate_hz : float
        Control rate [Hz].

    Returns
    -------
    DiscreteLaw
        Its difference equation at the rate.
    """
    return controller.discrete_law(rate_hz)
