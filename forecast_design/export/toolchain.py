"""Build and run an exported controller: host gcc (stdin/stdout or ctypes) and Cortex-M4 under qemu.

The cross-compile check of the export: ``fd_controller.c`` plus a bare-metal
harness is built with the F446RE's flags (:data:`ARM_CFLAGS`), linked for
qemu's ``mps2-an386`` (a Cortex-M4 with FPU: code and the embedded input
sequence in SSRAM1 at 0x0, data and stack in SSRAM2 at 0x20000000) and run
with semihosting for the output. No newlib start-up or stdio is used: the
harness carries its own vector table, FPU enable, and two semihosting calls
(SYS_WRITE0 for text, SYS_EXIT_EXTENDED for the status), so the only
library code that can be linked is what the controller itself needs
(``sinf``/``cosf`` for SFM harmonics).

Cost per step is measured, not guessed: qemu's ``-icount shift=0`` makes
its virtual clock advance 1 ns per executed instruction and the SysTick
timer, clocked at the board's 25 MHz, counts down on that clock; the
harness reads it around the whole run of ``fd_step`` calls, so
``instructions ~= 40 * ticks``. qemu does not model the Cortex-M4 pipeline
(nor the DWT cycle counter), so cycles are estimated from instructions with
a stated cycles-per-instruction bound (:data:`M4_CPI_BOUND`).

Both builds use ``-ffp-contract=off`` so no multiply-add is fused: the
host and the M4 then round every float operation identically.
"""

from __future__ import annotations

import ctypes
import math
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..controllers.code import C_CONTROLLER_FLAGS
from ..errors import ExportError

__all__ = [
    "HOST_CFLAGS",
    "ARM_CFLAGS",
    "USER_HOST_CFLAGS",
    "USER_ARM_CFLAGS",
    "M4_CLOCK_HZ",
    "M4_CPI_BOUND",
    "ToolPaths",
    "ArmRun",
    "find_tools",
    "build_host",
    "run_host",
    "HostController",
    "build_arm",
    "run_qemu",
    "text_size",
    "undefined_symbols",
    "double_precision_symbols",
    "static_instruction_count",
]

#: Host build flags: strict C99 and no fused multiply-add (bit-identical to the M4).
HOST_CFLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-ffp-contract=off")
#: Nucleo F446RE (Cortex-M4F, single-precision FPU) flags, as the issue states, plus no FMA contraction.
ARM_CFLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-O2", "-Wall",
              "-Wextra", "-Werror", "-std=c99", "-ffp-contract=off")
#: A user's C controller (fd_user.c) is compiled with the export's flags but without -Werror and
#: -pedantic (its warnings do not stop the build), after fd_controller.h (``-include``): its
#: definitions must match the interface's prototypes.
USER_HOST_CFLAGS = C_CONTROLLER_FLAGS
USER_ARM_CFLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", *C_CONTROLLER_FLAGS)
#: Core clock of the F446RE in the paper's set-up [Hz].
M4_CLOCK_HZ = 168e6
#: Cycles per instruction assumed for the estimate [-]: the Cortex-M4 issues most integer and
#: single-precision FPU instructions in 1 cycle, loads/stores in 2 (VLDR/VSTR/LDR), taken
#: branches in 2-4 (no cache: zero-wait-state flash with the ART accelerator); 2 bounds the
#: mix of fd_step (about a third loads/stores) with margin.
M4_CPI_BOUND = 2.0
#: Symbols whose presence means double-precision math was linked: soft-double helpers and the
#: double libm entry points.
_DOUBLE_SYMBOL = re.compile(r"^(__aeabi_d\w+|__aeabi_[fi]2d|__aeabi_d2\w+|__(add|sub|mul|div)df3|__extendsfdf2|"
                            r"__truncdfsf2|(sin|cos|tan|asin|acos|atan|atan2|sinh|cosh|tanh|exp|expm1|log|log1p|"
                            r"log10|pow|sqrt|fabs|floor|ceil|fmod|hypot|copysign|round|trunc)|__ieee754_\w*[^f])$")
