"""Symbolic SEA model: the paper's eqs. (1)-(8) derived with sympy.

Every transfer function here is *derived* (Laplace-transformed equations
solved with :func:`sympy.linsolve`, limits with :func:`sympy.limit`,
nominal plants by substitution) rather than typed in, so the tests can
compare the derivations with the formulas printed in the paper.

Model (experiment format, paper eq. (1)-(3)), zero initial conditions::

    J_m s^2 theta = tau_m - tau_s - d_m s theta        (motor, friction linearised)
    tau_s         = k (theta - q)                      (series spring)
    E(s) q        = tau_s,   E(s) = J s^2 + d s + k_e  (environment)

With the output locked, ``q = 0`` (the limit ``k_e -> infinity``).
"""

from __future__ import annotations

from functools import lru_cache

import sympy as sp

__all__ = [
    "s", "J_m", "d_m", "k", "J", "d", "k_e", "J_l", "d_l", "w_q",
    "environment_polynomial",
    "sea_equations",
    "sea_state_space",
    "solve_sea",
    "solve_locked_sea",
    "force_plant_expr",
    "locked_force_plant_expr",
    "motor_angle_plant_expr",
    "joint_angle_plant_expr",
    "sea_polynomials",
    "dob_force_dynamics_expr",
    "nominal_ea_expr",
    "nominal_lo_expr",
    "nominal_ld_expr",
    "paper_force_plant_expr",
    "paper_dob_force_dynamics_expr",
    "paper_nominal_lo_expr",
    "paper_nominal_ld_expr",
]

#: Laplace variable [rad/s].
s = sp.Symbol("s")
#: Motor reflected inertia [kg m^2].
J_m = sp.Symbol("J_m", positive=True)
#: Motor viscous friction [N m s/rad].
d_m = sp.Symbol("d_m", nonnegative=True)
#: Series spring stiffness [N m/rad].
k = sp.Symbol("k", positive=True)
#: Total output inertia J = J_e + J_l [kg m^2].
J = sp.Symbol("J", nonnegative=True)
#: Total output damping d = d_e + d_l [N m s/rad].
d = sp.Symbol("d", nonnegative=True)
#: Environment stiffness [N m/rad].
k_e = sp.Symbol("k_e", nonnegative=True)
#: Link inertia [kg m^2].
J_l = sp.Symbol("J_l", nonnegative=True)
#: Link damping [N m s/rad].
d_l = sp.Symbol("d_l", nonnegative=True)
#: Q-filter cutoff [rad/s].
w_q = sp.Symbol("w_q", positive=True)


def environment_polynomial() -> sp.Expr:
    """E(s) = J s^2 + d s + k_e, paper eq. (3).

    Returns
    -------
    sympy.Expr
        The environment impedance polynomial [N m/rad].
    """
    return J * s**2 + d * s + k_e


def sea_equations(theta: sp.Expr, q: sp.Expr, tau_s: sp.Expr, tau_m: sp.Expr, *,
                  tau_e: sp.Expr = 0, locked: bool = False) -> list[sp.Eq]:
    """The SEA equations (paper eq. 1 with E(s) q = tau_s), Laplace-transformed: the one home.

    Parameters
    ----------
    theta, q, tau_s, tau_m : sympy.Expr
        Motor angle [rad], joint angle [rad], spring torque [N m], motor torque [N m].
    tau_e : sympy.Expr
        Extra torque on the output (0 in the spec's model) [N m].
    locked : bool
        Output locked: q = 0 and no environment equation.

    Returns
    -------
    list of sympy.Eq
        J_m s^2 theta = tau_m - tau_s - d_m s theta; tau_s = k (theta - q); E(s) q = tau_s + tau_e.
    """
    equations = [
        sp.Eq(J_m * s**2 * theta, tau_m - tau_s - d_m * s * theta),
        sp.Eq(tau_s, k * (theta - (0 if locked else q))),
    ]
    if not locked:
        equations.append(sp.Eq(environment_polynomial() * q, tau_s + tau_e))
    return equations


