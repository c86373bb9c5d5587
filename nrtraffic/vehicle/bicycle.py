"""Dynamic bicycle model, paper eq. (1) (after Kong et al. 2015), with a low-speed treatment.

State ``x = (z1, z2, v_l, v_n, psi, psi_dot)``: centre-of-gravity position [m], longitudinal and
lateral body-frame velocity [m/s], heading [rad] (counter-clockwise from +x), yaw rate [rad/s].
Input ``u = (a_l, delta_f)``: longitudinal acceleration [m/s^2], front steering angle [rad].
Parameters ``p``: :meth:`BicycleParams.as_array`.

The tyre slip angles divide by ``v_l``, so the model is singular at standstill. Below
``v_blend_low`` the lateral/yaw equations are replaced by the kinematic bicycle model (no tyre
slip: ``psi_dot = v_l tan(delta_f) / (l_f + l_r)``, ``v_n = l_r psi_dot``, approached with time
constant ``tau_kin``), blended with a C^1 smoothstep up to ``v_blend_high``. Positions, heading and
``v_l`` follow the same equations in both. The plant never reverses: ``v_l`` is clamped at 0.

All functions are compiled with numba and take ``(x, u, p)`` in that order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# indices into the parameter array (see params.PARAM_NAMES)
_M, _IZ, _LF, _LR, _CAF, _CAR, _VLO, _VHI, _TAU = range(9)
# speed floor used inside the (then zero-weighted) dynamic tyre terms [m/s]
_V_FLOOR = 0.1


@njit(cache=True)
def blend_weight(vl, p):
    """Weight of the dynamic model, smoothstep of ``v_l`` over [v_blend_low, v_blend_high];
    returns (w, dw/dv_l)."""
    lo = p[_VLO]
    hi = p[_VHI]
    s = (vl - lo) / (hi - lo)
    if s <= 0.0:
        return 0.0, 0.0
    if s >= 1.0:
        return 1.0, 0.0
    return s * s * (3.0 - 2.0 * s), 6.0 * s * (1.0 - s) / (hi - lo)


@njit(cache=True)
def dynamics(x, u, p, out):
    """Write f(x, u) of eq. (1) (with the low-speed blend) into ``out`` (length 6)."""
    vl = x[2]
    vn = x[3]
    psi = x[4]
    r = x[5]
    a = u[0]
    d = u[1]
    m = p[_M]
    Iz = p[_IZ]
    lf = p[_LF]
    lr = p[_LR]
    L = lf + lr
    c = math.cos(psi)
    s = math.sin(psi)
    out[0] = vl * c - vn * s
    out[1] = vl * s + vn * c
    vl_dot = r * vn + a
    out[2] = vl_dot
    out[4] = r
    w, _ = blend_weight(vl, p)
    cd = math.cos(d)
    # dynamic model (eq. 1)
    vd = vl if vl > _V_FLOOR else _V_FLOOR
    Fcf = p[_CAF] * (d - math.atan((vn + lf * r) / vd))
    Fcr = -p[_CAR] * math.atan((vn - lr * r) / vd)
    vn_dyn = -r * vl + 2.0 * (Fcf * cd + Fcr) / m
    r_dyn = 2.0 * (lf * Fcf * cd - lr * Fcr) / Iz
    # kinematic model (no slip), first-order approach to its yaw rate and lateral velocity
    td = math.tan(d)
    tau = p[_TAU]
    r_kin = vl_dot * td / L + (vl * td / L - r) / tau
    vn_kin = lr * vl_dot * td / L + (lr * vl * td / L - vn) / tau
    out[3] = w * vn_dyn + (1.0 - w) * vn_kin
    out[5] = w * r_dyn + (1.0 - w) * r_kin


@njit(cache=True)
def jacobians(x, u, p, fx, fu):
    """Write the partial Jacobians df/dx (6x6) into ``fx`` and df/du (6x2) into ``fu``."""
    vl = x[2]
    vn = x[3]
    psi = x[4]
    r = x[5]
    a = u[0]
    d = u[1]
    m = p[_M]
    Iz = p[_IZ]
    lf = p[_LF]
    lr = p[_LR]
    Caf = p[_CAF]
    Car = p[_CAR]
    L = lf + lr
    tau = p[_TAU]
    fx[:, :] = 0.0
    fu[:, :] = 0.0
    c = math.cos(psi)
    s = math.sin(psi)
    # z1' = vl c - vn s ; z2' = vl s + vn c
    fx[0, 2] = c
    fx[0, 3] = -s
    fx[0, 4] = -vl * s - vn * c
    fx[1, 2] = s
    fx[1, 3] = c
    fx[1, 4] = vl * c - vn * s
    # vl' = r vn + a
    fx[2, 3] = r
    fx[2, 5] = vn
    fu[2, 0] = 1.0
    # psi' = r
    fx[4, 5] = 1.0
    vl_dot = r * vn + a
    w, dw = blend_weight(vl, p)
    cd = math.cos(d)
    sd = math.sin(d)
    # ---- dynamic part
    floor = vl <= _V_FLOOR
    vd = _V_FLOOR if floor else vl
    qf = (vn + lf * r) / vd
    qr = (vn - lr * r) / vd
    gf = 1.0 / (1.0 + qf * qf)
    gr = 1.0 / (1.0 + qr * qr)
    Fcf = Caf * (d - math.atan(qf))
    Fcr = -Car * math.atan(qr)
    dFcf_dvl = 0.0 if floor else Caf * gf * qf / vd
    dFcf_dvn = -Caf * gf / vd
    dFcf_dr = -Caf * gf * lf / vd
    dFcf_dd = Caf
    dFcr_dvl = 0.0 if floor else Car * gr * qr / vd
    dFcr_dvn = -Car * gr / vd
    dFcr_dr = Car * gr * lr / vd
    vn_dyn = -r * vl + 2.0 * (Fcf * cd + Fcr) / m
    r_dyn = 2.0 * (lf * Fcf * cd - lr * Fcr) / Iz
    Dvn_vl = -r + 2.0 * (dFcf_dvl * cd + dFcr_dvl) / m
    Dvn_vn = 2.0 * (dFcf_dvn * cd + dFcr_dvn) / m
    Dvn_r = -vl + 2.0 * (dFcf_dr * cd + dFcr_dr) / m
    Dvn_d = 2.0 * (dFcf_dd * cd - Fcf * sd) / m
    Dr_vl = 2.0 * (lf * dFcf_dvl * cd - lr * dFcr_dvl) / Iz
    Dr_vn = 2.0 * (lf * dFcf_dvn * cd - lr * dFcr_dvn) / Iz
    Dr_r = 2.0 * (lf * dFcf_dr * cd - lr * dFcr_dr) / Iz
    Dr_d = 2.0 * (lf * (dFcf_dd * cd - Fcf * sd)) / Iz
    # ---- kinematic part
    td = math.tan(d)
    sec2 = 1.0 + td * td
    r_kin = vl_dot * td / L + (vl * td / L - r) / tau
    vn_kin = lr * vl_dot * td / L + (lr * vl * td / L - vn) / tau
    Kr_vl = td / (L * tau)
    Kr_vn = r * td / L
    Kr_r = vn * td / L - 1.0 / tau
    Kr_a = td / L
    Kr_d = vl_dot * sec2 / L + vl * sec2 / (L * tau)
    Kvn_vl = lr * td / (L * tau)
    Kvn_vn = lr * r * td / L - 1.0 / tau
    Kvn_r = lr * vn * td / L
    Kvn_a = lr * td / L
    Kvn_d = lr * vl_dot * sec2 / L + lr * vl * sec2 / (L * tau)
    # ---- blend: f = w D + (1 - w) K, w = w(vl)
    wk = 1.0 - w
    fx[3, 2] = w * Dvn_vl + wk * Kvn_vl + dw * (vn_dyn - vn_kin)
    fx[3, 3] = w * Dvn_vn + wk * Kvn_vn
    fx[3, 5] = w * Dvn_r + wk * Kvn_r
    fu[3, 0] = wk * Kvn_a
    fu[3, 1] = w * Dvn_d + wk * Kvn_d
    fx[5, 2] = w * Dr_vl + wk * Kr_vl + dw * (r_dyn - r_kin)
    fx[5, 3] = w * Dr_vn + wk * Kr_vn
    fx[5, 5] = w * Dr_r + wk * Kr_r
    fu[5, 0] = wk * Kr_a
    fu[5, 1] = w * Dr_d + wk * Kr_d


@njit(cache=True)
def euler_step(x, u, p, h, work):
    """One forward-Euler plant step of length ``h`` [s] in place; ``v_l`` is clamped at 0
    (the vehicle brakes to a stop, it does not reverse). ``work`` is scratch of length 6."""
    dynamics(x, u, p, work)
    for i in range(6):
        x[i] += h * work[i]
    if x[2] < 0.0:
        x[2] = 0.0


def simulate(x0, u, p, h, n_steps):
    """Integrate the plant with a constant input; returns the (n_steps+1, 6) state history.

    Convenience for tests and scripts (the engine steps the batched kernel instead).
    """
    x = np.array(x0, dtype=np.float64)
    uu = np.asarray(u, dtype=np.float64)
    work = np.empty(6)
    out = np.empty((n_steps + 1, 6))
    out[0] = x
    for k in range(n_steps):
        euler_step(x, uu, p, h, work)
        out[k + 1] = x
    return out
