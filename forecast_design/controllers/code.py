"""Force controllers written as code: a Python class or a C file (the format's kind ``other``).

A lab's controller need not be a linear filter (impedance and admittance schemes with
switching, adaptive or gain-scheduled laws, energy tanks, learned controllers). Written as
code, it runs where the linear kinds run: the simulator calls it once per control period with
the compensator, the delays, the saturation and the plant around it unchanged; the benchmark,
Monte-Carlo repetitions and the Dask executor take it like any controller; a C controller also
runs in software in the loop (compiled with the host compiler, called through ctypes) and on the
board (linked into the firmware, ``pil`` on qemu).

Python interface (any class, instantiated with no arguments)::

    class MyController:
        def reset(self, rate_hz, testbed, environment): ...      # before each run; rate [Hz]
        def step(self, t, tau_r, tau_s, theta, q): return u     # once per period; u [N m]
        def transfer_function(self): ...                        # optional: a linearisation
                                                                # (control.TransferFunction / StateSpace)

C interface (one ``.c`` file, state in static variables, no heap, nothing of libc beyond ``math.h``)::

    void  fd_user_init(float rate_hz);
    float fd_user_step(float tau_r, float tau_s, float theta, float q);   /* u [N m] */

These classes are the controllers' *values* (where the code is); loading and running them is
:mod:`forecast_design.simulation.code`'s. A log records them as the format's ``other`` kind with
a ``name`` that says where the code was (``python my_ctl.py:Admittance``, ``c my_ctl.c``).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Mapping

from ..errors import ParameterError
from ..lti import RationalTF
from .base import Controller, DiscreteLaw

__all__ = ["CodeController", "PythonController", "CController", "code_controller_from_spelling", "load_python_class",
           "python_linearisation", "code_table_with_paths", "C_CONTROLLER_FLAGS", "C_CONTROLLER_INTERFACE"]

#: Flags a C controller is compiled with, on the host (software in the loop) and for the board
#: (with the Cortex-M4F's): the export's C99 without -Werror/-pedantic (the user's warnings do not
#: stop the build) and no fused multiply-add, so host and board round alike. Every build puts the
#: interface's prototypes first (``-include``), so a definition with other types does not compile.
C_CONTROLLER_FLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-ffp-contract=off")
#: The C interface, as error messages state it.
C_CONTROLLER_INTERFACE = ("void fd_user_init(float rate_hz); float fd_user_step(float tau_r, float tau_s, "
                          "float theta, float q)")

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_MODULE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


class CodeController(Controller):
    """A controller given as code (module docstring): no equations in the format, it runs as written."""

    __slots__ = ()
    is_code: ClassVar[bool] = True

    @property
    def name(self) -> str:   # pragma: no cover - each kind defines it
        raise NotImplementedError

    def to_mapping(self) -> dict[str, Any]:
        """The format's ``[controller]`` table of a run made with it: ``kind = "other"`` and a name."""
        return {"kind": "other", "name": self.name}

    def scenario_mapping(self) -> dict[str, Any]:
        """The scenario's ``[controller]`` table that runs it again (a path as given)."""
        return {"kind": self.kind, **{k: getattr(self, k) for k in self.keys}}

    def identity(self) -> str:   # pragma: no cover - each kind defines it
        """What a program and the firmware's upload blob record of the code (:class:`~forecast_design.program.ControllerProgram`)."""
        raise NotImplementedError

    def no_equations(self, what: str = "this analysis") -> ParameterError:
        """The one-line refusal for a tool that needs a linear model."""
        return ParameterError(f"controller {self.spelling()} is code with no linear model: {what} needs one "
                              "(a Python controller may define transfer_function())", name="controller",
                              value=self.spelling())

    @property
    def label(self) -> str:
        """``python FILE-NAME:Class`` / ``c FILE-NAME`` (the file's name without its folder)."""
        return self.name

    def content_digest(self) -> str:   # pragma: no cover - each kind defines it
        """SHA-256 of the code [hex]: a benchmark cell's result is reused only for the same code."""
        raise NotImplementedError

    @property
    def model(self) -> str:
        """What an analysis can use of it: its linearisation or nothing (said in outputs)."""
        return ("code, analysed through its linearisation transfer_function()" if self.has_equations
                else "code without a linear model: no margins")

    def feedback_tf(self) -> RationalTF:
        """Refused: code has no C(s) (a Python class may provide a linearisation)."""
        raise self.no_equations("the loop analysis")

    def reference_tf(self) -> RationalTF:
        """Refused: code has no C_r(s)."""
        raise self.no_equations("the loop analysis")

    def discrete_law(self, rate_hz: float) -> DiscreteLaw:
        """Refused: code runs as written, not as a difference equation the toolbox builds."""
        raise self.no_equations("a discrete law")


