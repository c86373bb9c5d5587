"""The leader of each controlled vehicle, compiled: the nearest vehicle ahead on the lanes of its own
path (:func:`nrtraffic.measure.leaders` says which vehicles count).

Lanes are integers here: every lane on some path has an index, and each path is a run of
``(lane, s at the lane's start [m], path length per SUMO lane metre)`` in the packed arrays
``pl_lane``, ``pl_start``, ``pl_scale`` (path ``p`` from ``pl_off[p]`` to ``pl_off[p + 1]``). A
position on a lane maps to the path's arc length as ``start + pos * scale``, as ``Movement.s_of``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from nrtraffic.control.batch import EXTERNAL_LEADER, NO_LEADER


@njit(cache=True, error_model="numpy")
def find_leaders(lane_id, lane_pos, x, y, psi, speed, accel, rows, path_id, pl_off, pl_lane, pl_start, pl_scale,
                 lookahead_m, cg_to_front, length, lead_idx, lead_ext, gap):
    """For each controlled vehicle ``i`` (table row ``rows[i]``, -1 when SUMO does not list it, on
    path ``path_id[i]``): its leader in ``lead_idx`` (the leader's batch index, ``NO_LEADER`` or
    ``EXTERNAL_LEADER``, whose centre-of-gravity position, velocity and acceleration in the world
    frame then go to ``lead_ext[i]``: px, py, vx, vy, ax, ay) and the bumper gap to it in ``gap``
    [m] (NaN without a leader; cars of one ``length``). The search runs along the vehicle's own
    lane ahead of it, then lane by lane along its path until ``lookahead_m`` of path lies behind
    the lane searched; each lane's vehicles are found in the table sorted by lane (the work grows
    with the vehicles near each one, not with the whole table). The table, one entry per vehicle
    SUMO lists: ``lane_id`` (lane index, -1
    off every path), ``lane_pos`` and the front-bumper ``x``, ``y`` [m], ``psi`` [rad], ``speed``
    [m/s], ``accel`` [m/s^2]."""
    n_tab = lane_id.shape[0]
    by_lane = np.argsort(lane_id, kind="mergesort")  # table rows by lane (in table order within one)
    lane_sorted = lane_id[by_lane]
    in_batch = np.full(n_tab, EXTERNAL_LEADER, dtype=np.int64)  # table row -> batch index
    for i in range(rows.shape[0]):
        if rows[i] >= 0:
            in_batch[rows[i]] = i
    for i in range(rows.shape[0]):
        lead_idx[i] = NO_LEADER
        gap[i] = np.nan
        k = rows[i]
        if k < 0:
            continue
        p = path_id[i]
        a0 = pl_off[p]
        a1 = pl_off[p + 1]
        k0 = -1
        for q in range(a0, a1):
            if pl_lane[q] == lane_id[k]:
                k0 = q
                break
        if k0 < 0:
            continue
        pos = lane_pos[k]
        ahead = 0.0
        for q in range(k0, a1):
            best = -1
            best_pos = math.inf
            for b in range(np.searchsorted(lane_sorted, pl_lane[q]), np.searchsorted(lane_sorted, pl_lane[q], "right")):
                r = by_lane[b]  # (only the vehicles on this lane)
                if r == k:
                    continue
                lp = lane_pos[r]
                if (q > k0 or lp > pos) and lp < best_pos:
                    best = r
                    best_pos = lp
            if best >= 0:
                # leader's rear minus own front
                gap[i] = (pl_start[q] + best_pos * pl_scale[q]) - length - (pl_start[k0] + pos * pl_scale[k0])
                lead_idx[i] = in_batch[best]
                if lead_idx[i] == EXTERNAL_LEADER:
                    c = math.cos(psi[best])
                    s = math.sin(psi[best])
                    lead_ext[i, 0] = x[best] - cg_to_front * c
                    lead_ext[i, 1] = y[best] - cg_to_front * s
                    lead_ext[i, 2] = speed[best] * c
                    lead_ext[i, 3] = speed[best] * s
                    lead_ext[i, 4] = accel[best] * c
                    lead_ext[i, 5] = accel[best] * s
                break
            if q + 1 < a1:
                ahead += pl_start[q + 1] - pl_start[q]
            if ahead > lookahead_m:
                break


def pack_path_lanes(movements) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(lane index, pl_off, pl_lane, pl_start, pl_scale)`` of ``movements`` (in their order), each
    with ``lanes`` and ``lane_offset`` like :class:`nrtraffic.junction.Movement`."""
    index: dict[str, int] = {}
    off, lanes, start, scale = [0], [], [], []
    for m in movements:
        for ln in m.lanes:
            lanes.append(index.setdefault(ln, len(index)))
            s0, sc = m.lane_offset[ln]
            start.append(s0)
            scale.append(sc)
        off.append(len(lanes))
    return (index, np.array(off, dtype=np.int64), np.array(lanes, dtype=np.int64), np.array(start, dtype=float),
            np.array(scale, dtype=float))
