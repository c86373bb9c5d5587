"""Energy-optimal profiles against closed forms and an independent discretised QP."""

import numpy as np
import pytest
from scipy.integrate import quad

from nrtraffic.planning.profiles import (InfeasibleProfile, PlanBounds, earliest_fixed, fixed_terminal, free_terminal,
                                         max_time, min_time, rear_end_constrained, rear_end_violation)

B = PlanBounds(v_min_mps=1.0, v_max_mps=20.0, u_min_mps2=-3.0, u_max_mps2=2.5)


def _num_energy(prof):
    # 1/2 int u^2 by adaptive quadrature of the evaluated profile, split at the knots
    pts = list(prof.knots[(prof.knots > 0) & (prof.knots < prof.T)])
    val, _ = quad(lambda t: prof.evaluate(prof.t0 + t)[2] ** 2, 0.0, prof.T, points=pts or None, limit=200)
    return 0.5 * val


@pytest.mark.parametrize("v0,D,T", [(13.4, 400.0, 29.85), (13.4, 400.0, 38.0), (13.4, 400.0, 60.0), (10.0, 400.0, 30.0)])
def test_free_terminal_unconstrained_boundary_conditions_and_cost(v0, D, T):
    prof = free_terminal(5.0, v0, D, T, B)
    assert prof.kind == "unconstrained"
    p, v, u = prof.evaluate(np.array([5.0, 5.0 + T]))
    assert p[0] == pytest.approx(0.0, abs=1e-12) and v[0] == pytest.approx(v0)
    assert p[1] == pytest.approx(D, rel=1e-12)
    assert u[1] == pytest.approx(0.0, abs=1e-12)  # free terminal speed: u(t_m) = 0
    assert v[1] == pytest.approx((3 * D / T - v0) / 2)
    closed = 3 * (D - v0 * T) ** 2 / (2 * T**3)
    assert prof.energy() == pytest.approx(closed, rel=1e-10, abs=1e-14)
    assert _num_energy(prof) == pytest.approx(closed, rel=1e-6, abs=1e-12)


def test_profile_is_consistent_double_integrator():
    # v is the derivative of p and u of v (central differences), on every arc kind
    for T in (38.0, 200.0, 21.0, min_time(13.4, 400.0, B) + 0.05, max_time(13.4, 400.0, B) - 0.5):
        prof = free_terminal(0.0, 13.4, 400.0, T, B)
        t = np.linspace(0.01, T - 0.01, 997)
        h = 1e-4
        p1, v1, u1 = prof.evaluate(t + h)
        p0, v0, u0 = prof.evaluate(t - h)
        _, v, u = prof.evaluate(t)
        assert np.allclose((p1 - p0) / (2 * h), v, atol=1e-5), prof.kind
        assert np.allclose((v1 - v0) / (2 * h), u, atol=1e-3), prof.kind


@pytest.mark.parametrize("T,kind", [(200.0, "speed"), (21.0, "speed")])
def test_speed_bounded_profiles(T, kind):
    prof = free_terminal(0.0, 13.4, 400.0, T, B)
    assert prof.kind == kind
    t = np.linspace(0, T, 4001)
    p, v, u = prof.evaluate(t)
    assert v.min() >= B.v_min_mps - 1e-9 and v.max() <= B.v_max_mps + 1e-9
    assert u.min() >= B.u_min_mps2 - 1e-9 and u.max() <= B.u_max_mps2 + 1e-9
    assert p[-1] == pytest.approx(400.0)
    # the junction with the cruise arc is tangential: u = 0 where the bound is reached
    vb = B.v_max_mps if T < 29.85 else B.v_min_mps
    tau1 = 3 * (vb * T - 400.0) / (vb - 13.4)
    assert prof.evaluate(tau1)[2] == pytest.approx(0.0, abs=1e-9)
    assert prof.evaluate(tau1)[1] == pytest.approx(vb)


