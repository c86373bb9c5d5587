"""Human drivers at a controlled junction, and reserved crossings from rest.

A human driver (``demand.controlled_share`` < 1) is sent to its stop line (``human``). Near it,
with nothing ahead, it goes on without stopping where its crossing fits now (:func:`go_on`);
otherwise, standing at the line or in the queue behind reserved drivers, its crossing is reserved
between the bounds of SUMO's Krauss update (``reserved``,
:meth:`~nrtraffic.planning.coordinator.Coordinator.reserve_crossing`); when the reservation starts
SUMO's driver sets off (``crossing``), and the reservation shrinks as it goes to what its bounds
still allow; past the merging zone it is spent (``crossed``). A controlled vehicle standing at the
stop line has its start from rest reserved the same way (:func:`reserve`).
"""

from __future__ import annotations

import math

from nrtraffic.junction import yielding
from nrtraffic.junction.build import HUMAN_BODY
from nrtraffic.lifecycle import HUMAN_DRIVERS, State, VehicleRecord
from nrtraffic.planning.crossing import CrossingBounds, KraussBounds, human_crossing


PLATOON_HEADWAY_S = 1.0  # a human driver starts this long after the human driver ahead of it on its lane [s]


def to_stop_line(st, vid: str) -> None:
    """A human driver on its way to a junction: SUMO stops it at the stop line of its movement
    there, where its crossing will be reserved (:func:`step`)."""
    rec = st.records[vid]
    st.life.move(vid, State.HUMAN, junction=rec.junction)
    st.sumo.stop_at(vid, *st.stop_line[rec.movement, rec.driver])
    st.sumo.colour(vid, "human")
    st.life.wait_at_line(vid, rec.lane)


def step(st, blocked_ahead) -> None:
    """Human drivers at the stop line: a driver standing at its stop, or standing in the queue
    behind drivers whose crossings are all reserved (``blocked_ahead(vid)`` false), has its
    crossing reserved from where it stands (``human`` -> ``reserved``, :func:`reserve_human`): a
    queue goes as a platoon instead of one driver at a time from the line; a reserved driver sets
    off when its reservation starts (-> ``crossing``: SUMO drives it on, the figures follow it as
    any SUMO-driven vehicle); past the merging zone its reservation is spent (-> ``crossed``)."""
    life = st.life
    for vid in life.members(*HUMAN_DRIVERS):
        rec = st.records[vid]
        if vid not in st.snap.row:  # left the network (not expected before its crossing)
            life.move(vid, State.GONE)
            continue
        if life.state(vid) is State.HUMAN:
            if st.standing_at_stop(vid):
                reserve_human(st, vid)
            elif float(st.snap.speed[st.snap.row[vid]]) >= 0.1:
                go_on(st, vid)
            elif standing_in_queue(st, vid) and not blocked_ahead(vid):
                reserve_human(st, vid, in_queue=True)
        if life.state(vid) is State.RESERVED and st.t < rec.t_release - 1e-9:
            advance(st, vid)
        if life.state(vid) is State.RESERVED and st.t >= rec.t_release - 1e-9:
            if rec.profile_kind == "human_queue":  # it stands short of its stop: the stop is dropped
                st.sumo.cancel_stop(vid)
                st.sumo.hold_speed(vid, -1.0)
            else:
                st.sumo.resume(vid)
            life.move(vid, State.CROSSING)
            st.sumo.colour(vid, "released")
        if life.state(vid) is State.CROSSING:
            if not math.isnan(rec.t_exit):  # past the merging zone: its reservation is spent
                st.reservations.pop(vid, None)
                life.move(vid, State.CROSSED)
                continue
            refresh(st, vid)


