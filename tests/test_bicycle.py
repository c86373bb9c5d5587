"""The plant against finite differences and closed forms."""

import math

import numpy as np
import pytest

from nrtraffic.vehicle.bicycle import dynamics, euler_step_limit, euler_step_limit_at, jacobians, rhs_tangent_s, simulate
from nrtraffic.vehicle.params import BicycleParams, preset

P = preset("paper")
p = P.as_array()


def _f(x, u):
    out = np.empty(6)
    dynamics(np.asarray(x, float), np.asarray(u, float), p, out)
    return out


@pytest.mark.parametrize("vl", [15.0, 3.0, 1.4, 1.0, 0.7, 0.3, 0.0])
def test_jacobians_match_finite_differences(vl):
    rng = np.random.default_rng(int(vl * 10))
    for _ in range(5):
        x = np.array([rng.normal(), rng.normal(), vl, 0.05 * rng.normal() * max(vl, 0.1), rng.uniform(-3, 3),
                      0.1 * rng.normal()])
        u = np.array([rng.normal(), 0.2 * rng.normal()])
        fx, fu = np.empty((6, 6)), np.empty((6, 2))
        jacobians(x, u, p, fx, fu)
        for k in range(6):
            h = 1e-6
            if k == 2 and vl == 0.0:
                continue  # v_l = 0 is the edge of the blend's flat region
            e = np.zeros(6)
            e[k] = h
            num = (_f(x + e, u) - _f(x - e, u)) / (2 * h)
            assert np.allclose(fx[:, k], num, rtol=1e-5, atol=1e-5 * (1 + np.abs(num).max())), (vl, k)
        for k in range(2):
            h = 1e-7
            e = np.zeros(2)
            e[k] = h
            num = (_f(x, u + e) - _f(x, u - e)) / (2 * h)
            assert np.allclose(fu[:, k], num, rtol=1e-5, atol=1e-5 * (1 + np.abs(num).max())), (vl, k)


@pytest.mark.parametrize("vl", [15.0, 3.0, 1.4, 1.0, 0.7, 0.3, 0.0])
def test_fused_tangent_equals_dynamics_and_jacobian_product(vl):
    # rhs_tangent_s is dynamics + f_x P + f_u in one pass, using only f_x's non-zero entries
    rng = np.random.default_rng(100 + int(vl * 10))
    for _ in range(10):
        x = np.array([rng.normal(), rng.normal(), vl, 0.05 * rng.normal() * max(vl, 0.1), rng.uniform(-3, 3),
                      0.1 * rng.normal()])
        a, d = rng.normal(), 0.2 * rng.normal()
        P = rng.normal(size=(6, 2))
        fx, fu = np.empty((6, 6)), np.empty((6, 2))
        jacobians(x, np.array([a, d]), p, fx, fu)
        r = rhs_tangent_s(x[2], x[3], x[5], math.cos(x[4]), math.sin(x[4]), a, d, math.cos(d), math.sin(d),
                          math.tan(d), p, *P[2:].ravel())  # rows 2-5 of P, row by row
        f, dP = np.array(r[:6]), np.array(r[6:]).reshape(6, 2)
        assert np.allclose(f, _f(x, [a, d]), rtol=1e-13, atol=1e-13)
        ref = fx @ P + fu
        assert np.allclose(dP, ref, rtol=1e-12, atol=1e-12 * (1 + np.abs(ref).max()))


def test_straight_constant_speed_moves_v_t():
    h, n, v = 0.005, 2000, 13.4
    psi = 0.7
    xs = simulate([1.0, -2.0, v, 0.0, psi, 0.0], [0.0, 0.0], p, h, n)
    t = h * n
    assert xs[-1, 0] == pytest.approx(1.0 + v * t * math.cos(psi), abs=1e-9)
    assert xs[-1, 1] == pytest.approx(-2.0 + v * t * math.sin(psi), abs=1e-9)
    assert np.abs(xs[:, 3]).max() < 1e-12 and np.abs(xs[:, 5]).max() < 1e-12
    assert np.allclose(xs[:, 4], psi)


def test_steady_cornering_matches_linear_bicycle_understeer():
    # independent closed form: r = v delta / (L + K v^2), K = m / L (l_r / C_f - l_f / C_r),
    # axle stiffness C = 2 C_alpha (eq. 1 has two tyres per axle)
    v, delta = 15.0, 0.002
    xs = simulate([0, 0, v, 0, 0, 0], [0.0, delta], p, 0.001, 20000)
    L = P.lf + P.lr
    K = P.m / L * (P.lr / (2 * P.Caf) - P.lf / (2 * P.Car))
    r_expected = v * delta / (L + K * v * v)
    assert xs[-1, 5] == pytest.approx(r_expected, rel=2e-3)


def test_kinematic_limit_at_low_speed():
    # below v_blend_low: no-slip yaw rate v tan(delta) / L and lateral velocity l_r * yaw rate
    v, delta = 0.3, 0.3
    xs = simulate([0, 0, v, 0, 0, 0], [0.0, delta], p, 0.005, 400)
    L = P.lf + P.lr
    vl = xs[-1, 2]  # v_l' = psi_dot v_n lets the speed creep up slightly
    assert vl == pytest.approx(v, rel=0.05)
    assert xs[-1, 5] == pytest.approx(vl * math.tan(delta) / L, rel=1e-4)
    assert xs[-1, 3] == pytest.approx(P.lr * vl * math.tan(delta) / L, rel=1e-4)