_SYSTICK_HZ = 25e6  # mps2-an386 system clock feeding SysTick


@dataclass(frozen=True, slots=True)
class ToolPaths:
    """Executables found on PATH (``None`` when missing).

    Parameters
    ----------
    cc : str or None
        Host C compiler (``cc`` or ``gcc``).
    arm_gcc, arm_size, arm_nm, arm_objdump : str or None
        The arm-none-eabi toolchain.
    qemu : str or None
        ``qemu-system-arm``.
    """

    cc: str | None
    arm_gcc: str | None
    arm_size: str | None
    arm_nm: str | None
    arm_objdump: str | None
    qemu: str | None

    @property
    def arm_ready(self) -> bool:
        """True when the cross toolchain, newlib and qemu are all there."""
        return None not in (self.arm_gcc, self.arm_size, self.arm_nm, self.arm_objdump, self.qemu)


def find_tools() -> ToolPaths:
    """Locate the host compiler, the arm-none-eabi toolchain and qemu-system-arm on PATH."""
    w = shutil.which
    return ToolPaths(w("cc") or w("gcc"), w("arm-none-eabi-gcc"), w("arm-none-eabi-size"), w("arm-none-eabi-nm"),
                     w("arm-none-eabi-objdump"), w("qemu-system-arm"))


def _run(cmd: list[str], what: str, **kw: Any) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(cmd, check=True, capture_output=True, **kw)
    except FileNotFoundError as exc:
        raise ExportError(f"{what}: {cmd[0]} not found") from exc
    except subprocess.CalledProcessError as exc:
        err = exc.stderr.decode("utf-8", "replace") if isinstance(exc.stderr, bytes) else str(exc.stderr)
        raise ExportError(f"{what} failed ({' '.join(cmd[:3])} ...): {err.strip()[:2000]}") from None
    except subprocess.TimeoutExpired:
        raise ExportError(f"{what}: timed out after {kw.get('timeout')} s") from None


# --- host ----------------------------------------------------------------------------------

_HOST_HARNESS = r"""/* host harness: float32 rows (tau_r, tau_s, theta, q) on stdin -> float32 tau_m on stdout */
#include <stdio.h>
#include "fd_controller.h"

int main(void)
{
    static fd_state state;
    float in[4];
    float out;
    fd_init(&state);
    while (fread(in, sizeof(float), 4, stdin) == 4) {
        out = fd_step(&state, in[0], in[1], in[2], in[3]);
        if (fwrite(&out, sizeof(float), 1, stdout) != 1) {
            return 1;
        }
    }
    return 0;
}
"""


def build_host(export_dir: str | Path, *, shared: bool = False, cc: str | None = None) -> Path:
    """Compile ``fd_controller.c`` with the host compiler.

    Parameters
    ----------
    export_dir : str or Path
        Folder holding ``fd_controller.h``/``fd_controller.c``; outputs go there too.
    shared : bool
        ``True``: a shared library for :class:`HostController`; ``False``: an
        executable reading float32 triples on stdin (:func:`run_host`).
    cc : str, optional
        Compiler (default: :func:`find_tools`).

    Returns
    -------
    Path
        The executable or library.

    Raises
    ------
    ExportError
        No compiler, or the code does not compile warning-free.
    """
    d = Path(export_dir)
    cc = cc or find_tools().cc
    if cc is None:
        raise ExportError("no host C compiler (cc/gcc) on PATH")
    pic = ["-fPIC"] if shared else []
    objs = []
    user = d / "fd_user.c"
    if user.is_file():
        # the user's C controller: the export's flags without -Werror/-pedantic (its warnings are its own)
        objs.append(d / "fd_user.host.o")
        _run([cc, *USER_HOST_CFLAGS, *pic, "-include", str(d / "fd_controller.h"), "-c", "-o", str(objs[-1]),
              str(user)], "host compile (fd_user.c)")
    if shared:
        out = d / "libfd_controller.so"
        cmd = [cc, *HOST_CFLAGS, *pic, "-shared", "-o", str(out), str(d / "fd_controller.c"), *map(str, objs), "-lm"]
    else:
        (d / "fd_host_harness.c").write_text(_HOST_HARNESS)
        out = d / "fd_host"
        cmd = [cc, *HOST_CFLAGS, "-o", str(out), str(d / "fd_host_harness.c"), str(d / "fd_controller.c"),
               *map(str, objs), "-lm"]
    _run(cmd, "host compile")
    return out


