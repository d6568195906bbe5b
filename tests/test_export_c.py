"""C export: host-compiled equivalence with the Python discrete implementation, closed loop, no libm."""

import string
import subprocess
from importlib import resources

import numpy as np
import pytest

from forecast_design.errors import ParameterError
from forecast_design.export import toolchain
from forecast_design.controllers import parse_controller
from forecast_design.export.c import export_controller, resolve_design
from forecast_design.program import ControllerProgram

TOOLS = toolchain.find_tools()
needs_cc = pytest.mark.skipif(TOOLS.cc is None, reason="no host C compiler (cc/gcc) on PATH")
KINDS = ["none", "sfm", "ea-fob", "lo-dob", "ld-dob", "motor-fob"]
LINEAR = [k for k in KINDS if k != "sfm"]
#: The issue's requirement: float32 C against the float64 Python design implementation.
TOL_F32_VS_F64 = 1e-4  # [N m]
#: Extended SFM of Section 7 (viscous, Coulomb, angle harmonics 1..4 and a direction-signed one),
#: values of the size the friction identification returns on the testbed.
SFM_PARAMS = {"viscous": 0.35, "coulomb": 0.30, "offset": 0.01,
              "sin1": 0.040, "cos1": -0.020, "sin2": 0.015, "cos2": 0.010,
              "sin3": -0.008, "cos3": 0.006, "sin4": 0.004, "cos4": -0.003, "coulomb_sin1": 0.02}


def _export(kind, out_dir, **kw):
    return export_controller(out_dir=out_dir, compensator=kind, sfm_params=SFM_PARAMS if kind == "sfm" else None,
                             **kw)


def _harness(out_dir, override_prev):
    text = resources.files("forecast_design.export").joinpath("templates", "fd_harness.c.in").read_text()
    io = "    FILE *fin = stdin;\n    FILE *fout = stdout;"
    body = string.Template(text).substitute(version="test", io_note="", open_io=io, close_io="")
    if override_prev:  # a 5th input is the logged previous command: breaks the observer's loop
        body = body.replace("float in[4];", "float in[5];").replace("fread(in, sizeof(float), 4, fin) == 4",
                                                                    "fread(in, sizeof(float), 5, fin) == 5")
        body = body.replace("out = fd_step(", "state.tau_m_prev = in[4];\n        out = fd_step(")
    (out_dir / "harness.c").write_text(body)
    exe = out_dir / "harness"
    subprocess.run([TOOLS.cc, *toolchain.HOST_CFLAGS, "-o", str(exe), str(out_dir / "harness.c"),
                    str(out_dir / "fd_controller.c"), "-lm"], check=True)
    return exe


@pytest.fixture(scope="module")
def closed_loop_log():
    """10 s of closed-loop measurements from the simulator per compensator (square reference, Coulomb)."""
    from forecast_design.effects import Coulomb
    from forecast_design.simulation.references import Square
    from forecast_design.simulation.run import simulate

    logs = {}
    for kind in KINDS:
        sim = simulate(resolve_design(compensator=kind), reference=Square(high=0.2, low=-0.2, period_s=1.0),
                       duration_s=10.0, effects=[Coulomb(F_c=0.1)],
                       sfm_params=SFM_PARAMS if kind == "sfm" else None)
        c = sim.to_experiment().signals.columns()
        logs[kind] = np.column_stack([c["tau_r"], c["tau_s"], c["theta"], c["tau_m"]])
    return logs


@needs_cc
@pytest.mark.parametrize("kind", KINDS)
def test_c_equals_float32_python(kind, tmp_path, closed_loop_log):
    """The C is the float32 ProgramStep: bit for bit for the linear parts (no FMA on either side)."""
    res = _export(kind, tmp_path)
    exe = toolchain.build_host(tmp_path)
    x = closed_loop_log[kind][:, :3].astype(np.float32).astype(float)
    y_c = toolchain.run_host(exe, x)
    y_py = res.program.make_step(np.float32).run(*x.T)
    if kind == "sfm":  # glibc sinf/cosf vs numpy's float32 sin/cos may differ in the last bit
        assert np.max(np.abs(y_c - y_py)) <= 1e-5
    else:
        assert np.max(np.abs(y_c - y_py)) == 0.0


@needs_cc
@pytest.mark.parametrize("kind", KINDS)
def test_c_matches_an_independent_float64_implementation(kind, tmp_path, closed_loop_log):
    """Same 10 s input sequence into the C (float32) and scipy's lfilter of the same laws (float64):
    the controller's C(z) on the error, the compensator's discrete filters on their signals (or the
    friction feed-forward)."""
    from scipy.signal import lfilter

    from forecast_design.compensators import compensator_strategy

    res = _export(kind, tmp_path)
    exe = _harness(tmp_path, override_prev=True)
    log = closed_loop_log[kind].astype(np.float32).astype(float)
    prev = np.concatenate([[0.0], log[:-1, 3]])
    raw = np.column_stack([log[:, :3], np.zeros(len(prev)), prev]).astype("<f4").tobytes()
    y_c = np.frombuffer(subprocess.run([str(exe)], input=raw, capture_output=True, check=True).stdout,
                        dtype="<f4").astype(float)
    C = res.design.controller.discrete_law(2000.0).feedback_tf()
    u = lfilter(C.num, C.den, log[:, 0] - log[:, 1])
    comp = res.design.compensator
    strategy = compensator_strategy(comp)
    if kind == "sfm":
        hat = strategy.feedforward(comp, 2000.0).evaluate(log[:, 2])
    else:
        signals = {"tau_m_prev": prev, "tau_s": log[:, 1], "theta": log[:, 2]}
        hat = sum((lfilter(tf.num, tf.den, signals[src])
                   for src, tf in strategy.discrete_filters(comp, res.design, 2000.0).paths()), np.zeros(len(log)))
    y_py = u + hat
    err = np.max(np.abs(y_c - y_py))
    assert err <= TOL_F32_VS_F64, f"max |C - Python| = {err:.3g} N m"
    if kind != "none":  # the compensator matters: its share of the command is far above the tolerance
        assert np.max(np.abs(y_py - u)) > 100 * TOL_F32_VS_F64


