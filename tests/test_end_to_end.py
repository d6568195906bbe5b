"""Hardware path end to end: emulate (a real pty, in a subprocess) -> run -> the log feeds check, identify, diagnose."""

import json
import os
import select
import signal
import subprocess
import sys
import time

import pytest

from forecast_design.cli import main
from forecast_design.experiment import load_experiment

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")


def _start_emulator(*faults):
    args = [sys.executable, "-m", "forecast_design", "emulate"]
    for fault in faults:
        args += ["--fault", fault]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 120)
    assert ready, "emulator printed no device path"
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), path
    return proc, path


def _stop(proc, *, kill=False):
    proc.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
    try:
        proc.communicate(timeout=20)     # also closes the pipes
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    if not kill:
        assert proc.returncode == 0, "emulator must exit cleanly on SIGTERM"


def _exit_code(argv):
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


def test_run_against_emulator_feeds_identify_and_diagnose(tmp_path, capsys):
    proc, port = _start_emulator()
    try:
        out = tmp_path / "run.toml"
        code = main(["run", "--port", port, "--compensator", "ea-fob", "--reference", "square:0.2:0.5", "--timeout", "30",
                     "--duration", "1.5", "--out", str(out), "--json", str(tmp_path / "summary.json")])
    finally:
        _stop(proc)
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["samples"] == 3000 and summary["lost"] == 0 and summary["corrupt_frames"] == 0
    run = load_experiment(out)
    assert run.n_samples == 3000 and run.rate_hz == 2000.0
    assert run.design.compensator.kind == "ea-fob"
    capsys.readouterr()
    assert main(["identify", str(out), "--model", "sfm", "--json", str(tmp_path / "fit.json")]) == 0
    fit = json.loads((tmp_path / "fit.json").read_text())
    assert fit["params"]["viscous"] >= 0.0
    assert main(["diagnose", str(out), "--json", str(tmp_path / "gap.json"), "--report", str(tmp_path / "rep")]) == 0
    gap = json.loads((tmp_path / "gap.json").read_text())
    assert set(gap) == {"verdict", "metric", "location", "ranking", "caveats", "isolability", "tau_s", "design"}
    # the diagnosis names the nominal model it measured the gap against: the one the board ran
    assert gap["design"]["compensator"]["kind"] == "ea-fob" and gap["design"]["duration_s"] == pytest.approx(1.5)
    assert (tmp_path / "rep").is_dir() and any(p.suffix == ".png" for p in (tmp_path / "rep").iterdir())


def test_faulty_stream_counts_every_lost_sample(tmp_path, capsys):
    proc, port = _start_emulator("flip:0.0005", "drop:0.0005", "seed:3")
    try:
        out = tmp_path / "run.toml"
        code = main(["run", "--port", port, "--duration", "1.5", "--timeout", "30", "--out", str(out),
                     "--json", str(tmp_path / "s.json")])
    finally:
        _stop(proc)
    assert code == 0
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["samples"] + s["lost"] == s["expected"] == 3000
    assert s["lost"] > 0 and (s["corrupt_frames"] > 0 or s["resyncs"] > 0)
    lost_from_ranges = sum(stop - first for first, stop in s["lost_ranges"])   # half-open
    assert lost_from_ranges == s["lost"]
    assert load_experiment(out).n_samples == 3000


def test_disconnect_mid_run_exits_2_and_keeps_what_arrived(tmp_path, capsys):
    proc, port = _start_emulator("disconnect:600")
    try:
        out = tmp_path / "run.toml"
        code = _exit_code(["run", "--port", port, "--duration", "2", "--out", str(out), "--timeout", "0.5",
                           "--json", str(tmp_path / "s.json")])
    finally:
        _stop(proc, kill=True)
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["samples"] + summary["lost"] == 4000 and summary["samples"] <= 600
    if summary["samples"]:          # bytes in flight die with the cable: a loaded host may get none
        assert out.exists(), "the partial run must be saved"
        assert load_experiment(out).n_samples <= 600
