"""C99 export of a discretised force controller and compensator for the Nucleo F446RE (Cortex-M4F).

The controller is reduced to a :class:`ControllerProgram`: a sum of
channels, each a cascade of second-order sections (the recursion of
:mod:`forecast_design.discrete`) on one input signal, scaled, plus
an optional sign term (the SFM's Coulomb part). The C code, the Python
reference (:meth:`ControllerProgram.make_step`), the emulator and the board
upload all run this one description.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import string
import struct
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .. import __version__
from ..errors import ExportError, ParameterError
from ..fileio import atomic_write_set
from ..environments import resolve_environments, resolve_testbed
from ..params import Compensator, Design, PDController, parse_controller, require_design, resolve_design
from ..discrete import METHODS, DiscreteFilter

__all__ = [
    "SOURCES",
    "c_float_literal",
    "Channel",
    "SfmBlock",
    "ControllerProgram",
    "ProgramStep",
    "ExportResult",
    "build_program",
    "emit_c",
    "export_controller",
    "parse_controller",
    "resolve_design",
]

#: Signals a channel can filter. ``error`` is tau_r - tau_s; ``tau_m_prev`` is the command
#: applied over the previous period (the one-sample delay that breaks the algebraic loop).
SOURCES = ("error", "tau_s", "theta", "tau_m_prev")

_BLOB_MAGIC = b"FDC2"


def _sfm_formula():
    """The simulator's SFM formula as plain Python (so that float32 inputs stay float32)."""
    from ..simulation.controllers import sfm_eval

    return getattr(sfm_eval, "py_func", sfm_eval)


@dataclass(frozen=True, slots=True)
class Channel:
    """One additive term of the motor command.

    The term is ``gain * y`` where ``y`` is ``source`` passed through the
    second-order sections ``sos``.

    Parameters
    ----------
    name : str
        C identifier fragment, e.g. ``"pd"`` or ``"obs_tau_s"``.
    source : str
        One of :data:`SOURCES`.
    sos : ndarray, shape (n_sections, 6)
        Delta sections, rows ``[b0, b1, b2, 1, a1, a2]`` in ``rho = z - 1`` (float64 design values;
        :mod:`forecast_design.discrete`).
    group : str
        ``"u"`` (controller output) or ``"hat"`` (friction estimate); the
        command is ``sat(sum(u) + sum(hat))``, each sum in channel order.
    gain : float
        Linear weight of the filter output [-].
    """

    name: str
    source: str
    sos: np.ndarray
    group: str = "u"
    gain: float = 1.0

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ParameterError(f"channel {self.name}: source must be one of {', '.join(SOURCES)}, "
                                 f"got {self.source!r}", name="source", value=self.source)
        if not self.name.isidentifier():
            raise ParameterError(f"channel name must be a C identifier, got {self.name!r}",
                                 name="name", value=self.name)
        sos = np.array(np.atleast_2d(np.asarray(self.sos, dtype=float)))
        if sos.ndim != 2 or sos.shape[1] != 6 or sos.shape[0] < 1 or not np.all(sos[:, 3] == 1.0):
            raise ParameterError(f"channel {self.name}: sos must have shape (n >= 1, 6) with a0 = 1",
                                 name="sos", value=self.sos)
        if not np.all(np.isfinite(sos)):
            raise ParameterError(f"channel {self.name}: sos has non-finite coefficients",
                                 name="sos", value=self.sos)
        if self.group not in ("u", "hat"):
            raise ParameterError(f"channel {self.name}: group must be 'u' or 'hat', got {self.group!r}",
                                 name="group", value=self.group)
        sos.flags.writeable = False
        object.__setattr__(self, "sos", sos)
        object.__setattr__(self, "gain", float(self.gain))


