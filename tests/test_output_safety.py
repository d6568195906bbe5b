"""Never destroy what the user points at (issue 23): device, FIFO and symlink outputs, inputs used as outputs.

Device nodes, FIFOs, sockets and symlinks are made in a temporary folder: no test touches the real
``/dev``. A character device made with ``os.mknod`` needs root (the lab PC or container case of the
issue); those cases are skipped otherwise.
"""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from forecast_design import fileio
from forecast_design.cli import main
from forecast_design.errors import OutputError
from forecast_design.fileio import atomic_open, atomic_write, atomic_write_set, output_kind

ROOT = os.geteuid() == 0 if hasattr(os, "geteuid") else False
needs_root = pytest.mark.skipif(not ROOT, reason="os.mknod of a character device needs root")
NULL, FULL = (1, 3), (1, 7)      # Linux's mem devices: the null device and the always-full device
SCENARIO = Path(__file__).resolve().parents[1] / "forecast_design" / "data" / "example_scenario.toml"


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(code, err, *words):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("forecast-design: error: "), err
    for w in words:
        assert w in lines[0], lines[0]


def _device(folder: Path, name: str, numbers: tuple[int, int]) -> Path:
    path = folder / name
    os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(*numbers))
    return path


def _is_char_device(path: Path) -> bool:
    return stat.S_ISCHR(os.lstat(path).st_mode)


def _reader(path: Path) -> tuple[threading.Thread, list[bytes]]:
    got: list[bytes] = []

    def read():
        with open(path, "rb") as fh:
            got.append(fh.read())

    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    return thread, got


# --- outputs that are not regular files -------------------------------------------------------------------------


@needs_root
@pytest.mark.parametrize("argv", [["tf", "--json", "{dev}"], ["tf", "--plot", "{dev}"],
                                  ["reproduce", "fig6", "--env", "soft", "--json", "{dev}"],
                                  ["margins", "--json", "{dev}"]])
def test_a_null_device_output_is_written_through_and_stays_a_device(tmp_path, capsys, argv):
    dev = _device(tmp_path, "null", NULL)
    code, out, err = _cli(capsys, *[a.format(dev=dev) for a in argv])
    assert code == 0, err
    assert _is_char_device(dev)                          # the node is still the device, not a regular file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null"]      # no temporary left beside it


@needs_root
def test_a_full_device_is_a_one_line_error_and_stays_a_device(tmp_path, capsys):
    dev = _device(tmp_path, "full", FULL)
    code, out, err = _cli(capsys, "tf", "--json", dev)
    _one_line_error(code, err, str(dev), "No space left on device")
    assert _is_char_device(dev)
    with pytest.raises(OutputError, match="No space left"):
        atomic_write(dev, "x" * 10)


@needs_root
def test_a_device_as_the_out_of_a_set_is_refused_and_nothing_is_created_beside_it(tmp_path, capsys):
    dev = _device(tmp_path, "null", NULL)
    code, out, err = _cli(capsys, "simulate", SCENARIO, "--out", dev)
    _one_line_error(code, err, str(dev), "device or FIFO", "set of files")
    code, out, err = _cli(capsys, "simulate", SCENARIO, "--out", dev, "--repetitions", "all")
    _one_line_error(code, err, str(dev))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null"]    # no null.csv, null.truth.*, null_000.toml
    assert _is_char_device(dev)
    with pytest.raises(OutputError, match="needs regular files"):
        atomic_write_set({tmp_path / "x.csv": "a", dev: "b"})
    assert not (tmp_path / "x.csv").exists()


def test_a_terminal_is_written_through(tmp_path):
    """A pseudo-terminal reached through a symlink to this process's descriptor of it (not /dev/pts)."""
    master, slave = os.openpty()
    try:
        node = tmp_path / "tty"
        os.symlink(f"/proc/self/fd/{slave}", node)
        assert os.isatty(slave) and output_kind(node) == "stream"
        atomic_write(node, "to the terminal\n")
        assert b"to the terminal" in os.read(master, 1024)
        assert os.path.islink(node) and os.isatty(slave)
    finally:
        os.close(master)
        os.close(slave)


