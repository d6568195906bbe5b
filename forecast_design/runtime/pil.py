"""Processor-in-the-loop: the board firmware on qemu (netduinoplus2), the virtual testbed on the host.

Each period the host measures the virtual testbed (the simulator's own
:class:`~forecast_design.simulation.plant.PlantStepper`), sends the raw encoder counts in a SENSOR
frame over the firmware's USART2 (a qemu pseudo-terminal), and applies the torque of the SAMPLE the
firmware answers with. The run is recorded in the experiment format like a hardware run.
:func:`python_closed_loop` runs the same loop with the controller in Python (the reference the PIL
run must match).
"""

from __future__ import annotations

import math
import os
import select
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import ExportError, ParameterError
from ..export.firmware import (FirmwareOptions, build_firmware, export_firmware, firmware_measurements,
                               firmware_reference, sensor_counts)
from ..export.toolchain import M4_CLOCK_HZ, budget_cycles, find_tools
from ..params import Design
from ..simulation import plant_stepper
from ..simulation.run import DEFAULT_PROCESS_NOISE_STD
from . import protocol as pr
from .board import Board, _save_with_recovery, check_writable, record_to_experiment
from .link import BoardError, LinkError

__all__ = ["PIL_LINK_TIMEOUT_MS", "PilFaults", "PilResult", "QemuBoard", "qemu_available", "run_pil", "pil_session",
           "python_closed_loop", "COUNT_OFFSET", "run_pil_scenario", "scenario_reference"]

#: Raw counts start here (mod 2**32), so the firmware's 32-bit counters wrap within the first periods.
COUNT_OFFSET = 2**32 - 3
#: The firmware's link timeout under PIL [ms]. The desktop host is not real-time: while it stalls, the
#: firmware polls the link and qemu -icount counts those instructions as virtual time (measured: a 20 s
#: host stall passes the board's 100 ms, a 3 s one does not); a loaded CI machine stalls that long.
PIL_LINK_TIMEOUT_MS = 10_000.0

#: Signals of a run by name, as the SAMPLE frame carries them (PilResult.arrays, python_closed_loop).
_SIGNALS = ("tau_m", "theta", "q", "tau_s", "tau_r", "u", "tau_frc_hat")


def qemu_available() -> str | None:
    """None when qemu-system-arm, arm-none-eabi-gcc and make are there, else the reason (one line)."""
    tools = find_tools()
    if tools.qemu is None:
        return "qemu-system-arm not on PATH (Debian package qemu-system-arm; tools/setup.sh --test)"
    if tools.arm_gcc is None:
        return "arm-none-eabi-gcc not on PATH (Debian package gcc-arm-none-eabi; tools/setup.sh --test)"
    if shutil.which("make") is None:
        return "make not on PATH (Debian package make)"
    return None


@dataclass(frozen=True, slots=True)
class PilFaults:
    """Faults the host injects on the PIL link (each at a period index; None: off).

    Parameters
    ----------
    garbage_at : int or None
        Before this period's SENSOR frame, send ``garbage_bytes`` bytes that hold no frame.
    garbage_bytes : int
        Length of that garbage [bytes].
    drop_at : int or None
        Never send this period's SENSOR frame (the next one follows).
    silent_at : int or None
        Stop sending at this period (a silent host).
    seed : int
        Seed of the garbage bytes.
    """

    garbage_at: int | None = None
    garbage_bytes: int = 200
    drop_at: int | None = None
    silent_at: int | None = None
    seed: int = 0


