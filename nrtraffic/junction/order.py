"""Starts from rest in their lane's order, and never into a vehicle standing in the way.

A controlled vehicle standing at its stop line (or in a standing queue before it) sets off when its
reserved start from rest comes (:meth:`~nrtraffic.junction.admission.Admission.start`). Two things
hold it back, besides a queued exit (:func:`~nrtraffic.junction.exits.wait_for_room`):

- the car standing ahead of it on its entry lane, also waiting for its start, has none (its exit
  queued) or a later one (:func:`after_leader`). Without this, the cars queued behind a car whose
  start was given up would be reserved again before it, set off into it, come late, and be reserved
  again behind the lane's last car, over and over, while their windows kept the crossing movements
  out;
- a vehicle with no crossing of its own arranged stands ahead of it on its path, short of its
  merging-zone exit (:func:`way_held`): a car of SUMO's on a lane that does not serve its turn (on a
  flared approach, where turn lanes are added inside the control zone), a held car, a human driver
  waiting for its reservation. Setting off, it would stop behind it and come late into its window.

Either way it gives its start up (:func:`~nrtraffic.junction.exits.give_up_start`: ``replans``
counts it) and waits; its start is reserved again once its exit is clear
(:func:`~nrtraffic.junction.exits.wait_for_room`), behind the car ahead.
"""

from __future__ import annotations

import math

from nrtraffic.junction import exits
from nrtraffic.junction.late import STANDING_MPS
from nrtraffic.lifecycle import State
from nrtraffic.sumo.network import edge_of

# a vehicle in one of these states has its crossing arranged (or its start, in its lane's order):
# standing ahead of a start from rest, it does not hold it (:func:`way_held`)
ARRANGED = frozenset({State.STARTING, State.CONTROLLED, State.RESERVED, State.CROSSING})


def starting_ahead(st, starting: list[str]) -> dict[str, str]:
    """Of the vehicles waiting for their start from rest (``starting``), each one's nearest such
    vehicle ahead on the same entry lane (nearer its merging zone), where there is one."""
    by_lane: dict[tuple[str, str], list[tuple[float, str]]] = {}
    for vid in starting:
        s = st.where_on_path(vid)
        if s == -math.inf:
            continue
        rec = st.records[vid]
        by_lane.setdefault((rec.junction, rec.lane), []).append((st.paths[rec.movement].s_merge - s, vid))
    ahead = {}
    for cars in by_lane.values():
        cars.sort()
        for (_, front), (_, back) in zip(cars, cars[1:]):
            ahead[back] = front
    return ahead


def after_leader(st, vid: str, leader: str) -> bool:
    """Whether ``vid`` waits for the vehicle standing ahead of it on its lane (``leader``) to have
    its start reserved first: where the leader has none (its exit queued) or a later one, ``vid``
    gives its own up and waits (True)."""
    rec, lead = st.records[vid], st.records[leader]
    if not (math.isinf(lead.t_release) or lead.t_release > rec.t_release + 1e-9):
        return False
    exits.give_up_start(st, vid)
    return True


def way_held(st, vid: str) -> bool:
    """Whether ``vid``, whose reserved start from rest has come, stands behind a vehicle with no
    crossing arranged (:func:`standing_ahead`): it gives its start up and waits (True). One that
    waits has its start reserved again only once none stands there
    (:meth:`~nrtraffic.junction.admission.Admission.start`)."""
    if standing_ahead(st, vid) is None:
        return False
    exits.give_up_start(st, vid)
    return True


def standing_ahead(st, vid: str) -> str | None:
    """The first vehicle found standing on ``vid``'s movement's lanes ahead of it (by SUMO's view
    now), whose rear is short of the merging zone's exit and whose crossing is not arranged
    (:data:`ARRANGED`), or None."""
    snap = st.snap
    s_self = st.where_on_path(vid)
    if s_self == -math.inf:
        return None
    mv = st.paths[st.records[vid].movement]
    front = s_self + st.params.cg_to_front
    rows = snap.rows_by_edge
    for lane in mv.lanes:
        off, scale = mv.lane_offset[lane]
        for k in rows.get(edge_of(lane), ()):
            if snap.lane[k] != lane or snap.speed[k] >= STANDING_MPS:
                continue
            other = snap.ids[k]
            s_front = off + float(snap.lane_pos[k]) * scale
            if other == vid or s_front <= front or s_front - st.params.length >= mv.s_exit:
                continue
            if st.life.state(other) not in ARRANGED:
                return other
    return None
