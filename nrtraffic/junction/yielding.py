"""Controlled vehicles on the move that give way to a vehicle standing at its stop line, where
human drivers take part.

A controlled vehicle is planned when it enters its control zone, hundreds of metres out; a human
driver's crossing is reserved only once it stands at its stop line, and so is the start from rest
of a controlled car queued behind one. First come, first served, these then wait behind every plan
made before they stood there, and at mid shares of automated vehicles they lose most of the
junction's time there. Yet a controlled vehicle still far from its merging zone can take a later
slot at little cost: it only slows a little on its way.

So where human drivers take part in the run, when a crossing from rest is reserved
(:func:`~nrtraffic.junction.humans.reserve`) to start more than :data:`YIELD_AFTER_S` after now,
the plans of the controlled vehicles of its junction that can still stop before their merging
zone with room to spare (at the planning's ``u_min_mps2``, plus :data:`ROOM_M`) are set aside, the
crossing is reserved again, and those vehicles are planned again from where they are, in the order
of their earlier merge times (a lane keeps its order), each behind the reservations that now
stand (:func:`replan_behind`). A vehicle that cannot be planned again within the planning's bounds
keeps its plan, and the others are planned again without it, up to :data:`SET_ASIDE_TRIES` times.
A vehicle already planned again :data:`MAX_REPLANS` times gives way no more, so that no car waits
without end behind the crossings from rest that come after it. Where the start would not come at
least :data:`GAIN_S` sooner, or no vehicle can give way, everything stays as it was. ``replans`` in
vehicles.csv counts the plans made again.
"""

from __future__ import annotations

import math

from nrtraffic.control import batch as kb
from nrtraffic.control.table import N_PROFILE_SEG
from nrtraffic.lifecycle import State
from nrtraffic.planning.coordinator import Request, ScheduleInfeasible, restore, snapshot

YIELD_AFTER_S = 2.0  # a crossing from rest that starts later than this from now asks the others to give way [s]
ROOM_M = 10.0  # ... those that could stop before their merging zone with this much to spare [m]
GAIN_S = 0.5  # ... where its start comes at least this much sooner [s]
SET_ASIDE_TRIES = 4  # how often the others are planned again without the one that could not be
MAX_REPLANS = 3  # a controlled vehicle planned again this often gives way no more


def give_way(st, vid: str, reserve) -> None:
    """Let the controlled vehicles of ``vid``'s junction give way to ``vid``, whose crossing from
    rest was just reserved (the module's docstring); ``reserve()`` reserves it again."""
    rec = st.records[vid]
    if not rec.t_release > st.t + YIELD_AFTER_S:
        return
    kept = (rec.t_release, rec.t_merge_planned, rec.v_merge_planned, rec.predecessor, rec.relation, rec.binding,
            st.reservations.get(vid))
    t_before = rec.t_release
    coord = st.junctions[rec.junction].coord

    def sooner() -> bool:
        coord.cancel(vid)
        reserve()
        return rec.t_release <= t_before - GAIN_S

    if not replan_behind(st, rec.junction, sooner):  # (as it was)
        (rec.t_release, rec.t_merge_planned, rec.v_merge_planned, rec.predecessor, rec.relation, rec.binding,
         res) = kept
        if res is not None:
            st.reservations[vid] = res


def replan_behind(st, junction: str, reserve_first) -> bool:
    """Whether the controlled vehicles of ``junction`` that can give way did (the module's
    docstring): with their plans set aside, ``reserve_first()`` reserves the crossing they give
    way to and says whether that is worth it; then they are planned again behind it. Where it is
    not worth it, or no vehicle can give way, the junction's reservations are as they were."""
    coord = st.junctions[junction].coord
    ctl = st.kernel.table
    u_brake = -st.sc.planning.u_min_mps2
    movers = []
    for i, v in enumerate(ctl.ids):
        r = st.records[v]
        if r.junction != junction or st.life.state(v) is not State.CONTROLLED or r.replans >= MAX_REPLANS:
            continue
        s = float(ctl.out[i, kb.OUT_S])
        D = float(ctl.s_zone[i, 0]) - s
        speed = math.hypot(ctl.X[i, 2], ctl.X[i, 3])
        if D > speed * speed / (2.0 * u_brake) + ROOM_M:
            movers.append((r.t_merge_planned, i, v, speed, D, s))
    saved = snapshot(coord)
    for _ in range(SET_ASIDE_TRIES):
        if not movers:
            break
        for *_, v, _, _, _ in movers:
            coord.cancel(v)
        if not reserve_first():
            break
        plans, stuck = [], None
        try:
            for _, i, v, speed, D, s in sorted(movers):
                r = st.records[v]
                mv = st.paths[r.movement]
                stuck = v
                req = Request(v, r.lane, st.t, speed, D, r.movement, mv.s_exit - mv.s_merge, mv.v_limit)
                plans.append((i, v, s, coord.schedule_request(req)))
        except ScheduleInfeasible:  # it keeps its plan; the others try again without it
            restore(coord, saved)
            movers = [m for m in movers if m[2] != stuck]
            continue
        for i, v, s, asg in plans:
            r = st.records[v]
            ctl.prof[i] = asg.profile.packed(N_PROFILE_SEG)
            ctl.t_enter[i], ctl.s_enter[i], ctl.t_merge[i] = st.t, s, asg.t_merge
            r.t_merge_planned, r.v_merge_planned = asg.t_merge, asg.profile.v_m
            r.predecessor, r.relation, r.binding = asg.predecessor, asg.relation, asg.binding
            r.profile_kind = asg.profile.kind
            r.replans += 1
        return True
    restore(coord, saved)
    return False