@dataclass(frozen=True, slots=True, kw_only=True)
class PythonController(CodeController):
    """A controller written in Python: ``source`` a ``.py`` file or an importable module, ``class_name`` its class.

    Parameters
    ----------
    source : str
        Path of a ``.py`` file (made absolute by :func:`code_controller_from_spelling`, so worker
        processes find it), or a dotted module name importable where it runs (on every Dask worker).
    class_name : str
        The class (instantiated with no arguments; module docstring for its methods).

    Examples
    --------
    >>> PythonController(source="mylab.control", class_name="Admittance").spelling()
    'mylab.control:Admittance'
    """

    kind: ClassVar[str] = "python"
    keys: ClassVar[tuple[str, ...]] = ("source", "class_name")
    required: ClassVar[tuple[str, ...]] = ("source", "class_name")

    source: str
    class_name: str

    def __post_init__(self) -> None:
        if not isinstance(self.source, str) or not self.source.strip():
            raise ParameterError(f"[controller] python: source must be a .py file or a module name, got "
                                 f"{self.source!r:.60}", name="source", value=self.source)
        if not self.source.endswith(".py") and not _MODULE.match(self.source):
            raise ParameterError(f"[controller] python: source {self.source!r:.60} is neither a .py file nor a "
                                 "module name", name="source", value=self.source)
        if not isinstance(self.class_name, str) or not _IDENT.match(self.class_name):
            raise ParameterError(f"[controller] python: class_name must be a Python identifier, got "
                                 f"{self.class_name!r:.60}", name="class_name", value=self.class_name)

    @property
    def name(self) -> str:
        """``python SOURCE:Class``."""
        return f"python {self.source}:{self.class_name}"

    @property
    def has_equations(self) -> bool:   # type: ignore[override]
        """True when the class provides a linearisation (``transfer_function()``)."""
        return python_linearisation(self) is not None

    def _linear(self) -> RationalTF:
        tf = python_linearisation(self)
        if tf is None:
            raise self.no_equations("the loop analysis")
        return tf

    @property
    def is_continuous(self) -> bool:
        """True unless its linearisation is discrete."""
        try:
            return self._linear().dt is None
        except ParameterError:
            return True

    def feedback_tf(self) -> RationalTF:
        """The linearisation the class provides, ``transfer_function()`` (continuous) [N m/N m]."""
        tf = self._linear()
        if tf.dt is not None:
            raise ParameterError(f"controller {self.spelling()}: its transfer_function() is discrete (dt = "
                                 f"{tf.dt:g} s): analyse the sampled loop (--sampled)", name="controller",
                                 value=self.spelling())
        return tf.named("C_F")

    def reference_tf(self) -> RationalTF:
        """The linearisation again (the class's own reference path is not known) [N m/N m]."""
        return self.feedback_tf().named("C_r")

    def discrete_law(self, rate_hz: float) -> DiscreteLaw:
        """For the sampled *analysis* only: the linearisation, Tustin-discretised (or as given in z)."""
        from ..discrete import DiscreteTF, discretize
        from .base import LawChannel

        tf = self._linear()
        if tf.dt is None:
            law = discretize(tf.named("C_F"), rate_hz, "tustin")
        else:
            if abs(1.0 / tf.dt - rate_hz) > 1e-9 * rate_hz:
                raise ParameterError(f"controller {self.spelling()}: its linearisation is at {1.0 / tf.dt:g} Hz, "
                                     f"asked at {rate_hz:g} Hz", name="rate_hz", value=rate_hz)
            law = DiscreteTF.from_z(tf.num, tf.den, rate_hz, "C_F")
        return DiscreteLaw(float(rate_hz), (LawChannel("error", law, "lin"),), None, float("-inf"), float("inf"),
                           self)

    def spelling(self) -> str:
        """``SOURCE:Class``."""
        return f"{self.source}:{self.class_name}"

    def identity(self) -> str:
        """``python MODULE-OR-FILE-NAME:Class`` (runs in Python only: never on the board)."""
        return f"python {Path(self.source).name if self.source.endswith('.py') else self.source}:{self.class_name}"

    @property
    def label(self) -> str:
        """``python FILE-NAME:Class`` or ``python module:Class``."""
        return self.identity()

    def content_digest(self) -> str:
        """SHA-256 of the ``.py`` file (or the module's file) [hex]."""
        import hashlib

        path = self.source
        if not path.endswith(".py"):
            spec = importlib.util.find_spec(self.source)
            path = spec.origin if spec is not None and spec.origin else ""
        from ..fileio import note_input

        if path:
            note_input(path)      # an output of this command must not replace it
        try:
            return hashlib.sha256(Path(path).read_bytes()).hexdigest()
        except OSError:
            return ""