@dataclass(frozen=True, slots=True)
class PilResult:
    """One PIL run.

    Parameters
    ----------
    samples : int
        SAMPLE frames received (one per period run) [-].
    expected : int
        Periods requested [-].
    fault : str or None
        The fault the firmware reported (torque zero), if any.
    fault_index : int or None
        Sample index at which it was detected.
    fault_latency_s : float or None
        Wall-clock time from the injected fault (the last host frame) to the FAULT frame [s].
    stats : dict or None
        The firmware's STATS: ticks per period and the instruction calibration.
    instructions_per_step : float or None
        Mean executed instructions per control period (qemu ``-icount``; None without it).
    path : str or None
        The experiment written.
    arrays : dict of ndarray
        Recorded signals by name (``tau_m``, ``theta``, ``q``, ``tau_s``, ``tau_r``, ``u``, ``tau_frc_hat``).
    rate_hz : float
        The firmware's control rate [Hz] (the period whose cycles are the budget).
    """

    samples: int
    expected: int
    fault: str | None
    fault_index: int | None
    fault_latency_s: float | None
    stats: dict | None
    instructions_per_step: float | None
    path: str | None
    arrays: dict
    rate_hz: float = 2000.0

    def to_mapping(self) -> dict[str, Any]:
        """Summary for ``--json`` (without the arrays)."""
        budget = budget_cycles(self.rate_hz)     # one control period at the firmware's rate
        ips = self.instructions_per_step
        worst = self.stats.get("max_instructions_per_step") if (self.stats and ips is not None) else None
        return {"samples": self.samples, "expected": self.expected, "fault": self.fault,
                "fault_index": self.fault_index, "fault_latency_s": self.fault_latency_s, "stats": self.stats,
                "instructions_per_step": ips, "max_instructions_per_step": worst,
                "rate_hz": self.rate_hz, "clock_hz": M4_CLOCK_HZ, "budget_cycles_per_period": budget,
                "budget_fraction_at_cpi_2": None if ips is None else 2.0 * ips / budget,
                "max_budget_fraction_at_cpi_2": None if worst is None else 2.0 * worst / budget, "path": self.path}