@dataclass(frozen=True, slots=True)
class SfmBlock:
    """The static friction model feed-forward, evaluated as the simulator's ``sfm_eval``.

    Parameters
    ----------
    velocity_sos : ndarray, shape (n, 6)
        Filtered derivative of theta giving v_hat [rad/s].
    coef : tuple of float
        ``(viscous [N m s/rad], coulomb [N m], offset [N m], deadband [rad/s], angle_offset [rad])``.
    harm : ndarray, shape (4, n_h)
        Rows sin, cos, coulomb_sin, coulomb_cos of harmonics 1..n_h [N m].
    """

    velocity_sos: np.ndarray
    coef: tuple[float, ...]
    harm: np.ndarray

    def __post_init__(self) -> None:
        sos = np.array(np.atleast_2d(np.asarray(self.velocity_sos, dtype=float)))
        harm = np.array(np.atleast_2d(np.asarray(self.harm, dtype=float)))
        if sos.shape[1] != 6 or harm.shape[0] != 4 or len(self.coef) != 5:
            raise ParameterError("sfm block: velocity_sos (n, 6), coef (5,), harm (4, n) expected",
                                 name="sfm", value=None)
        sos.flags.writeable = False
        harm.flags.writeable = False
        object.__setattr__(self, "velocity_sos", sos)
        object.__setattr__(self, "harm", harm)
        object.__setattr__(self, "coef", tuple(float(c) for c in self.coef))

    @property
    def has_harmonics(self) -> bool:
        """True when any angle harmonic is non-zero (the C then needs sinf/cosf)."""
        return bool(np.any(self.harm != 0.0))


