"""Controlled vehicles that can no longer keep their plan: none enters its merging zone late.

A controlled vehicle is driven to enter its merging zone at its planned time ``t_merge``, and its
occupancy of the conflict areas is reserved around that time (``coordinator.conflict_margin_s``
before and after). Something its plan did not foresee can hold it up before the merging zone: a
car of SUMO's that changed into its lane ahead of it inside the control zone, a queue from its exit
road, a vehicle whose start was reserved later standing in its way. Its barrier keeps it behind
that vehicle, and when the way clears its reference, long gone ahead, would take it into the
merging zone later than reserved, into the windows of the vehicles crossing its path.

Each step, a controlled vehicle still before its merging zone is *late* when even its fastest entry
from now (the planning's ``u_max_mps2`` from its speed, up to ``v_max_mps``) comes more than its
lateness allowance after ``t_merge``: half the conflict margin, and 0.1 s at the most where human
drivers take part (:meth:`~nrtraffic.planning.coordinator.CoordinatorSettings.late_tolerance_s`).
So is one within :data:`EXIT_CHECK_M` of its merging zone whose exit is queued up to the zone
(:mod:`nrtraffic.junction.exits`). Then:

- its merging-zone entry is closed to it: a standing obstacle for the longitudinal barrier (as well
  as the vehicle ahead, where that is nearer), so that it stops with its front bumper at the entry
  (where it can still stop there at the barrier's braking, ``barriers.max_braking_mps2``; a
  vehicle too close to stop has nearly kept its time).
  Once closed, it stays closed while the vehicle is late, until it stands;
- once it stands, its plan and reservation are given up (:meth:`~nrtraffic.planning.coordinator.
  Coordinator.cancel`), SUMO holds it where it stands, and its start from rest is reserved again
  behind the last vehicle of its lane, as for any vehicle standing at its stop line
  (``controlled`` -> ``starting``, :meth:`~nrtraffic.junction.admission.Admission.reserve_from_rest`).

A vehicle's ``replans`` in vehicles.csv counts how often its plan was made again: here, or to give
way to a crossing from rest (:mod:`nrtraffic.junction.yielding`).
"""

from __future__ import annotations

import math

import numpy as np

from nrtraffic.control import batch as kb
from nrtraffic.junction import exits
from nrtraffic.planning.crossing import travel_time

EXIT_CHECK_M = 60.0  # a controlled vehicle this near its merging zone stops before it where its exit is queued [m]
STANDING_MPS = 0.1  # below this speed a late vehicle stands, and its start is reserved again [m/s]


