"""Diagnosis on the independent generator's set-ups of issue 25, with every candidate's scores.

Run: python benchmarks/bench_gap_issue25.py [--per-effect N] [--scale S ...] [--seed S] [--workers W]
     [--cache DIR] [--json OUT] [--controllers]

Logs of :func:`forecast_design.independent.make_independent_log` (another SEA, 16/14-bit encoders,
loggers printing tau_s and the angles with fixed decimals or significant digits, asymmetric friction,
drawn from their own random stream) are simulated once (cached as pickles under ``--cache``) and
diagnosed blind (with ``--controllers`` half the closed loops run a PID); the table gives the accuracy and false alarms per scale, the misses with the
true effect's rank, reduction and identification, and the tau_s decisions.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from forecast_design.effects import Effect


def _summary(case) -> dict:
    return {"encoder_counts": case.encoder_counts, "tau_s": case.tau_s_logging, "angles": case.angle_logging,
            "controller": None if case.controller is None else case.design.controller.kind,
            "k": case.testbed.k, "closed": case.closed_loop, "env": case.environment_name,
            "excitation": case.excitation.kind, "asymmetric": "F_c_neg" in case.effect_params,
            "params": {k: (list(v) if isinstance(v, tuple) else v) for k, v in case.effect_params.items()}}


def _log(word: str, index: int, seed: int, scale: float, cache: str | None, controllers: bool = False):
    """(experiment, case summary, suite) of one log, simulated once (cached as the experiment's files)."""
    from forecast_design import independent as ind
    from forecast_design.errors import IdentifiabilityError
    from forecast_design.experiment import load_experiment, save_experiment

    stem = Path(cache) / f"{word}-{index}-{seed}-{scale:g}" if cache else None
    if stem is not None and stem.with_suffix(".json").exists():
        meta = json.loads(stem.with_suffix(".json").read_text())
        return load_experiment(stem.with_suffix(".toml")), meta["case"], meta["suite"]
    try:
        log = ind.make_independent_log(word, index, seed, magnitude_scale=scale, controllers=controllers)
        exp, case, suite = log.experiment, log.case, "main"
    except IdentifiabilityError:
        case = ind.draw_independent_case(word, index, seed, magnitude_scale=scale, controllers=controllers)
        exp, suite = ind.simulate_independent(case)[0], "hard"
    summary = _summary(case)
    if stem is not None:
        stem.parent.mkdir(parents=True, exist_ok=True)
        save_experiment(exp, stem.with_suffix(".toml"))
        stem.with_suffix(".json").write_text(json.dumps({"case": summary, "suite": suite}))
        exp = load_experiment(stem.with_suffix(".toml"))     # exactly what a tool reads from the files
    return exp, summary, suite


def run(job: tuple) -> dict:
    """Diagnose one log; the record holds the verdict and every candidate's scores."""
    import warnings

    from forecast_design.gap import diagnose

    word, index, seed, scale, cache, controllers = job
    exp, case, suite = _log(word, index, seed, scale, cache, controllers)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        diag = diagnose(exp, joint=False)
    doc = diag.to_mapping()
    ranking = [{k: r.get(k) for k in ("effect", "reduction", "reduction_in_equations", "p_value", "counts",
                                      "identified", "reasons")} for r in doc["ranking"]]
    return {"word": word, "index": index, "seed": seed, "scale": scale, "suite": suite,
            "verdict": doc["verdict"]["effect"], "grade": doc["verdict"].get("grade"),
            "weak": doc["verdict"].get("weak"), "secondary": (doc["verdict"].get("secondary") or {}).get("effect"),
            "gap_before": doc["verdict"]["gap_before"], "gap_after": doc["verdict"]["gap_after"],
            "tau_s": doc.get("tau_s"), "ranking": ranking, "caveats": doc["caveats"],
            "params": doc["verdict"]["params"], "status": doc["verdict"]["status"],
            "std_method": doc["verdict"].get("std_method"), "std_calibration_bound": doc["verdict"].get("std_calibration_bound"),
            "case": case,
            "seconds": time.perf_counter() - t0}


def summarise(records: list[dict]) -> str:
    """Accuracy, false alarms and misses per scale."""
    out = []
    for scale in sorted({r["scale"] for r in records}, reverse=True):
        recs = [r for r in records if r["scale"] == scale and r["suite"] == "main"]
        ok = sum(r["verdict"] == r["word"] for r in recs)
        fa = sum(r["word"] == "none" and r["verdict"] != "none" for r in recs)
        out.append(f"scale {scale:g}: {ok}/{len(recs)} = {100 * ok / max(len(recs), 1):.1f} % correct, "
                   f"{fa} false alarm(s); hard (not identifiable by the generator's rule): "
                   f"{sum(r['suite'] == 'hard' for r in records if r['scale'] == scale)}")
        for r in recs:
            if r["verdict"] == r["word"]:
                continue
            true = next((x for x in r["ranking"] if x["effect"] == r["word"]), None)
            rank = [x["effect"] for x in r["ranking"]].index(r["word"]) + 1 if true else None
            desc = (f"rank {rank}, reduction {true['reduction']:.2f} (own {true['reduction_in_equations'] or 0:.2f}), "
                    f"p {true['p_value']:.2g}, identified {true['identified']}"
                    + ("" if true["identified"] else f" ({'; '.join(true['reasons'][:1])})")) if true else "-"
            out.append(f"  {r['word']:<22} -> {r['verdict']:<20} weak={r.get('weak')} {desc}; "
                       f"tau_s {r['case']['tau_s']} read {r['tau_s'] and r['tau_s']['source']}; "
                       f"{r['case']['encoder_counts']} counts; k {r['case']['k']:g}; "
                       f"{'cl' if r['case']['closed'] else 'ol'}-{r['case']['excitation']} {r['case']['env']}")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-effect", type=int, default=5)
    ap.add_argument("--scale", type=float, nargs="+", default=[1.0, 0.125])
    ap.add_argument("--seed", type=int, default=25)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", default=None, help="folder for the simulated logs (pickles)")
    ap.add_argument("--words", default=",".join(str(w) for w in Effect))
    ap.add_argument("--json", default=None)
    ap.add_argument("--controllers", action="store_true", help="half the closed loops run a PID (use its own --cache)")
    args = ap.parse_args()
    jobs = [(w, i, args.seed, s, args.cache, args.controllers) for s in args.scale for w in args.words.split(",")
            for i in range(args.per_effect)]
    t0 = time.perf_counter()
    print(f"{len(jobs)} logs, {args.workers} workers; {platform.machine()} {os.cpu_count()} cores; load "
          f"{os.getloadavg()[0]:.2f}; {time.strftime('%Y-%m-%d %H:%M')}", flush=True)
    with ProcessPoolExecutor(args.workers) as ex:
        records = list(ex.map(run, jobs))
    print(summarise(records))
    print(f"wall {time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=1, default=str))


if __name__ == "__main__":
    main()
