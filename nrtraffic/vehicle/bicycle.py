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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def body_rates(x, a, d, p):
    """``(v_l', v_n', psi_dot')`` of eq. (1) (with the low-speed blend) under input ``(a, d)``."""
    vl = x[2]
    vn = x[3]
    r = x[5]
    m = p[_M]
    Iz = p[_IZ]
    lf = p[_LF]
    lr = p[_LR]
    L = lf + lr
    vl_dot = r * vn + a
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
    return vl_dot, w * vn_dyn + (1.0 - w) * vn_kin, w * r_dyn + (1.0 - w) * r_kin


@njit(cache=True, error_model="numpy")
def body_rates_affine(x, d, p):
    """:func:`body_rates` split by its affine dependence on ``a``: returns
    ``(vl_dot0, vn_dot0, r_dot0, dvn_da, dr_da)`` with the rates under ``(a, d)`` equal to
    ``(vl_dot0 + a, vn_dot0 + a dvn_da, r_dot0 + a dr_da)`` (``a`` enters ``v_l'`` directly and,
    in the kinematic blend, the yaw rate and lateral velocity through ``v_l'``)."""
    vl_dot0, vn_dot0, r_dot0 = body_rates(x, 0.0, d, p)
    w, _ = blend_weight(x[2], p)
    k = (1.0 - w) * math.tan(d) / (p[_LF] + p[_LR])
    return vl_dot0, vn_dot0, r_dot0, p[_LR] * k, k


@njit(cache=True, error_model="numpy")
def dynamics(x, u, p, out):
    """Write f(x, u) of eq. (1) (with the low-speed blend) into ``out`` (length 6)."""
    vl = x[2]
    vn = x[3]
    c = math.cos(x[4])
    s = math.sin(x[4])
    out[0] = vl * c - vn * s
    out[1] = vl * s + vn * c
    out[2], out[3], out[5] = body_rates(x, u[0], u[1], p)
    out[4] = x[5]


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


@njit(cache=True, error_model="numpy")
def euler_step(x, u, p, h, work):
    """One forward-Euler plant step of length ``h`` [s] in place; ``v_l`` is clamped at 0
    (the vehicle brakes to a stop, it does not reverse). ``work`` is scratch of length 6."""
    dynamics(x, u, p, work)
    for i in range(6):
        x[i] += h * work[i]
    if x[2] < 0.0:
        x[2] = 0.0


def euler_step_limit_at(x, u, p) -> float:
    """Longest forward-Euler plant step [s] that is linearly stable about state ``x`` under input
    ``u``: every eigenvalue ``lambda`` of eq. (1)'s ``df/dx`` with a negative real part needs
    ``|1 + h lambda| <= 1``, i.e. ``h <= -2 Re(lambda) / |lambda|^2``. Modes with a non-negative
    real part (position, heading, and an oversteering car's unstable mode above its critical speed)
    set no limit (``inf``)."""
    fx = np.zeros((6, 6))
    jacobians(np.asarray(x, dtype=float), np.asarray(u, dtype=float), p, fx, np.zeros((6, 2)))
    lam = np.linalg.eigvals(fx)
    lam = lam[lam.real < 0.0]
    return float(np.min(-2.0 * lam.real / np.abs(lam) ** 2)) if lam.size else math.inf


def euler_step_limit(p, v_max: float, dv: float = 0.01) -> tuple[float, float]:
    """Longest forward-Euler plant step [s] that is stable for eq. (1) driving straight at any
    speed in ``[0, v_max]`` [m/s] (sampled every ``dv``), and the speed [m/s] that sets it
    (:func:`euler_step_limit_at` of each). The lateral and yaw modes are stiffest at low speed
    (with the paper's car: -180 1/s at 1.35 m/s, in the blend to the kinematic model;
    h <= 0.0111 s). Straight driving is the stiffest case at a given speed: the slip angles enter
    through atan, whose slope is largest at zero slip."""
    x, u = np.zeros(6), np.zeros(2)
    h_max, v_at = math.inf, 0.0
    for v in np.arange(0.0, max(v_max, 2.0 * p[_VHI]) + dv, dv):
        x[2] = v
        h = euler_step_limit_at(x, u, p)
        if h < h_max:
            h_max, v_at = h, float(v)
    return h_max, v_at


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


