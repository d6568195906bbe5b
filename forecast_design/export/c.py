"""C99 export of a discretised force controller and compensator for the Nucleo F446RE (Cortex-M4F).

The C computes the :class:`~forecast_design.program.ControllerProgram` of the design (the one
the simulator runs and :class:`~forecast_design.program.ProgramStep` references in float32):
the controller's channels, a PID's integrator with its anti-windup, the controller's output
saturation, the compensator's channels and friction feed-forward, the command limit, in
:func:`~forecast_design.program.program_step`'s order of operations.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import string
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .. import __version__
from ..environments import resolve_environments, resolve_testbed
from ..errors import ExportError, ParameterError
from ..fileio import atomic_write_set
from ..params import Compensator, Design, require_design, resolve_design
from ..controllers import CController
from ..program import ControllerProgram, build_program

__all__ = [
    "c_float_literal",
    "ExportResult",
    "emit_c",
    "export_controller",
    "program_for_export",
]

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
        SHA-256 of the emitted header and source (and the user's C) [hex].
    user_source : pathlib.Path or None
        ``fd_user.c``, the copy of a C controller's file (written as code), or None.
    """

    header: Path
    source: Path
    program: ControllerProgram
    design: Design
    digest: str
    user_source: Path | None = None

    def to_mapping(self) -> dict[str, Any]:
        """Summary for ``--json``: files, rate, method, sections, coefficient count, digest."""
        comp = self.design.compensator
        return {
            "header": str(self.header), "source": str(self.source),
            "user_source": None if self.user_source is None else str(self.user_source),
            "external_controller": self.program.external or None,
            "rate_hz": self.program.rate_hz, "compensator_method": self.program.method,
            "controller_label": None if self.design.controller is None else self.design.controller.label,
            "channels": [{"name": ch.name, "source": ch.source, "sections": int(ch.sos.shape[0]),
                          "group": ch.group, "gain": ch.gain} for ch in self.program.channels],
            "integrator": None if self.program.integrator is None else {
                "anti_windup": self.program.integrator.anti_windup},
            "u_min_N_m": self.program.u_min if math.isfinite(self.program.u_min) else None,
            "u_max_N_m": self.program.u_max if math.isfinite(self.program.u_max) else None,
            "feedforward": self.program.feedforward is not None,
            # no saturation is null, not Infinity (strict JSON)
            "tau_max_N_m": self.program.tau_max if math.isfinite(self.program.tau_max) else None,
            "n_sections": self.program.n_sections,
            "controller": None if self.design.controller is None else self.design.controller.to_mapping(),
            # the defaults the tables leave out, said: how the controller is discretized, the Q filter's form
            "controller_discretization": getattr(self.design.controller, "discretization", None),
            "compensator": None if self.design.compensator is None else self.design.compensator.to_mapping(),
            "q_filter": {"family": comp.q_family, "order": comp.q_order} if comp is not None and comp.is_observer
            else None,
            # what the observer's nominal plant was built from (the believed environment, its link)
            "testbed": self.design.testbed.to_mapping(), "environment": self.design.environment.to_mapping(),
            "sha256": self.digest,
        }





def program_for_export(design: Design, *, rate_hz: float = 2000.0, tau_max: float = math.inf) -> ControllerProgram:
    """The program a design exports: :func:`~forecast_design.program.build_program` with its provenance lines.

    Parameters
    ----------
    design : Design
        Needs a controller with equations; the compensator believes the design.
    rate_hz : float
        Sample rate [Hz].
    tau_max : float
        Command saturation [N m] (``inf``: none).

    Returns
    -------
    ControllerProgram
        The program, ``info`` filled.
    """
    if not tau_max > 0.0:
        raise ParameterError(f"tau_max must be > 0 [N m], got {tau_max!r}", name="tau_max", value=tau_max)
    info = _provenance(design, rate_hz, tau_max)
    return build_program(design, rate_hz=rate_hz, tau_max=tau_max, info=info)


