"""Newton-Raphson-flow tracking, paper eqs. (11)-(16).

Predictor (eqs. 13-14): hold ``u`` constant over ``[t, t+T]``, integrate ``xi' = f(xi, u)`` from
``xi(t) = x(t)``; ``g(x, u) = h(xi(t+T)) = (xi_1, xi_2)``. Two integrators
(``controller.predictor``): forward Euler with step ``Dt`` (the paper's, ``Dt`` = 0.001 s) and the
classical fourth-order Runge-Kutta method (RK4), whose error at ``Dt`` = 0.02 s is far below
Euler's at 0.001 s for a twentieth of the evaluations (docs/method.md).

Jacobian: ``dg/du`` is the exact derivative of the *discrete* predictor, by the sensitivity
recursion that differentiates the integrator's own update (one pass beside the prediction instead
of m+1 passes of finite differences). For Euler,
``Psi_{k+1} = Psi_k + Dt (f_x(xi_k) Psi_k + f_u(xi_k))``; for RK4 every stage is differentiated,
``dK_1 = f_x(xi_k) Psi_k + f_u``, ``dK_2 = f_x(xi_k + Dt/2 K_1) (Psi_k + Dt/2 dK_1) + f_u``, ...,
``Psi_{k+1} = Psi_k + Dt/6 (dK_1 + 2 dK_2 + 2 dK_3 + dK_4)``, ``Psi_0 = 0``. ``dg/du`` is the
first two rows of ``Psi_N``.

Stiffness guard: the lateral and yaw modes of eq. (1) are fast at low speed: with the paper's
parameters their eigenvalues are about -172 and -65 1/s at 1.5 m/s (a complex pair of modulus 14
1/s at 13.9 m/s; :func:`stiffness`). An explicit method is stable only while ``Dt |lambda|`` stays
inside its stability region (to 2 on the negative real axis for Euler, 2.785 for RK4). The step
count is ``max(round(T / Dt), ceil(T rho / c))`` with ``rho`` the spectral radius at the current
speed and ``c`` = 1.8 (Euler) or 2.5 (RK4), under the limits. The step is then ``T / n``: with
``T`` = 0.2 s and ``Dt`` = 0.1 s, RK4 takes 2 steps at 13.9 m/s, 3 at 6.5 m/s and 14 at 1.5 m/s.

No reversing: like the plant (``bicycle.euler_step``), the prediction stops at ``v_l = 0`` (clamped
after every integrator step; a car standing under a braking input then holds its state) instead of
driving backwards under a held braking input: over a long horizon (8 s in the paper's barrier
experiment) a prediction through zero speed spins the car round, and the flow chases it. The
sensitivity recursion runs on while the car stands, so that the flow can still pull a braking
input back up from a standstill.

Update law (eq. 12): ``u' = alpha (dg/du)^-1 (r(t+T) - g(x, u))``, integrated by forward Euler at
the plant step. Near standstill the steering column of ``dg/du`` vanishes; the inverse is then
regularised as damped least squares ``(J^T J + lambda I)^-1 J^T`` with
``lambda = damping * trace(J^T J)`` (scale-free; ``damping`` ~1e-6 leaves a well-conditioned
``J`` untouched).

Units: positions [m], time [s], ``u = (a_l [m/s^2], delta_f [rad])``. The predictor works on
scalars and :func:`nr_update` on a workspace (:func:`new_workspace`), so that nothing is allocated
per call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from nrtraffic.vehicle.bicycle import blend_weight, rhs_tangent_s

EULER, RK4 = 0, 1
PREDICTORS = {"euler": EULER, "rk4": RK4}
_STABLE = (1.8, 2.5)  # Dt * rho allowed for Euler, RK4 (real-axis stability limits 2 and 2.785)
_V_FLOOR = 0.1  # as in the model's tyre terms [m/s]


@njit(cache=True)
def new_workspace():
    """Scratch for :func:`nr_update`: ``(vectors (3, 2), matrix (2, 2))``: the prediction ``g``, the
    error and the step; ``J``."""
    return np.zeros((3, 2)), np.zeros((2, 2))


@njit(cache=True, error_model="numpy")
def stiffness(vl, p):
    """Spectral radius [1/s] of the lateral-yaw block of eq. (1)'s Jacobian at speed ``vl`` [m/s],
    for the linear tyre (small slip, where the tyres are stiffest), blended like the model below
    ``v_blend_high`` with the kinematic block's ``2 / tau_kin``."""
    m, Iz, lf, lr, Caf, Car, tau = p[0], p[1], p[2], p[3], p[4], p[5], p[8]
    w, _ = blend_weight(vl, p)
    v = max(vl, _V_FLOOR)
    a33 = -2.0 * (Caf + Car) / (m * v)
    a35 = -v - 2.0 * (lf * Caf - lr * Car) / (m * v)
    a53 = -2.0 * (lf * Caf - lr * Car) / (Iz * v)
    a55 = -2.0 * (lf * lf * Caf + lr * lr * Car) / (Iz * v)
    tr = a33 + a55
    det = a33 * a55 - a35 * a53
    disc = tr * tr - 4.0 * det
    if disc >= 0.0:  # two real eigenvalues: the larger magnitude
        rho = 0.5 * (abs(tr) + math.sqrt(disc))
    else:  # a complex pair: |lambda| = sqrt(det)
        rho = math.sqrt(det)
    return w * rho + (1.0 - w) * 2.0 / tau


