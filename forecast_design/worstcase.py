"""Certified worst-case disk margin over a continuous box of true environments (branch and bound).

The true environment E(s) = J s^2 + d s + k_e (J = J_e + J_l, d = d_e + d_l) ranges over the box
J in J0 [1 - u, 1 + u], d in d0 [1 - u, 1 + u], k_e in k0 [1 - u, 1 + u] (``tune-q --uncertainty``'s
box, whose vertices and centre it used to check); what the observer believes stays nominal.

Why a bound is exact at each frequency: the environment enters the loop as one scalar block
(q = tau_s / E), so at a fixed frequency the sensitivity is a Moebius function of the complex
number E(jw), S = (a E + b) / (c E + d), and over a box E(jw) fills the rectangle
[k_lo - J_hi w^2, k_hi - J_lo w^2] + j [d_lo w, d_hi w]. The largest |S + (sigma - 1)/2| over
that rectangle lies on its edges (maximum modulus; a pole inside means a loop of the box is
marginally stable there) and on each edge it is a ratio of quadratics in the edge parameter,
whose maximum is at an end or at a root of a quadratic. Taking that maximum at every frequency
gives a lower bound of the disk margin over the box (each frequency may pick its own worst
environment); the exact margin at the box's centre is an upper bound. Branch and bound splits
the box with the lowest lower bound until the bounds meet to the tolerance.

The Moebius coefficients are fitted once per frequency from three environments of the loop
itself (the same :func:`~forecast_design.loops.force_loop` the margins use) and checked at a
fourth; the frequency supremum of the bound is taken on a 40-per-decade grid together with the
exact peak frequency of every loop evaluated. Continuous loops only: a sampled loop's ZOH plant
mixes frequencies, so its sensitivity is not a pointwise function of E(jw).
"""

from __future__ import annotations

import dataclasses
import heapq
import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import ParameterError
from .loops import force_loop
from .margins import disk_margin
from .margins.disk import check_skew
from .params import Compensator, Design

__all__ = ["WorstCaseMargin", "worst_case_disk_margin", "worst_case_ratio", "scaled_environment"]

_FIT_POINTS = ((0.5, 0.5, 0.5), (2.0, 1.0, 1.5), (1.0, 2.0, 0.7))   # (J, d, k_e) factors of the fit
_CHECK_POINT = (1.3, 0.8, 1.1)
_FIT_RTOL = 1e-7          # the fourth environment must match the fitted map to this
_ZOOM_SLACK = 1e-7        # relative allowance for the sampled frequency maximum of the bound


