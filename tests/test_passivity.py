"""Coupled stability with every passive environment (forecast_design.passivity), against independent computations.

Independent references: python-control frequency responses on dense grids (min Re Z, bands), python-control
feedback interconnections of the port with random passive environments (closed-loop poles), the force loop the
margins use (its characteristic polynomial at a true environment), and the positive-real theory's witness.
"""

import json
import math

import control
import numpy as np
import pytest

from forecast_design import analyse_passivity
from forecast_design.cli import main
from forecast_design.controllers import PAPER_PD, resolve_controller
from forecast_design.loops import force_loop
from forecast_design.params import Compensator, Design, Environment
from forecast_design.passivity import port_impedance, real_part_minimum, stable_parameter_intervals, \
    tustin_equivalent
from forecast_design.symbolic.numeric import catalogue_polynomials, parameter_values

CONTROLLERS = ["pd:5:0.1", "pd:5:0.1:0.0008", "pid:6:20:0.05:0.002", "tf:0.12,6,20/0.002,1,0"]
KINDS = [None, "ea-fob", "lo-dob", "ld-dob", "motor-fob"]
FIG6 = [(env, kind, wq) for env in ("soft", "stiff") for kind in ("ea-fob", "lo-dob", "ld-dob") for wq in (1.0, 5.0, 10.0)]


def _comp(kind, wq=10.0):
    return None if kind is None else Compensator(kind=kind, w_q_hz=wq)


def _coupled_poles(result, J_e, d_e, k_e):
    """Closed-loop poles of the port (admittance Y) fed back through Z_e = J_e s + d_e + k_e/s, by python-control.

    ``feedback(Y, Z_e)`` has the characteristic polynomial s (chi_free + E chi_locked): one pole at s = 0 is the
    environment's own integrator, not a mode of the loop, and is removed; with k_e = 0 a second one is the free
    output's position, which no torque sees (force_loop divides it out too).
    """
    Y = result.port.Y.to_control()
    Ze = control.tf([J_e, d_e, k_e], [1.0, 0.0])
    poles = np.sort_complex(control.poles(control.feedback(Y, Ze)))
    for _ in range(1 if k_e > 0.0 else 2):
        i = int(np.argmin(np.abs(poles)))
        assert abs(poles[i]) < 1e-6 * max(1.0, np.max(np.abs(poles)))
        poles = np.delete(poles, i)
    return poles


def _stable(poles):
    return bool(np.all(poles.real < -1e-9 * np.maximum(1.0, np.abs(poles))))


def _random_env(rng, J_l=0.0018, d_l=0.35):
    J_e = float(10 ** rng.uniform(-5, 0)) * (rng.random() > 0.1)
    d_e = float(10 ** rng.uniform(-4, 1.5)) * (rng.random() > 0.1)
    k_e = float(10 ** rng.uniform(-2, 4)) * (rng.random() > 0.1)
    return J_e, d_e, k_e


def test_catalogue_plant_is_affine_in_the_environment(rng):
    """sea(E) = E sea_locked + sea(E = 0): the fact the port's construction rests on."""
    base = Design.nominal("soft")
    for _ in range(20):
        J, d, k_e = 10 ** rng.uniform(-3, 0), 10 ** rng.uniform(-2, 1), 10 ** rng.uniform(-1, 3)
        values = {**parameter_values(base), "J": J, "d": d, "k_e": k_e}
        full = catalogue_polynomials("sea", values)
        locked = catalogue_polynomials("sea_locked", values)
        free = catalogue_polynomials("sea", {**values, "J": 0.0, "d": 0.0, "k_e": 0.0})
        E = np.array([J, d, k_e])
        for f, l0, z in zip(full, locked, free):
            want = np.polyadd(np.convolve(E, l0), z)
            np.testing.assert_allclose(np.polyadd(f, -want), 0.0, atol=1e-12 * np.max(np.abs(f)))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("spec", CONTROLLERS)
def test_port_with_an_environment_is_the_force_loop_margins_use(kind, spec, rng):
    """python-control feedback(Y, Z_e) has exactly the closed-loop poles of force_loop at that true environment."""
    believed = Design.nominal("soft")
    ctrl = resolve_controller(spec)
    r = analyse_passivity(believed, _comp(kind), controller=ctrl)
    for _ in range(3):
        J_e, d_e, k_e = 10 ** rng.uniform(-4, -1), 10 ** rng.uniform(-3, 0), 10 ** rng.uniform(-1, 2.5)
        true = Design(testbed=believed.testbed, environment=Environment(J_e=J_e, d_e=d_e, k_e=k_e))
        loop = force_loop(true, _comp(kind), controller=ctrl, believed=believed)
        ours = _coupled_poles(r, J_e, d_e, k_e)
        theirs = np.sort_complex(loop.closed_loop_poles)
        assert ours.size == theirs.size
        # match each pole to its nearest (multiple poles are ill-conditioned: tolerance on their cluster)
        for p in theirs:
            assert np.min(np.abs(ours - p)) <= 1e-5 * max(1.0, abs(p)), (p, ours)
        assert _stable(ours) == loop.stable


