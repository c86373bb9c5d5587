"""Newton-Raphson-flow tracking, paper eqs. (11)-(16).

Predictor (eqs. 13-14): hold ``u`` constant over ``[t, t+T]``, integrate ``xi' = f(xi, u)`` from
``xi(t) = x(t)`` by forward Euler with step ``Dt``; ``g(x, u) = h(xi(t+T)) = (xi_1, xi_2)``.

Jacobian: the exact derivative of the Euler predictor is the discrete sensitivity recursion
``Psi_{k+1} = Psi_k + Dt (f_x(xi_k, u) Psi_k + f_u(xi_k, u))``, ``Psi_0 = 0``; ``dg/du`` is the
first two rows of ``Psi_N`` (one pass beside the prediction instead of m+1 passes of finite
differences).

Update law (eq. 12): ``u' = alpha (dg/du)^-1 (r(t+T) - g(x, u))``, integrated by forward Euler at
the plant step. Near standstill the steering column of ``dg/du`` vanishes; the inverse is then
regularised as damped least squares ``(J^T J + lambda I)^-1 J^T`` with
``lambda = damping * trace(J^T J)`` (scale-free; ``damping`` ~1e-6 leaves a well-conditioned
``J`` untouched).

Units: positions [m], time [s], ``u = (a_l [m/s^2], delta_f [rad])``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from nrtraffic.vehicle.bicycle import dynamics, jacobians


@njit(cache=True)
def predict(x, u, p, horizon, dt_pred, want_jac, g, J):
    """Euler predictor of eqs. (13)-(14) with its sensitivity.

    Parameters
    ----------
    x : (6,) state at time t.
    u : (2,) input held over the horizon.
    p : predictor model parameters (may differ from the plant's: model error).
    horizon : T [s].
    dt_pred : Euler step Dt [s]; ``round(T / Dt)`` steps are taken.
    want_jac : compute ``J = dg/du`` as well.
    g : (2,) output, predicted position ``(z1, z2)(t+T)`` [m].
    J : (2, 2) output, ``dg/du`` [m per (m/s^2), m per rad].
    """
    n = int(round(horizon / dt_pred))
    xi = x.copy()
    f = np.empty(6)
    fx = np.empty((6, 6))
    fu = np.empty((6, 2))
    psi = np.zeros((6, 2))
    dpsi = np.empty((6, 2))
    for _ in range(n):
        if want_jac:
            jacobians(xi, u, p, fx, fu)
            # dpsi = fx @ psi + fu (explicit loops: 6x6x2, cheaper than a BLAS call)
            for i in range(6):
                for j in range(2):
                    acc = fu[i, j]
                    for k in range(6):
                        acc += fx[i, k] * psi[k, j]
                    dpsi[i, j] = acc
        dynamics(xi, u, p, f)
        for i in range(6):
            xi[i] += dt_pred * f[i]
        if want_jac:
            for i in range(6):
                for j in range(2):
                    psi[i, j] += dt_pred * dpsi[i, j]
    g[0] = xi[0]
    g[1] = xi[1]
    if want_jac:
        for i in range(2):
            for j in range(2):
                J[i, j] = psi[i, j]


@njit(cache=True)
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


@njit(cache=True)
def nr_update(x, u, p_pred, ref_future, horizon, dt_pred, alpha, damping, h, u_lo, u_hi, u_out, free_a=True,
              free_d=True, tx=1.0, ty=0.0):
    """One Euler step of the update law, eq. (12): ``u_out = clip(u + h alpha J^-1 (r - g))``.

    ``ref_future`` is ``r(t+T)`` [m]; ``h`` the controller step [s]; ``u_lo``/``u_hi`` the input
    bounds (the integrator restarts from the clipped value: no wind-up).
    ``free_a`` / ``free_d`` false mark an input a barrier overrides. The free input then takes the
    Gauss-Newton step of its own column of ``dg/du`` (``J_k^T e_k / (J_k^T J_k + lambda)``) on its
    share of the error only: the component along the path tangent ``(tx, ty)`` for the
    acceleration, along the normal for the steering. The full Newton step would make the steering
    compensate for an acceleration the barrier does not let through, i.e. swerve to chase the
    along-path error the barrier holds open.
    Returns the prediction error ``|r(t+T) - g|`` [m].
    """
    g = np.empty(2)
    J = np.empty((2, 2))
    predict(x, u, p_pred, horizon, dt_pred, True, g, J)
    e = np.empty(2)
    e[0] = ref_future[0] - g[0]
    e[1] = ref_future[1] - g[1]
    du = np.zeros(2)
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
    return np.sqrt(e[0] * e[0] + e[1] * e[1])
