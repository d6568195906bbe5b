"""Controllers written as code (issue 28): how much slower Python and C (in the loop) run than the kernel.

Two measurements, each in one run after a warm-up (numba caches loaded, the C file compiled):

``simulate``
    One ``simulate()`` of 1 s at 2 kHz (exp-soft, EA-FOB 10 Hz, a 0.2 N m step) with the paper's
    PD through the compiled kernel, with the example gain-scheduled PID written in Python, and
    with the same controller in C through ctypes; the three interleaved, ``--rounds`` times. Prints
    the median seconds per run, the cost of one more control period ((10 s run - 1 s run) / 18,000
    periods, fastest runs: the run's preparation left out), and the slowdown
    against the kernel (median of the per-round ratios).
``benchmark``
    The issue's workload through the command line: ``forecast-design benchmark`` over 7
    environments (a log grid of k_e) x the command's default compensators (none, sfm, ea-fob) x 10
    repetitions of 1 s (``--compensator`` to choose others), ``--no-plots``, a fresh result folder
    per command (no cell reused), the controllers (the paper's PD, the Python example, the C
    example) in turn, ``--times`` rounds, after a small warm-up benchmark that loads the numba
    caches. Prints each command's median wall time and range against the issue's target (under 2
    minutes for the code controllers: the slowest of the rounds), and its CPU time (the command
    and its worker processes, user + system), which a busy machine moves less than the wall time.

Usage::

    python benchmarks/bench_code_controllers.py [simulate|benchmark|all] [--workers N] [--rounds R]
        [--compensator LIST] [--times T]
    python benchmarks/bench_code_controllers.py simulate --baseline OLD_TREE

``--baseline OLD_TREE`` (a checkout of an earlier commit) runs the chosen measurements in
subprocesses, alternately with ``PYTHONPATH`` on this tree and on OLD_TREE, and prints this
tree's figure over the baseline's, pair by pair (median of the pairs), for a change's before/after.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SET = """[[environment]]
name = "k"
J_e = 0.01
k_e = {log = [0.1, 1000.0], n = 7}
"""
PYTHON_EXAMPLE = "forecast_design.controllers.examples.gain_scheduled_pid:GainScheduledPID"
LABELS = ("kernel pd:5:0.1", "Python example", "C example (ctypes)")


def _controllers() -> list[str]:
    from forecast_design.controllers.examples import example_path

    return ["pd:5:0.1", PYTHON_EXAMPLE, str(example_path("gain_scheduled_pid.c"))]


def measure_simulate(rounds: int) -> dict:
    """Median seconds of a 1 s run, marginal microseconds per period, ratios to the kernel."""
    from forecast_design.controllers import resolve_controller
    from forecast_design.params import Compensator, Design
    from forecast_design.simulation import simulate
    from forecast_design.simulation.references import Step

    base = Design.nominal("exp-soft")
    comp = Compensator(kind="ea-fob", w_q_hz=10.0)
    designs = [dataclasses.replace(base, controller=resolve_controller(s), compensator=comp)
               for s in _controllers()]
    ref = Step(amplitude=0.2)
    for d in designs:                                   # warm-up: numba caches, the C build
        simulate(d, reference=ref, duration_s=0.05)
    one = [[] for _ in designs]
    ten = [[] for _ in designs]
    for r in range(rounds):
        for i, d in enumerate(designs):
            t0 = time.perf_counter()
            simulate(d, reference=ref, duration_s=1.0, seed=r)
            one[i].append(time.perf_counter() - t0)
        if r < max(rounds // 2, 1):
            for i, d in enumerate(designs):
                t0 = time.perf_counter()
                simulate(d, reference=ref, duration_s=10.0, seed=r)
                ten[i].append(time.perf_counter() - t0)
    return {"run_1s_s": [statistics.median(t) for t in one],
            # the marginal cost of a period: the preparation (filters, program) is in both runs; the
            # fastest run of each length (the work is deterministic: slower runs waited for the machine)
            "period_us": [1e6 * (min(t10) - min(t1)) / 18_000 for t10, t1 in zip(ten, one)],
            "ratio": [statistics.median(a / b for a, b in zip(t, one[0])) for t in one]}


def _children_cpu() -> float:
    """User + system seconds of the finished child processes (the command and its workers)."""
    import resource

    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def measure_benchmark(workers: int, compensators: str, times: int = 1) -> dict:
    """Wall and CPU seconds of the benchmark command (fresh folder each), ``times`` rounds."""
    with tempfile.TemporaryDirectory(prefix="bench-code-") as folder:     # removed afterwards
        return _measure_benchmark(Path(folder), workers, compensators, times)


def _measure_benchmark(tmp: Path, workers: int, compensators: str, times: int) -> dict:
    (tmp / "set.toml").write_text(SET)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    cmd = [sys.executable, "-m", "forecast_design", "benchmark", "--no-plots", "--workers", str(workers)]
    specs = _controllers()
    # warm-up: the workers' numba caches, on a small set
    warm = subprocess.run([*cmd, *sum((["--controller", s] for s in specs), []), "--envs", "exp-soft",
                           "--repetitions", "2", "--duration", "0.1", "--out", str(tmp / "warm")],
                          capture_output=True, text=True, env=env)
    if warm.returncode != 0:
        raise SystemExit(f"warm-up failed: {warm.stderr.strip().splitlines()[-1:]}")
    walls: list[list[float]] = [[] for _ in specs]
    cpus: list[list[float]] = [[] for _ in specs]
    codes = [0 for _ in specs]
    for r in range(times):
        for i, spec in enumerate(specs):
            c0 = _children_cpu()
            t0 = time.perf_counter()
            proc = subprocess.run([*cmd, "--controller", spec, "--envs", str(tmp / "set.toml"),
                                   "--repetitions", "10", "--compensator", compensators,
                                   "--out", str(tmp / f"out{r}-{i}")],
                                  capture_output=True, text=True, env=env)
            walls[i].append(time.perf_counter() - t0)
            cpus[i].append(_children_cpu() - c0)
            codes[i] = codes[i] or proc.returncode
    return {"wall_s": [statistics.median(w) for w in walls], "range_s": [[min(w), max(w)] for w in walls],
            "cpu_s": [statistics.median(c) for c in cpus],
            "exit": codes, "workers": workers, "compensators": compensators, "times": times}


def _print_simulate(res: dict) -> None:
    print("| controller | 1 s run [s] (median) | slowdown vs kernel, 1 s runs | per period [us] (marginal) | "
          "slowdown vs kernel, per period |")
    print("|---|---|---|---|---|")
    for label, t, us, ratio in zip(LABELS, res["run_1s_s"], res["period_us"], res["ratio"]):
        print(f"| {label} | {t:.4f} | {ratio:.2f}x | {us:.1f} | {us / res['period_us'][0]:.1f}x |")


def _print_benchmark(res: dict) -> None:
    print(f"\nbenchmark command, 7 envs x compensators {res['compensators']} x 10 repetitions of 1 s, "
          f"--no-plots, fresh folder, --workers {res['workers']}, {res['times']} time(s) each, in turn:")
    print("| controller | wall [s] (median) | min - max [s] | CPU [s] (median) | exit | target < 120 s |")
    print("|---|---|---|---|---|---|")
    rows = zip(LABELS, res["wall_s"], res["range_s"], res["cpu_s"], res["exit"])
    for i, (label, wall, (lo, hi), cpu, code) in enumerate(rows):
        target = "(reference)" if i == 0 else ("met" if hi < 120 and code == 0 else "NOT met")
        print(f"| {label} | {wall:.1f} | {lo:.1f} - {hi:.1f} | {cpu:.1f} | {code} | {target} |")
    for what, key in (("wall", "wall_s"), ("CPU", "cpu_s")):
        print(f"{what} ratios to the kernel PD command: Python {res[key][1] / res[key][0]:.2f}x, "
              f"C {res[key][2] / res[key][0]:.2f}x")


def _vs_baseline(args: argparse.Namespace) -> None:
    """This tree against ``args.baseline``, alternately in subprocesses (A B A B ...)."""
    trees = {"this": str(HERE.parent), "baseline": str(Path(args.baseline).resolve())}
    argv = [sys.executable, str(Path(__file__).resolve()), args.what, "--json", "--workers",
            str(args.workers), "--rounds", str(args.rounds), "--compensator", args.compensator,
            "--times", str(args.times)]
    out: dict[str, list[dict]] = {"this": [], "baseline": []}
    for _ in range(args.pairs):
        for name, tree in trees.items():
            env = {**os.environ, "PYTHONPATH": tree}
            proc = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tree)
            if proc.returncode != 0:
                raise SystemExit(f"{name} tree failed: {proc.stderr.strip().splitlines()[-1:]}")
            out[name].append(json.loads(proc.stdout.strip().splitlines()[-1]))
    print(f"this tree / baseline, median of {args.pairs} pairs (A B A B ...; < 1 is faster):")
    keys = (("simulate", "run_1s_s", "1 s simulate() [s]"), ("simulate", "period_us", "per period [us]"),
            ("benchmark", "wall_s", "benchmark command wall [s]"),
            ("benchmark", "cpu_s", "benchmark command CPU [s]"))
    for part, key, what in keys:
        if part not in out["this"][0]:
            continue
        for i, label in enumerate(LABELS):
            a = [run[part][key][i] for run in out["this"]]
            b = [run[part][key][i] for run in out["baseline"]]
            ratio = statistics.median(x / y for x, y in zip(a, b))
            print(f"{what}, {label}: this {statistics.median(a):.4g}, baseline {statistics.median(b):.4g}, "
                  f"ratio {ratio:.3f}")


def main() -> None:
    """Run the measurements the first argument names (default all)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="?", default="all", choices=("simulate", "benchmark", "all"))
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="benchmark's --workers")
    parser.add_argument("--compensator", default="none,sfm,ea-fob",
                        help="benchmark's --compensator (default: the command's default)")
    parser.add_argument("--times", type=int, default=1, help="benchmark commands per controller")
    parser.add_argument("--rounds", type=int, default=20, help="interleaved simulate() rounds")
    parser.add_argument("--baseline", metavar="OLD_TREE", help="compare with another checkout")
    parser.add_argument("--pairs", type=int, default=3, help="with --baseline: A/B pairs")
    parser.add_argument("--json", action="store_true", help="print one JSON line (for --baseline)")
    args = parser.parse_args()
    if args.baseline:
        _vs_baseline(args)
        return
    res = {}
    load = os.getloadavg()[0]
    if args.what in ("simulate", "all"):
        res["simulate"] = measure_simulate(args.rounds)
    if args.what in ("benchmark", "all"):
        res["benchmark"] = measure_benchmark(args.workers, args.compensator, args.times)
    if args.json:
        print(json.dumps(res))
        return
    print(f"load average (1 min) before: {load:.2f}")
    if "simulate" in res:
        _print_simulate(res["simulate"])
    if "benchmark" in res:
        _print_benchmark(res["benchmark"])
    print(f"load average (1 min) after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
