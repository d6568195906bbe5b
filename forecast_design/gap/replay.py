"""Output-error replay: the second view of the gap.

The equation errors of :mod:`.residuals` compare *forces*. The replay compares
*trajectories*: the nominal linear model is driven by the recorded ``tau_m``
(held over each period, as the format defines a row) over short windows, each
re-initialised from the measured state (filtered ``theta``, ``theta'``, ``q``,
``q'`` at the window start), and the simulated ``theta`` and ``tau_s`` are
compared with the log. Short windows keep the rigid-body drift of a free link
and the slowly decaying spring mode from accumulating, so the error of a window
is what the model gets wrong within it.

The plant (experiment format, nominal part)::

    J_m theta'' + d_m theta' + k (theta - q) = tau_m + w_m
    J q'' + d q' + k_e q = k (theta - q) + w_e          (q == 0 when locked)

is discretised exactly for a held input (``scipy.signal.cont2discrete``,
``zoh``). ``w_m`` and ``w_e`` are optional extra torques, held per period: with
``w = 0`` the replay is the nominal model; with ``w`` the negative of a fitted
candidate's equation-error prediction (evaluated along the measured motion) and
the calibrated ``J_m``, ``d_m`` and spring scale it is the augmented model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal

from ..params import Environment, Testbed
from .residuals import GapData, lowpass

__all__ = ["ReplayCheck", "replay_check", "replay_trace", "replay_windows"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ReplayCheck:
    """Output-error replay of the nominal and the augmented model.

    Parameters
    ----------
    window_s : float
        Length of each replay window [s].
    n_windows : int
        Number of windows replayed [-].
    tau_s_error_before, tau_s_error_after : float
        RMS of measured minus replayed ``tau_s`` over all windows, nominal model and
        model with the verdict's effect (and calibration) [N m].
    theta_error_before, theta_error_after : float
        Same for the motor angle [rad].
    tau_s_rms : float
        RMS of the measured ``tau_s`` (mean removed per window) [N m], the scale of the errors.
    worst_windows_s : tuple of (float, float)
        Windows where the nominal replay misses ``tau_s`` most, worst first [s].
    """

    window_s: float
    n_windows: int
    tau_s_error_before: float
    tau_s_error_after: float
    theta_error_before: float
    theta_error_after: float
    tau_s_rms: float
    worst_windows_s: tuple[tuple[float, float], ...]

    @property
    def relative_before(self) -> float:
        """Nominal ``tau_s`` replay error over the ``tau_s`` RMS [-]."""
        return self.tau_s_error_before / self.tau_s_rms if self.tau_s_rms > 0 else float("nan")

    @property
    def relative_after(self) -> float:
        """Augmented ``tau_s`` replay error over the ``tau_s`` RMS [-]."""
        return self.tau_s_error_after / self.tau_s_rms if self.tau_s_rms > 0 else float("nan")

    def summary(self, effect: str) -> str:
        """One sentence for the location summary and the report."""
        if not all(np.isfinite([self.tau_s_error_before, self.theta_error_before, self.relative_before])):
            return (f"Output-error replay ({self.n_windows} windows of {self.window_s:g} s): the nominal model "
                    "cannot be replayed on this log (its discretisation at the log's rate overflows or the log's "
                    "tau_s has no spread): no replay comparison.")
        after_ok = np.isfinite([self.tau_s_error_after, self.theta_error_after, self.relative_after]).all()
        text = (f"Output-error replay ({self.n_windows} windows of {self.window_s:g} s, each started from the "
                f"measured state and driven by the recorded tau_m): the nominal model misses tau_s by "
                f"{self.tau_s_error_before:.3g} N m RMS ({100 * self.relative_before:.1f} % of its "
                f"{self.tau_s_rms:.3g} N m RMS) and theta by {self.theta_error_before:.3g} rad")
        if effect != "none" and not after_ok:
            text += f"; with {effect} added, the replay cannot be evaluated"
        elif effect != "none":
            text += (f"; with {effect} added, {self.tau_s_error_after:.3g} N m "
                     f"({100 * self.relative_after:.1f} %) and {self.theta_error_after:.3g} rad")
        return text + "."

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready mapping (not part of the diagnosis contract)."""
        return {"window_s": self.window_s, "n_windows": self.n_windows,
                "tau_s_error_before": self.tau_s_error_before, "tau_s_error_after": self.tau_s_error_after,
                "theta_error_before": self.theta_error_before, "theta_error_after": self.theta_error_after,
                "tau_s_rms": self.tau_s_rms, "worst_windows_s": [list(w) for w in self.worst_windows_s]}


