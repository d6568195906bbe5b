"""A gain-scheduled PID force controller written in Python (the interface: docs/controllers-as-code.md).

u = K_p(tau_r) e + x + d  with  e = tau_r - tau_s [N m]:
  K_p grows from P0 to P0 + P1 as |tau_r| goes from 0 to TAU_SCHEDULE (stiffer tracking of
      large forces, gentler near zero force where friction dominates);
  x   integrates I e and stops when the output sits on its limit (conditional integration);
  d   is D de/dt through a first-order filter T_F (backward Euler).
The output is limited to +-U_MAX. gain_scheduled_pid.c is the same controller in C.
"""



class GainScheduledPID:
    P0 = 4.0             # proportional gain at zero reference [N m/N m]
    P1 = 2.0             # added gain at |tau_r| >= TAU_SCHEDULE [N m/N m]
    TAU_SCHEDULE = 1.0   # reference at which the schedule saturates [N m]
    I = 20.0             # integral gain [1/s]
    D = 0.05             # derivative gain [s]
    T_F = 0.002          # derivative filter time constant [s]
    U_MAX = 10.0         # output limit [N m]

    def reset(self, rate_hz, testbed, environment):
        """Before each run: the control period and a state at rest."""
        self.dt = 1.0 / rate_hz
        self.x = 0.0
        self.d = 0.0
        self.e_prev = 0.0

    def step(self, t, tau_r, tau_s, theta, q):
        """One control period: the controller output u [N m]."""
        e = tau_r - tau_s
        kp = self.P0 + self.P1 * min(abs(tau_r) / self.TAU_SCHEDULE, 1.0)
        self.d = (self.T_F * self.d + self.D * (e - self.e_prev)) / (self.T_F + self.dt)
        self.e_prev = e
        u = kp * e + self.x + self.d
        if abs(u) < self.U_MAX or u * e < 0.0:      # conditional integration (anti-windup)
            self.x += self.I * self.dt * e
        return max(-self.U_MAX, min(self.U_MAX, u))

    def transfer_function(self):
        """Linearisation at small references (K_p = P0, no limit): C(s) = P0 + I/s + D s/(T_F s + 1).

        The toolbox's margins and Q-filter tuning use it (and say so); the schedule and the
        limit are not in it.
        """
        import control

        s = control.tf("s")
        return self.P0 + self.I / s + self.D * s / (self.T_F * s + 1)
