"""Benchmark: ``identify`` on a 1e6-sample experiment against a plain pandas + numpy script (issue 16).

Run from the repository root::

    python benchmarks/bench_identify.py [--rows N] [--repeat N] [--json OUT.json]

Target (issue 16): ``forecast-design identify LOG.toml --model extended-sfm`` on 1e6 samples
<= 1.5x the wall time of a plain script (``pandas.read_csv``, ``numpy.gradient`` twice, the
extended-SFM regressor and ``numpy.linalg.lstsq``) and peak memory <= 1.2x its peak, both as
whole processes measured interleaved in this run. Also the in-process data preparation
(``prepare_identification_data``) and its peak memory above the log's own arrays.
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

TARGET_TIME = 1.5
TARGET_MEMORY = 1.2
COUNT = 2 * np.pi / 2_000_000  # encoder count [rad]

# The floor: what a user would write by hand for the same fit (same columns, same regressor:
# J_m theta'' subtracted, viscous, Coulomb, 4 angle harmonics).
PLAIN = """
import sys
import numpy as np, pandas as pd
f = pd.read_csv(sys.argv[1], dtype=np.float64, usecols=["t", "theta", "tau_m", "tau_s"])
t, th = f["t"].to_numpy(), f["theta"].to_numpy()
dt = t[1] - t[0]
v = np.gradient(th, dt)
a = np.gradient(v, dt)
y = f["tau_m"].to_numpy() - f["tau_s"].to_numpy() - 0.133 * a
cols = [v, np.sign(v)]
for k in range(1, 5):
    cols += [np.sin(k * th), np.cos(k * th)]
Phi = np.column_stack(cols)
p, *_ = np.linalg.lstsq(Phi, y, rcond=None)
print(p)
"""


def _write_log(folder: Path, rows: int) -> Path:
    from forecast_design import Design, experiment_from_arrays, save_experiment

    rate = 2000.0
    t = np.arange(rows) / rate
    th = 4.0 * np.sin(2 * np.pi * 0.1 * t) + 1.0 * np.sin(2 * np.pi * 0.37 * t + 1.0)
    v = 4.0 * 2 * np.pi * 0.1 * np.cos(2 * np.pi * 0.1 * t) + 2 * np.pi * 0.37 * np.cos(2 * np.pi * 0.37 * t + 1.0)
    acc = -4.0 * (2 * np.pi * 0.1) ** 2 * np.sin(2 * np.pi * 0.1 * t) \
        - (2 * np.pi * 0.37) ** 2 * np.sin(2 * np.pi * 0.37 * t + 1.0)
    design = Design.nominal("soft")
    J_m = design.testbed.J_m
    friction = 0.3 * v + 0.4 * np.sign(v) + 0.05 * np.sin(th) - 0.03 * np.cos(2 * th)
    rng = np.random.default_rng(0)
    tau_s = 0.2 * np.sin(2 * np.pi * 0.05 * t)
    tau_m = J_m * acc + friction + tau_s + 0.005 * rng.standard_normal(rows)
    exp = experiment_from_arrays(design, rate, t, tau_m, np.round(th / COUNT) * COUNT, np.zeros(rows),
                                 tau_s=tau_s)
    return save_experiment(exp, folder / f"log{rows}.toml")


_PEAK = ("\nimport sys as _s\n_s.stderr.write('VmHWM ' + [l for l in open('/proc/self/status') "
         "if l.startswith('VmHWM')][0].split()[1] + '\\n')\n")


def _run(code: str, args: list[str]) -> tuple[float, float]:
    """Wall time [s] and peak resident memory [MiB] (VmHWM, Linux) of one whole process running `code`.

    (``ru_maxrss`` of a child would carry this process's peak across fork + exec.)
    """
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code + _PEAK, *args], cwd=ROOT, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"exit {proc.returncode}: {proc.stderr[-500:]}")
    line = [ln for ln in proc.stderr.splitlines() if ln.startswith("VmHWM ")][-1]
    return wall, int(line.split()[1]) / 1024.0


def whole_process(log: Path, repeat: int) -> dict:
    command = ("import sys\nfrom forecast_design.cli import main\n"
               "status = main(['identify', sys.argv[1], '--model', 'extended-sfm'])\n")
    rows = {"identify": [], "plain": []}
    for _ in range(repeat):
        rows["identify"].append(_run(command, [str(log)]))
        rows["plain"].append(_run(PLAIN, [str(log.with_suffix(".csv"))]))
    out = {}
    for name, runs in rows.items():
        out[name] = {"wall_s": statistics.median(r[0] for r in runs),
                     "peak_mib": statistics.median(r[1] for r in runs)}
    out["time_ratio"] = out["identify"]["wall_s"] / out["plain"]["wall_s"]
    out["memory_ratio"] = out["identify"]["peak_mib"] / out["plain"]["peak_mib"]
    return out


def preparation(log: Path) -> dict:
    """In-process: time and traced peak of the data preparation alone."""
    import tracemalloc

    from forecast_design import load_experiment
    from forecast_design.friction import friction_log, friction_model
    from forecast_design.friction.identify import prepare_identification_data

    data = friction_log(load_experiment(log))
    model = friction_model("extended-sfm")
    prepare_identification_data(data.t[:20000], data.position[:20000], data.force[:20000], model,
                                inertia=data.inertia)
    tracemalloc.start()
    t0 = time.perf_counter()
    prepare_identification_data(data.t, data.position, data.force, model, inertia=data.inertia)
    wall = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"samples": int(data.t.size), "wall_s": wall, "traced_peak_mib": peak / 2**20,
            "traced_peak_bytes_per_sample": peak / data.t.size}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", type=Path, help="write the results to this JSON file")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as name:
        log = _write_log(Path(name), args.rows)
        prep = preparation(log)
        whole = whole_process(log, args.repeat)
    print(f"identify --model extended-sfm on {args.rows} samples, whole processes, median of {args.repeat}:")
    for name in ("identify", "plain"):
        r = whole[name]
        print(f"  {name:<9} {r['wall_s']:7.3f} s  peak {r['peak_mib']:7.1f} MiB")
    print(f"  time ratio {whole['time_ratio']:.2f}x (target <= {TARGET_TIME:g}x: "
          f"{'met' if whole['time_ratio'] <= TARGET_TIME else 'MISSED'}); memory ratio "
          f"{whole['memory_ratio']:.2f}x (target <= {TARGET_MEMORY:g}x: "
          f"{'met' if whole['memory_ratio'] <= TARGET_MEMORY else 'MISSED'})")
    print(f"data preparation in-process: {prep['wall_s']:.3f} s, traced peak {prep['traced_peak_mib']:.0f} MiB "
          f"({prep['traced_peak_bytes_per_sample']:.0f} B/sample)")
    if args.json:
        args.json.write_text(json.dumps({"whole_process": whole, "preparation": prep}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