def advance(st, vid: str) -> None:
    """A reserved human driver waiting for its start sets off as soon as the conflict areas on its
    path are clear: its start moves to the earliest time from now at which its occupancies overlap
    no reservation (:meth:`~nrtraffic.planning.coordinator.Coordinator.advance`). The drivers
    crossing ahead of it have their reservations shrunk to where they are (:func:`refresh`), so it
    no longer waits for their slowest crossing. It still starts :data:`PLATOON_HEADWAY_S` after the
    human driver ahead of it on its lane; behind a controlled vehicle it keeps its start."""
    asg, bounds = st.reservations[vid]
    t_min = st.t
    if asg.follows is not None:
        if st.records[asg.follows].driver != "human":
            return
        ahead = st.reservations.get(asg.follows)
        if ahead is not None:
            t_min = max(t_min, ahead[0].t_release + PLATOON_HEADWAY_S)
    rec = st.records[vid]
    new = st.junctions[rec.junction].coord.advance(vid, t_min)
    if new is not None:
        _note(st, vid, new, bounds)


def standing_in_queue(st, vid: str) -> bool:
    """Whether a human driver stands on its entry lane short of its stop, within
    ``human.queue_reach_m`` of it (held there by the vehicles ahead)."""
    rec = st.records[vid]
    k = st.snap.row[vid]
    lane, pos = st.stop_line[rec.movement, rec.driver]
    return (st.snap.speed[k] < 0.1 and st.snap.lane[k] == lane
            and pos - st.sc.human.queue_reach_m <= st.snap.lane_pos[k] < pos - 1.0)


def go_on(st, vid: str) -> None:
    """A human driver on its way to its stop, from about where SUMO's driver starts braking for it
    (``v_max (tau + 1 s) + v_max^2 / (2 decel)`` before the merging zone) to the merging zone, with
    nothing ahead of it on its path to the end of the merging zone (SUMO's leader search): where
    its crossing at its own pace from where it is and how fast it goes, bounded as a reserved
    crossing is (:func:`human_bounds`), overlaps no reservation now, its stop is dropped and it
    drives on (``human`` -> ``reserved`` -> ``crossing``, profile ``human_go``); otherwise it drives
    on towards its stop, and is tried again at the next step."""
    rec = st.records[vid]
    mv = st.paths[rec.movement]
    s_cg = st.cg_on_path(vid)
    h, v_max = st.sc.human, st.sc.planning.v_max_mps
    # from about where SUMO's driver starts braking for its stop, plus a second
    reach = v_max * (h.tau_s + 1.0) + v_max * v_max / (2.0 * h.decel_mps2)
    if s_cg is None or not 0.0 < mv.s_merge - s_cg <= reach:
        return
    coord = st.junctions[rec.junction].coord
    if st.sumo.leader(vid, mv.s_exit - s_cg + st.params.length) is not None:
        return
    bounds = human_bounds(st, vid)
    offsets, merge_w, exit_w, v_exit = _windows(st, rec, s_cg, bounds, float(st.snap.speed[st.snap.row[vid]]))
    asg = coord.reserve_crossing(vid, rec.lane, body(rec), st.t, offsets, merge_w, exit_w, v_exit, None,
                                 driven_by_sumo=True, now_only=True)
    if asg is None:
        return
    _note(st, vid, asg, bounds)
    rec.profile_kind = "human_go"
    st.sumo.cancel_stop(vid)
    st.life.move(vid, State.RESERVED)
    st.life.move(vid, State.CROSSING)
    st.sumo.colour(vid, "released")


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


def reserve_human(st, vid: str, in_queue: bool = False) -> None:
    """Reserve the crossing of a human driver standing at its stop, or ``in_queue`` short of it
    (it is then held standing until its start: profile ``human_queue``): its occupancy of each
    conflict area bounded by Krauss's own speed update (:class:`~nrtraffic.planning.crossing.
    KraussBounds`) from the ``[human]`` section, its drawn speed factor and its path's speed limit."""
    rec = st.records[vid]
    reserve(st, vid, human_bounds(st, vid))
    rec.profile_kind = "human_queue" if in_queue else "human"
    if in_queue:  # (its stop still ahead: SUMO would move it up behind the driver ahead)
        st.sumo.hold_speed(vid, 0.0)
    st.life.move(vid, State.RESERVED)
    st.sumo.colour(vid, "human_reserved")


