"""Tests of forecast_design.experiment against the forecast-experiment/1 contract."""

from __future__ import annotations

import csv
import dataclasses
import math
import re
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings

from forecast_design.errors import ExperimentFormatError, ParameterError
from forecast_design.experiment import (
    FORMAT,
    Experiment,
    Signals,
    experiment_from_arrays,
    load_experiment,
    save_experiment,
)
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design, Environment, Testbed, environment_preset

import strategies

DATA = Path(__file__).resolve().parent / "data"
SHARED = Path(__file__).resolve().parents[1].parent / "shared"

RATE = 2000.0


# --- helpers ---------------------------------------------------------------------------


def _base_toml() -> dict:
    """The spec's example TOML as a mapping (parsed from the golden file)."""
    doc = tomllib.loads((DATA / "spec_example.toml").read_text())
    doc["data"] = "run.csv"
    return doc


def _csv_text(n: int = 6, *, header: str = "t,tau_m,theta,q", rate: float = RATE) -> str:
    rows = [header]
    for i in range(n):
        rows.append(f"{i / rate!r},{0.1 * i!r},{0.001 * i!r},{0.0002 * i!r}")
    return "\n".join(rows) + "\n"


def _write(tmp_path: Path, *, toml: dict | str | None = None, csv_text: str | None = None) -> Path:
    """Write run.toml (mapping or raw text) and run.csv; return the TOML path."""
    toml_path = tmp_path / "run.toml"
    doc = _base_toml() if toml is None else toml
    toml_path.write_text(doc if isinstance(doc, str) else tomli_w.dumps(doc))
    if csv_text is not None:
        (tmp_path / "run.csv").write_text(csv_text)
    return toml_path


def _raises(tmp_path: Path, pattern: str, *, toml=None, csv_text: str | None = None,
            file: str = "run.toml") -> ExperimentFormatError:
    """Load and expect an ExperimentFormatError whose single-line message starts with the
    file's path and then matches ``pattern``."""
    path = _write(tmp_path, toml=toml, csv_text=_csv_text() if csv_text is None else csv_text)
    full = re.escape(str(tmp_path / file)) + r": .*" + pattern
    with pytest.raises(ExperimentFormatError, match=full) as info:
        load_experiment(path)
    message = str(info.value)
    assert "\n" not in message and "\r" not in message, message
    return info.value


def _plain_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """Read a CSV with the standard library only (independent of the loader)."""
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array([[float(x) for x in row] for row in rows[1:]])


def _closed_loop_design() -> Design:
    return Design(testbed=Testbed(), environment=Environment(J_e=1e-3, d_e=0.063, k_e=5.0),
                  controller=PD(P=5.0, D=0.1),
                  compensator=Compensator(kind="ea-fob", w_q_hz=10.0))


def _example(rng, n: int = 200, design: Design | None = None, **kwargs) -> Experiment:
    design = _closed_loop_design() if design is None else design
    t = 3.25 + np.arange(n) / RATE
    q = np.zeros(n) if design.environment.locked else rng.standard_normal(n) * 1e-3
    return experiment_from_arrays(design, RATE, t, rng.standard_normal(n), rng.standard_normal(n) * 1e-2,
                                  q, **kwargs)


# --- round trips ----------------------------------------------------------------------


def test_save_load_round_trip_arrays_bit_identical_and_designs_equal(tmp_path, rng):
    n = 500
    exp = _example(rng, n, tau_r=rng.standard_normal(n),
                   extra={"i_a": rng.standard_normal(n), "temp_C": 20 + rng.random(n)},
                   description="PD step\nsecond line, ünïcode")
    path = save_experiment(exp, tmp_path / "run01.toml")
    back = load_experiment(path)
    assert back == exp
    assert back.design == exp.design
    assert back.description == exp.description
    assert back.rate_hz == RATE
    for name, arr in exp.signals.columns(include_derived=True).items():
        assert np.array_equal(back.signals.columns(include_derived=True)[name], arr), name
    assert list(back.signals.extra) == ["i_a", "temp_C"]
    assert back.data == "run01.csv" and back.source == tmp_path / "run01.toml"