def _with_q(inputs: np.ndarray) -> np.ndarray:
    """Inputs (n, 3) or (n, 4) as float32 rows (tau_r, tau_s, theta, q): q = 0 when not given."""
    x = np.asarray(inputs, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] not in (3, 4) or x.shape[0] < 1:
        raise ExportError(f"controller inputs must have shape (n >= 1, 3 or 4): tau_r, tau_s, theta[, q], got {x.shape}")
    if x.shape[1] == 3:
        x = np.column_stack([x, np.zeros(x.shape[0], dtype=np.float32)])
    return np.ascontiguousarray(x)


def run_host(exe: str | Path, inputs: np.ndarray) -> np.ndarray:
    """Run a :func:`build_host` executable on ``inputs`` (n, 3 or 4): tau_r [N m], tau_s [N m], theta [rad][, q [rad]].

    Returns
    -------
    ndarray, shape (n,)
        tau_m [N m] (float32 values as float64).
    """
    raw = _with_q(inputs).astype("<f4").tobytes()
    out = _run([str(exe)], "host run", input=raw).stdout
    return np.frombuffer(out, dtype="<f4").astype(float)


class HostController:
    """The compiled C controller, called through ctypes (for closed-loop tests against the simulator).

    Parameters
    ----------
    library : str or Path
        A :func:`build_host` shared library.
    n_sections : int
        ``FD_N_SECTIONS`` of the export (sizes the opaque ``fd_state``).
    """

    def __init__(self, library: str | Path, n_sections: int) -> None:
        self._lib = ctypes.CDLL(str(library))
        self._lib.fd_init.argtypes = [ctypes.c_void_p]
        self._lib.fd_init.restype = None
        self._lib.fd_step.argtypes = [ctypes.c_void_p, ctypes.c_float, ctypes.c_float, ctypes.c_float, ctypes.c_float]
        self._lib.fd_step.restype = ctypes.c_float
        self._n_sections = max(int(n_sections), 1)
        # struct { float z[n][2]; float tau_m_prev, u, hat, xi, e_prev; }: all floats, no padding
        self._state = (ctypes.c_float * (2 * max(int(n_sections), 1) + 5))()
        self.reset()

    def reset(self) -> None:
        """``fd_init``."""
        self._lib.fd_init(ctypes.byref(self._state))

    def step(self, tau_r: float, tau_s: float, theta: float, q: float = 0.0) -> float:
        """``fd_step``: motor torque command [N m] (``q`` the environment angle [rad])."""
        return float(self._lib.fd_step(ctypes.byref(self._state), tau_r, tau_s, theta, q))

    @property
    def u(self) -> float:
        """The last step's controller output ``fd_state.u`` [N m]."""
        return float(self._state[2 * self._n_sections + 1])

    @property
    def hat(self) -> float:
        """The last step's friction estimate ``fd_state.hat`` [N m]."""
        return float(self._state[2 * self._n_sections + 2])


# --- Cortex-M4 under qemu ----------------------------------------------------------------

