"""The independent log generator's CPU time against another revision's, interleaved in one process.

Run from the repository root::

    python benchmarks/bench_independent.py [--against REV] [--duration S] [--repeat R]

The plant and signal modules of ``REV`` (default ``HEAD``, read with ``git show``) are loaded
next to this tree's; ``friction_log`` of every law (2 kHz, seed 0) runs with each in turn, and
the best CPU time of R runs is printed per law with the ratio, and whether the two logs are
bit-identical (the generator's output may not change with its speed).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from forecast_design.independent import FRICTION_LAWS  # noqa: E402
from forecast_design.independent import friction_logs, plant  # noqa: E402


def _module(name: str, source: str) -> types.ModuleType:
    mod = types.ModuleType(f"forecast_design.independent.{name}")
    mod.__package__ = "forecast_design.independent"
    sys.modules[mod.__name__] = mod
    exec(compile(source, f"<{name}>", "exec"), mod.__dict__)
    return mod


def _revision(rev: str) -> types.ModuleType:
    def show(path: str) -> str:
        return subprocess.run(["git", "show", f"{rev}:forecast_design/independent/{path}"], cwd=ROOT,
                              check=True, capture_output=True, text=True).stdout

    _module("signals_rev", show("signals.py"))
    return _module("plant_rev", show("plant.py").replace("from .signals import", "from .signals_rev import"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default="HEAD")
    ap.add_argument("--duration", type=float, default=3.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    variants = {args.against: _revision(args.against).simulate_independent, "this tree": plant.simulate_independent}
    best: dict[tuple[str, str], float] = {}
    same = {}
    for _ in range(args.repeat):
        for law in FRICTION_LAWS:
            logs = {}
            for label, simulate in variants.items():
                friction_logs.simulate_independent = simulate
                a = time.process_time()
                exp, _ = friction_logs.friction_log(law, seed=0, duration_s=args.duration)
                best[label, law] = min(best.get((label, law), np.inf), time.process_time() - a)
                logs[label] = exp.signals
            friction_logs.simulate_independent = plant.simulate_independent
            a, b = logs.values()
            same[law] = all(np.array_equal(getattr(a, c), getattr(b, c)) for c in ("t", "tau_m", "theta", "q"))
    ref, new = variants
    for law in FRICTION_LAWS:
        print(f"{law:18s} {ref} {best[ref, law]:.3f} s, this tree {best[new, law]:.3f} s, "
              f"ratio {best[new, law] / best[ref, law]:.2f}, logs bit-identical: {same[law]}")
    total = sum(best[new, law] for law in FRICTION_LAWS) / sum(best[ref, law] for law in FRICTION_LAWS)
    print(f"all laws: ratio {total:.2f} ({args.duration:g} s logs at 2 kHz, best of {args.repeat})")


if __name__ == "__main__":
    main()
