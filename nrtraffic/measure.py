"""What a run measures each step, from SUMO's view of it: the zone crossings and figures of the
vehicles SUMO drives, the leader and bumper gap of every vehicle in a control zone, and the own
collision check.
"""

from __future__ import annotations

import math

import numpy as np

from nrtraffic.control import batch as kb
from nrtraffic.control.leaders import find_leaders
from nrtraffic.geometry import touching_pairs
from nrtraffic.lifecycle import SUMO_DRIVEN, State
from nrtraffic.vehicle.fuel import fuel_rate

# how far along its path a vehicle looks for its leader [m], counted from the start of the lane it is on
# (nrtraffic.control.leaders.find_leaders): on a longer lane it does not look past that lane
LEADER_LOOKAHEAD_M = 200.0


def track_sumo_driven(st, dt: float, next_leg) -> list[str]:
    """Zone crossings and figures of SUMO-driven vehicles (baselines, human drivers, scripted
    leaders), from their lane positions, speeds and accelerations each step; a vehicle that left
    the network is ``gone``. ``next_leg(vid)``: the hand-over to the next junction of its trip,
    called when it leaves a merging zone. Returns the SUMO-driven vehicles still in the network."""
    tab = st.snap
    cg = st.params.cg_to_front
    driven = st.life.members(*SUMO_DRIVEN)
    if not driven:
        return driven
    live = []
    for vid in driven:
        rec = st.records[vid]
        k = tab.row.get(vid)
        if k is None:
            st.life.move(vid, State.GONE)
            continue
        live.append(vid)
        mv = st.paths[rec.movement]
        lane, pos = tab.lane[k], float(tab.lane_pos[k])
        if lane not in mv.lane_offset:
            # (a vehicle SUMO lets change lanes, on another lane of its approach now: the movement
            # of that lane is its own)
            if rec.lane_kept or not math.isnan(rec.t_exit) or not st.choose_lane(vid, lane):
                continue
            mv = st.paths[rec.movement]
        s_new = mv.s_of(lane, pos) - cg
        v, a = float(tab.speed[k]), float(tab.accel[k])
        s_prev = rec.s_last
        if math.isnan(rec.t_enter) and s_new >= mv.s_control:
            frac = 0.0 if math.isnan(s_prev) or s_new <= s_prev else (mv.s_control - s_prev) / (s_new - s_prev)
            rec.t_enter = st.t - dt + dt * min(max(frac, 0.0), 1.0) if not math.isnan(s_prev) else st.t
            rec.v_enter, rec.s_enter = v, mv.s_control
        if not math.isnan(s_prev) and s_new > s_prev:
            if math.isnan(rec.t_merge_actual) and s_new >= mv.s_merge > s_prev:
                rec.t_merge_actual = st.t - dt + dt * (mv.s_merge - s_prev) / (s_new - s_prev)
            if math.isnan(rec.t_exit) and s_new >= mv.s_exit > s_prev:
                rec.t_exit = st.t - dt + dt * (mv.s_exit - s_prev) / (s_new - s_prev)
                rec.s_last = s_new
                st.junctions[rec.junction].left_zone(rec.lane, st.t)
                if next_leg(vid):  # (a corridor: on to the next junction)
                    continue
        if not math.isnan(rec.t_enter) and math.isnan(rec.t_exit):
            acc = rec.acc
            acc[kb.ACC_ENERGY] += 0.5 * a * a * dt
            acc[kb.ACC_FUEL] += fuel_rate(v, a) * dt
            acc[kb.ACC_MAX_ABS_A] = max(acc[kb.ACC_MAX_ABS_A], abs(a))
            acc[kb.ACC_STEPS] += 1
        rec.s_last = s_new
    return live


def leaders(st, driven: list[str]) -> None:
    """For each controlled vehicle, the nearest vehicle ahead on the lanes of its own path
    (controlled or SUMO-driven, of any movement: the same lane before a diverge, the same
    outgoing lane after a merge; :func:`nrtraffic.control.leaders.find_leaders`): its batch
    index or its state, and the bumper gap [m] to it, all at time ``t``; the same search gives the
    gaps of SUMO-driven vehicles (``driven``) in a control zone, for the figures. Vehicles on other lanes
    (crossing movements) are kept apart by the coordinator, not by the barrier. Sets each
    controlled vehicle's row in SUMO's table (``rows``, -1 where SUMO no longer lists it)."""
    tab, kern = st.snap, st.kernel
    lane_id = np.array([kern.lane_index.get(ln, -1) for ln in tab.lane], dtype=np.int64)
    p = st.params
    vids = [v for v in driven if not math.isnan(st.records[v].t_enter) and math.isnan(st.records[v].t_exit)]
    if vids:
        rows = np.array([tab.row.get(v, -1) for v in vids], dtype=np.int64)
        pid = np.array([kern.path_index[st.records[v].movement] for v in vids], dtype=np.int64)
        n = len(vids)
        idx, ext, gap = np.empty(n, dtype=np.int64), np.empty((n, 6)), np.empty(n)
        find_leaders(lane_id, tab.lane_pos, tab.x, tab.y, tab.psi, tab.speed, tab.accel, rows, pid, kern.pl_off,
                     kern.pl_lane, kern.pl_start, kern.pl_scale, LEADER_LOOKAHEAD_M, p.cg_to_front, p.length, idx,
                     ext, gap)
        _keep_min_gap(st, vids, gap)
    ctl = kern.table
    if not ctl.ids:
        return
    rows = ctl.rows = np.array([tab.row.get(v, -1) for v in ctl.ids], dtype=np.int64)
    find_leaders(lane_id, tab.lane_pos, tab.x, tab.y, tab.psi, tab.speed, tab.accel, rows, ctl.path_id, kern.pl_off,
                 kern.pl_lane, kern.pl_start, kern.pl_scale, LEADER_LOOKAHEAD_M, p.cg_to_front, p.length,
                 ctl.lead_idx, ctl.lead_ext, ctl.gap)
    _keep_min_gap(st, ctl.ids, ctl.gap)


def _keep_min_gap(st, vids, gap: np.ndarray) -> None:
    for vid, g in zip(vids, gap.tolist()):
        if g == g:  # a leader
            rec = st.records[vid]
            rec.min_gap = min(rec.min_gap, g)


def collisions_geometric(st, seen: set, log: list) -> None:
    """Own collision check: oriented rectangles (length x width) of every pair of vehicles
    whose circumscribed circles meet, separating-axis test; each pair counted once (``seen``,
    and its first contact in ``log``). It covers the vehicles of the batched read: all but
    released ones far down their exit road, which only SUMO drives and checks."""
    tab = st.snap
    ids = tab.ids
    if len(ids) < 2:
        return
    p = st.params
    psi = tab.psi
    c, sn = np.cos(psi), np.sin(psi)
    cx = tab.x - 0.5 * p.length * c
    cy = tab.y - 0.5 * p.length * sn
    ii, jj = touching_pairs(cx, cy, psi, p.length, p.width)
    for i, j in zip(ii.tolist(), jj.tolist()):
        pair = tuple(sorted((ids[i], ids[j])))
        if pair not in seen:
            seen.add(pair)
            log.append({"t": st.t, "pair": list(pair), "source": "geometric"})
