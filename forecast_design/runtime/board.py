"""The host side of a run: upload a controller, start, record the sample stream, save an experiment."""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import fileio
from ..errors import ForecastError, OutputError, ParameterError
from ..params import Design
from ..limits import PHYSICAL_RANGES
from . import protocol as pr
from .link import BoardError, Link, LinkError

__all__ = ["RunResult", "Board", "record_to_experiment", "check_writable", "run_deadline_s",
           "MIN_RATE_HZ", "MAX_RATE_HZ"]


@dataclass(frozen=True, slots=True)
class RunResult:
    """What a run recorded.

    Parameters
    ----------
    samples : int
        Samples received intact (valid or not) [-].
    expected : int
        Samples the run should have produced (requested at START) [-].
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
    invalid : int
        Samples received with a NaN or infinite value: kept, their row
        interpolated and flagged ``valid = 0`` [-].
    out_of_range : int
        Samples with an index at or beyond ``expected``: protocol errors, dropped [-].
    seq_skipped : int
        Board frame sequence numbers never received (frames lost whole or corrupt) [-].
    seq_repeated : int
        Board frames whose sequence number repeated or went back [-].
    fault : str or None
        The :class:`~forecast_design.runtime.protocol.Fault` the board stopped on (torque zero), if any.
    stats : dict or None
        The board's STATS (its measured cost of a control period), if it sent them.
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
    fault: str | None = None
    stats: dict | None = None
    invalid: int = 0
    out_of_range: int = 0
    seq_skipped: int = 0
    seq_repeated: int = 0

    def to_mapping(self) -> dict[str, Any]:
        """The summary JSON: samples, lost, corrupt_frames, resyncs, plus details."""
        return {"samples": self.samples, "lost": self.lost, "corrupt_frames": self.corrupt_frames,
                "resyncs": self.resyncs, "expected": self.expected, "out_of_order": self.out_of_order,
                "invalid": self.invalid, "out_of_range": self.out_of_range,
                "seq_skipped": self.seq_skipped, "seq_repeated": self.seq_repeated,
                "lost_ranges": [list(r) for r in self.lost_ranges], "completed": self.completed,
                "path": self.path, "fault": self.fault, "stats": self.stats}


#: Columns of a recorded run that the experiment format names; other sample fields become extra columns.
_FORMAT_FIELDS = ("tau_m", "theta", "q", "tau_s", "tau_r")


def record_to_experiment(design: Design, rate_hz: float, samples: "pr.SampleTracker | list[pr.Sample]",
                         n_rows: int, *, description: str = ""):
    """Turn received samples into an experiment with uniformly spaced rows.

    Rows ``0 .. n_rows - 1`` are written at ``t = index / rate_hz``. A row
    without a usable sample (lost, or received with a NaN/inf value) is
    filled by linear interpolation between its valid neighbours (held at
    the ends) so the format's uniform spacing holds, and flagged in two
    extra columns: ``received`` (1: the sample's frame arrived) and
    ``valid`` (1: the row holds the board's own finite values; 0: it is
    interpolated). Nothing is hidden: ``valid = 0`` marks every row that is
    not a measurement.

    Parameters
    ----------
    design : Design
        What ran (testbed, environment, controller, compensator).
    rate_hz : float
        Sample rate [Hz].
    samples : SampleTracker or list of Sample
        Received samples, strictly increasing index.
    n_rows : int
        Rows to write (last received index + 1 at most useful).
    description : str
        Free text for the TOML.

    Returns
    -------
    Experiment
        The run in the shared format.

    Raises
    ------
    BoardError
        If no received sample holds finite values (nothing to interpolate from).
    """
    from ..experiment import experiment_from_arrays

    tracker = samples
    if not isinstance(tracker, pr.SampleTracker):
        tracker = pr.SampleTracker()
        for sample in samples:
            tracker.add(sample)
    idx = np.frombuffer(tracker.indices, dtype=np.int64) if len(tracker.indices) else np.zeros(0, np.int64)
    valid = np.frombuffer(tracker.valid, dtype=np.int8).astype(bool) if len(tracker.valid) else np.zeros(0, bool)
    if not valid.any():
        raise BoardError(f"none of the {idx.size} samples received holds finite values: nothing to save")
    rows = np.arange(n_rows)
    received = np.zeros(n_rows)
    received[idx[idx < n_rows]] = 1.0
    good = np.zeros(n_rows)
    good[idx[valid & (idx < n_rows)]] = 1.0

    def col(name: str) -> np.ndarray:
        vals = np.frombuffer(tracker.column(name), dtype=np.float64)
        return np.interp(rows, idx[valid], vals[valid])

    q = col("q")
    if design.environment.locked:
        q = np.zeros(n_rows)
    extra = {name: col(name) for name in tracker._fields if name != "t" and name not in _FORMAT_FIELDS}
    extra.update(received=received, valid=good)
    return experiment_from_arrays(design, rate_hz, rows / rate_hz, col("tau_m"), col("theta"), q,
                                  tau_s=col("tau_s"), tau_r=col("tau_r"), extra=extra,
                                  description=description)


def check_writable(out: str | Path) -> Path:
    """Check before a run that the experiment can be written to ``out`` (TOML, CSV beside it).

    Creates missing folders and a probe file in the destination folder (removed
    again), so a run is never recorded only to be lost at the end.

    Parameters
    ----------
    out : str or Path
        The experiment TOML to write.

    Returns
    -------
    Path
        ``out`` as a path.

    Raises
    ------
    ParameterError
        One line naming the path and why it cannot be written.
    """
    path = Path(out)
    if path.name in ("", ".", ".."):
        raise ParameterError(f"--out {str(out)!r}: expected a file name such as run.toml", name="out", value=str(out))
    for target in (path, path.with_suffix(".csv")):
        try:
            fileio.check_writable(target, stream_ok=False)   # the probe every output uses; a set needs files
        except OutputError as exc:
            raise ParameterError(f"--out {exc}", name="out", value=str(out)) from None
    return path


def _save_with_recovery(experiment, out: Path) -> tuple[str, str | None]:
    """Save ``experiment`` to ``out``; if that fails, to a recovery file. Return (path, failure or None)."""
    from ..experiment import save_experiment

    try:
        return str(save_experiment(experiment, out)), None
    except (OSError, ForecastError) as exc:
        failure = f"cannot write {out} ({getattr(exc, 'strerror', None) or exc})"
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for folder in (Path.cwd(), Path(tempfile.gettempdir())):
        try:
            fd, name = tempfile.mkstemp(dir=folder, prefix=f"forecast-run-recovery-{stamp}-", suffix=".toml")
            os.close(fd)
            return str(save_experiment(experiment, name)), failure
        except (OSError, ForecastError):
            continue
    raise BoardError(f"{failure}; no recovery file could be written either (current folder and temporary folder)")


#: Least time a command's answer (ACK, PONG) is awaited [s], whatever the stream timeout.
ACK_TIMEOUT_S = 2.0
#: HEARTBEAT interval during a run [s]; the firmware's link timeout (100 ms by default) is 5 of them.
HEARTBEAT_S = 0.02
#: Sample rates a board may report in INFO [Hz]; anything else (NaN, negative, absurd) is refused.
MIN_RATE_HZ, MAX_RATE_HZ = PHYSICAL_RANGES["rate_hz"][:2]


def run_deadline_s(n_samples: int, rate_hz: float, timeout: float) -> float:
    """How long after START a run may last, whatever the board sends [s].

    The expected duration ``n_samples / rate_hz`` plus 10 %, plus the
    silence timeout, plus 2 s for the board to start and finish. A board
    that floods garbage, stale samples or other frames past this is stopped
    and the run ends with what was received (saved and counted).

    Parameters
    ----------
    n_samples : int
        Samples requested at START [-].
    rate_hz : float
        Sample rate [Hz].
    timeout : float
        Silence that counts as a disconnect [s].

    Returns
    -------
    float
        The deadline, measured from START [s].
    """
    return 1.1 * n_samples / rate_hz + timeout + 2.0


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
        if not (isinstance(timeout, (int, float)) and 0.0 < timeout <= 3600.0):
            raise ParameterError(f"timeout must be in (0, 3600] [s], got {timeout!r}", name="timeout", value=timeout)
        self.link = Link(port, baudrate=baudrate)
        self.timeout = float(timeout)
        self._seq = 0
        self.parser = pr.FrameParser(pr.BOARD_TYPES)
        self.sequence = pr.SequenceCounter()
        self.rate_hz: float | None = None
        self._pending: list[pr.Frame] = []  # frames parsed but not yet consumed (kept in order)
        self._stash: list[pr.Frame] = []    # SAMPLE/DONE frames seen while awaiting an answer
        self._fault: str | None = None      # FAULT the board reported during the current run
        self._stats: dict | None = None     # STATS the board reported during the current run

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

    def _noted(self, frames: list[pr.Frame]) -> list[pr.Frame]:
        for frame in frames:
            self.sequence.note(frame.seq)
        return frames

    def _feed(self, chunk: bytes) -> list[pr.Frame]:
        return self._noted(self.parser.feed(chunk))

    def _frames(self, timeout: float) -> list[pr.Frame]:
        """Frames left over from an earlier read first, then whatever the link brings."""
        if self._pending:
            frames, self._pending = self._pending, []
            return frames
        return self._feed(self.link.read(timeout=timeout))

    def _await(self, want: int, seq: int | None = None) -> pr.Frame:
        """Next frame of type ``want`` (an ACK must acknowledge ``seq``); BoardError on NAK/timeout.

        SAMPLE and DONE frames that arrive meanwhile (a board that starts streaming before its
        ACK is read) are kept for the run, not dropped.
        """
        # A command's answer may take longer than a gap in the 2 kHz stream (the board may be
        # busy setting up, the host loaded): answers get at least ACK_TIMEOUT_S.
        wait = max(self.timeout, ACK_TIMEOUT_S)
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            frames = self._frames(0.02)
            for i, frame in enumerate(frames):
                if frame.type == pr.MsgType.ACK and want == pr.MsgType.ACK:
                    a_type, a_seq, status = pr.decode_ack(frame.payload)
                    if a_seq != seq:
                        continue
                    self._pending = frames[i + 1:] + self._pending
                    if status != pr.Ack.OK:
                        raise BoardError(f"{self.link.port}: board refused {pr.type_name(a_type)}: "
                                         f"{pr.status_name(status)}")
                    return frame
                if frame.type == want:
                    self._pending = frames[i + 1:] + self._pending
                    return frame
                if frame.type in (pr.MsgType.SAMPLE, pr.MsgType.DONE) and len(self._stash) <= pr.MAX_RUN_SAMPLES:
                    self._stash.append(frame)
        raise LinkError(f"{self.link.port}: no {pr.type_name(want)} within {wait} s "
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
            A board speaking another protocol version, or reporting a rate outside
            [MIN_RATE_HZ, MAX_RATE_HZ] (NaN, infinite, negative, absurd).
        """
        deadline = time.monotonic() + connect_timeout
        while True:
            self._send(pr.MsgType.PING)
            resend = time.monotonic() + 0.25
            while time.monotonic() < resend:
                for frame in self._feed(self.link.read(timeout=0.02)):
                    if frame.type == pr.MsgType.INFO:
                        version, rate, _ = pr.decode_info(frame.payload)
                        if version != pr.PROTOCOL_VERSION:
                            raise BoardError(f"{self.link.port}: board speaks protocol {version}, "
                                             f"host speaks {pr.PROTOCOL_VERSION}")
                        if not (math.isfinite(rate) and MIN_RATE_HZ <= rate <= MAX_RATE_HZ):
                            raise BoardError(f"{self.link.port}: board reports a sample rate of {rate!r} Hz; "
                                             f"expected {MIN_RATE_HZ:g} .. {MAX_RATE_HZ:g} Hz")
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

    def _consume(self, frames: list[pr.Frame], tracker: pr.SampleTracker) -> bool:
        """Record the samples of ``frames``; True at DONE (later frames stay pending)."""
        for i, frame in enumerate(frames):
            if frame.type == pr.MsgType.SAMPLE:
                tracker.add(pr.decode_sample(frame.payload))
            elif frame.type == pr.MsgType.FAULT:
                self._fault = pr.fault_name(pr.decode_fault(frame.payload)[1])
            elif frame.type == pr.MsgType.STATS:
                self._stats = pr.decode_stats(frame.payload).to_mapping()
            elif frame.type == pr.MsgType.DONE:
                self._pending = frames[i + 1:] + self._pending
                return True
        return False

    def run(self, reference: pr.Reference | str, duration: float, design: Design, out: str | Path, *,
            description: str = "") -> RunResult:
        """Record one run and save it as an experiment (TOML + CSV, each written atomically).

        Parameters
        ----------
        reference : Reference or str
            Force reference (``"square:0.2:0.5"`` accepted).
        duration : float
            Run length [s]: at least one sample period, at most
            :data:`protocol.MAX_RUN_SAMPLES` samples.
        design : Design
            What is running (goes to the TOML).
        out : str or Path
            Experiment TOML path; checked writable before START. Should writing
            still fail at the end, the run goes to a recovery file
            (``forecast-run-recovery-*.toml`` in the current or the temporary
            folder) and the error says where.
        description : str
            Free text for the TOML.

        Returns
        -------
        RunResult
            Counts of samples, losses, invalid samples, protocol errors, corrupt frames and resyncs.

        Raises
        ------
        ParameterError
            A duration giving no sample or too many, an unwritable ``out``.
        LinkError
            The board went silent, the port failed, or the run passed its deadline
            (:func:`run_deadline_s`); whatever was received is saved first
            (``exc.saved``, ``exc.summary``).
        """
        if isinstance(reference, str):
            reference = pr.parse_reference(reference)
        if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0.0):
            raise ParameterError(f"duration must be > 0 [s], got {duration!r}", name="duration", value=duration)
        out = check_writable(out)
        if self.rate_hz is None:
            self.ping()
        rate = float(self.rate_hz)
        n = int(round(duration * rate))
        if n < 1:
            raise ParameterError(f"duration {duration!r} s is less than one sample at {rate:g} Hz "
                                 f"(at least {1.0 / rate:.3g} s)", name="duration", value=duration)
        if n > pr.MAX_RUN_SAMPLES:
            raise ParameterError(f"duration {duration!r} s is {n} samples at {rate:g} Hz; a run records at most "
                                 f"{pr.MAX_RUN_SAMPLES} ({pr.MAX_RUN_SAMPLES / rate:.0f} s)",
                                 name="duration", value=duration)
        self._command(pr.MsgType.SET_REFERENCE, pr.encode_reference(reference))
        stats_before = (self.parser.stats.corrupt_frames, self.parser.stats.resyncs)
        seq_before = (self.sequence.skipped, self.sequence.repeated)
        tracker = pr.SampleTracker(n)
        completed, error, overran = False, None, False
        self._fault, self._stats = None, None
        limit = run_deadline_s(n, rate, self.timeout)
        self._stash = []
        try:
            # Inside the try: a board that streams and disconnects before its ACK is read
            # (a loaded host) still has its samples saved and counted.
            deadline = time.monotonic() + limit
            self._command(pr.MsgType.START, pr.encode_start(n))
            early, self._stash = self._stash, []
            completed = self._consume(early, tracker)
            last_data = last_beat = time.monotonic()
            while not completed:
                now = time.monotonic()
                if now - last_beat > HEARTBEAT_S:  # a board stops its run when the host falls silent
                    self._send(pr.MsgType.HEARTBEAT)
                    last_beat = now
                if now > deadline:
                    overran = True
                    try:
                        self.stop()
                    except LinkError:
                        pass
                    raise LinkError(f"{self.link.port}: run not finished {limit:.3g} s after START "
                                    f"({n / rate:.3g} s expected; deadline = 1.1 x duration + timeout + 2 s); "
                                    f"stopped after {tracker.received} of {n} samples")
                if self._pending:
                    frames, self._pending = self._pending, []
                else:
                    chunk = self.link.read(timeout=0.05)
                    now = time.monotonic()
                    if chunk:
                        last_data = now
                    elif now - last_data > self.timeout:
                        raise LinkError(f"{self.link.port}: sample stream silent for {self.timeout} s after "
                                        f"{tracker.received} of {n} samples (disconnected?)")
                    frames = self._feed(chunk)
                completed = self._consume(frames, tracker)
                if not completed and tracker.next_index >= n:
                    # every sample is in; a DONE lost to corruption must not hang the run
                    completed = self._grace_for_done(tracker, deadline)
        except LinkError as exc:
            error = exc
            frames = self._stash + self._pending + self._noted(self.parser.close())
            self._stash, self._pending = [], []
            if self._consume(frames, tracker) and not overran:
                error = None  # the DONE was there, behind a false sync: the run is complete
            self._pending = []
        tracker.finish(n)
        stats = self.parser.stats
        result = RunResult(
            samples=tracker.received, expected=n, lost=tracker.n_lost, lost_ranges=tuple(tracker.lost),
            corrupt_frames=stats.corrupt_frames - stats_before[0], resyncs=stats.resyncs - stats_before[1],
            out_of_order=tracker.out_of_order, completed=error is None and self._fault is None,
            invalid=tracker.invalid,
            fault=self._fault, stats=self._stats,
            out_of_range=tracker.out_of_range, seq_skipped=self.sequence.skipped - seq_before[0],
            seq_repeated=self.sequence.repeated - seq_before[1],
        )
        path, failure = None, None
        if tracker.received and any(tracker.valid):
            n_rows = tracker.next_index
            text = description or f"recorded on {self.link.port}: reference {reference.to_string()}, {duration} s"
            if result.lost:
                text += f"; {result.lost} lost samples interpolated (columns received = 0, valid = 0)"
            if self._fault:
                text += f"; the board stopped the run on fault {self._fault} (torque set to zero)"
            if result.invalid:
                text += f"; {result.invalid} samples with NaN/inf values interpolated (column valid = 0)"
            exp = record_to_experiment(design, rate, tracker, n_rows, description=text)
            path, failure = _save_with_recovery(exp, out)
        result = dataclasses.replace(result, path=path)
        if error is not None:
            self.parser = pr.FrameParser(pr.BOARD_TYPES)
            if path:
                saved = f"; saved {result.samples} samples to {path}"
            else:
                saved = "; nothing received" if not tracker.received else "; no finite sample to save"
            if failure:
                saved += f" ({failure})"
            raise LinkError(f"{error}{saved}; lost {result.lost}", summary=result.to_mapping(),
                            saved=path) from None
        if failure:
            raise BoardError(f"{failure}: the run was saved to the recovery file {path} instead",
                             summary=result.to_mapping(), saved=path)
        if self._fault:
            raise BoardError(f"{self.link.port}: the board stopped the run on fault {self._fault} after "
                             f"{result.samples} of {n} samples (torque set to zero)"
                             + (f"; saved to {path}" if path else ""), summary=result.to_mapping(), saved=path)
        if not path:
            raise BoardError(f"{self.link.port}: none of the {result.samples} samples received holds finite "
                             "values: nothing saved", summary=result.to_mapping())
        return result

    def _grace_for_done(self, tracker: pr.SampleTracker, deadline: float) -> bool:
        end = min(time.monotonic() + min(self.timeout, 0.2), deadline)
        while time.monotonic() < end:
            if self._consume(self._feed(self.link.read(timeout=0.02)), tracker):
                return True
        return True

    def stop(self) -> None:
        """Ask the board to stop a run."""
        self._send(pr.MsgType.STOP)