def test_save_measured_tau_s_is_kept_not_overwritten(tmp_path, rng):
    n = 50
    measured = rng.standard_normal(n)  # deliberately unrelated to k (theta - q)
    exp = _example(rng, n, tau_s=measured)
    back = load_experiment(save_experiment(exp, tmp_path / "m.toml"))
    assert not back.signals.tau_s_derived
    assert np.array_equal(back.signals.tau_s, measured)
    header, _ = _plain_csv(tmp_path / "m.csv")
    assert header == ["t", "tau_m", "theta", "q", "tau_s"]


def test_round_trip_locked_environment(tmp_path, rng):
    design = Design.nominal("locked", controller=PD(P=2.0, D=0.05))
    exp = _example(rng, 100, design=design)
    back = load_experiment(save_experiment(exp, tmp_path / "locked.toml"))
    assert back == exp
    assert back.design.environment.locked is True
    assert back.design.environment == environment_preset("locked")
    assert tomllib.loads((tmp_path / "locked.toml").read_text())["environment"]["locked"] is True


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kwargs=strategies.experiments())
def test_round_trip_property_any_valid_design_and_signals(kwargs):
    exp = experiment_from_arrays(**kwargs)
    with tempfile.TemporaryDirectory() as folder:
        back = load_experiment(save_experiment(exp, Path(folder) / "x.toml"))
    assert back.design == exp.design
    assert back == exp
    for name, arr in exp.signals.columns(include_derived=True).items():
        # array_equal treats -0.0 == 0.0; compare bit patterns to prove "bit-identical".
        assert back.signals.columns(include_derived=True)[name].tobytes() == arr.tobytes(), name


def test_derived_tau_s_equals_k_times_theta_minus_q(tmp_path):
    toml_path = _write(tmp_path, csv_text=_csv_text(20))
    exp = load_experiment(toml_path)
    header, table = _plain_csv(tmp_path / "run.csv")
    theta, q = table[:, header.index("theta")], table[:, header.index("q")]
    assert exp.signals.tau_s_derived
    assert np.array_equal(exp.signals.tau_s, 58.0 * (theta - q))
    # Derived tau_s follows the design: another k, another tau_s.
    stiffer = dataclasses.replace(exp, design=dataclasses.replace(
        exp.design, testbed=Testbed(J_m=0.133, d_m=0.3, k=100.0)))
    assert np.array_equal(stiffer.signals.tau_s, 100.0 * (theta - q))


def test_derived_tau_s_is_not_written(tmp_path, rng):
    exp = _example(rng, 10)
    save_experiment(exp, tmp_path / "d.toml")
    header, _ = _plain_csv(tmp_path / "d.csv")
    assert "tau_s" not in header


def test_window_keeps_rows_in_half_open_interval(rng):
    exp = _example(rng, 100)
    t = exp.signals.t
    win = exp.window(t[10], t[30])
    assert win.n_samples == 20
    assert np.array_equal(win.signals.t, t[10:30])
    assert np.array_equal(win.signals.tau_m, exp.signals.tau_m[10:30])
    assert np.array_equal(win.signals.tau_s, exp.signals.tau_s[10:30])
    assert win.design == exp.design and win.rate_hz == exp.rate_hz
    assert exp.window(None, t[5]).n_samples == 5
    assert exp.window(t[95]).n_samples == 5
    with pytest.raises(ParameterError, match="holds no samples"):
        exp.window(t[-1] + 1.0, t[-1] + 2.0)
    with pytest.raises(ParameterError, match="t1 > t0"):
        exp.window(t[5], t[5])


def test_signal_arrays_are_read_only_and_copied(rng):
    tau_m = rng.standard_normal(8)
    exp = experiment_from_arrays(Design.nominal(), 100.0, np.arange(8) / 100.0, tau_m,
                                 np.zeros(8), np.zeros(8), extra={"x": np.ones(8)})
    tau_m[0] = 1e9  # the caller's array is not aliased
    assert exp.signals.tau_m[0] != 1e9
    for arr in exp.signals.columns(include_derived=True).values():
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        exp.rate_hz = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        exp.signals.extra["y"] = np.ones(8)  # type: ignore[index]


