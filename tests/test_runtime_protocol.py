"""Framed protocol: CRC, encoding round trips, resynchronisation and loss accounting."""

import struct
import numpy as np

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forecast_design.errors import ParameterError
from forecast_design.runtime import protocol as pr


def test_crc16_ccitt_false_standard_check_value():
    # the catalogued check value of CRC-16/CCITT-FALSE (a.k.a. CRC-16/IBM-3740)
    assert pr.crc16_ccitt_false(b"123456789") == 0x29B1
    assert pr._crc(b"123456789") == 0x29B1


def test_stream_fits_baud_rate_with_margin():
    # 45-byte frames x 2000 Hz x 10 bits (8N1) = 900 kbit/s
    frame = len(pr.encode_frame(pr.MsgType.SAMPLE, 0, pr.encode_sample(pr.Sample(0, 0, 0, 0, 0, 0, 0, 0, 0))))
    assert frame * 2000 * 10 == pr.stream_bits_per_second(2000.0)
    assert pr.stream_bits_per_second(2000.0) < 0.85 * pr.BAUD_RATE


def test_sample_round_trip_is_float32_exact():
    s = pr.Sample(12345, 0.5, 0.25, -1.5, 0.125, 2.0, -0.2, 0.3, -0.1)
    back = pr.decode_sample(pr.encode_sample(s))
    assert back.index == 12345
    assert back.tau_r == struct.unpack("<f", struct.pack("<f", -0.2))[0]


@pytest.mark.parametrize("text, kind, amp, period", [
    ("square:0.2:0.5", "square", 0.2, 0.5), ("sine:1:2", "sine", 1.0, 2.0), ("step:0.2", "step", 0.2, 0.0)])
def test_parse_reference_forms(text, kind, amp, period):
    ref = pr.parse_reference(text)
    assert (ref.kind, ref.amplitude, ref.period) == (kind, amp, period)
    assert pr.parse_reference(ref.to_string()) == ref


@pytest.mark.parametrize("text", ["square:0.2", "triangle:1:2", "square:a:1", "sine:1:0", ""])
def test_parse_reference_garbage_is_one_line_parameter_error(text):
    with pytest.raises(ParameterError, match="expected square:AMP:PERIOD|must be > 0") as info:
        pr.parse_reference(text)
    assert "\n" not in str(info.value)


def test_square_reference_values():
    ref = pr.parse_reference("square:0.2:0.5")
    assert ref.value(0.0) == 0.2 and ref.value(0.3) == -0.2 and ref.value(0.5) == 0.2


def _frames(n):
    return [pr.encode_frame(pr.MsgType.SAMPLE, i,
                            pr.encode_sample(pr.Sample(i, i / 2000, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0)))
            for i in range(n)]


def test_parser_any_chunking_gives_same_frames():
    data = b"".join(_frames(20))
    for size in (1, 3, 37, 1000):
        p = pr.FrameParser()
        got = []
        for i in range(0, len(data), size):
            got += p.feed(data[i:i + size])
        assert [f.seq for f in got] == list(range(20))
        assert p.stats.resyncs == 0 and p.stats.corrupt_frames == 0


def test_parser_counts_corrupt_frame_and_resync():
    frames = _frames(3)
    bad = bytearray(frames[1])
    bad[12] ^= 0x10  # payload bit: CRC must catch it
    p = pr.FrameParser()
    got = p.feed(frames[0] + bytes(bad) + frames[2])
    assert [f.seq for f in got] == [0, 2]
    assert p.stats.corrupt_frames == 1 and p.stats.resyncs == 1


def test_parser_truncated_stream_reported_on_close():
    frames = _frames(2)
    p = pr.FrameParser()
    got = p.feed(frames[0] + frames[1][:20])
    assert [f.seq for f in got] == [0]
    assert p.close() == [] and p.stats.truncated_bytes > 0


def test_tracker_counts_gaps_and_tail():
    t = pr.SampleTracker()
    for i in (0, 1, 4, 5, 9):
        t.add(pr.Sample(i, 0, 0, 0, 0, 0, 0, 0, 0))
    t.add(pr.Sample(5, 0, 0, 0, 0, 0, 0, 0, 0))  # a repeat is counted, not recorded
    t.finish(12)
    assert t.lost == [(2, 4), (6, 9), (10, 12)] and t.n_lost == 7 and t.out_of_order == 1


damage = st.one_of(st.just(("ok", 0, 0)), st.tuples(st.just("flip"), st.integers(0, 36), st.integers(0, 7)),
                   st.tuples(st.just("drop"), st.integers(0, 36), st.integers(1, 36)))


@settings(max_examples=200, deadline=None)
@given(plan=st.lists(st.tuples(damage, st.binary(max_size=40)), min_size=1, max_size=30),
       chunk=st.integers(1, 200))
