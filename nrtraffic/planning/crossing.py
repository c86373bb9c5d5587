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

import functools
import math
from dataclasses import dataclass

import numpy as np


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


def travel_times(d, a: float, v_cap, v0=0.0) -> np.ndarray:
    """:func:`travel_time` of arrays (``d``, ``v_cap`` and ``v0`` broadcast), branch for branch."""
    d, v_cap, v0 = np.broadcast_arrays(np.asarray(d, dtype=float), np.asarray(v_cap, dtype=float),
                                       np.asarray(v0, dtype=float))
    d_acc = (v_cap * v_cap - v0 * v0) / (2.0 * a)
    with np.errstate(invalid="ignore"):  # (the branches np.where does not take)
        accelerating = (np.sqrt(v0 * v0 + 2.0 * a * d) - v0) / a
    capped = (v_cap - v0) / a + (d - d_acc) / v_cap
    t = np.where(d <= d_acc, accelerating, capped)
    t = np.where(v0 >= v_cap, d / v_cap, t)
    return np.where(d <= 0.0, 0.0, t)


def speed_from_rest(d: float, a: float, v_cap: float, v0: float = 0.0) -> float:
    """Speed [m/s] after ``d`` [m] from speed ``v0`` (default rest) at acceleration ``a`` up to
    ``v_cap`` (from above the cap: the cap)."""
    return v_cap if v0 >= v_cap else min(v_cap, math.sqrt(v0 * v0 + 2.0 * a * max(d, 0.0)))


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

    def speed_at(self, d: float, v0: float = 0.0) -> float:
        """Its lowest speed [m/s] ``d`` [m] on from speed ``v0`` [m/s]."""
        return speed_from_rest(d, self.a_lo, self.v_lo, v0)


def human_crossing(bounds, areas: dict, d_merge: float, d_exit: float, v0: float = 0.0):
    """Occupancy offsets of a crossing from rest, or from speed ``v0`` [m/s] on the move (bounds
    :class:`CrossingBounds` or :class:`KraussBounds`): ``areas`` maps each other movement to the
    stretch ``(d_in, d_out)`` [m ahead of the centre of gravity] where the bodies can touch;
    ``d_merge``, ``d_exit`` the distances to the merging-zone entry and exit [m]. Returns
    ``(offsets, merge_window, exit_window, v_exit_min)`` as
    :meth:`~nrtraffic.planning.coordinator.Coordinator.reserve_crossing` takes them."""
    offsets = {o: bounds.window(max(a, 0.0), max(b, 0.0), v0) for o, (a, b) in areas.items()}
    # (a vehicle standing in the merging zone has passed its entry: d_merge < 0, entered now)
    return (offsets, bounds.window(d_merge, d_merge, v0), bounds.window(d_exit, d_exit, v0),
            bounds.speed_at(d_exit, v0))


@functools.lru_cache(maxsize=256)
def _krauss_motion(accel: float, sigma: float, v_cap: float, step_s: float) -> tuple:
    """Krauss's motion from rest, always dawdling by ``sigma`` (0: never) up to ``v_cap`` (see
    :class:`KraussBounds`): speeds [m/s] and positions [m] at the end of each step while it picks
    up speed, then its cruising speed. The same for every driver of a type and cap: computed once
    (a driver's bounds are asked for at every step while it approaches, :func:`~nrtraffic.
    junction.humans.go_on`)."""
    v = x = 0.0
    vs, xs = [0.0], [0.0]
    while True:
        u = min(v + accel * step_s, v_cap)
        u = max(u - sigma * step_s * (u if u < accel else accel), 0.0)
        if u <= v + 1e-12:  # cruising: it gains nothing more
            out = np.array(vs), np.array(xs), max(v, 1e-9)
            for arr in out[:2]:
                arr.flags.writeable = False  # (shared by every caller)
            return out
        v, x = u, x + u * step_s
        vs.append(v)
        xs.append(x)


