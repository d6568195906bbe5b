"""Benchmark: start-up of the command line and reading logs, each against its floor (issue 16).

Run from the repository root::

    python benchmarks/bench_io.py [--rows N] [--repeat N] [--json OUT.json]

Targets (issue 16): ``forecast-design --help`` <= 2x ``python -c 'import numpy'`` and
``reproduce fig6 --json FILE`` <= 3x it, as whole processes; an experiment and a ``--csv``
log of 1e6 rows read <= 1.5x ``pandas.read_csv``, memory per sample stated and linear.
Every ratio is measured in this run, the two sides interleaved.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

TARGET_HELP = 2.0
TARGET_FIG6 = 3.0
TARGET_READ = 1.5
BIN = Path(sys.executable).parent


def _process_time(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _interleaved(a, b, repeat: int) -> tuple[float, float]:
    ta, tb = [], []
    for _ in range(repeat):
        ta.append(a())
        tb.append(b())
    return statistics.median(ta), statistics.median(tb)


def startup(repeat: int, tmp: Path) -> dict:
    fd = str(BIN / "forecast-design")
    floor = [sys.executable, "-c", "import numpy"]
    out = {}
    for name, cmd, target in [("--help", [fd, "--help"], TARGET_HELP),
                              ("reproduce fig6 --json", [fd, "reproduce", "fig6", "--json", str(tmp / "f.json")],
                               TARGET_FIG6)]:
        t_cmd, t_floor = _interleaved(lambda: _process_time(cmd), lambda: _process_time(floor), repeat)
        out[name] = {"s": t_cmd, "numpy_s": t_floor, "ratio": t_cmd / t_floor, "target": target}
    proc = subprocess.run([sys.executable, "-X", "importtime", "-c",
                           "from forecast_design.cli import build_parser; build_parser()"],
                          cwd=ROOT, capture_output=True, text=True, check=True)
    rows = []
    for line in proc.stderr.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            rows.append((int(parts[1]), parts[2].rstrip()))
    out["importtime_top"] = [f"{us / 1000:8.1f} ms {name}" for us, name in sorted(rows, reverse=True)[:8]]
    return out


def _write_log(folder: Path, rows: int) -> Path:
    from forecast_design import Design, experiment_from_arrays, save_experiment

    rng = np.random.default_rng(0)
    t = np.arange(rows) / 2000.0
    exp = experiment_from_arrays(Design.nominal("soft"), 2000.0, t, rng.normal(size=rows),
                                 rng.normal(size=rows), rng.normal(size=rows), tau_s=rng.normal(size=rows),
                                 tau_r=rng.normal(size=rows))
    return save_experiment(exp, folder / f"log{rows}.toml")


def _peak_rss_mib(code: str) -> float:
    # VmHWM (Linux): the peak resident set of this process alone; ru_maxrss would carry
    # the parent's peak across fork + exec.
    probe = ("import sys; sys.path.insert(0, %r); " % str(ROOT)) + code + \
            "; print([l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1])"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    return int(out.split()[-1]) / 1024.0


def reading(rows: int, repeat: int, tmp: Path) -> dict:
    import pandas as pd

    from forecast_design import load_experiment
    from forecast_design.friction import load_axis_csv

    toml = _write_log(tmp, rows)
    csv = toml.with_suffix(".csv")
    exp = load_experiment(toml)
    frame = pd.read_csv(csv, dtype=np.float64)
    exact = all(np.array_equal(frame[k].to_numpy(), v) for k, v in exp.signals.columns().items())
    t_load, t_pd = _interleaved(lambda: _timed(lambda: load_experiment(toml)),
                                lambda: _timed(lambda: pd.read_csv(csv, dtype=np.float64)), repeat)
    t_axis, t_pd2 = _interleaved(
        lambda: _timed(lambda: load_axis_csv(csv, time="t", position="theta", force="tau_m")),
        lambda: _timed(lambda: pd.read_csv(csv, usecols=["t", "theta", "tau_m"], dtype=np.float64)), repeat)
    memory = {}
    for n in (rows // 2, rows):
        path = _write_log(tmp, n) if n != rows else toml
        base = _peak_rss_mib("import numpy, pyarrow.csv, forecast_design.experiment")
        peak = _peak_rss_mib(f"from forecast_design import load_experiment; load_experiment(r'{path}')")
        base_pd = _peak_rss_mib("import numpy, pandas")
        peak_pd = _peak_rss_mib(f"import numpy, pandas; pandas.read_csv(r'{path.with_suffix('.csv')}', "
                                "dtype=numpy.float64)")
        memory[n] = {"load_bytes_per_sample": (peak - base) * 2**20 / n,
                     "pandas_bytes_per_sample": (peak_pd - base_pd) * 2**20 / n}
    return {"rows": rows, "csv_mib": csv.stat().st_size / 2**20, "bitwise_equal_to_pandas": exact,
            "load_experiment_s": t_load, "pandas_s": t_pd, "ratio": t_load / t_pd,
            "axis_csv_s": t_axis, "pandas_usecols_s": t_pd2, "axis_ratio": t_axis / t_pd2,
            "memory": memory, "target": TARGET_READ}


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--json", type=Path, help="write the results to this JSON file")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        st = startup(args.repeat, tmp)
        rd = reading(args.rows, max(3, args.repeat // 2), tmp)
    print(f"{'start-up (whole process)':<28}{'command [s]':>12}{'numpy [s]':>11}{'ratio':>8}{'target':>8}")
    for name in ("--help", "reproduce fig6 --json"):
        r = st[name]
        print(f"{name:<28}{r['s']:>12.3f}{r['numpy_s']:>11.3f}{r['ratio']:>8.2f}{'<= %g' % r['target']:>8}"
              f"  {'met' if r['ratio'] <= r['target'] else 'MISSED'}")
    print("top -X importtime entries of build_parser():")
    for line in st["importtime_top"]:
        print("   ", line)
    print(f"\nread {rd['rows']} rows ({rd['csv_mib']:.0f} MiB CSV), bit-equal to pandas: {rd['bitwise_equal_to_pandas']}")
    print(f"  load_experiment {rd['load_experiment_s']:.3f} s vs pandas.read_csv {rd['pandas_s']:.3f} s: "
          f"{rd['ratio']:.2f}x (target <= {TARGET_READ:g}x: {'met' if rd['ratio'] <= TARGET_READ else 'MISSED'})")
    print(f"  load_axis_csv   {rd['axis_csv_s']:.3f} s vs pandas (3 columns) {rd['pandas_usecols_s']:.3f} s: "
          f"{rd['axis_ratio']:.2f}x (target <= {TARGET_READ:g}x: "
          f"{'met' if rd['axis_ratio'] <= TARGET_READ else 'MISSED'})")
    for n, m in rd["memory"].items():
        print(f"  peak memory over imports, {n} rows: load_experiment {m['load_bytes_per_sample']:.0f} B/sample, "
              f"pandas {m['pandas_bytes_per_sample']:.0f} B/sample")
    if args.json:
        args.json.write_text(json.dumps({"startup": st, "reading": rd}, indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