def _qp_energy(v0, D, T, b, n=400, vm=None):
    """Independent reference: the discretised problem min 1/2 sum u_k^2 dt s.t. double-integrator
    dynamics (exact zero-order hold), p_N = D (and v_N = vm when given), bounds on u and v --
    solved as a QP by OSQP (called directly, with sparse matrices)."""
    import osqp
    from scipy import sparse

    dt = T / n
    # p_N = v0 T + sum_k u_k dt^2 (N - k - 1/2); v_j = v0 + dt sum_{k<j} u_k
    A_eq = np.array([[dt * dt * (n - k - 0.5) for k in range(n)]])
    b_eq = np.array([D - v0 * T])
    if vm is not None:
        A_eq = np.vstack([A_eq, np.full(n, dt)])
        b_eq = np.array([D - v0 * T, vm - v0])
    L = np.tril(np.ones((n, n))) * dt
    G = np.vstack([L, -L])
    h = np.concatenate([np.full(n, b.v_max_mps - v0), np.full(n, v0 - b.v_min_mps)])
    # OSQP's form: min 1/2 u' P u  s.t.  l <= A u <= h (equalities, speed bounds, input bounds)
    A = sparse.vstack([sparse.csc_matrix(A_eq), sparse.csc_matrix(G), sparse.identity(n)], format="csc")
    lo = np.concatenate([b_eq, np.full(2 * n, -np.inf), np.full(n, b.u_min_mps2)])
    hi = np.concatenate([b_eq, h, np.full(n, b.u_max_mps2)])
    qp = osqp.OSQP()
    qp.setup(P=sparse.identity(n, format="csc") * dt, q=np.zeros(n), A=A, l=lo, u=hi, eps_abs=1e-9, eps_rel=1e-9,
             max_iter=200000, polishing=True, verbose=False)
    res = qp.solve(raise_error=True)
    u = res.x
    assert u is not None and np.all(np.isfinite(u))
    return 0.5 * float(np.sum(u * u) * dt)


@pytest.mark.parametrize("T", [21.0, 38.0, 150.0, 200.0])
def test_constrained_profile_matches_discretised_qp(T):
    prof = free_terminal(0.0, 13.4, 400.0, T, B)
    ref = _qp_energy(13.4, 400.0, T, B)
    assert prof.energy() == pytest.approx(ref, rel=0.01, abs=1e-4)


def test_acceleration_saturated_profiles_match_qp():
    tight = PlanBounds(v_min_mps=1.0, v_max_mps=30.0, u_min_mps2=-0.15, u_max_mps2=0.15)
    # decelerating hard enough that the unconstrained u(0) exceeds the 0.15 m/s^2 bound
    T = 36.0
    unc = 3 * (400.0 - 13.4 * T) / T**2
    assert abs(unc) > 0.15
    prof = free_terminal(0.0, 13.4, 400.0, T, tight)
    assert prof.kind in ("accel", "accel_speed")
    _, _, u = prof.evaluate(np.linspace(0, T, 2001))
    assert u.min() >= -0.15 - 1e-9
    assert u[-2] == pytest.approx(0.0, abs=1e-3)
    assert prof.energy() == pytest.approx(_qp_energy(13.4, 400.0, T, tight), rel=0.01)


def test_fixed_terminal_solves_the_boundary_value_system():
    v0, vm, D, T = 13.4, 8.0, 400.0, 35.0
    prof = fixed_terminal(0.0, v0, vm, D, T)
    # independent: the 4x4 system p = a t^3/6 + b t^2/2 + c t + d for (a, b, c, d)
    M = np.array([[0, 0, 0, 1], [0, 0, 1, 0], [T**3 / 6, T**2 / 2, T, 1], [T**2 / 2, T, 1, 0]])
    a, b, c, d = np.linalg.solve(M, [0.0, v0, D, vm])
    t = np.linspace(0, T, 50)
    p, v, u = prof.evaluate(t)
    assert np.allclose(p, a * t**3 / 6 + b * t**2 / 2 + c * t + d)
    assert np.allclose(u[:-1], a * t[:-1] + b)  # after T: constant speed
    assert v[-1] == pytest.approx(vm)


