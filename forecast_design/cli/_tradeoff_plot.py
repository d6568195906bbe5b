"""``tune-q --plot``: the cutoff trade-off of the tuned observer, the other observers beside it."""

from __future__ import annotations

import argparse
from typing import Any

from ..params import OBSERVER_KINDS

__all__ = ["plot_tune_q_tradeoff"]


def plot_tune_q_tradeoff(args: argparse.Namespace, result: Any, envs: Any, *, testbed: Any = None,
                         controller: Any = None) -> dict[str, Any]:
    """Compute the trade-off for every observer on the tuner's set and draw it to ``args.plot``.

    Parameters
    ----------
    args : argparse.Namespace
        The ``tune-q`` options (band, ratio, Q filter, loop settings, ``plot``).
    result : TuningResult
        The tuner's answer (its cutoff and, in ``--max-margin`` mode, its Q damping).
    envs : Any
        The environment set exactly as it was given to the tuner.
    testbed : Testbed, optional
        The tuner's testbed (None: Table 1).
    controller : Controller, optional
        The tuner's force controller (None: the paper's PD).

    Returns
    -------
    dict
        The tuned observer's trade-off as JSON (``tradeoff`` key of the verb's output).
    """
    from ..plotting.tuning import plot_tradeoff
    from ..tuning.tradeoff import cutoff_tradeoff

    band = tuple(args.band)
    if result.w_q_hz == result.w_q_hz:      # keep the chosen cutoff inside the drawn range
        band = (min(band[0], result.w_q_hz), max(band[1], result.w_q_hz))
    common = dict(band_hz=band, min_ratio=args.min_ratio, uncertainty=args.uncertainty, q_family=args.q_family,
                  q_order=args.q_order, break_at=args.break_at, sampled=args.sampled, rate_hz=args.rate_hz,
                  delay_samples=args.delay_samples, seed=args.seed, testbed=testbed)
    if controller is not None:
        common["controller"] = controller
    if result.q_damping is not None:
        common.update(q_family="butterworth", q_order=2)
    main = cutoff_tradeoff(result.observer, envs, chosen=result, q_damping=result.q_damping, **common)
    others = [cutoff_tradeoff(kind, envs, **common) for kind in OBSERVER_KINDS if kind != result.observer]
    shape = f", Q damping {result.q_damping:.3g}" if result.q_damping is not None else ""
    plot_tradeoff([main, *others], args.plot,
                  title=f"tune-q {result.observer}{shape}: {result.plants} plants, min ratio {args.min_ratio:g}")
    return main.to_mapping()
