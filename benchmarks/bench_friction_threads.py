"""Friction fits with one BLAS thread against the default pool, interleaved in one process.

Run from the repository root::

    python benchmarks/bench_friction_threads.py [--logs N] [--repeat R]

``fit_friction`` runs with one BLAS thread (``friction._lsq.one_blas_thread``); its undecorated
body (``fit_friction.__wrapped__``) runs the fit, its adequacy tests and the scale check's refit
with OpenBLAS's default pool: the code before the decorator, except that the linear solve itself
had one thread then (the method error's refits keep their one thread in both). Both identify the same
independent extended-SFM logs (10 s at 2 kHz, the Monte Carlo of
``tests/test_friction_calibration.py``), alternately; the CPU seconds (all threads) and the
largest difference of the estimates are printed. With another process busy on a 2-core machine
(``pytest -n 2``) the default pool waits for its second thread at every product.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from forecast_design.friction import identify  # noqa: E402
from forecast_design.friction.identify import fit_friction  # noqa: E402
from forecast_design.independent import friction_log  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    mod = sys.modules["forecast_design.friction.identify"]

    logs = [friction_log("extended-sfm", seed=s, duration_s=10.0)[0] for s in range(args.logs)]
    cpu = {"one thread": 0.0, "default pool": 0.0}
    worst = 0.0
    for _ in range(args.repeat):
        for exp in logs:
            fits = {}
            for label, fn in (("one thread", fit_friction), ("default pool", fit_friction.__wrapped__)):
                mod.fit_friction = fn          # identify() calls the module's name
                a = time.process_time()
                fits[label] = identify(exp, "extended-sfm", holdout=0.0)
                cpu[label] += time.process_time() - a
            mod.fit_friction = fit_friction
            a, b = fits["one thread"], fits["default pool"]
            worst = max([worst] + [abs(a.params[k] - b.params[k]) / max(abs(b.params[k]), 1e-300) for k in a.params])
    n = args.logs * args.repeat
    for label, s in cpu.items():
        print(f"{label:13s} {s / n:.3f} CPU s per identify (mean of {n})")
    print(f"ratio one thread / default pool: {cpu['one thread'] / cpu['default pool']:.2f}")
    print(f"largest relative difference of an estimate: {worst:.2g}")


if __name__ == "__main__":
    main()
