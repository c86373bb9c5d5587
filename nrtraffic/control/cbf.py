"""Control barrier functions (paper section 3.2 and 4.2), compiled.

Longitudinal barrier
--------------------
Follower centre of gravity ``p``, velocity ``v``; leader ``p_L``, ``v_L`` (world frame, [m], [m/s]);
``dp = p_L - p``, ``dv = v_L - v``, ``r = |dp|``, ``v_hat = <dp / r, dv>`` (negative while closing).
The paper argues (eq. 25) that braking at ``a_bar`` behind a leader of constant velocity keeps
``r >= r(t) - k v_hat^2`` with ``k = 1 / (2 a_bar)``, so the safe set is
``{r - k v_hat^2 >= d0}``. Its printed barrier, ``sqrt(k (r - d0)) - |v_hat|``, does not match that
set: ``sqrt(k (r - d0))`` is in seconds, ``|v_hat|`` in m/s, and ``|v_hat|`` would also forbid
*opening* speed. Solving the condition for the closing speed instead gives
``-v_hat <= sqrt(2 a_bar (r - d0))``, i.e. the barrier (units m/s) implemented here::

    h = sqrt(2 a_bar (r - d0)) + v_hat      (root extended as an odd function below d0)

In practice the root is smoothed, ``sqrt(z + c^2) - c`` with ``c`` = ``barriers.root_smoothing_mps``
(default 0.1 m/s): the exact root has an infinite slope at ``r = d0``, where a follower that
holds the distance sits, so that measurement noise of a few mm/s in ``v_hat`` turned into
acceleration spikes of several m/s^2. The smoothed set lies inside the exact one.

which is the safety barrier certificate of Wang, Ames and Egerstedt (2017) that the paper cites:
``h >= 0`` iff the follower can still stop closing in before ``r = d0`` by braking at ``a_bar``.
With ``dh/dt + kappa h >= 0`` (paper: ``kappa = 1``), and

    dh/dt = a_bar v_hat / sqrt(2 a_bar (r - d0)) + (|dv|^2 - v_hat^2) / r + <dp, a_L - a> / r,

where the follower's world acceleration ``a`` is affine in the input ``a_l`` (eq. 1 is control
affine in ``a_l``), the condition is one linear inequality ``G a_l <= b``: the QP of eq. (21)/(23)
``min (a_l - a_l*)^2`` s.t. ``G a_l <= b``, ``a_min <= a_l <= a_max``. Being one-dimensional it has
the closed form :func:`long_filter_closed`; :func:`long_filter_qp` solves the same problem through
qpsolvers (OSQP by default). When it is infeasible (or the solver fails) the fallback is maximal
braking ``a_min``.

Lateral barrier
---------------
``y`` lateral deviation from the lane centre (positive left), ``y_dot`` its rate;
``h = y_max - |y + k sgn(y) y_dot^2|``, ``k = 1 / (2 a_tilde)``, ``kappa(h) = gamma h^3`` (paper
eq. 26, gamma = 15). At ``y = 0`` the sign is taken from ``y_dot`` (the excursion is counted in the
direction of motion; ``h = y_max`` when both vanish). ``dh/dt`` involves ``y_ddot``, which depends on
the steering ``delta_f`` through the tyre forces (not affinely): :func:`lat_filter` keeps the
tracker's ``delta_f`` when it satisfies ``dh/dt + gamma h^3 >= 0``, otherwise bisects between it and
the admissible end of ``[-pi/4, pi/4]`` for the admissible value closest to it. When neither end is
admissible it applies the end with the larger ``dh/dt + gamma h^3`` (best effort) and reports it.
For a path with curvature ``c``: ``y_dot = <n, z_dot>`` and
``y_ddot = <n, z_ddot> - c <t, z_dot>^2 / (1 - c y)`` (``t``, ``n`` unit tangent and normal).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from nrtraffic.vehicle.bicycle import body_rates, body_rates_affine

# filter outcomes
INACTIVE, ACTIVE, FALLBACK = 0, 1, 2


@njit(cache=True, error_model="numpy")
def world_velocity(x):
    c = math.cos(x[4])
    s = math.sin(x[4])
    return x[2] * c - x[3] * s, x[2] * s + x[3] * c


@njit(cache=True, error_model="numpy")
def _accel_from_rates(x, c, s, vl_dot, vn_dot):
    """World-frame acceleration [m/s^2] from the body-frame rates; ``c, s`` = cos, sin of ``x[4]``."""
    r = x[5]
    ax = c * vl_dot - s * vn_dot + r * (-x[2] * s - x[3] * c)
    ay = s * vl_dot + c * vn_dot + r * (x[2] * c - x[3] * s)
    return ax, ay


@njit(cache=True, error_model="numpy")
def _root(z, c):
    """``sign(z) (sqrt(|z| + c^2) - c)`` and its derivative with respect to ``z``.

    ``c = 0`` is the square root of the barrier (odd extension below ``r = d0``); ``c > 0``
    [m/s] makes it Lipschitz at ``r = d0`` (derivative at most ``1 / (2 c)``) and the safe set
    slightly smaller (the allowed closing speed is lower by less than ``c``).
    """
    a = abs(z)
    q = math.sqrt(a + c * c)
    val = q - c
    d = 0.5 / max(q, 1e-9)
    return (val if z >= 0.0 else -val), d


@njit(cache=True, error_model="numpy")
def long_barrier(dpx, dpy, dvx, dvy, d0, a_bar, c=0.0):
    """``h = sqrt(2 a_bar (r - d0)) + v_hat`` [m/s] (with the smoothing ``c`` of :func:`_root`)."""
    r = math.sqrt(dpx * dpx + dpy * dpy)
    return _root(2.0 * a_bar * (r - d0), c)[0] + (dpx * dvx + dpy * dvy) / r


@njit(cache=True, error_model="numpy")
def long_constraint(x, delta, p, lead, d0, a_bar, gain, c=0.0):
    """The barrier condition as ``G a_l <= b``; returns ``(h, G, b)``.

    ``lead``: leader (px, py, vx, vy, ax, ay), world frame, centre of gravity. Below ``d0`` the
    root is extended as an odd function, so a small discrete-time overshoot into the unsafe set is
    pushed back by the same condition (``dh/dt >= -kappa h > 0``) instead of ending the filter.
    """
    f2, f3, _, g3, _ = body_rates_affine(x, delta, p)
    return long_constraint_given(x, math.cos(x[4]), math.sin(x[4]), f2, f3, g3, lead, d0, a_bar, gain, c)


@njit(cache=True, error_model="numpy")
def long_constraint_given(x, cp, sp, f2, f3, g3, lead, d0, a_bar, gain, c):
    """:func:`long_constraint` with the heading's ``cp, sp`` (cos, sin) and the body rates at
    ``a_l = 0`` with their slope in ``a_l`` (:func:`~nrtraffic.vehicle.bicycle.body_rates_affine`)
    already evaluated."""
    vx = x[2] * cp - x[3] * sp
    vy = x[2] * sp + x[3] * cp
    dpx = lead[0] - x[0]
    dpy = lead[1] - x[1]
    dvx = lead[2] - vx
    dvy = lead[3] - vy
    r = math.sqrt(dpx * dpx + dpy * dpy)
    if r < 1e-9:
        return -np.inf, np.nan, np.nan
    vh = (dpx * dvx + dpy * dvy) / r
    sroot, droot = _root(2.0 * a_bar * (r - d0), c)
    h = sroot + vh
    # follower acceleration, affine in a_l: acc(a) = acc0 + a * acc1
    a0x, a0y = _accel_from_rates(x, cp, sp, f2, f3)
    a1x = cp - sp * g3
    a1y = sp + cp * g3
    # dh/dt = drift - (<dp, acc1> / r) a_l >= -gain h
    # d/dt root(2 a_bar (r - d0)) = root' * 2 a_bar * r_dot, r_dot = v_hat
    drift = 2.0 * a_bar * droot * vh + (dvx * dvx + dvy * dvy - vh * vh) / r + (dpx * (lead[4] - a0x) + dpy * (lead[5] - a0y)) / r
    G = (dpx * a1x + dpy * a1y) / r
    return h, G, drift + gain * h


@njit(cache=True, error_model="numpy")
def long_filter_closed(a_star, G, b, a_lo, a_hi):
    """Exact solution of ``min (a - a*)^2 s.t. G a <= b, a_lo <= a <= a_hi``.

    Returns ``(a, status)``: INACTIVE (a* kept, clipped), ACTIVE (on the barrier), FALLBACK
    (infeasible or undefined: ``a_lo``, maximal braking).
    """
    if not (np.isfinite(G) and np.isfinite(b)):
        return a_lo, FALLBACK
    lo = a_lo
    hi = a_hi
    eps = 1e-12
    if G > eps:
        hi = min(hi, b / G)
    elif G < -eps:
        lo = max(lo, b / G)
    elif b < 0.0:
        return a_lo, FALLBACK
    if lo > hi:
        return a_lo, FALLBACK
    a = min(max(a_star, lo), hi)
    if a_star > hi and hi < a_hi:
        return a, ACTIVE
    if a_star < lo and lo > a_lo:
        return a, ACTIVE
    return a, INACTIVE


def long_filter_qp(a_star: float, G: float, b: float, a_lo: float, a_hi: float, solver: str = "osqp"):
    """The same QP (eq. 21/23) through qpsolvers; returns ``(a, status)`` like
    :func:`long_filter_closed` (FALLBACK when infeasible or the solver fails)."""
    from qpsolvers import Problem, solve_problem

    if not (np.isfinite(G) and np.isfinite(b)):
        return a_lo, FALLBACK
    Pm, Gm = np.array([[2.0]]), np.array([[G]])
    if solver == "osqp":  # a sparse solver: give it sparse matrices
        from scipy import sparse

        Pm, Gm = sparse.csc_matrix(Pm), sparse.csc_matrix(Gm)
    prob = Problem(P=Pm, q=np.array([-2.0 * a_star]), G=Gm, h=np.array([b]), lb=np.array([a_lo]),
                   ub=np.array([a_hi]))
    kwargs = {"eps_abs": 1e-9, "eps_rel": 1e-9, "polishing": True} if solver == "osqp" else {}
    import warnings

    try:
        with warnings.catch_warnings():  # an infeasible problem is an expected outcome here
            warnings.simplefilter("ignore")
            sol = solve_problem(prob, solver=solver, **kwargs)
    except Exception:
        return a_lo, FALLBACK
    if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
        return a_lo, FALLBACK
    a = float(sol.x[0])
    active = abs(a - min(max(a_star, a_lo), a_hi)) > 1e-6
    return a, ACTIVE if active else INACTIVE


@njit(cache=True, error_model="numpy")
def lat_barrier(y, ydot, y_max, k):
    """``h = y_max - |y + k sgn(y) y_dot^2|`` [m] (sgn(0) := sgn(y_dot))."""
    sg = 1.0 if y > 0.0 else (-1.0 if y < 0.0 else (1.0 if ydot > 0.0 else (-1.0 if ydot < 0.0 else 0.0)))
    return y_max - abs(y + k * sg * ydot * ydot)


@njit(cache=True, error_model="numpy")
def lat_condition(x, a, delta, p, y, tx, ty, curv, y_max, k, gamma):
    """``dh/dt + gamma h^3`` of the lateral barrier under steering ``delta``; also returns h.

    ``(tx, ty)`` path tangent at the projection, ``curv`` path curvature [1/m], ``y`` deviation.
    """
    vl_dot, vn_dot, _ = body_rates(x, a, delta, p)
    return lat_condition_given(x, math.cos(x[4]), math.sin(x[4]), vl_dot, vn_dot, y, tx, ty, curv, y_max, k, gamma)


@njit(cache=True, error_model="numpy")
def lat_condition_given(x, cp, sp, vl_dot, vn_dot, y, tx, ty, curv, y_max, k, gamma):
    """:func:`lat_condition` with the heading's ``cp, sp`` (cos, sin) and the body rates
    ``v_l', v_n'`` under the input already evaluated."""
    nx = -ty
    ny = tx
    vx = x[2] * cp - x[3] * sp
    vy = x[2] * sp + x[3] * cp
    ydot = nx * vx + ny * vy
    vt = tx * vx + ty * vy
    ax, ay = _accel_from_rates(x, cp, sp, vl_dot, vn_dot)
    yddot = nx * ax + ny * ay - curv * vt * vt / (1.0 - curv * y)
    sg = 1.0 if y > 0.0 else (-1.0 if y < 0.0 else (1.0 if ydot > 0.0 else (-1.0 if ydot < 0.0 else 0.0)))
    q = y + k * sg * ydot * ydot
    h = y_max - abs(q)
    sq = 1.0 if q > 0.0 else (-1.0 if q < 0.0 else 0.0)
    hdot = -sq * (ydot + 2.0 * k * sg * ydot * yddot)
    return hdot + gamma * h * h * h, h


@njit(cache=True, error_model="numpy")
def lat_filter(x, a, delta_star, p, y, tx, ty, curv, y_max, k, gamma, d_max, tol):
    """Closest admissible steering to ``delta_star`` in ``[-d_max, d_max]`` by bisection.

    Returns ``(delta, status, h)``; status INACTIVE, ACTIVE or FALLBACK (no admissible value: the
    end with the larger condition value).
    """
    vl_dot, vn_dot, _ = body_rates(x, a, delta_star, p)
    return lat_filter_given(x, math.cos(x[4]), math.sin(x[4]), a, delta_star, vl_dot, vn_dot, p, y, tx, ty, curv,
                            y_max, k, gamma, d_max, tol)


@njit(cache=True, error_model="numpy")
def lat_filter_given(x, cp, sp, a, delta_star, vl_dot, vn_dot, p, y, tx, ty, curv, y_max, k, gamma, d_max, tol):
    """:func:`lat_filter` with the heading's ``cp, sp`` and the body rates under
    ``(a, delta_star)`` already evaluated (other steering values are evaluated here)."""
    c0, h = lat_condition_given(x, cp, sp, vl_dot, vn_dot, y, tx, ty, curv, y_max, k, gamma)
    if c0 >= 0.0:
        return delta_star, INACTIVE, h
    c_lo = _lat_at(x, cp, sp, a, -d_max, p, y, tx, ty, curv, y_max, k, gamma)
    c_hi = _lat_at(x, cp, sp, a, d_max, p, y, tx, ty, curv, y_max, k, gamma)
    if c_lo < 0.0 and c_hi < 0.0:
        return (-d_max if c_lo > c_hi else d_max), FALLBACK, h
    # admissible end closest to delta_star
    if c_lo >= 0.0 and c_hi >= 0.0:
        end = -d_max if abs(delta_star + d_max) < abs(d_max - delta_star) else d_max
    else:
        end = -d_max if c_lo >= 0.0 else d_max
    bad = delta_star
    good = end
    while abs(good - bad) > tol:
        mid = 0.5 * (good + bad)
        if _lat_at(x, cp, sp, a, mid, p, y, tx, ty, curv, y_max, k, gamma) >= 0.0:
            good = mid
        else:
            bad = mid
    return good, ACTIVE, h


@njit(cache=True, error_model="numpy")
def _lat_at(x, cp, sp, a, delta, p, y, tx, ty, curv, y_max, k, gamma):
    vl_dot, vn_dot, _ = body_rates(x, a, delta, p)
    return lat_condition_given(x, cp, sp, vl_dot, vn_dot, y, tx, ty, curv, y_max, k, gamma)[0]