@pytest.mark.parametrize("v0, T", [(13.89, 29.6), (13.89, 31.0), (13.89, 33.5), (12.0, 32.0)])
def test_fixed_terminal_with_the_speed_bound_matches_discretised_qp(v0, T):
    """A car entering at (or near) the limit that must cross at 8 m/s: for merge times where the
    cubic would exceed v_max, the cruise-arc profile is the bounded optimum."""
    b = B_JUNCTION
    prof = fixed_terminal(0.0, v0, 8.0, 400.0, T, b)
    assert prof.kind == "fixed_speed_cruise"
    t = np.linspace(0.0, T, 4001)
    p, v, u = prof.evaluate(t)
    assert p[-1] == pytest.approx(400.0, abs=1e-9) and v[-1] == pytest.approx(8.0, abs=1e-9)
    assert v.max() <= b.v_max_mps + 1e-9 and u.min() >= b.u_min_mps2 - 1e-9 and u.max() <= b.u_max_mps2 + 1e-9
    assert prof.energy() == pytest.approx(_qp_energy(v0, 400.0, T, b, vm=8.0), rel=0.01)


def test_earliest_fixed_arrival_is_time_optimal_and_close_to_braking_at_the_bound():
    """400 m, 13.89 -> 8 m/s, |u_min| = 3: T = 29.35 s. At that time the arc's
    deceleration reaches |u_min|, a moment earlier no profile fits, and it loses at most 0.5 s
    against cruising and braking at constant |u_min| just in time."""
    b = B_JUNCTION
    for vm, D in ((8.0, 400.0), (6.5, 400.0), (8.0, 150.0)):
        T = earliest_fixed(13.89, vm, D, b)
        prof = fixed_terminal(0.0, 13.89, vm, D, T, b)
        _, _, u = prof.evaluate(np.linspace(0.0, T - 1e-9, 20001))
        assert u.min() == pytest.approx(b.u_min_mps2, abs=1e-6)
        with pytest.raises(InfeasibleProfile):
            fixed_terminal(0.0, 13.89, vm, D, T - 0.05, b)
        tb = (13.89 - vm) / -b.u_min_mps2  # constant braking
        t_phys = (D - (13.89 + vm) / 2.0 * tb) / 13.89 + tb
        assert 0.0 <= T - t_phys <= 0.5
    assert earliest_fixed(13.89, 8.0, 400.0, b) == pytest.approx(29.35, abs=0.01)


def test_min_and_max_time_are_the_feasibility_limits():
    t_min = min_time(13.4, 400.0, B)
    t_max = max_time(13.4, 400.0, B)
    free_terminal(0.0, 13.4, 400.0, t_min + 1e-3, B)
    free_terminal(0.0, 13.4, 400.0, t_max - 1e-3, B)
    with pytest.raises(InfeasibleProfile):
        free_terminal(0.0, 13.4, 400.0, t_min - 0.05, B)
    with pytest.raises(InfeasibleProfile):
        free_terminal(0.0, 13.4, 400.0, t_max + 0.5, B)
    # bang-cruise closed forms
    ta = (20.0 - 13.4) / 2.5
    assert t_min == pytest.approx(ta + (400.0 - (13.4 + 20.0) / 2 * ta) / 20.0)
    tb = (13.4 - 1.0) / 3.0
    assert t_max == pytest.approx(tb + (400.0 - (13.4 + 1.0) / 2 * tb) / 1.0)


B_JUNCTION = PlanBounds(v_min_mps=1.0, v_max_mps=13.89, u_min_mps2=-3.0, u_max_mps2=2.5)


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_rear_end_qp_reproduces_the_closed_form_when_the_leader_is_far(solver):
    """With the gap constraint inactive the QP's optimum is the closed form itself (u linear is
    inside its piecewise-linear family): the fixed- and free-terminal cases."""
    far = lambda t: np.full_like(np.asarray(t, float), 1e6)  # noqa: E731
    ref = fixed_terminal(0.0, 13.89, 8.0, 400.0, 40.0, B_JUNCTION)
    qp = rear_end_constrained(0.0, 13.89, 400.0, 40.0, B_JUNCTION, far, 40.0, 12.0, vm=8.0, solver=solver)
    t = np.linspace(0.0, 40.0, 801)
    assert np.max(np.abs(qp.evaluate(t)[0] - ref.evaluate(t)[0])) < 1e-3
    assert qp.energy() == pytest.approx(ref.energy(), rel=1e-4)
    ref = free_terminal(0.0, 10.0, 300.0, 24.0, B_JUNCTION)
    qp = rear_end_constrained(0.0, 10.0, 300.0, 24.0, B_JUNCTION, far, 24.0, 12.0, vm=None, solver=solver)
    assert np.max(np.abs(qp.evaluate(t[t <= 24.0])[0] - ref.evaluate(t[t <= 24.0])[0])) < 1e-3
    assert qp.v_m == pytest.approx(ref.v_m, abs=1e-4)


