"""What runs each control period: the force controller's law plus the compensator, as one program.

A :class:`ControllerProgram` is built once from a design (:func:`build_program`: the
controller's :meth:`~forecast_design.controllers.Controller.discrete_law` and the
compensator's strategy, :mod:`forecast_design.compensators`) and run by everything that runs a
controller: the simulator's compiled loop, the Python reference (:class:`ProgramStep`, float64
or float32), the emitted C (:mod:`forecast_design.export.c`), the board firmware and its upload
blob (:meth:`ControllerProgram.to_bytes`), and the board emulator. One period, with the
inputs ``tau_r``, ``tau_s``, ``theta`` and the previous command ``tau_m_prev``::

    e     = tau_r - tau_s
    u_lin = sum of the controller's channels (group u), in order     (cascades of delta sections)
            or, for a controller written as code (``external``), the code's output
    x     = x + b0 e + b1 e_prev                                     (PID integrator, if any)
    u     = sat(u_lin + x, u_min, u_max), then the anti-windup (controllers/base.py)
    hat   = sum of the compensator's channels (group hat) + the friction feed-forward (if any)
    tau_m = sat(u + hat, -tau_max, tau_max)

:func:`program_step` is that period, written once: compiled by numba for the simulator's
float64 kernel and for the float32 reference that the C reproduces bit for bit (every constant
is taken from the coefficient arrays, so a float32 call computes in float32 throughout).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from .compensators import FrictionFeedforward, compensator_strategy, feedforward_eval
from .controllers import Controller, DiscreteLaw
from .discrete import check_kernel_cache, njit, sos_step
from .errors import ParameterError
from .params import Compensator, Design

__all__ = [
    "SOURCES",
    "ANTI_WINDUP_CODES",
    "Channel",
    "IntegratorBlock",
    "FeedforwardBlock",
    "ControllerProgram",
    "PackedProgram",
    "ProgramStep",
    "program_step",
    "build_program",
]

#: Signals a channel can filter. ``error`` is tau_r - tau_s; ``tau_m_prev`` is the command
#: applied over the previous period (the one-sample delay that breaks the algebraic loop).
SOURCES = ("error", "tau_s", "theta", "tau_m_prev", "tau_r")
#: Anti-windup schemes as the kernel, the blob and the C number them.
ANTI_WINDUP_CODES = {"none": 0, "clamping": 1, "back-calculation": 2}

_BLOB_MAGIC = b"FDC4"


def _check_sos(owner: str, sos: Any) -> np.ndarray:
    arr = np.array(np.atleast_2d(np.asarray(sos, dtype=float)))
    if arr.ndim != 2 or arr.shape[1] != 6 or arr.shape[0] < 1 or not np.all(arr[:, 3] == 1.0):
        raise ParameterError(f"{owner}: sos must have shape (n >= 1, 6) with a0 = 1", name="sos", value=None)
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{owner}: sos has non-finite coefficients", name="sos", value=None)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, slots=True)
class Channel:
    """One additive term of the motor command: ``gain * H(source)``, H a cascade of delta sections.

    Parameters
    ----------
    name : str
        C identifier fragment, e.g. ``"ctl"`` or ``"obs_tau_s"``.
    source : str
        One of :data:`SOURCES`.
    sos : ndarray, shape (n_sections, 6)
        Delta sections, rows ``[b0, b1, b2, 1, a1, a2]`` in ``rho = z - 1`` (float64 design values;
        :mod:`forecast_design.discrete`).
    group : str
        ``"u"`` (controller output) or ``"hat"`` (friction estimate).
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
        if self.group not in ("u", "hat"):
            raise ParameterError(f"channel {self.name}: group must be 'u' or 'hat', got {self.group!r}",
                                 name="group", value=self.group)
        object.__setattr__(self, "sos", _check_sos(f"channel {self.name}", self.sos))
        object.__setattr__(self, "gain", float(self.gain))


