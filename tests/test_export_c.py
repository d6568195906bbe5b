"""C export: host-compiled equivalence with the Python discrete implementation, determinism, no libm."""

import shutil
import string
import subprocess
from importlib import resources

import numpy as np
import pytest

from forecast_design.errors import ParameterError
from forecast_design.export.c import ControllerProgram, export_controller, parse_controller

CC = shutil.which("cc") or shutil.which("gcc")
needs_cc = pytest.mark.skipif(CC is None, reason="no host C compiler (cc/gcc) on PATH")
KINDS = ["none", "ea-fob", "lo-dob", "motor-fob"]


def _harness(out_dir, override_prev):
    text = resources.files("forecast_design.export").joinpath("templates", "fd_harness.c.in").read_text()
    io = "    FILE *fin = stdin;\n    FILE *fout = stdout;"
    body = string.Template(text).substitute(version="test", io_note="", open_io=io, close_io="")
    if override_prev:  # the 4th input is the logged previous command: breaks the observer's loop
        body = body.replace("float in[3];", "float in[4];").replace("fread(in, sizeof(float), 3, fin) == 3",
                                                                    "fread(in, sizeof(float), 4, fin) == 4")
        body = body.replace("out = fd_step(", "state.tau_m_prev = in[3];\n        out = fd_step(")
    (out_dir / "harness.c").write_text(body)
    exe = out_dir / "harness"
    subprocess.run([CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-o", str(exe),
                    str(out_dir / "harness.c"), str(out_dir / "fd_controller.c")], check=True)
    return exe


def _run(exe, inputs):
    raw = np.ascontiguousarray(inputs, dtype="<f4").tobytes()
    out = subprocess.run([str(exe)], input=raw, capture_output=True, check=True).stdout
    return np.frombuffer(out, dtype="<f4").astype(float)


@pytest.fixture(scope="module")
def closed_loop_log():
    """10 s of closed-loop measurements from the simulator (square reference, Coulomb friction)."""
    from forecast_design.effects import Coulomb
    from forecast_design.export.c import resolve_design
    from forecast_design.simulation.references import Square
    from forecast_design.simulation.run import simulate

    logs = {}
    for kind in KINDS:
        sim = simulate(resolve_design(compensator=kind), reference=Square(high=0.2, low=-0.2, period_s=1.0),
                       duration_s=10.0, effects=[Coulomb(F_c=0.1)])
        c = sim.to_experiment().signals.columns()
        logs[kind] = np.column_stack([c["tau_r"], c["tau_s"], c["theta"], c["tau_m"]])
    return logs


@needs_cc
@pytest.mark.parametrize("kind", KINDS)
def test_c_equals_float32_python_bit_for_bit(kind, tmp_path, closed_loop_log):
    res = export_controller(out_dir=tmp_path, compensator=kind)
    exe = _harness(tmp_path, override_prev=False)
    x = closed_loop_log[kind][:, :3].astype(np.float32).astype(float)
    y_c = _run(exe, x)
    y_py = res.program.make_step(np.float32).run(*x.T)
    assert np.max(np.abs(y_c - y_py)) == 0.0


@needs_cc
@pytest.mark.parametrize("kind", KINDS)
def test_c_matches_simulator_controller_float64(kind, tmp_path, closed_loop_log):
    """Same 10 s input sequence into the C (float32) and the simulator's own step objects (float64)."""
    from forecast_design.simulation.controllers import DiscretePD, ObserverCompensator

    res = export_controller(out_dir=tmp_path, compensator=kind)
    exe = _harness(tmp_path, override_prev=True)
    log = closed_loop_log[kind].astype(np.float32).astype(float)
    prev = np.concatenate([[0.0], log[:-1, 3]])
    y_c = _run(exe, np.column_stack([log[:, :3], prev]))
    pd = DiscretePD(res.design.controller, 2000.0)
    obs = ObserverCompensator(res.design.compensator, res.design, 2000.0) if kind != "none" else None
    y_py = np.array([pd.step(r - s) + (obs.step(p, s, th) if obs else 0.0)
                     for (r, s, th, _), p in zip(log, prev)])
    err = np.max(np.abs(y_c - y_py))
    tol = {"none": 1e-4, "lo-dob": 2e-4, "motor-fob": 5e-4, "ea-fob": 2e-3}[kind]
    assert err <= tol, f"max |C - Python| = {err:.3g} N m"


def test_export_is_deterministic_and_records_provenance(tmp_path):
    a = export_controller(out_dir=tmp_path / "a", compensator="ea-fob")
    b = export_controller(out_dir=tmp_path / "b", compensator="ea-fob")
    assert a.digest == b.digest
    text = a.source.read_text()
    assert "method       tustin" in text and "w_q_hz = 10.0" in text and "forecast-design" in text
    assert "malloc" not in text and "double" not in text and "math.h" not in text
    header = a.header.read_text()
    assert "typedef struct fd_state" in header and "float fd_step(fd_state *s, float tau_r, float tau_s" in header


def test_upload_blob_round_trips_float32(tmp_path):
    res = export_controller(out_dir=tmp_path, compensator="motor-fob", tau_max=3.0)
    back = ControllerProgram.from_bytes(res.program.to_bytes())
    assert back.tau_max == 3.0 and [c.source for c in back.channels] == [c.source for c in res.program.channels]
    for c0, c1 in zip(res.program.channels, back.channels):
        assert np.array_equal(c0.sos.astype(np.float32).astype(float), c1.sos)


@pytest.mark.parametrize("text", ["pd:5", "pid:1:2:3", "pd:x:1", "pd:5:-1"])
def test_parse_controller_garbage(text):
    with pytest.raises(ParameterError, match="controller"):
        parse_controller(text)


@needs_cc
def test_object_references_no_libm(tmp_path):
    export_controller(out_dir=tmp_path, compensator="ea-fob")
    obj = tmp_path / "fd.o"
    subprocess.run([CC, "-std=c99", "-O2", "-c", "-o", str(obj), str(tmp_path / "fd_controller.c")], check=True)
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("no nm")
    undefined = subprocess.run([nm, "-u", str(obj)], capture_output=True, text=True, check=True).stdout.split()
    assert not [s for s in undefined if s not in ("U",)]