def _provenance(design: Design, rate_hz: float, tau_max: float) -> tuple:
    from ..compensators import OBSERVER_METHOD, compensator_strategy

    comp = design.compensator or Compensator()
    rows = [("tool", f"forecast-design {__version__}"), ("rate_hz", repr(float(rate_hz)))]
    if design.controller is not None and design.controller.is_code:
        rows.append(("law", f"{design.controller.label}; u = fd_user_step(tau_r, tau_s, theta, q) in fd_user.c, "
                            "its state in its own static variables"))
    elif design.controller is not None:
        rows.append(("law", f"{design.controller.label}; u = C_r(z) tau_r - C(z) tau_s as "
                            "forecast_design.controllers defines it"))
    rows.append(("tau_max", repr(float(tau_max)) + " N m"))
    for section, mapping in (("testbed", design.testbed.to_mapping()),
                             ("environment", design.environment.to_mapping()),
                             ("controller", design.controller.to_mapping() if design.controller else {}),
                             ("compensator", {k: v for k, v in comp.to_mapping().items() if k != "friction"})):
        rows.append((section, ", ".join(f"{k} = {v!r}" for k, v in mapping.items())))
    method = getattr(design.controller, "discretization", None)
    if method is not None and not (design.controller and design.controller.is_code):
        rows.append(("discretized", f"controller by {method}"))      # the table leaves its default out
    if comp.is_observer:
        rows.append(("q_filter", f"{comp.q_family}, order {comp.q_order}; filters discretised {OBSERVER_METHOD}"))
    if comp.friction:
        rows.append(("friction", ", ".join(f"{k} = {float(v)!r}" for k, v in comp.friction)))
    rows.append(("analysis", compensator_strategy(comp).analysis_note(comp)))
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


