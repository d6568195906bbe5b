"""Friction identification on independent logs: interval coverage per model and confident wrong numbers.

Run: python benchmarks/bench_friction_coverage.py [--logs N] [--workers W] [--families ...] [--laws ...]
[--cache DIR]

Families (each log drawn from its own seed, parameters drawn around the Forecast testbed's):

* ``open``: open-loop sliding logs of every law (sfm, extended-sfm, asymmetric, stribeck, lugre,
  position-friction), each fitted with its own model; 2 kHz, 12-20 s;
* ``closed``: PD force control (P 3-6, D 0.05-0.12) of a multisine or square force reference on
  stiff / exp-soft / soft / locked, sfm and extended-sfm friction;
* ``coarse``: open-loop sfm, extended-sfm and stribeck logs on 16- and 14-bit encoders;
* ``little``: the command barely breaks the motor away, one direction; fitted with the default
  sample selection and with ``selection="off"`` (the path a refusal used to suggest);
* ``wrong``: plain sfm fitted on asymmetric and Stribeck friction (the richer model is the truth).

Counted per fitted parameter: whether its 95 % interval covers the truth (coverage, over the
parameters with a finite interval), and a *confident wrong number*: status ``identified`` while
the truth lies beyond 4 standard deviations of the estimate or more than 10 % of the truth away
(the precision ``identified`` promises). In the ``wrong`` family a parameter of the misfitted
model is wrong when its interval covers none of the true levels it stands for.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

LAWS = ("sfm", "extended-sfm", "asymmetric", "stribeck", "lugre", "position-friction")
FAMILIES = ("open", "closed", "coarse", "little", "wrong")
#: In the ``wrong`` family, the true parameters each sfm parameter stands for.
STANDS_FOR = {"asymmetric": {"viscous": ("viscous_pos", "viscous_neg"), "coulomb": ("coulomb_pos", "coulomb_neg")},
              "stribeck": {"viscous": ("viscous",), "coulomb": ("coulomb",)}}


def draw_params(law: str, rng: np.random.Generator) -> dict[str, float]:
    """True friction parameters around the testbed's (viscous 0.15-0.45, Coulomb 0.15-0.45 N m)."""
    visc, coul = float(rng.uniform(0.15, 0.45)), float(rng.uniform(0.15, 0.45))
    if law == "sfm":
        return {"viscous": visc, "coulomb": coul}
    if law in ("extended-sfm", "position-friction"):
        # harmonics of the motor angle, added (extended SFM) or in the Coulomb level (position friction: at most
        # 0.03 N m each, so that the level stays positive)
        out = {"viscous": visc, "coulomb": coul}
        pre, top = ("", 0.04) if law == "extended-sfm" else ("coulomb_", 0.03)
        for i in range(1, 5):
            a = float(rng.uniform(0.0, top)) if rng.random() < 0.6 else 0.0
            ph = float(rng.uniform(0, 2 * math.pi))
            out[f"{pre}sin{i}"], out[f"{pre}cos{i}"] = a * math.cos(ph), a * math.sin(ph)
        return out
    if law == "asymmetric":
        return {"viscous_pos": visc, "viscous_neg": visc * float(rng.uniform(0.6, 1.4)),
                "coulomb_pos": coul, "coulomb_neg": coul * float(rng.uniform(0.6, 1.4))}
    static = coul * float(rng.uniform(1.3, 1.8))
    out = {"static": static, "coulomb": coul, "stribeck_velocity": float(rng.uniform(0.02, 0.1)), "viscous": visc}
    if law == "lugre":
        out = {"sigma0": float(rng.uniform(500.0, 2000.0)), "sigma1": float(rng.uniform(2.0, 8.0)), **out}
    return out