def test_a_fifo_output_is_written_through(tmp_path, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    thread, got = _reader(fifo)
    code, out, err = _cli(capsys, "margins", "--json", fifo)
    thread.join(10)
    assert code == 0, err
    assert json.loads(got[0])["stable"] is True
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    thread, got = _reader(fifo)
    with atomic_open(fifo) as fh:                        # the file-object writer (plots) too
        fh.write(b"png bytes")
    thread.join(10)
    assert got == [b"png bytes"]


def test_a_fifo_without_a_reader_is_a_bounded_wait_then_one_line(tmp_path, monkeypatch):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    monkeypatch.setattr(fileio, "FIFO_WAIT_S", 0.3)
    with pytest.raises(OutputError, match="no reader opened this FIFO within 0.3 s"):
        atomic_write(fifo, "x")


def test_a_symlink_to_this_process_stdout_reaches_stdout(tmp_path):
    link = tmp_path / "out.json"
    os.symlink("/proc/self/fd/1", link)
    done = subprocess.run([sys.executable, "-m", "forecast_design", "margins", "--json", str(link)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    start = done.stdout.index("{")
    doc, end = json.JSONDecoder().raw_decode(done.stdout[start:])
    assert doc["stable"] is True and "disk margin" in done.stdout[start + end:]   # then the human summary
    assert os.path.islink(link) and os.readlink(link) == "/proc/self/fd/1"


def test_stdout_redirected_to_a_file_is_appended_through_the_descriptor(tmp_path):
    """``--json /proc/self/fd/1`` with stdout a regular file: written at stdout's offset, not replacing it."""
    log = tmp_path / "log.txt"
    with open(log, "w") as fh:
        done = subprocess.run([sys.executable, "-c", "import sys; print('before', flush=True); "
                               "from forecast_design.cli import main; "
                               "sys.exit(main(['tf', '--json', '/proc/self/fd/1']))"],
                              stdout=fh, stderr=subprocess.PIPE, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    text = log.read_text()
    assert text.startswith("before\n") and '"P"' in text and "environment: soft" in text


def test_a_symlinked_output_replaces_its_target_and_stays_a_link(tmp_path, capsys):
    target = tmp_path / "data" / "result.json"
    target.parent.mkdir()
    target.write_text("old")
    link = tmp_path / "result.json"
    os.symlink(target, link)
    code, out, err = _cli(capsys, "margins", "--json", link)
    assert code == 0, err
    assert os.path.islink(link) and json.loads(target.read_text())["stable"] is True
    dangling = tmp_path / "new.json"
    os.symlink("data/created.json", dangling)
    atomic_write(dangling, "{}")
    assert os.path.islink(dangling) and (tmp_path / "data" / "created.json").read_text() == "{}"
    assert sorted(p.name for p in target.parent.iterdir()) == ["created.json", "result.json"]


def test_outputs_of_the_wrong_kind_are_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "folder").mkdir()
    os.symlink("loop_b", tmp_path / "loop_a")
    os.symlink("loop_a", tmp_path / "loop_b")
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(tmp_path / "sock"))
    try:
        for name, words in (("folder", "is a directory"), ("loop_a", "symbolic links"), ("sock", "is a socket")):
            code, out, err = _cli(capsys, "tf", "--json", tmp_path / name)
            _one_line_error(code, err, name, words)
    finally:
        sock.close()
    assert stat.S_ISSOCK(os.lstat(tmp_path / "sock").st_mode)


@pytest.mark.parametrize("length", [253, 254, 255])
def test_file_names_up_to_the_filesystem_limit_are_written(tmp_path, capsys, length):
    name = "r" * (length - 5) + ".json"
    code, out, err = _cli(capsys, "tf", "--json", tmp_path / name)
    assert code == 0, err
    assert json.loads((tmp_path / name).read_text())["P"]["den"][0] == 1.0
    long_toml = tmp_path / ("s" * 200 + ".toml")                  # a set: TOML + CSV + truth files
    code, out, err = _cli(capsys, "simulate", SCENARIO, "--out", long_toml)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == sorted(
        [name, long_toml.name, "s" * 200 + ".csv", "s" * 200 + ".truth.csv", "s" * 200 + ".truth.json"])


def test_temporaries_of_dead_writers_are_removed_and_a_live_writers_kept(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    pid = int(dead.stdout)                  # that process has exited and been reaped
    host = fileio._HOST
    stale = tmp_path / f".run.csv.~{host}-{pid}-abcd1234.tmp"
    stale_dir = tmp_path / f".set.~{host}-{pid}-abcd1234.tmpdir"
    live = tmp_path / f".run.csv.~{host}-{os.getpid()}-abcd1234.tmp"
    other_host = tmp_path / f".run.csv.~{'0' * 8 if host != '0' * 8 else '1' * 8}-{pid}-abcd1234.tmp"
    user_file = tmp_path / ".run.csv.my-notes.tmp"
    for p in (stale, live, other_host, user_file):
        p.write_text("x")
    stale_dir.mkdir()
    (stale_dir / "results.csv").write_text("x")
    fileio._CLEANED.discard(os.path.abspath(tmp_path))
    atomic_write(tmp_path / "run.csv", "new")        # the first write into a folder cleans it
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted([live.name, other_host.name, user_file.name, "run.csv"])


# --- an output that is an input ----------------------------------------------------------------------------------


def _experiment(folder: Path) -> Path:
    from forecast_design.experiment import experiment_from_arrays, save_experiment
    from forecast_design.params import Design

    import numpy as np

    t = np.arange(400) / 1000.0
    exp = experiment_from_arrays(Design.nominal("exp-soft"), 1000.0, t, 0.5 * np.sin(6 * t), 0.01 * np.sin(6 * t),
                                 0.005 * np.sin(6 * t))
    return save_experiment(exp, folder / "run.toml")


@pytest.mark.parametrize("argv, victim", [
    (["identify", "{toml}", "--json", "{csv}"], "csv"),
    (["identify", "--csv", "{csv}", "--time", "t", "--position", "theta", "--force", "tau_m", "--json", "{csv}"],
     "csv"),
    (["diagnose", "{toml}", "--json", "{toml}"], "toml"),
    (["diagnose", "{toml}", "--json", "{csv}"], "csv"),
    (["check", "{toml}", "--json", "{csv}"], "csv"),
    (["tf", "--experiment", "{toml}", "--json", "{toml}"], "toml"),
    (["tf", "--experiment", "{toml}", "--plot", "{csv}"], "csv"),
    (["margins", "--experiment", "{toml}", "--json", "{toml}"], "toml"),
    (["reproduce", "fig6", "--experiment", "{toml}", "--json", "{toml}"], "toml"),
    (["tune-q", "--observer", "ea-fob", "--experiment", "{toml}", "--json", "{toml}"], "toml"),
    (["export", "--experiment", "{toml}", "--json", "{toml}", "--out", "{dir}"], "toml"),
    (["export", "--compensator", "sfm", "--friction", "{friction}", "--json", "{friction}", "--out", "{dir}"],
     "friction"),
    (["tf", "--env", "{env}", "--json", "{env}"], "env"),
    (["tf", "--testbed", "{testbed}", "--json", "{testbed}"], "testbed"),
    (["simulate", "{scenario}", "--out", "{scenario}"], "scenario"),
    (["diagnose", "{toml}", "--json", "{link}"], "toml"),            # through a symlink
    (["diagnose", "{toml}", "--json", "{hard}"], "toml"),            # through a hard link
    (["export", "--controller", "{c_code}", "--json", "{c_code}", "--out", "{dir}"], "c_code"),   # controllers as code
    (["benchmark", "--controller", "{py_code}:GainScheduledPID", "--envs", "soft", "--repetitions", "2",
      "--duration", "0.05", "--out", "{dir}", "--no-plots", "--json", "{py_code}"], "py_code"),
    (["margins", "--controller", "{py_code}:GainScheduledPID", "--plot", "{py_code}"], "py_code"),
])
def test_no_verb_overwrites_a_file_it_reads(tmp_path, capsys, argv, victim):
    toml = _experiment(tmp_path)
    files = {"toml": toml, "csv": toml.with_suffix(".csv"), "friction": tmp_path / "F.json",
             "env": tmp_path / "env.toml", "testbed": tmp_path / "tb.toml", "scenario": tmp_path / "S.toml",
             "c_code": tmp_path / "ctrl.c", "py_code": tmp_path / "ctrl.py"}
    from forecast_design.controllers.examples import example_path

    files["c_code"].write_bytes(example_path("gain_scheduled_pid.c").read_bytes())
    files["py_code"].write_bytes(example_path("gain_scheduled_pid.py").read_bytes())
    files["friction"].write_text(json.dumps({"model": "sfm", "params": {"viscous": 0.1, "coulomb": 0.1}}))
    files["env"].write_text("[environment]\nk_e = 20.0\nJ_e = 0.02\nd_e = 1.0\n")
    files["testbed"].write_text("[testbed]\nk = 40.0\n")
    files["scenario"].write_text(SCENARIO.read_text())
    os.symlink(toml.name, tmp_path / "link.json")
    os.link(toml, tmp_path / "hard.json")
    before = {k: p.read_bytes() for k, p in files.items()}
    names = {**{k: str(p) for k, p in files.items()}, "dir": str(tmp_path / "c"), "link": str(tmp_path / "link.json"),
             "hard": str(tmp_path / "hard.json")}
    code, out, err = _cli(capsys, *[a.format(**names) for a in argv])
    _one_line_error(code, err, "would overwrite the input", files[victim].name)
    assert {k: p.read_bytes() for k, p in files.items()} == before


def test_an_input_found_while_running_is_guarded_when_written(tmp_path, capsys):
    """A scenario's environment file is only known once the scenario is read: refused at the write."""
    env = tmp_path / "env.toml"
    env.write_text("[environment]\nk_e = 20.0\nJ_e = 0.02\nd_e = 1.0\n")
    text = SCENARIO.read_text()
    table = text[text.index("[environment]"):text.index("[controller]")]
    scenario = text.replace(table, "").replace("[sampling]", 'environment = "env.toml"\n\n[sampling]', 1)
    (tmp_path / "S.toml").write_text(scenario)
    before = env.read_bytes()
    code, out, err = _cli(capsys, "simulate", tmp_path / "S.toml", "--out", env)
    _one_line_error(code, err, "would overwrite the input", "env.toml")
    assert env.read_bytes() == before
    # outside a command (library use), saving over a file read earlier stays possible
    atomic_write(env, before)


@needs_root
def test_a_block_device_output_is_refused_in_one_line_and_stays_a_device(tmp_path, capsys):
    """A disk node (made here with the loop device's numbers, never opened) is no output: one line, untouched."""
    node = tmp_path / "disk"
    os.mknod(node, stat.S_IFBLK | 0o600, os.makedev(7, 0))
    code, out, err = _cli(capsys, "tf", "--json", node)
    _one_line_error(code, err, "disk", "a block device")
    assert stat.S_ISBLK(os.lstat(node).st_mode)
