"""Bare-metal firmware for the Nucleo F446RE: the exported controller inside a 2 kHz loop with encoders,
the ESCON torque output and the serial protocol (docs/firmware.md).

:func:`export_firmware` writes a complete project folder (start-up code, linker script, register map,
drivers, protocol, the generated ``fd_controller.c``, ``fd_config.h`` and a Makefile) that
``make`` builds with ``arm-none-eabi-gcc`` alone into ``build/fd_firmware.elf``/``.bin`` (the board)
and ``make pil`` into ``build/fd_pil.elf`` (processor-in-the-loop on qemu's ``netduinoplus2``,
:mod:`forecast_design.runtime.pil`). The compiler flags are :data:`.toolchain.ARM_CFLAGS`.
"""

from __future__ import annotations

import hashlib
import math
import subprocess
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import ExportError, OutputError, ParameterError
from ..fileio import atomic_write_set, staged_set, verify_manifest
from ..params import BOARDS, OUTPUT_STAGES, Compensator, Design
from ..program import ControllerProgram
from .c import c_float_literal, export_controller
from .toolchain import ARM_CFLAGS, M4_CLOCK_HZ, USER_ARM_CFLAGS

__all__ = ["BOARDS", "OUTPUT_STAGES", "FirmwareOptions", "FirmwareResult", "export_firmware", "build_firmware",
           "sensor_counts", "firmware_measurements", "firmware_reference", "TEMPLATE_FILES", "code_cycle_check", "CYCLE_WARNING_FRACTION"]

#: Static sources copied verbatim from ``templates/firmware``.
TEMPLATE_FILES = ("Makefile", "stm32f446re.ld", "startup.c", "fd_app.c", "fd_drivers.c", "fd_drivers.h",
                  "fd_protocol.c", "fd_protocol.h", "fd_reference.c", "fd_reference.h", "fd_regs.h")
_PCLK1_HZ = int(M4_CLOCK_HZ) // 4   # APB1 = 168 MHz / 4 (fd_clock_init)
_TIMER_CLOCK_HZ = 2 * _PCLK1_HZ     # APB1 timers run at 2 x PCLK1 when the APB1 prescaler is not 1


def _default_counts() -> int:
    from ..simulation import ENCODER_COUNTS   # the simulator's encoder: PIL quantises like it

    return int(ENCODER_COUNTS)


