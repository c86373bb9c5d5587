"""The crossing of a vehicle the coordinator does not steer: a human driver that stands at the
stop line and sets off when its reservation starts (``demand.controlled_share``;
docs/mixed-traffic.md).

From rest, accelerating at ``a`` [m/s^2] up to ``v_cap`` [m/s], a vehicle covers ``d`` [m] in::

    T(d) = sqrt(2 d / a)                                  for d <= v_cap^2 / (2 a)
         = v_cap / a + (d - v_cap^2 / (2 a)) / v_cap      beyond

and from speed ``v0 < v_cap`` in ``(sqrt(v0^2 + 2 a d) - v0) / a`` while it accelerates; from
``v0 >= v_cap``, no later than ``d / v_cap`` (it may only slow down to ``v_cap``).

Its occupancy of a stretch ``[d_in, d_out]`` of its path (distances of its centre of gravity from
where it stands) is bounded by the earliest entry ``T_hi(d_in) - h`` and the latest exit
``T_lo(d_out) + h``: ``T_hi`` at the driver's highest acceleration and speed, ``T_lo`` at its lowest,
``h`` the SUMO step. SUMO's position update (semi-implicit Euler, ``x += v_new h``) runs ahead of
the continuous motion by at most ``a h t / 2``, less than one step's worth of time at the start,
hence ``- h``; the driver sets off at most one step after its release, hence ``+ h``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


def travel_time(d: float, a: float, v_cap: float, v0: float = 0.0) -> float:
    """Time [s] to cover ``d`` [m] from speed ``v0`` (default rest) at acceleration ``a`` [m/s^2]
    up to ``v_cap`` [m/s] (module docstring)."""
    if d <= 0.0:
        return 0.0
    if v0 >= v_cap:
        return d / v_cap
    d_acc = (v_cap * v_cap - v0 * v0) / (2.0 * a)
    if d <= d_acc:
        return (math.sqrt(v0 * v0 + 2.0 * a * d) - v0) / a
    return (v_cap - v0) / a + (d - d_acc) / v_cap


def speed_from_rest(d: float, a: float, v_cap: float) -> float:
    """Speed [m/s] after ``d`` [m] from rest at acceleration ``a`` up to ``v_cap``."""
    return min(v_cap, math.sqrt(2.0 * a * max(d, 0.0)))


@dataclass(frozen=True)
class CrossingBounds:
    """How fast a driver that sets off from rest may be: accelerations [m/s^2] and speed caps
    [m/s], lowest and highest, and the simulation step ``step_s`` [s]."""

    a_lo: float
    a_hi: float
    v_lo: float
    v_hi: float
    step_s: float

    def __post_init__(self) -> None:
        if not (0 < self.a_lo <= self.a_hi and 0 < self.v_lo <= self.v_hi and self.step_s >= 0):
            raise ValueError(f"crossing bounds need 0 < a_lo <= a_hi, 0 < v_lo <= v_hi, step >= 0: {self}")

    def window(self, d_in: float, d_out: float, v0: float = 0.0) -> tuple[float, float]:
        """Earliest entry and latest exit [s from now] of the stretch ``[d_in, d_out]`` [m ahead
        of the centre of gravity], for a vehicle at speed ``v0`` [m/s] (default: at rest, about to
        be released); never before now."""
        t_in = max(travel_time(d_in, self.a_hi, self.v_hi, v0) - self.step_s, 0.0)
        return t_in, travel_time(d_out, self.a_lo, self.v_lo, v0) + self.step_s


def human_crossing(bounds: CrossingBounds, areas: dict, d_merge: float, d_exit: float):
    """Occupancy offsets of a crossing from rest: ``areas`` maps each other movement to the stretch
    ``(d_in, d_out)`` [m ahead of the standing centre of gravity] where the bodies can touch;
    ``d_merge``, ``d_exit`` the distances to the merging-zone entry and exit [m]. Returns
    ``(offsets, merge_window, exit_window, v_exit_min)`` as
    :meth:`~nrtraffic.planning.coordinator.Coordinator.reserve_crossing` takes them."""
    offsets = {o: bounds.window(max(a, 0.0), max(b, 0.0)) for o, (a, b) in areas.items()}
    v_exit = speed_from_rest(d_exit, bounds.a_lo, bounds.v_lo)
    # (a vehicle standing in the merging zone has passed its entry: d_merge < 0, entered now)
    return offsets, bounds.window(d_merge, d_merge), bounds.window(d_exit, d_exit), v_exit
