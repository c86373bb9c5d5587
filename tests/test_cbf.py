"""Barrier functions: values and derivatives against finite differences, the QP against its closed
form, the lateral bisection against an independent root finder."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from nrtraffic.control import cbf
from nrtraffic.vehicle.bicycle import euler_step
from nrtraffic.vehicle.params import preset

P = preset("paper")
p = P.as_array()


def _simulate(x0, u, n, h=1e-4):
    x = np.array(x0, float)
    w = np.empty(6)
    out = [x.copy()]
    for _ in range(n):
        euler_step(x, np.asarray(u, float), p, h, w)
        out.append(x.copy())
    return np.array(out)


@pytest.mark.parametrize("c", [0.0, 0.1])
def test_longitudinal_barrier_derivative_matches_finite_differences(c):
    h_step = 1e-4
    x0 = [0.0, 0.3, 8.0, 0.05, 0.03, 0.02]
    u = (-0.7, 0.02)
    xs = _simulate(x0, u, 2000, h_step)
    # leader ahead with constant acceleration
    L0 = np.array([14.0, 0.0, 6.0, 0.0, -0.8, 0.0])

    def lead(t):
        return np.array([L0[0] + L0[2] * t + 0.5 * L0[4] * t * t, 0.0, L0[2] + L0[4] * t, 0.0, L0[4], 0.0])

    d0, a_bar, gain = 5.0, 3.0, 1.0
    hs = []
    for k, x in enumerate(xs):
        Ld = lead(k * h_step)
        vx, vy = cbf.world_velocity(x)
        hs.append(cbf.long_barrier(Ld[0] - x[0], Ld[1] - x[1], Ld[2] - vx, Ld[3] - vy, d0, a_bar, c))
    hs = np.array(hs)
    for k in (200, 1000, 1800):
        hb, G, b = cbf.long_constraint(xs[k], u[1], p, lead(k * h_step), d0, a_bar, gain, c)
        assert hb == pytest.approx(hs[k], rel=1e-12)
        hdot = (b - gain * hb) - G * u[0]
        fd = (hs[k + 1] - hs[k - 1]) / (2 * h_step)
        assert hdot == pytest.approx(fd, rel=2e-3, abs=2e-4)


def test_barrier_is_the_stopping_distance_condition():
    # h >= 0 iff braking at a_bar stops the closing before d0 (constant-velocity leader)
    d0, a_bar = 5.0, 3.0
    for r, closing in [(10.0, 5.0), (10.0, 5.6), (6.0, 2.4), (6.0, 2.5)]:
        h = cbf.long_barrier(r, 0.0, -closing, 0.0, d0, a_bar)
        stop = r - closing**2 / (2 * a_bar)
        assert (h >= 0) == (stop >= d0)


def test_closed_form_and_qp_agree_on_random_cases():
    rng = np.random.default_rng(11)
    n_inf = 0
    for _ in range(300):
        a_star = rng.uniform(-8, 8)
        G = rng.choice([rng.uniform(-2, 2), 0.0, 1e-14]) if rng.random() < 0.2 else rng.uniform(-2, 2)
        b = rng.uniform(-10, 10)
        lo, hi = -6.0, 3.0
        a1, s1 = cbf.long_filter_closed(a_star, G, b, lo, hi)
        a2, s2 = cbf.long_filter_qp(a_star, G, b, lo, hi, "osqp")
        n_inf += s1 == cbf.FALLBACK
        assert s1 == s2 or (s1 != cbf.FALLBACK and s2 != cbf.FALLBACK and abs(a1 - a2) < 1e-5), (a_star, G, b)
        assert a1 == pytest.approx(a2, abs=1e-5)
        if s1 != cbf.FALLBACK:
            assert G * a1 <= b + 1e-9 and lo - 1e-12 <= a1 <= hi + 1e-12
    assert n_inf > 10  # the random set does contain infeasible cases


def test_infeasible_qp_returns_maximal_braking():
    # constraint a <= -10 with a >= -6: infeasible
    assert cbf.long_filter_closed(0.5, 1.0, -10.0, -6.0, 3.0) == (-6.0, cbf.FALLBACK)
    assert cbf.long_filter_qp(0.5, 1.0, -10.0, -6.0, 3.0)[1] == cbf.FALLBACK
    # undefined constraint (vehicles on top of each other)
    assert cbf.long_filter_closed(0.5, np.nan, np.nan, -6.0, 3.0) == (-6.0, cbf.FALLBACK)
    # active but feasible: the closest admissible value
    a, st = cbf.long_filter_closed(2.0, 2.0, 1.0, -6.0, 3.0)
    assert st == cbf.ACTIVE and a == pytest.approx(0.5)


def test_lateral_barrier_value_and_derivative_on_a_straight_lane():
    h_step = 1e-4
    u = (0.0, -0.05)
    xs = _simulate([0.0, 0.1, 5.0, 0.0, 0.12, 0.0], u, 3000, h_step)
    y_max, k, gamma = 0.5, 0.25, 15.0
    vals = np.array([cbf.lat_barrier(x[1], cbf.world_velocity(x)[1], y_max, k) for x in xs])
    for i in (500, 1500, 2500):
        cond, h = cbf.lat_condition(xs[i], u[0], u[1], p, xs[i, 1], 1.0, 0.0, 0.0, y_max, k, gamma)
        assert h == pytest.approx(vals[i])
        fd = (vals[i + 1] - vals[i - 1]) / (2 * h_step)
        assert cond - gamma * h**3 == pytest.approx(fd, rel=2e-3, abs=1e-5)


def test_lateral_derivative_on_a_curved_lane():
    # circle of radius R around (0, R), travelled counter-clockwise: y = R - |z - c| (left positive)
    R = 60.0
    h_step = 1e-5
    u = (0.0, 0.06)
    xs = _simulate([0.0, -0.2, 6.0, 0.0, 0.05, 0.1], u, 20000, h_step)
    y_max, k, gamma = 0.5, 0.25, 15.0

    def lat(x):
        dz = x[:2] - np.array([0.0, R])
        return R - np.hypot(*dz)

    def tangent(x):
        dz = x[:2] - np.array([0.0, R])
        n = -dz / np.hypot(*dz)  # towards the centre = left of travel
        return n[1], -n[0]

    def ydot(x):
        dz = x[:2] - np.array([0.0, R])
        vx, vy = cbf.world_velocity(x)
        return -(dz[0] * vx + dz[1] * vy) / np.hypot(*dz)

    vals = np.array([cbf.lat_barrier(lat(x), ydot(x), y_max, k) for x in xs])
    for i in (4000, 10000, 16000):
        tx, ty = tangent(xs[i])
        cond, h = cbf.lat_condition(xs[i], u[0], u[1], p, lat(xs[i]), tx, ty, 1.0 / R, y_max, k, gamma)
        assert h == pytest.approx(vals[i], abs=1e-9)
        fd = (vals[i + 1] - vals[i - 1]) / (2 * h_step)
        assert cond - gamma * h**3 == pytest.approx(fd, rel=5e-3, abs=1e-5)


def test_lateral_bisection_finds_the_closest_admissible_steering():
    y_max, k, gamma, d_max = 0.5, 0.25, 15.0, math.pi / 4
    # drifting left fast near the bound: turning further left is inadmissible
    x = np.array([0.0, 0.35, 3.0, 0.0, 0.2, 0.0])
    y = x[1]
    d_star = 0.3

    def C(d):
        return cbf.lat_condition(x, 0.0, d, p, y, 1.0, 0.0, 0.0, y_max, k, gamma)[0]

    assert C(d_star) < 0 and C(-d_max) >= 0
    d, st, _ = cbf.lat_filter(x, 0.0, d_star, p, y, 1.0, 0.0, 0.0, y_max, k, gamma, d_max, 1e-10)
    assert st == cbf.ACTIVE
    root = brentq(C, -d_max, d_star, xtol=1e-12)  # independent root finder
    assert d == pytest.approx(root, abs=1e-8)
    # an admissible tracker steering is kept
    d2, st2, _ = cbf.lat_filter(x, 0.0, -0.5, p, y, 1.0, 0.0, 0.0, y_max, k, gamma, d_max, 1e-10)
    assert st2 == cbf.INACTIVE and d2 == -0.5


def test_lateral_filter_without_admissible_steering_is_best_effort():
    # far outside the set and moving away faster than any steering can fix within one step
    x = np.array([0.0, 1.5, 0.3, 0.0, 1.2, 0.0])
    d, st, h = cbf.lat_filter(x, 0.0, 0.0, p, 1.5, 1.0, 0.0, 0.0, 0.5, 0.25, 15.0, math.pi / 4, 1e-8)
    assert st == cbf.FALLBACK and h < 0
    c_lo = cbf.lat_condition(x, 0.0, -math.pi / 4, p, 1.5, 1.0, 0.0, 0.0, 0.5, 0.25, 15.0)[0]
    c_hi = cbf.lat_condition(x, 0.0, math.pi / 4, p, 1.5, 1.0, 0.0, 0.0, 0.5, 0.25, 15.0)[0]
    assert d == (-math.pi / 4 if c_lo > c_hi else math.pi / 4)


def test_lateral_sign_convention_at_zero():
    # y = 0: the excursion counts in the direction of motion; h = y_max when at rest on the centre
    assert cbf.lat_barrier(0.0, 0.0, 0.5, 0.25) == 0.5
    assert cbf.lat_barrier(0.0, 0.4, 0.5, 0.25) == pytest.approx(0.5 - 0.25 * 0.16)
    assert cbf.lat_barrier(0.0, -0.4, 0.5, 0.25) == pytest.approx(0.5 - 0.25 * 0.16)