def emit_c(program: ControllerProgram, out_dir: str | Path, *, user_source: str | Path | None = None
           ) -> tuple[Path, Path]:
    """Write ``fd_controller.h`` and ``fd_controller.c`` for ``program``.

    Parameters
    ----------
    program : ControllerProgram
        What the C code computes.
    out_dir : str or Path
        Folder (created if needed).
    user_source : str or Path, optional
        The C file of an ``external`` program's controller (written as code): copied to
        ``fd_user.c`` beside the generated files, its content checked against the program's
        identity; ``fd_step`` calls its ``fd_user_step``.

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
    lit = c_float_literal

    def table(name: str, sos: np.ndarray, note: str) -> None:
        rows = ",\n".join("    {" + ", ".join(lit(r[j]) for j in (0, 1, 2, 4, 5)) + "}" for r in sos)
        coeffs.append(f"/* {note} */\nstatic const float fd_sos_{name}[{sos.shape[0]}][5] = {{\n{rows}\n}};")

    def cascade(name: str, src: str, n: int) -> None:
        nonlocal offset
        body.append(f"    y = {src};")
        for i in range(n):
            body.append(f"    y = fd_section(fd_sos_{name}[{i}], s->z[{offset + i}], y);")
        offset += n

    def clamp(var: str, lo: float, hi: float, indent: str = "    ") -> None:
        # only the finite sides: a comparison with an infinite limit never fires
        if math.isfinite(hi) and math.isfinite(lo):
            body.append(f"{indent}if ({var} > {lit(hi)}) {{\n{indent}    {var} = {lit(hi)};\n{indent}}} else if "
                        f"({var} < {lit(lo)}) {{\n{indent}    {var} = {lit(lo)};\n{indent}}}")
        elif math.isfinite(hi):
            body.append(f"{indent}if ({var} > {lit(hi)}) {{\n{indent}    {var} = {lit(hi)};\n{indent}}}")
        elif math.isfinite(lo):
            body.append(f"{indent}if ({var} < {lit(lo)}) {{\n{indent}    {var} = {lit(lo)};\n{indent}}}")

    sources = {"error": "error", "tau_s": "tau_s", "theta": "theta", "tau_m_prev": "tau_m_prev", "tau_r": "tau_r"}
    external = _external_source(program, user_source)
    if external is not None:
        body.append("    /* the force controller: the user's C (fd_user.c) */")
        body.append("    u = fd_user_step(tau_r, tau_s, theta, q);")
    for ch in program.channels:
        n = ch.sos.shape[0]
        table(ch.name, ch.sos, f"{ch.name}: {ch.source} -> {ch.group}, {n} section(s), gain {ch.gain!r}")
        body.append(f"    /* {ch.name} */")
        cascade(ch.name, sources[ch.source], n)
        if ch.gain != 1.0:
            body.append(f"    y = {lit(ch.gain)} * y;")
        body.append(f"    {ch.group} = {ch.group} + y;")
    integ = program.integrator
    saturated = math.isfinite(program.u_min) or math.isfinite(program.u_max)
    if integ is not None:
        body.append(f"    /* integrator x += b0 e + b1 e_prev, anti-windup: {integ.anti_windup} */")
        body.append(f"    xi = s->xi + ({lit(integ.b0)} * error + {lit(integ.b1)} * s->e_prev);")
        body.append("    un = u + xi;")
    else:
        body.append("    un = u;")
    body.append("    us = un;")
    if saturated:
        body.append("    /* controller output saturation u_min <= u <= u_max */")
        clamp("us", program.u_min, program.u_max)
    if integ is not None:
        if integ.anti_windup == "clamping":
            body.append("    if (us != un && error * (un - us) > 0.0f) {   /* clamping: the integrator holds */")
            body.append("        xi = s->xi;")
            body.append("    }")
        elif integ.anti_windup == "back-calculation":
            body.append(f"    xi = xi + {lit(integ.back_gain)} * (us - un);   /* back-calculation */")
        body.append("    s->xi = xi;")
        body.append("    s->e_prev = error;")
    libm: list[str] = []
    ff = program.feedforward
    if ff is not None:
        c = ff.coef
        table("velocity", ff.velocity_sos, "friction feed-forward: velocity estimate v_hat [rad/s] from theta")
        body.append("    /* friction feed-forward (forecast_design.compensators.feedforward_eval) */")
        cascade("velocity", "theta", ff.velocity_sos.shape[0])
        body.append(f"    sgn = (y > {lit(c[7])}) ? 1.0f : ((y < -{lit(c[7])}) ? -1.0f : 0.0f);")
        body.append(f"    ff = (y > 0.0f) ? ({lit(c[0])} * y) : ({lit(c[1])} * y);")
        body.append(f"    if (sgn > 0.0f) {{\n        ff = ff + {lit(c[2])};\n    }} else if (sgn < 0.0f) {{\n"
                    f"        ff = ff - {lit(c[3])};\n    }}")
        if ff.has_stribeck:
            libm.append("expf")
            body.append(f"    r = y / {lit(c[5])};")
            body.append(f"    ff = ff + sgn * ({lit(c[4])} * expf(-(r * r)));")
        body.append(f"    ff = ff + {lit(c[6])};")
        if ff.has_harmonics:
            libm += ["sinf", "cosf"]
            body.append(f"    th = theta + {lit(c[8])};")
            for i in range(ff.harm.shape[1]):
                h = ff.harm[:, i]
                if not np.any(h):
                    continue
                body.append(f"    sn = sinf({float(i + 1)!r}f * th);")
                body.append(f"    cs = cosf({float(i + 1)!r}f * th);")
                body.append(f"    ff = ff + (({lit(h[0])} * sn) + ({lit(h[1])} * cs))"
                            f" + sgn * (({lit(h[2])} * sn) + ({lit(h[3])} * cs));")
        body.append("    hat = hat + ff;")
    locals_ = ["float y = 0.0f;", "float u = 0.0f;", "float hat = 0.0f;", "float un;", "float us;", "float tau_m;"]
    if integ is not None:
        locals_.append("float xi;")
    if ff is not None:
        locals_ += ["float sgn;", "float ff;"]
        if ff.has_stribeck:
            locals_.append("float r;")
        if ff.has_harmonics:
            locals_ += ["float th;", "float sn;", "float cs;"]
    saturation = ""
    if math.isfinite(program.tau_max):
        tmax = lit(program.tau_max)
        saturation = (f"    if (tau_m > {tmax}) {{\n        tau_m = {tmax};\n    }} else if (tau_m < -{tmax}) {{\n"
                      f"        tau_m = -{tmax};\n    }}\n")
    values = {
        "version": __version__, "provenance": provenance,
        "rate_hz": repr(float(program.rate_hz)), "rate_hz_c": lit(program.rate_hz),
        "n_sections": str(max(program.n_sections, 1)),
        "has_sections": "1" if program.n_sections > 0 else "0",
        "coefficients": "\n\n".join(coeffs) if coeffs else "/* no filters */",
        "body": "\n".join(body),
        "locals": "\n".join("    " + line for line in locals_),
        "saturation": saturation,
        "includes": (f"#include <math.h> /* {', '.join(libm)}: float versions only */\n" if libm else ""),
        "tau_max_c": lit(program.tau_max) if math.isfinite(program.tau_max) else "0.0f",
        "has_tau_max": "1" if math.isfinite(program.tau_max) else "0",
        "user_init": "    fd_user_init(FD_RATE_HZ);\n" if external is not None else "",
        "user_decl": _USER_DECL if external is not None else "",
    }
    # the pair's identity, checked by the C preprocessor: a header and a source written by two
    # exports (one interrupted during its renames, or copied by hand) do not compile together
    values["export_id"] = "0x" + hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:8]
    header = _render("fd_controller.h.in", **values)
    source = _render("fd_controller.c.in", **values)
    h_path, c_path = out / "fd_controller.h", out / "fd_controller.c"
    files: dict[Path, str | bytes] = {h_path: header, c_path: source}
    if external is not None:
        files[out / USER_SOURCE_NAME] = external
    else:
        stale = out / USER_SOURCE_NAME
        if stale.is_file() and stale.read_bytes().startswith(_USER_BANNER.encode()):
            stale.unlink()     # a previous export's copy of a C controller: this program has none
    atomic_write_set(files)
    return h_path, c_path


#: Name of the user's C controller in an export folder (compiled beside fd_controller.c).
USER_SOURCE_NAME = "fd_user.c"
_USER_BANNER = "/* fd_user.c: copied by forecast-design from "
_USER_DECL = """
/* The force controller is the user's C (fd_user.c; docs/controllers-as-code.md), its state in
 * its own static variables: fd_init() calls fd_user_init(FD_RATE_HZ), fd_step() calls
 * fd_user_step() once per period and adds the compensator's estimate. */
