"""Withheld-effect benchmark of the sim-to-real gap diagnosis (issue 6).

Usage: python benchmarks/bench_gap.py [--per-effect N] [--seed S] [--duration S] [--workers W]
                                     [--hard N] [--pairs N] [--json OUT]
Prints the confusion matrix (rows: withheld effect, columns: verdict), the
accuracy of the one-at-a-time verdict and of the joint group-lasso
attribution, false alarms on effect-free logs and timing; then the hard
(non-identifiable) suite, scored for honesty, and the two-effect suite
(forward selection against group lasso). The scoring rules are in the
docstring of forecast_design/gap/bench.py. Defaults reproduce the numbers in
benchmarks/RESULTS.md (N = 5 per effect, seed 1, 10 s logs).
"""

from __future__ import annotations

import argparse
import json
import math
import os

from forecast_design.gap.bench import benchmark


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--hard", type=int, default=2, help="logs per non-identifiable scenario")
    ap.add_argument("--pairs", type=int, default=2, help="logs per two-effect combination")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    load0 = os.getloadavg()
    res = benchmark(per_effect=args.per_effect, seed=args.seed, workers=args.workers, duration_s=args.duration,
                    hard=args.hard, pairs=args.pairs)
    load1 = os.getloadavg()
    print(res.format_confusion())
    secs = [c.seconds for c in res.cases]
    joint = "not run" if res.joint_accuracy is None else f"{100 * res.joint_accuracy:.1f} %"
    print(f"logs {len(res.cases)}  accuracy {100 * res.accuracy:.1f} %  joint accuracy "
          f"{joint}  false alarms {res.false_alarms}  "
          f"min true-effect reduction {res.min_true_reduction:.3f}")
    ok = res.accuracy >= 0.98 and res.false_alarms == 0 and res.min_true_reduction >= 0.5
    print(f"target: accuracy >= 98 %, no false alarm, true-effect reduction >= 0.5 -> {'met' if ok else 'NOT met'}")
    print(f"wall {res.elapsed_s:.1f} s on {res.workers} workers  diagnosis mean {sum(secs) / len(secs):.2f} s  "
          f"max {max(secs):.2f} s  load average {load0[0]:.2f} before, {load1[0]:.2f} after "
          f"({os.cpu_count()} cores)")
    for c in res.main:
        if not c.correct or (not math.isnan(c.true_reduction) and c.true_reduction < 0.5):
            print(f"  miss: truth {c.truth} verdict {c.verdict} reduction {c.true_reduction:.3f} "
                  f"({c.environment}, {c.excitation}) {c.effect_params}")
    hard = res.suite("hard")
    if hard:
        print(f"hard (non-identifiable) logs {len(hard)}: honest {100 * res.hard_honesty:.1f} %")
        for c in hard:
            print(f"  {'ok  ' if c.correct else 'FAIL'} truth {c.truth} verdict {c.verdict} ({c.environment}, "
                  f"{c.excitation}) caveats: {' | '.join(x[:70] for x in c.caveats) or '-'}")
    pairs = res.suite("pairs")
    if pairs:
        sc = res.pairs_scores()
        print(f"pairs logs {sc['n_logs']}: forward selection exact {100 * sc['forward_exact']:.1f} % "
              f"(verdict in truth {100 * sc['forward_verdict_in_truth']:.1f} %), group lasso exact "
              f"{100 * sc['joint_exact']:.1f} % (first in truth {100 * sc['joint_first_in_truth']:.1f} %)")
        for c in pairs:
            print(f"  truth {'+'.join(map(str, c.truths))}: forward {'+'.join(sorted(map(str, c.named))) or 'none'}"
                  f", lasso {'+'.join(map(str, c.joint)) or 'none'} ({c.environment}, {c.excitation})")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res.to_mapping(), fh, indent=2)


if __name__ == "__main__":
    main()
