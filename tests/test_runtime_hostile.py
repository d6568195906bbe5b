"""A hostile board on a real pseudo-terminal: floods, far indices, NaN samples, bad ACK/INFO frames,
sequence skips and repeats, samples before the ACK, unwritable outputs.

The fake board below speaks the protocol from ``docs/protocol.md`` by hand (frames built with
``protocol.encode_frame``) and misbehaves on purpose; the host is the real ``Board`` over the pty.
"""

import dataclasses
import os
import select
import struct
import threading
import time

import numpy as np
import pytest

from forecast_design.errors import ParameterError
from forecast_design.experiment import load_experiment
from forecast_design.params import Design, environment_preset
from forecast_design.runtime import Board, BoardError, LinkError, open_pty
from forecast_design.runtime import protocol as pr
from forecast_design.runtime.board import run_deadline_s

DESIGN = Design(environment=environment_preset("exp-soft"))
RATE = 2000.0


def sample_payload(index, value=0.5, **override):
    """A SAMPLE payload built from the protocol's own Sample fields (whatever the version carries)."""
    names = [f.name for f in dataclasses.fields(pr.Sample) if f.name != "index"]
    values = {name: value for name in names}
    values.update(t=index / RATE, theta=0.01 * value, q=0.0)
    values.update(override)
    return pr.encode_sample(pr.Sample(index & 0xFFFFFFFF, **values))


class FakeBoard:
    """Answers PING with INFO and every command with an ACK; on START calls ``on_start(board, n)``.

    ``on_start`` returns an iterable of byte chunks written after the ACK (``before_ack`` chunks go
    before it). The board numbers its frames +1 each, as the protocol says, unless a test asks otherwise.
    """

    def __init__(self, on_start=None, *, info_rate=RATE, ack_status=0, before_ack=None, give_up_s=12.0):
        self.on_start = on_start or (lambda board, n: [board.samples(range(n)), board.done(n)])
        self.info_rate = info_rate
        self.ack_status = ack_status
        self.before_ack = before_ack
        self.give_up_s = give_up_s   # a flood ends here at the latest, so a host without a deadline fails
        self.seq = 0
        self.stopped = False
        self.commands = []
        self.stop = threading.Event()
        self.master, self.slave, self.path = open_pty()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def frame(self, msg_type, payload=b"", seq=None):
        if seq is None:
            seq, self.seq = self.seq, (self.seq + 1) & 0xFFFF
        return pr.encode_frame(msg_type, seq, payload)

    def samples(self, indices, **override):
        return b"".join(self.frame(pr.MsgType.SAMPLE, sample_payload(i, **override)) for i in indices)

    def done(self, n):
        return self.frame(pr.MsgType.DONE, pr.encode_done(n, 0))

    def write(self, data):
        view = memoryview(data)
        while view and not self.stop.is_set():
            r, w, _ = select.select([self.master], [self.master], [], 0.05)
            if r and not w and any(g.type == pr.MsgType.STOP for g in self._read(0.0)):
                self.stopped = True   # the host stopped reading and said STOP: drop the rest
                return
            if w:
                try:
                    view = view[os.write(self.master, view):]
                except (BlockingIOError, OSError):
                    time.sleep(0.001)

    def _read(self, timeout):
        r, _, _ = select.select([self.master], [], [], timeout)
        if not r:
            return []
        try:
            data = os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            time.sleep(0.01)
            return []
        frames = self.parser.feed(data)
        self.commands += [pr.MsgType(f.type).name for f in frames]
        return frames

    def _serve(self):
        self.parser = pr.FrameParser(pr.HOST_TYPES)
        while not self.stop.is_set():
            for f in self._read(0.02):
                if f.type == pr.MsgType.PING:
                    self.write(self.frame(pr.MsgType.INFO, struct.pack("<BfI", pr.PROTOCOL_VERSION, self.info_rate, 1024)))
                    continue
                if f.type in (pr.MsgType.STOP, pr.MsgType.HEARTBEAT):
                    continue
                status = self.ack_status if f.type == pr.MsgType.UPLOAD else 0
                if f.type != pr.MsgType.START:
                    self.write(self.frame(pr.MsgType.ACK, pr.encode_ack(f.type, f.seq, status)))
                    continue
                n = pr.decode_start(f.payload)
                if self.before_ack:
                    self.write(self.before_ack(self, n))
                self.write(self.frame(pr.MsgType.ACK, pr.encode_ack(f.type, f.seq, status)))
                t0 = time.monotonic()
                for chunk in self.on_start(self, n):
                    if self.stop.is_set() or time.monotonic() - t0 > self.give_up_s:
                        break
                    self.write(chunk)
                    if self.stopped or any(g.type == pr.MsgType.STOP for g in self._read(0.0)):
                        break   # a real board ends its run on STOP

    def close(self):
        self.stop.set()
        self.thread.join(5)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


