"""The host side of a run: upload a controller, start, record the sample stream, save an experiment."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..params import Design
from . import protocol as pr
from .link import BoardError, Link, LinkError

__all__ = ["RunResult", "Board", "record_to_experiment"]


@dataclass(frozen=True, slots=True)
class RunResult:
    """What a run recorded.

    Parameters
    ----------
    samples : int
        Samples received intact [-].
    expected : int
        Samples the run should have produced [-].
    lost : int
        Samples missing (gaps in the sample index, or a missing tail) [-].
    lost_ranges : tuple of (int, int)
        Half-open index ranges of the lost samples.
    corrupt_frames : int
        Frames rejected by the CRC [-].
    resyncs : int
        Times the parser skipped garbage to find the next frame [-].
    out_of_order : int
        Samples rejected for a repeated or older index [-].
    completed : bool
        The board reported DONE.
    path : str or None
        The experiment TOML written.
    """

    samples: int
    expected: int
    lost: int
    lost_ranges: tuple[tuple[int, int], ...]
    corrupt_frames: int
    resyncs: int
    out_of_order: int = 0
    completed: bool = True
    path: str | None = None

    def to_mapping(self) -> dict[str, Any]:
        """The summary JSON: samples, lost, corrupt_frames, resyncs, plus details."""
        return {"samples": self.samples, "lost": self.lost, "corrupt_frames": self.corrupt_frames,
                "resyncs": self.resyncs, "expected": self.expected, "out_of_order": self.out_of_order,
                "lost_ranges": [list(r) for r in self.lost_ranges], "completed": self.completed,
                "path": self.path}


def record_to_experiment(design: Design, rate_hz: float, samples: list[pr.Sample], n_rows: int,
                         *, description: str = ""):
    """Turn received samples into an experiment with uniformly spaced rows.

    Rows ``0 .. n_rows - 1`` are written at ``t = index / rate_hz``. A lost
    sample's row is filled by linear interpolation between its received
    neighbours (held at the ends) and marked ``received = 0`` in an extra
    column, so the format's uniform spacing holds and nothing is hidden.

    Parameters
    ----------
    design : Design
        What ran (testbed, environment, controller, compensator).
    rate_hz : float
        Sample rate [Hz].
    samples : list of Sample
        Received samples, strictly increasing index.
    n_rows : int
        Rows to write (last received index + 1 at most useful).
    description : str
        Free text for the TOML.

    Returns
    -------
    Experiment
        The run in the shared format.
    """
    from ..experiment import experiment_from_arrays

    idx = np.array([s.index for s in samples], dtype=np.int64)
    rows = np.arange(n_rows)
    received = np.isin(rows, idx).astype(float)

    def col(name: str) -> np.ndarray:
        vals = np.array([getattr(s, name) for s in samples], dtype=float)
        return np.interp(rows, idx, vals)

    q = col("q")
    if design.environment.locked:
        q = np.zeros(n_rows)
    return experiment_from_arrays(design, rate_hz, rows / rate_hz, col("tau_m"), col("theta"), q,
                                  tau_s=col("tau_s"), tau_r=col("tau_r"), extra={"received": received},
                                  description=description)


#: Least time a command's answer (ACK, PONG) is awaited [s], whatever the stream timeout.
ACK_TIMEOUT_S = 2.0


class Board:
    """A force-control board (or its emulator) behind a serial port.

    Parameters
    ----------
    port : str
        Device path, pty path or pyserial URL (``loop://`` for tests).
    baudrate : int
        UART rate [bit/s] (:data:`protocol.BAUD_RATE`).
    timeout : float
        Silence after which the sample stream is declared lost [s]; a command's reply is
        awaited for at least ``ACK_TIMEOUT_S`` (2 s).

    Raises
    ------
    LinkError
        If the port cannot be opened.
    """

    def __init__(self, port: str, *, baudrate: int = pr.BAUD_RATE, timeout: float = 1.0) -> None:
        if not timeout > 0.0:
            raise ParameterError(f"timeout must be > 0 [s], got {timeout!r}", name="timeout", value=timeout)
        self.link = Link(port, baudrate=baudrate)
        self.timeout = float(timeout)
        self._seq = 0
        self.parser = pr.FrameParser()
        self.rate_hz: float | None = None
        self._pending: list[pr.Frame] = []  # frames parsed but not yet consumed (kept in order)

    def close(self) -> None:
        """Close the port."""
        self.link.close()

    def __enter__(self) -> "Board":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _send(self, msg_type: int, payload: bytes = b"") -> int:
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFFFF
        self.link.write(pr.encode_frame(msg_type, seq, payload))
        return seq

    def _frames(self, timeout: float) -> list[pr.Frame]:
        """Frames left over from an earlier read first, then whatever the link brings."""
        if self._pending:
            frames, self._pending = self._pending, []
            return frames
        return self.parser.feed(self.link.read(timeout=timeout))

    def _await(self, want: int, seq: int | None = None) -> pr.Frame:
        """Next frame of type ``want`` (an ACK must acknowledge ``seq``); BoardError on NAK/timeout."""
        # A command's answer may take longer than a gap in the 2 kHz stream (the board may be
        # busy setting up, the host loaded): answers get at least ACK_TIMEOUT_S.
        deadline = time.monotonic() + max(self.timeout, ACK_TIMEOUT_S)
        while time.monotonic() < deadline:
            frames = self._frames(0.02)
            for i, frame in enumerate(frames):
                if frame.type == pr.MsgType.ACK and want == pr.MsgType.ACK:
                    a_type, a_seq, status = pr.decode_ack(frame.payload)
                    if a_seq != seq:
                        continue
                    self._pending = frames[i + 1:] + self._pending
                    if status != pr.Ack.OK:
                        raise BoardError(f"{self.link.port}: board refused {pr.MsgType(a_type).name}: "
                                         f"{pr.Ack(status).name}")
                    return frame
                if frame.type == want:
                    self._pending = frames[i + 1:] + self._pending
                    return frame
        raise LinkError(f"{self.link.port}: no {pr.MsgType(want).name} within {self.timeout} s "
                        "(board disconnected or not running the protocol?)")

    def _command(self, msg_type: int, payload: bytes = b"") -> None:
        seq = self._send(msg_type, payload)
        self._await(pr.MsgType.ACK, seq)

    def ping(self, *, connect_timeout: float = 5.0) -> tuple[int, float]:
        """Ask for INFO until the board answers; return (protocol version, rate [Hz]).

        Parameters
        ----------
        connect_timeout : float
            How long to keep asking (a board may still be booting) [s].

        Returns
        -------
        tuple
            (protocol version, sample rate [Hz]).

        Raises
        ------
        LinkError
            No answer within ``connect_timeout``.
        BoardError
            A board speaking another protocol version.
        """
        deadline = time.monotonic() + connect_timeout
        while True:
            self._send(pr.MsgType.PING)
            resend = time.monotonic() + 0.25
            while time.monotonic() < resend:
                for frame in self.parser.feed(self.link.read(timeout=0.02)):
                    if frame.type == pr.MsgType.INFO:
                        version, rate, _ = pr.decode_info(frame.payload)
                        if version != pr.PROTOCOL_VERSION:
                            raise BoardError(f"{self.link.port}: board speaks protocol {version}, "
                                             f"host speaks {pr.PROTOCOL_VERSION}")
                        self.rate_hz = float(rate)
                        return version, float(rate)
            if time.monotonic() > deadline:
                raise LinkError(f"{self.link.port}: no answer to PING within {connect_timeout} s "
                                "(board not connected or not running the protocol?)")

    def upload(self, program) -> None:
        """Send a controller (a ``ControllerProgram`` or an ``ExportResult``) and await the ACK.

        Parameters
        ----------
        program : ControllerProgram or ExportResult
            The discretised controller; its float32 coefficients are uploaded.

        Raises
        ------
        BoardError
            If the board refuses it; LinkError on silence.
        """
        program = getattr(program, "program", program)
        blob = program.to_bytes()
        if len(blob) > pr.MAX_PAYLOAD:
            raise BoardError(f"controller needs {len(blob)} upload bytes; the protocol carries {pr.MAX_PAYLOAD}")
        self._command(pr.MsgType.UPLOAD, blob)

    def run(self, reference: pr.Reference | str, duration: float, design: Design, out: str | Path, *,
            description: str = "") -> RunResult:
        """Record one run and save it as an experiment (TOML + CSV, each written atomically).

        Parameters
        ----------
        reference : Reference or str
            Force reference (``"square:0.2:0.5"`` accepted).
        duration : float
            Run length [s].
        design : Design
            What is running (goes to the TOML).
        out : str or Path
            Experiment TOML path.
        description : str
            Free text for the TOML.

        Returns
        -------
        RunResult
            Counts of samples, losses, corrupt frames and resyncs.

        Raises
        ------
        LinkError
            The board went silent or the port failed mid-run; whatever was
            received is saved first (``exc.saved``, ``exc.summary``).
        """
        if isinstance(reference, str):
            reference = pr.parse_reference(reference)
        if not (duration > 0.0 and math.isfinite(duration)):
            raise ParameterError(f"duration must be > 0 [s], got {duration!r}", name="duration", value=duration)
        if self.rate_hz is None:
            self.ping()
        rate = float(self.rate_hz)
        n = int(round(duration * rate))
        self._command(pr.MsgType.SET_REFERENCE, pr.encode_reference(reference))
        stats_before = (self.parser.stats.corrupt_frames, self.parser.stats.resyncs)
        tracker = pr.SampleTracker()
        completed, error = False, None
        try:
            # Inside the try: a board that streams and disconnects before its ACK is read
            # (a loaded host) still has its samples saved and counted.
            self._command(pr.MsgType.START, pr.encode_start(n))
            last_data = time.monotonic()
            while not completed:
                if self._pending:
                    frames, self._pending = self._pending, []
                else:
                    chunk = self.link.read(timeout=0.05)
                    now = time.monotonic()
                    if chunk:
                        last_data = now
                    elif now - last_data > self.timeout:
                        raise LinkError(f"{self.link.port}: sample stream silent for {self.timeout} s after "
                                        f"{len(tracker.samples)} of {n} samples (disconnected?)")
                    frames = self.parser.feed(chunk)
                for i, frame in enumerate(frames):
                    if frame.type == pr.MsgType.SAMPLE:
                        tracker.add(pr.decode_sample(frame.payload))
                    elif frame.type == pr.MsgType.DONE:
                        completed = True
                        self._pending = frames[i + 1:]
                        break
                if not completed and tracker.next_index >= n:
                    # every sample is in; a DONE lost to corruption must not hang the run
                    completed = self._grace_for_done(tracker)
        except LinkError as exc:
            error = exc
            for frame in self._pending:
                if frame.type == pr.MsgType.SAMPLE:
                    tracker.add(pr.decode_sample(frame.payload))
            self._pending = []
            for frame in self.parser.close():
                if frame.type == pr.MsgType.SAMPLE:
                    tracker.add(pr.decode_sample(frame.payload))
        tracker.finish(n)
        stats = self.parser.stats
        result = RunResult(
            samples=len(tracker.samples), expected=n, lost=tracker.n_lost, lost_ranges=tuple(tracker.lost),
            corrupt_frames=stats.corrupt_frames - stats_before[0], resyncs=stats.resyncs - stats_before[1],
            out_of_order=tracker.out_of_order, completed=error is None,
        )
        path = None
        if tracker.samples:
            n_rows = tracker.samples[-1].index + 1
            text = description or f"recorded on {self.link.port}: reference {reference.to_string()}, {duration} s"
            if result.lost:
                text += f"; {result.lost} lost samples interpolated (column received = 0)"
            exp = record_to_experiment(design, rate, tracker.samples, n_rows, description=text)
            from ..experiment import save_experiment

            path = str(save_experiment(exp, out))
        result = dataclasses.replace(result, path=path)
        if error is not None:
            self.parser = pr.FrameParser()
            saved = f"; saved {result.samples} samples to {path}" if path else "; nothing received"
            raise LinkError(f"{error}{saved}; lost {result.lost}", summary=result.to_mapping(),
                            saved=path) from None
        return result

    def _grace_for_done(self, tracker: pr.SampleTracker) -> bool:
        deadline = time.monotonic() + min(self.timeout, 0.2)
        while time.monotonic() < deadline:
            for frame in self.parser.feed(self.link.read(timeout=0.02)):
                if frame.type == pr.MsgType.DONE:
                    return True
                if frame.type == pr.MsgType.SAMPLE:
                    tracker.add(pr.decode_sample(frame.payload))
        return True

    def stop(self) -> None:
        """Ask the board to stop a run."""
        self._send(pr.MsgType.STOP)