@dataclass(frozen=True, slots=True, kw_only=True)
class CController(CodeController):
    """A controller written in C (module docstring): ``source`` the ``.c`` file.

    Parameters
    ----------
    source : str
        Path of the ``.c`` file (made absolute by :func:`code_controller_from_spelling`).

    Examples
    --------
    >>> CController(source="/lab/admittance.c").name
    'c /lab/admittance.c'
    """

    kind: ClassVar[str] = "c"
    keys: ClassVar[tuple[str, ...]] = ("source",)
    required: ClassVar[tuple[str, ...]] = ("source",)
    has_equations: ClassVar[bool] = False

    source: str

    def __post_init__(self) -> None:
        if not isinstance(self.source, str) or not self.source.endswith(".c"):
            raise ParameterError(f"[controller] c: source must be a .c file, got {self.source!r:.60}",
                                 name="source", value=self.source)

    @property
    def name(self) -> str:
        """``c SOURCE``."""
        return f"c {self.source}"

    def spelling(self) -> str:
        """The file."""
        return self.source

    def read_source(self) -> bytes:
        """The file's bytes (a one-line error when it cannot be read)."""
        from ..fileio import note_input

        note_input(self.source)   # an output of this command must not replace it
        try:
            return Path(self.source).read_bytes()
        except OSError as exc:
            raise ParameterError(f"controller {self.source}: cannot read it: {exc.strerror or exc}",
                                 name="controller", value=self.source) from None

    def identity(self) -> str:
        """``c sha256:`` and the first 16 hex digits of the file's SHA-256: the firmware accepts the blob of this code only."""
        return "c sha256:" + self.content_digest()[:16]

    def content_digest(self) -> str:
        """SHA-256 of the file [hex]."""
        import hashlib

        return hashlib.sha256(self.read_source()).hexdigest()

    @property
    def label(self) -> str:
        """``c FILE-NAME``."""
        return f"c {Path(self.source).name}"


@functools.lru_cache(maxsize=64)
def load_python_class(controller: PythonController) -> type:
    """The class a :class:`PythonController` names, imported once per process.

    Parameters
    ----------
    controller : PythonController
        Where the class is.

    Returns
    -------
    type
        The class, checked to have callable ``reset`` and ``step``.

    Raises
    ------
    ParameterError
        A file that does not import (its error in one line), a missing module or class, a class
        without ``reset``/``step``.
    """
    src = controller.source
    try:
        if src.endswith(".py"):
            import hashlib

            name = f"_forecast_user_{hashlib.sha1(src.encode()).hexdigest()[:12]}"
            spec = importlib.util.spec_from_file_location(name, src)
            if spec is None or spec.loader is None:
                raise ImportError(f"cannot load {src}")
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module          # pickling the controller's objects finds the module
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(src)
    except Exception as exc:   # noqa: BLE001 - any error of the user's code is one line naming it
        where = f" (line {exc.lineno})" if isinstance(exc, SyntaxError) and exc.lineno else ""
        raise ParameterError(f"controller {controller.spelling()}: importing {src} failed{where}: "
                             f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
                             name="controller", value=src) from None
    cls = getattr(module, controller.class_name, None)
    if not isinstance(cls, type):
        raise ParameterError(f"controller {controller.spelling()}: {src} has no class {controller.class_name}",
                             name="controller", value=controller.class_name)
    for method in ("reset", "step"):
        if not callable(getattr(cls, method, None)):
            raise ParameterError(f"controller {controller.spelling()}: class {controller.class_name} has no "
                                 f"{method}() (the interface: reset(rate_hz, testbed, environment), "
                                 "step(t, tau_r, tau_s, theta, q) -> u)", name="controller", value=method)
    return cls