def _slowing_leader_case():
    gap, D = 12.0, 400.0
    lead = fixed_terminal(0.0, 13.89, 13.89, D, 54.0, B_JUNCTION)
    return gap, D, (lambda t: lead.evaluate(t)[0]), 4.3, 55.5, 8.0  # t_m: 54 s + 12 m / 8 m/s


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_rear_end_qp_keeps_behind_a_slowing_leader(solver):
    """A leader held back by a conflict slows deeply in the middle of the zone; a follower entering
    4 s later with a lower merge speed catches up with it in its closed form. The constrained
    profile meets its end conditions and the bounds, keeps the gap (sampled far finer than its
    grid), and costs more energy than the closed form."""
    gap, D, leader_pos, t0, t_m, vm = _slowing_leader_case()
    closed = fixed_terminal(t0, 13.89, vm, D, t_m - t0, B_JUNCTION)
    assert rear_end_violation(closed, leader_pos, t_m, gap) > 5.0  # the case exists
    prof = rear_end_constrained(t0, 13.89, D, t_m - t0, B_JUNCTION, leader_pos, t_m, gap, vm=vm, solver=solver)
    t = np.linspace(t0, t_m, 20001)
    p, v, u = prof.evaluate(t)
    assert np.max(p - (leader_pos(t) - gap)) < 0.05
    assert prof.coef[-1, 0] == pytest.approx(D, abs=1e-3) and prof.v_m == pytest.approx(vm, abs=1e-3)
    assert v.min() >= B_JUNCTION.v_min_mps - 1e-2 and v.max() <= B_JUNCTION.v_max_mps + 1e-2
    assert u.min() >= B_JUNCTION.u_min_mps2 - 1e-9 and u.max() <= B_JUNCTION.u_max_mps2 + 1e-9
    assert prof.energy() > closed.energy()
    # a continuous double integrator: position and speed join at every knot
    for k in range(1, len(prof.knots)):
        d = prof.knots[k] - prof.knots[k - 1]
        p0, v0, u0, j = prof.coef[k - 1]
        assert prof.coef[k, 0] == pytest.approx(p0 + v0 * d + u0 * d * d / 2 + j * d**3 / 6, abs=1e-9)
        assert prof.coef[k, 1] == pytest.approx(v0 + u0 * d + j * d * d / 2, abs=1e-9)


def test_dense_and_sparse_solvers_give_the_same_rear_end_plan():
    """DAQP (dense active set, the default) and OSQP (ADMM, tolerance 1e-6) solve the same QP: their
    plans agree within 5 mm in position and 0.01 m/s^2 in acceleration."""
    gap, D, leader_pos, t0, t_m, vm = _slowing_leader_case()
    a = rear_end_constrained(t0, 13.89, D, t_m - t0, B_JUNCTION, leader_pos, t_m, gap, vm=vm, solver="daqp")
    b = rear_end_constrained(t0, 13.89, D, t_m - t0, B_JUNCTION, leader_pos, t_m, gap, vm=vm, solver="osqp")
    t = np.linspace(t0, t_m, 5001)
    pa, _, ua = a.evaluate(t)
    pb, _, ub = b.evaluate(t)
    assert np.max(np.abs(pa - pb)) < 5e-3 and np.max(np.abs(ua - ub)) < 1e-2
    assert a.energy() == pytest.approx(b.energy(), rel=1e-4)


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_rear_end_qp_reports_an_impossible_gap(solver):
    """A leader standing 5 m into the zone cannot be followed 12 m behind from the entry."""
    stop = lambda t: np.full_like(np.asarray(t, float), 5.0)  # noqa: E731
    with pytest.raises(InfeasibleProfile):
        rear_end_constrained(0.0, 13.89, 400.0, 30.0, B_JUNCTION, stop, 30.0, 12.0, vm=13.89, solver=solver)