@njit(cache=True, error_model="numpy")
def predictor_steps(vl, p, horizon, dt_pred, method):
    """Number of integrator steps over the horizon (see the stiffness guard above)."""
    n = max(1, int(round(horizon / dt_pred)))
    need = int(math.ceil(horizon * stiffness(vl, p) / _STABLE[method]))
    return max(n, need)


@njit(cache=True, error_model="numpy")
def predict(x, u, p, horizon, dt_pred, method, g, J):
    """Predictor of eqs. (13)-(14) with its exact sensitivity.

    Parameters
    ----------
    x : (6,) state at time t.
    u : (2,) input held over the horizon.
    p : predictor model parameters (may differ from the plant's: model error).
    horizon : T [s].
    dt_pred : nominal step Dt [s] (see the stiffness guard).
    method : EULER or RK4.
    g : (2,) output, predicted position ``(z1, z2)(t+T)`` [m].
    J : (2, 2) or larger output, ``dg/du`` [m per (m/s^2), m per rad] in its top-left block.

    The steps run on scalars, so that they stay in registers: the state ``x0..x5``, the
    sensitivity ``P00..P51`` (row, column; zero at t), a stage's ``f`` ``k0..k5`` and its
    ``f_x P + f_u`` ``e00..e51``; ``s*`` and ``q*`` sum RK4's stages with their weights. A car
    standing under a braking input holds its state (the plant does not reverse), while ``P`` takes
    an Euler step, so that ``dg/du`` says how far releasing the brake would take it.
    """
    n = predictor_steps(x[2], p, horizon, dt_pred, method)
    h = horizon / n
    a = u[0]
    d = u[1]
    cd = math.cos(d)
    sd = math.sin(d)
    td = math.tan(d)
    x0, x1, x2, x3, x4, x5 = x[0], x[1], x[2], x[3], x[4], x[5]
    P00 = P01 = P10 = P11 = P20 = P21 = P30 = P31 = P40 = P41 = P50 = P51 = 0.0
    hh = 0.5 * h
    h6 = h / 6.0
    for _ in range(n):
        standing = x2 <= 0.0 and a + x5 * x3 <= 0.0
        # Euler's step, and RK4's first stage, at the step's start
        (k0, k1, k2, k3, k4, k5, e00, e01, e10, e11, e20, e21, e30, e31, e40, e41, e50, e51) = rhs_tangent_s(
            x2, x3, x5, math.cos(x4), math.sin(x4), a, d, cd, sd, td, p, P20, P21, P30, P31, P40, P41, P50, P51)
        if standing or method == EULER:
            P00 += h * e00; P01 += h * e01; P10 += h * e10; P11 += h * e11; P20 += h * e20; P21 += h * e21
            P30 += h * e30; P31 += h * e31; P40 += h * e40; P41 += h * e41; P50 += h * e50; P51 += h * e51
            if standing:
                continue
            x0 += h * k0; x1 += h * k1; x2 += h * k2; x3 += h * k3; x4 += h * k4; x5 += h * k5
        else:
            s0, s1, s2, s3, s4, s5 = k0, k1, k2, k3, k4, k5
            q00, q01, q10, q11, q20, q21, q30, q31, q40, q41, q50, q51 = (
                e00, e01, e10, e11, e20, e21, e30, e31, e40, e41, e50, e51)
            # stages 2 and 3 at the start + h/2 K (the previous stage's), weight 2
            for _stage in range(2):
                y4 = x4 + hh * k4
                (k0, k1, k2, k3, k4, k5, e00, e01, e10, e11, e20, e21, e30, e31, e40, e41, e50, e51) = rhs_tangent_s(
                    x2 + hh * k2, x3 + hh * k3, x5 + hh * k5, math.cos(y4), math.sin(y4), a, d, cd, sd, td, p,
                    P20 + hh * e20, P21 + hh * e21, P30 + hh * e30, P31 + hh * e31,
                    P40 + hh * e40, P41 + hh * e41, P50 + hh * e50, P51 + hh * e51)
                s0 += 2.0 * k0; s1 += 2.0 * k1; s2 += 2.0 * k2; s3 += 2.0 * k3; s4 += 2.0 * k4; s5 += 2.0 * k5
                q00 += 2.0 * e00; q01 += 2.0 * e01; q10 += 2.0 * e10; q11 += 2.0 * e11
                q20 += 2.0 * e20; q21 += 2.0 * e21; q30 += 2.0 * e30; q31 += 2.0 * e31
                q40 += 2.0 * e40; q41 += 2.0 * e41; q50 += 2.0 * e50; q51 += 2.0 * e51
            # stage 4 at the start + h K_3
            y4 = x4 + h * k4
            (k0, k1, k2, k3, k4, k5, e00, e01, e10, e11, e20, e21, e30, e31, e40, e41, e50, e51) = rhs_tangent_s(
                x2 + h * k2, x3 + h * k3, x5 + h * k5, math.cos(y4), math.sin(y4), a, d, cd, sd, td, p,
                P20 + h * e20, P21 + h * e21, P30 + h * e30, P31 + h * e31,
                P40 + h * e40, P41 + h * e41, P50 + h * e50, P51 + h * e51)
            x0 += h6 * (s0 + k0); x1 += h6 * (s1 + k1); x2 += h6 * (s2 + k2)
            x3 += h6 * (s3 + k3); x4 += h6 * (s4 + k4); x5 += h6 * (s5 + k5)
            P00 += h6 * (q00 + e00); P01 += h6 * (q01 + e01); P10 += h6 * (q10 + e10); P11 += h6 * (q11 + e11)
            P20 += h6 * (q20 + e20); P21 += h6 * (q21 + e21); P30 += h6 * (q30 + e30); P31 += h6 * (q31 + e31)
            P40 += h6 * (q40 + e40); P41 += h6 * (q41 + e41); P50 += h6 * (q50 + e50); P51 += h6 * (q51 + e51)
        if x2 < 0.0:  # as the plant: it brakes to a stop, it does not reverse
            x2 = 0.0
    g[0] = x0
    g[1] = x1
    J[0, 0] = P00
    J[0, 1] = P01
    J[1, 0] = P10
    J[1, 1] = P11


