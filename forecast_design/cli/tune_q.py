"""The ``tune-q`` verb: the Q-filter cutoff by optimisation (casadi) over a set of environments."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys

from ..params import BREAK_POINTS, OBSERVER_KINDS, Q_FAMILIES
from ..loops import COMMAND_DELAY_SAMPLES
from ..limits import require_no_nan
from . import (_add_controller_option, _add_environment_options, _command, _controller_from_args,
               _environments_from_args, _float_range, _progress_bar, _testbed_from_args, _write_json)


def _configure_tune_q(p: argparse.ArgumentParser) -> None:
    p.add_argument("--compensator", "--observer", dest="observer", required=True, choices=OBSERVER_KINDS,
                   help="the observer whose Q cutoff is tuned")
    _add_controller_option(p)
    _add_environment_options(p, default="soft,stiff", many=True)
    p.add_argument("--uncertainty", type=_float_range, default=0.0, metavar="FRACTION",
                   help="relative range of the true J, d, k_e (vertices of the box)")
    p.add_argument("--min-ratio", type=_float_range, default=0.9,
                   help="required disk-margin ratio observer/plant (default 0.9)")
    p.add_argument("--band", type=_float_range, nargs=2, default=(0.5, 30.0), metavar=("LO", "HI"),
                   help="search band of the cutoff [Hz] (default 0.5 30)")
    p.add_argument("--q-family", default="butterworth", choices=Q_FAMILIES)
    p.add_argument("--q-order", type=int, default=2)
    p.add_argument("--break-at", default="controller", choices=BREAK_POINTS)
    p.add_argument("--max-margin", metavar="W_Q_HZ", type=_float_range,
                   help="instead: at this fixed cutoff, choose the 2nd-order Q damping that "
                        "maximises the worst-case margin ratio")
    p.add_argument("--seed", type=int, default=0, help="seed of random:N environment sets")
    p.add_argument("--sampled", action="store_true",
                   help="analyse the sampled-data loop (discretised controller/observer, ZOH plant)")
    p.add_argument("--rate-hz", type=_float_range, default=2000.0, help="--sampled: control rate [Hz]")
    p.add_argument("--delay-samples", type=int, default=COMMAND_DELAY_SAMPLES,
                   help="--sampled: samples between computing the command and applying it (default 0: within the "
                        "period, as the simulator and the firmware run it)")
    p.add_argument("--exact-scan", action="store_true", help="verify with a full exact scan (slow)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="compute the plants' margins on N local processes (large sets; default: this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="compute them on a Dask cluster, tcp://HOST:PORT (same answer as locally)")
    p.add_argument("--json", metavar="OUT", nargs="?", const="-", help="write JSON to OUT (or stdout)")
    p.add_argument("--plot", metavar="OUT.png",
                   help="draw the trade-off: worst-case margin ratio and friction-rejection bandwidth "
                        "against the cutoff, per observer, with the chosen cutoff (JSON key 'tradeoff')")


@_command("tune-q", "choose the Q-filter cutoff by optimisation (casadi) over a set of environments",
          _configure_tune_q)
def _cmd_tune_q(args: argparse.Namespace) -> int:
    from ..tuning import tune_q, tune_q_shape

    # random:N is expanded here with --seed; the set (an EnvironmentSet) is what tune_q receives
    args.envs = _environments_from_args(args, seed=args.seed)
    testbed = _testbed_from_args(args)
    controller = _controller_from_args(args)
    with contextlib.ExitStack() as stack:
        executor = None
        if args.scheduler or args.workers is not None:
            from ..executor import make_executor

            executor = stack.enter_context(make_executor(args.scheduler, args.workers))
        if args.max_margin is not None:
            result = tune_q_shape(args.observer, args.envs, w_q_hz=args.max_margin, uncertainty=args.uncertainty,
                                  controller=controller, break_at=args.break_at, seed=args.seed,
                                  sampled=args.sampled, rate_hz=args.rate_hz, delay_samples=args.delay_samples,
                                  testbed=testbed, executor=executor)
        else:
            with _progress_bar("exact scan", "cutoff") as progress:
                result = tune_q(args.observer, args.envs, uncertainty=args.uncertainty, min_ratio=args.min_ratio,
                                band_hz=tuple(args.band), q_family=args.q_family, q_order=args.q_order,
                                controller=controller, break_at=args.break_at, seed=args.seed,
                                progress=progress, sampled=args.sampled, rate_hz=args.rate_hz,
                                delay_samples=args.delay_samples,
                                scan="exact" if args.exact_scan else "bounded", testbed=testbed, executor=executor)
    mapping = require_no_nan(result.to_mapping(), "tune-q")
    mapping["assumed"] = _assumed(args, testbed, controller)
    if args.plot:
        from ._tradeoff_plot import plot_tune_q_tradeoff

        mapping["tradeoff"] = plot_tune_q_tradeoff(args, result, args.envs, testbed=testbed, controller=controller)
    if args.json:
        _write_json(args.json, mapping)
    if args.json != "-":
        extra = f", Q damping {result.q_damping:.4g}" if result.q_damping is not None else ""
        hz = lambda v: f"{v:.4g} Hz" if math.isfinite(v) else "none"    # noqa: E731 (infeasible: no cutoff)
        print(f"{result.observer}: w_q = {hz(result.w_q_hz)}{extra}, worst ratio {result.worst_ratio:.4f} "
              f"({result.worst_environment or '-'}), feasible {result.feasible}; scan best {hz(result.scan_w_q_hz)}, "
              f"agrees {result.agrees_with_scan}; {result.plants} plants, {result.evaluations} evaluations")
        if result.worst_case is not None:
            print(result.worst_case.summary("worst ratio", f" in {result.worst_case_environment}"))
        if result.certified_for is not None:
            print(f"tuned to a ratio of {result.certified_for:.6f} at the vertices so that min-ratio "
                  f"{result.min_ratio:g} is certified over the whole box")
    if result.worst_case is None and args.uncertainty > 0.0 and args.sampled:
        print("forecast-design: note: --sampled: the worst case over the box is checked at its vertices only (the "
              "certified bound is for the continuous loop)", file=sys.stderr)
    if result.worst_case is not None and result.feasible and result.worst_case.lower < result.min_ratio:
        print(f"forecast-design: warning: min-ratio {result.min_ratio:g} is not certified over the box: the worst "
              f"ratio is only known to lie in [{result.worst_case.lower:.6f}, {result.worst_case.upper:.6f}]",
              file=sys.stderr)
    if result.at_bound:
        option = "--band" if result.q_damping is None else "the damping range"
        print(f"forecast-design: warning: the answer sits on the {result.at_bound}: the best value may lie "
              f"beyond it (widen {option} to find out)", file=sys.stderr)
    if not result.feasible:
        print(f"forecast-design: warning: no cutoff in the band meets min-ratio {result.min_ratio:g} in every "
              f"environment: the best of the band, {result.w_q_hz:.4g} Hz, keeps {result.worst_ratio:.3f} "
              f"({result.worst_environment})", file=sys.stderr)
        return 1
    return 0


def _assumed(args: argparse.Namespace, testbed, controller) -> dict:
    """What the cutoff was tuned for: controller, testbed, each environment's values (the nominal points; the
    vertices are their J, d, k_e scaled by 1 +- uncertainty), Q form, break point and loop."""
    from ..environments import resolve_environments, resolve_testbed

    tb = resolve_testbed(testbed)
    envs = resolve_environments(args.envs, testbed=tb, seed=args.seed)
    return {"controller": controller.to_mapping(), "testbed": tb.to_mapping(),
            "environments": {label: env.to_mapping() for label, env in envs},
            "uncertainty": args.uncertainty,
            # --max-margin tunes a 2nd-order Q's damping at a fixed cutoff: no family of its own
            "q_family": None if args.max_margin is not None else args.q_family,
            "q_order": 2 if args.max_margin is not None else args.q_order,
            "break_at": args.break_at, "loop": "sampled" if args.sampled else "continuous",
            "rate_hz": args.rate_hz if args.sampled else None}