@pytest.mark.parametrize("env,kind,wq", [("soft", "ea-fob", 10.0), ("stiff", "ea-fob", 10.0), ("soft", "lo-dob", 5.0),
                                         ("soft", "ld-dob", 10.0), ("stiff", None, 10.0), ("soft", "motor-fob", 5.0)])
@pytest.mark.parametrize("port", ["link", "spring"])
def test_min_re_z_and_bands_match_a_dense_python_control_grid(env, kind, wq, port):
    r = analyse_passivity(env, _comp(kind, wq), port=port)
    w = np.geomspace(1e-2, 1e5, 400_001)
    re = np.real(control.frequency_response(r.port.Z.to_control(), w).complex).ravel()
    scale = max(1.0, float(np.max(np.abs(re[:1000]))))
    # the exact minimum is a lower bound of every sample and the dense grid comes within its resolution
    assert r.min_re_z <= re.min() + 1e-9 * scale
    assert r.min_re_z >= re.min() - 1e-4 * scale
    if 0.0 < r.w_min_rad_s < math.inf:
        assert abs(r.w_min_rad_s - w[np.argmin(re)]) <= 1e-3 * r.w_min_rad_s
    negative = re < 0.0
    edges = w[1:][np.diff(negative.astype(int)) != 0]
    ours = [e for band in r.bands_rad_s for e in band if 1e-2 < e < 1e5]
    assert len(ours) == len(edges)
    for a, b in zip(ours, edges):
        assert abs(a - b) <= 1e-4 * b
    for lo, hi in r.bands_rad_s:
        inside = w[(w > lo) & (w < hi)]
        if inside.size:
            assert np.all(np.real(control.frequency_response(r.port.Z.to_control(), inside).complex) < 1e-12)
    assert r.passive == (r.locked_stable and re.min() >= -1e-9 * scale and not r.bands_rad_s)


@pytest.mark.parametrize("env,kind,wq,spec", [("soft", None, 10.0, "pd:5:0.1"), ("soft", "lo-dob", 5.0, "pd:5:0.1"),
                                              ("stiff", "ea-fob", 10.0, "pd:5:0.1"),
                                              ("soft", "ea-fob", 1.0, "pd:5:0.1")])
def test_passive_port_is_stable_with_every_random_passive_environment(env, kind, wq, spec, rng):
    r = analyse_passivity(env, _comp(kind, wq), controller=spec)
    assert r.passive
    for _ in range(150):
        J_e, d_e, k_e = _random_env(rng)
        if J_e == d_e == k_e == 0.0:
            continue
        assert _stable(_coupled_poles(r, J_e, d_e, k_e)), (J_e, d_e, k_e)


@pytest.mark.parametrize("env,kind,wq,spec", [("soft", "ea-fob", 10.0, "pd:5:0.1"), ("soft", "ld-dob", 10.0, "pd:5:0.1"),
                                              ("stiff", "ea-fob", 10.0, "pid:6:20:0.05:0.002")])
def test_non_passive_port_is_destabilised_by_a_passive_environment_in_its_band(env, kind, wq, spec):
    r = analyse_passivity(env, _comp(kind, wq), controller=spec)
    assert not r.passive and r.bands_rad_s
    e = r.destabilising_environment
    assert e is not None and min(e["J_e_kg_m2"], e["d_e_n_m_s_per_rad"], e["k_e_n_m_per_rad"]) >= 0.0
    assert any(lo <= e["at_rad_s"] <= hi for lo, hi in r.bands_rad_s)
    poles = _coupled_poles(r, e["J_e_kg_m2"], e["d_e_n_m_s_per_rad"], e["k_e_n_m_per_rad"])
    assert not _stable(poles)
    worst = poles[np.argmax(poles.real)]
    assert any(0.5 * lo <= abs(worst.imag) <= 1.5 * hi for lo, hi in r.bands_rad_s)


def test_index_interval_certifies_random_environments_outside_it(rng):
    """Every passive environment with |Z_e| below the interval on the bands (free port stable) is stable."""
    r = analyse_passivity("soft", _comp("ea-fob", 10.0))
    ii = r.index_interval
    assert ii["light_side_certified"] and ii["interval_n_m_s_per_rad"][0] > 0.0
    lo_mag = ii["interval_n_m_s_per_rad"][0]
    checked = 0
    for _ in range(3000):
        J_e, d_e, k_e = _random_env(rng)
        w = np.concatenate([np.linspace(a, b, 50) for a, b in r.bands_rad_s])
        if np.max(np.abs(J_e * 1j * w + d_e + k_e / (1j * w))) >= lo_mag or J_e == d_e == k_e == 0.0:
            continue
        checked += 1
        assert _stable(_coupled_poles(r, J_e, d_e, k_e)), (J_e, d_e, k_e)
    assert checked > 50