_LINKER_SCRIPT = """/* mps2-an386: SSRAM1 (code, 4 MB) at 0x0, SSRAM2 (data, 4 MB) at 0x20000000 */
MEMORY
{
  CODE (rx) : ORIGIN = 0x00000000, LENGTH = 4M
  RAM (rwx) : ORIGIN = 0x20000000, LENGTH = 4M
}
ENTRY(fd_reset_handler)
SECTIONS
{
  .text : {
    KEEP(*(.vectors))
    *(.text*)
    *(.rodata*)
    . = ALIGN(4);
  } > CODE
  .ARM.exidx : { *(.ARM.exidx*) } > CODE
  _sidata = LOADADDR(.data);
  .data : { _sdata = .; *(.data*) . = ALIGN(4); _edata = .; } > RAM AT > CODE
  .bss (NOLOAD) : { _sbss = .; *(.bss*) *(COMMON) . = ALIGN(4); _ebss = .; } > RAM
  _estack = ORIGIN(RAM) + LENGTH(RAM);
}
"""

_ARM_HARNESS = r"""/* Cortex-M4 bare-metal harness for qemu mps2-an386: vector table, FPU on, the embedded
 * input sequence through fd_step, outputs as hex float32 bits over semihosting. */
#include <stdint.h>
#include "fd_controller.h"
#include "fd_inputs.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void fd_reset_handler(void);
static void fd_fault_handler(void);

__attribute__((section(".vectors"), used))
static void (*const fd_vectors[16])(void) = {
    (void (*)(void))(&_estack), fd_reset_handler, fd_fault_handler, fd_fault_handler,
    fd_fault_handler, fd_fault_handler, fd_fault_handler, 0, 0, 0, 0,
    fd_fault_handler, fd_fault_handler, 0, fd_fault_handler, fd_fault_handler
};

static int32_t fd_semihost(int32_t op, void *arg)
{
    register int32_t r0 __asm__("r0") = op;
    register void *r1 __asm__("r1") = arg;
    __asm__ volatile ("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

static void fd_exit(int32_t code)
{
    uint32_t block[2];
    block[0] = 0x20026u;  /* ADP_Stopped_ApplicationExit */
    block[1] = (uint32_t)code;
    (void)fd_semihost(0x20, block);  /* SYS_EXIT_EXTENDED */
    for (;;) {
    }
}

static void fd_fault_handler(void)
{
    fd_exit(3);
}

void fd_reset_handler(void)
{
    uint32_t *src = &_sidata;
    uint32_t *dst;
    for (dst = &_sdata; dst < &_edata; ++dst) {
        *dst = *src++;
    }
    for (dst = &_sbss; dst < &_ebss; ++dst) {
        *dst = 0u;
    }
    *(volatile uint32_t *)0xE000ED88u |= 0xFu << 20;  /* CPACR: CP10, CP11 full access */
    __asm__ volatile ("dsb\n\tisb" ::: "memory");
    fd_exit(main());
}

static char fd_buf[4096];
static uint32_t fd_len;

static void fd_flush(void)
{
    fd_buf[fd_len] = '\0';
    if (fd_len > 0u) {
        (void)fd_semihost(0x04, fd_buf);  /* SYS_WRITE0 */
    }
    fd_len = 0u;
}

static void fd_put_hex(uint32_t v)
{
    static const char digits[] = "0123456789abcdef";
    int i;
    if (fd_len + 10u >= sizeof(fd_buf)) {
        fd_flush();
    }
    for (i = 7; i >= 0; --i) {
        fd_buf[fd_len++] = digits[(v >> (4 * i)) & 0xFu];
    }
    fd_buf[fd_len++] = '\n';
}

static float fd_out[FD_N_INPUTS];

int main(void)
{
    static fd_state state;
    volatile uint32_t *const syst = (volatile uint32_t *)0xE000E010u;
    uint32_t t0, t1, i, worst = 0u;
    union { float f; uint32_t u; } bits;
    fd_init(&state);
    syst[1] = 0x00FFFFFFu;  /* RVR */
    syst[2] = 0u;           /* CVR */
    syst[0] = 5u;           /* CSR: enable, core clock, no interrupt */
    t0 = syst[2];
    for (i = 0u; i < FD_N_INPUTS; ++i) {
        fd_out[i] = fd_step(&state, fd_inputs[i][0], fd_inputs[i][1], fd_inputs[i][2], fd_inputs[i][3]);
    }
    t1 = syst[2];
    /* second pass, each step timed alone: the longest step (a data-dependent controller's worst) */
    fd_init(&state);
    for (i = 0u; i < FD_N_INPUTS; ++i) {
        uint32_t a, b;
        syst[2] = 0u;
        a = syst[2];
        (void)fd_step(&state, fd_inputs[i][0], fd_inputs[i][1], fd_inputs[i][2], fd_inputs[i][3]);
        b = syst[2];
        if (((a - b) & 0x00FFFFFFu) > worst) {
            worst = (a - b) & 0x00FFFFFFu;
        }
    }
    syst[0] = 0u;
    for (i = 0u; i < FD_N_INPUTS; ++i) {
        bits.f = fd_out[i];
        fd_put_hex(bits.u);
    }
    fd_buf[fd_len++] = 'M';
    fd_put_hex(worst);
    fd_buf[fd_len++] = 'T';
    fd_put_hex((t0 - t1) & 0x00FFFFFFu);
    fd_flush();
    return 0;
}
"""


