"""Continuous-to-discrete conversion and the one discrete filter implementation.

:func:`discretize` maps a continuous :class:`~forecast_design.lti.RationalTF`
to a :class:`DiscreteTF` that records how it was made (method, rate,
prewarp). :meth:`DiscreteTF.to_delta_sos` realises it as *delta-operator
second-order sections* and :class:`DiscreteFilter` runs them with the
recursion below, the same one the simulator runs and the C export emits.

Why the delta operator
----------------------
At 2 kHz the poles and zeros of 1-100 Hz filters sit within a few
hundredths of z = 1. Shift-operator coefficients ``a1 ~ -2``, ``a2 ~ 1``
then carry the filter in their last few bits: in float32 the EA-FOB's
G_s = -Q / P_n^EA lost 0.6 % of its DC gain and a motor-side FOB's
double differentiator no longer had its zeros at z = 1. Rewriting every
section in ``rho = z - 1`` (the delta operator with T = 1) stores
``(z - p1)(z - p2) = rho^2 + (d1 + d2) rho + d1 d2`` with ``d = 1 - p``,
so poles and zeros near z = 1 keep their *relative* precision. The
coefficients are computed from the continuous roots mapped exactly
(Tustin ``rho = 2 s / (c - s)``, Euler ``rho = s T``, ``s T / (1 - s T)``,
ZOH ``rho = expm1(s T)``), never from the expanded z-polynomial.

Three more rules make the float32 realisation match float64 to ~1e-6:

* zeros exactly at s = 0 (differentiators: the motor-side FOB's
  J_m s^2, the SFM's velocity filter) become leading first-difference
  sections ``(1 - z^-1)`` that act on the raw input; the difference of two
  nearby floats is exact, so a large angle never has to cancel against
  an integrated state;
* each section with a finite, non-zero DC gain is scaled to DC gain 1
  *exactly* (its constant numerator coefficient is the very same number
  as its constant denominator coefficient), and the overall gain goes
  into the first non-difference section: a unity-DC Q filter keeps
  Q(1) = 1 in float32, so the observer loop ``1 - Q`` keeps its integral
  action and the estimate does not drift;
* poles are grouped in conjugate pairs (two real poles share a section,
  an odd one gets a first-order section); zeros are given to the pole
  group nearest the unit circle first, each taking its nearest zeros;
  sections run fastest-first, the slowest (most sensitive) last.

Delta section recursion
-----------------------
Each row ``[b0, b1, b2, 1, a1, a2]`` of a delta-SOS array is::

    H(rho) = (b0 + b1 rho^-1 + b2 rho^-2) / (1 + a1 rho^-1 + a2 rho^-2),  rho = z - 1,

run in transposed direct form II with ``rho^-1`` (an accumulator
``s[n+1] = s[n] + v[n]``) in place of ``z^-1``; states ``s1, s2`` per
section, initially zero, and this exact order of operations::

    y  = b0 x + s1
    t1 = (b1 x - a1 y) + s2
    t2 = b2 x - a2 y
    s1 = s1 + t1
    s2 = s2 + t2

The output ``y`` of section ``i`` is the input ``x`` of section ``i + 1``.
A row with ``b2 = a2 = 0`` is a first-order section ``(b0 rho + b1) / (rho
+ a1)`` (``s2`` stays 0); ``[1, 0, 0, 1, 1, 0]`` is the first difference
``1 - z^-1``. :func:`delta_to_sos` / :func:`sos_to_delta` convert to and
from scipy's shift-operator sections (for interoperability only: the
conversion to shift form is exactly what loses the precision).
"""

from .filters import (FIRST_DIFFERENCE, HAVE_NUMBA, DiscreteFilter, check_kernel_cache, delta_to_sos, njit, prange,
                      sos_filter, sos_step, sos_to_delta)
from .tf import METHODS, DiscreteTF, discretize

__all__ = [
    "METHODS",
    "DiscreteTF",
    "DiscreteFilter",
    "discretize",
    "sos_step",
    "sos_filter",
    "delta_to_sos",
    "sos_to_delta",
    "FIRST_DIFFERENCE",
    "njit",
    "HAVE_NUMBA",
    "check_kernel_cache",
]