@pytest.mark.parametrize("env,kind,wq,spec", [("soft", "ea-fob", 10.0, "pd:5:0.1"), ("soft", "ld-dob", 10.0, "pd:5:0.1"),
                                              ("soft", "ea-fob", 10.0, "pid:6:20:0.05:0.002"),
                                              ("fig7", "ea-fob", 10.0, "tf:0.12,6,20/0.002,1,0"),
                                              ("k_e=0,J_e=0.01,d_e=0", "ea-fob", 10.0, "pd:5:0.1")])
def test_stiffness_and_inertia_ranges_bound_the_python_control_poles(env, kind, wq, spec):
    r = analyse_passivity(env, _comp(kind, wq), controller=spec)
    e = r.design.environment
    for intervals, make in ((r.stiffness_intervals, lambda v: (e.J_e, e.d_e, v)),
                            (r.inertia_intervals, lambda v: (v, e.d_e, e.k_e))):
        assert intervals
        for lo, hi in intervals:
            if lo > 0.0:
                assert not _stable(_coupled_poles(r, *make(lo * (1 - 1e-3))))
            assert _stable(_coupled_poles(r, *make(lo * (1 + 1e-3) if lo > 0 else (hi if math.isfinite(hi) else 1.0)
                                                     * 1e-3)))
            if math.isfinite(hi):
                assert _stable(_coupled_poles(r, *make(hi * (1 - 1e-3))))
                assert not _stable(_coupled_poles(r, *make(hi * (1 + 1e-3))))


def test_stable_parameter_intervals_on_a_routh_example():
    """s^3 + 2 s^2 + s + p: Hurwitz iff 0 < p < 2 (Routh)."""
    (iv,) = stable_parameter_intervals(np.array([1.0, 2.0, 1.0, 0.0]), np.array([1.0]))
    assert iv[0] == 0.0 and iv[1] == pytest.approx(2.0, rel=1e-12)


def test_real_part_minimum_closed_form():
    """Z = (s + 2)/(s + 1): Re Z(jw) = (2 + w^2)/(1 + w^2), min 1 at w -> inf; Z = 1/(s^2 + 0.2 s + 1) dips at w = sqrt(1.2)."""
    assert real_part_minimum(np.array([1.0, 2.0]), np.array([1.0, 1.0])) == (pytest.approx(1.0), math.inf)
    value, w = real_part_minimum(np.array([1.0]), np.array([1.0, 0.2, 1.0]))
    grid = np.geomspace(0.1, 10, 200_001)
    re = np.real(1.0 / ((1j * grid) ** 2 + 0.2j * grid + 1.0))
    assert value == pytest.approx(re.min(), rel=1e-6) and w == pytest.approx(grid[np.argmin(re)], rel=1e-4)


def test_tustin_equivalent_matches_the_discrete_response():
    rate = 2000.0
    C = tustin_equivalent((5.0, -4.9), (1.0, -0.9), rate)
    w = np.geomspace(1.0, 0.9 * math.pi * rate, 50)
    z = np.exp(1j * w / rate)
    warped = 2.0 * rate * np.tan(w / (2.0 * rate))
    np.testing.assert_allclose(C(1j * warped), (5.0 * z - 4.9) / (z - 0.9), rtol=1e-10)


@pytest.mark.parametrize("env,kind,wq", FIG6)
def test_fig6_cases_the_given_environment_is_stable_iff_its_stiffness_is_in_the_range(env, kind, wq):
    """The paper's Fig. 6 settings: the computed ranges agree with the margins' loop at the given environment."""
    r = analyse_passivity(env, _comp(kind, wq))
    loop = force_loop(r.design, _comp(kind, wq), controller=PAPER_PD)
    assert (r.stiffness_range is not None) == loop.stable
    assert (r.inertia_range is not None) == loop.stable
    if r.passive:
        assert r.stiffness_intervals == ((0.0, math.inf),) and r.inertia_intervals == ((0.0, math.inf),)
        assert r.destabilising_environment is None


def test_passivity_verb_json_and_exit_codes(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main(["passivity", "--env", "soft", "--compensator", "ea-fob", "--w-q-hz", "10", "--json", str(out),
                 "--plot", str(tmp_path / "p.png")]) == 1
    doc = json.loads(out.read_text())
    assert doc["passive"] is False and doc["locked_stable"] is False
    assert doc["bands_rad_s"] and doc["stiffness_range_n_m_per_rad"][0] == 0.0
    assert doc["assumptions"]["compensator"]["w_q_hz"] == 10.0 and doc["assumptions"]["environment"]["name"] == "soft"
    assert {"passivity_indices", "passivity_index_interval", "inertia_range_kg_m2", "w_min_rad_s"} <= set(doc)
    assert (tmp_path / "p.png").stat().st_size > 10_000
    assert main(["passivity", "--env", "stiff", "--compensator", "lo-dob", "--w-q-hz", "5"]) == 0
    assert "PASSIVE" in capsys.readouterr().out


def test_passivity_verb_refuses_a_locked_environment_in_one_line(capsys):
    assert main(["passivity", "--env", "locked"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("forecast-design: error:") and "locked" in err[0]
