"""Benchmark: ``forecast-design diagnose`` on a 20 s log as a whole process (issue 16).

Run from the repository root::

    python benchmarks/bench_diagnose.py [--repeat N]

Target (issue 16): ``diagnose`` on a 20 s, 2 kHz log <= 1.0 s including start-up. Measured
interleaved in this run: the command as shipped (one BLAS thread inside ``diagnose``), the same
command with the BLAS's own thread count (as before issue 16's third round), and
``python -c 'import numpy'``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 1.0
THREADED = """
import contextlib, sys
import forecast_design.gap.diagnose as d
d.threadpool_limits = lambda *a, **k: contextlib.nullcontext()
from forecast_design.cli import main
raise SystemExit(main(sys.argv[1:]))
"""


def _timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    exe = str(Path(sys.executable).parent / "forecast-design")
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        scenario = tmp / "s.toml"
        text = (ROOT / "forecast_design" / "data" / "example_scenario.toml").read_text()
        scenario.write_text("\n".join("duration_s = 20.0" if line.startswith("duration_s") else line
                                      for line in text.splitlines()) + "\n")
        subprocess.run([exe, "simulate", str(scenario), "--out", str(tmp / "run.toml")], check=True,
                       stdout=subprocess.DEVNULL)
        log = str(tmp / "run.toml")
        cmds = {"diagnose": [exe, "diagnose", log, "--json", str(tmp / "a.json")],
                "diagnose, threaded BLAS": [sys.executable, "-c", THREADED, "diagnose", log, "--json",
                                            str(tmp / "b.json")],
                "python -c 'import numpy'": [sys.executable, "-c", "import numpy"]}
        times = {k: [] for k in cmds}
        for _ in range(args.repeat):
            for k, cmd in cmds.items():
                times[k].append(_timed(cmd))
    print(f"20 s, 2 kHz log (fig7, LuGre, PD + EA-FOB), whole processes, median of {args.repeat}:")
    for k, ts in times.items():
        print(f"  {k:<26} {statistics.median(ts):7.3f} s  (min {min(ts):.3f})")
    t = statistics.median(times["diagnose"])
    print(f"  target <= {TARGET_S:g} s: {'met' if t <= TARGET_S else 'MISSED by %.2fx' % (t / TARGET_S)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
