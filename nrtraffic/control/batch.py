"""The per-SUMO-step kernel: every controlled vehicle through the plant sub-steps, batched.

For each vehicle ``i`` and sub-step ``j`` (``t_j = t_start + j h``): the reference arc length is
``s_enter[i] + p_i(t - t_enter[i])`` (its energy-optimal profile mapped onto its lane path by distance
travelled, paper s. 4.1), the tracker takes one Euler step of eq. (12) toward ``r(t_j + T)``, and the
plant takes one Euler step of eq. (1) with the input held over the step. Figures accumulated per
vehicle (columns of ``acc``): see ``ACC_*``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from nrtraffic.control.nr_flow import nr_update
from nrtraffic.geometry import path_xy, project_local
from nrtraffic.metrics import fuel_rate
from nrtraffic.planning.profiles import packed_position
from nrtraffic.vehicle.bicycle import euler_step

ACC_MAX_ERR, ACC_MAX_ERR_STEADY, ACC_MAX_LAT, ACC_ENERGY, ACC_FUEL, ACC_MAX_ABS_A, ACC_MAX_ERR_TRANSIENT = range(7)
N_ACC = 7


@njit(cache=True)
def _ref_xy(prof, tau, s_enter, xy, s, out):
    q = np.empty(1)
    q[0] = s_enter + packed_position(prof, tau)
    path_xy(q, xy, s, out)
    return q[0]


@njit(cache=True)
def advance(X, U, t_start, n_sub, h, plant_p, pred_p, horizon, dt_pred, alpha, damping, u_lo, u_hi,
            prof, t_enter, s_enter, path_id, path_off, path_xy_all, path_s_all, hint, steady_after, acc,
            out_s, out_lat, out_ref, out_err):
    """Advance all vehicles from ``t_start`` by ``n_sub`` steps of ``h`` [s] (in place).

    X (N,6), U (N,2): plant states and tracker inputs. prof (N,K,5): packed profiles. path_*: packed
    lane paths, vehicle ``i`` uses path ``path_id[i]``. hint (N,): segment hints for the projection.
    acc (N, N_ACC): accumulated figures. out_*: arc length [m], lateral deviation [m], reference
    position [m] and tracking error [m] at the end of the step.
    """
    N = X.shape[0]
    work = np.empty(6)
    u_new = np.empty(2)
    ref = np.empty((1, 2))
    for i in range(N):
        a0 = path_off[path_id[i]]
        a1 = path_off[path_id[i] + 1]
        xy = path_xy_all[a0:a1]
        s = path_s_all[a0:a1]
        x = X[i]
        u = U[i]
        for j in range(n_sub):
            t = t_start + j * h
            # tracker: r(t + T), eq. (12)
            _ref_xy(prof[i], t + horizon - t_enter[i], s_enter[i], xy, s, ref)
            nr_update(x, u, pred_p, ref[0], horizon, dt_pred, alpha, damping, h, u_lo, u_hi, u_new)
            # plant, eq. (1), input held over the step
            a = u[0]
            v = x[2]
            euler_step(x, u, plant_p, h, work)
            acc[i, ACC_ENERGY] += 0.5 * a * a * h
            acc[i, ACC_FUEL] += fuel_rate(v, a) * h
            if abs(a) > acc[i, ACC_MAX_ABS_A]:
                acc[i, ACC_MAX_ABS_A] = abs(a)
            u[0] = u_new[0]
            u[1] = u_new[1]
            # figures at t + h
            tn = t + h
            sr = _ref_xy(prof[i], tn - t_enter[i], s_enter[i], xy, s, ref)
            err = math.sqrt((x[0] - ref[0, 0]) ** 2 + (x[1] - ref[0, 1]) ** 2)
            sp, lat, hint[i] = project_local(xy, s, x[0], x[1], hint[i], 3, 12)
            if err > acc[i, ACC_MAX_ERR]:
                acc[i, ACC_MAX_ERR] = err
            if tn - t_enter[i] > steady_after:
                if err > acc[i, ACC_MAX_ERR_STEADY]:
                    acc[i, ACC_MAX_ERR_STEADY] = err
            elif err > acc[i, ACC_MAX_ERR_TRANSIENT]:
                acc[i, ACC_MAX_ERR_TRANSIENT] = err
            if abs(lat) > acc[i, ACC_MAX_LAT]:
                acc[i, ACC_MAX_LAT] = abs(lat)
            if j == n_sub - 1:
                out_s[i] = sp
                out_lat[i] = lat
                out_ref[i, 0] = ref[0, 0]
                out_ref[i, 1] = ref[0, 1]
                out_err[i] = err
