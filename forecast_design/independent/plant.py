"""Independent log generator: plant (see the package docstring)."""

from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np
from scipy.integrate import ode, solve_ivp

from ..errors import ParameterError, SolverError
from ..experiment import Experiment, experiment_from_arrays
from .model import (IndependentCase, IndependentTruth, _ATOL, _BAND, _FREE, _LINEAR,
                    _MAX_EVENTS_PER_INTERVAL, _RTOL, _STUCK, _TOL_D, _TOL_N, _TOL_W)
from .signals import _harmonic, _to_log_frame, excitation_signal, round_significant

# --------------------------------------------------------------------------------------
# the plant and its hybrid integrator


class _Plant:
    """Right-hand side, mode-validity functions and mode transitions of the hybrid plant."""

    def __init__(self, case: IndependentCase):
        tb, env, p = case.true_testbed, case.true_environment, case.effect_params
        self.J_m, self.d_m, self.k = tb.J_m, tb.d_m, tb.k
        self.locked = env.locked
        self.J, self.d, self.k_e = env.J, env.d, env.k_e
        if not self.locked and self.J <= 0.0:
            raise ParameterError("the independent generator needs an output inertia J > 0 (or locked)",
                                 name="J_e", value=env.J)
        self.F_c = float(p.get("F_c", 0.0))
        self.F_s = float(p.get("F_s", self.F_c))
        self.v_s = float(p.get("v_s", 1.0))
        # asymmetric friction: the levels and the viscous coefficient for negative motion
        self.F_c_neg = float(p.get("F_c_neg", self.F_c))
        self.F_s_neg = float(p.get("F_s_neg", self.F_c_neg + (self.F_s - self.F_c)))
        self.d_neg = float(p.get("d_neg", self.d_m))
        self.stribeck = self.F_s != self.F_c or self.F_s_neg != self.F_c_neg
        if self.F_s < self.F_c or self.F_s_neg < self.F_c_neg:
            raise ParameterError(f"stiction needs F_s >= F_c, got {self.F_s} < {self.F_c}", name="F_s")
        if min(self.F_c_neg, self.d_neg) < 0.0:
            raise ParameterError("asymmetric friction needs F_c_neg, d_neg >= 0", name="F_c_neg")
        self.pos = [(i, a, b) for i, (a, b) in enumerate(zip(p.get("pos_a", ()), p.get("pos_b", ())), 1)
                    if a or b]
        self.cog = [(i, a, b) for i, (a, b) in enumerate(zip(p.get("cog_a", ()), p.get("cog_b", ())), 1)
                    if a or b]
        if self.pos and self.F_c - sum(math.hypot(a, b) for _, a, b in self.pos) < 0.0:
            raise ParameterError("position friction level F_c + sum(...) must stay >= 0",
                                 name="pos_a", value=p.get("pos_a"))
        self.lugre = "sigma0" in p
        self.sigma0 = float(p.get("sigma0", 0.0))
        self.sigma1 = float(p.get("sigma1", 0.0))
        self.h = 0.5 * float(p.get("width", 0.0))
        self.delay = float(p.get("delay_s", 0.0))
        self.gain = float(p.get("gain", 1.0))
        self.phi0 = float(case.initial_angle)
        self.sticking = (not self.lugre) and (self.F_s > 0.0 or self.F_s_neg > 0.0 or bool(self.pos))
        self.switching = self.sticking or self.h > 0.0
        self.u = 0.0                      # applied torque g tau_m(t - delay) [N m]
        self.motor = _STUCK if self.sticking else _FREE
        self.spring = _BAND if self.h > 0.0 else _LINEAR
        self.events = 0

    # ---- forces
    def spring_torque(self, d: float) -> float:
        m = self.spring
        if m == _LINEAR:
            return self.k * d
        if m == 1:
            return self.k * (d - self.h)
        if m == -1:
            return self.k * (d + self.h)
        return 0.0

    def cogging(self, angle: float) -> float:
        return _harmonic(self.cog, angle) if self.cog else 0.0

    def level(self, angle: float, w: float, direction: int = 0) -> float:
        """Friction magnitude when sliding at w (Stribeck curve + position part).

        ``direction`` (+1 / -1) picks the positive or negative levels of an asymmetric law
        (default: the sign of w, positive at rest).
        """
        neg = direction < 0 or (direction == 0 and w < 0.0)
        f_c, f_s = (self.F_c_neg, self.F_s_neg) if neg else (self.F_c, self.F_s)
        lv = f_c
        if self.stribeck:
            lv += (f_s - f_c) * math.exp(-((w / self.v_s) ** 2))
        if self.pos:
            lv += _harmonic(self.pos, angle)
        return lv

    def static_level(self, angle: float, direction: int = 1) -> float:
        """Breakaway level towards positive (``direction`` 1) or negative (-1) motion [N m]."""
        return (self.F_s if direction >= 0 else self.F_s_neg) + (_harmonic(self.pos, angle) if self.pos else 0.0)

    def viscous(self, w: float, direction: int = 0) -> float:
        """Viscous coefficient of the sliding direction (``d_neg`` for negative motion) [N m s/rad]."""
        return self.d_neg if (direction < 0 or (direction == 0 and w < 0.0)) else self.d_m

    def net(self, x) -> float:
        """Torque on the motor apart from friction and viscous damping [N m]."""
        return self.u - self.spring_torque(x[0] - x[2]) - self.cogging(x[0] + self.phi0)

    def rhs(self, t: float, x) -> list[float]:
        # the integrators call this ~8 times per sample: Python floats (the same IEEE operations as numpy
        # scalars, half the time) and level() / viscous() / cogging() written out for the sliding modes
        th, w, q, v, z = x.tolist()
        ts = self.k * (th - q) if self.spring == _LINEAR else self.spring_torque(th - q)
        if self.locked:
            dq = dv = 0.0
        else:
            dq, dv = v, (ts - self.d * v - self.k_e * q) / self.J
        m = self.motor
        if m == _STUCK:
            return [0.0, 0.0, dq, dv, 0.0]
        ang = th + self.phi0
        dz = 0.0
        if self.lugre:
            g = self.level(ang, w)
            dz = w - self.sigma0 * abs(w) * z / g
            tf = self.sigma0 * z + self.sigma1 * dz
            d_m = self.d_m
        elif m == _FREE:
            tf = 0.0
            d_m = self.d_neg if w < 0.0 else self.d_m
        else:                             # sliding: m * level(ang, w, m), viscous(w, m)
            f_c, f_s, d_m = (self.F_c_neg, self.F_s_neg, self.d_neg) if m < 0 else (self.F_c, self.F_s, self.d_m)
            lv = f_c
            if self.stribeck:
                lv += (f_s - f_c) * math.exp(-((w / self.v_s) ** 2))
            if self.pos:
                lv += _harmonic(self.pos, ang)
            tf = m * lv
        dw = (self.u - ts - d_m * w - tf - (_harmonic(self.cog, ang) if self.cog else 0.0)) / self.J_m
        return [w, dw, dq, dv, dz]

    def forces(self, x) -> tuple[float, float, float]:
        """(spring, friction beyond viscous, cogging) torques at state x [N m]."""
        th, w, q, _, z = x.tolist()
        ang = th + self.phi0
        ts = self.spring_torque(th - q)
        tc = self.cogging(ang)
        if self.lugre:
            dz = w - self.sigma0 * abs(w) * z / self.level(ang, w)
            tf = self.sigma0 * z + self.sigma1 * dz
        elif self.motor == _STUCK:
            tf = self.u - ts - tc
        elif self.motor == _FREE:
            tf = (self.viscous(w) - self.d_m) * w
        else:
            m = self.motor
            tf = m * self.level(ang, w, m) + (self.viscous(w, m) - self.d_m) * w
        return ts, tf, tc

    # ---- modes
    def tags(self) -> list[str]:
        out = []
        if self.motor in (1, -1):
            out.append("w")
        elif self.motor == _STUCK:
            out += ["stuck+", "stuck-"]
        if self.spring == 1:
            out.append("contact+")
        elif self.spring == -1:
            out.append("contact-")
        elif self.spring == _BAND:
            out += ["band+", "band-"]
        return out

    def validity(self, x) -> list[float]:
        """Mode-validity functions, all >= 0 while the current modes hold (order of :meth:`tags`)."""
        out = []
        x = x.tolist()
        m = self.motor
        if m == 1 or m == -1:
            out.append(m * x[1] + _TOL_W)
        elif m == _STUCK:
            n = self.net(x)
            ang = x[0] + self.phi0
            out += [self.static_level(ang, 1) - n + _TOL_N, self.static_level(ang, -1) + n + _TOL_N]
        s = self.spring
        if s != _LINEAR:
            d = x[0] - x[2]
            if s == 1:
                out.append(d - self.h + _TOL_D)
            elif s == -1:
                out.append(-d - self.h + _TOL_D)
            else:
                out += [self.h - d + _TOL_D, d + self.h + _TOL_D]
        return out

    def _stick_or_slip(self, x) -> None:
        n = self.net(x)
        ang = x[0] + self.phi0
        if -self.static_level(ang, -1) <= n <= self.static_level(ang, 1):
            self.motor = _STUCK
        else:
            self.motor = 1 if n > 0.0 else -1

    def transition(self, tag: str, x) -> None:
        """Apply the switch whose validity function crossed zero (x is modified in place)."""
        self.events += 1
        if tag == "w":
            x[1] = 0.0
            self._stick_or_slip(x)
        elif tag == "stuck+":
            self.motor = 1
        elif tag == "stuck-":
            self.motor = -1
        elif tag in ("contact+", "contact-"):
            self.spring = _BAND
        elif tag == "band+":
            self.spring = 1
        else:
            self.spring = -1

    def resolve(self, x) -> None:
        """Make the modes consistent with the state and the applied torque (after a torque step)."""
        for _ in range(6):
            changed = False
            if self.spring != _LINEAR:
                d = x[0] - x[2]
                s = self.spring
                valid = ((s == 1 and d >= self.h - _TOL_D) or (s == -1 and d <= -self.h + _TOL_D)
                         or (s == _BAND and -self.h - _TOL_D <= d <= self.h + _TOL_D))
                if not valid:
                    self.spring = 1 if d >= self.h else (-1 if d <= -self.h else _BAND)
                    changed = True
            if self.sticking:
                m = self.motor
                if m == _STUCK:
                    n = self.net(x)
                    ang = x[0] + self.phi0
                    if n > self.static_level(ang, 1) + _TOL_N or -n > self.static_level(ang, -1) + _TOL_N:
                        self.motor = 1 if n > 0.0 else -1
                        changed = True
                elif m * x[1] < -_TOL_W:    # a reversal the interval check missed
                    x[1] = 0.0
                    self._stick_or_slip(x)
                    changed = True
            if not changed:
                return