def _discrete(tb: Testbed, env: Environment, dt: float, spring_scale: float = 1.0):
    """ZOH discretisation of the nominal SEA (state space derived in symbolic.plant, the one home)."""
    from ..params import Design
    from ..symbolic.numeric import sea_state_space

    A, B = sea_state_space(Design(testbed=tb, environment=env), spring_scale=spring_scale)
    n = A.shape[0]
    Ad, Bd, *_ = signal.cont2discrete((A, B, np.eye(n), np.zeros((n, 2))), dt, method="zoh")
    return Ad, Bd


def replay_windows(tb: Testbed, env: Environment, inputs: np.ndarray, x0: np.ndarray, starts: np.ndarray,
                   length: int, rate_hz: float, *, spring_scale: float = 1.0) -> np.ndarray:
    """Simulate the linear model over windows, each from its own initial state.

    Parameters
    ----------
    tb : Testbed
        Motor side (``J_m`` [kg m^2], ``d_m`` [N m s/rad], ``k`` [N m/rad]).
    env : Environment
        Output side; a locked output has state ``(theta, theta')`` only.
    inputs : ndarray, shape (n, 2)
        Held motor torque and extra environment torque per period [N m].
    x0 : ndarray, shape (n_windows, n_states)
        Initial state of each window [rad, rad/s].
    starts : ndarray of int, shape (n_windows,)
        First sample of each window.
    length : int
        Samples per window [-].
    rate_hz : float
        Sample rate [Hz].
    spring_scale : float
        True spring torque over ``k (theta - q)`` [-].

    Returns
    -------
    ndarray, shape (n_windows, length, n_states)
        States at the sample instants; row 0 is ``x0``.
    """
    Ad, Bd = _discrete(tb, env, 1.0 / rate_hz, spring_scale)
    nw = starts.size
    X = np.empty((nw, length, Ad.shape[0]))
    X[:, 0] = x0
    for j in range(1, length):
        # the windows' inputs of one step, (nw, 2): the inputs of all steps at once held 16 B per sample
        X[:, j] = X[:, j - 1] @ Ad.T + inputs[starts + (j - 1)] @ Bd.T
    return X


def _upsample(data: GapData, dec: np.ndarray, n_raw: int) -> np.ndarray:
    """Linear interpolation of a decimated column back to the raw sample times."""
    t_raw = np.asarray(data.experiment.signals.t, dtype=float)
    return np.interp(t_raw[:n_raw], data.t, dec)


def _replay(data: GapData, fit: Any | None, starts: np.ndarray, L: int) -> dict[str, np.ndarray]:
    """Measured and replayed ``tau_s`` and ``theta`` over windows, shape (n_windows, L) each."""
    import dataclasses

    exp = data.experiment
    rate = exp.rate_hz
    sig = exp.signals
    tb, env = exp.design.testbed, exp.design.environment
    n = exp.n_samples
    theta = np.asarray(sig.theta, dtype=float)
    # the filtered motor angle and its speed are the prepared raw columns (the same low-pass and gradient);
    # the output's are made here and kept at the windows' starts only
    x0 = [data.raw["theta"][starts], data.raw["v"][starts]]
    if not env.locked:
        qf = lowpass(np.asarray(sig.q, dtype=float), data.settings)
        x0 += [qf[starts], np.gradient(qf, 1.0 / rate)[starts]]
        del qf
    x0 = np.column_stack(x0)
    tau_m = np.asarray(sig.tau_m, dtype=float)
    idx = starts[:, None] + np.arange(L)[None, :]
    out = {"t": np.asarray(sig.t, dtype=float)[idx], "tau_s": np.asarray(sig.tau_s, dtype=float)[idx],
           "theta": theta[idx]}
    del idx

    def run(tbx: Testbed, inputs: np.ndarray, scale: float, gain: float = 1.0, zero: float = 0.0
            ) -> tuple[np.ndarray, np.ndarray]:
        X = replay_windows(tbx, env, inputs, x0, starts, L, rate, spring_scale=scale)
        qs = np.zeros_like(X[..., 0]) if env.locked else X[..., 2]
        # the log's tau_s: k (theta - q) with the nominal k, or a sensor reading gain x k (theta - q) + zero
        return gain * tb.spring_torque(X[..., 0], qs) + zero, X[..., 0].copy()   # a copy: X is 4 columns

    out["tau_s_before"], out["theta_before"] = run(tb, np.column_stack([tau_m, np.zeros(n)]), 1.0)
    out["tau_s_after"], out["theta_after"] = out["tau_s_before"], out["theta_before"]
    if fit is not None:
        m = data.t.size
        parts = {eq: fit.prediction[i * m:(i + 1) * m] for i, eq in enumerate(data.equations)}
        cal = fit.calibration
        # a torque sensor's zero o is in the reading, not in the plant (true spring torque = scale tau_s + o)
        offset = float(cal.get("tau_s_offset_N_m", 0.0))
        # the prediction is what the effect adds to the equation error: remove it from the drive,
        # (tau_m - w_motor, -w_environment), made one column at a time
        inputs = np.empty((n, 2))
        np.subtract(tau_m, _upsample(data, parts.get("motor", np.zeros(m)), n), out=inputs[:, 0])
        np.negative(_upsample(data, parts.get("environment", np.zeros(m)), n), out=inputs[:, 1])
        tb1 = dataclasses.replace(tb, J_m=float(cal.get("J_m", tb.J_m)), d_m=float(max(cal.get("d_m", tb.d_m), 0.0)))
        if "k" in cal:
            # a measured tau_s: the plant's spring is the coupling's k; the sensor reads
            # (k_cal (theta - q) - o) / spring_scale (candidates._calibration)
            k_scale, sensor = float(cal["k"]) / tb.k, float(cal.get("spring_scale", 1.0))
            out["tau_s_after"], out["theta_after"] = run(tb1, inputs, k_scale, k_scale / sensor, -offset / sensor)
        else:
            out["tau_s_after"], out["theta_after"] = run(tb1, inputs, float(cal.get("spring_scale", 1.0)))
    return out