def test_finite_and_stable_from_speed_to_standstill_and_back():
    x = np.array([0, 0, 15.0, 0, 0, 0])
    h = 0.005
    hist = []
    # brake to a stop while steering, steer at standstill, accelerate straight, corner, straighten
    for a, d, n in [(-3.0, 0.05, 1400), (0.0, 0.3, 400), (2.0, 0.0, 1600), (0.0, -0.02, 600), (0.0, 0.0, 1000)]:
        xs = simulate(x, [a, d], p, h, n)
        hist.append(xs)
        x = xs[-1]
        if len(hist) == 3:  # from rest, straight: exactly 2 m/s^2 for 8 s
            assert x[2] == pytest.approx(16.0, abs=1e-5)
    allx = np.vstack(hist)
    assert np.all(np.isfinite(allx))
    assert allx[:, 2].min() >= 0.0  # never reverses
    # lateral velocity and yaw rate stay physical (no Euler blow-up near standstill)
    assert np.abs(allx[:, 3]).max() < 2.0 and np.abs(allx[:, 5]).max() < 1.5
    # and settle after the transient (straight, constant speed)
    assert abs(allx[-1, 5]) < 1e-3 and abs(allx[-1, 3]) < 1e-3


def test_invalid_parameters_are_rejected():
    with pytest.raises(ValueError, match="m must be"):
        BicycleParams(m=-1.0)
    with pytest.raises(ValueError, match="unknown vehicle preset"):
        preset("nope")


def test_kernel_plant_step_is_the_forward_euler_step_of_eq_1():
    """The batched kernel advances the plant from body rates it shares with the barriers; one plant
    step of it equals bicycle.euler_step with the input the kernel applied (reported in OUT_A/OUT_D),
    in a turn (curved reference) where steering, lateral and yaw dynamics all act."""
    from nrtraffic.control import batch as kb
    from nrtraffic.geometry import LanePath, segment_frames
    from nrtraffic.vehicle.bicycle import euler_step

    R = 60.0
    th = np.linspace(0.0, 1.5, 400)
    path = LanePath.from_points(np.c_[R * np.sin(th), R * (1 - np.cos(th))])
    x0 = np.array([0.0, 0.05, 8.0, 0.1, 0.02, 0.12])
    X, U = x0[None].copy(), np.array([[0.3, 0.05]])
    prof = np.zeros((1, 5, 5))
    prof[0, :, 0] = np.arange(5) * 1e9
    prof[0, :, 2] = 8.0
    cfg = np.zeros(kb.N_CFG)
    cfg[[kb.CFG_H, kb.CFG_HORIZON, kb.CFG_DT_PRED, kb.CFG_ALPHA, kb.CFG_DAMPING, kb.CFG_STEADY_AFTER,
         kb.CFG_PREDICTOR]] = (0.005, 0.2, 0.1, 100.0, 1e-6, 3.0, 1.0)
    out = np.zeros((1, kb.N_OUT))
    lo, hi = np.array([-6.0, -0.78]), np.array([3.0, 0.78])
    kb.advance(X, U, 0.0, 1, cfg, p, p, lo, hi, prof, np.zeros(1), np.zeros(1), np.zeros(1, dtype=np.int64),
               np.array([0, len(path.s)], dtype=np.int64), path.xy, path.s, segment_frames(path.xy, path.s),
               np.zeros(1, dtype=np.int64), np.full(1, kb.NO_LEADER, dtype=np.int64), np.zeros((1, 6)), kb.new_acc(1),
               out, np.zeros((1, 1, 0)), np.zeros((1, 2)), X.copy(), np.full((1, 2), np.nan))
    ref = x0.copy()
    euler_step(ref, np.array([out[0, kb.OUT_A], out[0, kb.OUT_D]]), p, 0.005, np.empty(6))
    assert np.allclose(X[0], ref, rtol=0.0, atol=1e-12)
    assert not np.allclose(X[0], x0)


def test_euler_step_limit_separates_decay_from_growth():
    """The plant's forward-Euler step limit against the plant itself: a small lateral and yaw
    disturbance at the limiting speed dies out a little below the limit and grows a little above."""
    h_max, v = euler_step_limit(p, 13.9)
    assert 0.005 < h_max < 0.02 and 0.5 < v < 1.5  # stiffest in the blend to the kinematic model
    x0 = [0.0, 0.0, v, 1e-6, 0.0, 1e-6]
    size = []
    for h in (0.97 * h_max, 1.03 * h_max):
        x = simulate(x0, [0.0, 0.0], p, h, 300)
        size.append(abs(x[-1, 3]) + abs(x[-1, 5]))
    assert size[0] < 1e-7  # below the limit: decayed from 2e-6
    assert size[1] > 1e-5  # above it: grown (about 1.06 per step)
    assert euler_step_limit(p, 13.9, dv=0.001)[0] == pytest.approx(h_max, rel=1e-3)  # sampled finely enough


def test_straight_driving_sets_the_step_limit():
    """Slip, yaw rate, steering and acceleration only soften the lateral and yaw modes (the slip
    angles enter through atan, steepest at zero slip): over random states the step that eq. (1)'s
    Jacobian allows is never shorter than the straight-driving limit."""
    h_max, _ = euler_step_limit(p, 13.9)
    rng = np.random.default_rng(1)
    states = [([0.0, 0.0, rng.uniform(0.0, 14.0), rng.uniform(-2.0, 2.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.5, 1.5)],
               [rng.uniform(-6.0, 3.0), rng.uniform(-0.6, 0.6)]) for _ in range(3000)]
    shortest = min(euler_step_limit_at(x, u, p) for x, u in states)
    assert h_max * (1 - 1e-3) <= shortest < 1.2 * h_max  # (and near it: the sample reaches the stiff band)