@dataclass(frozen=True, slots=True)
class IntegratorBlock:
    """A PID's integrator: ``x_k = x_(k-1) + b0 e_k + b1 e_(k-1)`` with its anti-windup.

    Parameters
    ----------
    b0, b1 : float
        Increment weights [N m/N m].
    anti_windup : str
        A key of :data:`ANTI_WINDUP_CODES`.
    back_gain : float
        ``T / T_t`` of back-calculation [-].
    """

    b0: float
    b1: float
    anti_windup: str = "none"
    back_gain: float = 0.0

    def __post_init__(self) -> None:
        if self.anti_windup not in ANTI_WINDUP_CODES:
            raise ParameterError(f"integrator anti_windup must be one of {', '.join(ANTI_WINDUP_CODES)}, "
                                 f"got {self.anti_windup!r}", name="anti_windup", value=self.anti_windup)
        for name in ("b0", "b1", "back_gain"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ParameterError(f"integrator {name} must be finite, got {value!r}", name=name, value=value)
            object.__setattr__(self, name, value)


@dataclass(frozen=True, slots=True)
class FeedforwardBlock:
    """The friction feed-forward: :func:`~forecast_design.compensators.feedforward_eval` on theta and v_hat.

    Parameters
    ----------
    velocity_sos : ndarray, shape (n, 6)
        Filtered derivative of theta giving v_hat [rad/s].
    coef : tuple of float
        The formula's 9 coefficients (:mod:`forecast_design.compensators.feedforward`).
    harm : ndarray, shape (4, n_h)
        Rows sin, cos, coulomb_sin, coulomb_cos of harmonics 1..n_h [N m].
    """

    velocity_sos: np.ndarray
    coef: tuple[float, ...]
    harm: np.ndarray

    def __post_init__(self) -> None:
        harm = np.array(np.atleast_2d(np.asarray(self.harm, dtype=float)))
        if harm.shape[0] != 4 or len(self.coef) != 9 or not np.all(np.isfinite(harm)) \
                or not all(math.isfinite(c) for c in self.coef):
            raise ParameterError("feed-forward block: finite coef (9,) and harm (4, n) expected",
                                 name="feedforward", value=None)
        harm.flags.writeable = False
        object.__setattr__(self, "velocity_sos", _check_sos("feed-forward velocity", self.velocity_sos))
        object.__setattr__(self, "harm", harm)
        object.__setattr__(self, "coef", tuple(float(c) for c in self.coef))

    @classmethod
    def from_feedforward(cls, ff: FrictionFeedforward) -> "FeedforwardBlock":
        """The block of a compensator's :class:`~forecast_design.compensators.FrictionFeedforward`."""
        return cls(ff.velocity.to_delta_sos(), tuple(ff.coef[:9]), ff.harm)

    @property
    def has_harmonics(self) -> bool:
        """True when any angle harmonic is non-zero (the C then needs sinf/cosf)."""
        return bool(np.any(self.harm != 0.0))

    @property
    def has_stribeck(self) -> bool:
        """True when a Stribeck excess is fed forward (the C then needs expf)."""
        return self.coef[4] != 0.0


@dataclass(frozen=True, slots=True)
class PackedProgram:
    """A program as the arrays :func:`program_step` reads (one dtype; fresh state from :meth:`new_state`).

    Parameters
    ----------
    sos : ndarray, shape (n, 6)
        Every channel's sections, then the feed-forward's velocity sections.
    meta : ndarray of int64, shape (n_channels, 4)
        Per channel: source index, group (0 u, 1 hat), first section, section count.
    gains : ndarray, shape (n_channels,)
        Channel gains.
    flags : ndarray of int64, shape (7,)
        Channel count, integrator present, anti-windup code, feed-forward present, first
        velocity section, velocity section count, external controller (its output is read
        from ``mem[3]``).
    par : ndarray, shape (9,)
        ``u_min, u_max, tau_max, b0, b1, back_gain, 0, 1, 0`` (the typed constants 0 and 1).
    ff_coef : ndarray, shape (10,)
        The feed-forward's coefficients and a typed 1.
    ff_harm : ndarray, shape (4, n_h)
        Its harmonics.
    """

    sos: np.ndarray
    meta: np.ndarray
    gains: np.ndarray
    flags: np.ndarray
    par: np.ndarray
    ff_coef: np.ndarray
    ff_harm: np.ndarray

    def new_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Zero section states (n, 2) and memory ``[x, e_prev, tau_m_prev, u, hat]``, in the program's dtype."""
        return np.zeros((self.sos.shape[0], 2), dtype=self.sos.dtype), np.zeros(5, dtype=self.sos.dtype)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """``(sos, meta, gains, flags, par, ff_coef, ff_harm)``: the constant arguments of :func:`program_step`."""
        return self.sos, self.meta, self.gains, self.flags, self.par, self.ff_coef, self.ff_harm


@njit
def program_step(sos, state, meta, gains, flags, par, ff_coef, ff_harm, mem, tau_r, tau_s, theta):
    """One control period of a packed program (module docstring); updates ``state`` and ``mem``.

    Parameters
    ----------
    sos, state, meta, gains, flags, par, ff_coef, ff_harm : ndarray
        :class:`PackedProgram`'s arrays and section states (``state`` updated in place).
    mem : ndarray, shape (5,)
        ``[x, e_prev, tau_m_prev, u, hat]``: integrator, previous error, previous command
        [N m] (updated), and this period's controller output and friction estimate [N m] (written).
        An external controller's output for this period is put in ``mem[3]`` before the call.
    tau_r, tau_s, theta : float
        Reference [N m], spring torque [N m], motor angle [rad].

    Returns
    -------
    float
        The motor torque command [N m], in the arrays' dtype.
    """
    e = tau_r - tau_s
    u = par[6]
    if flags[6] != 0:
        u = mem[3]          # a controller written as code: its output, computed by the caller
    hat = par[6]
    for c in range(flags[0]):
        src = meta[c, 0]
        if src == 0:
            x = e
        elif src == 1:
            x = tau_s
        elif src == 2:
            x = theta
        elif src == 3:
            x = mem[2]
        else:
            x = tau_r
        a = meta[c, 2]
        y = sos_step(sos[a:a + meta[c, 3]], state[a:a + meta[c, 3]], x)
        if gains[c] != par[7]:
            y = gains[c] * y
        if meta[c, 1] == 0:
            u = u + y
        else:
            hat = hat + y
    xi = par[6]
    if flags[1] != 0:
        xi = mem[0] + (par[3] * e + par[4] * mem[1])
        un = u + xi
    else:
        un = u
    us = un
    if us > par[1]:
        us = par[1]
    elif us < par[0]:
        us = par[0]
    if flags[1] != 0:
        if flags[2] == 1 and us != un and e * (un - us) > par[6]:
            # clamping: saturated and e pushes further into the limit: the integrator holds
            xi = mem[0]
        elif flags[2] == 2:
            xi = xi + par[5] * (us - un)
        mem[0] = xi
        mem[1] = e
    if flags[3] != 0:
        a = flags[4]
        v = sos_step(sos[a:a + flags[5]], state[a:a + flags[5]], theta)
        hat = hat + feedforward_eval(ff_coef, ff_harm, theta, v)
    tau_m = us + hat
    if tau_m > par[2]:
        tau_m = par[2]
    elif tau_m < -par[2]:
        tau_m = -par[2]
    mem[2] = tau_m
    mem[3] = us
    mem[4] = hat
    return tau_m


class ProgramStep:
    """A running instance of a :class:`ControllerProgram` (float64 by default): the Python reference.

    Parameters
    ----------
    program : ControllerProgram
        What to run.
    dtype : numpy dtype
        ``np.float64`` (the design implementation) or ``np.float32`` (what the C code computes,
        bit for bit for the linear parts when the C is built without FMA contraction).
    """

    def __init__(self, program: "ControllerProgram", dtype: Any = np.float64) -> None:
        import importlib

        check_kernel_cache(program_step, [importlib.import_module(m) for m in (
            "forecast_design.discrete.filters", "forecast_design.compensators.feedforward", __name__)])
        self.program = program
        self._f = np.dtype(dtype).type
        self._packed = program.pack(dtype)
        self._args = self._packed.arrays()
        self._state, self._mem = self._packed.new_state()

    def reset(self) -> None:
        """Back to rest, as ``fd_init``."""
        self._state[:] = 0.0
        self._mem[:] = 0.0

    @property
    def tau_m_prev(self) -> float:
        """The command applied over the previous period [N m]."""
        return float(self._mem[2])

    @property
    def u(self) -> float:
        """The last step's controller output [N m] (``fd_state.u``)."""
        return float(self._mem[3])

    @property
    def hat(self) -> float:
        """The last step's friction estimate [N m] (``fd_state.hat``)."""
        return float(self._mem[4])

    def step(self, tau_r: float, tau_s: float, theta: float, u_external: float = 0.0) -> float:
        """One period, as ``fd_step``: measurements in, motor torque command out [N m].

        Parameters
        ----------
        tau_r : float
            Force reference [N m].
        tau_s : float
            Measured spring torque [N m].
        theta : float
            Motor angle [rad].
        u_external : float
            An external controller's output this period [N m] (programs with ``external``).

        Returns
        -------
        float
            Motor torque command for the next period [N m].
        """
        sos, meta, gains, flags, par, ff_coef, ff_harm = self._args
        f = self._f
        if flags[6]:
            self._mem[3] = f(u_external)
        return float(program_step(sos, self._state, meta, gains, flags, par, ff_coef, ff_harm, self._mem,
                                  f(tau_r), f(tau_s), f(theta)))

    def run(self, tau_r: np.ndarray, tau_s: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Step through whole input arrays (shape (n,)) from the current state; return tau_m [N m]."""
        return np.array([self.step(a, b, c) for a, b, c in zip(tau_r, tau_s, theta)])


@dataclass(frozen=True, slots=True)
class ControllerProgram:
    """A discretised force controller plus compensator, ready for the simulator, C or the board.

    Parameters
    ----------
    rate_hz : float
        Sample rate [Hz].
    method : str
        How the compensator's filters were discretised (the controller's own method is in
        ``info``).
    channels : tuple of Channel
        Additive terms: the controller's (group ``u``), then the compensator's (``hat``).
    info : tuple of (str, str)
        Provenance lines for the generated comment block (design parameters...).
    integrator : IntegratorBlock or None
        A PID's integrator.
    feedforward : FeedforwardBlock or None
        A friction feed-forward (compensator ``sfm``).
    u_min, u_max : float
        Saturation of the controller output [N m] (-inf/inf: none).
    tau_max : float
        Command saturation |tau_m| <= tau_max [N m]; ``inf`` for none.
    external : str
        ``""`` for a controller the program computes; otherwise the identity of a controller
        written as code whose output the caller supplies each period (``c`` and the SHA-256 of
        its file, ``python module:Class``): the channels then hold the compensator only.
    """

    rate_hz: float
    method: str
    channels: tuple[Channel, ...]
    info: tuple[tuple[str, str], ...] = ()
    integrator: IntegratorBlock | None = None
    feedforward: FeedforwardBlock | None = None
    u_min: float = -math.inf
    u_max: float = math.inf
    tau_max: float = math.inf
    external: str = ""
    _packed: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (self.rate_hz > 0.0 and math.isfinite(self.rate_hz)):
            raise ParameterError(f"program rate_hz must be > 0 [Hz], got {self.rate_hz!r}", name="rate_hz",
                                 value=self.rate_hz)
        if not self.tau_max > 0.0:
            raise ParameterError(f"tau_max must be > 0 [N m], got {self.tau_max!r}", name="tau_max",
                                 value=self.tau_max)
        if not self.u_min < self.u_max:
            raise ParameterError(f"u_min = {self.u_min} must be below u_max = {self.u_max} [N m]", name="u_min",
                                 value=self.u_min)
        if self.external:
            if not isinstance(self.external, str) or len(self.external.encode("utf-8")) > 200:
                raise ParameterError(f"external controller identity must be a string of <= 200 bytes, got "
                                     f"{self.external!r:.60}", name="external", value=self.external)
            if any(ch.group == "u" for ch in self.channels) or self.integrator is not None:
                raise ParameterError("a program with an external controller (code) holds the compensator only: no "
                                     "controller channels or integrator", name="external", value=self.external)

    @property
    def n_sections(self) -> int:
        """Second-order sections over all filters [-]."""
        n = sum(ch.sos.shape[0] for ch in self.channels)
        return n + (0 if self.feedforward is None else self.feedforward.velocity_sos.shape[0])

    def pack(self, dtype: Any = np.float64) -> PackedProgram:
        """The arrays of :func:`program_step` in ``dtype`` (float64 or float32), cached per dtype.

        Parameters
        ----------
        dtype : numpy dtype
            Coefficient and arithmetic type.

        Returns
        -------
        PackedProgram
            Read-only arrays.
        """
        key = np.dtype(dtype).str
        if key in self._packed:
            return self._packed[key]
        rows, meta, gains = [], [], []
        for ch in self.channels:
            meta.append((SOURCES.index(ch.source), 0 if ch.group == "u" else 1, len(rows), ch.sos.shape[0]))
            rows.extend(ch.sos)
            gains.append(ch.gain)
        ff = self.feedforward
        vel_start = len(rows)
        if ff is not None:
            rows.extend(ff.velocity_sos)
        sos = np.array(rows if rows else np.zeros((1, 6)), dtype=dtype).reshape(-1, 6)
        integ = self.integrator
        flags = np.array([len(self.channels), integ is not None,
                          ANTI_WINDUP_CODES[integ.anti_windup] if integ else 0, ff is not None, vel_start,
                          0 if ff is None else ff.velocity_sos.shape[0], bool(self.external)], dtype=np.int64)
        with np.errstate(over="ignore"):
            par = np.array([self.u_min, self.u_max, self.tau_max, integ.b0 if integ else 0.0,
                            integ.b1 if integ else 0.0, integ.back_gain if integ else 0.0, 0.0, 1.0, 0.0],
                           dtype=dtype)
        ff_coef = np.array((*ff.coef, 1.0) if ff else (0.0,) * 9 + (1.0,), dtype=dtype)
        ff_harm = np.array(ff.harm if ff else np.zeros((4, 1)), dtype=dtype)
        meta_arr = np.array(meta if meta else np.zeros((0, 4)), dtype=np.int64).reshape(-1, 4)
        gains_arr = np.array(gains if gains else [], dtype=dtype)
        packed = PackedProgram(*(np.ascontiguousarray(a) for a in (sos, meta_arr, gains_arr, flags, par, ff_coef,
                                                                     ff_harm)))
        for a in packed.arrays():
            a.flags.writeable = False
        self._packed[key] = packed
        return packed

    def make_step(self, dtype: Any = np.float64) -> ProgramStep:
        """A fresh running instance (see :class:`ProgramStep`)."""
        return ProgramStep(self, dtype)

    def to_bytes(self) -> bytes:
        """The UPLOAD payload: float32 coefficients and layout (byte map in docs/protocol.md).

        Returns
        -------
        bytes
            ``b"FDC4"``, float32 rate [Hz], float32 tau_max [N m], float32 u_min and u_max
            [N m], uint8 channel count; per channel uint8 source, uint8 group, uint8 sections,
            float32 gain, 5 float32 per section (b0 b1 b2 a1 a2); uint8 integrator flag and, if
            set, uint8 anti-windup code and float32 b0, b1, back_gain; uint8 feed-forward flag
            and, if set, uint8 sections, the sections, 9 float32 coef, uint8 harmonics, 4 x n
            float32 harmonics (row-major); uint8 length and the UTF-8 identity of an external
            controller (0: none).
        """
        out = bytearray(_BLOB_MAGIC)
        out += struct.pack("<ffffB", self.rate_hz, self.tau_max, self.u_min, self.u_max, len(self.channels))

        def sections(sos: np.ndarray) -> bytes:
            return b"".join(struct.pack("<5f", r[0], r[1], r[2], r[4], r[5]) for r in sos)

        for ch in self.channels:
            out += struct.pack("<BBBf", SOURCES.index(ch.source), ("u", "hat").index(ch.group),
                               ch.sos.shape[0], ch.gain)
            out += sections(ch.sos)
        if self.integrator is None:
            out += b"\x00"
        else:
            i = self.integrator
            out += struct.pack("<BBfff", 1, ANTI_WINDUP_CODES[i.anti_windup], i.b0, i.b1, i.back_gain)
        if self.feedforward is None:
            out += b"\x00"
        else:
            ff = self.feedforward
            out += struct.pack("<BB", 1, ff.velocity_sos.shape[0]) + sections(ff.velocity_sos)
            out += struct.pack("<9fB", *ff.coef, ff.harm.shape[1])
            out += np.asarray(ff.harm, dtype="<f4").tobytes()
        ident = self.external.encode("utf-8")
        out += struct.pack("<B", len(ident)) + ident
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
            If the blob is malformed (wrong magic, truncated, unknown source, trailing bytes).
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

        codes = {v: k for k, v in ANTI_WINDUP_CODES.items()}
        try:
            rate_hz, tau_max, u_min, u_max, n = take("<ffffB")
            channels = []
            for i in range(n):
                src, grp, ns, gain = take("<BBBf")
                if src >= len(SOURCES) or grp > 1 or ns == 0:
                    raise bad(f"channel {i}: source {src}, group {grp}, {ns} sections invalid")
                channels.append(Channel(f"ch{i}", SOURCES[src], sections(ns), ("u", "hat")[grp], gain))
            (has_integ,) = take("<B")
            integ = None
            if has_integ:
                code, b0, b1, back = take("<Bfff")
                if code not in codes:
                    raise bad(f"anti-windup code {code} unknown")
                integ = IntegratorBlock(b0, b1, codes[code], back)
            (has_ff,) = take("<B")
            ff = None
            if has_ff:
                (ns,) = take("<B")
                vsos = sections(ns)
                *coef, nh = take("<9fB")
                harm = np.array(take(f"<{4 * nh}f"), dtype=float).reshape(4, nh)
                ff = FeedforwardBlock(vsos, tuple(coef), harm)
            (n_ident,) = take("<B")
            try:
                external = bytes(take(f"<{n_ident}s")[0]).decode("utf-8")
            except UnicodeDecodeError:
                raise bad("external controller identity is not UTF-8") from None
        except struct.error:
            raise bad("truncated") from None
        if pos != len(blob):
            raise bad(f"{len(blob) - pos} trailing bytes")
        if not (rate_hz > 0.0 and math.isfinite(rate_hz)) or not tau_max > 0.0 or not u_min < u_max:
            raise bad(f"rate_hz {rate_hz}, tau_max {tau_max}, u_min {u_min} < u_max {u_max} required")
        return cls(float(rate_hz), method, tuple(channels), integrator=integ, feedforward=ff, u_min=float(u_min),
                   u_max=float(u_max), tau_max=float(tau_max), external=external)


def _law_channels(law: DiscreteLaw) -> list[Channel]:
    return [Channel(ch.name, ch.source, ch.tf.to_delta_sos(), "u") for ch in law.channels]


def build_program(design: Design, *, rate_hz: float = 2000.0, tau_max: float = math.inf,
                  velocity_cutoff_hz: float | None = None, deadband: float = 0.0, angle_offset: float = 0.0,
                  info: tuple[tuple[str, str], ...] = ()) -> ControllerProgram:
    """The program a design runs at ``rate_hz``: its controller's law and its compensator.

    Parameters
    ----------
    design : Design
        Needs ``controller`` (with equations); ``compensator`` ``None`` means ``none``. The
        compensator believes ``design`` (its testbed and environment).
    rate_hz : float
        Control rate [Hz].
    tau_max : float
        Command saturation [N m] (``inf``: none).
    velocity_cutoff_hz : float, optional
        Velocity filter of a friction feed-forward [Hz] (default: the compensator module's).
    deadband : float
        Sign dead band of a friction feed-forward [rad/s].
    angle_offset : float
        Absolute motor angle at theta = 0 for the feed-forward's harmonics [rad].
    info : tuple of (str, str)
        Provenance lines to carry (the C export's comment block).

    Returns
    -------
    ControllerProgram
        Channels: the controller's (group u), then the compensator's linear paths
        ``obs_tau_m``, ``obs_tau_s``, ``obs_theta`` (group hat); the PID integrator, the
        controller's saturation and a friction feed-forward when present.

    Raises
    ------
    ParameterError
        No controller, a controller without equations (``other``), an SFM without friction, or a
        rate the discretisation rejects. A controller written as code
        (:mod:`forecast_design.controllers.code`) makes an ``external`` program: the compensator's
        channels only, the controller's output supplied by the caller each period.
    """
    from .compensators import DEFAULT_VELOCITY_CUTOFF_HZ

    controller = design.controller
    if not isinstance(controller, Controller):
        raise ParameterError("a program needs a controller (e.g. pd:5:0.1)", name="controller", value=None)
    if controller.is_code:
        # written as code: it runs as written, its output supplied each period (program_step's mem[3])
        channels, integ, u_min, u_max, external = [], None, -math.inf, math.inf, controller.identity()
    else:
        law = controller.discrete_law(rate_hz)
        channels = _law_channels(law)
        integ = None if law.integrator is None else IntegratorBlock(
            law.integrator.b0, law.integrator.b1, law.integrator.anti_windup, law.integrator.back_gain)
        u_min, u_max, external = law.u_min, law.u_max, ""
    comp = design.compensator or Compensator()
    strategy = compensator_strategy(comp)
    ff = None
    if comp.kind == "sfm":
        block = strategy.feedforward(comp, rate_hz, velocity_cutoff_hz=velocity_cutoff_hz or DEFAULT_VELOCITY_CUTOFF_HZ,
                                     deadband=deadband, angle_offset=angle_offset)
        ff = FeedforwardBlock.from_feedforward(block)
    else:
        names = {"tau_m_prev": "obs_tau_m", "tau_s": "obs_tau_s", "theta": "obs_theta"}
        for source, tf in strategy.discrete_filters(comp, design, rate_hz).paths():
            channels.append(Channel(names[source], source, tf.to_delta_sos(), "hat"))
    return ControllerProgram(float(rate_hz), "tustin", tuple(channels), tuple(info), integ, ff,
                             u_min, u_max, float(tau_max), external)