def test_replace_signals_switches_tau_s_between_measured_and_derived(rng):
    exp = _example(rng, 30)
    measured = exp.replace_signals(tau_s=np.ones(30))
    assert not measured.signals.tau_s_derived and np.array_equal(measured.signals.tau_s, np.ones(30))
    derived = measured.replace_signals(tau_s=None)
    assert derived.signals.tau_s_derived
    assert np.array_equal(derived.signals.tau_s, 58.0 * (exp.signals.theta - exp.signals.q))
    with pytest.raises(ParameterError, match="unknown signal 'tau_x'"):
        exp.replace_signals(tau_x=np.ones(30))


def test_dt_and_n_samples(rng):
    exp = _example(rng, 42)
    assert exp.dt == 1.0 / RATE and exp.n_samples == 42 and len(exp.signals) == 42


def test_saved_files_match_spec_with_plain_readers(tmp_path, rng):
    n = 25
    exp = _example(rng, n, tau_r=rng.standard_normal(n), extra={"i_a": rng.standard_normal(n)})
    exp = dataclasses.replace(exp, design=dataclasses.replace(exp.design, compensator=None))
    save_experiment(exp, tmp_path / "sub" / "run07.toml")
    doc = tomllib.loads((tmp_path / "sub" / "run07.toml").read_text())
    assert doc["format"] == "forecast-experiment/1" == FORMAT
    assert doc["data"] == "run07.csv" and (tmp_path / "sub" / doc["data"]).is_file()
    assert doc["sampling"] == {"rate_hz": RATE}
    assert doc["testbed"] == {"J_m": 0.133, "d_m": 0.3, "k": 58.0}
    assert set(doc["environment"]) == {"J_e", "d_e", "k_e", "J_l", "d_l", "locked"}
    assert doc["controller"] == {"kind": "pd", "P": 5.0, "D": 0.1}
    assert "compensator" not in doc  # only when present
    assert set(doc) == {"format", "data", "sampling", "testbed", "environment", "controller"}
    header, table = _plain_csv(tmp_path / "sub" / "run07.csv")
    assert header == ["t", "tau_m", "theta", "q", "tau_r", "i_a"]
    for j, name in enumerate(header):
        assert np.array_equal(table[:, j], exp.signals.columns()[name]), name
    # No temporary files are left behind by the atomic writes.
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["run07.csv", "run07.toml"]


def test_save_with_explicit_data_path_in_subfolder(tmp_path, rng):
    exp = _example(rng, 10)
    save_experiment(exp, tmp_path / "a.toml", data="logs/a_data.csv")
    assert tomllib.loads((tmp_path / "a.toml").read_text())["data"] == "logs/a_data.csv"
    assert load_experiment(tmp_path / "a.toml") == exp


def test_compensator_none_kind_writes_only_kind(tmp_path, rng):
    design = dataclasses.replace(_closed_loop_design(), compensator=Compensator(kind="sfm"))
    exp = _example(rng, 10, design=design)
    save_experiment(exp, tmp_path / "c.toml")
    assert tomllib.loads((tmp_path / "c.toml").read_text())["compensator"] == {"kind": "sfm"}
    assert load_experiment(tmp_path / "c.toml").design.compensator == Compensator(kind="sfm")


def test_save_overwrites_existing_files_atomically(tmp_path, rng):
    first, second = _example(rng, 10), _example(rng, 20)
    save_experiment(first, tmp_path / "o.toml")
    save_experiment(second, tmp_path / "o.toml")
    assert load_experiment(tmp_path / "o.toml") == second
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.csv", "o.toml"]


