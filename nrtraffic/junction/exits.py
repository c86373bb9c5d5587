"""Don't block the box: no controlled vehicle enters its merging zone while its exit road is
queued up to the zone.

Where a queue from the next junction reaches back to a merging zone (a short link past
capacity), a vehicle that enters on its plan finds, only once inside, a standing car just beyond
the zone on its exit lane, and stops in the zone, in the way of the movements that cross it.

A movement's exit is *blocked* for a vehicle when a vehicle past the merging zone's exit, on the
movement's lanes or beside them on the same road, stands or crawls (slower than
:data:`QUEUE_MPS`), or brakes (harder than :data:`BRAKING_MPS2`) to a stop, where its rear leaves
too little room between it and the exit for the vehicle and every vehicle ahead of it on its path:
a body length and the barrier's standstill gap each, and :data:`ROOM_M` to spare. A controlled
vehicle about to enter (:class:`~nrtraffic.junction.late.LateGuard`) stops at the entry instead,
and has its start from rest reserved again; a reserved start from rest waits until the exit is
clear (:meth:`~nrtraffic.junction.admission.Admission.start`).
"""

from __future__ import annotations

import math

import numpy as np

from nrtraffic.sumo.network import edge_of

QUEUE_MPS = 2.0  # a vehicle slower than this past a merging zone is a queue [m/s]
BRAKING_MPS2 = 0.5  # ... and one decelerating harder than this stops where its deceleration takes it [m/s^2]
ROOM_M = 3.0  # room a vehicle needs past its merging zone beyond its body and the standstill gap [m]


def _queued_edges(snap) -> set[str]:
    """The edges on which a vehicle stands, crawls or brakes (what :func:`blocked` counts as a
    queue, wherever it is), found once per snapshot."""
    found = snap.derived.get("queued_edges")
    if found is None:
        slow = np.flatnonzero((snap.speed < QUEUE_MPS) | (snap.accel < -BRAKING_MPS2)).tolist()
        found = snap.derived["queued_edges"] = {edge_of(snap.lane[k]) for k in slow}
    return found


def blocked(st, vid: str) -> str | None:
    """The vehicle that blocks ``vid``'s exit (the module's docstring), or None. ``vid`` is on its
    movement's path before or at its merging zone; vehicles behind it do not count, and each
    vehicle between it and the queue on its path needs its own room. On the roads past the junction
    every lane counts (a car queued on the next lane changes into this one); the junction's own
    (internal) lanes are not searched."""
    rec = st.records[vid]
    mv = st.paths[rec.movement]
    snap = st.snap
    queued = _queued_edges(snap)
    if queued.isdisjoint(mv.exit_edges):  # (no vehicle past the zone that could queue)
        return None
    s_self = st.cg_on_path(vid)
    if s_self is None:
        return None
    body = st.params.length + st.sc.barriers.min_gap_m  # room a car takes in a queue [m]
    rows = snap.rows_by_edge
    ahead, queue = [], []  # on its own lanes ahead of it; standing or stopping past the exit
    for lane in mv.lanes:
        if lane.startswith(":"):  # (the junction's own lanes are not searched: a car inside it is not counted)
            continue
        off, scale = mv.lane_offset[lane]
        for k in rows.get(edge_of(lane), ()):
            if snap.ids[k] == vid:
                continue
            s_front = off + float(snap.lane_pos[k]) * scale
            if s_front <= s_self:
                continue
            if snap.lane[k] == lane:
                ahead.append(s_front)
            v, a = float(snap.speed[k]), float(snap.accel[k])
            if s_front <= mv.s_exit:
                continue
            if v < QUEUE_MPS:
                queue.append((s_front, s_front, k))
            elif a < -BRAKING_MPS2:
                queue.append((s_front, s_front + v * v / (-2.0 * a), k))
    for s_front, s_stop, k in sorted(queue):
        between = sum(1 for s in ahead if s < s_front)
        if s_stop - st.params.length - mv.s_exit < (between + 1) * body + ROOM_M:
            return snap.ids[k]
    return None


def wait_for_room(st, vid: str, reserve_start) -> bool:
    """Whether a controlled vehicle whose start from rest is reserved waits for room past its
    merging zone: one whose start has come while its exit is queued gives it up (its reservation
    is cancelled) and stands; once the exit is clear, ``reserve_start(vid)`` reserves its start
    again."""
    rec = st.records[vid]
    if math.isinf(rec.t_release):  # (waiting)
        if vid in st.snap.row and blocked(st, vid) is None:
            reserve_start(vid)
        return True
    if st.t >= rec.t_release - 1e-9 and vid in st.snap.row and blocked(st, vid) is not None:
        give_up_start(st, vid)
        return True
    return False


def give_up_start(st, vid: str) -> None:
    """A controlled vehicle standing for its start from rest gives its reserved start up (its
    reservation is cancelled; ``t_release`` inf: it waits for a new one) where it has one."""
    rec = st.records[vid]
    if not math.isinf(rec.t_release):
        st.junctions[rec.junction].coord.cancel(vid)
        rec.t_release = math.inf
        rec.replans += 1