class LateGuard:
    """The late vehicles of a run (the module's docstring): :meth:`step` after admission hands
    the standing ones back for a new start, :meth:`close_gates` after the leader search makes
    the merging-zone entry the others' leader."""

    def __init__(self, st, admission) -> None:
        self.st, self.admission = st, admission
        sc = st.sc
        self.tol_s = sc.coordinator.late_tolerance_s(st.mixed)
        self.a, self.v_max = sc.planning.u_max_mps2, sc.planning.v_max_mps
        self.brake = sc.barriers.max_braking_mps2
        self.gated: dict[str, float] = {}  # late vehicle -> arc length [m] its centre of gravity stops at
        # a gate once closed stays closed while its vehicle is late, until it stands and starts again:
        # the barrier brings it to the stop ever more slowly, and within a few cm of it the test
        # "can it still stop there" fails at a walking pace, which had let it drive on into the
        # merging zone seconds late
        self.closed: set[str] = set()  # (the stop itself is worked out again each step)
        self._gates = False  # some row of the kernel's table has a second obstacle (``gate``)

    def _late(self, s: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Which rows of the kernel's table are late now, at arc lengths ``s`` [m] and speeds ``v``
        [m/s]: their fastest entry (a speed above ``v_max`` kept) comes too late."""
        ctl = self.st.kernel.table
        late = np.zeros(len(s), dtype=bool)
        s_merge, t_merge, t = ctl.s_zone[:, 0].tolist(), ctl.t_merge.tolist(), self.st.t
        for i, (si, vi) in enumerate(zip(s.tolist(), v.tolist())):  # (a few rows: faster than arrays)
            if si < s_merge[i]:
                late[i] = t + travel_time(s_merge[i] - si, self.a, max(self.v_max, vi), vi) > t_merge[i] + self.tol_s
        return late

    def step(self) -> None:
        """Find the late vehicles; those standing are handed back to SUMO where they stand, and
        their start from rest is reserved again."""
        st = self.st
        ctl = st.kernel.table
        self.gated.clear()
        if self.closed:  # (those that left the table: released, lost or started again)
            self.closed &= set(ctl.ids)
        if not ctl.ids:
            return
        s, v = ctl.out[:, kb.OUT_S], np.hypot(ctl.X[:, 2], ctl.X[:, 3])
        late = self._late(s, v)
        near = (s < ctl.s_zone[:, 0]) & (ctl.s_zone[:, 0] - s <= EXIT_CHECK_M) & ~late
        for i in np.flatnonzero(near).tolist():  # (don't block the box: junction.exits)
            if ctl.ids[i] in st.snap.row and exits.blocked(st, ctl.ids[i]) is not None:
                late[i] = True
        if not late.any():
            return
        cg = st.params.cg_to_front
        again = np.zeros(len(ctl.ids), dtype=bool)
        for i in np.flatnonzero(late).tolist():
            vid = ctl.ids[i]
            if v[i] < STANDING_MPS and vid in st.snap.row and st.cg_on_path(vid) is not None:
                again[i] = True  # (a car standing off its path's lanes cannot start from rest there)
                continue
            stop = float(ctl.s_zone[i, 0]) - cg  # front bumper at the merging-zone entry
            if vid in self.closed or v[i] * v[i] / (2.0 * self.brake) <= stop - s[i]:
                self.gated[vid] = stop
                self.closed.add(vid)
        if again.any():
            self._start_again(again)

    def _start_again(self, again: np.ndarray) -> None:
        st, ctl = self.st, self.st.kernel.table
        ids = [v for v, k in zip(ctl.ids, again) if k]
        for i in np.flatnonzero(again).tolist():
            st.records[ctl.ids[i]].acc = ctl.acc[i].copy()
        ctl.keep(~again)
        for vid in ids:
            self.closed.discard(vid)
            rec = st.records[vid]
            st.junctions[rec.junction].coord.cancel(vid)
            st.sumo.release(vid)
            st.sumo.hold_speed(vid, 0.0)
            rec.replans += 1
            self.admission.reserve_from_rest(vid)  # (controlled -> starting)

    def close_gates(self) -> None:
        """Make the merging-zone entry of each late vehicle that can stop before it a standing
        obstacle for its longitudinal barrier, whose centre of gravity lies the barrier's stopping
        distance ``d0`` beyond the stop: its leader where it is nearer than the vehicle ahead,
        otherwise a second obstacle besides that vehicle (the table's ``gate``). With the vehicle
        ahead alone, a late car behind a car that stands at the entry would follow it when it sets
        off, at the barrier's gap, and once that car had entered be too close to its own closed
        entry to stop there."""
        st, kern = self.st, self.st.kernel
        ctl = kern.table
        if self._gates:  # (last step's second obstacles)
            ctl.gate[:] = np.nan
            self._gates = False
        if not self.gated:
            return
        d0 = float(kern.cfg[kb.CFG_D0])  # centre to centre at a stop behind a leader [m]
        slack = d0 - st.params.length  # ... less the bumper gap there [m]
        row = {v: i for i, v in enumerate(ctl.ids)}
        for vid, stop in self.gated.items():
            i = row.get(vid)
            if i is None:
                continue
            s = float(ctl.out[i, kb.OUT_S])
            room = stop - s  # how far its centre of gravity may go on [m]
            px, py = st.paths[st.records[vid].movement].path.xy_at(stop + d0)
            if ctl.lead_idx[i] != kb.NO_LEADER and not math.isnan(ctl.gap[i]) and ctl.gap[i] - slack < room:
                ctl.gate[i] = (px, py)  # (the vehicle ahead is nearer: it stays the leader)
                self._gates = True
                continue
            ctl.lead_idx[i] = kb.EXTERNAL_LEADER
            ctl.lead_ext[i] = (px, py, 0.0, 0.0, 0.0, 0.0)
