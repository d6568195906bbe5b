"""Running a controller written as code in the virtual testbed: Python in-process, C in software in the loop.

:func:`code_runner` turns a :class:`~forecast_design.controllers.PythonController` or
:class:`~forecast_design.controllers.CController` into a runner with the one interface the
simulator calls once per period (``reset(rate_hz, testbed, environment)``,
``step(t, tau_r, tau_s, theta, q) -> u`` [N m]); :func:`run_code_loop` is the period loop of
:func:`~.run.simulate` for them: the same encoder readings, the same compensator, saturation
and command (the design's ``external`` :class:`~forecast_design.program.ControllerProgram`,
whose output slot the code fills), the same delays and plant step as the compiled loop. Each
period is one Python call of the user's ``step`` and one call of a compiled function that runs
the program, logs the period, steps the plant and reads the encoders for the next period
(``benchmarks/RESULTS.md``, "Controllers as code", has the cost per period against the compiled loop).

Software in the loop: the C file is compiled once per content with the host compiler
(:data:`~forecast_design.controllers.code.C_CONTROLLER_FLAGS`) into a shared library called
through ctypes, in float32 as on the board, and the compensator runs in float32 too
(:class:`~forecast_design.program.ProgramStep`, which the exported C reproduces bit for bit):
the commands are those of the firmware's ``fd_step`` with the same code. The file may call
``math.h`` and nothing else of libc (no heap, no I/O); the library's undefined symbols are
checked. Its state lives in static variables: each run loads its own copy of the library.

Faults stop a run safely, as the firmware does: a step that raises, returns NaN or infinity, or
does not return within ``step_timeout_s`` commands zero torque from that period on (the plant
keeps running to the end of the log) and the run records the fault
(:attr:`~.run.SimulationResult.fault`). A Python step that overruns is interrupted; a C step
that never returns is abandoned on its thread (its library stays loaded).
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import os
import re
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..controllers import CController, CodeController, PythonController, load_python_class
from ..controllers.code import C_CONTROLLER_FLAGS, C_CONTROLLER_INTERFACE
from ..errors import ParameterError

__all__ = ["DEFAULT_STEP_TIMEOUT_S", "CodeRunner", "code_runner", "compile_c_controller", "run_code_loop"]

#: Longest a controller step may take before the run stops with a fault [s]. It catches a step
#: that hangs, not one that is slow (a 2 kHz board has 0.5 ms; ``pil`` measures that), and is
#: far above any pause of a loaded machine.
DEFAULT_STEP_TIMEOUT_S = 10.0
# math.h: the only part of libc a controller may call (double and float forms)
_MATH = {f + suffix for f in ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "asinh",
                              "acosh", "atanh", "exp", "exp2", "expm1", "log", "log2", "log10", "log1p", "pow", "sqrt",
                              "cbrt", "hypot", "fabs", "floor", "ceil", "round", "lround", "trunc", "fmod", "remainder",
                              "fmin", "fmax", "fdim", "fma", "copysign", "nearbyint", "rint", "lrint", "ldexp",
                              "frexp", "modf", "erf", "erfc", "tgamma", "lgamma")
         for suffix in ("", "f")}


class StepTimeout(Exception):
    """Raised inside a Python step that ran past its time."""


class CodeRunner:
    """One controller's code, ready to run: ``reset`` before a run, ``step`` once per period.

    Parameters
    ----------
    controller : CodeController
        The code.
    """

    #: Arithmetic of the compensator around it (float32 for C: the board's).
    dtype: Any = np.float64

    def __init__(self, controller: CodeController) -> None:
        self.controller = controller

    def reset(self, rate_hz: float, testbed: Any, environment: Any) -> None:   # pragma: no cover - abstract
        """Before a run (``rate_hz`` [Hz]; the nominal testbed and environment)."""
        raise NotImplementedError

    def step(self, t: float, tau_r: float, tau_s: float, theta: float, q: float) -> float:  # pragma: no cover
        """One period: the controller's output u [N m]."""
        raise NotImplementedError


