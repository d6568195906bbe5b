"""A board emulator on a pseudo-terminal: the protocol, the uploaded controller and the virtual testbed."""

from __future__ import annotations

import math
import os
import select
import signal
import sys
import threading
import time
import tty
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..errors import ParameterError
from ..params import Design, environment_preset
from . import protocol as pr

__all__ = ["Faults", "parse_fault", "open_pty", "serve_emulator", "emulate"]


@dataclass(frozen=True, slots=True)
class Faults:
    """Fault injection on the bytes the emulated board sends during a run.

    Parameters
    ----------
    flip : float
        Probability per byte of flipping one random bit [-].
    drop : float
        Probability per byte of dropping it [-].
    disconnect_after : int or None
        Close the device after this many samples (a pulled cable) [-].
    seed : int
        Seed of the fault generator.
    """

    flip: float = 0.0
    drop: float = 0.0
    disconnect_after: int | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("flip", "drop"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ParameterError(f"fault {name} probability must be in [0, 1), got {v!r}", name=name, value=v)
        if self.disconnect_after is not None and self.disconnect_after < 0:
            raise ParameterError(f"fault disconnect_after must be >= 0, got {self.disconnect_after!r}",
                                 name="disconnect_after", value=self.disconnect_after)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**63:
            raise ParameterError(f"fault seed must be an integer in [0, 2**63), got {self.seed!r}",
                                 name="seed", value=self.seed)


def parse_fault(texts: Sequence[str]) -> Faults:
    """Parse ``--fault`` options: ``flip:P``, ``drop:P``, ``disconnect:N``, ``seed:S``.

    Parameters
    ----------
    texts : sequence of str
        E.g. ``["flip:1e-4", "disconnect:500"]``.

    Returns
    -------
    Faults
        The combined fault settings.

    Raises
    ------
    ParameterError
        One line naming the bad option.
    """
    kw: dict[str, Any] = {}
    names = {"flip": ("flip", float), "drop": ("drop", float), "disconnect": ("disconnect_after", int),
             "seed": ("seed", int)}
    for text in texts:
        key, _, value = str(text).partition(":")
        if key not in names or not value:
            raise ParameterError(f"fault {text!r}: expected flip:P, drop:P, disconnect:N or seed:S",
                                 name="fault", value=text)
        field_name, conv = names[key]
        try:
            kw[field_name] = conv(value)
        except ValueError:
            raise ParameterError(f"fault {text!r}: {value!r} is not a valid {conv.__name__}",
                                 name="fault", value=text) from None
    return Faults(**kw)


def open_pty() -> tuple[int, int, str]:
    """Open a raw pseudo-terminal.

    Returns
    -------
    tuple
        (master fd, slave fd, slave device path). The slave is in raw mode
        so no byte is translated or echoed.
    """
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


class _Emulator:
    def __init__(self, fd: int, design: Design, effects: Sequence[Any], faults: Faults, rate_hz: float,
                 realtime: bool, stop: threading.Event, noise_std: float) -> None:
        self.fd = fd
        self.design = design
        self.effects = tuple(effects)
        self.faults = faults
        self.rate_hz = rate_hz
        self.realtime = realtime
        self.stop = stop
        self.noise_std = noise_std
        self.parser = pr.FrameParser(pr.HOST_TYPES)
        self.seq = 0
        self.program = None
        self.reference = pr.Reference("step", 0.0)
        self.rng = np.random.default_rng(faults.seed)
        self.closed = False
        self.runs = 0

    # -- output ---------------------------------------------------------------
    def _write_all(self, data: bytes) -> None:
        view = memoryview(data)
        while view and not self.stop.is_set():
            _, w, _ = select.select([], [self.fd], [], 0.1)
            if not w:
                continue
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                continue
            view = view[n:]

    def _send(self, msg_type: int, payload: bytes = b"", *, faulty: bool = False) -> None:
        frame = pr.encode_frame(msg_type, self.seq, payload)
        self.seq = (self.seq + 1) & 0xFFFF
        if faulty:
            frame = self._corrupt(frame)
        self._write_all(frame)

    def _corrupt(self, frame: bytes) -> bytes:
        f = self.faults
        if f.flip == 0.0 and f.drop == 0.0:
            return frame
        data = bytearray(frame)
        if f.flip:
            for i in np.flatnonzero(self.rng.random(len(data)) < f.flip):
                data[i] ^= 1 << int(self.rng.integers(8))
        if f.drop:
            keep = self.rng.random(len(data)) >= f.drop
            data = bytearray(b for b, k in zip(data, keep) if k)
        return bytes(data)

    # -- input ----------------------------------------------------------------
    def _poll(self, timeout: float) -> list[pr.Frame]:
        r, _, _ = select.select([self.fd], [], [], timeout)
        if not r:
            return []
        try:
            data = os.read(self.fd, 4096)
        except BlockingIOError:
            return []
        except OSError:  # EIO: no process has the slave open; keep serving
            time.sleep(timeout)
            return []
        return self.parser.feed(data)

    def _handle(self, frame: pr.Frame) -> None:
        t, M = frame.type, pr.MsgType
        if t == M.PING:
            self._send(M.INFO, pr.encode_info(self.rate_hz))
            return
        if t == M.HEARTBEAT:   # the host is alive; never answered (the emulator has no link watchdog)
            return
        status = pr.Ack.OK
        n_start = None
        try:
            if t == M.UPLOAD:
                from ..program import ControllerProgram

                program = ControllerProgram.from_bytes(frame.payload)
                own = self.design.controller
                if program.external and not (own is not None and own.is_code and own.identity() == program.external):
                    # a board runs the code it was built with only (emulate --controller FILE.c)
                    status = pr.Ack.BAD_PAYLOAD
                else:
                    self.program = program
            elif t == M.SET_REFERENCE:
                self.reference = pr.decode_reference(frame.payload)
            elif t == M.START:
                if self.program is None:
                    status = pr.Ack.NO_CONTROLLER
                else:
                    n_start = pr.decode_start(frame.payload)
                    if not 1 <= n_start <= pr.MAX_RUN_SAMPLES:   # the host never asks for more
                        status, n_start = pr.Ack.BAD_PAYLOAD, None
            elif t == M.STOP:
                pass
            else:
                status = pr.Ack.UNKNOWN_TYPE
        except ParameterError:
            status = pr.Ack.BAD_PAYLOAD
        self._send(M.ACK, pr.encode_ack(t, frame.seq, status))
        if n_start is not None:
            self._run(n_start)

    def _run(self, n: int) -> None:
        M = pr.MsgType
        self.runs += 1
        from ..simulation.run import plant_stepper   # numba loads only when a run starts

        bed = plant_stepper(self.design, self.effects, n=n, rate_hz=self.rate_hz, seed=self.runs,
                            process_noise_std=self.noise_std)
        runner = None
        if self.program.external:   # a controller written as code: float32 around it, as on the board
            from ..simulation.code import code_runner

            runner = code_runner(self.design.controller)
            runner.reset(self.rate_hz, self.design.testbed, self.design.environment)
        ctrl = self.program.make_step(np.float32 if runner is not None else np.float64)
        dt = 1.0 / self.rate_hz
        t0 = time.monotonic()
        sent, reason = 0, 0
        batch = bytearray()
        references = self.reference.signal().sample(n, self.rate_hz).tolist()
        for i in range(n):
            if self.faults.disconnect_after is not None and sent >= self.faults.disconnect_after:
                self._write_all(bytes(batch))
                self.closed = True
                os.close(self.fd)  # the pulled cable: the host's next read fails
                return
            th, q, tau_s = bed.measure()
            t = i * dt
            tau_r = references[i]
            u_code = 0.0
            if runner is not None:
                try:
                    u_code = runner.step(t, tau_r, tau_s, th, q)
                except Exception:   # noqa: BLE001 - the user's code failed: the firmware's NaN path
                    u_code = math.nan
            tau_m = ctrl.step(tau_r, tau_s, th, u_external=u_code)
            if not math.isfinite(ctrl.u + ctrl.hat):   # the firmware (before its saturation): zero torque,
                # FAULT CONTROLLER, DONE (fault)
                self._write_all(bytes(batch))
                self._send(M.FAULT, pr.encode_fault(i, pr.Fault.CONTROLLER))
                self._send(M.DONE, pr.encode_done(sent, 2))
                return
            sample = pr.Sample(i, t, tau_m, th, q, tau_s, tau_r, ctrl.u, ctrl.hat)
            frame = pr.encode_frame(M.SAMPLE, self.seq, pr.encode_sample(sample))
            self.seq = (self.seq + 1) & 0xFFFF
            batch += self._corrupt(frame)
            bed.advance(tau_m)
            sent += 1
            if len(batch) >= 1024 or i == n - 1:
                self._write_all(bytes(batch))
                batch.clear()
                if any(f.type == M.STOP for f in self._poll(0.0)):
                    reason = 1
                    break
                if self.stop.is_set():
                    return
                if self.realtime:
                    lag = t0 + (i + 1) * dt - time.monotonic()
                    if lag > 0:
                        time.sleep(lag)
        self._send(M.DONE, pr.encode_done(sent, reason), faulty=True)

    def serve(self) -> None:
        while not self.stop.is_set() and not self.closed:
            for frame in self._poll(0.05):
                self._handle(frame)
                if self.closed:
                    break


def warm_up(design: Design, effects: Sequence[Any] = (), rate_hz: float = 2000.0) -> None:
    """Step the virtual testbed once so numba compiles the kernel before a host is waiting."""
    from ..simulation.run import plant_stepper

    plant_stepper(design, effects, n=1, rate_hz=rate_hz, process_noise_std=0.0).warm_up()


def serve_emulator(fd: int, *, design: Design | None = None, effects: Sequence[Any] = (),
                   faults: Faults | None = None, rate_hz: float = 2000.0, realtime: bool = False,
                   stop: threading.Event | None = None, noise_std: float = 1e-3) -> int:
    """Speak the board protocol on ``fd`` (a pty master) until ``stop`` is set or a disconnect fault.

    A ``disconnect_after`` fault closes ``fd`` itself; otherwise the caller closes it.

    Parameters
    ----------
    fd : int
        Non-blocking file descriptor of the host side's peer (pty master).
    design : Design, optional
        The virtual testbed's design (default: Table 1 testbed, ``exp-soft``).
    effects : sequence
        Unmodelled effects of the virtual hardware (:mod:`forecast_design.effects`).
    faults : Faults, optional
        Fault injection on the sample stream.
    rate_hz : float
        Control rate [Hz].
    realtime : bool
        Pace the stream at ``rate_hz`` (default: as fast as the link takes it).
    stop : threading.Event, optional
        Set it to end the service.
    noise_std : float
        Process torque noise of the virtual testbed [N m].

    Returns
    -------
    int
        Runs served.
    """
    design = design or Design(environment=environment_preset("exp-soft"))
    warm_up(design, effects, rate_hz)
    emu = _Emulator(fd, design, effects, faults or Faults(), float(rate_hz), realtime,
                    stop or threading.Event(), noise_std)
    emu.serve()
    return emu.runs


def emulate(*, faults: Faults | None = None, design: Design | None = None, effects: Sequence[Any] = (),
            realtime: bool = False, out=None) -> int:
    """The ``forecast-design emulate`` verb: print the pty path, serve until SIGTERM/SIGINT.

    Parameters
    ----------
    faults : Faults, optional
        Fault injection (``--fault``).
    design : Design, optional
        Virtual testbed design.
    effects : sequence
        Unmodelled effects of the virtual hardware.
    realtime : bool
        Pace the stream in real time.
    out : file, optional
        Where the device path goes (default stdout), alone on the first line, flushed.

    Returns
    -------
    int
        Exit code 0.
    """
    warm_up(design or Design(environment=environment_preset("exp-soft")), effects)
    master, slave, path = open_pty()
    stop = threading.Event()

    def _stop(signum, frame):  # noqa: ARG001 - signal handler signature
        stop.set()

    old = {s: signal.signal(s, _stop) for s in (signal.SIGTERM, signal.SIGINT)}
    out = out or sys.stdout
    out.write(path + "\n")
    out.flush()
    try:
        serve_emulator(master, design=design, effects=effects, faults=faults, realtime=realtime, stop=stop)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass
    return 0