class KraussBounds:
    """The earliest and latest times [s] in which SUMO's Krauss driver covers a distance, computed
    by stepping its own speed update rather than bounding it by constant accelerations.

    Each step of ``step_s`` [s], Krauss's next speed is ``u = min(v + accel step, v_cap)`` less its
    dawdling, ``sigma u step r`` while ``u < accel`` (numerically: SUMO compares the speed with the
    acceleration) and ``sigma accel step r`` above, ``r`` uniform in [0, 1)
    (``MSCFModel_Krauss::dawdle2``); the position moves on by ``u step`` (semi-implicit Euler).
    ``r = 0`` at ``v_hi`` gives the earliest motion, ``r -> 1`` at ``v_lo`` the latest, which also
    sets off one step late. A start from rest therefore picks up speed at almost ``accel`` until
    it reaches ``accel`` [m/s] numerically, and at ``(1 - sigma) accel`` only above it, where
    :class:`CrossingBounds` assumes ``(1 - sigma) accel`` throughout: about half a second less per
    conflict area at SUMO's defaults. On the move, from speed ``v0``, the bounds continue the
    motion from rest from its last step no faster (latest) or first step no slower (earliest) than
    ``v0``: the speed update is monotone in the speed, so either is on the safe side.

    ``a_lo``, ``v_lo``: a constant-acceleration motion no faster than the latest one (a follower
    planned behind this start keeps behind it, :meth:`~nrtraffic.planning.coordinator.Coordinator.
    reserve_crossing`)."""

    def __init__(self, accel: float, sigma: float, v_lo: float, v_hi: float, step_s: float):
        if not (accel > 0 and 0 <= sigma < 1 and 0 < v_lo <= v_hi and step_s > 0):
            raise ValueError(f"Krauss bounds need accel > 0, 0 <= sigma < 1, 0 < v_lo <= v_hi, step > 0: "
                             f"{accel}, {sigma}, {v_lo}, {v_hi}, {step_s}")
        self.step_s = step_s
        self._lo = _krauss_motion(accel, sigma, v_lo, step_s)
        self._hi = _krauss_motion(accel, 0.0, v_hi, step_s)
        self.a_lo, self.a_hi = (1.0 - sigma) * accel, accel
        self.v_lo, self.v_hi = self._lo[2], v_hi  # (the latest cruises a dawdle below its cap)

    @staticmethod
    def _step(vs: np.ndarray, v0: float, slowest: bool) -> int:
        """The step of a motion to continue from a state of speed ``v0``: the last no faster
        (``slowest``: for the latest) or the first no slower (for the earliest); len(vs) where
        none is."""
        if slowest:
            return int(np.searchsorted(vs, v0 + 1e-9, side="right")) - 1
        return int(np.searchsorted(vs, v0 - 1e-9, side="left"))

    def _time(self, motion: tuple, d: float, v0: float, slowest: bool) -> float:
        """Steps [s] from a state of speed ``v0`` to cover ``d`` [m] on ``motion``."""
        vs, xs, v_cruise = motion
        h = self.step_s
        j = self._step(vs, v0, slowest)
        if j >= len(vs):  # faster than the motion ever gets: (earliest) at its own speed
            return d / max(v0, v_cruise)
        target = xs[j] + d
        k = int(np.searchsorted(xs, target - 1e-9, side="left"))
        if k < len(xs):
            return (k - j) * h
        return (len(xs) - 1 - j + math.ceil((target - xs[-1]) / (v_cruise * h) - 1e-9)) * h

    def speed_at(self, d: float, v0: float = 0.0) -> float:
        """Its lowest speed [m/s] ``d`` [m] on from speed ``v0`` [m/s]."""
        vs, xs, v_cruise = self._lo
        j = self._step(vs, v0, True)
        k = int(np.searchsorted(xs, xs[j] + d - 1e-9, side="left"))
        return float(vs[k]) if k < len(vs) else v_cruise

    def window(self, d_in: float, d_out: float, v0: float = 0.0) -> tuple[float, float]:
        """Earliest entry and latest exit [s from now] of the stretch ``[d_in, d_out]`` [m ahead
        of the centre of gravity], for a driver at speed ``v0`` [m/s] (default: at rest, about to
        be released); the latest sets off one step late (SUMO acts on a release, or a dropped stop,
        in its next step); never before now."""
        t_in = self._time(self._hi, d_in, v0, False) if d_in > 0 else 0.0
        t_out = self._time(self._lo, d_out, v0, True) if d_out > 0 else 0.0
        return max(t_in - self.step_s, 0.0), t_out + self.step_s