@lru_cache(maxsize=None)
def sea_state_space(*, locked: bool = False) -> tuple[sp.Matrix, sp.Matrix]:
    """State-space form x' = A x + B u of :func:`sea_equations`.

    Parameters
    ----------
    locked : bool
        Output locked.

    Returns
    -------
    (A, B) : tuple of sympy.Matrix
        States x = (theta, theta', q, q') (locked: (theta, theta')); inputs u = (tau_m, tau_e)
        (locked: tau_e has no effect and its column is zero).

    Notes
    -----
    Each equation is a polynomial in s times the unknowns; s^n x is read as the n-th
    time derivative (zero initial conditions are irrelevant to the matrices), tau_s is
    eliminated and the equations are solved for the accelerations.
    """
    theta, q, tau_s, tau_m, tau_e = sp.symbols("theta q tau_s tau_m tau_e")
    x = sp.symbols("x0:4")       # theta, theta', q, q'
    acc = sp.symbols("a_theta a_q")
    derivatives = {theta: (x[0], x[1], acc[0]), q: (x[2], x[3], acc[1])}

    def time_domain(expr):
        out = 0
        for term in sp.Add.make_args(sp.expand(expr)):
            for var, (d0, d1, d2) in derivatives.items():
                if term.has(var):
                    power = sp.degree(term, s)
                    out += (term / (s**power * var)) * (d0, d1, d2)[power]
                    break
            else:
                out += term
        return out

    eqs = [sp.Eq(time_domain(e.lhs), time_domain(e.rhs))
           for e in sea_equations(theta, q, tau_s, tau_m, tau_e=tau_e, locked=locked)]
    spring = sp.solve(eqs[1], tau_s)[0]
    motion = [e.subs(tau_s, spring) for e in (eqs[:1] + eqs[2:])]
    unknowns = [acc[0]] if locked else list(acc)
    solved = sp.solve(motion, unknowns, dict=True)[0]
    states = [x[0], x[1]] if locked else list(x)
    rates = [x[1], solved[acc[0]]] if locked else [x[1], solved[acc[0]], x[3], solved[acc[1]]]
    rates = [sp.simplify(r) for r in rates]
    A = sp.Matrix(rates).jacobian(states)
    B = sp.Matrix(rates).jacobian([tau_m, tau_e])
    return A, B


@lru_cache(maxsize=None)
def solve_sea() -> dict[str, sp.Expr]:
    """Solve the Laplace-transformed SEA equations for unit motor torque.

    Returns
    -------
    dict of str to sympy.Expr
        ``{"tau_s": tau_s/tau_m, "theta": theta/tau_m, "q": q/tau_m}``,
        each a cancelled rational function of ``s`` [N m/N m], [rad/(N m)],
        [rad/(N m)].

    Notes
    -----
    The three linear equations of eq. (1) with E(s) q = tau_s are solved
    with :func:`sympy.linsolve` for (theta, q, tau_s) with tau_m = 1.
    """
    theta, q, tau_s, tau_m = sp.symbols("theta q tau_s tau_m")
    (solution,) = sp.linsolve(sea_equations(theta, q, tau_s, tau_m), [theta, q, tau_s])
    return {name: sp.cancel(expr.subs(tau_m, 1))
            for name, expr in zip(("theta", "q", "tau_s"), solution)}


@lru_cache(maxsize=None)
def solve_locked_sea() -> dict[str, sp.Expr]:
    """Solve the SEA equations with the output locked (q = 0).

    Returns
    -------
    dict of str to sympy.Expr
        ``{"tau_s": tau_s/tau_m, "theta": theta/tau_m}`` [N m/N m], [rad/(N m)].
    """
    theta, q, tau_s, tau_m = sp.symbols("theta q tau_s tau_m")
    (solution,) = sp.linsolve(sea_equations(theta, q, tau_s, tau_m, locked=True), [theta, tau_s])
    return {name: sp.cancel(expr.subs(tau_m, 1)) for name, expr in zip(("theta", "tau_s"), solution)}


def force_plant_expr() -> sp.Expr:
    """P(s) = tau_s/tau_m from the solved equations (paper eq. (2)).

    Returns
    -------
    sympy.Expr
        Rational function of ``s`` in J_m, d_m, k, J, d, k_e [N m/N m].
    """
    return solve_sea()["tau_s"]


@lru_cache(maxsize=None)
def locked_force_plant_expr() -> sp.Expr:
    """Locked-output plant: lim_{k_e -> inf} P(s) = k / (J_m s^2 + d_m s + k).

    Returns
    -------
    sympy.Expr
        Rational function of ``s`` in J_m, d_m, k [N m/N m].
    """
    return sp.cancel(sp.limit(force_plant_expr(), k_e, sp.oo))


def motor_angle_plant_expr(*, locked: bool = False) -> sp.Expr:
    """theta/tau_m, the motor-angle response used by the motor-side FOB.

    Parameters
    ----------
    locked : bool
        Output locked (q = 0).

    Returns
    -------
    sympy.Expr
        Rational function of ``s`` [rad/(N m)].
    """
    return (solve_locked_sea() if locked else solve_sea())["theta"]


def joint_angle_plant_expr() -> sp.Expr:
    """q/tau_m, the joint (output) angle response.

    Returns
    -------
    sympy.Expr
        Rational function of ``s`` [rad/(N m)].
    """
    return solve_sea()["q"]