@dataclass(frozen=True, slots=True)
class WorstCaseMargin:
    """Bounds on the smallest disk margin over a box of true environments.

    Parameters
    ----------
    lower : float
        Certified lower bound of min alpha over the box [-] (0 when a loop of the box may be unstable).
    upper : float
        Disk margin of the worst environment found (an upper bound of the minimum) [-].
    point : tuple of float
        (J [kg m^2], d [N m s/rad], k_e [N m/rad]) of that environment (J, d include the link).
    factors : tuple of float
        The same point as factors of the nominal (J, d, k_e) [-].
    vertex_min : float
        The smallest margin over the box's 8 vertices and centre (what a vertex check sees) [-].
    uncertainty : float
        Relative half-width u of the box [-].
    boxes : int
        Sub-boxes bounded.
    converged : bool
        ``upper - lower <= tolerance * upper``.
    tolerance : float
        Relative gap asked for [-].
    """

    lower: float
    upper: float
    point: tuple[float, float, float]
    factors: tuple[float, float, float]
    vertex_min: float
    uncertainty: float
    boxes: int
    converged: bool
    tolerance: float

    @property
    def gap(self) -> float:
        """``upper - lower`` [-]."""
        return self.upper - self.lower

    def summary(self, quantity: str, where: str = "") -> str:
        """One line for a verb's output: the certified bounds of ``quantity``, the worst point, the vertex answer.

        Parameters
        ----------
        quantity : str
            What is bounded (``disk margin``, ``worst ratio``).
        where : str
            Appended after the point (e.g. `` in soft``).
        """
        J, d, k_e = self.point
        return (f"over J, d, k_e x [{1 - self.uncertainty:g}, {1 + self.uncertainty:g}] (continuous loop): "
                f"{quantity} certified in [{self.lower:.6f}, {self.upper:.6f}] (gap {self.gap:.2g}) at J_e + J_l = "
                f"{J:.4g} kg m^2, d_e + d_l = {d:.4g} N m s/rad, k_e = {k_e:.4g} N m/rad{where}; the vertices alone "
                f"gave {self.vertex_min:.6f}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (``worst_case_lower``, ``worst_case_upper``, ``worst_case_point``, ...)."""
        return {"worst_case_lower": self.lower, "worst_case_upper": self.upper, "worst_case_gap": self.gap,
                # the output's whole inertia and damping (environment and link), as the box scales them
                "worst_case_point": {"J_e_plus_J_l_kg_m2": self.point[0], "d_e_plus_d_l_N_m_s_per_rad": self.point[1],
                                     "k_e_N_m_per_rad": self.point[2]},
                "worst_case_factors": {"J": self.factors[0], "d": self.factors[1], "k_e": self.factors[2]},
                "vertex_min": self.vertex_min, "uncertainty": self.uncertainty, "boxes": self.boxes,
                "converged": self.converged, "tolerance": self.tolerance,
                "method": "branch and bound over the (J, d, k_e) box; frequency-wise Moebius bound "
                          "(lower), exact disk margin of the worst environment found (upper)"}


def scaled_environment(design: Design, factors: tuple[float, float, float]) -> Design:
    """The design with its environment's J (J_e and J_l), d (d_e and d_l) and k_e scaled.

    Parameters
    ----------
    design : Design
        The nominal true design (environment not locked).
    factors : (float, float, float)
        Factors of J, d and k_e [-].

    Returns
    -------
    Design
        The scaled design, as :func:`forecast_design.tuning.environment_set` scales a vertex.
    """
    fj, fd, fk = (float(f) for f in factors)
    env = design.environment
    return dataclasses.replace(design, environment=dataclasses.replace(
        env, J_e=env.J_e * fj, J_l=env.J_l * fj, d_e=env.d_e * fd, d_l=env.d_l * fd, k_e=env.k_e * fk))


def _segment_extrema(A, B, C, D, E0, h) -> tuple[np.ndarray, np.ndarray]:
    """max and min over t in [0, 1] of |(A E + B) / (C E + D)|^2 with E = E0 + t h (arrays over w)."""
    al, be, ga, de = A * E0 + B, A * h, C * E0 + D, C * h
    n0, n1, n2 = np.abs(al) ** 2, 2.0 * np.real(al * np.conj(be)), np.abs(be) ** 2
    d0, d1, d2 = np.abs(ga) ** 2, 2.0 * np.real(ga * np.conj(de)), np.abs(de) ** 2
    # (N/D)' = 0: N'D - ND' is a quadratic (the cubic terms cancel)
    q2, q1, q0 = n2 * d1 - n1 * d2, 2.0 * (n2 * d0 - n0 * d2), n1 * d0 - n0 * d1
    with np.errstate(all="ignore"):
        disc = np.sqrt(np.maximum(q1 * q1 - 4.0 * q2 * q0, 0.0))
        lin = np.abs(q2) <= 1e-14 * (np.abs(q1) + np.abs(q0))
        r1 = np.where(lin, -q0 / q1, (-q1 + disc) / (2.0 * q2))
        r2 = np.where(lin, np.nan, (-q1 - disc) / (2.0 * q2))
        ts = np.stack([np.zeros_like(n0), np.ones_like(n0), r1, r2])
        ts = np.where((ts >= 0.0) & (ts <= 1.0), ts, np.nan)
        f = (n0 + n1 * ts + n2 * ts * ts) / (d0 + d1 * ts + d2 * ts * ts)
    return np.nanmax(f, axis=0), np.nanmin(f, axis=0)


def _rectangle_extrema(coef: np.ndarray, x_lo, x_hi, y_lo, y_hi) -> tuple[np.ndarray, np.ndarray]:
    """max and min of |G| over the rectangle [x_lo, x_hi] + j [y_lo, y_hi] at each frequency."""
    A, B, C, D = coef
    # the four edges at once (rows): bottom, top, left, right
    E0 = np.stack([x_lo + 1j * y_lo, x_lo + 1j * y_hi, x_lo + 1j * y_lo, x_hi + 1j * y_lo])
    h = np.stack([(x_hi - x_lo) + 0j, (x_hi - x_lo) + 0j, 1j * (y_hi - y_lo), 1j * (y_hi - y_lo)])
    hi, lo = _segment_extrema(A, B, C, D, E0, h)
    big, small = np.sqrt(np.max(hi, axis=0)), np.sqrt(np.min(lo, axis=0))
    with np.errstate(all="ignore"):
        pole, zero = -D / C, -B / A

    def inside(z):
        return (z.real >= x_lo) & (z.real <= x_hi) & (z.imag >= y_lo) & (z.imag <= y_hi)

    big = np.where(inside(pole) | ~np.isfinite(big), np.inf, big)
    small = np.where(inside(zero), 0.0, small)
    return big, small


class _Problem:
    """The loop family of one box: its Moebius coefficients on a grid and exact margins at points."""

    def __init__(self, design: Design, compensator: Compensator | None, controller: Any, believed: Design,
                 break_at: str, sigma: float) -> None:
        self.design, self.compensator, self.controller = design, compensator, controller
        self.believed, self.break_at, self.sigma = believed, break_at, sigma
        env = design.environment
        self.J0, self.d0, self.k0 = env.J_e + env.J_l, env.d_e + env.d_l, env.k_e
        self.w = np.logspace(-2.0, 5.0, 281)
        self.coef = np.zeros((4, 0), dtype=complex)
        self.certified_fit = True

    def loop(self, factors):
        return force_loop(scaled_environment(self.design, factors), self.compensator, controller=self.controller,
                          believed=self.believed, break_at=self.break_at)

    def alpha(self, factors) -> tuple[float, float]:
        """Exact disk margin [-] and its peak frequency [rad/s] of the environment at ``factors``."""
        fl = self.loop(factors)
        m = disk_margin(fl.L, skew=self.sigma, closed_loop_stable=fl.stable)
        return float(m.alpha), float(m.frequency_rad_s)

    def fit(self, extra_w: list[float]) -> None:
        """The four loops the Moebius map is fitted from (three) and checked at (one), and the grid."""
        self.fit_loops = [(self.loop(f).L, f) for f in (*_FIT_POINTS, _CHECK_POINT)]
        self.w = np.unique(np.concatenate([self.w, [x for x in extra_w if math.isfinite(x) and x > 0.0]]))
        self.coef = self.coefficients(self.w)

    def coefficients(self, w: np.ndarray) -> np.ndarray:
        """Moebius coefficients (A, B, C, D) of G = S + (sigma - 1)/2 = (A E + B)/(C E + D) at ``w`` [rad/s]."""
        s = 1j * w
        c0 = (self.sigma - 1.0) / 2.0
        E, G = [], []
        for L, f in self.fit_loops:
            num, den = np.polyval(L.num, s), np.polyval(L.den, s)
            G.append(den / (den + num) + c0)
            E.append(f[2] * self.k0 - f[0] * self.J0 * w * w + 1j * f[1] * self.d0 * w)
        # (A E + B) - G (C E + D) = 0 at three points: the null vector of a 3 x 4 matrix per frequency
        M = np.stack([np.stack([E[i], np.ones_like(E[i]), -G[i] * E[i], -G[i]], axis=-1) for i in range(3)], axis=1)
        _, _, vh = np.linalg.svd(M)
        coef = np.conj(vh[:, -1, :]).T                     # (4, n_w)
        A, B, C, D = coef
        with np.errstate(all="ignore"):
            check = (A * E[3] + B) / (C * E[3] + D)
            err = np.abs(check - G[3]) / np.maximum(np.abs(G[3]), 1e-300)
        if not np.all(err <= _FIT_RTOL):
            self.certified_fit = False
        return coef

    def _envelope(self, box: np.ndarray, w: np.ndarray, coef: np.ndarray, which: int = 0) -> np.ndarray:
        (fj_lo, fj_hi), (fd_lo, fd_hi), (fk_lo, fk_hi) = box
        w2 = w * w
        return _rectangle_extrema(coef, fk_lo * self.k0 - fj_hi * self.J0 * w2, fk_hi * self.k0 - fj_lo * self.J0 * w2,
                                  fd_lo * self.d0 * w, fd_hi * self.d0 * w)[which]

    def upper_bound(self, box: np.ndarray) -> float:
        """1 / max over the grid of min |G| over the box's rectangle: no loop of the box has a larger
        disk margin [-] (inf when |G| can vanish everywhere)."""
        env = self._envelope(box, self.w, self.coef, which=1)
        peak = float(np.max(env))
        return math.inf if peak <= 0.0 else 1.0 / peak

    def lower_bound(self, box: np.ndarray) -> float:
        """1 / max over frequency of max |G| over the box's rectangle of E(jw) [-].

        The maximum over frequency: the grid, then two zooms of 64 points between the neighbours
        of each of the two largest grid values (a 1e-5 relative step in w at the end: the value is
        within ~1e-9 of the envelope's peak, and the bound is lowered by _ZOOM_SLACK to cover it).
        """
        env = self._envelope(box, self.w, self.coef)
        if not np.all(np.isfinite(env)):
            return 0.0
        peak = float(np.max(env))
        for i in np.argsort(env)[-2:]:
            lo, hi = math.log(self.w[max(i - 1, 0)]), math.log(self.w[min(i + 1, self.w.size - 1)])
            for _ in range(2):
                pts = np.exp(np.linspace(lo, hi, 64))
                vals = self._envelope(box, pts, self.coefficients(pts))
                if not np.all(np.isfinite(vals)):
                    return 0.0
                j = int(np.argmax(vals))
                peak = max(peak, float(vals[j]))
                lo, hi = math.log(pts[max(j - 1, 0)]), math.log(pts[min(j + 1, pts.size - 1)])
        # the limits w -> 0 and w -> infinity of |G| are those of the vertices (checked exactly)
        return 0.0 if peak <= 0.0 else (1.0 - _ZOOM_SLACK) / peak


def worst_case_disk_margin(design: Design, compensator: Compensator | None = None, *, controller: Any = None,
                           uncertainty: float = 0.1, believed: Design | None = None, skew: float = 0.0,
                           break_at: str = "controller", tolerance: float = 1e-3,
                           max_boxes: int = 400) -> WorstCaseMargin:
    """Worst-case disk margin over the box [1 - u, 1 + u]^3 of the true J, d and k_e, with certified bounds.

    Parameters
    ----------
    design : Design
        The nominal true testbed and environment (not locked: a locked output has no J, d, k_e).
    compensator : Compensator or None
        The compensator (the observer keeps believing ``believed``).
    controller : Controller, str or None
        The force controller; None takes ``design.controller`` (the paper's PD if unset).
    uncertainty : float
        Relative half-width u of the box, 0 < u < 1 [-].
    believed : Design or None
        What the observer believes; None: the nominal ``design``.
    skew : float
        Skew sigma of the disk [-].
    break_at : str
        ``controller`` or ``plant-input``.
    tolerance : float
        Relative gap ``(upper - lower) / upper`` at which to stop [-].
    max_boxes : int
        Budget of sub-boxes; the bounds reached are returned (``converged`` False) when it runs out.

    Returns
    -------
    WorstCaseMargin
        Lower and upper bounds, the worst point and the vertex answer for comparison.

    Raises
    ------
    ParameterError
        A locked environment, ``u`` outside (0, 1), a non-positive tolerance or budget.

    Examples
    --------
    >>> from forecast_design import Compensator, Design
    >>> r = worst_case_disk_margin(Design.nominal("soft"), Compensator(kind="lo-dob", w_q_hz=2.0),
    ...                            uncertainty=0.5)
    >>> r.lower <= r.upper <= r.vertex_min
    True
    """
    problems = _problems(design, compensator, controller, believed, break_at, skew, uncertainty, tolerance, max_boxes)
    return _branch_and_bound(problems, float(uncertainty), float(tolerance), int(max_boxes), ratio=False)


def worst_case_ratio(design: Design, compensator: Compensator, *, controller: Any = None, uncertainty: float = 0.1,
                     believed: Design | None = None, skew: float = 0.0, break_at: str = "controller",
                     tolerance: float = 1e-3, max_boxes: int = 400) -> WorstCaseMargin:
    """Worst case over the box of the margin ratio alpha(compensated) / alpha(plant alone), with certified bounds.

    The ratio ``tune-q`` requires (both loops see the same true environment). The lower bound of
    a box is its compensated loop's margin bound divided by the largest margin the plant-alone
    loop can have there (from the smallest |G| over each frequency's rectangle).

    Parameters
    ----------
    design, compensator, controller, uncertainty, believed, skew, break_at, tolerance, max_boxes
        As :func:`worst_case_disk_margin`.

    Returns
    -------
    WorstCaseMargin
        Bounds on the worst ratio (``lower``, ``upper``), its point, the vertex answer.

    Raises
    ------
    ParameterError
        As :func:`worst_case_disk_margin`.
    """
    obs = _problems(design, compensator, controller, believed, break_at, skew, uncertainty, tolerance, max_boxes)
    plant = _problems(design, None, controller, believed, break_at, skew, uncertainty, tolerance, max_boxes)
    return _branch_and_bound(obs + plant, float(uncertainty), float(tolerance), int(max_boxes), ratio=True)


def _problems(design, compensator, controller, believed, break_at, skew, uncertainty, tolerance,
              max_boxes) -> list[_Problem]:
    if design.environment.locked:
        raise ParameterError("a locked output has no J, d, k_e to be uncertain about: drop --uncertainty",
                             name="uncertainty", value=uncertainty)
    if not (0.0 < float(uncertainty) < 1.0):
        raise ParameterError(f"uncertainty must be in (0, 1), got {uncertainty!r}", name="uncertainty",
                             value=uncertainty)
    if not (tolerance > 0.0) or int(max_boxes) < 1:
        raise ParameterError(f"tolerance must be > 0 and max_boxes >= 1, got {tolerance!r}, {max_boxes!r}",
                             name="tolerance", value=tolerance)
    sigma = check_skew(skew)
    controller = controller if controller is not None else design.controller
    if controller is None:
        from .controllers import PAPER_PD
        controller = PAPER_PD
    return [_Problem(design, compensator, controller, believed if believed is not None else design, break_at, sigma)]


def _branch_and_bound(problems: list[_Problem], u: float, tolerance: float, max_boxes: int, *,
                      ratio: bool) -> WorstCaseMargin:
    """Minimise alpha (one problem) or alpha_0 / alpha_1 (two) over the box [1 - u, 1 + u]^3."""

    def value(f) -> tuple[float, float]:
        a, w_peak = problems[0].alpha(f)
        if not ratio:
            return a, w_peak
        b, _ = problems[1].alpha(f)
        return (a / b if b > 0.0 else math.inf), w_peak

    def bound(box) -> float:
        lb = problems[0].lower_bound(box)
        if not ratio:
            return lb
        ub = problems[1].upper_bound(box)
        return 0.0 if not math.isfinite(ub) else lb / ub

    peaks: list[float] = []
    best = (math.inf, (1.0, 1.0, 1.0))
    for f in [(1.0, 1.0, 1.0), *itertools.product((1 - u, 1 + u), repeat=3)]:
        a, w_peak = value(f)
        peaks.append(w_peak)
        best = min(best, (a, tuple(f)))
    vertex_min = best[0]
    for problem in problems:
        problem.fit(peaks)
    root = np.array([[1 - u, 1 + u]] * 3)
    heap = [(bound(root), 0, root)]
    counter = boxes = 1
    while heap:
        lb, _, box = heap[0]
        if best[0] - lb <= tolerance * best[0] or boxes >= max_boxes:
            break
        heapq.heappop(heap)
        k = int(np.argmax(np.log(box[:, 1] / box[:, 0])))
        mid = math.sqrt(box[k, 0] * box[k, 1])
        for half in ((box[k, 0], mid), (mid, box[k, 1])):
            child = box.copy()
            child[k] = half
            centre = tuple(float(math.sqrt(a * b)) for a, b in child)
            best = min(best, (value(centre)[0], centre))
            heapq.heappush(heap, (bound(child), counter, child))
            counter += 1
            boxes += 1
    lower = min([entry[0] for entry in heap] + [best[0]])
    if not all(problem.certified_fit for problem in problems):
        lower = 0.0      # the Moebius fit failed its check at some frequency: no certificate
    fj, fd, fk = best[1]
    p0 = problems[0]
    upper = best[0]
    return WorstCaseMargin(lower=float(lower), upper=float(upper), point=(fj * p0.J0, fd * p0.d0, fk * p0.k0),
                           factors=(fj, fd, fk), vertex_min=float(vertex_min), uncertainty=u, boxes=boxes,
                           converged=bool(upper - lower <= tolerance * upper), tolerance=tolerance)
