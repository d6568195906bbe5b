"""Run every benchmark script in this folder, one after another, and print their reports.

Usage::

    .venv/bin/python benchmarks/run_all.py [--skip NAME ...]

Each ``bench_*.py`` prints its own table (targets next to measurements); record
the numbers with the machine and date in ``benchmarks/RESULTS.md``. Benchmarks
time the machine they run on: run them on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip", action="append", default=[], help="benchmark name to skip, e.g. gap")
    args = parser.parse_args()
    print(f"machine: {platform.machine()}, {platform.processor() or platform.platform()}, "
          f"Python {platform.python_version()}; {time.strftime('%Y-%m-%d')}")
    status = 0
    for script in sorted(HERE.glob("bench_*.py")):
        name = script.stem.removeprefix("bench_")
        if name in args.skip:
            continue
        print(f"\n=== {script.name} ===", flush=True)
        start = time.perf_counter()
        proc = subprocess.run([sys.executable, str(script)], cwd=HERE.parent)
        print(f"({script.name}: {time.perf_counter() - start:.1f} s, exit {proc.returncode})", flush=True)
        status = status or proc.returncode
    return status


if __name__ == "__main__":
    raise SystemExit(main())
