"""Batched Monte-Carlo simulation against the single-run loop, and the ``simulate`` command (issue 16).

Run: ``python benchmarks/bench_simulation_batch.py [--runs 16] [--duration 10] [--repeats 3]``.

1. ``simulate_batch`` over ``--runs`` runs (fig7 environment, PD + EA-FOB, LuGre whose static
   level and Stribeck velocity vary with the angle, a different seed, initial angle and
   breakaway level per run; 2 kHz, 10 RK4 substeps) against a Python loop of ``simulate`` over
   the same runs, interleaved ``--repeats`` times: simulated seconds per wall second and per
   CPU second of each side and their ratio. Target >= 1000 simulated s per wall s on 2 cores.
2. ``forecast-design simulate SCENARIO.toml --out RUN.toml`` for a 20 s run as a whole process
   (start-up, simulation, writing the experiment and truth files) against
   ``python -c 'import numpy'``: real-time factor. Target >= 100x real time.

0. The plant kernel alone: CPU ns per RK4 substep of ``integrate_open_loop`` (fig7; no effect,
   LuGre, LuGre with angle harmonics) against a hand-written numba RK4 of the same linear plant
   (scalars only: the floor of the arithmetic).

The machine's load average is printed: other processes on the cores lower the wall rates, not
the CPU rates.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from forecast_design.discrete import njit
from forecast_design.effects import Stiction
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design
from forecast_design.simulation import Square, simulate
from forecast_design.simulation.batch import BatchRun, simulate_batch
from forecast_design.simulation.plant import build_plant, integrate_open_loop

REF = Square(high=1.0, low=-1.0, period_s=2.0)
SCENARIO = """format = "forecast-scenario/1"
environment = "fig7"
[sampling]
rate_hz = 2000.0
[testbed]
J_m = 0.133
d_m = 0.3
k = 58.0
[controller]
kind = "pd"
P = 5.0
D = 0.1
[compensator]
kind = "ea-fob"
w_q_hz = 10.0
[[truth.effects]]
effect = "stiction"
[reference]
kind = "square"
high = 1.0
low = -1.0
period_s = 2.0
[simulation]
duration_s = 20.0
substeps = 10
"""



@njit
def _hand_rk4(x, tau_cmd, nsub, h, jm, dm, k, j, d, ke):
    """RK4 of the linear two-mass plant (no friction effect), scalars only."""
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    for n in range(tau_cmd.shape[0]):
        tau = tau_cmd[n]
        for _ in range(nsub):
            a0, a2 = x1, x3
            a1 = (tau - k * (x0 - x2) - dm * x1) / jm
            a3 = (k * (x0 - x2) - d * x3 - ke * x2) / j
            y0, y1, y2, y3 = x0 + 0.5 * h * a0, x1 + 0.5 * h * a1, x2 + 0.5 * h * a2, x3 + 0.5 * h * a3
            b0, b2 = y1, y3
            b1 = (tau - k * (y0 - y2) - dm * y1) / jm
            b3 = (k * (y0 - y2) - d * y3 - ke * y2) / j
            y0, y1, y2, y3 = x0 + 0.5 * h * b0, x1 + 0.5 * h * b1, x2 + 0.5 * h * b2, x3 + 0.5 * h * b3
            c0, c2 = y1, y3
            c1 = (tau - k * (y0 - y2) - dm * y1) / jm
            c3 = (k * (y0 - y2) - d * y3 - ke * y2) / j
            y0, y1, y2, y3 = x0 + h * c0, x1 + h * c1, x2 + h * c2, x3 + h * c3
            d1 = (tau - k * (y0 - y2) - dm * y1) / jm
            d3 = (k * (y0 - y2) - d * y3 - ke * y2) / j
            x0 += h / 6.0 * (a0 + 2.0 * b0 + 2.0 * c0 + y1)
            x1 += h / 6.0 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
            x2 += h / 6.0 * (a2 + 2.0 * b2 + 2.0 * c2 + y3)
            x3 += h / 6.0 * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
    x[0], x[1], x[2], x[3] = x0, x1, x2, x3


def _substep_costs(periods: int = 40000, repeats: int = 5) -> None:
    """Print CPU ns per RK4 substep of the plant kernel and of the hand-written linear RK4."""
    design = Design.nominal("fig7")
    cmd = 1.5 * np.sin(np.arange(periods) / 2000.0 * 2 * np.pi * 0.5)
    harm = Stiction(F_s_a=(0.05,), F_s_b=(0.02,), v_s_a=(0.2,), v_s_b=(0.1,))
    parts = []
    for name, effects in (("no effect", ()), ("LuGre", (Stiction(),)), ("LuGre + angle harmonics", (harm,))):
        plant = build_plant(design, effects, substeps=10)
        integrate_open_loop(plant, cmd[:10], substeps=10)
        best = min(_timed(lambda: integrate_open_loop(plant, cmd, substeps=10))[1] for _ in range(repeats))
        parts.append(f"{name} {best / (10 * periods) * 1e9:.0f} ns")
    tb, env = design.testbed, design.environment
    args = (cmd, 10, 1.0 / 20000.0, tb.J_m, tb.d_m, tb.k, env.J, env.d, env.k_e)
    _hand_rk4(np.zeros(4), cmd[:10], *args[1:])
    best = min(_timed(lambda: _hand_rk4(np.zeros(4), *args))[1] for _ in range(repeats))
    parts.append(f"hand-written linear RK4 {best / (10 * periods) * 1e9:.0f} ns")
    print("CPU per RK4 substep (integrate_open_loop, fig7, 2 kHz x 10): " + "; ".join(parts))

def _runs(count: int) -> list[BatchRun]:
    design = Design.nominal("fig7", controller=PD(), compensator=Compensator(kind="ea-fob", w_q_hz=10.0))
    rng = np.random.default_rng(0)
    return [BatchRun(design=design, effects=(Stiction(F_s=float(rng.uniform(0.45, 0.6)), F_s_a=(0.05,), F_s_b=(0.02,),
                                                      v_s_a=(0.2,), v_s_b=(0.1,)),),
                     seed=i, initial_angle=float(rng.uniform(0.0, 6.28))) for i in range(count)]


def _single(runs: list[BatchRun], duration: float) -> None:
    for r in runs:
        simulate(r.design, reference=REF, duration_s=duration, effects=r.effects, seed=r.seed,
                 initial_angle=r.initial_angle)


def _timed(func) -> tuple[float, float]:
    c0, w0 = time.process_time(), time.perf_counter()
    func()
    return time.perf_counter() - w0, time.process_time() - c0


def _process(cmd: list[str]) -> float:
    w0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - w0


def main() -> None:
    """Print the batch and command measurements."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=16, help="runs per batch")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run [s]")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repetitions")
    args = parser.parse_args()
    _substep_costs()
    runs = _runs(args.runs)
    simulate_batch(runs[:2], duration_s=0.01, reference=REF)   # compilation / cache load
    _single(runs[:1], 0.01)
    total = args.runs * args.duration
    print(f"load average before: {os.getloadavg()[0]:.2f}; {args.runs} runs x {args.duration:g} s, "
          f"LuGre with angle harmonics, 2 kHz x 10 substeps")
    print(f"{'repeat':>6s} {'batch sim-s/wall-s':>19s} {'(cpu)':>8s} {'loop sim-s/wall-s':>18s} {'(cpu)':>8s} "
          f"{'batch/loop':>10s}")
    ratios, rates = [], []
    for k in range(args.repeats):
        wb, cb = _timed(lambda: simulate_batch(runs, duration_s=args.duration, reference=REF))
        ws, cs = _timed(lambda: _single(runs, args.duration))
        ratios.append(ws / wb)
        rates.append(total / wb)
        print(f"{k:6d} {total / wb:19.0f} {total / cb:8.0f} {total / ws:18.0f} {total / cs:8.0f} {ws / wb:10.2f}")
    print(f"batch: best {max(rates):.0f} simulated s per wall s (target >= 1000); median speed-up over the loop "
          f"{np.median(ratios):.2f}x; load average after: {os.getloadavg()[0]:.2f}")

    exe = Path(sys.executable).with_name("forecast-design")
    with tempfile.TemporaryDirectory() as tmp:
        scenario = Path(tmp) / "scenario.toml"
        scenario.write_text(SCENARIO)
        _process([str(exe), "simulate", str(scenario), "--out", str(Path(tmp) / "warm.toml")])
        rows = []
        for k in range(args.repeats):
            out = Path(tmp) / f"run{k}.toml"
            wc = _process([str(exe), "simulate", str(scenario), "--out", str(out)])
            wn = _process([sys.executable, "-c", "import numpy"])
            rows.append((wc, wn))
            print(f"simulate 20 s as a command: {wc:.3f} s = {20.0 / wc:.0f}x real time "
                  f"(python -c 'import numpy' {wn:.3f} s; command / numpy {wc / wn:.1f}x)")
        best = min(r[0] for r in rows)
        print(f"simulate command: best {20.0 / best:.0f}x real time (target >= 100x)")


if __name__ == "__main__":
    main()