@njit(cache=True, error_model="numpy")
def nr_direction(J, e, damping, du):
    """``du = (J^T J + lambda I)^-1 J^T e`` with ``lambda = damping * trace(J^T J)`` (2x2)."""
    a11 = J[0, 0] * J[0, 0] + J[1, 0] * J[1, 0]
    a22 = J[0, 1] * J[0, 1] + J[1, 1] * J[1, 1]
    a12 = J[0, 0] * J[0, 1] + J[1, 0] * J[1, 1]
    lam = damping * (a11 + a22) + 1e-300
    a11 += lam
    a22 += lam
    b1 = J[0, 0] * e[0] + J[1, 0] * e[1]
    b2 = J[0, 1] * e[0] + J[1, 1] * e[1]
    det = a11 * a22 - a12 * a12
    du[0] = (a22 * b1 - a12 * b2) / det
    du[1] = (a11 * b2 - a12 * b1) / det


@njit(cache=True, error_model="numpy")
def nr_update(x, u, p_pred, ref_future, horizon, dt_pred, method, alpha, damping, h, u_lo, u_hi, u_out, ws, wsP,
              free_a=True, free_d=True, tx=1.0, ty=0.0):
    """One Euler step of the update law, eq. (12): ``u_out = clip(u + h alpha J^-1 (r - g))``.

    ``ref_future`` is ``r(t+T)`` [m]; ``method`` the predictor (EULER, RK4); ``h`` the controller
    step [s]; ``ws, wsP`` the workspace; ``u_lo``/``u_hi`` the input
    bounds (the integrator restarts from the clipped value: no wind-up).
    ``free_a`` / ``free_d`` false mark an input a barrier overrides. The free input then takes the
    Gauss-Newton step of its own column of ``dg/du`` (``J_k^T e_k / (J_k^T J_k + lambda)``) on its
    share of the error only: the component along the path tangent ``(tx, ty)`` for the
    acceleration, along the normal for the steering. The full Newton step would make the steering
    compensate for an acceleration the barrier does not let through, i.e. swerve to chase the
    along-path error the barrier holds open.
    Returns the prediction error ``|r(t+T) - g|`` [m].
    """
    g, e, du = ws[0], ws[1], ws[2]
    J = wsP
    predict(x, u, p_pred, horizon, dt_pred, method, g, J)
    e[0] = ref_future[0] - g[0]
    e[1] = ref_future[1] - g[1]
    nr_direction(J, e, damping, du)
    for k in range(2):
        if (k == 0 and not free_d and free_a) or (k == 1 and not free_a and free_d):
            # the other input is pinned: this one takes the Gauss-Newton step of its own column on
            # its own share of the error; the pinned one keeps its Newton step (it keeps pressing
            # against the barrier, which pins it again next step)
            dx = tx if k == 0 else -ty
            dy = ty if k == 0 else tx
            ek = e[0] * dx + e[1] * dy
            n2 = J[0, k] * J[0, k] + J[1, k] * J[1, k]
            du[k] = (J[0, k] * dx + J[1, k] * dy) * ek / (n2 * (1.0 + damping) + 1e-300)
    for i in range(2):
        v = u[i] + h * alpha * du[i]
        if v < u_lo[i]:
            v = u_lo[i]
        elif v > u_hi[i]:
            v = u_hi[i]
        u_out[i] = v
    return math.sqrt(e[0] * e[0] + e[1] * e[1])