def _inputs_header(inputs: np.ndarray) -> str:
    x = _with_q(inputs)
    # SysTick is 24 bits at 40 instructions per tick: ~6.7e8 instructions per run at most
    if x.shape[0] > 200_000:
        raise ExportError(f"harness inputs: at most 200000 steps, got {x.shape[0]}")
    rows = ",\n".join("    {" + ", ".join(float(v).hex() + "f" for v in row) + "}" for row in x)
    return (f"/* {x.shape[0]} input samples (tau_r, tau_s, theta, q), float32 exact (hex literals) */\n"
            f"#define FD_N_INPUTS {x.shape[0]}u\nstatic const float fd_inputs[{x.shape[0]}][4] = {{\n{rows}\n}};\n")


def build_arm(export_dir: str | Path, inputs: np.ndarray, *, tools: ToolPaths | None = None) -> Path:
    """Cross-compile the export and an input-driven harness for qemu's mps2-an386.

    Parameters
    ----------
    export_dir : str or Path
        Folder with ``fd_controller.h``/``.c``; build products go to ``export_dir/arm``.
    inputs : ndarray, shape (n, 3) or (n, 4)
        tau_r [N m], tau_s [N m], theta [rad][, q [rad], 0 when absent] per step (rounded to
        float32, embedded as const).
    tools : ToolPaths, optional
        Default :func:`find_tools`.

    Returns
    -------
    Path
        ``arm/fd_qemu.elf``; ``arm/fd_controller.o`` is the controller alone.

    Raises
    ------
    ExportError
        Missing toolchain, or a warning/error under :data:`ARM_CFLAGS`.
    """
    tools = tools or find_tools()
    if tools.arm_gcc is None:
        raise ExportError("arm-none-eabi-gcc not on PATH (tools/setup.sh --test installs it)")
    d = Path(export_dir)
    b = d / "arm"
    b.mkdir(exist_ok=True)
    (b / "fd_inputs.h").write_text(_inputs_header(inputs))
    (b / "fd_harness.c").write_text(_ARM_HARNESS)
    (b / "mps2_an386.ld").write_text(_LINKER_SCRIPT)
    inc = ["-I", str(d), "-I", str(b)]
    _run([tools.arm_gcc, *ARM_CFLAGS, *inc, "-c", "-o", str(b / "fd_controller.o"), str(d / "fd_controller.c")],
         "arm compile (controller)")
    user = []
    if (d / "fd_user.c").is_file():
        user = [str(b / "fd_user.o")]
        _run([tools.arm_gcc, *USER_ARM_CFLAGS, "-include", str(d / "fd_controller.h"), "-c", "-o", user[0],
              str(d / "fd_user.c")], "arm compile (fd_user.c)")
    # -fno-tree-loop-distribute-patterns: the start-up copy loops must not become memcpy calls
    _run([tools.arm_gcc, *ARM_CFLAGS, "-fno-tree-loop-distribute-patterns", *inc, "-c", "-o",
          str(b / "fd_harness.o"), str(b / "fd_harness.c")], "arm compile (harness)")
    elf = b / "fd_qemu.elf"
    _run([tools.arm_gcc, *ARM_CFLAGS, "-nostartfiles", "--specs=nosys.specs", "-T", str(b / "mps2_an386.ld"),
          "-Wl,--gc-sections", "-o", str(elf), str(b / "fd_harness.o"), str(b / "fd_controller.o"), *user, "-lm"],
         "arm link")
    return elf


