"""Tests of the experiment files' reader/writer (experiment_io) and the one atomic writer (fileio)."""

from __future__ import annotations

import errno
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from forecast_design.errors import ExperimentFormatError, OutputError
from forecast_design.experiment import experiment_from_arrays, load_experiment, save_experiment
from forecast_design.experiment_io import _columnar, _scan_rows, read_csv_table
from forecast_design.fileio import atomic_open, atomic_write, atomic_write_set, refuse_overwriting
from forecast_design.friction import load_axis_csv
from forecast_design.params import Design

RATE = 1000.0


def _experiment(n=50, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    return experiment_from_arrays(Design.nominal("soft"), RATE, t, rng.normal(size=n), rng.normal(size=n),
                                  rng.normal(size=n), tau_r=rng.normal(size=n))


def _write_pair(folder, csv_bytes):
    folder.mkdir(parents=True, exist_ok=True)
    save_experiment(_experiment(3), folder / "run.toml")
    toml = (folder / "run.toml").read_text()
    (folder / "run.toml").write_text("\n".join(l for l in toml.splitlines() if not l.startswith("# data-crc32")))
    (folder / "run.csv").write_bytes(csv_bytes)
    return folder / "run.toml"


def _plain_csv(exp):
    cols = exp.signals.columns()
    lines = [",".join(cols)] + [",".join(repr(float(v)) for v in row) for row in zip(*cols.values())]
    return "\n".join(lines) + "\n"


# --- reading: dialects a logger can produce ----------------------------------------------


@pytest.mark.parametrize("variant", ["bom", "crlf", "cr", "trailing-blank-lines", "no-final-newline",
                                     "quoted", "blanks-around-cells"])
def test_logger_dialects_read_the_same_values(tmp_path, variant):
    exp = _experiment()
    text = _plain_csv(exp)
    if variant == "bom":
        raw = b"\xef\xbb\xbf" + text.encode()
    elif variant == "crlf":
        raw = text.replace("\n", "\r\n").encode()
    elif variant == "cr":
        raw = text.replace("\n", "\r").encode()
    elif variant == "trailing-blank-lines":
        raw = (text + "\n \n\r\n").encode()
    elif variant == "no-final-newline":
        raw = text.rstrip("\n").encode()
    elif variant == "quoted":
        raw = re.sub(r"(-?[0-9][0-9.e+-]*)", r'"\1"', text).encode()
    else:
        raw = text.replace(",", " , ").encode()
    names, columns = read_csv_table(raw, "x.csv")
    assert names == list(exp.signals.columns())
    for name, values in exp.signals.columns().items():
        assert np.array_equal(columns[name], values), name
    # the same file as an experiment: loads, equal to the original
    assert load_experiment(_write_pair(tmp_path / variant, raw)).signals == exp.signals


@pytest.mark.parametrize("cell,message", [
    ("5_2", r"line 3, column 'theta': '5_2' is not a number"),           # float() would say 52
    ("\u0661", r"line 3, column 'theta': '\u0661' is not a number"),      # an Arabic-Indic digit
    ("# x", r"line 3, column 'theta': '# x' is not a number"),            # comments are not in the format
    ("0x10", r"line 3, column 'theta': '0x10' is not a number"),
])
def test_cells_outside_the_number_syntax_name_line_and_column(cell, message):
    raw = f"t,tau_m,theta,q\n0,0,0,0\n0.001,0,{cell},0\n".encode()
    with pytest.raises(ExperimentFormatError, match=message):
        read_csv_table(raw, "x.csv")


def test_binary_and_latin1_files_are_one_line_errors():
    with pytest.raises(ExperimentFormatError, match=r"x\.csv: not UTF-8 text"):
        read_csv_table(b"t,tau_m,theta,q\n0,0,0,0\n0.001,0,\xe9,0\n", "x.csv")
    with pytest.raises(ExperimentFormatError, match=r"x\.csv: not UTF-8 text"):
        read_csv_table(b"t,\xff\xfe\x00,theta,q\n0,0,0,0\n", "x.csv")
    with pytest.raises(ExperimentFormatError, match=r"x\.csv: line 2, column 't': '.*' is not a number"):
        read_csv_table(b"t,tau_m,theta,q\n1\x002,0,0,0\n", "x.csv")


_CELL = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(lambda v: f"{v!r}"),
    st.floats(width=32).map(lambda v: f"{v:.6g}"),
    st.from_regex(r"[ \t]?[+-]?[0-9]{0,3}\.?[0-9]{0,3}([eE][+-]?[0-9]{1,3})?[ \t]?", fullmatch=True),
    st.sampled_from(["nan", "-inf", "Infinity", "+.5", "1.", "", " ", "1e", "e1", "--1", "5_2", "1,5"]),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.lists(_CELL, min_size=1, max_size=6))