class ProgramStep:
    """A running instance of a :class:`ControllerProgram` (float64 by default).

    Parameters
    ----------
    program : ControllerProgram
        What to run.
    dtype : numpy dtype
        ``np.float64`` (the design implementation) or ``np.float32`` (what
        the C code computes, bit for bit for the linear parts when the C is
        built without FMA contraction).
    """

    def __init__(self, program: "ControllerProgram", dtype: Any = np.float64) -> None:
        self.program = program
        self._f = np.dtype(dtype).type
        self._filters = [DiscreteFilter(ch.sos, dtype=dtype) for ch in program.channels]
        self._gains = [self._f(ch.gain) for ch in program.channels]
        sfm = program.sfm
        self._velocity = None if sfm is None else DiscreteFilter(sfm.velocity_sos, dtype=dtype)
        self._sfm_coef = None if sfm is None else np.asarray(sfm.coef, dtype=dtype)
        self._sfm_harm = None if sfm is None else np.asarray(sfm.harm, dtype=dtype)
        self._sfm_eval = None if sfm is None else _sfm_formula()
        self.tau_m_prev = 0.0
        self.u = 0.0    # the last step's controller output [N m] (fd_state.u)
        self.hat = 0.0  # the last step's friction estimate [N m] (fd_state.hat)

    def reset(self) -> None:
        """Back to rest, as ``fd_init``."""
        for f in self._filters:
            f.reset()
        if self._velocity is not None:
            self._velocity.reset()
        self.tau_m_prev = 0.0
        self.u = self.hat = 0.0

    def _sfm(self, theta):
        # the simulator's own SFM formula, run un-compiled on this program's dtype
        v = self._f(self._velocity.step(theta))
        return self._f(self._sfm_eval(self._sfm_coef, self._sfm_harm, self._f(theta), v))

    def step(self, tau_r: float, tau_s: float, theta: float) -> float:
        """One period, as ``fd_step``: measurements in, motor torque command out [N m].

        Parameters
        ----------
        tau_r : float
            Force reference [N m].
        tau_s : float
            Measured spring torque [N m].
        theta : float
            Motor angle [rad].

        Returns
        -------
        float
            Motor torque command for the next period [N m].
        """
        f = self._f
        tau_r, tau_s, theta = f(tau_r), f(tau_s), f(theta)
        inputs = {"error": f(tau_r - tau_s), "tau_s": tau_s, "theta": theta, "tau_m_prev": f(self.tau_m_prev)}
        sums = {"u": f(0.0), "hat": f(0.0)}
        for ch, filt, g in zip(self.program.channels, self._filters, self._gains):
            y = f(filt.step(inputs[ch.source]))
            sums[ch.group] = f(sums[ch.group] + (y if ch.gain == 1.0 else f(g * y)))
        if self._velocity is not None:
            sums["hat"] = f(sums["hat"] + self._sfm(theta))
        tau_m = f(sums["u"] + sums["hat"])
        self.u, self.hat = float(sums["u"]), float(sums["hat"])
        lim = self.program.tau_max
        if math.isfinite(lim):
            tau_m = f(min(max(tau_m, f(-lim)), f(lim)))
        self.tau_m_prev = float(tau_m)
        return float(tau_m)

    def run(self, tau_r: np.ndarray, tau_s: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Step through whole input arrays (shape (n,)) from the current state; return tau_m [N m]."""
        return np.array([self.step(a, b, c) for a, b, c in zip(tau_r, tau_s, theta)])


@dataclass(frozen=True, slots=True)
class ControllerProgram:
    """A discretised force controller plus compensator, ready for C or the emulator.

    Parameters
    ----------
    rate_hz : float
        Sample rate [Hz].
    method : str
        Discretisation method (see :data:`forecast_design.discrete.METHODS`).
    channels : tuple of Channel
        Additive terms; the command is their sum.
    prewarp_hz : float or None
        Tustin prewarp frequency [Hz].
    info : tuple of (str, str)
        Provenance lines for the generated comment block (design parameters...).
    sfm : SfmBlock or None
        Static friction model feed-forward (compensator ``sfm``).
    tau_max : float
        Command saturation |tau_m| <= tau_max [N m]; ``inf`` for none.
    """

    rate_hz: float
    method: str
    channels: tuple[Channel, ...]
    prewarp_hz: float | None = None
    info: tuple[tuple[str, str], ...] = ()
    sfm: SfmBlock | None = None
    tau_max: float = math.inf

    @property
    def n_sections(self) -> int:
        """Second-order sections over all filters [-]."""
        n = sum(ch.sos.shape[0] for ch in self.channels)
        return n + (0 if self.sfm is None else self.sfm.velocity_sos.shape[0])

    def make_step(self, dtype: Any = np.float64) -> ProgramStep:
        """A fresh running instance (see :class:`ProgramStep`)."""
        return ProgramStep(self, dtype)

    def to_bytes(self) -> bytes:
        """The UPLOAD payload: float32 coefficients and layout (byte map in docs/protocol.md).

        Returns
        -------
        bytes
            ``b"FDC2"``, float32 rate [Hz], float32 tau_max [N m], uint8 channel
            count; per channel uint8 source, uint8 group, uint8 sections,
            float32 gain, 5 float32 per section (b0 b1 b2 a1 a2); uint8 SFM
            flag and, if set, uint8 sections, the sections, 5 float32 coef,
            uint8 harmonics, 4 x n float32 harmonics (row-major).
        """
        out = bytearray(_BLOB_MAGIC)
        out += struct.pack("<ffB", self.rate_hz, self.tau_max, len(self.channels))

        def sections(sos: np.ndarray) -> bytes:
            return b"".join(struct.pack("<5f", r[0], r[1], r[2], r[4], r[5]) for r in sos)

        for ch in self.channels:
            out += struct.pack("<BBBf", SOURCES.index(ch.source), ("u", "hat").index(ch.group),
                               ch.sos.shape[0], ch.gain)
            out += sections(ch.sos)
        if self.sfm is None:
            out += b"\x00"
        else:
            out += struct.pack("<BB", 1, self.sfm.velocity_sos.shape[0]) + sections(self.sfm.velocity_sos)
            out += struct.pack("<5fB", *self.sfm.coef, self.sfm.harm.shape[1])
            out += np.asarray(self.sfm.harm, dtype="<f4").tobytes()
        return bytes(out)

    @classmethod
    def from_bytes(cls, blob: bytes, *, method: str = "uploaded") -> "ControllerProgram":
        """Inverse of :meth:`to_bytes` (coefficients come back float32-rounded).

        Parameters
        ----------
        blob : bytes
            An UPLOAD payload.
        method : str
            Label recorded as the discretisation method.

        Returns
        -------
        ControllerProgram
            The program the blob describes.

        Raises
        ------
        ParameterError
            If the blob is malformed (wrong magic, truncated, unknown source).
        """
        def bad(why: str) -> ParameterError:
            return ParameterError(f"controller upload blob: {why}", name="blob", value=len(blob))

        blob = bytes(blob)
        if blob[:4] != _BLOB_MAGIC:
            raise bad(f"magic must be {_BLOB_MAGIC!r}, got {blob[:4]!r}")
        pos = 4

        def take(fmt: str) -> tuple:
            nonlocal pos
            vals = struct.unpack_from(fmt, blob, pos)
            pos += struct.calcsize(fmt)
            return vals

        def sections(n: int) -> np.ndarray:
            rows = np.array(take(f"<{5 * n}f"), dtype=float).reshape(n, 5)
            return np.column_stack([rows[:, :3], np.ones(n), rows[:, 3:]])

        try:
            rate_hz, tau_max, n = take("<ffB")
            channels = []
            for i in range(n):
                src, grp, ns, gain = take("<BBBf")
                if src >= len(SOURCES) or grp > 1 or ns == 0:
                    raise bad(f"channel {i}: source {src}, group {grp}, {ns} sections invalid")
                channels.append(Channel(f"ch{i}", SOURCES[src], sections(ns), ("u", "hat")[grp], gain))
            (has_sfm,) = take("<B")
            sfm = None
            if has_sfm:
                (ns,) = take("<B")
                vsos = sections(ns)
                *coef, nh = take("<5fB")
                harm = np.array(take(f"<{4 * nh}f"), dtype=float).reshape(4, nh)
                sfm = SfmBlock(vsos, tuple(coef), harm)
        except struct.error:
            raise bad("truncated") from None
        if pos != len(blob):
            raise bad(f"{len(blob) - pos} trailing bytes")
        if not (rate_hz > 0.0 and math.isfinite(rate_hz)) or not tau_max > 0.0:
            raise bad(f"rate_hz {rate_hz} and tau_max {tau_max} must be > 0")
        return cls(float(rate_hz), method, tuple(channels), sfm=sfm, tau_max=float(tau_max))


@dataclass(frozen=True, slots=True)
class ExportResult:
    """What :func:`export_controller` wrote.

    Parameters
    ----------
    header : pathlib.Path
        ``fd_controller.h``.
    source : pathlib.Path
        ``fd_controller.c``.
    program : ControllerProgram
        The discretised controller (coefficients in float64; the C holds them in float32).
    design : Design
        Testbed, environment, controller and compensator exported.
    digest : str
        SHA-256 of the emitted header and source [hex].
    """

    header: Path
    source: Path
    program: ControllerProgram
    design: Design
    digest: str

    def to_mapping(self) -> dict[str, Any]:
        """Summary for ``--json``: files, rate, method, sections, coefficient count, digest."""
        return {
            "header": str(self.header), "source": str(self.source),
            "rate_hz": self.program.rate_hz, "method": self.program.method,
            "prewarp_hz": self.program.prewarp_hz,
            "channels": [{"name": ch.name, "source": ch.source, "sections": int(ch.sos.shape[0]),
                          "group": ch.group, "gain": ch.gain} for ch in self.program.channels],
            "sfm": self.program.sfm is not None,
            # no saturation is null, not Infinity (strict JSON); "tau_max" kept one release beside tau_max_N_m
            "tau_max": self.program.tau_max if math.isfinite(self.program.tau_max) else None,
            "tau_max_N_m": self.program.tau_max if math.isfinite(self.program.tau_max) else None,
            "n_sections": self.program.n_sections,
            "controller": None if self.design.controller is None else self.design.controller.to_mapping(),
            "compensator": None if self.design.compensator is None else self.design.compensator.to_mapping(),
            "sha256": self.digest,
        }





def build_program(design: Design, *, rate_hz: float = 2000.0, method: str = "tustin",
                  sfm_params: Mapping[str, float] | None = None,
                  tau_max: float = math.inf) -> ControllerProgram:
    """Discretise the design's controller and compensator exactly as the simulator does.

    Uses the simulator's own objects (:class:`~forecast_design.simulation.controllers.DiscretePD`,
    :class:`~forecast_design.simulation.controllers.ObserverCompensator`,
    :class:`~forecast_design.simulation.controllers.SfmCompensator`), so the
    coefficients are the very ones the simulated closed loop runs.

    Parameters
    ----------
    design : Design
        Needs ``controller``; ``compensator`` ``None`` means ``none``. The
        observers believe ``design`` (its testbed and environment).
    rate_hz : float
        Sample rate [Hz].
    method : str
        Discretisation method of the controller and observer filters (default ``tustin``).
    sfm_params : Mapping[str, float], optional
        Kept for one release: prefer ``Compensator(kind="sfm", friction=...)``. Identified
        SFM parameters (``viscous``, ``coulomb``, ``offset``, ``sin<i>``...) that replace
        the compensator's own (:meth:`Design.with_friction`).
    tau_max : float
        Command saturation [N m] (``inf``: none).

    Returns
    -------
    ControllerProgram
        Channels: ``pd`` (group u), then ``obs_tau_m``, ``obs_tau_s``,
        ``obs_theta`` (group hat, zero filters omitted), or an SFM block.

    Raises
    ------
    ParameterError
        No controller, SFM without parameters, or a method/rate :func:`discretize` rejects.
    """
    from ..simulation.controllers import DiscretePD, ObserverCompensator, SfmCompensator

    if design.controller is None:
        raise ParameterError("export needs a controller (e.g. pd:5:0.1)", name="controller", value=None)
    design = design.with_friction(sfm_params)   # the compensator carries its identified friction
    if not tau_max > 0.0:
        raise ParameterError(f"tau_max must be > 0 [N m], got {tau_max!r}", name="tau_max", value=tau_max)
    channels = [Channel("pd", "error", DiscretePD(design.controller, rate_hz, method=method).sos, "u")]
    comp = design.compensator or Compensator()
    sfm = None
    if comp.is_observer:
        obs = ObserverCompensator(comp, design, rate_hz, method=method)
        for name, source, sos, tf in zip(("obs_tau_m", "obs_tau_s", "obs_theta"),
                                         ("tau_m_prev", "tau_s", "theta"),
                                         (obs.sos_m, obs.sos_s, obs.sos_theta), obs.tfs):
            if any(c != 0.0 for c in tf.num):
                channels.append(Channel(name, source, sos, "hat"))
    elif comp.kind == "sfm":
        sc = SfmCompensator(comp.require_friction(), rate_hz)
        sfm = SfmBlock(sc.velocity_sos, tuple(sc.coefficients.coef), sc.coefficients.harm)
    info = _provenance(design, rate_hz, method, comp.friction_params, tau_max)
    return ControllerProgram(float(rate_hz), method, tuple(channels), None, info, sfm, float(tau_max))


def _provenance(design: Design, rate_hz: float, method: str, sfm_params: Mapping[str, float] | None,
                tau_max: float) -> tuple:
    from ..simulation.controllers import DEFAULT_DERIVATIVE_CUTOFF_HZ

    rows = [("tool", f"forecast-design {__version__}"),
            ("rate_hz", repr(float(rate_hz))), ("method", method),
            ("pd_filter", f"C_F(s) = P + D s / (s / w_d + 1), w_d = 2 pi {DEFAULT_DERIVATIVE_CUTOFF_HZ!r} Hz"),
            ("tau_max", repr(float(tau_max)) + " N m")]
    for section, mapping in (("testbed", design.testbed.to_mapping()),
                             ("environment", design.environment.to_mapping()),
                             ("controller", design.controller.to_mapping() if design.controller else {}),
                             ("compensator", (design.compensator or Compensator()).to_mapping())):
        rows.append((section, ", ".join(f"{k} = {v!r}" for k, v in mapping.items())))
    comp = design.compensator or Compensator()
    if comp.is_observer:
        rows.append(("q_filter", f"{comp.q_family}, order {comp.q_order}"))
    if sfm_params is not None:
        rows.append(("sfm", ", ".join(f"{k} = {float(v)!r}" for k, v in sorted(sfm_params.items()))))
    return tuple(rows)


def c_float_literal(v: float) -> str:
    """A float32 C literal that round-trips: %.9g of the float32 value.

    Parameters
    ----------
    v : float
        The value.

    Returns
    -------
    str
        The literal with an ``f`` suffix.

    Raises
    ------
    ExportError
        When the value overflows float32.
    """
    with np.errstate(over="ignore"):   # an overflow is this function's one-line error, not a warning
        v32 = float(np.float32(v))
    if not math.isfinite(v32):
        raise ExportError(f"coefficient {float(v)!r} overflows float32 (|value| > 3.4e38): check the controller "
                          f"gains and the design's parameters")
    text = f"{v32:.9g}"
    if "e" not in text and "." not in text:
        text += ".0"
    return text + "f"


def _render(template: str, **values: str) -> str:
    text = resources.files("forecast_design.export").joinpath("templates", template).read_text("utf-8")
    try:
        return string.Template(text).substitute(values)
    except (KeyError, ValueError) as exc:
        raise ExportError(f"template {template}: {exc}") from None


def emit_c(program: ControllerProgram, out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``fd_controller.h`` and ``fd_controller.c`` for ``program``.

    Parameters
    ----------
    program : ControllerProgram
        What the C code computes.
    out_dir : str or Path
        Folder (created if needed).

    Returns
    -------
    tuple of Path
        (header, source). The text is deterministic: no timestamps, fixed
        ordering, ``%.9g`` float32 literals that round-trip exactly.
    """
    out = Path(out_dir)
    provenance = "\n".join(f" *   {k:<12} {v}" for k, v in program.info) or " *   (no design information)"
    coeffs, body = [], []
    offset = 0

    def table(name: str, sos: np.ndarray, note: str) -> None:
        rows = ",\n".join("    {" + ", ".join(c_float_literal(r[j]) for j in (0, 1, 2, 4, 5)) + "}" for r in sos)
        coeffs.append(f"/* {note} */\nstatic const float fd_sos_{name}[{sos.shape[0]}][5] = {{\n{rows}\n}};")

    def cascade(name: str, src: str, n: int) -> None:
        nonlocal offset
        body.append(f"    y = {src};")
        for i in range(n):
            body.append(f"    y = fd_section(fd_sos_{name}[{i}], s->z[{offset + i}], y);")
        offset += n

    for ch in program.channels:
        n = ch.sos.shape[0]
        table(ch.name, ch.sos, f"{ch.name}: {ch.source} -> {ch.group}, {n} section(s), gain {ch.gain!r}")
        body.append(f"    /* {ch.name} */")
        cascade(ch.name, ch.source, n)
        term = "y" if ch.gain == 1.0 else f"{c_float_literal(ch.gain)} * y"
        body.append(f"    {ch.group} = {ch.group} + {term};")
    needs_libm = False
    if program.sfm is not None:
        sfm = program.sfm
        c = sfm.coef
        table("velocity", sfm.velocity_sos, "sfm velocity estimate v_hat [rad/s] from theta")
        body.append("    /* sfm: viscous v + coulomb sign(v) + offset + angle harmonics */")
        cascade("velocity", "theta", sfm.velocity_sos.shape[0])
        body.append(f"    sgn = (y > {c_float_literal(c[3])}) ? 1.0f : ((y < -{c_float_literal(c[3])}) ? -1.0f : 0.0f);")
        body.append(f"    hat = hat + ((({c_float_literal(c[0])} * y) + ({c_float_literal(c[1])} * sgn)) + {c_float_literal(c[2])});")
        if sfm.has_harmonics:
            needs_libm = True
            body.append(f"    th = theta + {c_float_literal(c[4])};")
            for i in range(sfm.harm.shape[1]):
                h = sfm.harm[:, i]
                if not np.any(h):
                    continue
                body.append(f"    sn = sinf({float(i + 1)!r}f * th);")
                body.append(f"    cs = cosf({float(i + 1)!r}f * th);")
                body.append(f"    hat = hat + (({c_float_literal(h[0])} * sn) + ({c_float_literal(h[1])} * cs))"
                            f" + sgn * (({c_float_literal(h[2])} * sn) + ({c_float_literal(h[3])} * cs));")
    locals_ = ["float y;", "float u = 0.0f;", "float hat = 0.0f;", "float tau_m;"]
    if program.sfm is not None:
        locals_.append("float sgn;")
        if needs_libm:
            locals_ += ["float th;", "float sn;", "float cs;"]
    saturation = ""
    if math.isfinite(program.tau_max):
        lim = c_float_literal(program.tau_max)
        saturation = (f"    if (tau_m > {lim}) {{\n        tau_m = {lim};\n    }} else if (tau_m < -{lim}) {{\n"
                      f"        tau_m = -{lim};\n    }}\n")
    values = {
        "version": __version__, "provenance": provenance,
        "rate_hz": repr(float(program.rate_hz)), "rate_hz_c": c_float_literal(program.rate_hz),
        "n_sections": str(max(program.n_sections, 1)),
        "coefficients": "\n\n".join(coeffs) if coeffs else "/* no filters */",
        "body": "\n".join(body),
        "locals": "\n".join("    " + line for line in locals_),
        "saturation": saturation,
        "includes": "#include <math.h> /* sinf, cosf: float versions only */\n" if needs_libm else "",
        "tau_max_c": c_float_literal(program.tau_max) if math.isfinite(program.tau_max) else "0.0f",
        "has_tau_max": "1" if math.isfinite(program.tau_max) else "0",
    }
    header = _render("fd_controller.h.in", **values)
    source = _render("fd_controller.c.in", **values)
    h_path, c_path = out / "fd_controller.h", out / "fd_controller.c"
    atomic_write_set({h_path: header, c_path: source})
    return h_path, c_path