void fd_user_init(float rate_hz);
float fd_user_step(float tau_r, float tau_s, float theta, float q);
"""


def _external_source(program: ControllerProgram, user_source: Any) -> bytes | None:
    """The user's C of an external program, checked against the identity the program (and its blob) records."""
    if not program.external:
        if user_source is not None:
            raise ExportError("a C controller's source was given for a program that computes its own controller")
        return None
    if not program.external.startswith("c sha256:"):
        raise ExportError(f"controller {program.external} runs in Python only: export a C controller (FILE.c) or "
                          "a linear kind for the board")
    if user_source is None:
        raise ExportError(f"the program's controller is C code ({program.external}): give its source file")
    text = Path(user_source).read_bytes()
    if "c sha256:" + hashlib.sha256(text).hexdigest()[:16] != program.external:
        raise ExportError(f"{user_source}: its content is not the C controller the program was built with "
                          f"({program.external}); it changed since")
    return _USER_BANNER.encode() + Path(user_source).name.encode("utf-8", "replace").replace(b"*/", b"* /") + \
        b" (SHA-256 " + hashlib.sha256(text).hexdigest().encode() + b"); do not edit here. */\n" + text


def export_controller(design: Design | None = None, out_dir: str | Path = ".", *,
                      controller: Any = None,
                      compensator: Compensator | str | None = None,
                      env: Any = None, w_q_hz: float | None = None,
                      rate_hz: float = 2000.0,
                      sfm_params: Mapping[str, float] | None = None,
                      tau_max: float = math.inf, testbed: Any = None) -> ExportResult:
    """Discretise a design's force controller and compensator and emit C99.

    Parameters
    ----------
    design : Design, optional
        Base design (default: the Table 1 testbed, environment ``exp-soft``).
    out_dir : str or Path
        Where ``fd_controller.h`` / ``fd_controller.c`` go.
    controller : Controller, str or python-control system, optional
        Overrides the design's controller (anything
        :func:`~forecast_design.controllers.resolve_controller` takes, e.g. ``"pid:6:20:0.05:0.002"``);
        default the paper's PD. It runs with its own discretisation.
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
    sfm_params : Mapping[str, float], optional
        Identified friction for an ``sfm`` compensator (:meth:`Design.with_friction`).
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
        Bad controller/compensator strings, unknown environment, a controller without
        equations, an unstable discretisation.
    """
    if design is not None:
        require_design(design, "export_controller")
    if testbed is not None:
        design = dataclasses.replace(resolve_design(design), testbed=resolve_testbed(testbed))
    if env is not None:
        tb = design.testbed if design is not None else None
        env = resolve_environments(env, testbed=tb).single("export")[1]
    design = resolve_design(design, controller=controller, compensator=compensator, env=env, w_q_hz=w_q_hz)
    design = design.with_friction(sfm_params)
    program = program_for_export(design, rate_hz=rate_hz, tau_max=tau_max)
    user = design.controller.source if isinstance(design.controller, CController) else None
    if user is not None:
        from ..simulation.code import compile_c_controller

        # compiled once with the host compiler (as software in the loop does) before anything is
        # written: a file that does not compile or lacks a symbol is one line here, not at the lab's build
        compile_c_controller(design.controller)
    h, c = emit_c(program, out_dir, user_source=user)
    parts = [h, c] + ([Path(out_dir) / USER_SOURCE_NAME] if user is not None else [])
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in parts)).hexdigest()
    return ExportResult(h, c, program, design, digest, parts[2] if user is not None else None)