class _Integrator:
    """Advance the hybrid plant over intervals of constant applied torque."""

    def __init__(self, plant: _Plant):
        self.plant = plant
        self.ode = ode(plant.rhs).set_integrator("dopri5", rtol=_RTOL, atol=_ATOL, nsteps=200_000)

    def advance(self, x: np.ndarray, t_a: float, t_b: float) -> np.ndarray:
        p = self.plant
        p.resolve(x)
        r = self.ode
        r.set_initial_value(x, t_a)
        y = r.integrate(t_b)
        if not r.successful():
            raise SolverError(f"dopri5 failed on [{t_a}, {t_b}] s (code {r.get_return_code()})")
        if not p.switching or min(p.validity(y), default=1.0) >= 0.0:
            return np.array(y)
        return self._advance_with_events(np.array(x, dtype=float), t_a, t_b)

    def _advance_with_events(self, x: np.ndarray, t: float, t_b: float) -> np.ndarray:
        p = self.plant
        for _ in range(_MAX_EVENTS_PER_INTERVAL):
            tags = p.tags()
            events = []
            for i in range(len(tags)):
                def ev(_t, y, i=i):
                    return p.validity(y)[i]
                ev.terminal = True
                ev.direction = -1.0
                events.append(ev)
            sol = solve_ivp(p.rhs, (t, t_b), x, method="DOP853", rtol=_RTOL, atol=_ATOL, events=events)
            if sol.status == -1:
                raise SolverError(f"solve_ivp failed on [{t}, {t_b}] s: {sol.message}")
            if sol.status != 1:
                return sol.y[:, -1].copy()
            hits = [(te[0], i, ye[0])
                    for i, (te, ye) in enumerate(zip(sol.t_events, sol.y_events)) if len(te)]
            t_e, i, x_e = min(hits, key=lambda h: h[0])
            x = np.array(x_e, dtype=float)
            t = float(t_e)
            p.transition(tags[i], x)
            p.resolve(x)
            if t >= t_b:
                return x
        raise SolverError(f"more than {_MAX_EVENTS_PER_INTERVAL} mode switches in one interval at t = {t} s")