@pytest.fixture
def fake():
    boards = []

    def make(*args, **kwargs):
        boards.append(FakeBoard(*args, **kwargs))
        return boards[-1]

    yield make
    for b in boards:
        b.close()


def record(board, out, duration=0.005, timeout=0.3):
    with Board(board.path, timeout=timeout) as host:
        return host.run("step:0.2", duration, DESIGN, out)


# --- deadline ---------------------------------------------------------------------------------------------


def _garbage(board, n):
    rng = np.random.default_rng(0)
    while True:
        yield rng.integers(0, 256, 512, dtype=np.uint8).tobytes().replace(pr.SYNC, b"\0\0")


def _stale(board, n):
    yield board.samples([0])
    while True:
        yield board.samples([0] * 20)


def _info_frames(board, n):
    while True:
        yield b"".join(board.frame(pr.MsgType.INFO, pr.encode_info(RATE)) for _ in range(20))


@pytest.mark.parametrize("flood", [_garbage, _stale, _info_frames], ids=["garbage", "stale-samples", "info-frames"])
def test_a_flooding_board_cannot_keep_a_run_going_past_its_deadline(fake, tmp_path, flood):
    board = fake(flood)
    limit = run_deadline_s(10, RATE, 0.3)
    t0 = time.monotonic()
    with pytest.raises(LinkError, match="run not finished") as info:
        record(board, tmp_path / "run.toml")
    elapsed = time.monotonic() - t0
    assert elapsed < limit + 1.0, f"the run lasted {elapsed:.1f} s, deadline {limit:.1f} s"
    summary = info.value.summary
    assert summary["samples"] + summary["lost"] == 10 and not summary["completed"]
    wait = time.monotonic() + 2.0
    while "STOP" not in board.commands and time.monotonic() < wait:
        time.sleep(0.01)
    assert "STOP" in board.commands   # the host tells the board to stop
    if flood is _stale:
        assert summary["samples"] == 1 and summary["out_of_order"] > 0 and info.value.saved


# --- indices beyond the count requested at START ----------------------------------------------------------


@pytest.mark.parametrize("far", [10, 2_000_000, 0xFFFFFFF0])
def test_indices_beyond_start_count_are_protocol_errors_and_memory_stays_bounded(fake, tmp_path, far):
    import tracemalloc

    board = fake(lambda b, n: [b.samples(range(n - 1)), b.samples([far]), b.samples([n - 1]), b.done(n)])
    tracemalloc.start()
    try:
        result = record(board, tmp_path / "run.toml")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert result.out_of_range == 1 and result.lost == 0 and result.samples == 10 and result.completed
    assert load_experiment(tmp_path / "run.toml").n_samples == 10
    assert peak < 20e6   # a far index allocates nothing in proportion to it


# --- invalid samples ----------------------------------------------------------------------------------------


