"""The board link's framed binary protocol: pure encoding and incremental parsing (bytes in, frames out).

See ``docs/protocol.md`` for the byte layout. Nothing here touches a serial
port, so every property (resynchronisation, CRC rejection, loss accounting) is
testable without hardware.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import Any
from enum import IntEnum

from ..errors import ParameterError

__all__ = [
    "SYNC",
    "HEADER_SIZE",
    "CRC_SIZE",
    "MAX_PAYLOAD",
    "PROTOCOL_VERSION",
    "BAUD_RATE",
    "MsgType",
    "Ack",
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
    "encode_done",
    "decode_done",
    "encode_info",
    "decode_info",
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
#: Version number the board reports in INFO.
PROTOCOL_VERSION = 1
#: UART rate of the link [bit/s]; the 2 kHz sample stream needs 740 kbit/s (see docs/protocol.md).
BAUD_RATE = 921_600

_LEN = struct.Struct("<H")
_HDR = struct.Struct("<HBH")  # length, type, sequence
_SAMPLE = struct.Struct("<I6f")  # index, t, tau_m, theta, q, tau_s, tau_r
_REFERENCE = struct.Struct("<B3f")  # kind, amplitude, period/delay, offset
_START = struct.Struct("<I")  # samples to record
_ACK = struct.Struct("<BHB")  # acked type, acked sequence, status
_DONE = struct.Struct("<IB")  # samples sent, reason
_INFO = struct.Struct("<BfI")  # protocol version, rate_hz, max upload bytes


class MsgType(IntEnum):
    """Message types (host -> board below 0x80, board -> host from 0x80)."""

    PING = 0x01          #: host asks for INFO
    UPLOAD = 0x10        #: controller coefficient blob (see export.c.ControllerProgram.to_bytes)
    SET_REFERENCE = 0x11  #: reference generator settings
    START = 0x12         #: start a run of N samples
    STOP = 0x13          #: stop the run now
    ACK = 0x80           #: acknowledges one host frame (status 0 = ok)
    INFO = 0x81          #: protocol version and sample rate
    SAMPLE = 0x90        #: one recorded sample
    DONE = 0x91          #: the run ended


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
}


_KNOWN_TYPES = frozenset(int(t) for t in MsgType)


def crc16_ccitt_false(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor).

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
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def _crc_table() -> tuple[int, ...]:
    return tuple(crc16_ccitt_false(bytes([b]), 0) for b in range(256))


_TABLE = _crc_table()


def _crc(data: bytes) -> int:
    """Table-driven CRC-16/CCITT-FALSE (same result as crc16_ccitt_false, faster)."""
    crc = 0xFFFF
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _TABLE[((crc >> 8) ^ byte) & 0xFF]
    return crc


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

    Examples
    --------
    >>> p = FrameParser()
    >>> frames = p.feed(b"junk" + encode_frame(MsgType.PING, 7))
    >>> [(f.type, f.seq) for f in frames], p.stats.resyncs
    ([(1, 7)], 1)
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._skipping = False
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
            if (msg_type not in _KNOWN_TYPES or length > MAX_PAYLOAD
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


@dataclass(frozen=True, slots=True)
class Sample:
    """One recorded sample as streamed by the board (float32 on the wire).

    Parameters
    ----------
    index : int
        Sample number since START, from 0 [-].
    t : float
        Board time [s].
    tau_m : float
        Motor torque command applied over [t, t + 1/rate) [N m].
    theta : float
        Motor angle [rad].
    q : float
        Environment/joint angle [rad].
    tau_s : float
        Spring torque [N m].
    tau_r : float
        Force reference [N m].
    """

    index: int
    t: float
    tau_m: float
    theta: float
    q: float
    tau_s: float
    tau_r: float


def encode_sample(s: Sample) -> bytes:
    """SAMPLE payload: uint32 index then six float32 (t, tau_m, theta, q, tau_s, tau_r)."""
    return _SAMPLE.pack(s.index & 0xFFFFFFFF, s.t, s.tau_m, s.theta, s.q, s.tau_s, s.tau_r)


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
    form = "expected square:AMP:PERIOD, sine:AMP:PERIOD or step:AMP[:DELAY] (N m, s)"
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


def encode_done(n_sent: int, reason: int = 0) -> bytes:
    """DONE payload: uint32 samples sent, uint8 reason (0 complete, 1 stopped)."""
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
        Frame bytes x rate x bits per byte [bit/s]; 37 x 2000 x 10 = 740000 at 2 kHz.
    """
    frame_bytes = HEADER_SIZE + _SAMPLE.size + CRC_SIZE
    return float(frame_bytes * rate_hz * bits_per_byte)


@dataclass(slots=True)
class SampleTracker:
    """Loss accounting over the sample indices received.

    Samples must arrive with strictly increasing indices; a gap is counted
    as lost (by index), a repeated or older index as out of order and kept
    out of the record (the counter says so: nothing is dropped silently).

    Attributes
    ----------
    samples : list of Sample
        Accepted samples, strictly increasing index.
    lost : list of tuple of int
        Half-open ranges ``(first, stop)`` of missing indices.
    out_of_order : int
        Samples rejected for a non-increasing index.
    """

    samples: list = field(default_factory=list)
    lost: list = field(default_factory=list)
    out_of_order: int = 0

    @property
    def next_index(self) -> int:
        """Index expected next [-]."""
        return self.samples[-1].index + 1 if self.samples else 0

    def add(self, sample: Sample) -> None:
        """Record one received sample."""
        expected = self.next_index
        if sample.index < expected:
            self.out_of_order += 1
            return
        if sample.index > expected:
            self.lost.append((expected, sample.index))
        self.samples.append(sample)

    def finish(self, n_expected: int) -> None:
        """Count the missing tail once the run is over (``n_expected`` samples were due)."""
        if self.next_index < n_expected:
            self.lost.append((self.next_index, n_expected))

    @property
    def n_lost(self) -> int:
        """Number of lost samples [-]."""
        return sum(stop - first for first, stop in self.lost)