# --------------------------------------------------------------------------------------
# simulation and logging


def simulate_independent(case: IndependentCase) -> tuple[Experiment, IndependentTruth]:
    """Simulate one case and write its log.

    Parameters
    ----------
    case : IndependentCase
        The case (see :func:`draw_independent_case`).

    Returns
    -------
    experiment : Experiment
        The log: nominal TOML, quantised angles, printed ``tau_m`` (and
        ``tau_r``), ``tau_s`` as the case's logger writes it.
    truth : IndependentTruth
        The true signals at the rows and the true parameters.

    Raises
    ------
    SolverError
        If an integration step fails or the modes chatter.
    """
    plant = _Plant(case)
    integ = _Integrator(plant)
    rate, n = float(case.rate_hz), case.n_samples
    T = 1.0 / rate
    rng = np.random.default_rng(np.random.SeedSequence([int(case.seed), 0x10660]))
    step = case.encoder_step
    enc_noise = rng.standard_normal((n, 2)) * (case.encoder_noise_counts * step)
    sens_noise = rng.standard_normal(n) * case.sensor_noise
    k_nom = case.testbed.k
    digits = int(case.tau_m_digits)
    fmt = f".{digits - 1}e"
    tau_s_mode = case.tau_s_logging
    ref = excitation_signal(case.excitation, n, rate)
    if case.closed_loop:
        ref = round_significant(ref, digits)
        ctrl = case.controller
        tf = 1.0 / (2.0 * math.pi * case.derivative_filter_hz)
        c1, c2 = (2.0 * tf - T) / (2.0 * tf + T), 2.0 / (2.0 * tf + T)
        limit = case.torque_limit
        e_prev = None
        de = 0.0
        gain_i = float(getattr(ctrl, "I", 0.0)) * T / 2.0       # a PID's integrator, trapezoidal
        ui = 0.0
    else:
        ref_cmd = round_significant(ref, digits)

    m_delay = int(math.floor(plant.delay * rate + 1e-12))
    r_delay = plant.delay - m_delay * T
    if r_delay < 1e-12 * T:
        r_delay = 0.0
    cmd = np.zeros(n)
    rec = np.empty((n, 5))
    rec_forces = np.empty((n, 4))
    stuck = np.zeros(n, dtype=bool)
    smode = np.empty(n, dtype=np.int8)
    theta_m = np.empty(n)
    q_m = np.empty(n)
    tau_s_log = np.empty(n)
    x = np.zeros(5)

    def applied(j: int) -> float:
        return plant.gain * cmd[j] if j >= 0 else 0.0

    enc, sens = enc_noise.tolist(), sens_noise.tolist()     # Python floats per sample: the same values, faster
    for k in range(n):
        t_k = k * T
        # measurement at t_k
        x0, _, x2, _, _ = x.tolist()
        th_meas = round((x0 + enc[k][0]) / step) * step
        q_meas = 0.0 if plant.locked else round((x2 + enc[k][1]) / step) * step
        theta_m[k], q_m[k] = th_meas, q_meas
        if tau_s_mode == "sensor":
            tau_meas = float(format(case.sensor_gain * plant.spring_torque(x0 - x2) + case.sensor_offset
                                    + sens[k], ".6e"))
        else:
            tau_meas = k_nom * (th_meas - q_meas)
        tau_s_log[k] = tau_meas
        # command
        if case.closed_loop:
            e = ref[k] - tau_meas
            de = 0.0 if e_prev is None else c1 * de + c2 * (e - e_prev)
            ui += gain_i * (e + (0.0 if e_prev is None else e_prev))
            e_prev = e
            u = min(max(ctrl.P * e + ui + ctrl.D * de, -limit), limit)
            cmd[k] = float(format(u, fmt))
        else:
            cmd[k] = ref_cmd[k]
        # truth at t_k (modes resolved for the torque applied from t_k on)
        plant.u = applied(k - m_delay - 1) if r_delay > 0.0 else applied(k - m_delay)
        plant.resolve(x)
        rec[k] = x
        ts, tfr, tc = plant.forces(x)
        rec_forces[k] = (ts, tfr, tc, plant.u)
        stuck[k] = plant.motor == _STUCK
        smode[k] = plant.spring
        if k == n - 1:
            break
        # advance to t_{k+1}; the delay splits the period where the delayed command switches
        if r_delay > 0.0:
            x = integ.advance(x, t_k, t_k + r_delay)
            plant.u = applied(k - m_delay)
            x = integ.advance(x, t_k + r_delay, t_k + T)
        else:
            x = integ.advance(x, t_k, t_k + T)
        if not np.isfinite(x).all() or abs(x[0]) > 1e6:
            raise SolverError(f"the state left any physical range at t = {t_k + T} s")

    t = np.round(case.t0_s + np.arange(n) * T, 9)
    if case.angle_logging != "exact":     # the logger prints the angles (tau_s was computed before)
        kind, _, places = case.angle_logging.partition(":")
        if kind == "float32":
            theta_m, q_m = (np.asarray(a, dtype=np.float32).astype(float) for a in (theta_m, q_m))
        elif kind == "digits":
            theta_m, q_m = round_significant(theta_m, int(places)), round_significant(q_m, int(places))
        else:
            fixed = f".{int(places)}f"
            theta_m = np.array([float(format(v, fixed)) for v in theta_m.tolist()])
            q_m = np.array([float(format(v, fixed)) for v in q_m.tolist()])
    if tau_s_mode == "omitted":
        tau_s_col = None
    elif tau_s_mode == "sensor":
        tau_s_col = tau_s_log
    elif tau_s_mode == "float32":                        # a logger storing k (theta - q) as a 32-bit float
        tau_s_col = tau_s_log.astype(np.float32).astype(float)
    elif tau_s_mode.startswith("decimals:"):
        fixed = f".{int(tau_s_mode.split(':')[1])}f"     # a logger printing %.<n>f
        tau_s_col = np.array([float(format(v, fixed)) for v in tau_s_log.tolist()])
    else:
        tau_s_col = round_significant(tau_s_log, int(tau_s_mode.split(":")[1]))
    words = ", ".join(str(w) for w in case.words) or "none"
    description = (f"independent generator: {words} at x{case.magnitude_scale:g}, {case.excitation.kind}, "
                   f"{case.environment_name}, {'closed' if case.closed_loop else 'open'} loop")
    exp = experiment_from_arrays(case.design, rate, t, cmd, theta_m, q_m, tau_s=tau_s_col,
                                 tau_r=ref if case.closed_loop else None, description=description)
    params = dict(case.effect_params)
    for key in ("cog", "pos"):
        if f"{key}_a" in params:
            a, b = _to_log_frame(params[f"{key}_a"], params[f"{key}_b"], case.initial_angle)
            params[f"{key}_a_log"], params[f"{key}_b_log"] = a, b

    def ro(a: np.ndarray) -> np.ndarray:
        a = np.array(a)
        a.flags.writeable = False
        return a

    truth = IndependentTruth(
        t=ro(t), theta=ro(rec[:, 0]), omega=ro(rec[:, 1]), q=ro(rec[:, 2]), v=ro(rec[:, 3]),
        tau_spring=ro(rec_forces[:, 0]), tau_friction=ro(rec_forces[:, 1]), tau_cogging=ro(rec_forces[:, 2]),
        tau_applied=ro(rec_forces[:, 3]), command=ro(cmd), stuck=ro(stuck), spring_mode=ro(smode),
        testbed=case.true_testbed, environment=case.true_environment,
        effect_params=MappingProxyType(params), initial_angle=float(case.initial_angle), events=plant.events,
    )
    return exp, truth
