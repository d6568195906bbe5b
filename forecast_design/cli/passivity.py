"""The ``passivity`` verb: is the force-controlled SEA stable with every passive environment?"""

from __future__ import annotations

import argparse
import math
import sys

from ..params import Q_FAMILIES
from . import _COMPENSATOR_CHOICES, _add_json_option, _command, _write_json
from ._options import (_add_controller_option, _add_environment_options, _controller_from_args, _float_range,
                       _note, _one_environment_from_args, _testbed_from_args)


def _configure_passivity(p: argparse.ArgumentParser) -> None:
    _add_environment_options(p, default="soft", many=False)
    p.add_argument("--compensator", "--observer", dest="observer", default="none", choices=_COMPENSATOR_CHOICES,
                   help="compensator/observer (default none); an observer is designed for the --env environment")
    p.add_argument("--w-q-hz", type=_float_range, default=10.0, help="Q cutoff [Hz]")
    p.add_argument("--q-family", default="butterworth", choices=Q_FAMILIES)
    _add_controller_option(p)
    p.add_argument("--port", default="link", choices=("link", "spring"),
                   help="where environments attach: the link's end (default; the link is the actuator's) or the "
                        "spring's end")
    p.add_argument("--rate-hz", type=_float_range, default=None,
                   help="rate of a discrete controller that does not carry one [Hz]")
    _add_json_option(p, "the passivity analysis")
    p.add_argument("--plot", metavar="OUT.png", help="Re Z over frequency with the bands where it is negative")


def _fmt_range(r) -> str:
    if r is None:
        return "none (the given environment is unstable)"
    return f"[{r[0]:.4g}, {'inf' if math.isinf(r[1]) else f'{r[1]:.4g}'}]"


@_command("passivity", "is the force-controlled SEA stable with every passive environment (Colgate's coupled "
          "stability); exit 1 if not passive", _configure_passivity)
def _cmd_passivity(args: argparse.Namespace) -> int:
    from ..limits import require_no_nan
    from ..params import Compensator, Design
    from ..passivity import analyse_passivity

    env_name, env = _one_environment_from_args(args, "passivity")
    design = Design(testbed=_testbed_from_args(args), environment=env)
    comp = None if args.observer == "none" else Compensator(kind=args.observer, w_q_hz=args.w_q_hz,
                                                            q_family=args.q_family)
    result = analyse_passivity(design, comp, controller=_controller_from_args(args), port=args.port,
                               rate_hz=args.rate_hz, environment_name=env_name)
    _note(result.notes)
    if args.plot:
        from ..plotting.passivity import plot_passivity

        plot_passivity(result, args.plot)
    mapping = require_no_nan(result.to_mapping(), "passivity")
    if args.json:
        _write_json(args.json, mapping)
    out = sys.stderr if args.json == "-" else sys.stdout
    print(f"port: {result.title()}", file=out)
    if args.json != "-":
        w = result.w_min_rad_s
        print(("PASSIVE: stable with every passive environment" if result.passive else "NOT passive") +
              f"; locked loop {'stable' if result.locked_stable else 'UNSTABLE'}, free port "
              f"{'stable' if result.free_stable else 'UNSTABLE'}")
        print(f"min Re Z = {result.min_re_z:.6g} N m s/rad at " +
              ("infinite frequency" if math.isinf(w) else f"{w:.6g} rad/s ({w / (2 * math.pi):.4g} Hz)"))
        for lo, hi in result.bands_rad_s:
            print(f"  Re Z < 0 for {lo:.6g} < w < {hi:.6g} rad/s")
        print(f"stiffness k_e keeping it stable (J_e {env.J_e:g}, d_e {env.d_e:g}): "
              f"{_fmt_range(result.stiffness_range)} N m/rad; inertia J_e (d_e {env.d_e:g}, k_e {env.k_e:g}): "
              f"{_fmt_range(result.inertia_range)} kg m^2")
        if result.destabilising_environment:
            e = result.destabilising_environment
            print(f"a passive environment that destabilises it: J_e {e['J_e_kg_m2']:.4g} kg m^2, d_e "
                  f"{e['d_e_n_m_s_per_rad']:.4g} N m s/rad, k_e {e['k_e_n_m_per_rad']:.4g} N m/rad")
        if args.plot:
            print(f"plot: {args.plot}")
    return 0 if result.passive else 1