class QemuBoard:
    """qemu-system-arm running a firmware image on ``netduinoplus2`` with USART2 on a pseudo-terminal.

    Parameters
    ----------
    elf : str or Path
        A ``make pil`` image.
    icount : bool
        Run with ``-icount shift=0`` (1 instruction = 1 ns of virtual time: the firmware's SysTick then
        counts instructions; the link timeout runs on that slower virtual clock).
    """

    def __init__(self, elf: str | Path, *, icount: bool = True) -> None:
        qemu = find_tools().qemu
        if qemu is None:
            raise ExportError("qemu-system-arm not on PATH (tools/setup.sh --test installs it)")
        cmd = [qemu, "-M", "netduinoplus2", "-display", "none", "-monitor", "none", "-serial", "null",
               "-serial", "pty", "-kernel", str(elf)] + (["-icount", "shift=0"] if icount else [])
        self.process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT)
        self.port = self._pty_path()

    def _pty_path(self) -> str:
        deadline, text = time.monotonic() + 10.0, b""
        fd = self.process.stdout.fileno()
        while time.monotonic() < deadline:
            r, _, _ = select.select([fd], [], [], 0.2)
            if r:
                chunk = os.read(fd, 4096)
                if not chunk:
                    break
                text += chunk
                for line in text.decode("utf-8", "replace").splitlines():
                    if "redirected to" in line and "serial1" in line:
                        return line.split("redirected to", 1)[1].split()[0]
        self.close()
        raise ExportError(f"qemu did not report the USART2 pseudo-terminal: {text.decode('utf-8', 'replace')[:300]!r}")

    def close(self) -> None:
        """Stop qemu (this process only)."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process.stdout:
            self.process.stdout.close()

    def __enter__(self) -> "QemuBoard":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def python_closed_loop(program, design: Design, reference: pr.Reference | str, n: int, *,
                       options: FirmwareOptions | None = None, effects: Sequence[Any] = (), seed: int = 1,
                       noise_std: float = 1e-3, dtype: Any = np.float32, substeps: int = 10,
                       initial_angle: float = 0.0, include_nominal_viscous: bool = True) -> dict[str, np.ndarray]:
    """The all-Python closed loop: the same plant stepper and discrete controller, no firmware.

    A controller written as code (the program is ``external``) runs as its code: a C file
    compiled for the host (software in the loop), fed the firmware's own float32 measurements.

    Parameters
    ----------
    program : ControllerProgram
        The exported controller (``FirmwareResult.program``).
    design : Design
        The virtual testbed's design.
    reference : Reference or str
        Force reference.
    n : int
        Periods [-].
    options : FirmwareOptions, optional
        Encoder resolution of the firmware.
    effects : sequence
        Unmodelled effects of the virtual testbed.
    seed, noise_std, substeps, initial_angle, include_nominal_viscous
        Process noise [N m], RK4 substeps, initial absolute motor angle [rad] and whether the nominal
        d_m is part of the true friction, of the virtual testbed (as the PIL run).
    dtype : numpy dtype
        ``np.float32``: the controller and the sensor conversion run in float32 exactly as the
        firmware does (:func:`~forecast_design.export.firmware.firmware_measurements`);
        ``np.float64``: the design implementation on the plant's own measurements.

    Returns
    -------
    dict of ndarray
        ``tau_m``, ``theta``, ``q``, ``tau_s``, ``tau_r``, ``u``, ``tau_frc_hat`` per period.
    """
    opt = options or FirmwareOptions()
    ref = pr.parse_reference(reference) if isinstance(reference, str) else reference
    rate = program.rate_hz
    bed = plant_stepper(design, effects, n=n, rate_hz=rate, seed=seed, process_noise_std=noise_std,
                        encoder_counts=opt.encoder_counts, substeps=substeps, initial_angle=initial_angle,
                        include_nominal_viscous=include_nominal_viscous)
    ctrl = program.make_step(dtype)
    single = np.dtype(dtype) == np.float32
    # float32: the firmware's own reference generator (its edges fall on the same periods)
    refs = firmware_reference(ref, n, rate) if single else ref.signal().sample(n, rate)
    runner = None
    if program.external:   # a controller written as code: software in the loop (its C on the host)
        from ..simulation.code import code_runner

        if design.controller is None or not design.controller.is_code or \
                design.controller.identity() != program.external:
            raise ParameterError(f"the program runs {program.external}: give the design that controller",
                                 name="controller", value=program.external)
        runner = code_runner(design.controller)
        runner.reset(rate, design.testbed, design.environment)
    out = {k: np.zeros(n) for k in _SIGNALS}
    for i in range(n):
        th, q, tau_s = bed.measure()
        if single:
            th, q, tau_s = firmware_measurements(sensor_counts(th, opt.rad_per_count),
                                                 sensor_counts(q, opt.rad_per_count), opt.rad_per_count,
                                                 design.testbed.k, design.environment.locked)
        tau_r = float(refs[i])
        u_code = 0.0 if runner is None else runner.step(i / rate, tau_r, tau_s, th, q)
        tau_m = ctrl.step(tau_r, tau_s, th, u_external=u_code)
        for key, v in zip(out, (tau_m, th, q, tau_s, tau_r, ctrl.u, ctrl.hat)):
            out[key][i] = v
        bed.advance(tau_m)
    return out


def pil_session(board: Board, program, design: Design, reference: pr.Reference, n: int, *,
                options: FirmwareOptions, faults: PilFaults | None = None, effects: Sequence[Any] = (),
                seed: int = 1, noise_std: float = 1e-3, timeout: float = 30.0, substeps: int = 10,
                initial_angle: float = 0.0, include_nominal_viscous: bool = True) -> tuple[list, dict]:
    """Upload, start, and run ``n`` lock-step periods against a firmware behind ``board``.

    ``effects``, ``seed``, ``noise_std``, ``substeps``, ``initial_angle`` [rad] and
    ``include_nominal_viscous`` describe the virtual testbed (:func:`~forecast_design.simulation.plant_stepper`).

    Returns
    -------
    tuple
        (received samples, info dict with ``fault``, ``fault_index``, ``fault_latency_s``, ``stats``).
    """
    faults = faults or PilFaults()
    rate = program.rate_hz
    # everything slow happens before START: once the firmware runs, a host pause longer than its
    # link timeout is a LINK_TIMEOUT fault, not a slow machine
    bed = plant_stepper(design, effects, n=n, rate_hz=rate, seed=seed, process_noise_std=noise_std,
                        encoder_counts=options.encoder_counts, substeps=substeps,
                        initial_angle=initial_angle, include_nominal_viscous=include_nominal_viscous).warm_up()
    board.ping(connect_timeout=20.0)
    board.upload(program)
    board._command(pr.MsgType.SET_REFERENCE, pr.encode_reference(reference))
    board._command(pr.MsgType.START, pr.encode_start(n))
    rng = np.random.default_rng(faults.seed)
    samples: list[pr.Sample] = []
    info: dict[str, Any] = {"fault": None, "fault_index": None, "fault_latency_s": None, "stats": None}
    pending = list(board._pending)
    board._pending = []
    last_sent = time.monotonic()
    k, done = 0, False
    while not done:
        waiting_for = None
        if k < n and k != faults.silent_at:
            if k == faults.garbage_at:
                junk = rng.integers(0, 256, faults.garbage_bytes, dtype=np.uint8)
                junk[junk == 0xA5] = 0x00   # garbage that holds no sync byte: nothing to resynchronise to
                board.link.write(junk.tobytes())
            if k != faults.drop_at:
                th, q, _ = bed.measure()
                raw_m = sensor_counts(th, options.rad_per_count) + COUNT_OFFSET
                raw_e = sensor_counts(q, options.rad_per_count) + COUNT_OFFSET
                board._send(pr.MsgType.SENSOR, pr.encode_sensor(k, raw_m, raw_e))
                waiting_for = k
            last_sent = time.monotonic()
        deadline = time.monotonic() + timeout
        got = False
        while not got and not done:
            frames, pending = (pending, []) if pending else (board._feed(board.link.read(timeout=0.01)), [])
            for frame in frames:
                if frame.type == pr.MsgType.SAMPLE:
                    s = pr.decode_sample(frame.payload)
                    samples.append(s)
                    if s.index == waiting_for:
                        bed.advance(s.tau_m)
                        got = True
                elif frame.type == pr.MsgType.FAULT:
                    index, code = pr.decode_fault(frame.payload)
                    info.update(fault=pr.fault_name(code),
                                fault_index=index, fault_latency_s=time.monotonic() - last_sent)
                elif frame.type == pr.MsgType.STATS:
                    info["stats"] = pr.decode_stats(frame.payload).to_mapping()
                elif frame.type == pr.MsgType.DONE:
                    done = True
            if frames:
                deadline = time.monotonic() + timeout   # silence is no frame at all, not a slow answer
            if waiting_for is None and k < n and k != faults.silent_at and not done:
                break   # a dropped frame: send the next period at once
            if not got and not done and time.monotonic() > deadline:
                raise LinkError(f"{board.link.port}: firmware silent for {timeout} s at period {k} "
                                f"({len(samples)} samples received; a controller step that never returns blocks "
                                "the firmware: on the board its 10 ms watchdog resets it, torque off)")
        k += 1
    return samples, info


def run_pil(design: Design | None = None, *, controller: str | None = "pd:5:0.1",
            compensator: Any = "none", env: Any = "exp-soft", w_q_hz: float | None = 10.0,
            rate_hz: float = 2000.0, sfm_params: Mapping[str, float] | None = None,
            reference: str | pr.Reference = "square:0.2:0.5", duration: float = 0.5,
            out: str | Path | None = None, work_dir: str | Path | None = None,
            options: FirmwareOptions | None = None, faults: PilFaults | None = None,
            effects: Sequence[Any] = (), seed: int = 1, noise_std: float = 1e-3, icount: bool = True,
            timeout: float = 30.0, testbed: Any = None, substeps: int = 10, initial_angle: float = 0.0,
            include_nominal_viscous: bool = True, description: str = "") -> PilResult:
    """The ``forecast-design pil`` verb: build the PIL firmware, run it on qemu against the virtual testbed.

    Parameters
    ----------
    design, controller, compensator, env, w_q_hz, rate_hz, sfm_params, testbed
        The design, as :func:`forecast_design.export.firmware.export_firmware`.
    reference : str or Reference
        Force reference (``square:AMP:PERIOD`` ...).
    duration : float
        Simulated time [s].
    out : str or Path, optional
        Experiment TOML to write (CSV beside it).
    work_dir : str or Path, optional
        Where the firmware project is written and built (default: beside ``out``, else ``pil-firmware``).
    options : FirmwareOptions, optional
        Board settings (link timeout, torque limit...); default the board's with a link timeout of
        ``PIL_LINK_TIMEOUT_MS`` (the host is not real-time).
    faults : PilFaults, optional
        Link faults to inject.
    effects, seed, noise_std, substeps, initial_angle, include_nominal_viscous
        The virtual testbed's unmodelled effects, process noise [N m], RK4 substeps per period,
        absolute motor angle at theta = 0 [rad] and whether the nominal d_m is part of the true
        friction (:func:`run_pil_scenario` takes them from a scenario).
    description : str
        Said first in the recorded experiment's description (e.g. the scenario it ran).
    icount : bool
        Count instructions (qemu ``-icount shift=0``).
    timeout : float
        Host wait for each answer [s]: generous, since a loaded machine can stall qemu for
        seconds; a firmware that never answers is reported after it.

    Returns
    -------
    PilResult
        Samples, fault (if any), STATS and instructions per step, the experiment path and arrays.

    Raises
    ------
    ExportError
        qemu, the toolchain or make missing, or a failed build.
    LinkError
        The firmware fell silent.
    """
    ref = pr.parse_reference(reference) if isinstance(reference, str) else reference
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ParameterError(f"duration must be > 0 [s], got {duration!r}", name="duration", value=duration)
    why = qemu_available()
    if why:
        raise ExportError(f"pil: {why}")
    if out is not None:
        check_writable(out)   # before the build and the session, not after them
    opt = options or FirmwareOptions(link_timeout_ms=PIL_LINK_TIMEOUT_MS)
    work = Path(work_dir) if work_dir else (Path(out).with_suffix("").with_name(Path(out).stem + "-firmware")
                                            if out else Path("pil-firmware"))
    # the firmware's own STATS measure every period's cost here: no separate cycle check
    fw = export_firmware(design, work, controller=controller, compensator=compensator, env=env, w_q_hz=w_q_hz,
                         rate_hz=rate_hz, sfm_params=sfm_params, options=opt, testbed=testbed, check_cycles=False)
    elf = build_firmware(work, "pil")
    n = int(round(duration * fw.program.rate_hz))
    with QemuBoard(elf, icount=icount) as qemu, Board(qemu.port, timeout=timeout) as board:
        samples, info = pil_session(board, fw.program, fw.design, ref, n, options=opt, faults=faults,
                                    effects=effects, seed=seed, noise_std=noise_std, timeout=timeout,
                                    substeps=substeps, initial_angle=initial_angle,
                                    include_nominal_viscous=include_nominal_viscous)
    arrays = {name: np.array([getattr(s, name) for s in samples], dtype=float) for name in _SIGNALS}
    path = None
    if out is not None and samples:
        text = (f"{description + '; ' if description else ''}processor-in-the-loop on qemu netduinoplus2: "
                f"reference {ref.to_string()}, {duration} s"
                + (f"; firmware fault {info['fault']} at sample {info['fault_index']} (torque zero)"
                   if info["fault"] else ""))
        exp = record_to_experiment(fw.design, fw.program.rate_hz, samples, samples[-1].index + 1, description=text)
        # the session is not repeatable for free: a late write failure goes to a recovery file
        path, failure = _save_with_recovery(exp, Path(out))
        if failure:
            raise BoardError(f"{failure}: the PIL run was saved to the recovery file {path} instead", saved=path)
    stats = info["stats"]
    ips = stats["mean_instructions_per_step"] if (stats and icount) else None
    return PilResult(len(samples), n, info["fault"], info["fault_index"], info["fault_latency_s"], stats, ips,
                     path, arrays, rate_hz=fw.program.rate_hz)



def scenario_reference(reference: Any) -> pr.Reference:
    """The firmware's reference generator for a scenario's ``[reference]``: the inverse of
    :meth:`~forecast_design.runtime.protocol.Reference.signal`.

    Parameters
    ----------
    reference : simulation reference
        ``Constant``, ``Step``, ``Square`` (duty 0.5, from t = 0) or ``Sine`` (zero phase, from t = 0) of
        :mod:`forecast_design.simulation.references` [N m, s].

    Returns
    -------
    Reference
        The same signal as the firmware generates it.

    Raises
    ------
    ParameterError
        For a reference the firmware cannot generate (one line naming it and what it can).
    """
    from ..simulation import references as refs

    if isinstance(reference, refs.Constant):
        return pr.Reference("step", reference.value, 0.0)
    if isinstance(reference, refs.Step):
        return pr.Reference("step", reference.amplitude, reference.t0, reference.offset)
    if isinstance(reference, refs.Square) and reference.duty == 0.5 and reference.t0 == 0.0:
        return pr.Reference("square", (reference.high - reference.low) / 2.0, reference.period_s,
                            (reference.high + reference.low) / 2.0)
    if isinstance(reference, refs.Sine) and reference.phase_rad == 0.0 and reference.t0 == 0.0 \
            and reference.frequency_hz > 0.0:
        return pr.Reference("sine", reference.amplitude, 1.0 / reference.frequency_hz, reference.offset)
    raise ParameterError(f"the firmware generates {pr.REFERENCE_SYNTAX}, not the scenario's reference "
                         f"{reference.to_mapping()!r:.120}; give pil --reference", name="reference",
                         value=getattr(reference, "kind", reference))


def run_pil_scenario(scenario: Any, *, reference: str | pr.Reference | None = None, duration: float | None = None,
                     out: str | Path | None = None, work_dir: str | Path | None = None,
                     options: FirmwareOptions | None = None, faults: PilFaults | None = None, icount: bool = True,
                     timeout: float = 30.0) -> PilResult:
    """:func:`run_pil` on a simulation scenario: its nominal model and controller are the firmware's, its
    hardware (friction and every ``[truth]`` effect, process noise, seed, initial angle, RK4 substeps,
    encoder resolution) the virtual testbed's, as ``simulate`` would run it (repetition 0).

    Parameters
    ----------
    scenario : Scenario
        A loaded scenario (:func:`~forecast_design.simulation.scenario.load_scenario`); closed loop.
    reference : str or Reference, optional
        Overrides the scenario's ``[reference]`` (which must otherwise be one the firmware generates,
        :func:`scenario_reference`).
    duration : float, optional
        Overrides the scenario's ``duration_s`` [s].
    out, work_dir, options, faults, icount, timeout
        As for :func:`run_pil`; ``options.encoder_counts`` is the scenario's when it sets one.

    Returns
    -------
    PilResult
        As :func:`run_pil`.

    Raises
    ------
    ParameterError
        An open-loop scenario, a reference the firmware cannot generate, or exact angles
        (``encoder_counts = 0``: the firmware reads counts).
    """
    import dataclasses

    if not scenario.closed_loop:
        raise ParameterError(f"{scenario.source or 'the scenario'}: pil runs a force controller; the scenario "
                             "has no [controller] (open loop)", name="controller")
    opts = scenario.options
    opt = options or FirmwareOptions(link_timeout_ms=PIL_LINK_TIMEOUT_MS)
    counts = opts.get("encoder_counts")
    if counts is not None:
        if not counts:
            raise ParameterError(f"{scenario.source or 'the scenario'}: [simulation] encoder_counts = 0 (exact "
                                 "angles) cannot run on the firmware, which reads encoder counts; give a resolution",
                                 name="encoder_counts", value=counts)
        opt = dataclasses.replace(opt, encoder_counts=int(counts))
    rep = scenario.repetition(0)
    with scenario.naming_errors():
        ref = reference if reference is not None else scenario_reference(scenario.reference)
        return run_pil(scenario.design, controller=None, compensator=None, env=None, w_q_hz=None,
                       rate_hz=scenario.rate_hz, sfm_params=opts.get("sfm_params"), reference=ref,
                       duration=float(opts["duration_s"]) if duration is None else duration, out=out,
                       work_dir=work_dir, options=opt, faults=faults, effects=rep.effects, seed=rep.seed,
                       noise_std=float(opts.get("process_noise_std", DEFAULT_PROCESS_NOISE_STD)), icount=icount,
                       timeout=timeout, substeps=int(opts.get("substeps", 10)), initial_angle=rep.initial_angle,
                       include_nominal_viscous=bool(opts.get("include_nominal_viscous", True)), description=f"scenario {scenario.source}" if scenario.source else "")
