"""The Newton-Raphson-flow tracker: exact sensitivities, regularised inverse, closed loop."""

import math

import numpy as np
import pytest

from nrtraffic.control.nr_flow import EULER, RK4, new_workspace, nr_direction, nr_update, predict
from nrtraffic.vehicle.bicycle import euler_step
from nrtraffic.vehicle.params import preset

P = preset("paper")
p = P.as_array()
p2 = P.with_mass_factor(2.0).as_array()


def _g(x, u, params=p, T=0.2, dt=0.001, method=EULER):
    g, J = np.empty(2), np.empty((2, 2))
    predict(np.asarray(x, float), np.asarray(u, float), params, T, dt, method, g, J)
    return g, J


@pytest.mark.parametrize("method,dt", [(EULER, 0.001), (RK4, 0.02), (RK4, 0.05)])
@pytest.mark.parametrize("vl", [13.4, 2.0, 1.0, 0.4])
def test_sensitivity_jacobian_matches_finite_differences_of_predictor(vl, method, dt):
    # the exact derivative of the discrete map (Euler, or RK4 with every stage differentiated)
    x = np.array([3.0, -1.0, vl, 0.02 * vl, 0.4, 0.01])
    u = np.array([0.3, 0.04])
    g, J = _g(x, u, p2, dt=dt, method=method)
    for k in range(2):
        e = np.zeros(2)
        e[k] = 1e-6
        num = (_g(x, u + e, p2, dt=dt, method=method)[0] - _g(x, u - e, p2, dt=dt, method=method)[0]) / 2e-6
        assert np.allclose(J[:, k], num, rtol=1e-6, atol=1e-9), k


def _flow(x, u, params, T):
    """Independent reference: the continuous flow of eq. (1) by scipy's DOP853 at tight tolerance."""
    from scipy.integrate import solve_ivp

    from nrtraffic.vehicle.bicycle import dynamics

    uu = np.asarray(u, float)

    def f(_, y):
        out = np.empty(6)
        dynamics(y, uu, params, out)
        return out

    return solve_ivp(f, (0.0, T), np.asarray(x, float), method="DOP853", rtol=1e-12, atol=1e-12).y[:2, -1]


@pytest.mark.parametrize("vl", [13.4, 8.0, 3.0, 1.5, 1.0])
def test_rk4_predictor_matches_the_continuous_flow(vl):
    # RK4 at Dt = 0.02 s predicts the flow far better than the paper's Euler at 0.001 s, at every
    # speed (the stiffness guard shortens the step where the tyre modes are fast)
    x = np.array([0.0, 0.0, vl, 0.01 * vl, 0.2, 0.05])
    u = np.array([0.5, 0.03])
    ref = _flow(x, u, p, 0.2)
    err_rk4 = np.abs(_g(x, u, p, dt=0.02, method=RK4)[0] - ref).max()
    err_euler = np.abs(_g(x, u, p, dt=0.001, method=EULER)[0] - ref).max()
    # below ~3 m/s the guard's step is at the edge of RK4's stability region: 3.5e-6 m at 1.5 m/s
    assert err_rk4 < (1e-6 if vl >= 3.0 else 5e-6)
    assert err_rk4 < 0.1 * err_euler


def test_stiffness_is_the_spectral_radius_of_the_lateral_yaw_block():
    # against numpy's eigenvalues of the Jacobian of eq. (1) (the reference implementation) at a
    # small-slip state, where the linear-tyre block the guard uses is exact
    from nrtraffic.control.nr_flow import stiffness
    from nrtraffic.vehicle.bicycle import jacobians

    for vl in (13.9, 6.5, 3.0, 1.5):
        fx, fu = np.empty((6, 6)), np.empty((6, 2))
        jacobians(np.array([0.0, 0.0, vl, 0.0, 0.3, 0.0]), np.zeros(2), p, fx, fu)
        block = fx[np.ix_([3, 5], [3, 5])]
        assert stiffness(vl, p) == pytest.approx(np.abs(np.linalg.eigvals(block)).max(), rel=1e-12)


def test_rk4_predictor_converges_at_fourth_order():
    x = np.array([0.0, 0.0, 10.0, 0.1, 0.2, 0.3])
    u = np.array([1.0, 0.1])
    ref = _flow(x, u, p, 0.2)
    e1 = np.abs(_g(x, u, p, dt=0.02, method=RK4)[0] - ref).max()
    e2 = np.abs(_g(x, u, p, dt=0.01, method=RK4)[0] - ref).max()
    assert 12.0 < e1 / e2 < 22.0  # 2^4 = 16 in the limit (18.7 at these steps)