def jobs(family: str, n: int, seed0: int) -> list[dict]:
    """The logs of one family: keyword dictionaries for :func:`run_job`."""
    out = []
    for i in range(n):
        rng = np.random.default_rng([seed0, i, FAMILIES.index(family)])
        if family == "open":
            law = LAWS[i % len(LAWS)]
            out.append(dict(family=family, law=law, model=law, params=draw_params(law, rng), seed=seed0 + i,
                            kw=dict(duration_s=float(rng.uniform(12, 20)))))
        elif family == "closed":
            law = ("sfm", "extended-sfm")[i % 2]
            env = ("stiff", "exp-soft", "soft", "locked")[(i // 2) % 4]
            exc = ("multisine", "square")[(i // 8) % 2]
            from forecast_design.controllers import PD
            ctrl = PD(P=float(rng.uniform(3, 6)), D=float(rng.uniform(0.05, 0.12)))
            out.append(dict(family=family, law=law, model=law, params=draw_params(law, rng), seed=seed0 + i,
                            kw=dict(loop="closed", excitation=exc, environment=env, controller=ctrl, duration_s=20.0)))
        elif family == "coarse":
            law = ("sfm", "extended-sfm", "stribeck")[i % 3]
            counts = (2**16, 2**14)[(i // 3) % 2]
            out.append(dict(family=family, law=law, model=law, params=draw_params(law, rng), seed=seed0 + i,
                            kw=dict(encoder_counts=counts, duration_s=20.0)))
        elif family == "little":
            law = LAWS[i % len(LAWS)]
            sel = ("auto", "off")[(i // len(LAWS)) % 2]
            out.append(dict(family=family, law=law, model=law, params=draw_params(law, rng), seed=seed0 + i,
                            kw=dict(excitation="little-sliding", duration_s=15.0), selection=sel))
        elif family == "wrong":
            law = ("asymmetric", "stribeck")[i % 2]
            out.append(dict(family=family, law=law, model="sfm", params=draw_params(law, rng), seed=seed0 + i,
                            kw=dict(duration_s=20.0)))
    return out


def _cached_log(job: dict):
    """The job's log and truth: simulated, or read back from ``job["cache"]`` (experiment files + truth JSON)."""
    import json
    from pathlib import Path

    from forecast_design.experiment import load_experiment

    stem = Path(job["cache"]) / f"{job['family']}-{job['law']}-{job['seed']}-{job.get('selection', 'auto')}" \
        if job.get("cache") else None
    if stem is not None and stem.with_suffix(".json").exists():
        return load_experiment(stem.with_suffix(".toml")), json.loads(stem.with_suffix(".json").read_text())
    from forecast_design.experiment import save_experiment
    from forecast_design.independent import friction_log

    exp, true = friction_log(job["law"], job["params"], seed=job["seed"], **job["kw"])
    if stem is not None:
        stem.parent.mkdir(parents=True, exist_ok=True)
        save_experiment(exp, stem.with_suffix(".toml"))
        stem.with_suffix(".json").write_text(json.dumps(true))
        exp = load_experiment(stem.with_suffix(".toml"))
    return exp, true


def run_job(job: dict) -> dict:
    """Simulate one log, identify it, score every parameter."""
    import warnings

    from forecast_design.errors import IdentifiabilityError
    from forecast_design.friction import identify

    t0 = time.perf_counter()
    exp, true = _cached_log(job)
    rec = dict(family=job["family"], law=job["law"], model=job["model"], seed=job["seed"],
               selection=job.get("selection", "auto"), counts=job["kw"].get("encoder_counts", 2_000_000),
               env=job["kw"].get("environment", "link-only"), params=[], refused=None)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = identify(exp, job["model"], selection=job.get("selection", "auto"))
    except IdentifiabilityError as exc:
        rec["refused"] = str(exc)
        rec["seconds"] = time.perf_counter() - t0
        return rec
    rec["identifiability"] = fit.identifiability
    rec["adequacy"] = getattr(fit, "adequacy", None) and fit.adequacy.to_mapping()
    for name, st in fit.status.items():
        if name in ("offset", "inertia"):
            continue
        est, std = float(fit.params[name]), float(fit.std[name])
        lo, hi = fit.interval95[name]
        if job["model"] == job["law"]:
            truths = (true[name],)
        else:
            truths = tuple(true[k] for k in STANDS_FOR[job["law"]].get(name, ()))
        if not truths:
            continue
        covered = any(lo <= t <= hi for t in truths) if math.isfinite(lo) and math.isfinite(hi) else None
        err = min(abs(est - t) for t in truths)
        scale = max(abs(t) for t in truths)
        wrong = st.status == "identified" and (
            (job["model"] != job["law"] and not covered)
            or not (math.isfinite(std) and std > 0) or err > 4 * std or (scale > 0 and err > 0.1 * scale))
        rec["params"].append(dict(name=name, truth=truths, est=est, std=std, lo=lo, hi=hi, status=st.status,
                                  covered=covered, wrong=bool(wrong)))
    rec["seconds"] = time.perf_counter() - t0
    return rec


def summarise(records: list[dict]) -> str:
    """Coverage per family and model, and the confident wrong numbers."""
    lines = []
    groups: dict[tuple, list] = {}
    for r in records:
        groups.setdefault((r["family"], r["model"] if r["family"] != "wrong" else f"sfm on {r['law']}"), []).append(r)
    lines.append("| family | model | logs | refused / not identifiable | parameters with an interval | coverage | "
                 "identified | confident wrong |")
    lines.append("|---|---|---|---|---|---|---|---|")
    total_wrong = 0
    for (fam, model), recs in sorted(groups.items()):
        ps = [p for r in recs for p in r["params"]]
        cov = [p["covered"] for p in ps if p["covered"] is not None]
        ident = sum(p["status"] == "identified" for p in ps)
        wrong = [f"{r['law']} seed {r['seed']} {p['name']} {p['est']:.4g} (true {', '.join(f'{t:.4g}' for t in p['truth'])})"
                 for r in recs for p in r["params"] if p["wrong"]]
        total_wrong += len(wrong)
        refused = sum(r["refused"] is not None or str(r.get("identifiability", "")).startswith("not identifiable")
                      for r in recs)
        c = f"{100 * np.mean(cov):.1f} % ({sum(cov)}/{len(cov)})" if cov else "-"
        lines.append(f"| {fam} | {model} | {len(recs)} | {refused} | {len(cov)} | {c} | {ident} | {len(wrong)} |")
        for w in wrong:
            lines.append(f"|  |  |  |  |  |  |  | {w} |")
    lines.append(f"\nconfident wrong numbers in total: {total_wrong}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=24, help="logs per family and model (open: per law)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--families", default="open,closed,coarse,little,wrong")
    ap.add_argument("--laws", default=",".join(LAWS), help="keep only the logs of these laws (same seeds as all)")
    ap.add_argument("--seed", type=int, default=2500)
    ap.add_argument("--json", metavar="OUT", help="also write every record as JSON")
    ap.add_argument("--cache", metavar="DIR", help="keep the simulated logs (experiment files) here and reuse them")
    args = ap.parse_args()
    per_family = {"open": args.logs * len(LAWS), "closed": args.logs, "coarse": args.logs, "little": 2 * len(LAWS),
                  "wrong": 12}
    laws = set(args.laws.split(","))
    all_jobs = [{**j, "cache": args.cache} for f in args.families.split(",") for j in jobs(f, per_family[f], args.seed)
                if j["law"] in laws]
    t0 = time.perf_counter()
    print(f"{len(all_jobs)} logs on {args.workers} workers; machine {platform.machine()}, {os.cpu_count()} cores, "
          f"{platform.processor() or platform.platform()}; load {os.getloadavg()[0]:.2f}; "
          f"{time.strftime('%Y-%m-%d %H:%M')}", flush=True)
    with ProcessPoolExecutor(args.workers) as ex:
        records = list(ex.map(run_job, all_jobs))
    print(summarise(records))
    if args.json:
        import json

        with open(args.json, "w") as fh:
            json.dump(records, fh, indent=1, default=str)
    print(f"wall {time.perf_counter() - t0:.0f} s, load after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
