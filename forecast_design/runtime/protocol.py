"""The board link's framed binary protocol: pure encoding and incremental parsing (bytes in, frames out).

See ``docs/protocol.md`` for the byte layout. Nothing here touches a serial
port, so every property (resynchronisation, CRC rejection, loss accounting) is
testable without hardware. The recorded samples and their loss accounting live in
:mod:`forecast_design.runtime.samples` (re-exported here: ``Sample``, ``SampleTracker``,
``SequenceCounter``, ``MAX_RUN_SAMPLES``).
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass
from typing import Any
from enum import IntEnum

from ..errors import ParameterError
from .samples import MAX_RUN_SAMPLES, Sample, SampleTracker, SequenceCounter

__all__ = [
    "SYNC",
    "HEADER_SIZE",
    "CRC_SIZE",
    "MAX_PAYLOAD",
    "PROTOCOL_VERSION",
    "BAUD_RATE",
    "MsgType",
    "Ack",
    "BOARD_TYPES",
    "HOST_TYPES",
    "MAX_RUN_SAMPLES",
    "SequenceCounter",
    "Frame",
    "Sample",
    "Reference",
    "crc16_ccitt_false",
    "encode_frame",
    "FrameParser",
    "ParserStats",
    "SampleTracker",
    "encode_sample",
    "decode_sample",
    "encode_reference",
    "decode_reference",
    "encode_start",
    "decode_start",
    "encode_ack",
    "decode_ack",
    "type_name",
    "status_name",
    "encode_done",
    "decode_done",
    "encode_info",
    "decode_info",
    "Fault",
    "encode_sensor",
    "decode_sensor",
    "encode_fault",
    "decode_fault",
    "fault_name",
    "encode_stats",
    "decode_stats",
    "Stats",
    "parse_reference",
    "stream_bits_per_second",
]

#: Two sync bytes open every frame; 0xA5 0x5A is rare in float32 sample data.
SYNC = b"\xa5\x5a"
#: sync (2) + length (2) + type (1) + sequence (2) [bytes].
HEADER_SIZE = 7
#: CRC-16/CCITT-FALSE, little-endian [bytes].
CRC_SIZE = 2
#: Longest payload a receiver accepts; a larger length field is a corrupt header [bytes].
MAX_PAYLOAD = 1024
#: Version number the board reports in INFO (2: SAMPLE carries u and tau_frc_hat; HEARTBEAT,
#: SENSOR, FAULT and STATS messages).
PROTOCOL_VERSION = 2
#: UART rate of the link [bit/s]; the 2 kHz sample stream needs 900 kbit/s (see docs/protocol.md).
#: 2 Mbit/s is an exact divisor of the F446RE's 42 MHz APB1 clock (USARTDIV 1 + 5/16).
BAUD_RATE = 2_000_000

_LEN = struct.Struct("<H")
_HDR = struct.Struct("<HBH")  # length, type, sequence
_SAMPLE = struct.Struct("<I8f")  # index, t, tau_m, theta, q, tau_s, tau_r, u, tau_frc_hat
_REFERENCE = struct.Struct("<B3f")  # kind, amplitude, period/delay, offset
_START = struct.Struct("<I")  # samples to record
_ACK = struct.Struct("<BHB")  # acked type, acked sequence, status
_DONE = struct.Struct("<IB")  # samples sent, reason
_INFO = struct.Struct("<BfI")  # protocol version, rate_hz, max upload bytes
_SENSOR = struct.Struct("<III")  # period index, raw motor encoder count, raw environment encoder count
_FAULT = struct.Struct("<IB")  # sample index, fault code
_STATS = struct.Struct("<IIfIfI")  # steps, max ticks, mean ticks, calibration ticks, tick rate, calib instr.


class MsgType(IntEnum):
    """Message types (host -> board below 0x80, board -> host from 0x80)."""

    PING = 0x01          #: host asks for INFO
    UPLOAD = 0x10        #: controller coefficient blob (see program.ControllerProgram.to_bytes)
    SET_REFERENCE = 0x11  #: reference generator settings
    START = 0x12         #: start a run of N samples
    STOP = 0x13          #: stop the run now
    HEARTBEAT = 0x14     #: the host is alive (no reply); a board faults when they stop during a run
    SENSOR = 0x15        #: processor-in-the-loop: raw encoder counts of one period (board answers SAMPLE)
    ACK = 0x80           #: acknowledges one host frame (status 0 = ok)
    INFO = 0x81          #: protocol version and sample rate
    SAMPLE = 0x90        #: one recorded sample
    DONE = 0x91          #: the run ended
    FAULT = 0x92         #: the board stopped the run on a fault (torque set to zero)
    STATS = 0x93         #: the board's measured cost of a control period


class Ack(IntEnum):
    """ACK status codes."""

    OK = 0
    BAD_PAYLOAD = 1      #: payload malformed for its type
    NO_CONTROLLER = 2    #: START before a valid UPLOAD
    BUSY = 3             #: a run is in progress
    UNKNOWN_TYPE = 4     #: type not understood


#: Payload lengths of the fixed-size message types; a mismatch marks the header corrupt.
_FIXED_LENGTH = {
    MsgType.PING: 0,
    MsgType.SET_REFERENCE: _REFERENCE.size,
    MsgType.START: _START.size,
    MsgType.STOP: 0,
    MsgType.ACK: _ACK.size,
    MsgType.INFO: _INFO.size,
    MsgType.SAMPLE: _SAMPLE.size,
    MsgType.DONE: _DONE.size,
    MsgType.HEARTBEAT: 0,
    MsgType.SENSOR: _SENSOR.size,
    MsgType.FAULT: _FAULT.size,
    MsgType.STATS: _STATS.size,
}


_KNOWN_TYPES = frozenset(int(t) for t in MsgType)
#: Types a board sends (0x80 and up); the host's parser accepts these only.
BOARD_TYPES = frozenset(t for t in _KNOWN_TYPES if t >= 0x80)
#: Types a host sends (below 0x80); the board's parser accepts these only.
HOST_TYPES = frozenset(t for t in _KNOWN_TYPES if t < 0x80)


def crc16_ccitt_false(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor).

    The standard library's ``binascii.crc_hqx`` is exactly this CRC (the
    XMODEM/CCITT polynomial, unreflected, no final xor) with a free initial
    value; the test suite checks it against a bit-by-bit reference on random frames.

    Parameters
    ----------
    data : bytes
        Message bytes.
    crc : int
        Running CRC to continue from [-].

    Returns
    -------
    int
        The 16-bit CRC; ``crc16_ccitt_false(b"123456789") == 0x29B1``.
    """
    return binascii.crc_hqx(data, crc & 0xFFFF)