def test_nan_and_inf_samples_are_kept_flagged_and_counted(fake, tmp_path):
    def stream(b, n):
        yield b.samples(range(3), value=1.0)
        yield b.samples([3], tau_s=float("nan"))
        yield b.samples([4], value=2.0)
        yield b.samples([5], theta=float("inf"))
        yield b.samples(range(6, n), value=3.0)
        yield b.done(n)

    result = record(fake(stream), tmp_path / "run.toml")
    assert result.completed and result.invalid == 2 and result.samples == 10 and result.lost == 0
    exp = load_experiment(tmp_path / "run.toml")
    cols = exp.signals.columns()
    np.testing.assert_array_equal(cols["valid"], [1, 1, 1, 0, 1, 0, 1, 1, 1, 1])
    np.testing.assert_array_equal(cols["received"], np.ones(10))
    # an invalid row is the linear interpolation of its valid neighbours (row 3 between 1.0 and 2.0)
    assert cols["tau_s"][3] == pytest.approx(1.5) and cols["theta"][5] == pytest.approx(0.025)
    assert "2 samples with NaN/inf" in exp.description


def test_a_run_of_only_invalid_samples_is_an_error_not_a_nan_file(fake, tmp_path):
    board = fake(lambda b, n: [b.samples(range(n), tau_m=float("nan")), b.done(n)])
    with pytest.raises(BoardError, match="finite") as info:
        record(board, tmp_path / "run.toml")
    assert info.value.summary["invalid"] == 10 and not (tmp_path / "run.toml").exists()


# --- bad ACK and INFO frames --------------------------------------------------------------------------------


@pytest.mark.parametrize("status, words", [(9, "unknown status 9"), (2, "NO_CONTROLLER")])
def test_an_ack_with_a_bad_status_is_a_board_error(fake, status, words):
    board = fake(ack_status=status)
    from forecast_design.export.c import build_program
    from forecast_design.params import resolve_design

    program = build_program(resolve_design(compensator="ea-fob"))
    with Board(board.path, timeout=0.3) as host, pytest.raises(BoardError, match=words):
        host.ping()
        host.upload(program)


@pytest.mark.parametrize("rate", [float("nan"), float("inf"), -2000.0, 0.0, 1e30])
def test_an_info_frame_with_an_absurd_rate_is_a_board_error(fake, tmp_path, rate):
    board = fake(info_rate=rate)
    with pytest.raises(BoardError, match="sample rate"):
        record(board, tmp_path / "run.toml")
    assert "START" not in board.commands


# --- sequence numbers, samples before the ACK, trailing garbage ---------------------------------------------


def test_sequence_skips_and_repeats_are_counted(fake, tmp_path):
    def stream(b, n):
        yield b.samples(range(4))
        b.seq += 3                      # three frames the host never sees
        yield b.samples(range(4, 7))
        again = b.samples([7])
        yield again + again             # the same frame twice (same sequence number)
        b.seq += 2
        yield b.samples(range(8, n))
        yield b.done(n)

    result = record(fake(stream), tmp_path / "run.toml")
    assert (result.seq_skipped, result.seq_repeated) == (5, 1)
    assert result.out_of_order == 1 and result.samples == 10 and result.lost == 0


def test_samples_before_the_start_ack_are_kept(fake, tmp_path):
    board = fake(lambda b, n: [b.samples(range(4, n)), b.done(n)], before_ack=lambda b, n: b.samples(range(4)))
    result = record(board, tmp_path / "run.toml")
    assert result.samples == 10 and result.lost == 0 and result.completed


def test_a_trailing_frame_with_an_absurd_length_does_not_spoil_a_complete_run(fake, tmp_path):
    # a header of a host-bound type claiming 1000 payload bytes, before and after DONE
    bogus = pr.SYNC + struct.pack("<HBH", 1000, pr.MsgType.UPLOAD, 0)
    board = fake(lambda b, n: [b.samples(range(n)), bogus, b.done(n), bogus])
    with Board(board.path, timeout=0.3) as host:
        result = host.run("step:0.2", 0.005, DESIGN, tmp_path / "run.toml")
        assert result.completed and result.samples == 10 and result.lost == 0
        second = host.run("step:0.2", 0.005, DESIGN, tmp_path / "run2.toml")   # the link is still usable
    assert second.completed and second.samples == 10