@dataclass(frozen=True, slots=True)
class FirmwareOptions:
    """What the board firmware needs beyond the controller.

    Parameters
    ----------
    board : str
        One of :data:`BOARDS`.
    output : str
        ``dac`` (ESCON analog set value from DAC1 on PA4) or ``pwm`` (PWM set value, TIM3 CH1 on PA6).
    tau_limit_N_m : float
        Torque limit [N m]: the exported controller saturates there and the firmware clamps again.
    tau_full_scale_N_m : float
        Motor torque at the ESCON's full-scale set value (k_t x gear ratio x the current range set
        in ESCON Studio) [N m]; must be >= ``tau_limit_N_m``.
    pwm_hz : float
        PWM frequency of the ``pwm`` output [Hz] (the ESCON 50/5 accepts 10 Hz .. 5 kHz).
    link_timeout_ms : float
        Host silence during a run that zeroes the torque and reports LINK_TIMEOUT [ms].
    garbage_limit_bytes : int
        Bytes rejected in a row (since the last intact frame) that count as a link beyond
        resynchronisation (LINK_CORRUPT) [bytes].
    encoder_counts : int or None
        Counts per revolution after x4 decoding; default the simulator's (DHO-05, 2,000,000).
    encoder_jump_counts : int
        Largest plausible encoder motion in one period (ENCODER fault above) [counts].
    """

    board: str = "nucleo-f446re"
    output: str = "dac"
    tau_limit_N_m: float = 1.0
    tau_full_scale_N_m: float = 2.0
    pwm_hz: float = 4000.0
    link_timeout_ms: float = 100.0
    garbage_limit_bytes: int = 64
    encoder_counts: int | None = None
    encoder_jump_counts: int = 100_000

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ParameterError:
            return ParameterError(f"firmware option {name}: {why}, got {getattr(self, name)!r}", name=name,
                                  value=getattr(self, name))

        if self.board not in BOARDS:
            raise bad("board", f"expected one of {', '.join(BOARDS)}")
        if self.output not in OUTPUT_STAGES:
            raise bad("output", f"expected one of {', '.join(OUTPUT_STAGES)}")
        for name in ("tau_limit_N_m", "tau_full_scale_N_m", "pwm_hz", "link_timeout_ms"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise bad(name, "must be a finite number > 0")
        if self.tau_full_scale_N_m < self.tau_limit_N_m:
            raise bad("tau_full_scale_N_m", f"must be >= tau_limit_N_m = {self.tau_limit_N_m!r}")
        if not 10.0 <= self.pwm_hz <= 5000.0:
            raise bad("pwm_hz", "the ESCON PWM set value takes 10 .. 5000 Hz")
        counts = self.encoder_counts if self.encoder_counts is not None else _default_counts()
        if not (isinstance(counts, int) and 4 <= counts < 2**31):
            raise bad("encoder_counts", "must be an integer in [4, 2**31)")
        object.__setattr__(self, "encoder_counts", counts)
        for name in ("garbage_limit_bytes", "encoder_jump_counts"):
            v = getattr(self, name)
            if not (isinstance(v, int) and 0 < v < 2**31):
                raise bad(name, "must be an integer in [1, 2**31)")

    @property
    def rad_per_count(self) -> float:
        """Encoder resolution [rad/count]."""
        return 2.0 * math.pi / self.encoder_counts

    def to_mapping(self) -> dict[str, Any]:
        """The options as plain values."""
        return asdict(self)


@dataclass(frozen=True, slots=True)
class FirmwareResult:
    """What :func:`export_firmware` wrote.

    Parameters
    ----------
    out_dir : pathlib.Path
        The project folder (``make`` there builds it).
    program : ControllerProgram
        The exported controller (saturating at the torque limit).
    design : Design
        Testbed, environment, controller and compensator.
    options : FirmwareOptions
        Board settings.
    digest : str
        SHA-256 over every file written [hex].
    files : tuple of str
        File names written, sorted.
    cycles : dict or None
        A C controller's measured cost (:func:`code_cycle_check`); None otherwise.
    """

    out_dir: Path
    program: ControllerProgram
    design: Design
    options: FirmwareOptions
    digest: str
    files: tuple[str, ...]
    cycles: Mapping[str, Any] | None = None

    def to_mapping(self) -> dict[str, Any]:
        """Summary for ``--json``."""
        return {"out_dir": str(self.out_dir), "board": self.options.board, "options": self.options.to_mapping(),
                "external_controller": self.program.external or None,
                "controller_cycles": None if self.cycles is None else dict(self.cycles),
                "files": list(self.files), "sha256": self.digest, "rate_hz": self.program.rate_hz,
                "n_sections": self.program.n_sections, "tau_max_N_m": self.program.tau_max,
                "controller": None if self.design.controller is None else self.design.controller.to_mapping(),
                "compensator": (self.design.compensator or Compensator()).to_mapping(),
                "testbed": self.design.testbed.to_mapping(), "environment": self.design.environment.to_mapping(),
                "build": "make (board: build/fd_firmware.elf, .bin); make pil (qemu netduinoplus2: build/fd_pil.elf)"}


def _config_header(program: ControllerProgram, design: Design, opt: FirmwareOptions) -> str:
    rate = program.rate_hz
    if abs(rate - round(rate)) > 0 or not 100 <= rate <= 20_000 or (M4_CLOCK_HZ / rate) % 1:
        raise ExportError(f"firmware rate_hz must be a whole number of Hz dividing {M4_CLOCK_HZ:.0f} "
                          f"(100 .. 20000), got {rate!r}")
    k = design.testbed.k
    lines = [
        "/* fd_config.h: generated by forecast-design; do not edit. Board settings of this export. */",
        "#ifndef FD_CONFIG_H", "#define FD_CONFIG_H", "", "#include <stdint.h>", "",
        "#ifndef FD_PIL", "#define FD_PIL 0   /* 1: processor-in-the-loop build (make pil) */", "#endif",
        f'#define FD_BOARD "{opt.board}"',
        f"#define FD_CORE_HZ {int(M4_CLOCK_HZ)}u        /* SYSCLK [Hz] */",
        f"#define FD_PCLK1_HZ {_PCLK1_HZ}u        /* APB1, USART2 clock [Hz] */",
        "#define FD_BAUD 2000000u           /* USART2 [bit/s]: docs/protocol.md */",
        f"#define FD_RATE_HZ_U {int(round(rate))}u         /* control rate [Hz] */",
        f"#define FD_SYSTICK_LOAD {int(M4_CLOCK_HZ / rate) - 1}u     /* SysTick reload: one period */",
        f"#define FD_COUNTS_PER_REV {opt.encoder_counts}  /* after x4 decoding */",
        f"#define FD_RAD_PER_COUNT {c_float_literal(opt.rad_per_count)}   /* 2 pi / counts [rad] */",
        f"#define FD_K_RAD_PER_COUNT {c_float_literal(k * opt.rad_per_count)}   /* k 2 pi / counts, k = {k!r} N m/rad */",
        f"#define FD_LOCKED {1 if design.environment.locked else 0}     /* 1: q = 0 (locked output) */",
        f"#define FD_TAU_LIMIT {c_float_literal(opt.tau_limit_N_m)}   /* torque limit [N m] */",
        f"#define FD_TAU_FULL_SCALE {c_float_literal(opt.tau_full_scale_N_m)}   /* torque at full-scale set value [N m] */",
        f"#define FD_OUTPUT_PWM {1 if opt.output == 'pwm' else 0}      /* 0: DAC on PA4, 1: PWM on PA6 */",
        f"#define FD_PWM_ARR {int(round(_TIMER_CLOCK_HZ / opt.pwm_hz)) - 1}u    /* TIM3 at 84 MHz: {opt.pwm_hz!r} Hz */",
        "#define FD_PIN_ENABLE 8u          /* PA8 (D7): ESCON enable */",
        "#define FD_PIN_LED 5u             /* PA5: LD2 */",
        f"#define FD_LINK_TIMEOUT_TICKS {max(1, int(math.ceil(opt.link_timeout_ms * rate / 1000.0)))}u "
        f"  /* {opt.link_timeout_ms!r} ms of host silence */",
        f"#define FD_GARBAGE_LIMIT {opt.garbage_limit_bytes}u   /* bytes rejected in a row */",
        f"#define FD_ENCODER_JUMP_LIMIT {opt.encoder_jump_counts}   /* counts per period */",
        f"#define FD_BLOB_SIZE {len(program.to_bytes())}u", "",
        "/* the controller this firmware runs, as the host uploads it (docs/protocol.md, UPLOAD) */",
        "extern const uint8_t fd_blob[FD_BLOB_SIZE];", "", "#endif /* FD_CONFIG_H */", ""]
    return "\n".join(lines)


def _blob_source(program: ControllerProgram) -> str:
    blob = program.to_bytes()
    rows = ",\n".join("    " + ", ".join(f"0x{b:02x}u" for b in blob[i:i + 12]) for i in range(0, len(blob), 12))
    return ("/* fd_blob.c: generated by forecast-design; do not edit. The UPLOAD blob of the exported\n"
            " * controller: the firmware accepts an upload equal to it (tau_max, bytes 8..11, may differ). */\n"
            f'#include "fd_config.h"\n\nconst uint8_t fd_blob[FD_BLOB_SIZE] = {{\n{rows}\n}};\n')


#: A C controller whose longest measured step needs more than this share of the period is exported
#: with a warning (above the whole period it is refused) [-].
CYCLE_WARNING_FRACTION = 0.5


def code_cycle_check(design: Design | None = None, *, controller: Any = None, compensator: Any = None,
                     env: Any = None, w_q_hz: float | None = None, rate_hz: float = 2000.0,
                     sfm_params: Mapping[str, float] | None = None, tau_max: float = math.inf,
                     testbed: Any = None, n_steps: int = 4000) -> dict[str, Any]:
    """The cost of a C controller's ``fd_step`` on the Cortex-M4 against the period's cycle budget.

    The export (generated compensator and the user's ``fd_user.c``) is cross-compiled with the
    board's flags in a scratch folder and run on qemu (mps2-an386, ``-icount``) over
    :func:`~.toolchain.test_sequence` (with ``q``): the mean and the longest step are measured in
    instructions and bounded in cycles at :data:`~.toolchain.M4_CPI_BOUND` cycles per instruction;
    the outputs are compared with the same C built for the host (software in the loop).

    Parameters
    ----------
    design, controller, compensator, env, w_q_hz, rate_hz, sfm_params, tau_max, testbed
        As :func:`~forecast_design.export.c.export_controller`.
    n_steps : int
        Length of the input sequence [periods].

    Returns
    -------
    dict
        :meth:`~.toolchain.ArmRun.to_mapping` plus ``max_abs_diff_vs_host`` [N m], ``budget_cycles_per_period``
        at ``rate_hz``, ``verdict`` (``ok``, ``warning``: the longest step above
        :data:`CYCLE_WARNING_FRACTION` of the period, ``over``: above the period) and
        ``inputs`` (what the cost was measured on); or ``{"measured": False, "why": ...}``
        without the cross toolchain and qemu.
    """
    import shutil

    from .toolchain import check_on_cortex_m4, find_tools, scratch_dir

    tools = find_tools()
    if not tools.arm_ready:
        return {"measured": False, "why": "no arm-none-eabi toolchain and qemu-system-arm on PATH "
                                          "(tools/setup.sh --test installs them)"}
    tmp = scratch_dir()
    try:
        export_controller(design, tmp, controller=controller, compensator=compensator, env=env, w_q_hz=w_q_hz,
                          rate_hz=rate_hz, sfm_params=sfm_params, tau_max=tau_max, testbed=testbed)
        m = check_on_cortex_m4(tmp, n_steps=n_steps, rate_hz=rate_hz)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    budget = m["budget_cycles_per_period"]       # the period at the export's rate
    worst = m["max_cycles_per_step_bound"]
    verdict = "over" if worst > budget else ("warning" if worst > CYCLE_WARNING_FRACTION * budget else "ok")
    return {"measured": True, **m, "verdict": verdict,
            "inputs": f"test_sequence({n_steps}): 0.2 N m square reference, first-order tau_s with noise, "
                      "slow theta; a data-dependent controller may take longer on other inputs"}


def export_firmware(design: Design | None = None, out_dir: str | Path = ".", *,
                    controller: Any = None, compensator: Compensator | str | None = None,
                    env: Any = None, w_q_hz: float | None = None, rate_hz: float = 2000.0,
                    sfm_params: Mapping[str, float] | None = None,
                    options: FirmwareOptions | None = None, testbed: Any = None,
                    check_cycles: bool = True) -> FirmwareResult:
    """Write the bare-metal firmware project for the Nucleo F446RE.

    Parameters
    ----------
    design : Design, optional
        Base design (default: Table 1 testbed, ``exp-soft``).
    out_dir : str or Path
        Project folder (created).
    controller, compensator, env, w_q_hz, rate_hz, sfm_params, testbed
        As :func:`forecast_design.export.c.export_controller`.
    options : FirmwareOptions, optional
        Board settings (output stage, torque limit and scaling, link timeout...).
    check_cycles : bool
        For a controller written in C (``FILE.c``, linked as ``fd_user.c``): measure its cost
        first (:func:`code_cycle_check`) and refuse a step longer than the period.

    Returns
    -------
    FirmwareResult
        Folder, program, design, options, a digest of the files and, for a C controller, its
        measured cost.

    Raises
    ------
    ParameterError
        Bad design options; ExportError for a rate the SysTick cannot divide, or a C controller
        whose longest measured step exceeds the period's cycle budget.
    """
    from ..controllers import CController, resolve_controller

    opt = options or FirmwareOptions()
    out = Path(out_dir)
    cycles = None
    code = resolve_controller(controller) if controller is not None else (design.controller if design else None)
    if check_cycles and isinstance(code, CController):
        cycles = code_cycle_check(design, controller=controller, compensator=compensator, env=env, w_q_hz=w_q_hz,
                                  rate_hz=rate_hz, sfm_params=sfm_params, tau_max=opt.tau_limit_N_m,
                                  testbed=testbed)
        if cycles.get("verdict") == "over":
            raise ExportError(f"controller {code.source}: its longest step takes up to "
                              f"{cycles['max_cycles_per_step_bound']:.0f} cycles "
                              f"({cycles['max_instructions_per_step']:.0f} instructions x CPI "
                              f"{cycles['cpi_bound']:g}) of the {cycles['budget_cycles_per_period']:.0f} in a {rate_hz:g} Hz "
                              "period: it would overrun on the board (fault OVERRUN); make it cheaper or lower the rate")
    # One project, one unit: every file is written into a staging folder and swapped in with the
    # manifest last (fileio.staged_set); the Makefile refuses to build without a matching manifest,
    # so a kill never leaves new controller sources beside an old fd_blob.c that still builds.
    with staged_set(out) as staging:
        res = export_controller(design, staging, controller=controller, compensator=compensator, env=env,
                                w_q_hz=w_q_hz, rate_hz=rate_hz, sfm_params=sfm_params,
                                tau_max=opt.tau_limit_N_m, testbed=testbed)
        texts: dict[str, str] = {}
        src = resources.files("forecast_design.export").joinpath("templates", "firmware")
        for name in TEMPLATE_FILES:
            texts[name] = src.joinpath(name).read_text("utf-8")
        texts["fd_config.h"] = _config_header(res.program, res.design, opt)
        texts["fd_blob.c"] = _blob_source(res.program)
        texts["config.mk"] = ("# generated by forecast-design: the export's Cortex-M4F flags "
                              "(forecast_design.export.toolchain.ARM_CFLAGS; USER_ARM_CFLAGS for a C controller)\n"
                              "CFLAGS = " + " ".join(ARM_CFLAGS) + "\nUSER_CFLAGS = " + " ".join(USER_ARM_CFLAGS) + "\n")
        atomic_write_set({staging / name: text for name, text in texts.items()})
        names = sorted([*texts, res.header.name, res.source.name]
                       + ([res.user_source.name] if res.user_source is not None else []))
        digest = hashlib.sha256(b"".join((staging / n).read_bytes() for n in names)).hexdigest()
    return FirmwareResult(out, res.program, res.design, opt, digest, tuple(names), cycles)


def build_firmware(out_dir: str | Path, target: str = "board", *, timeout: float = 300.0) -> Path:
    """Run ``make`` (board) or ``make pil`` in an exported firmware folder.

    Parameters
    ----------
    out_dir : str or Path
        A folder written by :func:`export_firmware`.
    target : str
        ``board`` (``build/fd_firmware.elf`` and ``.bin``) or ``pil`` (``build/fd_pil.elf``).
    timeout : float
        Wall-clock limit [s].

    Returns
    -------
    Path
        The ``.elf`` image.

    Raises
    ------
    ExportError
        ``make`` or the toolchain missing, or a warning/error (``-Werror``) in the build.
    """
    if target not in ("board", "pil"):
        raise ParameterError(f"firmware target must be board or pil, got {target!r}", name="target", value=target)
    d = Path(out_dir)
    try:
        verify_manifest(d)      # a complete project, not an interrupted export (the Makefile checks it too)
    except OutputError as exc:
        raise ExportError(f"firmware build: {exc}") from None
    cmd = ["make", "-j2", "-C", str(d)] + (["pil"] if target == "pil" else [])
    try:
        subprocess.run(cmd, check=True, capture_output=True, timeout=timeout)
    except FileNotFoundError:
        raise ExportError("make not on PATH (Debian package make)") from None
    except subprocess.CalledProcessError as exc:
        err = (exc.stderr or b"").decode("utf-8", "replace").strip()
        raise ExportError(f"firmware build ({' '.join(cmd[1:])}) failed: {err[-2000:]}") from None
    except subprocess.TimeoutExpired:
        raise ExportError(f"firmware build: timed out after {timeout} s") from None
    return d / "build" / ("fd_pil.elf" if target == "pil" else "fd_firmware.elf")


def sensor_counts(angle: float, rad_per_count: float) -> int:
    """The encoder count of a quantised angle (the virtual testbed's encoders give whole counts) [-]."""
    return int(math.floor(angle / rad_per_count + 0.5))


def firmware_reference(reference: Any, n: int, rate_hz: float) -> np.ndarray:
    """The force reference of periods ``0..n-1`` exactly as the firmware generates it (float32).

    ``fd_reference_value`` in fd_reference.c counts whole periods when the reference's period is a
    whole number of samples (a square's edges then fall on exact indices) and otherwise works on
    ``t = index / rate`` in float32; the host's float64 signal can put an edge one sample apart
    (``0.075 / 0.05`` is 1.4999999999999998). Software in the loop uses these values so that it
    and the firmware see the same reference (a sine's ``sinf`` may still differ by one float32
    step between libms).

    Parameters
    ----------
    reference : forecast_design.runtime.protocol.Reference
        ``kind`` (step, square, sine), ``amplitude`` [N m], ``period`` [s], ``offset`` [N m].
    n : int
        Number of periods.
    rate_hz : float
        Control rate [Hz].

    Returns
    -------
    ndarray of float32, shape (n,)
        tau_r [N m] per period.
    """
    f = np.float32
    index = np.arange(n, dtype=np.uint32)
    rate, period = f(rate_hz), f(reference.period)
    amplitude, offset = f(reference.amplitude), f(reference.offset)
    per = f(period * rate)
    whole = np.uint32(f(per + f(0.5)))
    samples = int(whole) if abs(f(per - f(whole))) < f(1.0e-3) else 0
    t = index.astype(f) / rate
    if reference.kind == "square":
        if samples > 0:
            high = 2 * (index % np.uint32(samples)) < samples
        else:
            cycles = t / period
            high = (cycles - cycles.astype(np.uint32).astype(f)) < f(0.5)
        return np.where(high, f(offset + amplitude), f(offset - amplitude)).astype(f)
    if reference.kind == "sine":
        return (offset + amplitude * np.sin(f(6.28318531) * (t / period))).astype(f)
    on = index >= samples if (samples > 0 or period == 0.0) else t >= period
    return np.where(on, f(offset + amplitude), offset).astype(f)


def firmware_measurements(count_m: int, count_e: int, rad_per_count: float, k: float,
                          locked: bool) -> tuple[float, float, float]:
    """``theta``, ``q``, ``tau_s`` exactly as the firmware computes them in float32 from encoder counts.

    Parameters
    ----------
    count_m, count_e : int
        Motor and environment counts since the start of the run [-].
    rad_per_count : float
        Encoder resolution [rad].
    k : float
        Spring stiffness [N m/rad].
    locked : bool
        Locked output (q = 0, tau_s = k theta).

    Returns
    -------
    tuple of float
        theta [rad], q [rad], tau_s [N m], each a float32 value (``fd_period`` in fd_app.c).
    """
    f = np.float32
    step, k_step = f(rad_per_count), f(k * rad_per_count)
    theta = f(f(count_m) * step)
    if locked:
        return float(theta), 0.0, float(f(f(count_m) * k_step))
    return float(theta), float(f(f(count_e) * step)), float(f(f(count_m - count_e) * k_step))
