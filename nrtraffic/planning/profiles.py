"""Energy-optimal longitudinal profiles in closed form (Malikopoulos, Cassandras, Zhang 2018).

Double integrator ``p' = v, v' = u``; cost ``J = 1/2 int u^2`` from control-zone entry (local time
``tau = 0``, position 0, speed ``v0``) to merging-zone entry (``tau = T``, position ``D``).
REFERENCE.md section 3; units: [m], [s], [m/s], [m/s^2].

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
``b = (6 D - 2 T (2 v0 + v_m))/T^2``; bounds are checked, not handled.

After ``T`` every profile continues at constant speed (the vehicle crosses the merging zone at
constant speed).
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
    """

    v_min_mps: float = 1.0
    v_max_mps: float = 20.0
    u_min_mps2: float = -3.0
    u_max_mps2: float = 2.5

    def __post_init__(self) -> None:
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
    the boundary conditions). ``bounds`` are checked (raise :class:`InfeasibleProfile`), not handled."""
    if not (T > 0.0 and D > 0.0):
        raise InfeasibleProfile(f"need T > 0 and D > 0 (got T={T}, D={D})")
    a = (6.0 * T * (v0 + vm) - 12.0 * D) / T**3
    b = (6.0 * D - 2.0 * T * (2.0 * v0 + vm)) / T**2
    prof = _build(t0, T, D, v0, "fixed_speed", [(T, b, a)])
    if bounds is not None:
        # v has an interior extremum where u = 0
        tau_star = -b / a if a != 0.0 else -1.0
        vs = [v0, vm]
        if 0.0 < tau_star < T:
            vs.append(v0 + b * tau_star + a * tau_star**2 / 2.0)
        us = [b, a * T + b]
        if min(vs) < bounds.v_min_mps - 1e-9 or max(vs) > bounds.v_max_mps + 1e-9 or min(us) < bounds.u_min_mps2 - 1e-9 or max(us) > bounds.u_max_mps2 + 1e-9:
            raise InfeasibleProfile(
                f"fixed-terminal profile v0={v0:.2f} -> vm={vm:.2f} m/s over D={D:.2f} m in T={T:.2f} s leaves the bounds"
            )
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
    k = 0
    for i in range(seg.shape[0]):
        if seg[i, 0] <= tau:
            k = i
    d = tau - seg[k, 0]
    return seg[k, 1] + seg[k, 2] * d + seg[k, 3] * d * d / 2.0 + seg[k, 4] * d * d * d / 6.0
