"""Energy-optimal longitudinal profiles in closed form (Malikopoulos, Cassandras, Zhang 2018).

Double integrator ``p' = v, v' = u``; cost ``J = 1/2 int u^2`` from control-zone entry (local time
``tau = 0``, position 0, speed ``v0``) to merging-zone entry (``tau = T``, position ``D``).
Malikopoulos, Cassandras and Zhang, Automatica 2018; units: [m], [s], [m/s], [m/s^2].

Free terminal speed (the paper's case, ``u(T) = 0``): ``u = a (tau - T)``, ``a = 3 (v0 T - D)/T^3``,
``v_m = (3 D / T - v0) / 2``, ``J = 3 (D - v0 T)^2 / (2 T^3)``. With bounds the optimum is
``u = sat(c (tau1 - tau))`` followed by a cruise; the arcs join with ``u = 0`` at a speed bound.
Four closed-form arc sequences (``k = +-u_bound`` signed with the direction of the speed change,
``vb`` the speed bound in that direction):

- ``unconstrained``: one linear arc.
- ``speed``: linear arc to ``vb`` then cruise at ``vb``; switch at ``tau1 = 3 (vb T - D)/(vb - v0)``.
- ``accel``: ``u = k`` until ``T - w``, then linear to 0 at ``T``; ``w^2 = 3 T^2 - 6 (D - v0 T)/k``.
- ``accel_speed``: ``u = k`` for ``q - w/2``, linear to 0 over ``w`` reaching ``vb``, cruise;
  ``q = |vb - v0| / |k|``, ``w^2 = 24 (vb T - (vb - v0) q / 2 - D) / k``.

Fixed terminal speed ``v_m``: ``u = a tau + b``, ``a = (6 T (v0 + v_m) - 12 D)/T^3``,
``b = (6 D - 2 T (2 v0 + v_m))/T^2``. When that cubic would exceed ``v_max`` (a car entering at
the limit that must cross slower: ``b > 0``), the optimum has the speed bound as an arc
(``cruise``): a linear-``u`` arc from ``v0`` up to ``v_max`` ending with ``u = 0``, a cruise at
``v_max``, and a linear-``u`` arc from ``u = 0`` down to ``v_m``. With ``d1 = v_max - v0``,
``d2 = v_max - v_m`` the arcs take ``s_i = mu sqrt(d_i)`` (minimising ``J = 4/3 (d1^2 / s1 +
d2^2 / s2)`` for the distance ``D = v_max T - (d1 s1 + d2 s2) / 3``), ``mu = 3 (v_max T - D) /
(d1^1.5 + d2^1.5)``; their peak accelerations are ``2 d_i / s_i``. The other bounds are checked.
The earliest such arrival (:func:`earliest_fixed`) puts the binding arc's peak acceleration on its
bound: for ``v0 = v_max``, ``s2 = 2 (v0 - v_m) / |u_min|`` and ``T = (D + s2 (v0 - v_m) / 3) / v0``
(docs/method.md).

After ``T`` every profile continues at constant speed (the vehicle crosses the merging zone at
constant speed).

Rear-end safety inside the control zone (:func:`rear_end_constrained`): the closed forms ignore the
vehicle ahead, and a follower whose merge time is bound by spacing at the zone entry can catch up
with a slower leader on the way (a leader held back by a conflict slows down deeply in the middle
of the zone). Malikopoulos et al. (2018) state the rear-end constraint as a state constraint of the
same problem; it is solved here numerically: ``u`` piecewise linear on a uniform grid (so the
profile stays piecewise cubic), the exact integrals of it, ``J`` exact, and the gap to the
leader's planned position required at every grid instant -- a quadratic program.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

_TOL = 1e-9


class InfeasibleProfile(ValueError):
    """No profile within the bounds meets the boundary conditions."""


@dataclass(frozen=True)
class PlanBounds:
    """Bounds of the planning model.

    Attributes
    ----------
    v_min_mps, v_max_mps : speed bounds [m/s] (``0 < v_min < v_max``).
    u_min_mps2, u_max_mps2 : acceleration bounds [m/s^2] (``u_min < 0 < u_max``).
    max_lateral_accel_mps2 : lateral acceleration [m/s^2] that bounds the speed through the merging
        zone on a curved path, ``v <= sqrt(a / kappa_max)`` (0: no bound; SUMO's own turn speeds
        still apply at a junction).
    """

    v_min_mps: float = 1.0
    v_max_mps: float = 20.0
    u_min_mps2: float = -3.0
    u_max_mps2: float = 2.5
    max_lateral_accel_mps2: float = 0.0

    def __post_init__(self) -> None:
        if self.max_lateral_accel_mps2 < 0.0:
            raise ValueError(f"planning.max_lateral_accel_mps2 must be >= 0, got {self.max_lateral_accel_mps2}")
        if not (0.0 < self.v_min_mps < self.v_max_mps):
            raise ValueError(f"planning bounds need 0 < v_min < v_max, got {self.v_min_mps}, {self.v_max_mps}")
        if not (self.u_min_mps2 < 0.0 < self.u_max_mps2):
            raise ValueError(f"planning bounds need u_min < 0 < u_max, got {self.u_min_mps2}, {self.u_max_mps2}")


@dataclass(frozen=True)
class Profile:
    """A piecewise-cubic position profile in local time ``tau = t - t0``.

    ``knots[k]`` is the start of segment ``k``; ``coef[k] = (p, v, u, jerk)`` at that start.
    The last segment is the constant-speed continuation after ``T``.
    """

    t0: float
    T: float
    D: float
    v0: float
    kind: str
    knots: np.ndarray
    coef: np.ndarray

    @property
    def v_m(self) -> float:
        """Speed at the merging-zone entry [m/s]."""
        return float(self.coef[-1, 1])

    @property
    def t_m(self) -> float:
        """Merging-zone entry time (global) [s]."""
        return self.t0 + self.T

    def energy(self) -> float:
        """``1/2 int_0^T u^2 dtau`` [m^2/s^3], exact over the arcs."""
        J = 0.0
        for k in range(len(self.knots) - 1):
            d = self.knots[k + 1] - self.knots[k]
            u0, j = self.coef[k, 2], self.coef[k, 3]
            J += u0 * u0 * d + u0 * j * d * d + j * j * d**3 / 3.0
        return 0.5 * J

    def evaluate(self, t):
        """Position [m, from the entry point], speed and acceleration at global time(s) ``t``."""
        tau = np.asarray(t, dtype=np.float64) - self.t0
        k = np.clip(np.searchsorted(self.knots, tau, side="right") - 1, 0, len(self.knots) - 1)
        d = tau - self.knots[k]
        p0, v0, u0, j = (self.coef[k, i] for i in range(4))
        p = p0 + v0 * d + u0 * d * d / 2.0 + j * d**3 / 6.0
        v = v0 + u0 * d + j * d * d / 2.0
        u = u0 + j * d
        return p, v, u

    def packed(self, n_seg: int) -> np.ndarray:
        """``(n_seg, 5)`` rows ``(knot, p, v, u, jerk)`` for the compiled kernels, padded by
        repeating the final (cruise) segment."""
        out = np.empty((n_seg, 5))
        K = len(self.knots)
        if K > n_seg:
            raise ValueError(f"profile has {K} segments, more than {n_seg}")
        for i in range(n_seg):
            k = min(i, K - 1)
            out[i, 0] = self.knots[k] if i < K else self.knots[-1] + (i - K + 1) * 1e9
            out[i, 1:] = self.coef[k]
        return out


def _build(t0, T, D, v0, kind, arcs) -> Profile:
    """Chain arcs ``(duration, u_start, jerk)`` from (p, v) = (0, v0), then cruise."""
    knots, coef = [], []
    tau, p, v = 0.0, 0.0, v0
    for dur, u0, j in arcs:
        if dur <= _TOL:
            continue
        knots.append(tau)
        coef.append((p, v, u0, j))
        p += v * dur + u0 * dur * dur / 2.0 + j * dur**3 / 6.0
        v += u0 * dur + j * dur * dur / 2.0
        tau += dur
    knots.append(tau)
    coef.append((p, v, 0.0, 0.0))
    return Profile(float(t0), float(T), float(D), float(v0), kind, np.array(knots), np.array(coef))


def _within(prof: Profile, b: PlanBounds, tol: float = 1e-6) -> bool:
    # u is piecewise linear: extremes at knots; v is monotone on each arc (u keeps one sign)
    u_start = prof.coef[:, 2]
    u_end = u_start[:-1] + prof.coef[:-1, 3] * np.diff(prof.knots)
    us = np.concatenate([u_start, u_end])
    vs = prof.coef[1:, 1]  # the entry speed itself may lie outside (a queued, slow vehicle)
    return bool(
        np.all(us >= b.u_min_mps2 - tol)
        and np.all(us <= b.u_max_mps2 + tol)
        and np.all(vs >= b.v_min_mps - tol)
        and np.all(vs <= b.v_max_mps + tol)
        and abs(prof.coef[-1, 0] - prof.D) < 1e-6 * max(1.0, prof.D)
    )


def free_terminal(t0: float, v0: float, D: float, T: float, bounds: PlanBounds) -> Profile:
    """Energy-optimal profile with free terminal speed (``u(T) = 0``) within ``bounds``.

    Raises :class:`InfeasibleProfile` when no arc sequence meets ``D`` at ``T`` within the bounds.
    """
    if not (T > 0.0 and D > 0.0 and v0 >= 0.0):
        raise InfeasibleProfile(f"need T > 0, D > 0, v0 >= 0 (got T={T}, D={D}, v0={v0})")
    cands = []
    a = 3.0 * (v0 * T - D) / T**3
    cands.append(_build(t0, T, D, v0, "unconstrained", [(T, -a * T, a)]))
    accel = D > v0 * T
    k = bounds.u_max_mps2 if accel else bounds.u_min_mps2  # signed acceleration bound
    vb = bounds.v_max_mps if accel else bounds.v_min_mps
    dv = vb - v0
    # speed: linear arc to vb, cruise
    if abs(dv) > _TOL:
        tau1 = 3.0 * (vb * T - D) / dv
        if _TOL < tau1 <= T + _TOL:
            c = 2.0 * dv / tau1**2
            cands.append(_build(t0, T, D, v0, "speed", [(tau1, c * tau1, -c), (T - tau1, 0.0, 0.0)]))
    # accel: u = k, then linear to 0 at T
    w2 = 3.0 * T * T - 6.0 * (D - v0 * T) / k
    if w2 >= 0.0:
        w = math.sqrt(w2)
        if w <= T + _TOL:
            w = min(w, T)
            arcs = [(T - w, k, 0.0), (w, k, -k / w if w > _TOL else 0.0)]
            cands.append(_build(t0, T, D, v0, "accel", arcs))
    # accel_speed: u = k, linear to 0 reaching vb, cruise
    if abs(dv) > _TOL and dv * k > 0.0:
        q = dv / k
        w2 = 24.0 * (vb * T - dv * q / 2.0 - D) / k
        if w2 >= -_TOL:
            w = math.sqrt(max(w2, 0.0))
            if w <= 2.0 * q + _TOL and q + w / 2.0 <= T + _TOL:
                ta = max(q - w / 2.0, 0.0)
                arcs = [(ta, k, 0.0), (w, k, -k / w if w > _TOL else 0.0), (T - ta - w, 0.0, 0.0)]
                cands.append(_build(t0, T, D, v0, "accel_speed", arcs))
    ok = [c for c in cands if _within(c, bounds)]
    if not ok:
        raise InfeasibleProfile(
            f"no energy-optimal profile covers D={D:.2f} m in T={T:.2f} s from v0={v0:.2f} m/s "
            f"within v in [{bounds.v_min_mps}, {bounds.v_max_mps}] m/s, u in [{bounds.u_min_mps2}, {bounds.u_max_mps2}] m/s^2"
        )
    return min(ok, key=lambda c: c.energy())


def fixed_terminal(t0: float, v0: float, vm: float, D: float, T: float, bounds: PlanBounds | None = None) -> Profile:
    """Energy-optimal profile with fixed terminal speed ``vm``: ``u = a tau + b`` (4x4 system of
    the boundary conditions), or, where that would exceed ``bounds.v_max_mps``, the profile with the
    speed bound as a cruise arc (module docstring). Other bounds are checked (raise
    :class:`InfeasibleProfile`), not handled."""
    if not (T > 0.0 and D > 0.0):
        raise InfeasibleProfile(f"need T > 0 and D > 0 (got T={T}, D={D})")
    a = (6.0 * T * (v0 + vm) - 12.0 * D) / T**3
    b = (6.0 * D - 2.0 * T * (2.0 * v0 + vm)) / T**2
    prof = _build(t0, T, D, v0, "fixed_speed", [(T, b, a)])
    if bounds is None:
        return prof
    # v has an interior extremum where u = 0
    tau_star = -b / a if a != 0.0 else -1.0
    vs = [v0, vm]
    if 0.0 < tau_star < T:
        vs.append(v0 + b * tau_star + a * tau_star**2 / 2.0)
    us = [b, a * T + b]
    v_hi = max(bounds.v_max_mps, v0)
    v_lo = min(bounds.v_min_mps, v0)  # (a slow or standing car: never slower than it is)

    def inside(vs, us):
        return (min(vs) >= v_lo - 1e-9 and max(vs) <= v_hi + 1e-9
                and min(us) >= bounds.u_min_mps2 - 1e-9 and max(us) <= bounds.u_max_mps2 + 1e-9)

    if inside(vs, us):
        return prof
    # the speed bound as a cruise arc (the optimum when the cubic only exceeds v_max); when an
    # acceleration bound binds too, cruising at the entry speed instead still meets every bound at
    # and after the earliest arrival of :func:`earliest_fixed` (then feasible, if not optimal)
    for vb in dict.fromkeys((v_hi, v0)):
        cruise = _cruise_arcs(v0, vm, D, T, vb)
        if cruise is not None:
            us = [arc[1] for arc in cruise] + [arc[1] + arc[2] * arc[0] for arc in cruise]
            if inside([v0, vm, vb], us):
                return _build(t0, T, D, v0, "fixed_speed_cruise", cruise)
    slow = _slow_arcs(v0, vm, D, T, bounds)
    if slow is not None:
        return _build(t0, T, D, v0, "fixed_speed_slow", slow)
    raise InfeasibleProfile(
        f"fixed-terminal profile v0={v0:.2f} -> vm={vm:.2f} m/s over D={D:.2f} m in T={T:.2f} s leaves the bounds"
    )


def _slow_arcs(v0: float, vm: float, D: float, T: float, b: PlanBounds):
    """Arcs ``(duration, u_start, jerk)`` of the fixed-terminal optimum with the lower speed bound
    as a cruise arc (a long wait: the cubic would fall below ``v_min``), or None where they do not
    fit in ``T`` within the acceleration bounds. The mirror of the upper-bound case (module
    docstring): with ``d1 = v0 - v_min``, ``d2 = vm - v_min`` the arcs take ``s_i = mu sqrt(d_i)``,
    ``mu = 3 (D - v_min T) / (d1^1.5 + d2^1.5)``, since ``D = v_min T + (d1 s1 + d2 s2) / 3``; the
    first arc brakes with peak ``2 d1 / s1``, the last accelerates with peak ``2 d2 / s2``. *derived*"""
    vb = b.v_min_mps
    d1, d2 = v0 - vb, vm - vb
    K = 3.0 * (D - vb * T)
    if d1 < 0.0 or d2 < 0.0 or K <= 0.0 or d1 + d2 <= _TOL:
        return None
    mu = K / (d1**1.5 + d2**1.5)
    s1, s2 = mu * math.sqrt(d1), mu * math.sqrt(d2)
    if s1 + s2 > T + _TOL:
        return None
    if (s1 > _TOL and 2.0 * d1 / s1 > -b.u_min_mps2 + 1e-9) or (s2 > _TOL and 2.0 * d2 / s2 > b.u_max_mps2 + 1e-9):
        return None
    arcs = []
    if s1 > _TOL:
        arcs.append((s1, -2.0 * d1 / s1, 2.0 * d1 / s1**2))
    arcs.append((max(T - s1 - s2, 0.0), 0.0, 0.0))
    if s2 > _TOL:
        arcs.append((s2, 0.0, 2.0 * d2 / s2**2))
    return arcs


def from_rest(t0: float, D: float, a: float, v_cap: float) -> Profile:
    """A start from rest at ``t0``: constant acceleration ``a`` [m/s^2] up to ``v_cap`` [m/s], then
    cruise; ``T`` is when it has covered ``D`` [m] (its merging-zone entry). The crossing of a
    controlled vehicle that queued at the stop line behind a human driver (docs/mixed-traffic.md):
    it is not energy-optimal, and its speed starts below ``v_min``."""
    if not (a > 0.0 and v_cap > 0.0 and D >= 0.0):
        raise InfeasibleProfile(f"a start from rest needs a > 0, v_cap > 0, D >= 0 (got {a}, {v_cap}, {D})")
    from nrtraffic.planning.crossing import travel_time

    return _build(t0, travel_time(D, a, v_cap), D, 0.0, "from_rest", [(v_cap / a, a, 0.0)])


def standing_start(t0: float, t_start: float, D: float, a: float, v_cap: float) -> Profile:
    """A vehicle standing ``D`` [m] before its merging zone from ``t0`` that sets off at
    ``t_start`` at constant acceleration ``a`` [m/s^2] up to ``v_cap`` [m/s] (:func:`from_rest`
    with the wait before it): the motion a follower on its lane plans behind."""
    if not (a > 0.0 and v_cap > 0.0 and D >= 0.0 and t_start >= t0):
        raise InfeasibleProfile(f"a standing start needs a > 0, v_cap > 0, D >= 0, t_start >= t0 "
                                f"(got {a}, {v_cap}, {D}, {t_start} < {t0})")
    from nrtraffic.planning.crossing import travel_time

    return _build(t0, t_start - t0 + travel_time(D, a, v_cap), D, 0.0, "from_rest",
                  [(t_start - t0, 0.0, 0.0), (v_cap / a, a, 0.0)])


def _cruise_arcs(v0: float, vm: float, D: float, T: float, vb: float):
    """Arcs ``(duration, u_start, jerk)`` of the fixed-terminal optimum with the cruise arc at
    ``vb`` (module docstring), or None when they do not fit in ``T``."""
    d1, d2 = max(vb - v0, 0.0), max(vb - vm, 0.0)
    K = 3.0 * (vb * T - D)
    den = d1**1.5 + d2**1.5
    if den <= _TOL or K <= 0.0:
        return None
    mu = K / den
    s1, s2 = mu * math.sqrt(d1), mu * math.sqrt(d2)
    if s1 + s2 > T + _TOL:
        return None
    arcs = []
    if s1 > _TOL:
        arcs.append((s1, 2.0 * d1 / s1, -2.0 * d1 / s1**2))
    arcs.append((max(T - s1 - s2, 0.0), 0.0, 0.0))
    if s2 > _TOL:
        arcs.append((s2, 0.0, -2.0 * d2 / s2**2))
    return arcs


def earliest_fixed(v0: float, vm: float, D: float, bounds: PlanBounds, v_cruise: float | None = None) -> float:
    """Earliest arrival [s] over ``D`` [m] from ``v0`` to a fixed crossing speed ``vm`` [m/s]
    within the bounds: the cruise-arc profile of :func:`fixed_terminal` whose binding arc has its
    peak acceleration on the bound (time-optimal among the energy-optimal profiles), cruising at
    ``v_cruise`` (default ``v_max``; the entry speed for a coordinator that does not let cars
    arrive earlier than cruising at it). When ``D`` is too short for a cruise, the uniform change of
    speed ``2 D / (v0 + vm)`` (or the bounds' :func:`min_time`)."""
    vb = max(bounds.v_max_mps if v_cruise is None else v_cruise, v0)
    d1, d2 = vb - v0, max(vb - vm, 0.0)
    mu = max(2.0 * math.sqrt(d1) / bounds.u_max_mps2 if d1 > 0.0 else 0.0,
             2.0 * math.sqrt(d2) / -bounds.u_min_mps2 if d2 > 0.0 else 0.0)
    s1, s2 = mu * math.sqrt(d1), mu * math.sqrt(d2)
    arcs = s1 * (v0 + 2.0 * vb) / 3.0 + s2 * (2.0 * vb + vm) / 3.0  # distance on the two arcs [m]
    if arcs <= D:
        return s1 + s2 + (D - arcs) / vb
    return max(min_time(v0, D, bounds), 2.0 * D / (v0 + vm))


def rear_end_violation(prof: Profile, leader_pos, t_end: float, gap_m: float, dt: float = 0.1) -> float:
    """Largest intrusion [m] of ``prof`` into the gap behind its leader over ``[t0, t_end]``:
    ``max(p(t) - (leader_pos(t) - gap_m))`` sampled every ``dt`` [s] (<= 0: no violation).
    ``leader_pos(t)`` is the leader's planned position in this vehicle's coordinates [m]."""
    if t_end <= prof.t0:
        return -math.inf
    t = np.linspace(prof.t0, t_end, max(2, int(math.ceil((t_end - prof.t0) / dt)) + 1))
    return float(np.max(prof.evaluate(t)[0] - (leader_pos(t) - gap_m)))


def rear_end_constrained(t0: float, v0: float, D: float, T: float, bounds: PlanBounds, leader_pos, t_end: float,
                         gap_m: float, vm: float | None = None, step_s: float = 0.5, max_intervals: int = 80,
                         solver: str = "daqp") -> Profile:
    """Energy-optimal profile that also stays ``gap_m`` behind the leader's plan.

    Minimises ``J = 1/2 int_0^T u^2`` (exact for piecewise-linear ``u``) over the values of ``u`` at
    ``N = min(max_intervals, ceil(T / step_s))`` uniform intervals, subject to ``p(T) = D``,
    ``v(T) = vm`` (or ``u(T) = 0`` when ``vm`` is None: free terminal speed), the speed and
    acceleration bounds at the grid instants, and ``p(tau_k) <= leader_pos(t0 + tau_k) - gap_m``
    at every grid instant up to ``t_end`` [s]. One QP through qpsolvers (DAQP by default, dense).

    Raises :class:`InfeasibleProfile` when no such profile exists (or the solver fails).
    """
    from qpsolvers import Problem, solve_problem

    if not (T > 0.0 and D > 0.0):
        raise InfeasibleProfile(f"need T > 0 and D > 0 (got T={T}, D={D})")
    N = int(min(max_intervals, max(4, math.ceil(T / step_s))))
    h = T / N
    n = N + 1
    # v_k = v0 + Av[k] @ u, p_k = v0 tau_k + Ap[k] @ u (exact for u linear on each interval)
    Av = np.zeros((n, n))
    Ap = np.zeros((n, n))
    for k in range(N):
        Av[k + 1] = Av[k]
        Av[k + 1, k] += h / 2.0
        Av[k + 1, k + 1] += h / 2.0
        Ap[k + 1] = Ap[k] + h * Av[k]
        Ap[k + 1, k] += h * h / 3.0
        Ap[k + 1, k + 1] += h * h / 6.0
    tau = h * np.arange(n)
    # J = 1/2 sum h/3 (u_k^2 + u_k u_k+1 + u_k+1^2) = 1/2 u^T P u
    P = np.zeros((n, n))
    for k in range(N):
        P[k, k] += 2.0 * h / 3.0
        P[k + 1, k + 1] += 2.0 * h / 3.0
        P[k, k + 1] += h / 3.0
        P[k + 1, k] += h / 3.0
    A = [Ap[N]]
    b = [D - v0 * T]
    if vm is None:
        A.append(np.eye(n)[N])
        b.append(0.0)
    else:
        A.append(Av[N])
        b.append(vm - v0)
    G = [Av[1:], -Av[1:]]
    hv = [np.full(N, bounds.v_max_mps - v0), np.full(N, v0 - bounds.v_min_mps)]
    ahead = np.flatnonzero((tau > 0.0) & (t0 + tau <= t_end + 1e-9))
    if ahead.size:
        G.append(Ap[ahead])
        hv.append(leader_pos(t0 + tau[ahead]) - gap_m - v0 * tau[ahead])
    Gm, Am = np.vstack(G), np.vstack(A)
    if solver == "osqp":  # a sparse solver: give it sparse matrices
        from scipy import sparse

        P, Gm, Am = sparse.csc_matrix(P), sparse.csc_matrix(Gm), sparse.csc_matrix(Am)
    prob = Problem(P=P, q=np.zeros(n), G=Gm, h=np.concatenate(hv), A=Am, b=np.array(b),
                   lb=np.full(n, bounds.u_min_mps2), ub=np.full(n, bounds.u_max_mps2))
    kwargs = {"eps_abs": 1e-6, "eps_rel": 1e-6, "polishing": True, "max_iter": 100000} if solver == "osqp" else {}
    import warnings

    try:
        with warnings.catch_warnings():  # an infeasible problem is an expected outcome here
            warnings.simplefilter("ignore")
            sol = solve_problem(prob, solver=solver, **kwargs)
    except Exception as exc:  # a solver error is the same outcome for the caller
        raise InfeasibleProfile(f"rear-end constrained profile: solver {solver} failed: {exc}") from None
    if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
        raise InfeasibleProfile(
            f"no profile covers D={D:.2f} m in T={T:.2f} s from v0={v0:.2f} m/s and stays {gap_m:g} m behind the "
            f"leader's plan within the bounds")
    u = np.clip(sol.x, bounds.u_min_mps2, bounds.u_max_mps2)
    prof = _build(t0, T, D, v0, "rear_end", [(h, u[k], (u[k + 1] - u[k]) / h) for k in range(N)])
    if abs(prof.coef[-1, 0] - D) > 1e-3 or (vm is not None and abs(prof.coef[-1, 1] - vm) > 1e-3):
        raise InfeasibleProfile(f"rear-end constrained profile: solver {solver} did not meet the end conditions "
                                f"(p {prof.coef[-1, 0]:.4f} of {D:.4f} m, v {prof.coef[-1, 1]:.4f} m/s)")
    return prof


def min_time(v0: float, D: float, bounds: PlanBounds) -> float:
    """Shortest time [s] to cover ``D`` from ``v0`` within the bounds: full acceleration to
    ``v_max``, then cruise (the limit ``w -> 0`` of the ``accel``/``accel_speed`` arcs)."""
    v0 = min(v0, bounds.v_max_mps)
    ta = (bounds.v_max_mps - v0) / bounds.u_max_mps2
    da = (v0 + bounds.v_max_mps) * ta / 2.0
    if da >= D:
        return (-v0 + math.sqrt(v0 * v0 + 2.0 * bounds.u_max_mps2 * D)) / bounds.u_max_mps2
    return ta + (D - da) / bounds.v_max_mps


def max_time(v0: float, D: float, bounds: PlanBounds) -> float:
    """Longest time [s] to cover ``D`` from ``v0`` arriving at speed >= ``v_min``: full braking to
    ``v_min``, then cruise (``inf`` is impossible since ``v_min > 0``)."""
    v0 = max(v0, bounds.v_min_mps)
    tb = (v0 - bounds.v_min_mps) / -bounds.u_min_mps2
    db = (v0 + bounds.v_min_mps) * tb / 2.0
    if db >= D:
        # arrives before v_min is reached: solve v0 t + u_min t^2/2 = D (earliest root)
        disc = v0 * v0 + 2.0 * bounds.u_min_mps2 * D
        return (v0 - math.sqrt(max(disc, 0.0))) / -bounds.u_min_mps2
    return tb + (D - db) / bounds.v_min_mps


@njit(cache=True)
def packed_position(seg, tau):
    """Compiled position [m] of a packed profile (:meth:`Profile.packed`) at local time ``tau``."""
    # last segment whose knot is <= tau (the first one before it); knots increase
    lo, hi = 0, seg.shape[0] - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if seg[mid, 0] <= tau:
            lo = mid
        else:
            hi = mid - 1
    k = lo
    d = tau - seg[k, 0]
    return seg[k, 1] + seg[k, 2] * d + seg[k, 3] * d * d / 2.0 + seg[k, 4] * d * d * d / 6.0
