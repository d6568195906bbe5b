"""The paper's Table 3 (Section 7) on the virtual testbed: repeatability and fidelity of step responses.

Library side of ``forecast-design reproduce table3`` (re-exported by
:mod:`forecast_design.reproduce`); the figure is drawn by
:func:`~forecast_design.plotting.simulation.plot_table3`.

Ten 0.2 N m step responses per cell, each from a different random absolute
motor angle (:class:`~forecast_design.simulation.scenario.Variability`), on
hardware whose stiction level and Stribeck curve depend on the angle (LuGre with
F_s and ln v_s harmonics, :data:`TABLE3_TRUTH`), with angle-periodic Coulomb
friction and cogging (Section 2, Figs. 2c and 3), in the
``exp-soft`` and ``locked`` environments, with PD alone, PD + extended SFM
and PD + EA-FOB (10 Hz). The extended SFM is *identified* with
:func:`forecast_design.friction.identify` (model ``extended-sfm``, N = 4)
from a simulated open-loop identification run of the same hardware, never
copied from the truth. Metrics per cell:

* ``xcorr``: mean over the 45 pairs of responses of the zero-lag normalised
  cross-correlation of the mean-removed responses (Pearson's r of tau_s over
  the run). Zero lag, so a delayed response counts as less repeatable. Section 7
  defines no more than "mean cross-correlation among step responses"; the other
  readings (:data:`XCORR_MODES`: best lag, means kept) are a parameter and are all
  reported. Keeping the means gives >= 0.99 to any settling step response (PD alone
  in the soft environment included, paper 0.73), so the paper's numbers imply the
  means removed.
* ``mae``: mean over the ten runs of the MAE [N m] between the measured
  tau_s and the frictionless response: the same PD on the nominal plant with
  no friction at all (no effects and d_m = 0), no compensator, no noise
  ("how the system would perform in the absence of friction").
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from .effects import Backlash, Cogging, PositionFriction, Stiction
from .environments import resolve_environments
from .errors import ParameterError
from .controllers import DERIVATIVE_ON, PD
from .params import Compensator, Design, Testbed

__all__ = [
    "PAPER_TABLE3",
    "TABLE3_TRUTH",
    "TABLE3_SFM_DEADBAND",
    "TABLE3_DERIVATIVE_ON",
    "table3_controller",
    "TABLE3_PLAY_PROBE",
    "Table3Row",
    "Table3Result",
    "reproduce_table3",
    "pairwise_xcorr",
    "pairwise_xcorr_se",
    "pairwise_xcorr_per_run",
    "xcorr_se_from_per_run",
    "XCORR_MODES",
    "identify_extended_sfm",
]

#: Control rate of the testbed's board [Hz] (Section 7: 2 kHz).
_RATE = 2000.0

#: The paper's Table 3: (environment, compensator) -> (mean cross-correlation [-], MAE [N m]).
PAPER_TABLE3: Mapping[tuple[str, str], tuple[float, float]] = {
    ("exp-soft", "none"): (0.73, 0.04), ("exp-soft", "sfm"): (0.98, 0.05), ("exp-soft", "ea-fob"): (0.99, 0.008),
    ("locked", "none"): (0.90, 0.02), ("locked", "sfm"): (0.99, 0.02), ("locked", "ea-fob"): (0.99, 0.01),
}

#: Hardware of the Table 3 reproduction (Section 2, Fig. 2c: the stiction level and the Stribeck
#: curve depend on the motor angle; angle-periodic friction ripple). LuGre with Table 2's F_c,
#: sigma1, sigma2, a static level F_s(theta) = 0.7 N m with harmonics of 0.18 and 0.072 N m (0.45 to
#: 0.90 N m: above ~0.75 N m the PD's 1 N m command for the 0.2 N m step hardly breaks it) and a
#: Stribeck velocity v_s(theta) = 0.05 rad/s exp(+-1.2 ...) (about 0.01 to 0.3 rad/s: sharp
#: breakaway at some angles, a wide negative-slope region, i.e. stick-slip, at others);
#: position-dependent Coulomb 0.1 +- 0.09 and a small cogging [N m]. The bristle stiffness is
#: 30000 N m/rad, a presliding range F_s / sigma0 of 23 urad as in rolling bearings: Table 2's
#: 260 N m/rad (the paper's *simulation*, Section 6) makes it 2.7 mrad, as large as the whole
#: deflection of a 0.2 N m step into the locked output (tau/k = 3.4 mrad), which then only strains
#: the bristles like a second spring and leaves every run's response the same shape.
TABLE3_TRUTH: tuple = (
    Stiction(F_s=0.7, F_s_a=(0.18, 0.072), F_s_b=(0.0, 0.048), v_s=0.05, v_s_a=(1.2, 0.4), v_s_b=(0.5, 0.0),
             sigma0=30000.0),
    PositionFriction(F_c=0.1, a=(0.04, 0.02), b=(0.02, 0.01)),
    Cogging(a=(0.01, 0.0, 0.0, 0.005), b=(0.0, 0.01, 0.0, 0.0)),
)


#: Dead band of the Table 3 SFM's sign(theta') [rad/s]. The paper prints a plain sign(); on an
#: encoder-differentiated velocity that drives a stick-slip limit cycle whenever the motor stops
#: (run-to-run phase differences; the sensitivity rows), which the testbed's SFM (x-corr 0.98 /
#: 0.99) evidently did not have; 0.01 rad/s removes it and still compensates the few mrad/s of
#: a step into the locked output (0.1 rad/s would not: sensitivity rows).
TABLE3_SFM_DEADBAND = 0.01

#: Where the board's PD takes its derivative in the Table 3 reproduction (``simulate``'s
#: ``derivative_on``): ``measurement``, u = P (tau_r - tau_s) - D d tau_s/dt (no derivative kick
#: at the step), or ``error``, the
#: format's u = P e + D de/dt, whose kick at a 0.2 N m step (an impulse D x 0.2 = 0.02 N m s, one
#: period of ~25 N m through the 200 Hz derivative filter) throws the motor past any stiction
#: level and makes every run rise alike. Section 7 does not say; ``measurement`` is the common
#: implementation of a PD on a stepped reference, and the other reading is reported too.
TABLE3_DERIVATIVE_ON = "measurement"

#: The derivative filter of the board's PD in the reproduction [Hz] (T_f = 1/(2 pi 200 Hz), Tustin):
#: the filtered PD every Table 3 figure in benchmarks/RESULTS.md was measured with.
TABLE3_DERIVATIVE_CUTOFF_HZ = 200.0


def table3_controller(derivative_on: str = TABLE3_DERIVATIVE_ON) -> PD:
    """The board's PD of the Table 3 reproduction: P = 5, D = 0.1, a 200 Hz derivative filter, Tustin.

    Parameters
    ----------
    derivative_on : str
        ``measurement`` (the reproduction's reading) or ``error``.

    Returns
    -------
    PD
        The controller (its ``[controller]`` table says all of this in the simulated logs).
    """
    return PD(P=5.0, D=0.1, T_f=1.0 / (2.0 * math.pi * TABLE3_DERIVATIVE_CUTOFF_HZ), discretization="tustin",
              derivative_on=derivative_on)

#: Play [rad] of the Oldham couplings in the probe of ``Table3Result.mechanisms``: a source of
#: run-to-run spread the paper names (Section 2: shaft misalignment at the Oldham couplings),
#: with the coupling starting anywhere inside its play in each repetition
#: (:class:`~forecast_design.simulation.scenario.Variability` ``backlash_position = "random"``).
#: The paper gives no clearance; 2 mrad (7 arcmin) is a loose commercial Oldham coupling.
TABLE3_PLAY_PROBE = 2e-3


@dataclass(frozen=True, slots=True)
class Table3Row:
    """One cell pair of Table 3.

    Attributes
    ----------
    environment : str
        ``exp-soft`` or ``locked``.
    compensator : str
        ``none``, ``sfm`` or ``ea-fob``.
    xcorr : float
        Mean pairwise zero-lag normalised cross-correlation of the responses [-].
    mae : float
        Mean MAE to the frictionless response [N m].
    paper_xcorr, paper_mae : float or None
        The paper's values for the cell.
    xcorr_se : float or None
        Jackknife standard error of ``xcorr`` over the repetitions (:func:`pairwise_xcorr_se`) [-]:
        its spread under another draw of initial angles.
    mae_se : float or None
        Standard error of ``mae``, the runs' standard deviation / sqrt(repetitions) [N m].
    """

    environment: str
    compensator: str
    xcorr: float
    mae: float
    paper_xcorr: float | None = None
    paper_mae: float | None = None
    xcorr_se: float | None = None
    mae_se: float | None = None

    def to_mapping(self) -> dict[str, Any]:
        """``{"environment", "compensator", "xcorr", "mae", "paper_xcorr", "paper_mae"}``.

        ``mae_N_m``, ``paper_mae_N_m`` and ``mae_se_N_m`` repeat the MAE and its standard error with
        the unit [N m] in the name (``mae``/``paper_mae``/``mae_se`` stay for existing scripts);
        ``xcorr_se`` is the x-corr's standard error [-].
        """
        out = dataclasses.asdict(self)
        out["mae_N_m"], out["paper_mae_N_m"], out["mae_se_N_m"] = self.mae, self.paper_mae, self.mae_se
        return out


@dataclass(frozen=True, slots=True)
class Table3Result:
    """Table 3 on the virtual testbed; iterates over its rows like a list.

    Attributes
    ----------
    rows : tuple of Table3Row
        Environment x compensator.
    initial_angles : ndarray, shape (repetitions,)
        Absolute motor angle of each repetition [rad].
    sfm_params : dict
        Extended-SFM parameters identified from the simulated identification run.
    identification_fit_percent : float
        Fit of that identification [%].
    choices : dict
        Step amplitude [N m], duration [s], repetitions, seed, w_q_hz [Hz], truth effects.
    explanation : str
        Deviations from the paper and why.
    sensitivity : tuple of dict
        SFM cells recomputed with other sign() dead bands: ``environment``,
        ``compensator``, ``sfm_deadband`` [rad/s], ``xcorr`` [-], ``mae`` [N m].
    readings : tuple of dict
        Every cell's x-corr under each reading of :data:`XCORR_MODES`: ``environment``,
        ``compensator`` and one key per mode [-].
    mechanisms : tuple of dict
        Every cell recomputed with one choice changed (the PD's derivative on the other signal;
        the Oldham couplings' play added to the hardware): ``mechanism``, ``environment``,
        ``compensator``, ``xcorr`` [-], ``mae`` [N m].
    responses : dict
        ``(environment, compensator) -> list of SimulationResult`` (not in JSON).
    expected : dict
        ``environment -> SimulationResult`` of the frictionless PD (not in JSON).
    """

    rows: tuple
    initial_angles: np.ndarray
    sfm_params: Mapping[str, float]
    identification_fit_percent: float
    choices: Mapping[str, Any]
    explanation: str
    sensitivity: tuple = ()
    readings: tuple = ()
    mechanisms: tuple = ()
    responses: Mapping[tuple[str, str], Any] = field(default_factory=dict, repr=False, compare=False)
    expected: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def __iter__(self):
        return iter(self.rows)

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i):
        return self.rows[i]

    def row(self, environment: str, compensator: str) -> Table3Row:
        """The row of one cell."""
        for r in self.rows:
            if r.environment == environment and r.compensator == compensator:
                return r
        raise KeyError((environment, compensator))

    def to_mapping(self) -> list[dict[str, Any]]:
        """JSON of the ``reproduce table3`` verb: the list of rows (issue 5)."""
        return [r.to_mapping() for r in self.rows]

    def to_document(self) -> dict[str, Any]:
        """Rows plus provenance: ``{"rows", "choices", "sfm_params", "initial_angles", ..., "explanation"}``."""
        return {"rows": self.to_mapping(), "choices": dict(self.choices), "sfm_params": dict(self.sfm_params),
                "identification_fit_percent": self.identification_fit_percent,
                "initial_angles": [float(a) for a in self.initial_angles],
                "sensitivity": [dict(r) for r in self.sensitivity], "readings": [dict(r) for r in self.readings],
                "mechanisms": [dict(r) for r in self.mechanisms], "explanation": self.explanation}


#: Readings of the paper's "mean cross-correlation among step responses" (Section 7, Table 3),
#: which the paper does not define further. ``pearson`` (default): zero-lag normalised
#: cross-correlation of the mean-removed responses (Pearson's r); ``pearson-max-lag``: its maximum
#: over all lags (a delayed copy counts as repeatable); ``raw``: zero-lag normalised
#: cross-correlation without removing the means (MATLAB ``xcorr(x, y, 0, 'coeff')``).
XCORR_MODES = ("pearson", "pearson-max-lag", "raw")
_XCORR_DEFINITION = {
    "pearson": "mean over pairs of the zero-lag Pearson correlation of tau_s",
    "pearson-max-lag": "mean over pairs of the largest normalised cross-correlation of the mean-removed tau_s",
    "raw": "mean over pairs of the zero-lag normalised cross-correlation of tau_s, means kept",
}


def _pair_matrix(responses: np.ndarray, mode: str) -> np.ndarray:
    """The m x m matrix of one reading of the normalised cross-correlation between every two responses."""
    if mode not in XCORR_MODES:
        raise ParameterError(f"xcorr mode must be one of {', '.join(XCORR_MODES)}, got {mode!r}", name="xcorr",
                             value=mode)
    x = np.asarray(responses, dtype=float)
    if x.ndim != 2 or x.shape[0] < 2:
        raise ParameterError(f"pairwise_xcorr needs at least two responses as rows, got shape {x.shape}",
                             name="responses", value=x.shape)
    if mode == "pearson":
        return np.corrcoef(x)
    if mode == "raw":
        g = x @ x.T
        d = np.sqrt(np.diag(g))
        return g / np.outer(d, d)
    from scipy import signal

    xc = x - x.mean(axis=1, keepdims=True)
    norms = np.sqrt(np.sum(xc * xc, axis=1))
    m = x.shape[0]
    c = np.eye(m)
    for i, j in zip(*np.triu_indices(m, 1)):
        c[i, j] = c[j, i] = np.max(signal.correlate(xc[i], xc[j], mode="full", method="fft")) / (norms[i] * norms[j])
    return c


def pairwise_xcorr(responses: np.ndarray, mode: str = "pearson") -> float:
    """Mean normalised cross-correlation over all pairs of responses.

    Parameters
    ----------
    responses : ndarray, shape (m, n)
        One response per row [any unit], m >= 2.
    mode : str
        One of :data:`XCORR_MODES`. ``pearson``: ``sum (x_i - mean x_i)(x_j - mean x_j) /
        sqrt(sum (x_i - mean x_i)^2 sum (x_j - mean x_j)^2)`` (Pearson's r); ``pearson-max-lag``:
        the largest value of that normalised cross-correlation over all lags; ``raw``:
        ``sum x_i x_j / sqrt(sum x_i^2 sum x_j^2)`` (no mean removal).

    Returns
    -------
    float
        Mean over the pairs i < j [-].
    """
    c = _pair_matrix(responses, mode)
    return float(np.mean(c[np.triu_indices(c.shape[0], 1)]))


def pairwise_xcorr_per_run(responses: np.ndarray, mode: str = "pearson") -> np.ndarray:
    """Each run's mean normalised cross-correlation with the other repetitions [-].

    Parameters
    ----------
    responses : ndarray, shape (m, n)
        One response per row, m >= 2.
    mode : str
        Reading, one of :data:`XCORR_MODES`.

    Returns
    -------
    ndarray, shape (m,)
        Its mean equals :func:`pairwise_xcorr` of the set.
    """
    c = _pair_matrix(responses, mode)
    return (np.sum(c, axis=1) - np.diag(c)) / (c.shape[0] - 1)


def xcorr_se_from_per_run(per_run: np.ndarray) -> float:
    """Jackknife standard error of the mean pairwise x-corr from each run's mean correlation [-].

    Leaving run i out removes its m - 1 pairs, so the leave-one-out means are
    ``(m R - 2 r_i) / (m - 2)`` (``R`` the set's value, ``r_i`` run i's mean correlation with
    the others) and the jackknife ``sqrt((m - 1)/m sum (R_(i) - mean)^2)`` reduces to
    ``2 / (m - 2) sqrt((m - 1)/m sum (r_i - mean r)^2)``. Linear in ``r``, so the difference of
    two sets run from the same initial conditions takes ``r_i - r'_i``.

    Parameters
    ----------
    per_run : ndarray, shape (m,)
        :func:`pairwise_xcorr_per_run` (or a paired difference of two), m >= 3.

    Returns
    -------
    float
        Standard error [-]; NaN when fewer than three runs are finite.
    """
    r = np.asarray(per_run, dtype=float)
    r = r[np.isfinite(r)]
    m = r.size
    if m < 3:
        return math.nan
    return float(2.0 / (m - 2) * math.sqrt((m - 1) / m * np.sum((r - r.mean()) ** 2)))


def pairwise_xcorr_se(responses: np.ndarray, mode: str = "pearson", *, paired_with: np.ndarray | None = None
                      ) -> float:
    """Jackknife standard error of :func:`pairwise_xcorr` over the repetitions [-].

    The mean pairwise correlation is a U-statistic of the m repetitions; leaving each repetition
    out in turn (its m - 1 pairs) gives the jackknife estimate of its sampling standard error
    (Arvesen 1969; :func:`xcorr_se_from_per_run`): how much the value would move with another
    draw of initial angles. Measured on synthetic step responses with ten repetitions (tests): its
    mean is 0.97 of the statistic's actual spread, but +-1.96 standard errors cover the true mean
    only ~86 % of the time (the estimate from ten runs is itself uncertain and a correlation
    bounded by 1 is skewed): read it as a scale, and use about +-2.3 for a 90 % statement.

    Parameters
    ----------
    responses : ndarray, shape (m, n)
        One response per row, m >= 3.
    mode : str
        Reading, one of :data:`XCORR_MODES`.
    paired_with : ndarray, shape (m, n'), optional
        A second set run from the same m initial conditions (row i with row i): the standard
        error of the *difference* ``pairwise_xcorr(responses) - pairwise_xcorr(paired_with)``,
        whose shared draw of angles cancels.

    Returns
    -------
    float
        Standard error [-].
    """
    r = pairwise_xcorr_per_run(responses, mode)
    if r.size < 3:
        raise ParameterError(f"a jackknife standard error needs at least three repetitions, got {r.size}",
                             name="responses", value=r.size)
    if paired_with is not None:
        r2 = pairwise_xcorr_per_run(paired_with, mode)
        if r2.size != r.size:
            raise ParameterError(f"paired_with needs the same {r.size} repetitions, got {r2.size}",
                                 name="paired_with", value=r2.size)
        r = r - r2
    return xcorr_se_from_per_run(r)


def _identification_profile(levels: Sequence[float], hold_s: float, ramp_s: float = 0.2):
    from .simulation import PiecewiseLinear

    times, values = [], []
    for i, level in enumerate(levels):
        times += [i * hold_s, i * hold_s + ramp_s, (i + 1) * hold_s - ramp_s]
        values += [0.0, float(level), float(level)]
    times.append(len(levels) * hold_s)
    values.append(0.0)
    return PiecewiseLinear(times_s=tuple(times), values=tuple(values))


def identify_extended_sfm(effects: Sequence[Any] = TABLE3_TRUTH, *, seed: int = 0, hold_s: float = 5.0,
                          testbed: Testbed | None = None) -> tuple[dict[str, float], Any, Any]:
    """Identify the paper's extended SFM on a simulated open-loop run of the hardware.

    The free link (``link-only``) is driven by a staircase of motor torques
    (+-0.8, +-1.2, +-1.6 N m, each held ``hold_s``), turning the motor over
    about two revolutions: enough for three viscous levels, both directions
    and the angle harmonics. :func:`forecast_design.friction.identify` fits
    ``viscous``, ``coulomb`` and 4 angle harmonics to ``tau_m - J_m theta'' -
    tau_s`` from the measured (quantised) signals only.

    Parameters
    ----------
    effects : sequence of effect parameter values
        The hardware (default :data:`TABLE3_TRUTH`).
    seed : int
        Process-noise seed.
    hold_s : float
        Duration of each torque level [s].
    testbed : Testbed, optional
        The SEA (default the paper's Table 1).

    Returns
    -------
    params : dict
        Identified parameters (``viscous`` [N m s/rad], ``coulomb``, ``sin<i>``, ``cos<i>`` [N m]).
    fit : FrictionFit
        The identification result.
    run : SimulationResult
        The identification run (homed at absolute angle 0).

    Notes
    -----
    Deterministic and seconds long: the last four are kept in this process (reproduce_table3 and
    a benchmark's SFM ask for the same one) and returned again, the same ``fit`` and ``run``.
    """
    try:
        hash(key := (tuple(effects), seed, hold_s, testbed))
    except TypeError:            # effects or testbed not hashable: not kept
        key = None
    params, fit, run = (_identify_extended_sfm_kept(*key) if key is not None
                        else _identify_extended_sfm(effects, seed, hold_s, testbed))
    return dict(params), fit, run


def _identify_extended_sfm(effects, seed, hold_s, testbed):
    from .friction import identify
    from .simulation import simulate
    from .simulation.plant import stable_substeps

    levels = (0.8, 1.2, 1.6, -0.8, -1.2, -1.6)
    profile = _identification_profile(levels, hold_s)
    design = Design.nominal("link-only") if testbed is None else Design.nominal("link-only", testbed=testbed)
    run = simulate(design, reference=profile, duration_s=len(levels) * hold_s,
                   substeps=stable_substeps(design, effects, rate_hz=_RATE),
                   closed_loop=False, effects=effects, seed=seed, rate_hz=_RATE,
                   description="reproduce table3: extended-SFM identification run")
    fit = identify(run.to_experiment(), "extended-sfm")
    return {k: float(v) for k, v in fit.params.items()}, fit, run


_identify_extended_sfm_kept = functools.lru_cache(maxsize=4)(_identify_extended_sfm)


def reproduce_table3(*, repetitions: int = 10, amplitude: float = 0.2, duration_s: float = 1.0, seed: int = 0,
                     w_q_hz: float = 10.0, environments: Any = ("exp-soft", "locked"),
                     effects: Sequence[Any] = TABLE3_TRUTH, sfm_deadband: float = TABLE3_SFM_DEADBAND,
                     sensitivity: Sequence[float] = (0.0, 0.002, 0.1), xcorr: str = "pearson",
                     play_probe_rad: float | None = TABLE3_PLAY_PROBE,
                     derivative_on: str = TABLE3_DERIVATIVE_ON) -> Table3Result:
    """Reproduce the paper's Table 3 (repeatability and fidelity of step responses) in simulation.

    Parameters
    ----------
    repetitions : int
        Step responses per cell, each from its own random absolute motor
        angle, uniform in [0, 2 pi) [-] (>= 2; standard errors from 3).
    amplitude : float
        Step reference [N m].
    duration_s : float
        Length of each response [s].
    seed : int
        Seed of the initial angles and of the process noise.
    w_q_hz : float
        EA-FOB Q cutoff [Hz].
    environments : str, Environment, EnvironmentSet, path or sequence
        The environments (paper: ``exp-soft`` and ``locked``), in any form
        :func:`~forecast_design.environments.resolve_environments` accepts; rows carry the set's names.
    effects : sequence of effect parameter values
        The hardware (default :data:`TABLE3_TRUTH`).
    sfm_deadband : float
        Dead band of the SFM's sign(theta') [rad/s] (default :data:`TABLE3_SFM_DEADBAND`); 0 is
        the printed formula's plain sign.
    sensitivity : sequence of float
        Further SFM dead bands [rad/s] whose SFM cells are recomputed for
        ``Table3Result.sensitivity`` (empty: none).
    xcorr : str
        Reading of the paper's "mean cross-correlation" used for the rows, one of
        :data:`XCORR_MODES` (default ``pearson``: zero-lag, means removed; the only reading under
        which the paper's soft-environment PD value 0.73 is reachable at all, since ``raw`` gives
        >= 0.99 to every step response that settles). Every reading is reported in
        ``Table3Result.readings``.
    play_probe_rad : float or None
        Width [rad] of the Oldham-coupling play added in the mechanism probe
        (``Table3Result.mechanisms``, default :data:`TABLE3_PLAY_PROBE`); None: no probe.
    derivative_on : str
        Where the PD takes its derivative, one of
        :data:`~forecast_design.controllers.DERIVATIVE_ON` (default
        :data:`TABLE3_DERIVATIVE_ON`); the frictionless reference uses the same PD. Every cell is
        also recomputed with the other choice (``Table3Result.mechanisms``).

    Returns
    -------
    Table3Result
        Rows ``{"environment", "compensator", "xcorr", "mae"}`` (plus the
        paper's values and standard errors), responses, the identified SFM and the explanation.
    """
    from .simulation import Step, simulate

    from .simulation.scenario import Variability

    if isinstance(repetitions, bool) or not isinstance(repetitions, int) or repetitions < 2:
        raise ParameterError(f"table3 repetitions must be an integer >= 2, got {repetitions!r}",
                             name="repetitions", value=repetitions)
    if xcorr not in XCORR_MODES:
        raise ParameterError(f"table3 xcorr must be one of {', '.join(XCORR_MODES)}, got {xcorr!r}", name="xcorr",
                             value=xcorr)
    if derivative_on not in DERIVATIVE_ON:
        raise ParameterError(f"table3 derivative_on must be one of {', '.join(DERIVATIVE_ON)}, got "
                             f"{derivative_on!r}", name="derivative_on", value=derivative_on)
    if play_probe_rad is not None and not (isinstance(play_probe_rad, (int, float)) and
                                           not isinstance(play_probe_rad, bool) and 0.0 < play_probe_rad < 0.1):
        raise ParameterError(f"table3 play_probe_rad must be a width in (0, 0.1) rad or None, got "
                             f"{play_probe_rad!r}", name="play_probe_rad", value=play_probe_rad)
    angles = Variability(repetitions=repetitions, seed=seed).initial_angles()
    sfm_params, fit, _ = identify_extended_sfm(effects, seed=seed)
    pds = {on: table3_controller(on) for on in DERIVATIVE_ON}
    ref = Step(amplitude=amplitude)
    envset = resolve_environments(environments)      # presets, inline values, files, Environment objects
    environments, env_of = envset.names, dict(envset.items())
    expected = {}
    references: dict[tuple[str, str], Any] = {}      # (environment, derivative_on) -> frictionless run

    def frictionless(env: str, on: str):
        if (env, on) not in references:
            references[(env, on)] = simulate(
                Design(environment=env_of[env], controller=pds[on]), reference=ref, duration_s=duration_s, rate_hz=_RATE,
                include_nominal_viscous=False, process_noise_std=0.0, encoder_counts=None,
                description=f"reproduce table3: {env}, frictionless PD")
        return references[(env, on)]

    def cell(env: str, kind: str, *, on: str = derivative_on, deadband: float = sfm_deadband,
             play: Any = None, keep: bool = False):
        comp = Compensator(kind=kind, w_q_hz=w_q_hz) if kind == "ea-fob" else Compensator(kind=kind)
        design = Design(environment=env_of[env], controller=pds[on], compensator=comp)
        runs = [simulate(design, reference=ref, duration_s=duration_s, rate_hz=_RATE,
                         effects=tuple(effects) if play is None else play.effects_of(
                             tuple(effects) + (Backlash(width_rad=float(play_probe_rad)),), i),
                         initial_angle=float(a), seed=seed + 1 + i,
                         sfm_params=sfm_params if kind == "sfm" else None, sfm_deadband=float(deadband),
                         description=f"reproduce table3: {env}, {kind}, run {i}" if keep else "")
                for i, a in enumerate(angles)]
        ref_tau = frictionless(env, on).tau_s
        tau = np.array([r.tau_s for r in runs])
        return runs, tau, np.mean(np.abs(tau - ref_tau), axis=1)

    rows, responses, readings = [], {}, []
    for env in environments:
        expected[env] = frictionless(env, derivative_on)
        for kind in ("none", "sfm", "ea-fob"):
            runs, tau, mae_runs = cell(env, kind, keep=True)
            responses[(env, kind)] = runs
            paper = PAPER_TABLE3.get((env, kind), (None, None))
            se = (pairwise_xcorr_se(tau, xcorr), float(np.std(mae_runs, ddof=1) / math.sqrt(repetitions))) \
                if repetitions >= 3 else (None, None)
            rows.append(Table3Row(env, kind, pairwise_xcorr(tau, xcorr), float(np.mean(mae_runs)), paper[0], paper[1],
                                  *se))
            readings.append({"environment": env, "compensator": kind,
                             **{mode: pairwise_xcorr(tau, mode) for mode in XCORR_MODES}})
    sens = []
    for db in sensitivity:
        for env in environments:
            _, tau, mae_runs = cell(env, "sfm", deadband=db)
            sens.append({"environment": env, "compensator": "sfm", "sfm_deadband": float(db),
                         "xcorr": pairwise_xcorr(tau, xcorr), "mae": float(np.mean(mae_runs))})
    mechanisms = []
    other = next(o for o in DERIVATIVE_ON if o != derivative_on)
    probes = [(f"PD derivative on the {other}", {"on": other})]
    if play_probe_rad is not None:
        # the couplings' play, each repetition starting elsewhere inside it (Variability)
        probes.append((f"oldham play {1e3 * play_probe_rad:g} mrad, random start",
                       {"play": Variability(repetitions=repetitions, seed=seed, backlash_position="random")}))
    for name, kw in probes:
        for env in environments:
            for kind in ("none", "sfm", "ea-fob"):
                _, tau, mae_runs = cell(env, kind, **kw)
                mechanisms.append({"mechanism": name, "environment": env, "compensator": kind,
                                   "xcorr": pairwise_xcorr(tau, xcorr), "mae": float(np.mean(mae_runs))})
    choices = {"repetitions": repetitions, "amplitude": amplitude, "duration_s": duration_s, "seed": seed,
               "w_q_hz": w_q_hz, "environments": list(environments), "sfm_deadband": float(sfm_deadband),
               "derivative_on": derivative_on, "effects": [e.to_mapping() for e in effects],
               "xcorr": xcorr, "play_probe_rad": play_probe_rad,
               "xcorr_definition": _XCORR_DEFINITION[xcorr],
               "mae": "mean over runs of mean |tau_s - tau_s(frictionless PD, d_m = 0, no noise)|"}
    result = Table3Result(tuple(rows), angles, sfm_params, float(fit.fit_percent_estimation), choices, "",
                          tuple(sens), tuple(readings), tuple(mechanisms), responses, expected)
    return dataclasses.replace(result, explanation=_table3_explanation(result))


def _static_levels(effects: Sequence[Any], angles: np.ndarray) -> np.ndarray | None:
    """F_s(theta) [N m] of the hardware's LuGre stiction at the given absolute angles (None without one)."""
    st = next((e for e in effects if isinstance(e, Stiction)), None)
    if st is None:
        return None
    th = np.asarray(angles, dtype=float)
    level = np.full(th.shape, st.F_s)
    for i, (a, b) in enumerate(zip(st.F_s_a, st.F_s_b), start=1):
        level = level + a * np.sin(i * th) + b * np.cos(i * th)
    return level


def _hardware_text(result: Table3Result) -> str:
    """The hardware and board choices the numbers rest on, computed from them."""
    from .effects import effect_from_mapping

    effects = [effect_from_mapping(e) for e in result.choices.get("effects", [])]
    grid = _static_levels(effects, np.linspace(0.0, 2.0 * np.pi, 721))
    on = result.choices.get("derivative_on", TABLE3_DERIVATIVE_ON)
    text = f"Board: PD 5 / 0.1 with its derivative on the {on}"
    text += (" (no kick at the step)." if on == "measurement" else
             " (a kick of D x step at the step, as the format's u = P e + D de/dt).")
    if grid is not None:
        st = next(e for e in effects if isinstance(e, Stiction))
        text += (f" Hardware: angle-dependent static friction F_s(theta) {grid.min():.2f}-{grid.max():.2f} N m "
                 f"(the PD's command for a {result.choices.get('amplitude', 0.2):g} N m step is "
                 f"{5.0 * result.choices.get('amplitude', 0.2):.2g} N m), presliding range F_s/sigma0 = "
                 f"{1e6 * st.F_s / st.sigma0:.0f} urad.")
    return text


def _stuck_runs(result: Table3Result, env: str) -> str:
    """How many PD-alone runs never broke away, and the static levels at their start angles."""
    runs = result.responses.get((env, "none"))
    exp = result.expected.get(env)
    if not runs or exp is None:
        return ""
    from .effects import effect_from_mapping

    effects = [effect_from_mapping(e) for e in result.choices.get("effects", [])]
    levels = _static_levels(effects, result.initial_angles)
    final = np.array([np.mean(r.tau_s[-max(1, r.tau_s.size // 10):]) for r in runs])
    stuck = final < 0.25 * float(exp.tau_s[-1])
    if not stuck.any() or levels is None:
        return ""
    moved = ~stuck
    text = (f" {int(stuck.sum())} of {stuck.size} PD-alone runs end below a quarter of the frictionless level "
            f"(F_s {levels[stuck].min():.2f}-{levels[stuck].max():.2f} N m at their start angles: the motor hardly "
            "breaks away, its response is presliding and creep)")
    if moved.any():
        text += (f", the others (F_s {levels[moved].min():.2f}-{levels[moved].max():.2f} N m) break away and stick at "
                 f"{final[moved].min():.3f}-{final[moved].max():.3f} N m")
    return text + ": two shapes, which the mean-removed correlation does not forgive."


def _table3_explanation(result: Table3Result) -> str:
    parts = [f"Extended SFM identified from a simulated open-loop run (fit {result.identification_fit_percent:.1f} "
             f"%; paper: 89.95 %): viscous {result.sfm_params.get('viscous', 0.0):.3f} N m s/rad, coulomb "
             f"{result.sfm_params.get('coulomb', 0.0):.3f} N m; SFM sign() dead band "
             f"{result.choices.get('sfm_deadband', 0.0):g} rad/s.", _hardware_text(result)]
    for r in result.rows:
        if r.paper_xcorr is not None:
            parts.append(f"{r.environment}/{r.compensator}: xcorr {r.xcorr:.3f}{_pm(r.xcorr_se, 3)} (paper "
                         f"{r.paper_xcorr:.2f}), MAE {r.mae:.4f}{_pm(r.mae_se, 4)} N m (paper {r.paper_mae:g}).")
    if any(r.xcorr_se is not None for r in result.rows):
        parts.append("(+- one standard error over the repetitions' draw of initial angles: jackknife for the "
                     "x-corr, std/sqrt(n) for the MAE.)")
    envs = list(dict.fromkeys(r.environment for r in result.rows))
    for env in envs:
        cells = {r.compensator: r for r in result.rows if r.environment == env}
        if not {"none", "sfm", "ea-fob"} <= set(cells):
            continue
        e, s, n = cells["ea-fob"], cells["sfm"], cells["none"]
        pd_least = n.xcorr < min(s.xcorr, e.xcorr)
        best_m = e.mae < min(s.mae, n.mae)
        parts.append(f"{env}: PD alone is {'the least' if pd_least else 'not the least'} repeatable; the EA-FOB is "
                     f"{'the closest' if best_m else 'not the closest'} to the frictionless response."
                     + _paired_differences(result, env, n) + (_stuck_runs(result, env) if pd_least else ""))
        if n.paper_xcorr is not None and not pd_least:
            parts.append(_pd_deviation(result, env, n))
        elif n.paper_xcorr is not None and abs(n.xcorr - n.paper_xcorr) > 0.1 and \
                result.choices.get("xcorr", "pearson") == "raw":
            parts.append(f"{env}: PD alone {n.xcorr:.2f} vs the paper's {n.paper_xcorr:.2f}: the 'raw' reading keeps "
                         "the means, and with them no settling step response falls far below 1 (x-corr "
                         "readings below).")
        elif n.paper_xcorr is not None and abs(n.xcorr - n.paper_xcorr) > 0.1:
            parts.append(f"{env}: PD alone {n.xcorr:.2f} vs the paper's {n.paper_xcorr:.2f}: the x-corr of PD alone "
                         "follows how many start angles hold the motor, i.e. the spread of the static level read "
                         "from Fig. 2c (a guess) and the draw of ten angles (its standard error above).")
        if n.paper_mae is not None and n.mae > 1.5 * n.paper_mae:
            parts.append(f"{env}: PD alone's MAE {n.mae:.3f} N m exceeds the paper's {n.paper_mae:g}: the simulated "
                         "static level holds the motor further from the frictionless response than the testbed's "
                         "friction did (its spread is read from Fig. 2c's three identifications, not measured).")
        if s.paper_mae is not None and s.mae < 0.5 * s.paper_mae:
            parts.append(f"{env}: the SFM's MAE {s.mae:.4f} N m is below the paper's {s.paper_mae:g}: the "
                         "simulated hardware has exactly the friction structure the extended SFM models "
                         "(viscous, Coulomb, angle harmonics), so its identified model is better than on the "
                         "testbed, where the fit reached 89.95 %.")
        elif s.paper_mae is not None and s.mae > 1.5 * s.paper_mae:
            parts.append(f"{env}: the SFM's MAE {s.mae:.4f} N m exceeds the paper's {s.paper_mae:g}: below its "
                         "sign() dead band the feed-forward stops and the motor sticks wherever the angle-dependent "
                         "static level holds it (the 'different static errors' Section 7 reports for this cell), "
                         "further from the frictionless level here than on the testbed.")
        if e.paper_xcorr is not None and e.xcorr < e.paper_xcorr - 0.015:
            parts.append(f"{env}: the EA-FOB's x-corr {e.xcorr:.3f} is below the paper's {e.paper_xcorr:.2f}: its "
                         "10 Hz Q filter lets the first ~20 ms of the angle-dependent breakaway through, which "
                         "differs between runs.")
        if s.paper_xcorr is not None and s.xcorr < s.paper_xcorr - 0.015:
            parts.append(f"{env}: the SFM's x-corr {s.xcorr:.3f} is below the paper's {s.paper_xcorr:.2f}: the "
                         "feed-forward cannot follow the angle-dependent static level, so some runs stop early.")
    if result.mechanisms:
        by_name: dict[str, list] = {}
        for m in result.mechanisms:
            by_name.setdefault(m["mechanism"], []).append(m)
        parts.append("Every cell recomputed with one choice changed: " + "; ".join(
            f"{name}: " + ", ".join(f"{m['environment']}/{m['compensator']} {m['xcorr']:.3f}" for m in rows)
            for name, rows in by_name.items())
            + ". With the derivative on the error the kick throws the motor past any static level and every run "
              "rises alike (PD alone stays repeatable with the output locked, where the EA-FOB's breakaway "
              "transient differs between runs instead); the couplings' play lies inside the measured deflection "
              "k (theta - q), so while the motor crosses it the loop only softens.")
    if result.readings:
        parts.append("x-corr readings (Section 7 says only 'mean cross-correlation among step "
                     "responses'): " + "; ".join(
            f"{r['environment']}/{r['compensator']} " + ", ".join(f"{m} {r[m]:.3f}" for m in XCORR_MODES)
            for r in result.readings) + ". Keeping the means ('raw') gives >= 0.99 to every cell, PD alone "
            "included (paper 0.73 / 0.90), so the paper's values need the means removed. Rows use '"
            + str(result.choices.get("xcorr", "pearson")) + "'.")
    if result.sensitivity:
        parts.append("SFM with other sign() dead bands (sensitivity): " + "; ".join(
            f"{r['environment']} {r['sfm_deadband']:g} rad/s: xcorr {r['xcorr']:.3f}, MAE {r['mae']:.4f} N m"
            for r in result.sensitivity) + ". With the plain sign() (0 rad/s) the SFM drives a stick-slip limit "
            "cycle once the motor stops, whose phase differs from run to run; a dead band of 0.1 rad/s no longer "
            "compensates the few mrad/s of a step into the locked output.")
    return " ".join(parts)


def _pm(se: float | None, digits: int) -> str:
    return "" if se is None else f" +- {se:.{digits}f}"


def _paired_differences(result: Table3Result, env: str, n: Table3Row) -> str:
    """PD alone's x-corr minus each compensated cell's, with the paired jackknife standard error.

    The cells of one environment are run from the same initial angles, so their difference is
    judged against the spread of the difference, not of each cell.
    """
    pd_runs = result.responses.get((env, "none"))
    if not pd_runs or len(pd_runs) < 3:
        return ""
    mode = str(result.choices.get("xcorr", "pearson"))
    tau_pd = np.array([r.tau_s for r in pd_runs])
    diffs = []
    for kind in ("sfm", "ea-fob"):
        runs = result.responses.get((env, kind))
        if not runs or len(runs) != len(pd_runs):
            continue
        other = result.row(env, kind)
        se = pairwise_xcorr_se(tau_pd, mode, paired_with=np.array([r.tau_s for r in runs]))
        diffs.append(f"{kind} {n.xcorr - other.xcorr:+.3f} +- {se:.3f}")
    text = f" PD alone's x-corr minus the compensated cells' (paired over the same angles): {', '.join(diffs)}."
    if n.paper_xcorr is not None and n.xcorr_se:
        text += (f" PD alone lies {abs(n.xcorr - n.paper_xcorr) / n.xcorr_se:.1f} standard errors from the "
                 f"paper's {n.paper_xcorr:.2f}.")
    return text


def _pd_deviation(result: Table3Result, env: str, n: Table3Row) -> str:
    """Why PD alone is not the least repeatable cell in ``env``: the choices that decide it, measured."""
    return (f"{env}: deviation: PD alone ({n.xcorr:.3f}) is as repeatable as the compensated loops (paper "
            f"{n.paper_xcorr:.2f}). PD alone varies between runs only when the static level at some start angles "
            "comes close to its command (P x step) and the motor rises through sliding, not through a derivative "
            "kick or the bristles' presliding spring: the rows recomputed with one choice changed (below) "
            "measure each.")
