"""The main job writes a complete report from bundled defaults."""

import json

from forecast_design import Compensator, loop_margins
from forecast_design.cli import main


def test_pipeline_writes_report_with_plots_and_consistent_numbers(tmp_path, capsys):
    assert main(["pipeline", "--out", str(tmp_path / "report"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    report = tmp_path / "report"
    index = (report / "index.md").read_text()
    for step, info in summary["steps"].items():
        assert f"## {step}" in index
        for name in info["files"]:
            path = report / name
            assert path.stat().st_size > 0, name
            if name.endswith(".png"):
                assert path.read_bytes()[:4] == b"\x89PNG"
            if name.endswith(".json"):
                json.loads(path.read_text())
    # The locked plant has unit DC gain whatever else the pipeline does.
    assert abs(summary["steps"]["derive"]["summary"]["locked"]["dc_gain"] - 1.0) < 1e-12
    tuned = summary["steps"]["tune"]["summary"]
    cutoff = {obs: t["w_q_hz"] for obs, t in tuned.items()}
    assert cutoff["ea-fob"] > cutoff["lo-dob"] and cutoff["ea-fob"] > cutoff["ld-dob"]
    # the EA-FOB keeps the plant's margin over the whole band: its cutoff is the band's end, and the summary says so
    assert tuned["ea-fob"]["w_q_hz"] == 30.0 and "30 Hz" in tuned["ea-fob"]["at_bound"]
    assert all(t["feasible"] and t["worst_ratio"] >= 0.9 for t in tuned.values())
    # The diagnosis names the effect the pipeline withheld from the nominal model.
    assert summary["steps"]["diagnose"]["summary"]["verdict"] == "cogging"
    assert summary["steps"]["diagnose"]["summary"]["reduction"] >= 0.5
    # Friction identified from the simulated log recovers the true mean level within 5 %.
    ident = summary["steps"]["identify"]["summary"]
    assert abs(ident["params"]["coulomb"] / ident["truth"]["F_c"] - 1) < 0.05
    # The exported C uses the cutoff tuned for the environment it is exported for (exp-soft): there it keeps
    # 90 % of the plant's own disk margin (exact margins, outside the tuner), which soft/stiff's cutoff does not.
    export = summary["steps"]["export"]["summary"]
    assert export["environment"] == "exp-soft"

    def ratio(w_q_hz):
        return (loop_margins("exp-soft", Compensator(kind="ea-fob", w_q_hz=w_q_hz)).alpha
                / loop_margins("exp-soft").alpha)

    assert ratio(export["w_q_hz"]) >= 0.9 * (1 - 1e-6) and ratio(tuned["ea-fob"]["w_q_hz"]) < 0.9
    assert (tmp_path / "report" / "export" / "fd_controller.c").read_text().count("fd_step") >= 1
