"""Benchmark verb and executor (issue 17): throughput with 1 and 2 local workers, Dask overhead per task.

Prints a table: the 7-environment x 3-compensator x 10-repetition benchmark (1 s steps)
on 1 and 2 local worker processes and on a 2-worker Dask cluster on the loopback, the
command's wall time (target < 60 s), and the scheduler overhead per task (a trivial task
mapped 500 times through the Dask executor, minus the same through the serial executor).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from forecast_design.benchmark import BenchmarkSpec, parse_compensators, parse_controller, parse_reference, \
    run_benchmark
from forecast_design.environments import resolve_environments
from forecast_design.executor import LocalExecutor, make_executor

SET = """[[environment]]
name = "k"
J_e = 0.01
k_e = {log = [0.1, 1000.0], n = 7}
"""


def _spec(envs):
    return BenchmarkSpec(controllers=(parse_controller("pd:5:0.1"),), compensators=parse_compensators("none,sfm,ea-fob"),
                         environments=tuple(envs.items()), references=(parse_reference("step:0.2:1.0"),),
                         repetitions=10)


def main() -> None:
    tmp = Path(tempfile.mkdtemp())
    (tmp / "set.toml").write_text(SET)
    envs = resolve_environments(tmp / "set.toml")
    spec = _spec(envs)
    run_benchmark(spec, executor=LocalExecutor(1))            # warm the numba cache
    rows = []
    for workers in (1, 2):
        with LocalExecutor(workers) as ex:
            t0 = time.perf_counter()
            cells, _ = run_benchmark(spec, executor=ex)
            dt = time.perf_counter() - t0
        rows.append((f"local, {workers} worker(s)", len(cells), dt))
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        with make_executor(cluster.scheduler_address) as ex:
            ex.map(abs, [1, 2])                                # workers import forecast_design
            run_benchmark(spec, executor=ex)                   # and load the numba cache
            t0 = time.perf_counter()
            cells, _ = run_benchmark(spec, executor=ex)
            rows.append(("dask, 2 workers (loopback)", len(cells), time.perf_counter() - t0))
            n = 500
            t0 = time.perf_counter()
            ex.map(abs, list(range(n)))
            dask_task = (time.perf_counter() - t0) / n
    print("| executor | cells | runs | wall [s] | runs/s |")
    print("|---|---|---|---|---|")
    for name, n_cells, dt in rows:
        print(f"| {name} | {n_cells} | {n_cells * 10} | {dt:.2f} | {n_cells * 10 / dt:.1f} |")
    print(f"\nDask scheduler overhead per task (trivial task, 500 tasks, 2 workers): {1e3 * dask_task:.2f} ms")
    out = tmp / "cmd"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "forecast_design", "benchmark", "--envs", str(tmp / "set.toml"),
                           "--repetitions", "10", "--out", str(out)], capture_output=True, text=True,
                          env={**os.environ, "MPLBACKEND": "Agg"})
    dt = time.perf_counter() - t0
    print(f"command `benchmark` 7 envs x 3 compensators x 10 repetitions, fresh folder: {dt:.1f} s "
          f"(target < 60 s: {'met' if dt < 60 and proc.returncode == 0 else 'NOT met'}), exit {proc.returncode}")


if __name__ == "__main__":
    main()