@dataclass(frozen=True, slots=True)
class ArmRun:
    """Outputs and measured cost of one qemu run.

    Parameters
    ----------
    outputs : ndarray, shape (n,)
        tau_m [N m] per step (float32 values).
    instructions_per_step : float
        Executed instructions per ``fd_step`` call incl. the call and loop [-]
        (SysTick ticks x 40 under ``-icount shift=0``; resolution 40 / n).
    max_instructions_per_step : float
        The longest single step of the sequence, timed alone, rounded up to the SysTick tick
        (40 instructions) [-]: an upper bound of that step (with the two SysTick reads around it).
    """

    outputs: np.ndarray
    instructions_per_step: float
    max_instructions_per_step: float = math.nan

    @property
    def cycles_per_step_bound(self) -> float:
        """instructions_per_step x :data:`M4_CPI_BOUND` [cycles]."""
        return self.instructions_per_step * M4_CPI_BOUND

    @property
    def max_cycles_per_step_bound(self) -> float:
        """max_instructions_per_step x :data:`M4_CPI_BOUND` [cycles]: against the period's budget."""
        return self.max_instructions_per_step * M4_CPI_BOUND

    def to_mapping(self, rate_hz: float = 2000.0) -> dict[str, Any]:
        """Steps, instructions and the cycle estimate against one control period at ``rate_hz`` [Hz] and 168 MHz."""
        budget = budget_cycles(rate_hz)
        return {"steps": int(self.outputs.size), "instructions_per_step": self.instructions_per_step,
                "max_instructions_per_step": self.max_instructions_per_step,
                "cpi_bound": M4_CPI_BOUND, "cycles_per_step_bound": self.cycles_per_step_bound,
                "max_cycles_per_step_bound": self.max_cycles_per_step_bound,
                "rate_hz": float(rate_hz), "clock_hz": M4_CLOCK_HZ, "budget_cycles_per_period": budget,
                "budget_fraction": self.cycles_per_step_bound / budget,
                "max_budget_fraction": self.max_cycles_per_step_bound / budget}


