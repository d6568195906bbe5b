"""Verdicts of the gap diagnosis over closed-loop set-ups the withheld-effect benchmark does not draw.

Usage: python benchmarks/bench_gap_setups.py [--duration S] [--workers W] [--encoder-counts N]
                                            [--noise N_M]

Every effect word (and none) x environment (stiff, exp-soft, locked) x compensator (PD alone,
PD + EA-FOB 10 Hz) x reference (+-1 N m square of 4 s, a three-tone multisine, a 0.2-8 Hz chirp),
10 s at 2 kHz on the virtual testbed, diagnosed from the in-memory log (tau_s as the Forecast
logger computes it, k (theta - q)). The motor turns through 0.03-0.5 rad in these set-ups, less
than a revolution, so position_friction cannot be told from coulomb here: those rows are counted
apart. Prints each wrong verdict with the motor's angle span [rad] and the counts.
``--encoder-counts 4096 --noise 0.02`` repeats it with a coarse encoder and a noisy motor torque.
"""

from __future__ import annotations

import argparse
import itertools
from concurrent.futures import ProcessPoolExecutor

from forecast_design import effects as fx
from forecast_design.gap import diagnose
from forecast_design.controllers import PD
from forecast_design.params import Compensator, Design
from forecast_design.simulation import references as refs
from forecast_design.simulation import simulate

EFFECTS = {"none": None, "coulomb": fx.Coulomb(F_c=0.4), "stiction": fx.Stiction(),
           "position_friction": fx.PositionFriction(F_c=0.3, a=(0.1,), b=(0.05,)),
           "cogging": fx.Cogging(a=(0.15,), b=(0.05,)), "backlash": fx.Backlash(width_rad=2e-3),
           "delay": fx.Delay(delay_s=2e-3), "torque_gain": fx.TorqueGain(gain=0.85),
           "environment_mismatch": fx.EnvironmentMismatch(k_e_scale=1.4)}
REFERENCES = {"square": refs.Square(high=1.0, low=-1.0, period_s=4.0),
              "multisine": refs.Multisine(amplitudes=(0.8, 0.5, 0.3), frequencies_hz=(0.4, 1.3, 3.1),
                                          phases_rad=(0.0, 1.0, 2.0)),
              "chirp": refs.Chirp(amplitude=0.8, f0_hz=0.2, f1_hz=8.0, duration_s=10.0)}


def _one(case: tuple) -> tuple[tuple[str, ...], str, float]:
    effect, env, comp, ref, duration_s, counts, noise = case
    design = Design.nominal(env, controller=PD(P=5.0, D=0.1), compensator=Compensator(kind=comp))
    eff = () if EFFECTS[effect] is None else (EFFECTS[effect],)
    res = simulate(design, reference=REFERENCES[ref], duration_s=duration_s, effects=eff, seed=7, initial_angle=0.3,
                   encoder_counts=counts, process_noise_std=noise)
    d = diagnose(res.to_experiment())
    return (effect, env, comp, ref), str(d.effect), float(d.location.angle_span_rad)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--encoder-counts", type=int, default=2_000_000, help="counts per revolution")
    ap.add_argument("--noise", type=float, default=0.001, help="process noise std [N m]")
    args = ap.parse_args()
    cases = [(e, env, c, r, args.duration, args.encoder_counts, args.noise)
             for e, env, c, r in itertools.product(EFFECTS, ("stiff", "exp-soft", "locked"), ("none", "ea-fob"),
                                                   REFERENCES)
             if not (e == "environment_mismatch" and env == "locked")]   # no environment equation
    with ProcessPoolExecutor(args.workers) as ex:
        out = list(ex.map(_one, cases))
    wrong = [(case, v, span) for case, v, span in out if v != case[0]]
    for case, verdict, span in wrong:
        print(" ".join(case), "->", verdict, f"(angle span {span:.3f} rad)")
    pf = sum(1 for case, _, _ in wrong if case[0] == "position_friction")
    print(f"set-ups {len(out)}, wrong verdicts {len(wrong)} (position_friction named coulomb over less than a "
          f"revolution: {pf}; others: {len(wrong) - pf})")


if __name__ == "__main__":
    main()