def export_controller(design: Design | None = None, out_dir: str | Path = ".", *,
                      controller: PDController | str | None = None,
                      compensator: Compensator | str | None = None,
                      env: Any = None, w_q_hz: float | None = None,
                      rate_hz: float = 2000.0, method: str = "tustin",
                      sfm_params: Mapping[str, float] | None = None,
                      tau_max: float = math.inf, testbed: Any = None) -> ExportResult:
    """Discretise a design's force controller and compensator and emit C99.

    Parameters
    ----------
    design : Design, optional
        Base design (default: the Table 1 testbed, environment ``exp-soft``).
    out_dir : str or Path
        Where ``fd_controller.h`` / ``fd_controller.c`` go.
    controller : PDController or str, optional
        Overrides the design's controller (``"pd:5:0.1"`` accepted); default P = 5, D = 0.1.
    compensator : Compensator or str, optional
        Overrides the compensator (a kind string such as ``"ea-fob"`` accepted).
    env : Environment, str or EnvironmentSet, optional
        The one environment the observer is built for, overriding the design's: an
        Environment, a preset name, inline ``k_e=..,J_e=..`` values or a file holding one
        (:func:`~forecast_design.environments.resolve_environments`; a set of several is an error).
    w_q_hz : float, optional
        Q-filter cutoff override [Hz].
    rate_hz : float
        Sample rate [Hz] (2000 on the F446RE).
    method : str
        Discretisation method; ``tustin`` by default (the simulator's choice).
    sfm_params : Mapping[str, float], optional
        Identified SFM parameters (compensator ``sfm`` only).
    tau_max : float
        Command saturation [N m]; ``inf`` (default) for none.
    testbed : Testbed, str or None
        Testbed overriding the design's (:func:`~forecast_design.environments.resolve_testbed`).

    Returns
    -------
    ExportResult
        Paths, the discretised program, the design and a digest.

    Raises
    ------
    ParameterError
        Bad controller/compensator strings, unknown environment or method.
    """
    if method not in METHODS:
        raise ParameterError(f"export method must be one of {', '.join(METHODS)}, got {method!r}",
                             name="method", value=method)
    if design is not None:
        require_design(design, "export_controller")
    if testbed is not None:
        design = dataclasses.replace(resolve_design(design), testbed=resolve_testbed(testbed))
    if env is not None:
        tb = design.testbed if design is not None else None
        env = resolve_environments(env, testbed=tb).single("export")[1]
    design = resolve_design(design, controller=controller, compensator=compensator, env=env, w_q_hz=w_q_hz)
    program = build_program(design, rate_hz=rate_hz, method=method, sfm_params=sfm_params, tau_max=tau_max)
    h, c = emit_c(program, out_dir)
    digest = hashlib.sha256(h.read_bytes() + c.read_bytes()).hexdigest()
    return ExportResult(h, c, program, design, digest)