def test_failed_save_leaves_previous_files_and_no_temporaries(tmp_path, rng, monkeypatch):
    first = _example(rng, 10)
    save_experiment(first, tmp_path / "f.toml")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr("forecast_design.experiment.os.replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        save_experiment(_example(rng, 20), tmp_path / "f.toml")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    monkeypatch.undo()
    assert load_experiment(tmp_path / "f.toml") == first


def test_golden_spec_example_loads_with_spec_values():
    exp = load_experiment(DATA / "spec_example.toml")
    assert exp.description == "PD force step, soft environment"
    assert exp.rate_hz == 2000.0
    assert exp.design.testbed == Testbed(J_m=0.133, d_m=0.3, k=58.0)
    assert exp.design.environment == Environment(J_e=0.001, d_e=0.063, k_e=5.0, J_l=0.0018, d_l=0.35)
    assert exp.design.controller == PD(P=5.0, D=0.1)
    assert exp.design.compensator == Compensator(kind="ea-fob", w_q_hz=10.0)
    header, table = _plain_csv(DATA / "spec_example.csv")
    assert list(exp.signals.columns()) == header
    for j, name in enumerate(header):
        assert np.array_equal(exp.signals.columns()[name], table[:, j])
    assert np.array_equal(exp.signals.tau_s, 58.0 * (table[:, 2] - table[:, 3]))
    assert list(exp.signals.extra) == ["i_a"]


def test_emps_time_column_jitter_passes_uniformity_check():
    """Real logs carry float jitter in t; EMPS (1 kHz) steps deviate by ~2e-5 relative."""
    path = SHARED / "data" / "emps" / "emps_train.csv"
    if not path.is_file():
        pytest.skip("shared EMPS data not available")
    header, table = _plain_csv(path)
    t = table[:, header.index("t_s")]
    step = np.diff(t)
    assert 1e-6 < np.max(np.abs(step * 1000.0 - 1.0)) < 1e-3  # jitter is really there
    zeros = np.zeros_like(t)
    exp = experiment_from_arrays(Design.nominal("locked"), 1000.0, t, zeros, zeros, zeros)
    assert exp.n_samples == t.size


def test_summary_is_json_ready(rng):
    import json

    exp = _example(rng, 10)
    summary = json.loads(json.dumps(exp.summary()))
    assert summary["n_samples"] == 10 and summary["rate_hz"] == RATE
    assert summary["columns"] == ["t", "tau_m", "theta", "q"] and summary["tau_s_derived"] is True
    assert summary["design"]["compensator"] == {"kind": "ea-fob", "w_q_hz": 10.0}


def test_large_csv_bad_cell_deep_in_file_named_by_line(tmp_path):
    n = 60_000
    lines = _csv_text(n).splitlines()
    lines[50_000] = lines[50_000].replace(",", ",x", 1)  # row index 49_999 -> line 50_001
    err = _raises(tmp_path, r"line 50001, column 'tau_m': 'x[^']*' is not a number",
                  csv_text="\n".join(lines) + "\n", file="run.csv")
    assert err.key == "tau_m"


@pytest.mark.slow
def test_million_row_csv_round_trips_in_seconds(tmp_path, rng):
    n = 1_000_000
    exp = _example(rng, n, tau_r=rng.standard_normal(n))
    save_experiment(exp, tmp_path / "big.toml")
    start = time.perf_counter()
    back = load_experiment(tmp_path / "big.toml")
    elapsed = time.perf_counter() - start
    assert back == exp
    assert elapsed < 15.0, f"loading 1e6 rows took {elapsed:.1f} s"


# --- bad input: each rule, one test, message names file and key/line -----------------


def test_missing_toml_file_names_file(tmp_path):
    with pytest.raises(ExperimentFormatError, match=re.escape(str(tmp_path / "nope.toml")) + ": .*not found"):
        load_experiment(tmp_path / "nope.toml")


def test_toml_syntax_error_names_file_and_line(tmp_path):
    text = (DATA / "spec_example.toml").read_text().replace("k   = 58.0", "k = = 58.0")
    err = _raises(tmp_path, r"TOML syntax error: .*line 13", toml=text)
    assert err.key == "line 13"


@pytest.mark.parametrize("section,key", [(None, "format"), (None, "data"), ("sampling", "rate_hz"),
                                         ("testbed", "k"), ("environment", "d_l"), ("controller", "P")])
def test_missing_key_names_key_and_file(tmp_path, section, key):
    doc = _base_toml()
    del (doc if section is None else doc[section])[key]
    err = _raises(tmp_path, rf"missing required key '{key}'", toml=doc)
    assert err.key == (key if section is None else f"{section}.{key}")
    assert err.path == str(tmp_path / "run.toml")


@pytest.mark.parametrize("table", ["sampling", "testbed", "environment"])
def test_missing_required_table_names_table(tmp_path, table):
    doc = _base_toml()
    del doc[table]
    _raises(tmp_path, rf"missing required table \[{table}\]", toml=doc)


@pytest.mark.parametrize("section,key", [(None, "notes"), ("sampling", "dt"), ("testbed", "J_x"),
                                         ("environment", "k_env"), ("controller", "I"),
                                         ("compensator", "q_shape"), ("compensator", "friction")])
def test_unknown_key_names_key_and_file(tmp_path, section, key):
    # a key of another kind is as foreign as an unknown one (the pd's I, an ea-fob's friction)
    doc = _base_toml()
    (doc if section is None else doc[section])[key] = 1.0
    err = _raises(tmp_path, rf"(unknown (top-level )?key '{key}'|key '{key}' does not belong to kind)", toml=doc)
    assert err.key == (key if section is None else f"{section}.{key}")


@pytest.mark.parametrize("value", ["forecast-experiment/2", "forecast-experiment/1 ", 1])
def test_wrong_format_string(tmp_path, value):
    doc = _base_toml()
    doc["format"] = value
    err = _raises(tmp_path, r'format must be "forecast-experiment/1", got ' + re.escape(repr(value)),
                  toml=doc)
    assert err.key == "format"


@pytest.mark.parametrize("section,key,value,pattern", [
    ("sampling", "rate_hz", "2000", r"\[sampling\] rate_hz must be a number"),
    ("testbed", "k", "58", r"\[testbed\] k must be a number"),
    ("environment", "locked", "no", r"\[environment\] locked must be true or false"),
    ("controller", "D", True, r"\[controller\] D must be a number"),
    (None, "description", 3, r"description must be a string"),
    (None, "data", 5, r"data must be a non-empty string"),
    (None, "testbed", 5, r"\[testbed\] must be a table"),
])
def test_wrong_type_names_key_and_file(tmp_path, section, key, value, pattern):
    doc = _base_toml()
    (doc if section is None else doc[section])[key] = value
    _raises(tmp_path, pattern, toml=doc)


@pytest.mark.parametrize("rate", [0.0, -2000.0, float("inf"), float("nan")])
def test_nonpositive_or_nonfinite_rate_rejected(tmp_path, rate):
    doc = _base_toml()
    doc["sampling"]["rate_hz"] = rate
    err = _raises(tmp_path, r"\[sampling\] rate_hz must be > 0 and finite", toml=doc)
    assert err.key == "sampling.rate_hz"


@pytest.mark.parametrize("section,key,value", [("testbed", "J_m", -0.133), ("testbed", "k", -58.0),
                                               ("testbed", "k", 0.0), ("environment", "J_e", -1e-3)])
def test_negative_inertia_or_stiffness_names_key_and_file(tmp_path, section, key, value):
    doc = _base_toml()
    doc[section][key] = value
    err = _raises(tmp_path, rf"\[{section}\] {key} must be >=? 0, got {re.escape(repr(value))}", toml=doc)
    assert err.key == f"{section}.{key}"
    assert str(err).count(f"[{section}]") == 1


def test_missing_csv_names_csv_and_data_key(tmp_path):
    toml_path = _write(tmp_path)  # no CSV written
    pattern = (re.escape(str(tmp_path / "run.csv")) + r": CSV file not found \(the 'data' key of "
               + re.escape(str(toml_path)) + r" is 'run.csv'\)")
    with pytest.raises(ExperimentFormatError, match=pattern) as info:
        load_experiment(toml_path)
    assert info.value.key == "data"


def test_empty_csv(tmp_path):
    _raises(tmp_path, r"empty file; expected a header line", csv_text="", file="run.csv")


def test_header_only_csv(tmp_path):
    err = _raises(tmp_path, r"no data rows \(header only\)", csv_text="t,tau_m,theta,q\n", file="run.csv")
    assert err.key == "line 2"


def test_missing_required_column_lists_required(tmp_path):
    text = _csv_text().replace("theta", "theta_m")
    err = _raises(tmp_path, r"column 'theta' missing; required columns: t, tau_m, theta, q",
                  csv_text=text, file="run.csv")
    assert err.key == "theta"


@pytest.mark.parametrize("sep,word", [(";", "semicolons"), ("\t", "tabs")])
def test_a_semicolon_or_tab_separated_file_is_named_as_such(tmp_path, sep, word):
    # what a spreadsheet in a comma-decimal locale writes: one line that says why, not only "missing"
    text = _csv_text().replace(",", sep)
    _raises(tmp_path, rf"column 't' missing; .* the header is separated by {word}, the format's CSV by commas",
            csv_text=text, file="run.csv")


def test_duplicate_column(tmp_path):
    text = "\n".join(line + (",1.0" if i else ",tau_m") for i, line in enumerate(_csv_text().splitlines()))
    _raises(tmp_path, r"line 1: duplicate column 'tau_m'", csv_text=text, file="run.csv")


def test_non_numeric_cell_names_line_and_column(tmp_path):
    lines = _csv_text().splitlines()
    cells = lines[3].split(",")
    cells[2] = "0.0o2"
    lines[3] = ",".join(cells)
    err = _raises(tmp_path, r"line 4, column 'theta': '0.0o2' is not a number",
                  csv_text="\n".join(lines), file="run.csv")
    assert err.key == "theta"


def test_ragged_row_names_line(tmp_path):
    lines = _csv_text().splitlines()
    lines[5] += ",7"
    _raises(tmp_path, r"line 6 has 5 fields but the header \(line 1\) has 4 columns",
            csv_text="\n".join(lines), file="run.csv")


def test_all_rows_shorter_than_header_names_line_2(tmp_path):
    text = _csv_text(header="t,tau_m,theta,q,tau_r")
    _raises(tmp_path, r"line 2 has 4 fields but the header \(line 1\) has 5 columns", csv_text=text,
            file="run.csv")


def test_blank_line_inside_data_names_line(tmp_path):
    lines = _csv_text().splitlines()
    lines.insert(3, "")
    _raises(tmp_path, r"line 4 is empty", csv_text="\n".join(lines) + "\n\n\n", file="run.csv")


@pytest.mark.parametrize("cell,shown", [("nan", "nan"), ("inf", "inf"), ("-inf", "-inf")])
def test_nonfinite_value_names_line_and_column(tmp_path, cell, shown):
    lines = _csv_text().splitlines()
    cells = lines[4].split(",")
    cells[3] = cell
    lines[4] = ",".join(cells)
    err = _raises(tmp_path, rf"line 5: column 'q' is {shown}; expected a finite number",
                  csv_text="\n".join(lines), file="run.csv")
    assert err.key == "q"


def test_t_not_strictly_increasing_names_line(tmp_path):
    lines = _csv_text(8).splitlines()
    lines[4], lines[5] = lines[5], lines[4]  # rows 3 and 4 swapped: line 6 goes back in time
    _raises(tmp_path, r"line 6: t = .* is not greater than t = .* of line 5; t must be strictly increasing",
            csv_text="\n".join(lines), file="run.csv")


def test_repeated_time_stamp_names_line(tmp_path):
    lines = _csv_text(8).splitlines()
    t3 = lines[3].split(",")[0]
    lines[4] = ",".join([t3] + lines[4].split(",")[1:])
    _raises(tmp_path, r"line 5: t = .* is not greater than", csv_text="\n".join(lines), file="run.csv")


def test_non_uniform_step_names_line(tmp_path):
    # 40 rows at 2 kHz; the step into line 12 is 2 % long and the next one 2 % short, so the
    # mean rate still agrees and only the per-step rule can fire.
    t = np.arange(40) / RATE
    t[10] += 0.02 / RATE
    text = "t,tau_m,theta,q\n" + "".join(f"{x!r},0,0,0\n" for x in t.tolist())
    _raises(tmp_path, r"line 12: t step of 0.00051 s deviates from 1/\[sampling\] rate_hz of "
            + re.escape(str(tmp_path / "run.toml")) + r" = 0.0005 s by more than 1%",
            csv_text=text, file="run.csv")


def test_dropped_sample_is_a_non_uniform_step(tmp_path):
    t = np.delete(np.arange(400) / RATE, 200)  # row 200 lost: line 202 holds t = 201 T
    text = "t,tau_m,theta,q\n" + "".join(f"{x!r},0,0,0\n" for x in t.tolist())
    _raises(tmp_path, r"line 202: t step of 0.001 s deviates", csv_text=text, file="run.csv")


def test_jitter_below_tolerance_passes(tmp_path, rng):
    t = (np.arange(1000) + 2e-5 * rng.standard_normal(1000)) / RATE  # EMPS-size jitter
    text = "t,tau_m,theta,q\n" + "".join(f"{x!r},0,0,0\n" for x in t.tolist())
    _write(tmp_path, csv_text=text)
    assert np.array_equal(load_experiment(tmp_path / "run.toml").signals.t, t)


def test_csv_rate_disagrees_with_toml_names_both_rates(tmp_path):
    err = _raises(tmp_path, r"mean step of 0.001 s \(1000 Hz\) but \[sampling\] rate_hz of "
                  + re.escape(str(tmp_path / "run.toml")) + r" = 2000 Hz; they differ by more than 1%",
                  csv_text=_csv_text(50, rate=1000.0), file="run.csv")
    assert err.key == "t"


def test_locked_with_nonzero_q_names_line(tmp_path):
    doc = _base_toml()
    doc["environment"]["locked"] = True
    err = _raises(tmp_path, r"line 3: q = 0.0002 rad but locked = true in "
                  + re.escape(str(tmp_path / "run.toml")) + r" requires q == 0",
                  toml=doc, file="run.csv")
    assert err.key == "q"


def test_locked_with_q_below_tolerance_loads(tmp_path):
    doc = _base_toml()
    doc["environment"]["locked"] = True
    text = "t,tau_m,theta,q\n" + "".join(f"{i / RATE!r},0,0.01,{(-1) ** i * 1e-10!r}\n" for i in range(5))
    _write(tmp_path, toml=doc, csv_text=text)
    exp = load_experiment(tmp_path / "run.toml")
    assert exp.design.environment.locked and np.max(np.abs(exp.signals.q)) == 1e-10


# --- in-memory construction validates like the loader ------------------------------


def _arrays(n: int = 10) -> dict:
    t = np.arange(n) / RATE
    return dict(design=Design.nominal(), rate_hz=RATE, t=t, tau_m=np.zeros(n), theta=np.zeros(n),
                q=np.zeros(n))


@pytest.mark.parametrize("change,pattern", [
    (dict(theta=np.r_[np.zeros(4), np.nan, np.zeros(5)]), r"sample 4: column 'theta' is nan"),
    (dict(t=np.r_[np.arange(5), np.arange(4, 9)] / RATE), r"sample 5: t = .* strictly increasing"),
    (dict(rate_hz=1000.0), r"mean step of 0.0005 s \(2000 Hz\) but rate_hz = 1000 Hz"),
    (dict(rate_hz=-1.0), r"rate_hz must be > 0"),
    (dict(tau_m=np.zeros(9)), r"signal 'tau_m' has 9 samples but 't' has 10"),
    (dict(q=np.zeros((10, 1))), r"signal 'q' must be a 1-D array"),
    (dict(t=np.array([]), tau_m=np.array([]), theta=np.array([]), q=np.array([])), r"no samples"),
    (dict(design=Design.nominal("locked"), q=np.full(10, 1e-3)),
     r"sample 0: q = 0.001 rad but locked = true"),
    (dict(extra={"tau_s": np.zeros(10)}), r"extra column name 'tau_s' is a spec column"),
    (dict(extra={"a,b": np.zeros(10)}), r"contains a comma"),
])
def test_experiment_from_arrays_validates_like_loader(change, pattern):
    kwargs = _arrays() | change
    with pytest.raises(ExperimentFormatError, match=pattern) as info:
        experiment_from_arrays(**kwargs)
    assert "\n" not in str(info.value)


def test_experiment_from_arrays_single_sample_is_valid():
    exp = experiment_from_arrays(**_arrays(1))
    assert exp.n_samples == 1 and exp.dt == 1.0 / RATE


def test_signals_equality_is_exact_and_ordered():
    common = dict(t=[0.0, 1.0], theta=[0.0, 0.0], q=[0.0, 0.0])
    a = Signals(**common, tau_m=[1.0, 2.0], extra={"x": [1, 2], "y": [3, 4]})
    b = Signals(**common, tau_m=[1.0, 2.0], extra={"y": [3, 4], "x": [1, 2]})
    c = Signals(t=[0.0, 1.0], tau_m=[1.0, math.nextafter(2.0, 3.0)], theta=[0.0, 0.0], q=[0.0, 0.0],
                extra={"x": [1, 2], "y": [3, 4]})
    assert a == Signals(t=[0.0, 1.0], tau_m=[1.0, 2.0], theta=[0.0, 0.0], q=[0.0, 0.0],
                        extra={"x": [1, 2], "y": [3, 4]})
    assert a != b and a != c