def _windows(data: GapData, window_s: float) -> tuple[np.ndarray, int]:
    exp = data.experiment
    n, e = exp.n_samples, data.settings.edge_samples
    L = max(8, int(round(window_s * exp.rate_hz)))
    starts = np.arange(e, n - e - L, L)
    if starts.size == 0:
        L = max(2, n - 2 * e - 1)
        starts = np.array([e])
    return starts, L


def replay_trace(data: GapData, fit: Any | None, start_s: float, *, window_s: float = 0.5) -> dict[str, np.ndarray]:
    """Measured and replayed signals over one window (for plots).

    Parameters
    ----------
    data : GapData
        Prepared log.
    fit : CandidateFit, optional
        The augmented model's fit (see :func:`replay_check`).
    start_s : float
        Window start [s] (clipped to the log minus the filter edges).
    window_s : float
        Window length [s].

    Returns
    -------
    dict of ndarray
        ``t`` [s], ``tau_s``, ``tau_s_before``, ``tau_s_after`` [N m], ``theta``,
        ``theta_before``, ``theta_after`` [rad], each shape (L,).
    """
    exp = data.experiment
    e = data.settings.edge_samples
    L = max(8, int(round(window_s * exp.rate_hz)))
    t = np.asarray(exp.signals.t, dtype=float)
    start = int(np.clip(np.searchsorted(t, start_s), e, max(e, exp.n_samples - e - L - 1)))
    L = min(L, exp.n_samples - start)
    out = _replay(data, fit, np.array([start]), L)
    return {k: v[0] for k, v in out.items()}


def replay_check(data: GapData, fit: Any | None = None, *, window_s: float = 0.5) -> ReplayCheck:
    """Replay the nominal model (and the model with a fitted effect) from the recorded ``tau_m``.

    Parameters
    ----------
    data : GapData
        Prepared log.
    fit : CandidateFit, optional
        The verdict's fit; its equation-error prediction (motor and environment
        rows) enters as extra held torques and its calibration replaces ``J_m``,
        ``d_m`` and the spring scale. ``None``: the "after" numbers repeat "before".
    window_s : float
        Window length [s]; the windows tile the log between the filter edges.

    Returns
    -------
    ReplayCheck
        Replay errors before and after, and the worst windows.
    """
    starts, L = _windows(data, window_s)
    r = _replay(data, fit, starts, L)
    meas_ts = r["tau_s"]
    ts_rms = float(np.sqrt(np.mean((meas_ts - meas_ts.mean(axis=1, keepdims=True)) ** 2)))
    ets0, eth0 = meas_ts - r["tau_s_before"], r["theta"] - r["theta_before"]
    ets1, eth1 = meas_ts - r["tau_s_after"], r["theta"] - r["theta_after"]
    per_window = np.sqrt(np.mean(ets0 ** 2, axis=1))
    order = np.argsort(-per_window)[:3]
    worst = tuple((float(r["t"][i, 0]), float(r["t"][i, -1])) for i in order)
    rms = lambda a: float(np.sqrt(np.mean(a ** 2)))  # noqa: E731
    rate = data.experiment.rate_hz
    return ReplayCheck(window_s=L / rate, n_windows=int(starts.size), tau_s_error_before=rms(ets0),
                       tau_s_error_after=rms(ets1), theta_error_before=rms(eth0), theta_error_after=rms(eth1),
                       tau_s_rms=ts_rms, worst_windows_s=worst)
