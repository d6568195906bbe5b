"""An independent log generator: the spec's plant equations, integrated apart from the virtual testbed.

The virtual testbed (:mod:`forecast_design.simulation`) made every log the gap
diagnosis and the friction identification were tuned on. This module writes
logs of the same plant with other code, another integrator and another
logger, so methods can be judged on data the project did not make:

* plant (experiment format, SI, rad)::

      J_m theta'' = g tau_m(t - delay) - tau_s - d_m theta' - tau_f(theta', theta) - tau_cog(theta)
      tau_s       = k (theta - q)       (backlash: k deadzone(theta - q, width / 2))
      J q'' + d q' + k_e q = tau_s      (locked: q == 0)

* friction with true sticking: event-based stick/slip switching (Karnopp-like
  but exact: the switch instants are located by root finding), optionally
  LuGre bristle dynamics written from Canudas de Wit et al. (1995);
* backlash as three modes (contact +, dead band, contact -), switched by events;
* integration: Dormand-Prince 5(4) (``scipy.integrate.ode``, ``dopri5``) over
  each interval on which the applied torque is constant (exact zero-order
  hold, the delay splits a period in two); when a mode-validity function turns
  negative at the end of an interval the interval is redone by
  ``scipy.integrate.solve_ivp`` (DOP853) with terminal events, so every switch
  is located by root finding, never smoothed;
* the logger: 2,000,000-count encoders, 1 or 2 kHz, ``tau_s`` omitted,
  printed from ``k_nominal (theta - q)`` at 6-10 significant digits or measured
  by a torque sensor with noise, ``tau_m`` printed at 7-9 significant digits,
  a nominal testbed that is up to 2 % off the simulated one;
* closed loop: a discrete PD force controller with a first-order filtered
  derivative (Tustin), updated at the log rate, command held over the period.

It imports no simulation code of the toolbox (layer 2 of the package, it uses
only :mod:`params`, :mod:`effects` (the vocabulary), :mod:`experiment` and
:mod:`errors`).


The generator is split by concern: :mod:`.model` (constants and the case, truth and log
types), :mod:`.signals` (excitations and the logger's rounding), :mod:`.plant` (the
event-located integration), :mod:`.draw` (random cases and their identifiability) and
:mod:`.friction_logs` (friction-only logs for the identification).
"""

from .draw import draw_independent_case, identifiability, make_independent_log
from .friction_logs import FRICTION_EXCITATIONS, friction_log
from .model import (
    ANGLE_WORDS,
    COUNTS_PER_REV,
    ENCODER_COUNTS,
    ENCODER_STEP,
    EXCITATION_KINDS,
    FRICTION_LAWS,
    MAX_ATTEMPTS,
    RATES_HZ,
    Excitation,
    IndependentCase,
    IndependentLog,
    IndependentTruth,
)
from .plant import simulate_independent
from .signals import excitation_signal, one_line_fraction, round_significant

__all__ = [
    "COUNTS_PER_REV",
    "ENCODER_COUNTS",
    "ENCODER_STEP",
    "MAX_ATTEMPTS",
    "RATES_HZ",
    "EXCITATION_KINDS",
    "FRICTION_LAWS",
    "ANGLE_WORDS",
    "Excitation",
    "IndependentCase",
    "IndependentTruth",
    "IndependentLog",
    "excitation_signal",
    "round_significant",
    "one_line_fraction",
    "draw_independent_case",
    "simulate_independent",
    "identifiability",
    "make_independent_log",
    "friction_log",
    "FRICTION_EXCITATIONS",
]

#: Encoder resolution of the Forecast testbed (paper section 7) [counts/rev].