@functools.lru_cache(maxsize=64)
def python_linearisation(controller: PythonController) -> RationalTF | None:
    """The linearisation a Python controller's class provides (``transfer_function()``), or None.

    Parameters
    ----------
    controller : PythonController
        The controller.

    Returns
    -------
    RationalTF or None
        Its C(s) (or C(z) with ``dt``) [N m/N m].
    """
    cls = load_python_class(controller)
    make = getattr(cls, "transfer_function", None)
    if make is None:
        return None
    try:
        tf = make(cls())
        out = tf if isinstance(tf, RationalTF) else RationalTF.from_control(tf, name="C_F")
    except ParameterError as exc:
        raise ParameterError(f"controller {controller.spelling()}: transfer_function(): {exc}", name="controller",
                             value=controller.class_name) from None
    except Exception as exc:   # noqa: BLE001 - the user's code
        raise ParameterError(f"controller {controller.spelling()}: transfer_function() failed: "
                             f"{type(exc).__name__}: {exc}", name="controller", value=controller.class_name) from None
    return out


def code_controller_from_spelling(text: str, *, base: Path | None = None,
                                  kinds: tuple[str, ...] = ()) -> CodeController | None:
    """A code controller from a command-line spelling, or None when ``text`` is not one.

    ``FILE.c`` is a C controller; ``FILE.py:Class`` and ``module.path:Class`` are Python ones.
    A relative file is taken relative to ``base`` (default: the working directory) and made
    absolute; a missing file is a one-line error.

    Parameters
    ----------
    text : str
        The spelling.
    base : Path, optional
        Folder relative paths start from (a scenario's).
    kinds : tuple of str
        Registered kinds: ``KIND:...`` is never read as ``module:Class``.

    Returns
    -------
    CodeController or None
        The controller.
    """
    t = str(text).strip()
    root = Path.cwd() if base is None else Path(base)

    def located(path: str) -> str:
        p = Path(path).expanduser()
        p = p if p.is_absolute() else root / p
        if not p.is_file():
            raise ParameterError(f"controller {text!r:.80}: file {str(p)!r} not found", name="controller", value=t)
        return str(p.resolve())

    if t.endswith(".c"):
        return CController(source=located(t))
    head, sep, cls = t.rpartition(":")
    if sep and head.endswith(".py") and _IDENT.match(cls):
        return PythonController(source=located(head), class_name=cls)
    if sep and _MODULE.match(head) and _IDENT.match(cls) and head.lower() not in kinds and not head.endswith(".py"):
        return PythonController(source=head, class_name=cls)
    return None


def code_table_with_paths(mapping: Mapping[str, Any], base: Path | None) -> Mapping[str, Any]:
    """A scenario's code-controller table with its file made absolute (relative to ``base``, the scenario's folder).

    Parameters
    ----------
    mapping : Mapping
        The ``[controller]`` table.
    base : Path or None
        The folder relative paths start from.

    Returns
    -------
    Mapping
        The table, ``source`` absolute when it names a file.
    """
    out = dict(mapping)
    src = out.get("source")
    if isinstance(src, str) and (src.endswith(".py") or src.endswith(".c")):
        p = Path(src).expanduser()
        p = p if p.is_absolute() or base is None else Path(base) / p
        out["source"] = str(p.resolve()) if p.exists() else str(p)
    return out