def test_columnar_reader_and_line_scan_agree_on_every_cell(cells):
    """pyarrow and the line-by-line scan accept the same cells and give the same bits."""
    body = ",".join(cells)
    width = len(cells)
    names = [f"c{j}" for j in range(width)]
    fast = _columnar(memoryview(body.encode()), width)
    try:
        slow = _scan_rows([body], names, "x.csv")[0]
    except ExperimentFormatError:
        slow = None
    if fast is None:
        assert slow is None, (body, slow)
    else:
        assert slow is not None, body
        got = np.array([c[0] for c in fast])
        assert np.array_equal(got.view(np.int64), slow.view(np.int64)) or np.array_equal(got, slow, equal_nan=True)
        assert np.array_equal(got, np.array([float(c) for c in cells]), equal_nan=True)


def test_axis_csv_reader_shares_the_reader(tmp_path):
    p = tmp_path / "axis.csv"
    p.write_bytes(b"\xef\xbb\xbftime,pos,tau\r\n0,0.1,1\r\n0.001,0.2,2\r\n0.002,0.3,3\r\n")
    log = load_axis_csv(p, time="time", position="pos", force="tau")
    assert np.array_equal(log.position, [0.1, 0.2, 0.3])
    p.write_text("time,pos,tau\n0,0.1,1\n0.001,5_2,2\n")
    with pytest.raises(ExperimentFormatError, match=r"axis\.csv: line 3, column 'pos': '5_2' is not a number"):
        load_axis_csv(p, time="time", position="pos", force="tau")


# --- reading: what `data` may point at -----------------------------------------------------


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="POSIX FIFOs")
def test_a_fifo_is_refused_without_reading(tmp_path):
    toml = _write_pair(tmp_path, b"t,tau_m,theta,q\n0,0,0,0\n")
    (tmp_path / "run.csv").unlink()
    os.mkfifo(tmp_path / "run.csv")
    with pytest.raises(ExperimentFormatError, match=r"run\.csv: not a regular file"):
        load_experiment(toml)          # would block forever if opened
    with pytest.raises(ExperimentFormatError, match=r"run\.csv: not a regular file"):
        load_axis_csv(tmp_path / "run.csv", time="t", position="theta", force="tau_m")


def test_device_directory_and_nul_data_are_one_line_errors(tmp_path):
    toml = _write_pair(tmp_path, b"")
    text = (tmp_path / "run.toml").read_text()
    for data, message in [(os.devnull, "not a regular file"), (".", "a directory"), ("a\\u0000b", "data must be")]:
        (tmp_path / "run.toml").write_text(text.replace('data = "run.csv"', f'data = "{data}"'))
        with pytest.raises(ExperimentFormatError, match=message):
            load_experiment(toml)


def test_errors_echo_a_bounded_part_of_a_foreign_file(tmp_path):
    secret = "root:x:0:0:" + "s" * 500
    toml = _write_pair(tmp_path, (secret + "\n" + secret + "\n").encode())
    with pytest.raises(ExperimentFormatError) as err:
        load_experiment(toml)
    assert "s" * 100 not in str(err.value) and len(str(err.value)) < 400