@njit(cache=True, error_model="numpy", inline="always")
def rhs_tangent_s(vl, vn, r, c, s, a, d, cd, sd, td, p, p20, p21, p30, p31, p40, p41, p50, p51):
    """``f(x, u)`` of eq. (1) and ``dP = f_x(x, u) P + f_u(x, u)`` in one pass (the predictor's
    sensitivity recursion, :mod:`nrtraffic.control.nr_flow`), on scalars, so that the predictor's
    steps stay in registers.

    The same maths as :func:`dynamics` and :func:`jacobians`, fused: the two tyre atans are
    evaluated once, the heading's ``c, s`` (cos, sin of ``psi``) and the steering's ``cd, sd, td``
    (cos, sin, tan of ``d`` [rad]; constant while the input is held) come from the caller, and only
    the 15 non-zero entries of ``f_x`` enter the product. ``vl, vn`` [m/s], ``r`` [rad/s]: the
    state's speeds and yaw rate (the positions do not enter, the heading only through ``c, s``);
    ``pij``: row ``i`` (2-5), column ``j`` of ``P`` (6, 2), the sensitivity of the state to
    ``u = (a, d)``. Returns ``(f_0, ..., f_5, dP_00, dP_01, dP_10, ..., dP_51)``: ``f`` then ``dP``
    row by row.
    """
    m = p[_M]
    Iz = p[_IZ]
    lf = p[_LF]
    lr = p[_LR]
    Caf = p[_CAF]
    Car = p[_CAR]
    im2 = 2.0 / m
    iz2 = 2.0 / Iz
    iL = 1.0 / (lf + lr)
    itau = 1.0 / p[_TAU]
    f0 = vl * c - vn * s
    f1 = vl * s + vn * c
    vl_dot = r * vn + a
    w, dw = blend_weight(vl, p)
    wk = 1.0 - w
    # row 3 (v_n) and row 5 (psi_dot) of f_x, f_u: A3*, A5*, B3*, B5*
    f3 = 0.0
    f5 = 0.0
    A32 = A33 = A35 = A52 = A53 = A55 = 0.0
    B30 = B31 = B50 = B51 = 0.0
    if w > 0.0:
        floor = vl <= _V_FLOOR
        vd = _V_FLOOR if floor else vl
        ivd = 1.0 / vd
        qf = (vn + lf * r) * ivd
        qr = (vn - lr * r) * ivd
        gf = 1.0 / (1.0 + qf * qf)
        gr = 1.0 / (1.0 + qr * qr)
        Fcf = Caf * (d - math.atan(qf))
        Fcr = -Car * math.atan(qr)
        vn_dyn = -r * vl + im2 * (Fcf * cd + Fcr)
        r_dyn = iz2 * (lf * Fcf * cd - lr * Fcr)
        dFcf_dvl = 0.0 if floor else Caf * gf * qf * ivd
        dFcf_dvn = -Caf * gf * ivd
        dFcf_dr = lf * dFcf_dvn
        dFcr_dvl = 0.0 if floor else Car * gr * qr * ivd
        dFcr_dvn = -Car * gr * ivd
        dFcr_dr = -lr * dFcr_dvn
        f3 += w * vn_dyn
        f5 += w * r_dyn
        A32 += w * (-r + im2 * (dFcf_dvl * cd + dFcr_dvl)) + dw * vn_dyn
        A33 += w * (im2 * (dFcf_dvn * cd + dFcr_dvn))
        A35 += w * (-vl + im2 * (dFcf_dr * cd + dFcr_dr))
        B31 += w * (im2 * (Caf * cd - Fcf * sd))
        A52 += w * (iz2 * (lf * dFcf_dvl * cd - lr * dFcr_dvl)) + dw * r_dyn
        A53 += w * (iz2 * (lf * dFcf_dvn * cd - lr * dFcr_dvn))
        A55 += w * (iz2 * (lf * dFcf_dr * cd - lr * dFcr_dr))
        B51 += w * (iz2 * lf * (Caf * cd - Fcf * sd))
    if wk > 0.0:
        sec2 = 1.0 + td * td
        tL = td * iL
        r_kin = vl_dot * tL + (vl * tL - r) * itau
        vn_kin = lr * vl_dot * tL + (lr * vl * tL - vn) * itau
        f3 += wk * vn_kin
        f5 += wk * r_kin
        A32 += wk * (lr * tL * itau) - dw * vn_kin
        A33 += wk * (lr * r * tL - itau)
        A35 += wk * (lr * vn * tL)
        B30 += wk * (lr * tL)
        B31 += wk * (lr * sec2 * iL * (vl_dot + vl * itau))
        A52 += wk * (tL * itau) - dw * r_kin
        A53 += wk * (r * tL)
        A55 += wk * (vn * tL - itau)
        B50 += wk * tL
        B51 += wk * (sec2 * iL * (vl_dot + vl * itau))
    # dP = f_x P + f_u, row by row (f_u's entries added last)
    return (f0, f1, vl_dot, f3, r, f5,
            c * p20 - s * p30 - f1 * p40, c * p21 - s * p31 - f1 * p41,
            s * p20 + c * p30 + f0 * p40, s * p21 + c * p31 + f0 * p41,
            r * p30 + vn * p50 + 1.0, r * p31 + vn * p51,
            A32 * p20 + A33 * p30 + A35 * p50 + B30, A32 * p21 + A33 * p31 + A35 * p51 + B31,
            p50, p51,
            A52 * p20 + A53 * p30 + A55 * p50 + B50, A52 * p21 + A53 * p31 + A55 * p51 + B51)
