"""Withheld-effect benchmark of the sim-to-real gap diagnosis (issue 6).

Usage: python benchmarks/bench_gap.py [--per-effect N] [--seed S] [--duration S] [--workers W] [--json OUT]
Prints the confusion matrix (rows: withheld effect, columns: verdict), the
accuracy of the one-at-a-time verdict and of the joint group-lasso
attribution, false alarms on effect-free logs and timing.
"""

from __future__ import annotations

import argparse
import json
import math

from forecast_design.gap.bench import benchmark


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    res = benchmark(per_effect=args.per_effect, seed=args.seed, workers=args.workers, duration_s=args.duration)
    print(res.format_confusion())
    secs = [c.seconds for c in res.cases]
    print(f"logs {len(res.cases)}  accuracy {100 * res.accuracy:.1f} %  joint accuracy "
          f"{100 * res.joint_accuracy:.1f} %  false alarms {res.false_alarms}  "
          f"min true-effect reduction {res.min_true_reduction:.3f}")
    print(f"wall {res.elapsed_s:.1f} s  diagnosis mean {sum(secs) / len(secs):.2f} s  max {max(secs):.2f} s")
    for c in res.cases:
        if not c.correct or (not math.isnan(c.true_reduction) and c.true_reduction < 0.5):
            print(f"  miss: truth {c.truth} verdict {c.verdict} ({c.environment}, {c.excitation}) {c.effect_params}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res.to_mapping(), fh, indent=2)


if __name__ == "__main__":
    main()
