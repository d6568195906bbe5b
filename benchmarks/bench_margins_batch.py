"""Benchmark: batched exact disk margins of N random SEA loops (issue 16).

Run from the repository root::

    python benchmarks/bench_margins_batch.py [--loops N]

Target (issue 16): ``disk_margins`` over N = 1000 SEA loops amortised <= 0.25 ms per loop,
exact (equal to the single-loop ``disk_margin`` to 1e-9); ``tune-q`` over 1000 environments < 5 s
as a whole command, verified exactly (batched; against the same command verifying one loop at a
time, same answer). Measured in the same run against
the single-loop routine and against the floor the issue names: a plain numpy frequency
response of all loops at once on 200 points (which is not exact: it misses sharp peaks).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

TARGET_MS = 0.25
TARGET_TUNE_S = 5.0
TUNE_ONE_BY_ONE = """
import sys
from forecast_design.tuning import plants as tuning_plants
from forecast_design.cli import main
tuning_plants._BATCH_MARGINS = False
raise SystemExit(main(sys.argv[1:]))
"""


def _loops(n: int):
    from forecast_design.environments import resolve_environments
    from forecast_design.loops import force_loop
    from forecast_design.params import Compensator

    rng = np.random.default_rng(1)
    kinds = ("ea-fob", "lo-dob", "ld-dob", None)
    out = []
    for i, (_, d) in enumerate(resolve_environments(f"random:{n}", seed=1).designs()):
        kind = kinds[i % 4]
        comp = None if kind is None else Compensator(kind=kind, w_q_hz=float(np.exp(rng.uniform(np.log(0.5), np.log(30)))))
        out.append(force_loop(d, comp).L)
    return out


def _best(fn, repeat=3):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        value = fn()
        times.append(time.perf_counter() - t0)
    return min(times), statistics.median(times), value


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loops", type=int, default=1000)
    parser.add_argument("--tune-envs", type=int, default=1000,
                        help="environments of the tune-q command timing (0: skip it)")
    args = parser.parse_args(argv)
    from forecast_design.margins import disk_margin
    from forecast_design.margins import disk_margins

    loops = _loops(args.loops)
    n = len(loops)
    _, t_batch, batch = _best(lambda: disk_margins(loops))
    _, t_single, single = _best(lambda: [disk_margin(L) for L in loops], repeat=1)
    width = max(len(L.den) for L in loops)
    num = np.array([np.pad(np.asarray(L.num, float), (width - len(L.num), 0)) for L in loops])
    den = np.array([np.pad(np.asarray(L.den, float), (width - len(L.den), 0)) for L in loops])
    s = 1j * np.logspace(-1, 4, 200)
    V = np.vander(s, width)

    def response():
        nv, dv = num @ V.T, den @ V.T
        return 1.0 / np.max(np.abs(dv / (dv + nv) - 0.5), axis=1)

    _, t_resp, grid_alpha = _best(response)
    alpha = np.array([m.alpha for m in single])
    rel = np.abs(batch.alpha - alpha) / np.where(alpha > 0, alpha, 1.0)
    grid_err = np.abs(grid_alpha - alpha)[batch.stable] / alpha[batch.stable]
    per = t_batch / n * 1e3
    print(f"{n} random SEA loops (random:{n}, seed 1; PD + EA-FOB/LO-DOB/LD-DOB/none, w_q 0.5-30 Hz)")
    print(f"  disk_margins (batch, exact)     {t_batch:8.3f} s  {per:7.3f} ms/loop  "
          f"(target <= {TARGET_MS} ms/loop: {'met' if per <= TARGET_MS else 'MISSED'})")
    print(f"  disk_margin one by one (exact)  {t_single:8.3f} s  {t_single / n * 1e3:7.3f} ms/loop  "
          f"-> batch {t_single / t_batch:.1f}x faster")
    print(f"  numpy response, 200 points      {t_resp:8.3f} s  {t_resp / n * 1e3:7.3f} ms/loop  "
          f"(not exact: alpha off by up to {grid_err.max():.1e} relative)")
    print(f"  batch vs single-loop alpha: max relative difference {rel.max():.1e}; "
          f"stability agrees on all: {bool(np.array_equal(batch.stable, [m.stable for m in single]))}")
    if args.tune_envs:
        tune_q_command(args.tune_envs)
    return 0


def tune_q_command(envs: int, repeat: int = 2) -> None:
    """``tune-q --env random:N`` as a whole process: batched verification vs one disk_margin per loop."""
    import json
    import subprocess
    import tempfile

    exe = str(Path(sys.executable).parent / "forecast-design")
    print(f"\ntune-q --env random:{envs} as a whole command (median of {repeat}, interleaved):")
    with tempfile.TemporaryDirectory() as tmp:
        for obs in ("ea-fob", "lo-dob", "ld-dob"):
            args = ["tune-q", "--compensator", obs, "--env", f"random:{envs}", "--json"]
            times = {"batch": [], "one-by-one": []}
            answers = {}
            for _ in range(repeat):
                for name, cmd in (("batch", [exe, *args]), ("one-by-one", [sys.executable, "-c", TUNE_ONE_BY_ONE,
                                                                             *args])):
                    out = Path(tmp) / f"{obs}-{name}.json"
                    t0 = time.perf_counter()
                    subprocess.run(cmd + [str(out)], check=True, stdout=subprocess.DEVNULL)
                    times[name].append(time.perf_counter() - t0)
                    answers[name] = json.loads(out.read_text())
            tb, ts = statistics.median(times["batch"]), statistics.median(times["one-by-one"])
            a, b = answers["batch"], answers["one-by-one"]
            same = abs(a["w_q_hz"] / b["w_q_hz"] - 1) <= 1e-9 and a["worst_environment"] == b["worst_environment"]
            print(f"  {obs:<7} batch {tb:6.2f} s  one-by-one {ts:6.2f} s  ({ts / tb:.1f}x)  w_q {a['w_q_hz']:.6g} Hz, "
                  f"worst ratio {a['worst_ratio']:.6f}, same answer: {same}  "
                  f"(target < {TARGET_TUNE_S:g} s: {'met' if tb < TARGET_TUNE_S else 'MISSED'})")


if __name__ == "__main__":
    raise SystemExit(main())