class _PythonRunner(CodeRunner):
    def __init__(self, controller: PythonController) -> None:
        super().__init__(controller)
        cls = load_python_class(controller)
        try:
            self._obj = cls()
        except Exception as exc:   # noqa: BLE001 - the user's code
            raise ParameterError(f"controller {controller.spelling()}: {controller.class_name}() failed: "
                                 f"{type(exc).__name__}: {exc}", name="controller", value=controller.class_name) from None

    def reset(self, rate_hz: float, testbed: Any, environment: Any) -> None:
        try:
            self._obj.reset(rate_hz, testbed, environment)
        except Exception as exc:   # noqa: BLE001 - the user's code
            raise ParameterError(f"controller {self.controller.spelling()}: reset() failed: {type(exc).__name__}: "
                                 f"{exc}", name="controller", value=self.controller.spelling()) from None

    def step(self, t: float, tau_r: float, tau_s: float, theta: float, q: float) -> float:
        return float(self._obj.step(t, tau_r, tau_s, theta, q))


_COMPILED: dict[str, Path] = {}
_COMPILE_LOCK = threading.Lock()
_FOLDER: list[Path] = []


def _build_folder() -> Path:
    """This process's private build folder (removed at exit): nothing another user wrote is loaded."""
    if not _FOLDER:
        import atexit

        _FOLDER.append(Path(tempfile.mkdtemp(prefix="forecast-design-sil-")))
        atexit.register(shutil.rmtree, _FOLDER[0], True)
    return _FOLDER[0]


def _first_error(stderr: str) -> str:
    for line in stderr.splitlines():
        if "error" in line:
            return line.strip()
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    return lines[0] if lines else "the compiler failed"


def compile_c_controller(controller: CController, *, cc: str | None = None) -> Path:
    """The C controller compiled into a shared library for software in the loop (once per content).

    Parameters
    ----------
    controller : CController
        The file.
    cc : str, optional
        The host compiler (default ``cc`` or ``gcc`` on PATH).

    Returns
    -------
    Path
        The library (in this process's private temporary folder, one per content).

    Raises
    ------
    ParameterError
        An unreadable file or no compiler, the compiler's first error (one line), a missing
        ``fd_user_init``/``fd_user_step``, or a call to libc beyond ``math.h`` (heap, stdio...).
    """
    src = Path(controller.source)
    text = controller.read_source()
    digest = hashlib.sha256(text + " ".join(C_CONTROLLER_FLAGS).encode()).hexdigest()[:16]
    with _COMPILE_LOCK:
        if digest in _COMPILED and _COMPILED[digest].exists():
            return _COMPILED[digest]
        cc = cc or shutil.which("cc") or shutil.which("gcc")
        if cc is None:
            raise ParameterError("a C controller needs a host C compiler (cc or gcc on PATH) for software in the loop",
                                 name="controller", value=str(src))
        folder = _build_folder() / digest
        folder.mkdir(exist_ok=True)
        copy = folder / "fd_user.c"      # compiled from this copy: the file checked is the file built
        copy.write_bytes(text)
        # the interface's prototypes come first, as fd_controller.h does in the export: a definition
        # with other types (double, int...) is a compile error instead of garbage through the call
        interface = folder / "fd_user_interface.h"
        interface.write_text(C_CONTROLLER_INTERFACE.replace("; ", ";\n") + ";\n")
        tmp = folder / f".libfd_user.{os.getpid()}.{threading.get_ident()}.so"
        try:
            proc = subprocess.run([cc, *C_CONTROLLER_FLAGS, "-include", str(interface), "-fPIC", "-shared", "-o",
                                   str(tmp), str(copy), "-lm"], capture_output=True, text=True)
        except OSError as exc:
            raise ParameterError(f"controller {src}: the compiler {cc} did not run: {exc}", name="controller",
                                 value=str(src)) from None
        if proc.returncode != 0:
            first = _first_error(proc.stderr).replace(str(copy), src.name)
            if "conflicting types for" in first:
                first += f" (the interface: {C_CONTROLLER_INTERFACE})"
            raise ParameterError(f"controller {src}: does not compile: {first}", name="controller", value=str(src))
        try:
            _check_symbols(tmp, src)
            lib = folder / "libfd_user.so"
            os.replace(tmp, lib)
        finally:
            tmp.unlink(missing_ok=True)
        _COMPILED[digest] = lib
        return lib