@lru_cache(maxsize=None)
def sea_polynomials(*, locked: bool = False) -> tuple[sp.Expr, sp.Expr, sp.Expr]:
    """tau_s/tau_m and theta/tau_m over one common denominator.

    Parameters
    ----------
    locked : bool
        Output locked (q = 0).

    Returns
    -------
    (N_s, N_theta, D) : tuple of sympy.Expr
        Expanded polynomials in ``s`` with P = N_s/D and theta/tau_m = N_theta/D.
        D is the least common multiple of the two solved denominators, so the
        pair is one realisation of the plant (no duplicated modes).
    """
    sol = solve_locked_sea() if locked else solve_sea()
    n_s, d_s = sp.fraction(sp.cancel(sol["tau_s"]))
    n_t, d_t = sp.fraction(sp.cancel(sol["theta"]))
    den = sp.lcm(sp.Poly(d_s, s), sp.Poly(d_t, s))
    num_s = sp.cancel(n_s * den.as_expr() / d_s)
    num_t = sp.cancel(n_t * den.as_expr() / d_t)
    return sp.expand(num_s), sp.expand(num_t), sp.expand(den.as_expr())


@lru_cache(maxsize=None)
def dob_force_dynamics_expr() -> sp.Expr:
    """F_DOB = tau_s/u of the open-loop DOB of Fig. 5, solved from its blocks.

    Returns
    -------
    sympy.Expr
        Expression in the block symbols ``P``, ``P_n``, ``Q`` (sympy Symbols
        named so) [N m/N m].

    Notes
    -----
    Block equations (our sign convention, see :mod:`forecast_design.symbolic.observers`)::

        tau_m     = u + tau_frc_hat
        tau_frc_hat = Q (tau_m - P_n^{-1} tau_s)
        tau_s     = P tau_m

    Solving gives F_DOB = P / (1 + Q (P_n^{-1} P - 1)), the paper's eq. (4).
    """
    P, P_n, Q = sp.symbols("P P_n Q")
    u, tau_m, tau_s, est = sp.symbols("u tau_m tau_s tau_frc_hat")
    equations = [
        sp.Eq(tau_m, u + est),
        sp.Eq(est, Q * (tau_m - tau_s / P_n)),
        sp.Eq(tau_s, P * tau_m),
    ]
    (solution,) = sp.linsolve(equations, [tau_m, est, tau_s])
    return sp.simplify(solution[2] / u)


@lru_cache(maxsize=None)
def nominal_ea_expr() -> sp.Expr:
    """EA-FOB nominal plant P_n^EA (eq. (5)): P(s) with d_m = 0.

    Returns
    -------
    sympy.Expr
        Rational function of ``s`` in J_m, k, J, d, k_e [N m/N m].
    """
    return sp.cancel(force_plant_expr().subs(d_m, 0))


@lru_cache(maxsize=None)
def nominal_lo_expr() -> sp.Expr:
    """LO-DOB nominal plant P_n^LO = lim_{k_e -> inf} P_n^EA (eq. (6)).

    Returns
    -------
    sympy.Expr
        Rational function of ``s`` in J_m, k [N m/N m].
    """
    return sp.cancel(sp.limit(nominal_ea_expr(), k_e, sp.oo))


@lru_cache(maxsize=None)
def nominal_ld_expr() -> sp.Expr:
    """LD-DOB nominal plant P_n^LD: P_n^EA with E = J_l s^2 + d_l s (eqs. (7)-(8)).

    Returns
    -------
    sympy.Expr
        Rational function of ``s`` in J_m, k, J_l, d_l [N m/N m].
    """
    return sp.cancel(nominal_ea_expr().subs({J: J_l, d: d_l, k_e: 0}))


# The formulas as printed in the paper, only for comparison in the tests.

def paper_force_plant_expr() -> sp.Expr:
    """Paper eq. (2) as printed: E / ((E/k + 1)(J_m s^2 + d_m s) + E).

    Returns
    -------
    sympy.Expr
        [N m/N m].
    """
    E = environment_polynomial()
    return E / ((E / k + 1) * (J_m * s**2 + d_m * s) + E)


def paper_dob_force_dynamics_expr() -> sp.Expr:
    """Paper eq. (4) as printed, in the block symbols ``P``, ``P_n``, ``Q``.

    Returns
    -------
    sympy.Expr
        [N m/N m].
    """
    P, P_n, Q = sp.symbols("P P_n Q")
    return P / (1 + Q * (P / P_n - 1))


def paper_nominal_lo_expr() -> sp.Expr:
    """Paper eq. (6) as printed: 1 / (J_m/k s^2 + 1).

    Returns
    -------
    sympy.Expr
        [N m/N m].
    """
    return 1 / (J_m / k * s**2 + 1)


def paper_nominal_ld_expr() -> sp.Expr:
    """Paper eq. (8) as printed.

    Returns
    -------
    sympy.Expr
        [N m/N m].
    """
    return k * (J_l * s + d_l) / (J_m * J_l * s**3 + J_m * d_l * s**2 + k * (J_m + J_l) * s + k * d_l)