def run_qemu(elf: str | Path, n_steps: int, *, qemu: str | None = None, timeout: float = 120.0) -> ArmRun:
    """Run a :func:`build_arm` image on qemu-system-arm (mps2-an386, semihosting, ``-icount shift=0``).

    Parameters
    ----------
    elf : str or Path
        The image.
    n_steps : int
        Number of embedded input samples (checks the output length).
    qemu : str, optional
        Executable (default :func:`find_tools`).
    timeout : float
        Wall-clock limit [s].

    Returns
    -------
    ArmRun
        Outputs and instructions per step.

    Raises
    ------
    ExportError
        qemu missing, a non-zero exit (3: a fault handler ran) or malformed output.
    """
    qemu = qemu or find_tools().qemu
    if qemu is None:
        raise ExportError("qemu-system-arm not on PATH (tools/setup.sh --test installs it)")
    with tempfile.TemporaryDirectory(prefix="fd_qemu_") as tmp:
        out_path = Path(tmp) / "semihosting.txt"
        # semihosting output to a file chardev: qemu's stdio console would write to the terminal
        cmd = [qemu, "-M", "mps2-an386", "-display", "none", "-monitor", "none", "-serial", "none",
               "-icount", "shift=0", "-chardev", f"file,id=fdsh,path={out_path}",
               "-semihosting-config", "enable=on,target=native,chardev=fdsh", "-kernel", str(elf)]
        _run(cmd, "qemu run", timeout=timeout, stdin=subprocess.DEVNULL)
        text = out_path.read_text("ascii", "replace") if out_path.exists() else ""
    lines = text.split()
    if not lines or not lines[-1].startswith("T"):
        raise ExportError(f"qemu run: no timing line in the output (last: {lines[-1:]!r})")
    ticks = int(lines[-1][1:], 16)
    if len(lines) < 2 or not lines[-2].startswith("M"):
        raise ExportError(f"qemu run: no longest-step line in the output (got {lines[-2:-1]!r})")
    worst = int(lines[-2][1:], 16)
    words = np.array([int(w, 16) for w in lines[:-2]], dtype=np.uint32)
    if words.size != n_steps:
        raise ExportError(f"qemu run: {words.size} outputs for {n_steps} inputs")
    ns = 1e9 / _SYSTICK_HZ   # 1 instruction = 1 ns of virtual time
    # a step timed alone reads whole ticks of 40 instructions: one more tick bounds it from above
    return ArmRun(words.view(np.float32).astype(float), ticks * ns / n_steps, (worst + 1) * ns)


def text_size(path: str | Path, *, size_tool: str | None = None) -> int:
    """``.text`` size [bytes] of an object or image (arm-none-eabi-size, Berkeley format)."""
    size_tool = size_tool or find_tools().arm_size
    if size_tool is None:
        raise ExportError("arm-none-eabi-size not on PATH")
    out = _run([size_tool, str(path)], "size").stdout.decode().splitlines()
    return int(out[1].split()[0])


def undefined_symbols(path: str | Path, *, nm: str | None = None) -> list[str]:
    """Undefined symbols of an object (``nm -u``)."""
    nm = nm or find_tools().arm_nm
    if nm is None:
        raise ExportError("nm not on PATH")
    return [line.split()[-1] for line in _run([nm, "-u", str(path)], "nm").stdout.decode().splitlines()
            if line.strip()]


def double_precision_symbols(elf: str | Path, *, nm: str | None = None) -> list[str]:
    """Soft-double helpers and double libm functions present in a linked image (should be none).

    Parameters
    ----------
    elf : str or Path
        Linked image (every symbol it contains, defined or not, is checked).
    nm : str, optional
        ``arm-none-eabi-nm``.

    Returns
    -------
    list of str
        Offending symbol names (``__aeabi_dmul``, ``sin``, ``exp``...).
    """
    nm = nm or find_tools().arm_nm
    if nm is None:
        raise ExportError("arm-none-eabi-nm not on PATH")
    names = [line.split()[-1] for line in _run([nm, str(elf)], "nm").stdout.decode().splitlines() if line.strip()]
    return sorted({n for n in names if _DOUBLE_SYMBOL.match(n)})