# --- writing: one set, checked on load ------------------------------------------------------


def test_round_trip_is_exact_and_the_toml_records_the_csv(tmp_path):
    exp = _experiment(2000, seed=3)
    save_experiment(exp, tmp_path / "run.toml")
    assert load_experiment(tmp_path / "run.toml") == exp
    line = (tmp_path / "run.toml").read_text().splitlines()[-1]
    raw = (tmp_path / "run.csv").read_bytes()
    import zlib
    assert line == f"# data-crc32 = {zlib.crc32(raw):08x}, data-bytes = {len(raw)}"


def test_a_csv_from_another_save_is_detected_not_mixed(tmp_path):
    save_experiment(_experiment(40, seed=1), tmp_path / "a" / "run.toml")
    save_experiment(_experiment(40, seed=2), tmp_path / "b" / "run.toml")
    # what a kill between the two renames leaves: the new CSV beside the old TOML
    (tmp_path / "a" / "run.csv").write_bytes((tmp_path / "b" / "run.csv").read_bytes())
    with pytest.raises(ExperimentFormatError, match=r"run\.csv: does not match .*run\.toml"):
        load_experiment(tmp_path / "a" / "run.toml")
    # the message's remedy works: without the checksum line the CSV is accepted as it is
    toml = tmp_path / "a" / "run.toml"
    toml.write_text("\n".join(l for l in toml.read_text().splitlines() if not l.startswith("# data-crc32")))
    assert load_experiment(toml).signals == _experiment(40, seed=2).signals


def test_a_failed_set_changes_nothing_and_leaves_no_temporaries(tmp_path):
    old = _experiment(30, seed=1)
    save_experiment(old, tmp_path / "run.toml")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def failing():
        yield "t,x\n"
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OutputError, match=r"^\S*sidecar\.csv: cannot write: No space left on device$"):
        save_experiment(_experiment(30, seed=2), tmp_path / "run.toml", sidecars={tmp_path / "sidecar.csv": failing()})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    assert load_experiment(tmp_path / "run.toml") == old


def test_a_directory_as_the_toml_leaves_no_orphan_csv(tmp_path):
    (tmp_path / "run.toml").mkdir()
    with pytest.raises(OutputError, match=r"run\.toml: is a directory"):
        save_experiment(_experiment(10), tmp_path / "run.toml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.toml"]


def test_atomic_write_keeps_the_old_file_on_a_full_disk(tmp_path, monkeypatch):
    target = tmp_path / "out.json"
    atomic_write(target, json.dumps({"old": 1}))

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError, match=r"out\.json: cannot write: No space left on device$") as err:
        atomic_write(target, json.dumps({"new": 2}))
    assert str(tmp_path) in str(err.value) and ".tmp" not in str(err.value)
    assert json.loads(target.read_text()) == {"old": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_atomic_open_discards_on_error_and_set_rejects_repeats(tmp_path):
    target = tmp_path / "fig.png"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_open(target) as fh:
            fh.write(b"partial")
            raise RuntimeError("drawing failed")
    assert target.read_bytes() == b"old" and len(list(tmp_path.iterdir())) == 1
    with pytest.raises(OutputError, match="named twice"):
        atomic_write_set({target: "a", tmp_path / "x" / ".." / "fig.png": "b"})
    with pytest.raises(OutputError, match=r"would overwrite the input"):
        refuse_overwriting([tmp_path / "x" / ".." / "fig.png"], [target])


def test_cli_json_and_plot_outputs_are_atomic(tmp_path):
    """--json/--plot to a folder that is a file: one line naming the user's path, exit 2."""
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    for extra in (["--json", str(blocker / "out.json")], ["--plot", str(blocker / "out.png")],
                  ["--plot", str(tmp_path / "out.xyz")]):
        proc = subprocess.run([sys.executable, "-m", "forecast_design", "reproduce", "fig6", *extra],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, (extra, proc.stderr)
        assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr
        assert extra[1] in proc.stderr or "xyz" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]
