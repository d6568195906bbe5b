"""The paper's PD path before and after the controller seam (issue: any force controller).

Run with the package under test importable, once per tree, interleaved by the caller
(``farm-bench --vs``)::

    python benchmarks/bench_controller_seam.py simulate    # simulated s per wall s, 4 cases, 20 s each
    python benchmarks/bench_controller_seam.py benchmark   # the 7 x 3 x 10 benchmark command, fresh folder
    python benchmarks/bench_controller_seam.py tune-q      # tune-q --observer lo-dob on soft,stiff

Only names both trees have are used (the default controller of a ``Design`` is each tree's
paper PD), so the same file measures the tree before the seam (``PYTHONPATH=OLD_TREE``) and
after it. Prints one line ``<what> <figure>`` per case.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

SET = """[[environment]]
name = "k"
J_e = 0.01
k_e = {log = [0.1, 1000.0], n = 7}
"""


def _simulate() -> None:
    from forecast_design.effects import Stiction
    from forecast_design.params import Compensator, Design
    from forecast_design.simulation import Square, simulate

    for env, kind in (("fig7", "none"), ("fig7", "ea-fob"), ("fig7", "sfm"), ("locked", "ea-fob")):
        design = Design.nominal(env, compensator=Compensator(kind=kind, w_q_hz=10.0))
        kw = dict(reference=Square(high=1.0, low=-1.0, period_s=2.0), effects=[Stiction()],
                  sfm_params={"viscous": 0.4, "coulomb": 0.4} if kind == "sfm" else None)
        simulate(design, duration_s=0.01, **kw)          # compilation / cache load
        t0 = time.perf_counter()
        simulate(design, duration_s=20.0, **kw)
        print(f"simulate[{env},{kind}] {20.0 / (time.perf_counter() - t0):.1f}")


def _cli(argv: list[str]) -> None:
    from forecast_design.cli import main

    t0 = time.perf_counter()
    code = main(argv)
    print(f"{argv[0]} {time.perf_counter() - t0:.3f} (exit {code})")


def main() -> None:
    """Run the case named by the first argument."""
    what = sys.argv[1] if len(sys.argv) > 1 else "simulate"
    if what == "simulate":
        _simulate()
    elif what == "benchmark":
        tmp = Path(tempfile.mkdtemp())
        (tmp / "set.toml").write_text(SET)
        _cli(["benchmark", "--envs", str(tmp / "set.toml"), "--repetitions", "10", "--out", str(tmp / "out"),
              "--no-plots", "--json", str(tmp / "s.json")])
    elif what == "tune-q":
        _cli(["tune-q", "--observer", "lo-dob", "--env", "soft,stiff", "--json", str(Path(tempfile.mkdtemp()) / "t.json")])
    else:
        raise SystemExit(f"unknown case {what!r}: simulate, benchmark or tune-q")


if __name__ == "__main__":
    main()