@pytest.mark.parametrize("v0, vm, T", [(13.89, 13.89, 100.0), (13.89, 13.89, 250.0), (13.89, 8.0, 150.0),
                                       (6.0, 13.89, 200.0)])
def test_fixed_terminal_with_a_long_wait_cruises_at_v_min_and_matches_discretised_qp(v0, vm, T):
    """A merge time much later than cruising gives (the junction is saturated): the cubic would fall
    below v_min, and the bounded optimum brakes to v_min, cruises there, and speeds up to vm."""
    b = B_JUNCTION
    prof = fixed_terminal(0.0, v0, vm, 400.0, T, b)
    assert prof.kind == "fixed_speed_slow"
    t = np.linspace(0.0, T, 8001)
    p, v, u = prof.evaluate(t)
    assert p[-1] == pytest.approx(400.0, abs=1e-6) and v[-1] == pytest.approx(vm, abs=1e-9)
    assert v.min() >= b.v_min_mps - 1e-9 and v.min() == pytest.approx(b.v_min_mps, abs=1e-6)
    assert u.min() >= b.u_min_mps2 - 1e-9 and u.max() <= b.u_max_mps2 + 1e-9
    assert np.all(np.diff(p) >= 0.0)
    assert prof.energy() == pytest.approx(_qp_energy(v0, 400.0, T, b, vm=vm, n=800), rel=0.01)


def test_a_wait_longer_than_v_min_allows_is_refused():
    b = B_JUNCTION
    with pytest.raises(InfeasibleProfile):
        fixed_terminal(0.0, 13.89, 13.89, 400.0, 500.0, b)  # 400 m at >= 1 m/s take at most ~390 s


@pytest.mark.parametrize("T", [30.0, 45.0])
def test_a_standing_car_gets_the_energy_optimal_start_and_never_reverses(T):
    """From rest (below v_min) the plan starts from rest and never drops below the speed it has:
    the discretised QP with v >= 0 is the reference."""
    b = B_JUNCTION
    prof = fixed_terminal(0.0, 0.0, 13.89, 300.0, T, b)
    t = np.linspace(0.0, T, 4001)
    p, v, u = prof.evaluate(t)
    assert p[-1] == pytest.approx(300.0, abs=1e-6) and v[-1] == pytest.approx(13.89, abs=1e-9)
    assert v.min() >= -1e-9 and v.max() <= b.v_max_mps + 1e-9
    from_rest = PlanBounds(v_min_mps=1e-9, v_max_mps=b.v_max_mps, u_min_mps2=b.u_min_mps2, u_max_mps2=b.u_max_mps2)
    assert prof.energy() == pytest.approx(_qp_energy(0.0, 300.0, T, from_rest, vm=13.89), rel=0.01)


def test_a_standing_car_with_too_long_a_wait_is_refused():
    """It would have to drive backwards (or stop, which is no energy-optimal arc): refused, so that
    it is held and starts from rest at its stop line."""
    with pytest.raises(InfeasibleProfile):
        fixed_terminal(0.0, 0.0, 13.89, 300.0, 200.0, B_JUNCTION)


def test_a_standing_start_waits_then_accelerates_as_the_closed_form():
    """Standing 40 m before the zone from t = 10 s, setting off at 13 s at 2.5 m/s^2 up to 10 m/s:
    p = 0 until 13 s, then 1.25 (t - 13)^2 up to 17 s (20 m, 10 m/s), then 20 + 10 (t - 17);
    the merging zone (40 m) is reached at 19 s."""
    from nrtraffic.planning.profiles import standing_start

    prof = standing_start(10.0, 13.0, 40.0, 2.5, 10.0)
    t = np.linspace(10.0, 25.0, 301)
    p, v, _ = prof.evaluate(t)
    expect = np.where(t < 13.0, 0.0, np.where(t < 17.0, 1.25 * (t - 13.0) ** 2, 20.0 + 10.0 * (t - 17.0)))
    assert np.allclose(p, expect, atol=1e-9)
    assert np.allclose(v, np.gradient(expect, t), atol=0.2)  # (the kink's neighbours)
    assert prof.t_m == pytest.approx(19.0)
    with pytest.raises(InfeasibleProfile):
        standing_start(10.0, 9.0, 40.0, 2.5, 10.0)
