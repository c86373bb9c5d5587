"""Human drivers at a controlled junction, and reserved crossings from rest.

A human driver (``demand.controlled_share`` < 1) is sent to its stop line (``human``); standing
there, its crossing is reserved between kinematic bounds (``reserved``,
:meth:`~nrtraffic.planning.coordinator.Coordinator.reserve_crossing`); when the reservation starts
SUMO's driver sets off (``crossing``), and the reservation shrinks as it goes to what its bounds
still allow; past the merging zone it is spent (``crossed``). A controlled vehicle standing at the
stop line has its start from rest reserved the same way (:func:`reserve`).
"""

from __future__ import annotations

import math

from nrtraffic.junction.build import HUMAN_BODY
from nrtraffic.lifecycle import HUMAN_DRIVERS, State, VehicleRecord
from nrtraffic.planning.crossing import CrossingBounds, human_crossing


def to_stop_line(st, vid: str) -> None:
    """A human driver on its way to a junction: SUMO stops it at the stop line of its movement
    there, where its crossing will be reserved (:func:`step`)."""
    rec = st.records[vid]
    st.life.move(vid, State.HUMAN, junction=rec.junction)
    st.sumo.stop_at(vid, *st.stop_line[rec.movement, rec.driver])
    st.sumo.colour(vid, "human")
    st.life.wait_at_line(vid, rec.lane)


def step(st) -> None:
    """Human drivers at the stop line: a driver standing at its stop (``human`` -> ``reserved``)
    has its crossing reserved (:func:`reserve_human`); a reserved driver sets off when its
    reservation starts (-> ``crossing``: SUMO drives it on, the figures follow it as any
    SUMO-driven vehicle); past the merging zone its reservation is spent (-> ``crossed``)."""
    life = st.life
    for vid in life.members(*HUMAN_DRIVERS):
        rec = st.records[vid]
        if vid not in st.snap.row:  # left the network (not expected before its crossing)
            life.move(vid, State.GONE)
            continue
        if life.state(vid) is State.HUMAN and st.standing_at_stop(vid):
            reserve_human(st, vid)
        if life.state(vid) is State.RESERVED and st.t >= rec.t_release - 1e-9:
            st.sumo.resume(vid)
            life.move(vid, State.CROSSING)
            st.sumo.colour(vid, "released")
        if life.state(vid) is State.CROSSING:
            if not math.isnan(rec.t_exit):  # past the merging zone: its reservation is spent
                st.reservations.pop(vid, None)
                life.move(vid, State.CROSSED)
                continue
            refresh(st, vid)


def refresh(st, vid: str) -> None:
    """Shrink the reservation of a human driver on its way across to what its bounds allow from
    where it is and how fast it goes now: its latest exit of each conflict area comes no later
    than reserved, and sooner when it drives faster than the slowest the bounds allowed, which
    frees the area for the requests that come after. (Entries only move later.)"""
    rec = st.records[vid]
    asg, bounds = st.reservations[vid]
    mv = st.paths[rec.movement]
    s_cg = st.cg_on_path(vid)
    if s_cg is None:
        return
    v = float(st.snap.speed[st.snap.row[vid]])
    for other, (lo, hi) in areas_of(st, rec).items():
        t_in, t_out = bounds.window(mv.s_merge + lo - s_cg, mv.s_merge + hi - s_cg, v)
        old_in, old_out = asg.occupancy[other]
        asg.occupancy[other] = (max(old_in, st.t + t_in), min(old_out, st.t + t_out))


def reserve_human(st, vid: str) -> None:
    """Reserve the crossing of a human driver standing at its stop: its occupancy of each
    conflict area bounded by :class:`~nrtraffic.planning.crossing.CrossingBounds` from the
    ``[human]`` section, its drawn speed factor and its path's speed limit."""
    rec = st.records[vid]
    mv = st.paths[rec.movement]
    h, v_max = st.sc.human, st.sc.planning.v_max_mps
    factor = st.sumo.speed_factor(vid)
    bounds = CrossingBounds(a_lo=(1.0 - h.sigma) * h.accel_mps2, a_hi=h.accel_mps2,
                            v_lo=min(mv.v_limit, v_max) * min(1.0, factor), v_hi=v_max,
                            step_s=st.sc.sumo.step_length_s)
    reserve(st, vid, bounds)
    rec.profile_kind = "human"
    st.life.move(vid, State.RESERVED)
    st.sumo.colour(vid, "human_reserved")


def reserve(st, vid: str, bounds: CrossingBounds):
    """Reserve the crossing from rest of a vehicle standing where SUMO has it now, within
    ``bounds`` (:meth:`~nrtraffic.planning.coordinator.Coordinator.reserve_crossing`); its record
    takes the start, the planned merging-zone entry (latest) and its predecessor."""
    rec = st.records[vid]
    mv = st.paths[rec.movement]
    s_cg = st.cg_on_path(vid)
    areas = {other: (mv.s_merge + lo - s_cg, mv.s_merge + hi - s_cg) for other, (lo, hi) in areas_of(st, rec).items()}
    offsets, merge_w, exit_w, v_exit = human_crossing(bounds, areas, mv.s_merge - s_cg, mv.s_exit - s_cg)
    start = (max(mv.s_merge - s_cg, 0.0), bounds.a_lo, bounds.v_lo)  # its slowest start, for a follower's plan
    asg = st.junctions[rec.junction].coord.reserve_crossing(vid, rec.lane, body(rec), st.t, offsets, merge_w, exit_w,
                                                            v_exit, start)
    rec.t_release = asg.t_release
    rec.t_merge_planned, rec.v_merge_planned = asg.t_merge, asg.profile.v_m
    rec.predecessor, rec.relation, rec.binding = asg.predecessor, asg.relation, asg.binding
    if rec.driver == "human":
        st.reservations[vid] = (asg, bounds)  # refreshed as it crosses (refresh)
    return asg


def body(rec: VehicleRecord) -> str:
    """The name its body's conflict areas go by: its movement's, or ``<movement>~human``."""
    return rec.movement + (HUMAN_BODY if rec.driver == "human" else "")


def areas_of(st, rec: VehicleRecord) -> dict[str, tuple[float, float]]:
    """The conflict areas of a vehicle's body on its movement: other movement -> (from, to) [m
    from its merging-zone entry]."""
    key = body(rec)
    return {other: area for (a, other), area in st.conflict_areas.items() if a == key}