def test_predictor_is_euler_of_the_plant():
    x = np.array([0.0, 0.0, 10.0, 0.1, 0.2, 0.05])
    u = np.array([0.5, 0.03])
    g, _ = _g(x, u, p, T=0.3, dt=0.001)
    xe = x.copy()
    w = np.empty(6)
    for _ in range(300):
        euler_step(xe, u, p, 0.001, w)
    assert np.allclose(g, xe[:2], atol=1e-12)


def test_nr_direction_is_the_inverse_without_damping_and_finite_when_singular():
    J = np.array([[0.02, 0.001], [-0.003, 0.9]])
    e = np.array([0.1, -0.2])
    du = np.empty(2)
    nr_direction(J, e, 0.0, du)
    assert np.allclose(du, np.linalg.solve(J, e))
    # standstill: steering column zero -> no steering change, acceleration still solved
    Js = np.array([[0.02, 0.0], [0.0, 0.0]])
    nr_direction(Js, e, 1e-6, du)
    assert np.all(np.isfinite(du)) and du[1] == 0.0
    assert du[0] == pytest.approx(0.1 / 0.02, rel=1e-5)


def _closed_loop(x0, ref, n, T=0.2, h=0.005, params_pred=p2, method=EULER, dt_pred=0.001):
    x = np.array(x0, float)
    ws = new_workspace()
    u, un, w = np.zeros(2), np.zeros(2), np.empty(6)
    lo, hi = np.array([-6.0, -math.pi / 4]), np.array([3.0, math.pi / 4])
    errs = []
    for k in range(n):
        t = k * h
        nr_update(x, u, params_pred, ref(t + T), T, dt_pred, method, 100.0, 1e-6, h, lo, hi, un, *ws)
        euler_step(x, u, p, h, w)
        u[:] = un
        errs.append(np.hypot(*(x[:2] - ref(t + h))))
    return np.array(errs), x


@pytest.mark.parametrize("method,dt", [(EULER, 0.001), (RK4, 0.02)])
def test_closed_loop_converges_to_a_straight_reference_with_model_error(method, dt):
    v = 13.4
    errs, x = _closed_loop([0.0, 0.5, v, 0, 0, 0], lambda t: np.array([v * t, 0.0]), 2000, method=method, dt_pred=dt)
    assert errs[0] > 0.4
    assert errs[-400:].max() < 1e-3  # converged within 10 s, despite the 2x predictor mass
    assert abs(x[4]) < 1e-3


@pytest.mark.parametrize("method,dt", [(EULER, 0.001), (RK4, 0.02)])
def test_closed_loop_tracks_a_stop_and_go_reference(method, dt):
    # decelerate 13.4 -> 0 at 2 m/s^2, stand 3 s, accelerate at 1 m/s^2: finite, no reversing, tracks
    def ref(t):
        t1 = 6.7
        if t < t1:
            s = 13.4 * t - t * t
        elif t < t1 + 3.0:
            s = 13.4 * t1 - t1 * t1
        else:
            s = 13.4 * t1 - t1 * t1 + 0.5 * (t - t1 - 3.0) ** 2
        return np.array([s, 0.0])

    errs, x = _closed_loop([0.0, 0.0, 13.4, 0, 0, 0], ref, 3000, method=method, dt_pred=dt)
    assert np.all(np.isfinite(errs))
    assert errs.max() < 0.05
    assert x[2] == pytest.approx(1.0 * (15.0 - 9.7), abs=0.05)


def test_prediction_stops_at_standstill_and_does_not_reverse():
    """A held braking input over a horizon longer than the stop: the predicted position is the
    stopping point v^2 / (2 |a|) within one predictor step's travel, not a point behind the car;
    the acceleration column of the sensitivity stays positive (the flow can release the brake)."""
    import numpy as np

    from nrtraffic.control.nr_flow import RK4, predict
    from nrtraffic.vehicle.params import preset

    p = preset("paper").as_array()
    g, J = np.zeros(2), np.zeros((2, 2))
    for v0, a in ((1.0, -6.0), (2.0, -3.0), (0.0, -1.0)):
        predict(np.array([0.0, 0.0, v0, 0.0, 0.0, 0.0]), np.array([a, 0.0]), p, 8.0, 0.1, RK4, g, J)
        stop = v0 * v0 / (2.0 * abs(a))
        assert stop - 0.1 * v0 <= g[0] <= stop + 1e-9 and abs(g[1]) < 1e-9
        assert J[0, 0] > 0.0