@needs_cc
@pytest.mark.parametrize("kind", ["ea-fob", "motor-fob", "sfm"])
def test_c_controller_in_closed_loop_with_the_virtual_testbed(kind, tmp_path):
    """The compiled C (ctypes) against the simulator's plant stepping: tau_s follows the Python controller's.

    The linear controllers are compared with the float64 design implementation. The SFM's
    sign(v_hat) is discontinuous: where float32 and float64 v_hat straddle zero the command jumps
    by 2 coulomb for a sample, so the SFM is compared with the float32 Python implementation.
    """
    from forecast_design.effects import Coulomb
    from forecast_design.simulation import plant_stepper

    res = _export(kind, tmp_path)
    c_ctrl = toolchain.HostController(toolchain.build_host(tmp_path, shared=True), res.program.n_sections)
    runs = {}
    reference = res.program.make_step(np.float32 if kind == "sfm" else np.float64)
    for label, ctrl in (("c", c_ctrl), ("python", reference)):
        bed = plant_stepper(res.design, [Coulomb(F_c=0.1)], n=10_000, process_noise_std=0.0)
        tau_s = np.empty(10_000)
        for i in range(tau_s.size):
            th, _, ts = bed.measure()
            tau_r = 0.2 if (i // 1000) % 2 == 0 else -0.2  # 1 Hz square, 5 s
            bed.advance(ctrl.step(tau_r, ts, th))
            tau_s[i] = ts
        runs[label] = tau_s
    assert np.max(np.abs(runs["c"] - runs["python"])) <= 1e-3
    # and the loop tracks: mean |error| over the last half-period of each step is small
    assert abs(np.mean(runs["c"][500:1000]) - 0.2) < 0.05


def test_export_is_deterministic_and_records_provenance(tmp_path):
    a = export_controller(out_dir=tmp_path / "a", compensator="ea-fob")
    b = export_controller(out_dir=tmp_path / "b", compensator="ea-fob")
    assert a.digest == b.digest
    text = a.source.read_text()
    assert "law          PD P=5 D=0.1" in text and "w_q_hz = 10.0" in text and "forecast-design" in text
    assert "filters discretised tustin" in text
    assert "malloc" not in text and "double" not in text and "math.h" not in text
    header = a.header.read_text()
    assert "typedef struct fd_state" in header and "float fd_step(fd_state *s, float tau_r, float tau_s" in header


def test_upload_blob_round_trips_float32(tmp_path):
    res = export_controller(out_dir=tmp_path, compensator="motor-fob", tau_max=3.0)
    back = ControllerProgram.from_bytes(res.program.to_bytes())
    assert back.tau_max == 3.0 and [c.source for c in back.channels] == [c.source for c in res.program.channels]
    for c0, c1 in zip(res.program.channels, back.channels):
        assert np.array_equal(c0.sos.astype(np.float32).astype(float), c1.sos)


@pytest.mark.parametrize("text", ["pd:5", "pi:1:2:3", "pd:x:1", "pd:5:-1"])
def test_parse_controller_garbage(text):
    with pytest.raises(ParameterError, match="controller"):
        parse_controller(text)


@needs_cc
@pytest.mark.parametrize("kind", ["ea-fob", "sfm"])
def test_object_references_no_double_libm(kind, tmp_path):
    _export(kind, tmp_path)
    obj = tmp_path / "fd.o"
    subprocess.run([TOOLS.cc, *toolchain.HOST_CFLAGS, "-c", "-o", str(obj), str(tmp_path / "fd_controller.c")],
                   check=True)
    undefined = set(toolchain.undefined_symbols(obj, nm="nm"))
    if kind == "ea-fob":
        assert undefined == set()
    else:  # gcc may merge sinf + cosf of one angle into sincosf: still the float versions
        assert undefined and undefined <= {"sinf", "cosf", "sincosf"}


@needs_cc
def test_a_header_and_a_source_of_two_exports_do_not_compile_together(tmp_path):
    """A pair left mixed (an export interrupted during its renames, or files copied by hand) is a compile
    error naming the cause; each export's own pair compiles."""
    a = export_controller(out_dir=tmp_path / "a", compensator="ea-fob")
    b = export_controller(out_dir=tmp_path / "b", compensator="lo-dob")

    def compile_pair(header, source):
        d = tmp_path / f"mix-{header.parent.name}{source.parent.name}"
        d.mkdir()
        (d / "fd_controller.h").write_bytes(header.read_bytes())
        (d / "fd_controller.c").write_bytes(source.read_bytes())
        return subprocess.run([TOOLS.cc, "-std=c99", "-c", "-o", str(d / "x.o"), str(d / "fd_controller.c")],
                              capture_output=True, text=True)

    assert compile_pair(a.header, a.source).returncode == 0 and compile_pair(b.header, b.source).returncode == 0
    mixed = compile_pair(a.header, b.source)
    assert mixed.returncode != 0 and "come from different exports" in mixed.stderr