def _crc(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of a frame body (init 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded frame.

    Parameters
    ----------
    type : int
        Message type (a :class:`MsgType` value when known).
    seq : int
        Sender's frame counter modulo 65536 [-].
    payload : bytes
        Message body.
    """

    type: int
    seq: int
    payload: bytes


def encode_frame(msg_type: int, seq: int, payload: bytes = b"") -> bytes:
    """Encode one frame: sync, length, type, sequence, payload, CRC.

    Parameters
    ----------
    msg_type : int
        Message type, 0..255.
    seq : int
        Frame sequence number; taken modulo 65536.
    payload : bytes
        At most :data:`MAX_PAYLOAD` bytes.

    Returns
    -------
    bytes
        The frame; the CRC covers length, type, sequence and payload.

    Raises
    ------
    ParameterError
        If the payload is too long or the type out of range.
    """
    if len(payload) > MAX_PAYLOAD:
        raise ParameterError(f"frame payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}",
                             name="payload", value=len(payload))
    if not 0 <= int(msg_type) <= 255:
        raise ParameterError(f"message type must be 0..255, got {msg_type}", name="msg_type", value=msg_type)
    body = _HDR.pack(len(payload), int(msg_type), seq & 0xFFFF) + bytes(payload)
    return SYNC + body + _LEN.pack(_crc(body))


@dataclass(slots=True)
class ParserStats:
    """Counters of what the parser could not use.

    Attributes
    ----------
    frames : int
        Intact frames delivered.
    corrupt_frames : int
        Candidate frames (plausible header) whose CRC failed.
    resyncs : int
        Times the parser had to skip bytes to find the next sync.
    discarded_bytes : int
        Bytes skipped while resynchronising.
    truncated_bytes : int
        Bytes of an unfinished frame at the end of the stream.
    """

    frames: int = 0
    corrupt_frames: int = 0
    resyncs: int = 0
    discarded_bytes: int = 0
    truncated_bytes: int = 0

    def to_mapping(self) -> dict[str, int]:
        """The counters as a dict (for JSON)."""
        return {"frames": self.frames, "corrupt_frames": self.corrupt_frames, "resyncs": self.resyncs,
                "discarded_bytes": self.discarded_bytes, "truncated_bytes": self.truncated_bytes}


class FrameParser:
    """Incremental frame parser that resynchronises after garbage.

    Feed it bytes as they arrive; it returns the intact frames in stream
    order. A candidate whose header is implausible or whose CRC fails is
    abandoned by skipping only its first byte, so a real frame that starts
    inside the rejected span (a corrupt length field, dropped bytes) is
    still found: an intact frame is never lost to a neighbour's damage.

    Parameters
    ----------
    types : frozenset of int, optional
        Message types this end accepts (default: every known type). The host
        passes :data:`BOARD_TYPES`, so a header of a host-bound type arriving
        from the board (say an UPLOAD claiming 1024 bytes) is a false sync,
        skipped at once instead of swallowing the frames that follow it.

    Examples
    --------
    >>> p = FrameParser()
    >>> frames = p.feed(b"junk" + encode_frame(MsgType.PING, 7))
    >>> [(f.type, f.seq) for f in frames], p.stats.resyncs
    ([(1, 7)], 1)
    """

    def __init__(self, types: "frozenset[int] | None" = None) -> None:
        self._buf = bytearray()
        self._skipping = False
        self._types = _KNOWN_TYPES if types is None else frozenset(int(t) for t in types) & _KNOWN_TYPES
        self.stats = ParserStats()

    def _skip(self, n: int) -> None:
        if n <= 0:
            return
        if not self._skipping:
            self.stats.resyncs += 1
            self._skipping = True
        self.stats.discarded_bytes += n
        del self._buf[:n]

    def _parse(self, final: bool) -> list[Frame]:
        out: list[Frame] = []
        buf = self._buf
        while True:
            i = buf.find(SYNC)
            if i < 0:
                # keep a trailing first sync byte: it may pair with the next chunk
                keep = 1 if (buf[-1:] == SYNC[:1] and not final) else 0
                self._skip(len(buf) - keep)
                return out
            self._skip(i)
            if len(buf) < HEADER_SIZE:
                if final:
                    self.stats.truncated_bytes += len(buf)
                    self._skip(len(buf))
                return out
            length, msg_type, seq = _HDR.unpack_from(buf, 2)
            fixed = _FIXED_LENGTH.get(msg_type)
            if (msg_type not in self._types or length > MAX_PAYLOAD
                    or (fixed is not None and length != fixed)):
                self._skip(1)
                continue
            end = HEADER_SIZE + length + CRC_SIZE
            if len(buf) < end:
                if not final:
                    return out
                # the stream ended inside this candidate: it may be a truncated frame or
                # a false sync in garbage, so keep scanning the rest for intact frames
                self.stats.truncated_bytes += 1
                self._skip(1)
                continue
            (crc,) = _LEN.unpack_from(buf, end - CRC_SIZE)
            if crc != _crc(bytes(buf[2:end - CRC_SIZE])):
                self.stats.corrupt_frames += 1
                self._skip(1)
                continue
            out.append(Frame(msg_type, seq, bytes(buf[HEADER_SIZE:end - CRC_SIZE])))
            self.stats.frames += 1
            del buf[:end]
            self._skipping = False

    def feed(self, data: bytes) -> list[Frame]:
        """Consume bytes; return the frames completed by them, in order.

        Parameters
        ----------
        data : bytes
            The next bytes of the stream (any chunking).

        Returns
        -------
        list of Frame
            Intact frames, in stream order.
        """
        self._buf.extend(data)
        return self._parse(final=False)

    def close(self) -> list[Frame]:
        """Declare the end of the stream; return frames still recoverable from the buffer.

        Returns
        -------
        list of Frame
            Intact frames found in the remaining bytes; any unfinished
            frame is counted in ``stats.truncated_bytes``.
        """
        return self._parse(final=True)

    @property
    def pending(self) -> int:
        """Bytes buffered but not yet resolved into frames or garbage [bytes]."""
        return len(self._buf)


def encode_sample(s: Sample) -> bytes:
    """SAMPLE payload: uint32 index then eight float32 (t, tau_m, theta, q, tau_s, tau_r, u, tau_frc_hat)."""
    return _SAMPLE.pack(s.index & 0xFFFFFFFF, s.t, s.tau_m, s.theta, s.q, s.tau_s, s.tau_r, s.u, s.tau_frc_hat)


def decode_sample(payload: bytes) -> Sample:
    """Inverse of :func:`encode_sample`."""
    return Sample(*_SAMPLE.unpack(payload))


#: Reference kinds on the wire.
REFERENCE_KINDS = {"step": 0, "square": 1, "sine": 2}


@dataclass(frozen=True, slots=True)
class Reference:
    """Force reference generator tau_r(t).

    Parameters
    ----------
    kind : str
        ``step``: ``offset`` before ``period`` [s], ``offset + amplitude`` after;
        ``square``: ``offset + amplitude`` for the first half of each period,
        ``offset - amplitude`` for the second; ``sine``: ``offset + amplitude sin(2 pi t / period)``.
    amplitude : float
        [N m].
    period : float
        Period of square/sine [s]; delay of step [s].
    offset : float
        Constant added [N m].
    """

    kind: str
    amplitude: float
    period: float = 0.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in REFERENCE_KINDS:
            raise ParameterError(f"reference kind must be one of {', '.join(REFERENCE_KINDS)}, got {self.kind!r}",
                                 name="reference", value=self.kind)
        for name in ("amplitude", "period", "offset"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ParameterError(f"reference {name} must be finite, got {v!r}", name=name, value=v)
        if self.kind in ("square", "sine") and self.period <= 0.0:
            raise ParameterError(f"reference {self.kind} period must be > 0 [s], got {self.period!r}",
                                 name="period", value=self.period)
        if self.kind == "step" and self.period < 0.0:
            raise ParameterError(f"reference step delay must be >= 0 [s], got {self.period!r}",
                                 name="period", value=self.period)

    def signal(self) -> Any:
        """The same reference as a :mod:`forecast_design.simulation.references` signal (one home).

        Returns
        -------
        Step, Square or Sine
            Callable on times [s] since START, values in [N m].
        """
        from ..simulation import references as refs   # the protocol itself stays numpy-free

        if self.kind == "step":
            return refs.Step(amplitude=self.amplitude, t0=self.period, offset=self.offset)
        if self.kind == "square":
            return refs.Square(high=self.offset + self.amplitude, low=self.offset - self.amplitude,
                               period_s=self.period)
        return refs.Sine(amplitude=self.amplitude, frequency_hz=1.0 / self.period, offset=self.offset)

    def value(self, t: float) -> float:
        """Reference at time ``t`` [s] since START, in [N m]."""
        return float(self.signal()(t))

    def to_string(self) -> str:
        """The ``kind:amplitude[:period]`` form accepted by :func:`parse_reference`."""
        text = f"{self.kind}:{self.amplitude!r}"
        if self.kind != "step" or self.period:
            text += f":{self.period!r}"
        return text


#: The colon syntax of :func:`parse_reference` (the ``run --reference`` help quotes it). The
#: numbers map onto :mod:`forecast_design.simulation.references` as ``Square(period_s=PERIOD)``,
#: ``Sine(frequency_hz=1/PERIOD)`` and ``Step(t0=DELAY)`` (:meth:`Reference.signal`).
REFERENCE_SYNTAX = "square:AMP:PERIOD, sine:AMP:PERIOD or step:AMP[:DELAY] (N m, s)"


def parse_reference(text: str) -> Reference:
    """Parse ``square:AMP:PERIOD``, ``sine:AMP:PERIOD`` or ``step:AMP[:DELAY]``.

    Parameters
    ----------
    text : str
        E.g. ``"square:0.2:0.5"`` (0.2 N m amplitude, 0.5 s period).

    Returns
    -------
    Reference
        The reference generator.

    Raises
    ------
    ParameterError
        One line naming the string and the expected form.
    """
    form = f"expected {REFERENCE_SYNTAX}"
    parts = str(text).split(":")
    try:
        numbers = [float(p) for p in parts[1:]]
    except ValueError:
        raise ParameterError(f"reference {text!r}: {form}", name="reference", value=text) from None
    kind = parts[0]
    ok = (kind in ("square", "sine") and len(numbers) == 2) or (kind == "step" and len(numbers) in (1, 2))
    if not ok:
        raise ParameterError(f"reference {text!r}: {form}", name="reference", value=text)
    try:
        return Reference(kind, numbers[0], numbers[1] if len(numbers) > 1 else 0.0)
    except ParameterError as exc:
        raise ParameterError(f"reference {text!r}: {exc}", name="reference", value=text) from None


def encode_reference(ref: Reference) -> bytes:
    """SET_REFERENCE payload: uint8 kind, float32 amplitude, period, offset."""
    return _REFERENCE.pack(REFERENCE_KINDS[ref.kind], ref.amplitude, ref.period, ref.offset)


def decode_reference(payload: bytes) -> Reference:
    """Inverse of :func:`encode_reference`; ParameterError on an unknown kind."""
    code, amp, period, offset = _REFERENCE.unpack(payload)
    names = {v: k for k, v in REFERENCE_KINDS.items()}
    if code not in names:
        raise ParameterError(f"reference kind code {code} unknown", name="reference", value=code)
    return Reference(names[code], amp, period, offset)


def encode_start(n_samples: int) -> bytes:
    """START payload: uint32 number of samples to record."""
    return _START.pack(n_samples)


def decode_start(payload: bytes) -> int:
    """Inverse of :func:`encode_start`."""
    return _START.unpack(payload)[0]


def encode_ack(acked_type: int, acked_seq: int, status: int = Ack.OK) -> bytes:
    """ACK payload: uint8 acknowledged type, uint16 its sequence, uint8 status."""
    return _ACK.pack(acked_type, acked_seq & 0xFFFF, status)


def decode_ack(payload: bytes) -> tuple[int, int, int]:
    """Inverse of :func:`encode_ack`: (type, seq, status)."""
    return _ACK.unpack(payload)


def type_name(msg_type: int) -> str:
    """The name of a message type, or ``type 0xNN`` for one the protocol does not define."""
    try:
        return MsgType(msg_type).name
    except ValueError:
        return f"type 0x{int(msg_type) & 0xFF:02x}"


def status_name(status: int) -> str:
    """The name of an ACK status, or ``unknown status N`` for one the protocol does not define."""
    try:
        return Ack(status).name
    except ValueError:
        return f"unknown status {int(status)}"


def encode_done(n_sent: int, reason: int = 0) -> bytes:
    """DONE payload: uint32 samples sent, uint8 reason (0 complete, 1 stopped, 2 fault)."""
    return _DONE.pack(n_sent, reason)


def decode_done(payload: bytes) -> tuple[int, int]:
    """Inverse of :func:`encode_done`: (samples sent, reason)."""
    return _DONE.unpack(payload)


def encode_info(rate_hz: float, max_upload: int = MAX_PAYLOAD) -> bytes:
    """INFO payload: uint8 protocol version, float32 rate [Hz], uint32 max upload [bytes]."""
    return _INFO.pack(PROTOCOL_VERSION, rate_hz, max_upload)


def decode_info(payload: bytes) -> tuple[int, float, int]:
    """Inverse of :func:`encode_info`: (version, rate_hz, max upload bytes)."""
    return _INFO.unpack(payload)


class Fault(IntEnum):
    """Fault codes of a FAULT frame; on any of them the board sets the torque to zero and ends the run."""

    LINK_TIMEOUT = 1     #: no valid host frame for the link timeout during a run (a silent host)
    LINK_CORRUPT = 2     #: bytes rejected beyond resynchronisation (more than the garbage limit in a row)
    FRAME_DROPPED = 3    #: a SENSOR frame's period index skipped (processor-in-the-loop)
    OVERRUN = 4          #: a control period started before the previous one finished
    WATCHDOG_RESET = 5   #: the board restarted from its independent watchdog (reported at the next START)
    ENCODER = 6          #: an encoder moved more counts in one period than the plausibility limit
    CONTROLLER = 7       #: the controller's command was NaN or infinite (e.g. a controller written as code failed)


def encode_sensor(index: int, raw_motor: int, raw_env: int) -> bytes:
    """SENSOR payload: uint32 period index, uint32 raw motor and environment encoder counts (mod 2**32)."""
    return _SENSOR.pack(index & 0xFFFFFFFF, raw_motor & 0xFFFFFFFF, raw_env & 0xFFFFFFFF)


def decode_sensor(payload: bytes) -> tuple[int, int, int]:
    """Inverse of :func:`encode_sensor`: (index, raw motor count, raw environment count)."""
    return _SENSOR.unpack(payload)


def encode_fault(index: int, code: int) -> bytes:
    """FAULT payload: uint32 sample index at which the fault was detected, uint8 :class:`Fault` code."""
    return _FAULT.pack(index & 0xFFFFFFFF, int(code))


def decode_fault(payload: bytes) -> tuple[int, int]:
    """Inverse of :func:`encode_fault`: (sample index, fault code)."""
    return _FAULT.unpack(payload)


def fault_name(code: int) -> str:
    """The name of a :class:`Fault` code, or ``code N`` for one the protocol does not define."""
    try:
        return Fault(code).name
    except ValueError:
        return f"code {code}"


@dataclass(frozen=True, slots=True)
class Stats:
    """The board's own measurement of a control period's cost (STATS frame, sent before DONE).

    Fields, in wire order: ``steps`` periods measured [-]; ``max_ticks`` and ``mean_ticks``, the
    longest and mean period computation [SysTick ticks]; ``calib_ticks``, the ticks a fixed loop of
    ``calib_instructions`` instructions took (converts ticks to instructions where the clock counts
    instructions, as under qemu's ``-icount``); ``tick_hz``, the core clock the firmware assumes [Hz].
    """

    steps: int
    max_ticks: int
    mean_ticks: float
    calib_ticks: int
    tick_hz: float
    calib_instructions: int

    @property
    def instructions_per_tick(self) -> float:
        """Executed instructions per SysTick tick, from the calibration loop [-]."""
        return self.calib_instructions / self.calib_ticks if self.calib_ticks else math.nan

    def to_mapping(self) -> dict[str, Any]:
        """All fields plus mean/max instructions per period (via the calibration) [-]."""
        k = self.instructions_per_tick
        return {"steps": self.steps, "max_ticks": self.max_ticks, "mean_ticks": self.mean_ticks,
                "calib_ticks": self.calib_ticks, "calib_instructions": self.calib_instructions,
                "tick_hz": self.tick_hz, "mean_instructions_per_step": self.mean_ticks * k,
                "max_instructions_per_step": self.max_ticks * k}


def encode_stats(s: Stats) -> bytes:
    """STATS payload: uint32 steps, uint32 max ticks, float32 mean ticks, uint32 calibration ticks,
    float32 tick rate [Hz], uint32 calibration instructions."""
    return _STATS.pack(s.steps, s.max_ticks, s.mean_ticks, s.calib_ticks, s.tick_hz, s.calib_instructions)


def decode_stats(payload: bytes) -> Stats:
    """Inverse of :func:`encode_stats`."""
    return Stats(*_STATS.unpack(payload))


def stream_bits_per_second(rate_hz: float = 2000.0, bits_per_byte: int = 10) -> float:
    """Line rate the SAMPLE stream needs [bit/s] (8N1 UART: 10 bits per byte).

    Parameters
    ----------
    rate_hz : float
        Sample rate [Hz].
    bits_per_byte : int
        Start + data + stop bits [-].

    Returns
    -------
    float
        Frame bytes x rate x bits per byte [bit/s]; 45 x 2000 x 10 = 900000 at 2 kHz.
    """
    frame_bytes = HEADER_SIZE + _SAMPLE.size + CRC_SIZE
    return float(frame_bytes * rate_hz * bits_per_byte)