def _check_symbols(lib: Path, src: Path) -> None:
    nm = shutil.which("nm")
    if nm is None:    # pragma: no cover - binutils comes with the compiler
        return
    defined = subprocess.run([nm, "-D", "--defined-only", str(lib)], capture_output=True, text=True).stdout
    names = {line.split()[-1] for line in defined.splitlines() if line.split()}
    for needed in ("fd_user_init", "fd_user_step"):
        if needed not in names:
            raise ParameterError(f"controller {src}: missing symbol {needed} (the interface: {C_CONTROLLER_INTERFACE})",
                                 name="controller", value=needed)
    undefined = subprocess.run([nm, "-D", "--undefined-only", str(lib)], capture_output=True, text=True).stdout
    called = {re.sub(r"@.*$", "", line.split()[-1]) for line in undefined.splitlines() if line.split()}
    foreign = sorted(n for n in called if n not in _MATH and not n.startswith("_"))
    if foreign:
        raise ParameterError(f"controller {src}: calls {', '.join(foreign[:5])} of libc; a controller may use math.h "
                             "only (no heap, no I/O: it runs in the board's 2 kHz interrupt)", name="controller",
                             value=foreign[0])


class _CRunner(CodeRunner):
    dtype = np.float32

    def __init__(self, controller: CController) -> None:
        super().__init__(controller)
        lib = compile_c_controller(controller)
        # a private copy per runner: its static state is this runner's alone (the loader maps one
        # copy per path), and a step abandoned in one run cannot touch the next run's state
        copy = lib.with_name(f".run.{os.getpid()}.{id(self)}.so")
        shutil.copyfile(lib, copy)
        try:
            self._lib = ctypes.CDLL(str(copy))
        finally:
            copy.unlink(missing_ok=True)
        self._lib.fd_user_init.argtypes = [ctypes.c_float]
        self._lib.fd_user_init.restype = None
        self._lib.fd_user_step.argtypes = [ctypes.c_float] * 4
        self._lib.fd_user_step.restype = ctypes.c_float

    def reset(self, rate_hz: float, testbed: Any, environment: Any) -> None:
        self._lib.fd_user_init(float(rate_hz))

    def step(self, t: float, tau_r: float, tau_s: float, theta: float, q: float) -> float:
        return float(self._lib.fd_user_step(tau_r, tau_s, theta, q))


def code_runner(controller: CodeController) -> CodeRunner:
    """A runner of a code controller (module docstring).

    Parameters
    ----------
    controller : PythonController or CController
        The controller.

    Returns
    -------
    CodeRunner
        Ready to ``reset`` and ``step``.

    Raises
    ------
    ParameterError
        A Python class that does not load or construct; a C file that does not compile or
        breaks the interface.
    """
    if isinstance(controller, PythonController):
        return _PythonRunner(controller)
    if isinstance(controller, CController):
        return _CRunner(controller)
    raise ParameterError(f"no runner for controller {controller!r:.60}", name="controller", value=controller)


