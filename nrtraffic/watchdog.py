"""The watchdogs of a run: a junction, or one of its entry lanes, that makes no progress, and a run
without a duration that cannot end. Each raises :class:`Gridlock` (the run's status
``"gridlock"``), naming the vehicles."""

from __future__ import annotations

import math

from nrtraffic.limits import MAX_DURATION_S

MOVING_MPS = 0.1  # a vehicle slower than this stands still (a run without a duration) [m/s]


class Gridlock(RuntimeError):
    """A junction made no progress: no vehicle left its merging zone for ``outputs.stall_s`` while
    vehicles waited there, or none of one of its entry lanes while vehicles waited on it; or, in a
    run without a duration, no vehicle moved."""


def watch_junctions(st, admission) -> None:
    """Raise :class:`Gridlock` when a junction has had vehicles waiting and none leaving its
    merging zone for ``outputs.stall_s``, or when one of its entry lanes has (its other lanes may
    go on crossing: a lane that stands still for ever is no less a gridlock), naming the junction,
    the lane, the waiting vehicles and their movements."""
    stall = st.sc.outputs.stall_s
    if stall <= 0:
        return
    for j in st.junctions.values():
        waiting = admission.waiting(j)
        crossed = max(j.lane_exit.values(), default=-math.inf) > j.looked_at  # (since the last look)
        j.looked_at = st.t
        if crossed or not waiting:
            j.idle_since = st.t
        elif st.t - j.idle_since >= stall:
            raise Gridlock(f"junction {j.id or '(road)'}: no vehicle crossed for {st.t - j.idle_since:.0f} s "
                           f"(outputs.stall_s = {stall:g}) while {len(waiting)} in its control zone waited to "
                           f"cross: {_names(st, waiting)}")
        _watch_lanes(st, j, waiting, stall)


def _watch_lanes(st, j, waiting: list[str], stall: float) -> None:
    """The watchdog's look at each entry lane of junction ``j`` where vehicles wait (``waiting``)."""
    lanes: dict[str, list[str]] = {}
    for v in waiting:
        lanes.setdefault(st.records[v].lane, []).append(v)
    j.lane_waiting = {lane: j.lane_waiting.get(lane, st.t) for lane in lanes}
    for lane, vids in lanes.items():
        idle = st.t - max(j.lane_waiting[lane], j.lane_exit.get(lane, -math.inf))
        if idle >= stall:
            raise Gridlock(f"junction {j.id or '(road)'}: no vehicle crossed for {idle:.0f} s from its lane {lane} "
                           f"(outputs.stall_s = {stall:g}) while {len(vids)} on that lane waited to cross: "
                           f"{_names(st, vids)}; its other lanes went on crossing")


def _names(st, vids: list[str]) -> str:
    names = ", ".join(f"{v} ({st.records[v].movement}, {st.records[v].status})" for v in vids[:12])
    return names + (f" and {len(vids) - 12} more" if len(vids) > 12 else "")


class OpenEnd:
    """A run without a duration (``--duration 0``: until every vehicle has left) that cannot end:
    :meth:`watch` raises :class:`Gridlock` when every vehicle in the network has stood still for
    ``outputs.stall_s`` (one parked outside every control zone holds the run for ever), and fails
    the run when the clock reaches the longest run accepted, :data:`~nrtraffic.limits.MAX_DURATION_S`."""

    def __init__(self) -> None:
        self.still_since = 0.0  # since when no vehicle has moved [s]

    def watch(self, st) -> None:
        stall = st.sc.outputs.stall_s
        if st.t >= MAX_DURATION_S:
            raise RuntimeError(f"--duration 0 runs until every vehicle has left, and {st.sumo.pending()} had not after "
                               f"{MAX_DURATION_S:g} s, the longest run: give a duration")
        moving = bool((st.snap.speed > MOVING_MPS).any())
        if not moving:  # (those forgotten outside every zone are not in the snapshot: asked one by one;
            # an empty network waits for departures to come)
            ids = st.sumo.vehicle_ids()
            moving = not ids or any(st.sumo.speed(v) > MOVING_MPS for v in ids)
        if moving or stall <= 0:
            self.still_since = st.t
            return
        if st.t - self.still_since >= stall:
            ids = st.sumo.vehicle_ids()
            names = ", ".join(ids[:12]) + (f" and {len(ids) - 12} more" if len(ids) > 12 else "")
            raise Gridlock(f"--duration 0 runs until every vehicle has left, but every vehicle in the network has "
                           f"stood still for {st.t - self.still_since:.0f} s (outputs.stall_s = {stall:g}): {names}; "
                           "give a duration, or let them drive on")
