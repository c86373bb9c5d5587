"""The per-SUMO-step kernel: every controlled vehicle through the plant sub-steps, batched.

For each sub-step ``t_j = t_start + j h`` and each vehicle ``i``:

1. the tracker's input ``u*`` (the state of the update law, eq. 12) is filtered by the barrier
   functions: lateral bisection on ``delta_f`` first, then the longitudinal QP on ``a_l`` given that
   steering (paper s. 3.2, 4.2; :mod:`nrtraffic.control.cbf`);
2. the tracker takes one Euler step of eq. (12) toward ``r(t_j + T)``, the reference being the
   vehicle's energy-optimal profile mapped onto its lane path by distance travelled (paper s. 4.1).
   With anti-windup it integrates from the *applied* (filtered) input, otherwise from its own;
3. the plant takes one Euler step of eq. (1) with the applied input.

Leaders (for the longitudinal barrier) are either controlled vehicles of the batch (their state at
the start of the sub-step) or external vehicles whose state at ``t_start`` is extrapolated with
constant acceleration.

Disturbances (``[disturbances]``, docs/mixed-traffic.md, Robustness): with measurement noise the tracker and both
barriers see the measured state (the plant's plus the sub-step's row of ``noise``: own x, y, v_l,
v_n, psi, then the leader's x, y, v_x, v_y), the plant stays exact and the figures (gaps, centre
distances, deviations) are the true ones. With an actuator lag the plant receives the output of a
first-order lag of time constant ``tau`` driven by the filtered input, discretised exactly for an
input held over the plant step: ``u_act <- u_act + (1 - exp(-h / tau)) (u_cmd - u_act)``, the plant
step taking ``u_act`` at its start. A constant force per unit mass acts on the plant along and
across the body. With a state observer the tracker and barriers see its estimate ``x_e`` instead of
the measurement ``y``: every plant step ``x_e <- x_e + (h / tau_o) (y - x_e)``, then
``x_e <- x_e + h f(x_e, u)`` with the model of eq. (1) and the filtered input (a constant-gain
observer; it knows neither the actuator lag nor the forces).

Figures accumulated per vehicle are the columns ``ACC_*`` of ``acc``; the state at the end of the
step is written to the columns ``OUT_*`` of ``out``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, objmode

from nrtraffic.control import cbf
from nrtraffic.control.nr_flow import new_workspace, nr_update
from nrtraffic.geometry import path_point_near, project_local
from nrtraffic.planning.profiles import packed_position
from nrtraffic.vehicle.bicycle import body_rates_affine
from nrtraffic.vehicle.fuel import fuel_rate

(ACC_MAX_ERR, ACC_MAX_ERR_STEADY, ACC_MAX_LAT, ACC_ENERGY, ACC_FUEL, ACC_MAX_ABS_A, ACC_MAX_ERR_TRANSIENT,
 ACC_STEPS, ACC_LONG_ACTIVE, ACC_LAT_ACTIVE, ACC_LONG_FALLBACK, ACC_LAT_FALLBACK, ACC_MIN_CENTER, ACC_MIN_H_LONG,
 ACC_MIN_H_LAT) = range(15)
N_ACC = 15

(OUT_S, OUT_LAT, OUT_REFX, OUT_REFY, OUT_ERR, OUT_A, OUT_D, OUT_LONG_FRAC, OUT_LAT_FRAC, OUT_H_LONG, OUT_H_LAT,
 OUT_CENTER, OUT_AX, OUT_AY) = range(14)
N_OUT = 14

# columns of a sub-step's measurement noise (``noise[i, j]``) [m, m/s, rad]
(NZ_X, NZ_Y, NZ_VL, NZ_VN, NZ_PSI, NZ_LX, NZ_LY, NZ_LVX, NZ_LVY) = range(9)
N_NOISE = 9

# settings packed in ``cfg``
(CFG_H, CFG_HORIZON, CFG_DT_PRED, CFG_ALPHA, CFG_DAMPING, CFG_STEADY_AFTER, CFG_CBF_LONG, CFG_CBF_LAT, CFG_D0,
 CFG_A_BAR, CFG_LONG_GAIN, CFG_Y_MAX, CFG_K_LAT, CFG_GAMMA, CFG_BISECT_TOL, CFG_ANTI_WINDUP, CFG_QP_MODE,
 CFG_ROOT_C, CFG_PREDICTOR, CFG_LAG_TAU, CFG_FORCE_LONG, CFG_FORCE_LAT, CFG_OBSERVER_TAU) = range(23)
N_CFG = 23  # CFG_LAG_TAU: the actuator lag's time constant [s] (0: none); CFG_FORCE_*: [m/s^2];
# CFG_OBSERVER_TAU: the state observer's time constant [s] (0: the controller sees the measurement)

NO_LEADER = -1
EXTERNAL_LEADER = -2

# the qpsolvers backend used when cfg[CFG_QP_MODE] == 1 (set by nrtraffic.control.kernel.kernel_config)
QP_SOLVER = ["osqp"]


def new_acc(n: int) -> np.ndarray:
    """Fresh accumulator rows (minima start at +inf)."""
    acc = np.zeros((n, N_ACC))
    acc[:, ACC_MIN_CENTER] = np.inf
    acc[:, ACC_MIN_H_LONG] = np.inf
    acc[:, ACC_MIN_H_LAT] = np.inf
    return acc


def _qp(a_star, G, b, lo, hi):
    a, st = cbf.long_filter_qp(a_star, G, b, lo, hi, QP_SOLVER[0])
    return a, st


@njit(cache=True, error_model="numpy")
def _long_filter(a_star, G, b, a_lo, a_hi, qp_mode):
    """The longitudinal barrier's QP ``G a <= b``, ``a_lo <= a <= a_hi`` closest to ``a_star``:
    its closed form (``qp_mode`` 0) or through qpsolvers (1); returns ``(a, status)``."""
    if qp_mode == 0:
        return cbf.long_filter_closed(a_star, G, b, a_lo, a_hi)
    with objmode(a="float64", st="int64"):
        a, st = _qp(a_star, G, b, a_lo, a_hi)
    return a, st


@njit(cache=True, error_model="numpy")
def _ref_xy(prof, tau, s_enter, xy, s, near):
    """Reference point ``(x, y)`` [m] at local time ``tau`` [s]: the profile's distance mapped onto
    the lane path (searched from segment ``near``, the vehicle's own)."""
    return path_point_near(s_enter + packed_position(prof, tau), xy, s, near)


@njit(cache=True, error_model="numpy")
def advance(X, U, t_start, n_sub, cfg, plant_p, pred_p, u_lo, u_hi, prof, t_enter, s_enter, path_id, path_off,
            path_xy_all, path_s_all, path_frames, hint, lead_idx, lead_ext, acc, out, noise, act, xe, gate):
    """Advance all vehicles from ``t_start`` by ``n_sub`` plant steps (in place).

    X (N,6), U (N,2): plant states and tracker inputs (the update law's state). prof (N,K,5):
    packed profiles. path_*: packed lane paths, vehicle ``i`` on path ``path_id[i]``. hint (N,):
    projection segment of each vehicle (updated). lead_idx (N,): leader's batch index, NO_LEADER or
    EXTERNAL_LEADER; path_frames: :func:`nrtraffic.geometry.segment_frames` of the packed paths, row
    for row; lead_ext (N,6): external leader (px, py, vx, vy, ax, ay) at ``t_start``.
    acc (N, N_ACC): accumulated figures. out (N, N_OUT): holds the vehicle's arc length, lateral
    deviation, tracking error and world acceleration (over its last plant step; what a follower's
    barrier reads of it as a leader) at ``t_start`` on entry and at the end of the step on return.
    noise (N, n_sub, N_NOISE) or (N, n_sub, 0) without noise: the measurement noise of every
    sub-step. act (N, 2): the actuators' output (with a lag; updated). xe (N, 6): the state
    observer's estimate (with an observer; updated). gate (N, 2): a second, standing obstacle
    (x, y) [m] for the longitudinal barrier besides the leader (a late vehicle's closed
    merging-zone entry behind a nearer leader, :mod:`nrtraffic.junction.late`), NaN for none; the
    acceleration then keeps within both barriers' bounds.
    """
    N = X.shape[0]
    h = cfg[CFG_H]
    horizon = cfg[CFG_HORIZON]
    cbf_long = cfg[CFG_CBF_LONG] > 0.5
    cbf_lat = cfg[CFG_CBF_LAT] > 0.5
    anti_windup = cfg[CFG_ANTI_WINDUP] > 0.5
    qp_mode = int(cfg[CFG_QP_MODE])
    method = int(cfg[CFG_PREDICTOR])
    noisy = noise.shape[2] > 0
    lagged = cfg[CFG_LAG_TAU] > 0.0
    lag_c = 1.0 - math.exp(-h / cfg[CFG_LAG_TAU]) if lagged else 1.0
    force_l = cfg[CFG_FORCE_LONG]
    force_n = cfg[CFG_FORCE_LAT]
    observing = cfg[CFG_OBSERVER_TAU] > 0.0
    k_obs = h / cfg[CFG_OBSERVER_TAU] if observing else 0.0
    seen = noisy or observing  # the controller's view differs from the plant's state
    xm = np.empty(6)
    e_dz1 = e_dz2 = e_vl = e_vn = e_r = 0.0  # the observer's model step
    ws, wsP = new_workspace()
    u_new = np.empty(2)
    u_app = np.empty(2)
    ref = np.empty(2)
    lead = np.empty(6)
    snap = np.empty((N, 6))
    n_long = np.zeros(N)
    n_lat = np.zeros(N)
    # cos and sin of each vehicle's heading, carried from one plant step to the next
    cs = np.empty((N, 2))
    for i in range(N):
        cs[i, 0] = math.cos(X[i, 4])
        cs[i, 1] = math.sin(X[i, 4])
    for j in range(n_sub):
        t = t_start + j * h
        for i in range(N):
            snap[i, 0] = X[i, 0]
            snap[i, 1] = X[i, 1]
            snap[i, 2] = X[i, 2] * cs[i, 0] - X[i, 3] * cs[i, 1]
            snap[i, 3] = X[i, 2] * cs[i, 1] + X[i, 3] * cs[i, 0]
            snap[i, 4] = out[i, OUT_AX]
            snap[i, 5] = out[i, OUT_AY]
        for i in range(N):
            a0 = path_off[path_id[i]]
            a1 = path_off[path_id[i] + 1]
            xy = path_xy_all[a0:a1]
            s = path_s_all[a0:a1]
            x = X[i]  # the plant's state
            u = U[i]
            cp = cs[i, 0]
            sp = cs[i, 1]
            # what the tracker and barriers see: the state as measured
            if noisy:
                for k in range(6):
                    xm[k] = x[k]
                xm[0] += noise[i, j, NZ_X]
                xm[1] += noise[i, j, NZ_Y]
                xm[2] += noise[i, j, NZ_VL]
                xm[3] += noise[i, j, NZ_VN]
                xm[4] += noise[i, j, NZ_PSI]
                xv = xm
            else:
                xv = x
            if observing:  # the estimate, corrected toward the measurement
                for k in range(6):
                    xe[i, k] += k_obs * (xv[k] - xe[i, k])
                xv = xe[i]
            if seen:
                cpv = math.cos(xv[4])
                spv = math.sin(xv[4])
            else:
                cpv = cp
                spv = sp
            u_app[0] = u[0]
            u_app[1] = u[1]
            pinned_a = False
            pinned_d = False
            fell = False  # the longitudinal barrier fell back
            fr = a0 + hint[i]
            tx = path_frames[fr, 0]
            ty = path_frames[fr, 1]
            curv = path_frames[fr, 2]
            # body rates of eq. (1) at a_l = 0 and their slope in a_l, at the tracker's steering:
            # shared by both barriers and the plant (re-evaluated if the lateral barrier steers;
            # for the plant again, at the true state, when what the barriers see differs)
            f2, f3, f5, g3, g5 = body_rates_affine(xv, u_app[1], plant_p)
            # ---- lateral barrier: bisection on the steering
            if cbf_lat:
                a = u_app[0]
                lat_v = out[i, OUT_LAT]
                if seen:  # the deviation of the position seen
                    lat_v += tx * (xv[1] - x[1]) - ty * (xv[0] - x[0])
                d, st, hl = cbf.lat_filter_given(xv, cpv, spv, a, u_app[1], f2 + a, f3 + a * g3, plant_p,
                                                 lat_v, tx, ty, curv, cfg[CFG_Y_MAX], cfg[CFG_K_LAT],
                                                 cfg[CFG_GAMMA], u_hi[1], cfg[CFG_BISECT_TOL])
                if d != u_app[1]:
                    u_app[1] = d
                    f2, f3, f5, g3, g5 = body_rates_affine(xv, d, plant_p)
                out[i, OUT_H_LAT] = hl
                if hl < acc[i, ACC_MIN_H_LAT]:
                    acc[i, ACC_MIN_H_LAT] = hl
                if st != cbf.INACTIVE:
                    pinned_d = True
                    acc[i, ACC_LAT_ACTIVE] += 1.0
                    n_lat[i] += 1.0
                if st == cbf.FALLBACK:
                    acc[i, ACC_LAT_FALLBACK] += 1.0
            # ---- leader state at t
            has_lead = lead_idx[i] != NO_LEADER
            if has_lead:
                if lead_idx[i] >= 0:
                    for k in range(6):
                        lead[k] = snap[lead_idx[i], k]
                else:
                    tau = t - t_start
                    for k in range(2):
                        lead[k] = lead_ext[i, k] + lead_ext[i, 2 + k] * tau + 0.5 * lead_ext[i, 4 + k] * tau * tau
                        lead[2 + k] = lead_ext[i, 2 + k] + lead_ext[i, 4 + k] * tau
                        lead[4 + k] = lead_ext[i, 4 + k]
                dc = math.sqrt((lead[0] - x[0]) ** 2 + (lead[1] - x[1]) ** 2)  # true
                out[i, OUT_CENTER] = dc
                if dc < acc[i, ACC_MIN_CENTER]:
                    acc[i, ACC_MIN_CENTER] = dc
                if noisy:  # the leader as measured
                    lead[0] += noise[i, j, NZ_LX]
                    lead[1] += noise[i, j, NZ_LY]
                    lead[2] += noise[i, j, NZ_LVX]
                    lead[3] += noise[i, j, NZ_LVY]
            # ---- longitudinal barrier: one-dimensional QP on the acceleration
            if cbf_long and has_lead:
                hb, G, b = cbf.long_constraint_given(xv, cpv, spv, f2, f3, g3, lead, cfg[CFG_D0], cfg[CFG_A_BAR],
                                                     cfg[CFG_LONG_GAIN], cfg[CFG_ROOT_C])
                a, st = _long_filter(u_app[0], G, b, u_lo[0], u_hi[0], qp_mode)
                u_app[0] = a
                out[i, OUT_H_LONG] = hb
                if hb < acc[i, ACC_MIN_H_LONG]:
                    acc[i, ACC_MIN_H_LONG] = hb
                if st != cbf.INACTIVE:
                    pinned_a = True
                    acc[i, ACC_LONG_ACTIVE] += 1.0
                    n_long[i] += 1.0
                if st == cbf.FALLBACK:
                    acc[i, ACC_LONG_FALLBACK] += 1.0
                    fell = True
            # ---- a second, standing obstacle: the vehicle's closed merging-zone entry
            if cbf_long and not math.isnan(gate[i, 0]):
                lead[0] = gate[i, 0]
                lead[1] = gate[i, 1]
                for k in range(2, 6):
                    lead[k] = 0.0
                _, G, b = cbf.long_constraint_given(xv, cpv, spv, f2, f3, g3, lead, cfg[CFG_D0], cfg[CFG_A_BAR],
                                                    cfg[CFG_LONG_GAIN], cfg[CFG_ROOT_C])
                a, st = _long_filter(u_app[0], G, b, u_lo[0], u_hi[0], qp_mode)
                u_app[0] = a
                if st != cbf.INACTIVE and not pinned_a:  # (a plant step is counted once)
                    pinned_a = True
                    acc[i, ACC_LONG_ACTIVE] += 1.0
                    n_long[i] += 1.0
                if st == cbf.FALLBACK and not fell:
                    acc[i, ACC_LONG_FALLBACK] += 1.0
            # ---- tracker, eq. (12). Anti-windup: it integrates from the applied input, and an input
            # a barrier overrides is pinned (the flow moves the other one alone). Without: it runs on
            # its own state as if unfiltered.
            ref[0], ref[1] = _ref_xy(prof[i], t + horizon - t_enter[i], s_enter[i], xy, s, hint[i])
            if anti_windup:
                u[0] = u_app[0]
                u[1] = u_app[1]
                nr_update(xv, u, pred_p, ref, horizon, cfg[CFG_DT_PRED], method, cfg[CFG_ALPHA], cfg[CFG_DAMPING],
                          h, u_lo, u_hi, u_new, ws, wsP, not pinned_a, not pinned_d, tx, ty)
            else:
                nr_update(xv, u, pred_p, ref, horizon, cfg[CFG_DT_PRED], method, cfg[CFG_ALPHA], cfg[CFG_DAMPING], h,
                          u_lo, u_hi, u_new, ws, wsP, True, True)
            # ---- plant, eq. (1): one forward-Euler step with the applied input held over it
            # (bicycle.euler_step, from the rates above; v_l is clamped at 0: no reversing)
            a = u_app[0]
            if observing:  # the estimate's model step, from the rates the barriers used (at x_e)
                e_dz1 = xv[2] * cpv - xv[3] * spv
                e_dz2 = xv[2] * spv + xv[3] * cpv
                e_vl = f2 + a
                e_vn = f3 + a * g3
                e_r = f5 + a * g5
            if lagged:  # the actuators' output at the start of the step, then toward the command
                a = act[i, 0]
                d_act = act[i, 1]
                act[i, 0] += lag_c * (u_app[0] - act[i, 0])
                act[i, 1] += lag_c * (u_app[1] - act[i, 1])
                f2, f3, f5, g3, g5 = body_rates_affine(x, d_act, plant_p)
            elif seen:
                f2, f3, f5, g3, g5 = body_rates_affine(x, u_app[1], plant_p)
            v = x[2]
            vx0 = snap[i, 2]
            vy0 = snap[i, 3]
            r = x[5]
            dz1 = x[2] * cp - x[3] * sp
            dz2 = x[2] * sp + x[3] * cp
            x[0] += h * dz1
            x[1] += h * dz2
            x[2] += h * (f2 + a + force_l)
            x[3] += h * (f3 + a * g3 + force_n)
            x[4] += h * r
            x[5] += h * (f5 + a * g5)
            if x[2] < 0.0:
                x[2] = 0.0
            if observing:
                xe[i, 0] += h * e_dz1
                xe[i, 1] += h * e_dz2
                xe[i, 2] += h * e_vl
                xe[i, 3] += h * e_vn
                xe[i, 4] += h * xe[i, 5]
                xe[i, 5] += h * e_r
                if xe[i, 2] < 0.0:
                    xe[i, 2] = 0.0
            cp = math.cos(x[4])
            sp = math.sin(x[4])
            cs[i, 0] = cp
            cs[i, 1] = sp
            out[i, OUT_AX] = (x[2] * cp - x[3] * sp - vx0) / h
            out[i, OUT_AY] = (x[2] * sp + x[3] * cp - vy0) / h
            acc[i, ACC_ENERGY] += 0.5 * a * a * h
            acc[i, ACC_FUEL] += fuel_rate(v, a) * h
            acc[i, ACC_STEPS] += 1.0
            if abs(a) > acc[i, ACC_MAX_ABS_A]:
                acc[i, ACC_MAX_ABS_A] = abs(a)
            u[0] = u_new[0]
            u[1] = u_new[1]
            # ---- figures at t + h
            tn = t + h
            sp_, lat, hint[i] = project_local(xy, s, x[0], x[1], hint[i], 3, 12)
            rx, ry = _ref_xy(prof[i], tn - t_enter[i], s_enter[i], xy, s, hint[i])
            err = math.sqrt((x[0] - rx) ** 2 + (x[1] - ry) ** 2)
            out[i, OUT_S] = sp_
            out[i, OUT_LAT] = lat
            out[i, OUT_REFX] = rx
            out[i, OUT_REFY] = ry
            out[i, OUT_ERR] = err
            out[i, OUT_A] = u_app[0]
            out[i, OUT_D] = u_app[1]
            if err > acc[i, ACC_MAX_ERR]:
                acc[i, ACC_MAX_ERR] = err
            if tn - t_enter[i] > cfg[CFG_STEADY_AFTER]:
                if err > acc[i, ACC_MAX_ERR_STEADY]:
                    acc[i, ACC_MAX_ERR_STEADY] = err
            elif err > acc[i, ACC_MAX_ERR_TRANSIENT]:
                acc[i, ACC_MAX_ERR_TRANSIENT] = err
            if abs(lat) > acc[i, ACC_MAX_LAT]:
                acc[i, ACC_MAX_LAT] = abs(lat)
    for i in range(N):
        out[i, OUT_LONG_FRAC] = n_long[i] / n_sub
        out[i, OUT_LAT_FRAC] = n_lat[i] / n_sub