def human_bounds(st, vid: str) -> KraussBounds:
    """How fast a human driver may cross: SUMO's Krauss update with the ``[human]`` section's
    acceleration and sigma, up to the planning's ``v_max_mps`` at the most, and at the least up to
    the slowest speed limit on its path times its drawn speed factor, or the slowest cap of the
    human driver reserved ahead of it on its lane where that is lower (it may be held back
    behind it)."""
    rec = st.records[vid]
    mv = st.paths[rec.movement]
    h, v_max = st.sc.human, st.sc.planning.v_max_mps
    v_lo = min(mv.v_limit, v_max) * min(1.0, st.sumo.speed_factor(vid))
    ahead = st.junctions[rec.junction].coord.last_on_lane(rec.lane)
    if ahead is not None and ahead.vehicle_id in st.reservations:
        v_lo = min(v_lo, st.reservations[ahead.vehicle_id][1].v_lo)
    return KraussBounds(h.accel_mps2, h.sigma, v_lo=v_lo, v_hi=v_max, step_s=st.sc.sumo.step_length_s)


def reserve(st, vid: str, bounds: CrossingBounds | KraussBounds, give_way: bool = True) -> None:
    """Reserve the crossing from rest of a vehicle standing where SUMO has it now, within
    ``bounds`` (:meth:`~nrtraffic.planning.coordinator.Coordinator.reserve_crossing`); its record
    takes the start, the planned merging-zone entry (latest) and its predecessor. Where human
    drivers take part (``st.mixed``), a start that is far off has the controlled vehicles that can
    give way to it planned again behind it (``give_way``, :mod:`nrtraffic.junction.yielding`)."""
    rec = st.records[vid]
    mv = st.paths[rec.movement]
    s_cg = st.cg_on_path(vid)
    offsets, merge_w, exit_w, v_exit = _windows(st, rec, s_cg, bounds)
    start = (max(mv.s_merge - s_cg, 0.0), bounds.a_lo, bounds.v_lo)  # its slowest start, for a follower's plan
    human = rec.driver == "human"
    asg = st.junctions[rec.junction].coord.reserve_crossing(
        vid, rec.lane, body(rec), st.t, offsets, merge_w, exit_w, v_exit, start, driven_by_sumo=human,
        platoon_headway_s=PLATOON_HEADWAY_S)
    _note(st, vid, asg, bounds)
    if give_way and st.mixed:
        yielding.give_way(st, vid, lambda: reserve(st, vid, bounds, give_way=False))


def _windows(st, rec: VehicleRecord, s_cg: float, bounds, v0: float = 0.0):
    """:func:`~nrtraffic.planning.crossing.human_crossing` of a vehicle whose centre of gravity is
    at ``s_cg`` [m] on its path, at speed ``v0`` [m/s]."""
    mv = st.paths[rec.movement]
    areas = {other: (mv.s_merge + lo - s_cg, mv.s_merge + hi - s_cg) for other, (lo, hi) in areas_of(st, rec).items()}
    return human_crossing(bounds, areas, mv.s_merge - s_cg, mv.s_exit - s_cg, v0)


def _note(st, vid: str, asg, bounds) -> None:
    """A reserved crossing into the vehicle's record: its start, planned merging-zone entry
    (latest) and predecessor; a human driver's reservation is refreshed as it crosses
    (:func:`refresh`)."""
    rec = st.records[vid]
    rec.t_release = asg.t_release
    rec.t_merge_planned, rec.v_merge_planned = asg.t_merge, asg.profile.v_m
    rec.predecessor, rec.relation, rec.binding = asg.predecessor, asg.relation, asg.binding
    if rec.driver == "human":
        st.reservations[vid] = (asg, bounds)


def body(rec: VehicleRecord) -> str:
    """The name its body's conflict areas go by: its movement's, or ``<movement>~human``."""
    return rec.movement + (HUMAN_BODY if rec.driver == "human" else "")


def areas_of(st, rec: VehicleRecord) -> dict[str, tuple[float, float]]:
    """The conflict areas of a vehicle's body on its movement: other movement -> (from, to) [m
    from its merging-zone entry]."""
    key = body(rec)
    return {other: area for (a, other), area in st.conflict_areas.items() if a == key}