def _interrupt(thread: threading.Thread) -> None:
    """Raise :class:`StepTimeout` in ``thread`` at its next Python instruction."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread.ident), ctypes.py_object(StepTimeout))


def run_code_loop(prep: Any, runner: CodeRunner, meas: np.ndarray, truth: np.ndarray, *,
                  step_timeout_s: float = DEFAULT_STEP_TIMEOUT_S) -> dict[str, Any] | None:
    """The simulator's period loop with the controller's output from code (module docstring).

    Parameters
    ----------
    prep : _Prepared
        One run of :func:`~.run.simulate`, packed (its program is ``external``: the compensator).
    runner : CodeRunner
        The controller.
    meas, truth : ndarray
        The logs to fill, shapes (n, 6) and (n, 8) as the compiled loop's.
    step_timeout_s : float
        Longest one step may take [s].

    Returns
    -------
    dict or None
        The fault that stopped the controller (``period``, ``t_s``, ``reason``), or None.
    """
    from .plant import I_BL, I_BLC, I_K, history_length
    from .run import _check_kernel_cache, _code_period, _jitter, _reading, _sensors

    if not (step_timeout_s > 0 and math.isfinite(step_timeout_s)):
        raise ParameterError(f"step_timeout_s must be > 0 [s], got {step_timeout_s!r}", name="step_timeout_s",
                             value=step_timeout_s)
    _check_kernel_cache(_code_period)
    rate = prep.rate_hz
    packed = prep.program.pack(runner.dtype)
    state, mem = packed.new_state()
    x = np.zeros(5)
    # the compiled period's arguments after the controller's output: the plant, the program, the logs
    period_args = (prep.substeps, int(prep.plant.delay_substeps), prep.arrays["p"], prep.arrays["harm"], x,
                   prep.enc_step, prep.arrays["jit"], prep.arrays["noise"], prep.k_nominal, prep.arrays["sens"], prep.sensor_gain,
                   *(np.array(a, order="C") for a in packed.arrays()), state, mem, meas, truth,
                   np.zeros(history_length(prep.substeps, prep.plant.delay_substeps)), np.zeros(2))
    runner.reset(rate, prep.ran.testbed, prep.ran.environment)
    par, sens, jit = prep.arrays["p"], prep.arrays["sens"], prep.arrays["jit"]

    def measure(k: int) -> tuple[float, float, float]:      # the readings of period k (the kernel's _sensors)
        return _sensors(float(x[0]), float(x[2]), _jitter(jit, k, 0), _jitter(jit, k, 1), prep.enc_step,
                        prep.k_nominal, sens.shape[0] > 0, prep.sensor_gain,
                        _reading(sens, k) if sens.shape[0] else 0.0, par[I_K], par[I_BL], par[I_BLC])
    ref = prep.ref.tolist()
    n = prep.n
    name = runner.controller.spelling()
    # the loop runs on a worker thread holding `lock` except inside the user's step; this thread
    # watches the step's time and, past the timeout, interrupts it (Python) or abandons it (C)
    shared: dict[str, Any] = {"k": 0, "since": None, "abandoned": False, "fault": None, "crash": None}
    lock = threading.Lock()

    def loop() -> None:
        step, monotonic, period = runner.step, time.monotonic, _code_period
        th, qq, tau_s = measure(0)
        lock.acquire()
        try:
            for k in range(n):
                u, error = 0.0, None
                shared["since"] = monotonic()
                try:
                    try:
                        lock.release()
                        u = step(k / rate, ref[k], tau_s, th, qq)
                        if not math.isfinite(u):
                            error = ValueError(f"step returned {u!r}")
                    except StepTimeout:
                        raise
                    except BaseException as exc:   # noqa: BLE001 - any failure of the user's code stops the run
                        error = exc
                    finally:
                        lock.acquire()
                    shared["since"] = None
                except StepTimeout as exc:
                    # the watchdog's interrupt lands in the step or, at the latest, right after the
                    # lock is taken back: the lock is held here either way
                    error = exc
                    shared["since"] = None
                if shared["abandoned"]:
                    return
                if error is not None:
                    why = (f"step did not return within {step_timeout_s:g} s" if isinstance(error, StepTimeout)
                           else f"{type(error).__name__}: {error}")
                    shared["fault"] = {"period": k, "t_s": k / rate, "reason": f"controller {name}: {why}"}
                    return
                th, qq, tau_s = period(k, th, qq, tau_s, u, ref[k], False, *period_args)
                shared["k"] = k + 1
        except BaseException as exc:   # noqa: BLE001 - the simulator's own failure: raised again below
            shared["crash"] = exc
        finally:
            lock.release()

    worker = threading.Thread(target=loop, name="forecast-design-controller", daemon=True)
    worker.start()
    interrupted_at = None
    while worker.is_alive():
        worker.join(0.05)
        since = shared["since"]
        if since is None or time.monotonic() - since <= step_timeout_s:
            continue
        if interrupted_at is not None and time.monotonic() - interrupted_at <= step_timeout_s:
            continue
        with lock:      # held by the worker except inside the step
            if shared["since"] is not since or not worker.is_alive():
                continue
            if isinstance(runner, _PythonRunner) and interrupted_at is None:
                interrupted_at = time.monotonic()
                _interrupt(worker)
                continue
            shared["abandoned"] = True
            k = shared["k"]
            shared["fault"] = {"period": k, "t_s": k / rate, "reason": f"controller {name}: step did not return "
                               f"within {step_timeout_s:g} s (abandoned)"}
            break
    if shared["crash"] is not None:
        raise shared["crash"]
    fault = shared["fault"]
    # after a fault: zero torque to the end of the log, the plant running on (the firmware's safe stop)
    k = shared["k"]
    th, qq, tau_s = measure(k)
    for k in range(shared["k"], n):
        th, qq, tau_s = _code_period(k, th, qq, tau_s, 0.0, 0.0, True, *period_args)
    return fault