def test_parser_recovers_every_intact_frame_in_order(plan, chunk):
    frames = _frames(len(plan))
    stream = bytearray()
    intact = []
    for i, ((kind, pos, arg), garbage) in enumerate(plan):
        f = bytearray(frames[i])
        if kind == "flip":
            f[pos] ^= 1 << arg
        elif kind == "drop":
            del f[pos:pos + arg]
        # garbage may put back what a drop took from the frame's head (e.g. the sync byte): intact again
        if kind == "ok" or (garbage + bytes(f)).endswith(frames[i]):
            intact.append(i)
        stream += garbage + f
    p = pr.FrameParser()
    got = []
    for k in range(0, len(stream), chunk):
        got += p.feed(bytes(stream[k:k + chunk]))
    got += p.close()
    tracker = pr.SampleTracker()
    for f in got:
        assert f.type == pr.MsgType.SAMPLE
        tracker.add(pr.decode_sample(f.payload))
    tracker.finish(len(plan))
    indices = [s.index for s in tracker.samples]
    # every intact frame comes out, in order, nothing else; the rest is reported lost
    assert indices == intact
    assert tracker.n_lost == len(plan) - len(intact)
    assert tracker.out_of_order == 0


def test_wire_reference_is_the_simulators_reference():
    from forecast_design.runtime.protocol import Reference

    t = np.arange(2000) / 2000.0
    sine = Reference("sine", 0.5, 0.25, offset=0.1).signal().sample(t.size, 2000.0)
    np.testing.assert_allclose(sine, 0.1 + 0.5 * np.sin(2 * np.pi * t / 0.25), atol=1e-12)
    square = Reference("square", 0.2, 0.5).signal().sample(t.size, 2000.0)
    np.testing.assert_array_equal(square, np.where(np.mod(t, 0.5) < 0.25, 0.2, -0.2))
    step = Reference("step", 0.3, 0.1).signal().sample(t.size, 2000.0)
    np.testing.assert_array_equal(step, np.where(t >= 0.1, 0.3, 0.0))
    assert Reference("sine", 0.5, 0.25).value(0.0625) == pytest.approx(0.5)


def _crc16_bitwise_reference(data: bytes, crc: int = 0xFFFF) -> int:
    """The former pure-Python CRC-16/CCITT-FALSE (bit loop), kept as the reference for binascii.crc_hqx."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


@settings(max_examples=300, deadline=None, derandomize=True)
@given(payload=st.binary(max_size=pr.MAX_PAYLOAD), msg_type=st.sampled_from(sorted(pr.BOARD_TYPES | pr.HOST_TYPES)),
       seq=st.integers(0, 0xFFFF), init=st.integers(0, 0xFFFF))
def test_crc_hqx_equals_the_bitwise_reference_on_random_frames(payload, msg_type, seq, init):
    frame = pr.encode_frame(msg_type, seq, payload)
    body = frame[2:-2]
    assert pr.crc16_ccitt_false(body) == _crc16_bitwise_reference(body) == struct.unpack("<H", frame[-2:])[0]
    assert pr.crc16_ccitt_false(body, init) == _crc16_bitwise_reference(body, init)


def test_sequence_counter_counts_skips_repeats_and_wraps():
    c = pr.SequenceCounter()
    for seq in (65533, 65534, 65535, 0, 3, 3, 4, 2, 3):
        c.note(seq)
    # 0 -> 3 skips two; 3 again is a repeat; 4 -> 2 goes back (repeat, resync), 2 -> 3 is in order
    assert (c.skipped, c.repeated) == (2, 2)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(indices=st.lists(st.integers(0, 2**32 - 1), max_size=60), n=st.integers(0, 50))
def test_tracker_accounts_for_every_sample_and_never_exceeds_the_start_count(indices, n):
    t = pr.SampleTracker(n)
    for i in indices:
        t.add(pr.Sample(i, *([0.0] * (len(pr.Sample.__slots__) - 1))))
    t.finish(n)
    assert t.received + t.out_of_order + t.out_of_range == len(indices)
    assert t.received + t.n_lost == n
    assert all(i < n for i in t.indices) and list(t.indices) == sorted(set(t.indices))


def test_board_parser_skips_host_bound_headers_at_once():
    # a header claiming a 1000-byte UPLOAD cannot swallow the DONE frame behind it on the host side
    bogus = pr.SYNC + struct.pack("<HBH", 1000, pr.MsgType.UPLOAD, 0)
    done = pr.encode_frame(pr.MsgType.DONE, 1, pr.encode_done(10, 0))
    assert [f.type for f in pr.FrameParser(pr.BOARD_TYPES).feed(bogus + done)] == [pr.MsgType.DONE]
    assert pr.FrameParser().feed(bogus + done) == []   # an all-types parser waits for the 1000 bytes
