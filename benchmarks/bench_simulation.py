"""Real-time factor of the virtual testbed (LuGre at 2 kHz, 10 RK4 substeps per period).

Run: ``python benchmarks/bench_simulation.py [--duration 20] [--substeps 10]``.
Prints simulated seconds per CPU second and per wall second for a few set-ups.
``NUMBA_DISABLE_JIT=1`` runs the same loop as plain Python (use a short
``--duration``, e.g. 0.5) to see what compilation buys.
"""

from __future__ import annotations

import argparse
import time

from forecast_design.effects import Cogging, PositionFriction, Stiction
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design
from forecast_design.simulation import Square, simulate

CASES = [
    ("fig7 LuGre, PD", "fig7", "none", [Stiction()]),
    ("fig7 LuGre, PD + EA-FOB", "fig7", "ea-fob", [Stiction()]),
    ("fig7 LuGre, PD + SFM", "fig7", "sfm", [Stiction()]),
    ("exp-soft LuGre + position friction + cogging, EA-FOB", "exp-soft", "ea-fob",
     [Stiction(F_s_a=(0.05, 0.02), F_s_b=(0.0, 0.01)), PositionFriction(F_c=0.1, a=(0.03,), b=(0.02,)),
      Cogging(a=(0.02, 0.01, 0.005, 0.002), b=(0.0, 0.0, 0.0, 0.0))]),
    ("locked LuGre, PD + EA-FOB", "locked", "ea-fob", [Stiction()]),
]


def main() -> None:
    """Time each case once after a warm-up (compilation) run and print the real-time factors."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds per case [s]")
    parser.add_argument("--substeps", type=int, default=10, help="RK4 steps per 0.5 ms period")
    args = parser.parse_args()
    print(f"{'case':58s} {'RT (cpu)':>10s} {'RT (wall)':>10s}")
    for label, env, kind, effects in CASES:
        design = Design.nominal(env, controller=PD(), compensator=Compensator(kind=kind, w_q_hz=10.0))
        kw = dict(reference=Square(high=1.0, low=-1.0, period_s=2.0), effects=effects, substeps=args.substeps,
                  sfm_params={"viscous": 0.4, "coulomb": 0.4} if kind == "sfm" else None)
        simulate(design, duration_s=0.01, **kw)  # warm-up: numba compilation / cache load
        c0, w0 = time.process_time(), time.perf_counter()
        simulate(design, duration_s=args.duration, **kw)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        print(f"{label:58s} {args.duration / cpu:10.1f} {args.duration / wall:10.1f}")


if __name__ == "__main__":
    main()