# --- durations ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("duration, words", [(1e-4, "less than one sample"), (1e9, "at most"),
                                             (float("nan"), "must be > 0")])
def test_a_duration_without_samples_or_with_too_many_is_refused_before_start(fake, tmp_path, duration, words):
    board = fake()
    with pytest.raises(ParameterError, match=words):
        record(board, tmp_path / "run.toml", duration=duration)
    assert "START" not in board.commands and not (tmp_path / "run.toml").exists()


def test_run_cli_duration_errors_are_one_line_exit_2(fake, tmp_path, capsys):
    from forecast_design.cli import main

    board = fake()
    for duration in ("0.0001", "1e9"):
        code = main(["run", "--port", board.path, "--duration", duration, "--out", str(tmp_path / "r.toml")])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and err.startswith("forecast-design: error: duration")


# --- unwritable output -------------------------------------------------------------------------------------------


def test_an_unwritable_output_is_refused_before_start(fake, tmp_path):
    (tmp_path / "file").write_text("not a folder")
    board = fake()
    for out in (tmp_path / "file" / "run.toml", tmp_path):
        with pytest.raises(ParameterError, match="--out"):
            record(board, out)
    assert "START" not in board.commands


def test_a_late_write_failure_saves_the_run_to_a_recovery_file(fake, tmp_path, monkeypatch):
    import shutil

    monkeypatch.chdir(tmp_path)
    target = tmp_path / "lab" / "run.toml"

    def sabotage(b, n):
        shutil.rmtree(tmp_path / "lab")
        (tmp_path / "lab").write_text("the folder became a file mid-run")
        return [b.samples(range(n)), b.done(n)]

    with pytest.raises(BoardError, match="recovery file") as info:
        record(fake(sabotage), target)
    saved = info.value.saved
    assert saved and "forecast-run-recovery-" in saved and str(saved) in str(info.value)
    assert load_experiment(saved).n_samples == 10 and info.value.summary["samples"] == 10


# --- the emulator's own faults ---------------------------------------------------------------------------------


def test_emulator_disconnect_zero_sends_no_sample(tmp_path):
    from forecast_design.runtime import Faults, run_on_port, serve_emulator

    master, slave, path = open_pty()
    stop = threading.Event()
    th = threading.Thread(target=serve_emulator, args=(master,),
                          kwargs={"faults": Faults(disconnect_after=0), "stop": stop}, daemon=True)
    th.start()
    try:
        with pytest.raises(LinkError) as info:
            run_on_port(path, out=tmp_path / "run.toml", duration=0.05, timeout=0.5)
        assert info.value.summary["samples"] == 0 and info.value.summary["lost"] == 100
    finally:
        stop.set()
        th.join(5)
        os.close(slave)


def test_emulator_seed_must_be_non_negative():
    from forecast_design.runtime import parse_fault

    with pytest.raises(ParameterError, match="seed"):
        parse_fault(["seed:-1"])


def test_a_failing_tcdrain_is_a_link_error_not_a_termios_traceback(monkeypatch):
    """A board hanging up makes pyserial's flush() raise termios.error (not an OSError): a LinkError."""
    import termios

    from forecast_design.runtime.link import Link, LinkError as _LinkError

    master, slave, path = open_pty()
    try:
        link = Link(path, timeout=0.1)

        def hung_up():
            raise termios.error(5, "Input/output error")

        monkeypatch.setattr(link._serial, "flush", hung_up)  # noqa: SLF001
        with pytest.raises(_LinkError, match="write failed"):
            link.write(b"\x00")
        link.close()
    finally:
        os.close(master)
        os.close(slave)