def static_instruction_count(elf: str | Path, function: str = "fd_step", *, objdump: str | None = None) -> int:
    """Instructions in a function's disassembly (``fd_step`` is loop-free: each runs at most once).

    Parameters
    ----------
    elf : str or Path
        Image or object.
    function : str
        Symbol name.
    objdump : str, optional
        ``arm-none-eabi-objdump``.

    Returns
    -------
    int
        Number of instructions (literal-pool words excluded).
    """
    objdump = objdump or find_tools().arm_objdump
    if objdump is None:
        raise ExportError("arm-none-eabi-objdump not on PATH")
    text = _run([objdump, "-d", "--no-show-raw-insn", str(elf)], "objdump").stdout.decode()
    m = re.search(rf"^[0-9a-f]+ <{re.escape(function)}>:\n(.*?)(?:\n\n|\Z)", text, re.S | re.M)
    if m is None:
        raise ExportError(f"objdump: no function {function} in {elf}")
    n = 0
    for line in m.group(1).splitlines():
        parts = line.split("\t")
        if len(parts) >= 2 and parts[1].strip() and not parts[1].startswith("."):
            n += 1
    return n


def scratch_dir() -> Path:
    """A fresh temporary folder (callers remove it)."""
    return Path(tempfile.mkdtemp(prefix="fd_export_"))


def budget_cycles(rate_hz: float = 2000.0, clock_hz: float = M4_CLOCK_HZ) -> float:
    """Cycles in one control period [cycles]: 84,000 at 2 kHz and 168 MHz."""
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ExportError(f"rate_hz must be > 0, got {rate_hz!r}")
    return clock_hz / rate_hz


def test_sequence(n_steps: int = 20_000, *, rate_hz: float = 2000.0, seed: int = 7, with_q: bool = False) -> np.ndarray:
    """A reproducible closed-loop-like input sequence for equivalence checks.

    Parameters
    ----------
    n_steps : int
        Samples (20,000 = 10 s at 2 kHz).
    rate_hz : float
        Sample rate [Hz].
    seed : int
        Noise seed.

    with_q : bool
        Add the environment angle q [rad] (theta minus a spring deflection tau_s / 4 N m/rad).

    Returns
    -------
    ndarray, shape (n_steps, 3) or (n_steps, 4), float32
        Columns tau_r [N m] (0.2 N m square wave, 1 s period), tau_s [N m] (first-order
        response with noise), theta [rad] (slow sine plus a random walk)[, q [rad]].
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_steps) / rate_hz
    tau_r = np.where((t % 1.0) < 0.5, 0.2, -0.2)
    tau_s = tau_r * (1 - np.exp(-(t % 0.5) / 0.05)) + 1e-3 * rng.normal(size=n_steps)
    theta = 0.3 + 2.0 * np.sin(2 * np.pi * 0.3 * t) + np.cumsum(rng.normal(size=n_steps)) * 1e-4
    cols = [tau_r, tau_s, theta] + ([theta - tau_s / 4.0] if with_q else [])
    return np.column_stack(cols).astype(np.float32)


def check_on_cortex_m4(export_dir: str | Path, *, n_steps: int = 20_000, rate_hz: float = 2000.0) -> dict[str, Any]:
    """Cross-compile an export for the Cortex-M4, run it on qemu and compare with the host build.

    Parameters
    ----------
    export_dir : str or Path
        Folder with ``fd_controller.h``/``.c``.
    n_steps : int
        Length of the :func:`test_sequence` input [samples].
    rate_hz : float
        The export's control rate [Hz]: the period whose cycles are the budget.

    Returns
    -------
    dict
        :meth:`ArmRun.to_mapping` plus ``max_abs_diff_vs_host`` [N m], ``text_bytes``
        (controller object) and ``double_precision_symbols`` (must be empty).

    Raises
    ------
    ExportError
        Missing toolchain or a failed build or run.
    """
    inputs = test_sequence(n_steps, with_q=(Path(export_dir) / "fd_user.c").is_file())
    elf = build_arm(export_dir, inputs)
    run = run_qemu(elf, n_steps)
    host = run_host(build_host(export_dir), inputs.astype(float))
    return {**run.to_mapping(rate_hz), "max_abs_diff_vs_host": float(np.max(np.abs(run.outputs - host))),
            "text_bytes": text_size(Path(export_dir) / "arm" / "fd_controller.o"),
            "double_precision_symbols": double_precision_symbols(elf)}
