"""Merge-time assignment by arrival at the control zone (docs/junction-control.md): first in, first
out, or in batches whose order is chosen (:meth:`Coordinator.schedule_batch`).

For vehicle ``i`` arriving at ``t0`` with speed ``v0``, ``D`` metres before the merging zone::

    t_m(i) = max( t0 + T_earliest(i),
                  t_m(j) + max(h_min, delta / v_s)      for the last vehicle j on i's lane,
                  t_exit(j) + delta / v_s - S(i) / v_hi(i)      for the same j,
                  t_exit(j)                             for every earlier j on a conflicting movement )

with ``t_exit(j) = t_m(j) + S(j) / v_m(j)``, ``S(j)`` the length of j's path in the merging zone,
``v_s = min(v_m(j), v_hi(i))`` the slower of the two crossing speeds:
only one of two conflicting vehicles is in the merging zone at a time. The third term keeps the
spacing at the zone exit too (``v_hi(i)`` is the fastest i may cross): both cross at constant speed,
so spacing at entry and exit means no catching up inside, even behind a slower turning vehicle.

Spacing at the entry and exit of the merging zone does not keep the planned trajectories apart on
the way to it: a follower can catch up with a leader whose plan slows down deeply (held back by a
conflict). When the closed-form profile comes closer than ``delta`` to the leader's plan anywhere
before its own merge time (the leader's plan continues at constant speed past its merge), it is
replaced by the energy-optimal profile with that rear-end constraint
(:func:`~nrtraffic.planning.profiles.rear_end_constrained`, a QP). A vehicle that enters closer
than ``delta`` behind its leader (in a queue reaching back past the zone entry) keeps the spacing
the slowest plan within the bounds can keep, and may go slower than ``v_min`` behind a crawling
leader. If that QP has no solution, the closed form is kept where it runs at most
``HOLD_INTRUSION_M`` into the gap (its intrusion is recorded, and the longitudinal barrier keeps the
cars apart); beyond that the request fails: the vehicle is held, stops behind its leader and starts
from rest behind it (a car entering close behind a standing queue whose start is far off). A
vehicle handed over from a junction upstream (``Request.handed_over``) gets no such plan: its
request fails, and it asks again once SUMO's driver has made room.

``T_earliest`` is ``D / v0`` (cruise at the entry speed, as Malikopoulos et al. 2018 and the paper:
an unhindered vehicle keeps its speed) or the bound-limited minimum time, whichever is longer; a
vehicle slowed before its entry (``Request.hindered``: behind a human driver, or in a queue) gets
the bound-limited minimum time;
``delta`` is the rear-end spacing [m] and ``h_min`` a minimum merge headway [s]. The energy-optimal
free-terminal profile for ``T = t_m - t0`` is then computed in closed form.

Relations between movements come from :mod:`nrtraffic.planning.conflicts`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from nrtraffic.planning.conflicts import CONFLICT
from nrtraffic.planning.crossing import travel_time, travel_times
from nrtraffic.planning.profiles import (InfeasibleProfile, PlanBounds, Profile, earliest_fixed, fixed_terminal,
                                         free_terminal, max_time, min_time, rear_end_constrained, rear_end_violation,
                                         standing_start)

# the rear-end constrained profile holds the gap at its grid instants (0.5 s apart); between them it
# may enter the gap by millimetres. A plan that enters it by more is counted as unresolved [m].
REAR_END_TOL_M = 0.05
# a plan that would run further than this into the gap behind its leader's plan (no plan within the
# bounds keeps behind it: a car entering close behind a standing queue whose start is far off) is not
# given; the car is held, stops behind its leader and starts from where it stands, in its lane's
# order. Smaller intrusions are left to the barrier, which keeps the real gap [m]
HOLD_INTRUSION_M = 2.0


class ScheduleInfeasible(InfeasibleProfile):
    """The merge time a vehicle must respect cannot be met within the planning bounds."""


# where human drivers take part, a controlled vehicle enters its merging zone no later than this
# after its plan, or is stopped at the zone's entry [s] (CoordinatorSettings.late_tolerance_s)
MIXED_LATE_TOLERANCE_S = 0.1
_EPS_S = 1e-9  # occupancies closer than this [s] count as apart (rounding of the pushed times)


@dataclass(frozen=True)
class CoordinatorSettings:
    """Coordinator settings.

    Attributes
    ----------
    rear_end_spacing_m : ``delta``, spacing between consecutive vehicles of a lane at the merging
        zone entry [m] (centre to centre).
    min_merge_headway_s : ``h_min``, minimum time between consecutive merge times of a lane [s].
    earliest : ``"entry_speed"`` (arrive no earlier than cruising at the entry speed) or
        ``"max_speed"`` (arrive as early as the bounds allow).
    terminal_speed : ``"free"`` (the paper: u(t_m) = 0, a held-back car arrives slower) or
        ``"fixed"`` (cross the merging zone at the highest speed its path allows, ``min(v_max,
        turn speed)``, with the fixed-terminal profile -- slowing down and speeding up again when
        held back; when that leaves the bounds the schedule is infeasible and the car waits at the
        zone entry). At a junction "fixed" is the default and "free" is refused: a held-back car
        crosses slowly, holds the zone longer than its reservation and holds back the next ones
        (on cross4 at 400 veh/h per approach, with the other keys at their defaults, 23
        collisions in SUMO's check); "free" stays the default of a plain road (the paper's merge).
    qp_solver : qpsolvers backend of the rear-end constrained profile's QP: ``"daqp"`` (dense
        dual active set, the default: these QPs have at most 81 variables) or ``"osqp"``.
    conflict_model : ``"zone"`` (the paper's: two conflicting vehicles are never in the merging
        zone together) or ``"conflict_points"``: a vehicle occupies each conflict area on its path
        (movements.json) from reaching it to leaving it, at its constant crossing speed, and two
        conflicting vehicles' occupancies of their shared area, each widened by
        ``conflict_margin_s``, must not overlap; a vehicle takes the earliest merge time at which
        every area on its path is free of all reservations made before it (gaps between them may
        be used). Needs ``terminal_speed = "fixed"`` (the crossing speed is then known).
    conflict_margin_s : safety time added before and after each occupancy of a conflict area [s], between
        two controlled vehicles (a human driver's: ``human.conflict_margin_s``, plus 0.1 s with a controlled one).
    policy : ``"fifo"`` (each vehicle is scheduled when it enters the control zone, in that order)
        or ``"batch"``: vehicles entering within ``batch_window_s`` of the first of them are
        scheduled together when the window closes (they drive on at their speed under SUMO till
        then), in an order chosen to lose the least time (:meth:`Coordinator.schedule_batch`):
        same-approach and compatible vehicles then follow each other instead of each paying the
        cross-flow's clearance. Same-lane order never changes. Needs ``conflict_model =
        "conflict_points"``.
    batch_window_s : how long a batch collects vehicles [s].
    max_passed : how many later arrivals may be scheduled before a vehicle (the starvation cap of
        "batch"; 0 gives first-in-first-out order within each batch).
    max_wait_s : the longest a plan may hold a vehicle back past its earliest arrival [s]; a
        vehicle that would wait longer is not committed to a plan (which could not be brought
        forward when the junction clears) but held, and asked again as it comes closer (0, the
        default: no limit). Past capacity a limit costs throughput: the held cars stop at the
        stop line and start from rest, which passes fewer cars than the queue's own plans.
    """

    rear_end_spacing_m: float = 10.0
    min_merge_headway_s: float = 0.0
    earliest: str = "entry_speed"
    terminal_speed: str = "free"
    qp_solver: str = "daqp"
    conflict_model: str = "zone"
    conflict_margin_s: float = 1.0
    policy: str = "fifo"
    batch_window_s: float = 6.0
    max_passed: int = 3
    max_wait_s: float = 0.0

    def late_tolerance_s(self, mixed: bool = False) -> float:
        """How late [s] past its planned merge time a controlled vehicle may still enter its
        merging zone (:mod:`nrtraffic.junction.late` stops a later one at the zone's entry): half
        the conflict margin, so that two controlled vehicles' margin covers both their
        allowances; where human drivers take part (``mixed``), :data:`MIXED_LATE_TOLERANCE_S` at
        the most, so that the margin to a human driver's occupancy can be small
        (:meth:`Coordinator.margin_between`)."""
        half = 0.5 * self.conflict_margin_s
        return min(half, MIXED_LATE_TOLERANCE_S) if mixed else half

    # the values each string setting takes (also the scenario file's JSON Schema)
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {
        "earliest": ("entry_speed", "max_speed"), "terminal_speed": ("free", "fixed"), "qp_solver": ("daqp", "osqp"),
        "conflict_model": ("zone", "conflict_points"), "policy": ("fifo", "batch")}

    def __post_init__(self) -> None:
        if self.rear_end_spacing_m < 0 or self.min_merge_headway_s < 0:
            raise ValueError("coordinator spacing and headway must be >= 0")
        for key, allowed in self.CHOICES.items():
            if getattr(self, key) not in allowed:
                raise ValueError(f"coordinator.{key} must be one of {', '.join(map(repr, allowed))}, "
                                 f"got {getattr(self, key)!r}")
        if self.conflict_margin_s < 0 or self.max_wait_s < 0:
            raise ValueError("coordinator.conflict_margin_s and coordinator.max_wait_s must be >= 0")
        if self.batch_window_s < 0 or self.max_passed < 0:
            raise ValueError("coordinator.batch_window_s and coordinator.max_passed must be >= 0")
        if self.policy == "batch" and self.conflict_model != "conflict_points":
            raise ValueError('coordinator.policy = "batch" needs coordinator.conflict_model = "conflict_points"')
        if self.conflict_model == "conflict_points" and self.terminal_speed != "fixed":
            raise ValueError('coordinator.conflict_model = "conflict_points" needs coordinator.terminal_speed = "fixed"')


@dataclass(frozen=True)
class Assignment:
    """What the coordinator decided for one vehicle."""

    vehicle_id: str
    lane: str
    t_enter: float
    t_merge: float
    profile: Profile
    predecessor: str | None
    relation: str  # relation to the predecessor: "none", "same_lane" or "conflict"
    binding: str  # which term set t_merge: "earliest", "rear_end" or "conflict"
    movement: str = ""
    t_exit: float = 0.0  # planned merging-zone exit [s]
    plan_intrusion_m: float = float("nan")  # how far the plan enters the gap behind the lane leader's plan [m]
    t_release: float = float("nan")  # a reserved crossing (:meth:`Coordinator.reserve_crossing`): its start [s]
    occupancy: dict | None = None  # ... and its occupancy of each conflict area: other movement -> (in, out) [s]
    motion: Profile | None = None  # ... and its slowest start (standing_start), that a follower keeps behind
    driven_by_sumo: bool = False  # ... and SUMO's driver makes it (a human driver)
    follows: str | None = None  # ... behind this vehicle on its lane


@dataclass(frozen=True)
class Crossing:
    """Stands for the profile of a reserved crossing that has no plan: ``v_m`` its lowest speed
    at the merging-zone exit [m/s]."""

    v_m: float


@dataclass(frozen=True)
class Request:
    """A vehicle asking for a merge time (the arguments of :meth:`Coordinator.schedule`); requests
    are given to :meth:`Coordinator.schedule_batch` in the order the vehicles entered the control
    zone."""

    vehicle_id: str
    lane: str
    t0: float
    v0: float
    D: float
    movement: str = ""
    zone_length_m: float = 0.0
    v_limit: float = float("inf")
    # slowed before its entry by a vehicle it cannot pass (a human driver ahead, or a queue reaching
    # back past the zone entry): it does not keep an entry speed, so its earliest arrival is the one
    # the bounds allow
    hindered: bool = False
    # handed over from a junction upstream (a corridor): it may come in fast, close behind a slow
    # leader that turned onto its road; a plan that cannot keep behind the leader's is then not
    # committed (ScheduleInfeasible) but asked for again once SUMO's driver has made room
    handed_over: bool = False


@dataclass
class Coordinator:
    """Merge-time scheduler: :meth:`schedule` one vehicle at a time in the order they enter the
    control zone (``policy = "fifo"``), or :meth:`schedule_batch` a batch of them."""

    settings: CoordinatorSettings
    bounds: PlanBounds
    relations: dict = field(default_factory=dict)  # (movement, movement) -> relation
    # (movement, other) -> (from, to) [m from the merging-zone entry]: the conflict area on the
    # movement's path (planning.conflicts.conflict_areas), for conflict_model "conflict_points"
    areas: dict = field(default_factory=dict)
    _reserved: list = field(default_factory=list)  # assignments holding conflict-area reservations
    _last_on_lane: dict[str, Assignment] = field(default_factory=dict)
    _last_on_movement: dict[str, Assignment] = field(default_factory=dict)
    _passed: dict[str, int] = field(default_factory=dict)  # times a waiting vehicle has been passed ("batch")
    qp_wall_s: float = 0.0  # wall time spent in the rear-end QPs [s] (for the benchmarks)
    # the margin between two human drivers' occupancies of a conflict area [s] (human.conflict_margin_s;
    # None: the margin)
    human_margin_s: float | None = None

    def schedule(self, vehicle_id: str, lane: str, t0: float, v0: float, D: float, movement: str = "",
                 zone_length_m: float = 0.0, v_limit: float = float("inf")) -> Assignment:
        """Assign a merge time and profile to a vehicle that entered the control zone.

        Parameters
        ----------
        lane : key of the lane (vehicles with the same key are rear-end constrained).
        t0 : entry time [s]; v0 : entry speed [m/s]; D : distance to the merging zone [m].
        movement : the vehicle's movement (for the conflict relations).
        zone_length_m : length of its path inside the merging zone [m].
        v_limit : highest speed its path allows through the merging zone [m/s] (a turn). When the
            free-terminal profile would arrive faster, the fixed-terminal profile to ``v_limit`` is
            used, and the earliest arrival is the time-optimal one within the bounds: cruise, then
            the arc down to ``v_limit`` whose deceleration peaks at ``|u_min|``
            (:func:`~nrtraffic.planning.profiles.earliest_fixed`).

        Raises
        ------
        ScheduleInfeasible : the required merge time is later than the bounds allow.
        """
        return self.schedule_request(Request(vehicle_id, lane, t0, v0, D, movement, zone_length_m, v_limit))

    def schedule_request(self, r: Request) -> Assignment:
        """:meth:`schedule` for a :class:`Request`."""
        vehicle_id, lane, t0, v0, D, movement = r.vehicle_id, r.lane, r.t0, r.v0, r.D, r.movement
        t_m, binding, pred, relation, prev, t_early = self._merge_time(r)
        wait_cap = self.settings.max_wait_s
        if wait_cap > 0.0 and t_m - t_early > wait_cap:
            raise ScheduleInfeasible(f"vehicle {vehicle_id}: it would wait {t_m - t_early:.1f} s past its earliest "
                                     f"arrival, more than coordinator.max_wait_s = {wait_cap:g} s")
        prof = energy_optimal(self.settings, self.bounds, vehicle_id, t0, v0, D, t_m, r.v_limit)
        intrusion = float("nan")
        if prev is not None:
            prof, intrusion = self._keep_behind(prof, prev, t0, v0, D, t_m, strict=r.handed_over)
            if intrusion > (REAR_END_TOL_M if r.handed_over else HOLD_INTRUSION_M):
                raise ScheduleInfeasible(f"vehicle {vehicle_id}: no plan within the bounds keeps "
                                         f"{self.settings.rear_end_spacing_m:g} m behind {prev.vehicle_id}'s "
                                         f"(it would come {intrusion:.2f} m closer)")
        t_exit = t_m + r.zone_length_m / prof.v_m
        return self._commit(Assignment(vehicle_id, lane, t0, t_m, prof, pred, relation, binding, movement, t_exit,
                                       intrusion))

    def _commit(self, a: Assignment) -> Assignment:
        """Keep ``a``: the last of its lane, a reservation (those left before its request are
        dropped), and the last of its movement where it leaves the merging zone after the last."""
        self._last_on_lane[a.lane] = a
        self._reserved = [x for x in self._reserved if x.t_exit + self.settings.conflict_margin_s > a.t_enter] + [a]
        prev_m = self._last_on_movement.get(a.movement)
        if prev_m is None or a.t_exit > prev_m.t_exit:
            self._last_on_movement[a.movement] = a
        return a

    def _zone_clear(self, movement: str) -> tuple[float, str | None]:
        """``conflict_model = "zone"``: when the merging zone is clear of every movement that
        conflicts with ``movement`` (the latest planned exit [s] of a vehicle on one, -inf when
        there is none) and that vehicle; ``(-inf, None)`` in the other model."""
        t, last = -math.inf, None
        if self.settings.conflict_model == "zone":
            for other, a in self._last_on_movement.items():
                if self.relations.get((movement, other)) == CONFLICT and a.t_exit > t:
                    t, last = a.t_exit, a.vehicle_id
        return t, last

    def _earliest(self, v0: float, D: float, v_limit: float, hindered: bool = False) -> float:
        """Earliest time [s] from the control-zone entry to the merging zone (see :meth:`schedule`)."""
        b = self.bounds
        t_min = min_time(v0, D, b)
        cruise = self.settings.earliest == "entry_speed" and not hindered
        if cruise and v0 > 0.0:
            t_min = max(t_min, D / min(v0, b.v_max_mps))
        if v_limit < v0:  # must cross slower than it enters: cruise, then brake on the arc
            v_cruise = v0 if cruise else None
            t_min = earliest_fixed(v0, min(v_limit, b.v_max_mps), D, b, v_cruise)
        if v0 < b.v_min_mps:  # slow or standing: the earliest energy-optimal start to the crossing speed
            t_min = max(t_min, earliest_fixed(v0, min(v_limit, b.v_max_mps), D, b))
        return t_min

    def _merge_time(self, r: Request, extra: tuple = ()):
        """The merge time the rules give, without committing it: ``(t_m, binding, predecessor,
        relation, lane leader's assignment or None, earliest merge time)``. ``extra``: tentative
        reservations ``(vehicle_id, movement, t_merge, v_m)`` counted besides the committed ones."""
        lane, t0, v0, D, movement, zone_length_m, v_limit = r.lane, r.t0, r.v0, r.D, r.movement, r.zone_length_m, r.v_limit
        b = self.bounds
        t_early = t0 + self._earliest(v0, D, v_limit, r.hindered)
        t_m, binding, pred = t_early, "earliest", None
        relation = "none"
        prev = self._last_on_lane.get(lane)
        if prev is not None:
            pred, relation = prev.vehicle_id, "same_lane"
            # delta at the zone entry, at the slower of the two crossing speeds: when this vehicle is
            # the slower, the gap is delta at the leader's merge time (and grows after it)
            v_hi = min(v_limit, b.v_max_mps)
            spacing_t = self.settings.rear_end_spacing_m / min(prev.profile.v_m, v_hi)
            t_same = max(prev.t_merge + max(self.settings.min_merge_headway_s, spacing_t),
                         prev.t_exit + spacing_t - zone_length_m / v_hi)
            if t_same > t_m:
                t_m, binding = t_same, "rear_end"
        if self.settings.conflict_model == "conflict_points":
            v_zone = min(v_limit, b.v_max_mps)  # fixed terminal speed: the crossing speed
            t_free, blocker = self._first_free(t_m, movement, v_zone, extra)
            if blocker is not None:
                t_m, binding, pred, relation = t_free, "conflict", blocker, "conflict"
        else:  # the latest exit of each conflicting movement binds (FIFO: all were scheduled earlier)
            t_clear, last = self._zone_clear(movement)
            if t_clear > t_m:
                t_m, binding, pred, relation = t_clear, "conflict", last, "conflict"
        return t_m, binding, pred, relation, prev, t_early

    def schedule_batch(self, requests: list[Request]) -> list[tuple[Request, Assignment | ScheduleInfeasible]]:
        """Schedule a batch of vehicles (``policy = "batch"``), given in the order they entered the
        control zone; returns each with its assignment, or the :class:`ScheduleInfeasible` that
        holds it, in the order they were served.

        Order: among the first waiting vehicle of each lane (same-lane order never changes), serve
        the one that minimises the time lost by it and by the others' first vehicles if it goes
        first: its merge time past its earliest, plus, for every other lane's first vehicle, its
        merge time past its earliest with this one's conflict areas reserved (a one-step
        look-ahead). A vehicle that lane-mates or cross traffic would hold back little goes before
        one that would hold many back. Ties go to the earlier arrival. Starvation cap: every time a
        vehicle is served, each vehicle of the batch that arrived before it is counted as passed;
        a vehicle passed ``max_passed`` times goes next (its lane's earlier vehicles first). When a
        vehicle cannot be scheduled, it and the rest of its lane in the batch are held (returned
        with the exception) and keep their counts for the next batch.
        """
        cap = self.settings.max_passed
        queues: dict[str, list[Request]] = {}
        for r in requests:
            queues.setdefault(r.lane, []).append(r)
        rank = {r.vehicle_id: k for k, r in enumerate(requests)}
        passed = {r.vehicle_id: self._passed.get(r.vehicle_id, 0) for r in requests}
        done: list[tuple[Request, Assignment | ScheduleInfeasible]] = []
        while queues:
            heads = [q[0] for q in queues.values()]
            starving = [r for q in queues.values() for r in q if passed[r.vehicle_id] >= cap]
            if starving:
                chosen = queues[min(starving, key=lambda r: rank[r.vehicle_id]).lane][0]
            else:
                chosen = min(heads, key=lambda c: (self._batch_cost(c, heads), rank[c.vehicle_id]))
            queue = queues[chosen.lane]
            try:
                a = self.schedule_request(chosen)
            except ScheduleInfeasible as exc:
                for r in queue:  # its lane waits behind it, and keeps its counts for the next batch
                    done.append((r, exc if r is chosen else ScheduleInfeasible(
                        f"vehicle {r.vehicle_id}: waits behind {chosen.vehicle_id} on its lane")))
                    self._passed[r.vehicle_id] = passed.pop(r.vehicle_id)
                del queues[chosen.lane]
                continue
            for r in requests:
                if rank[r.vehicle_id] < rank[chosen.vehicle_id] and r.vehicle_id in passed:
                    passed[r.vehicle_id] += 1
            del passed[chosen.vehicle_id]
            self._passed.pop(chosen.vehicle_id, None)
            done.append((chosen, a))
            queue.pop(0)
            if not queue:
                del queues[chosen.lane]
        return done

    def _batch_cost(self, c: Request, heads: list[Request]) -> float:
        """Time lost [s] by ``c`` and by the other lanes' first vehicles if ``c`` is served next."""
        t_m, *_, t_early = self._merge_time(c)
        cost = t_m - t_early
        mine = ((c.vehicle_id, c.movement, t_m, min(c.v_limit, self.bounds.v_max_mps)),)
        for h in heads:
            if h is not c:
                t_h, *_, e_h = self._merge_time(h, extra=mine)
                cost += t_h - e_h
        return cost

    def _first_free(self, t_m: float, movement: str, v: float, extra: tuple = (),
                    offsets: dict | None = None, driven_by_sumo: bool = False,
                    own: str | None = None) -> tuple[float, str | None]:
        """Earliest merge time from ``t_m`` at which this movement's occupancy of every conflict
        area on its path (entered at ``t + from / v``, left at ``t + to / v``, crossing at ``v``),
        widened by the margin, overlaps no reservation's occupancy of the same area; and the
        vehicle whose reservation pushed it last (None when ``t_m`` was free). ``extra``: tentative
        reservations ``(vehicle_id, movement, t_merge, v_m)``. ``offsets`` replaces the constant
        crossing speed: other movement -> (entry, exit) of the shared area [s after ``t``] (a
        crossing the coordinator does not steer, :meth:`reserve_crossing`). ``driven_by_sumo``: the
        request is a human driver's, whose margin to another's is :meth:`margin_between`. ``own``:
        the requesting vehicle, whose own reservation is not in its way (:meth:`advance`)."""
        margin = self.settings.conflict_margin_s
        blocker = None
        reserved = [(r.vehicle_id, r.movement, r.t_merge, r.profile.v_m, r.occupancy,
                     self.margin_between(driven_by_sumo, r.driven_by_sumo))
                    for r in self._reserved if r.vehicle_id != own]
        reserved += [(*x, None, margin) for x in extra]
        if offsets is None:
            def mine_of(other):
                a = self.areas.get((movement, other))
                return None if a is None else (a[0] / v, a[1] / v)
        else:
            mine_of = offsets.get
        moved = True
        while moved:
            moved = False
            for r_id, r_mv, r_tm, v_r, occ, gap in reserved:
                mine = mine_of(r_mv)
                if mine is None:
                    continue
                if occ is None:  # a steered vehicle: constant speed through the zone
                    theirs = self.areas.get((r_mv, movement))
                    if theirs is None:
                        continue
                    r_in, r_out = r_tm + theirs[0] / v_r, r_tm + theirs[1] / v_r
                else:  # its reserved occupancy of the area it shares with this movement
                    w = occ.get(movement)
                    if w is None:
                        continue
                    r_in, r_out = w
                m_in, m_out = t_m + mine[0], t_m + mine[1]
                if m_in < r_out + gap - _EPS_S and r_in < m_out + gap - _EPS_S:  # overlap
                    later = r_out + gap - mine[0]  # wait until it has left
                    if later > t_m:  # (rounding must not stall the search)
                        t_m = later
                        blocker = r_id
                        moved = True
        return t_m, blocker

    def margin_between(self, a_human: bool, b_human: bool) -> float:
        """The margin [s] between two occupancies of a conflict area: ``human_margin_s`` between two
        human drivers' (their bounds hold every motion their driver model allows, a step to spare);
        that plus the lateness allowance (:meth:`CoordinatorSettings.late_tolerance_s`) between a
        human's and a controlled vehicle's (never early); ``conflict_margin_s`` between two controlled."""
        if self.human_margin_s is None or not (a_human or b_human):
            return self.settings.conflict_margin_s
        return self.human_margin_s + (0.0 if a_human and b_human else self.settings.late_tolerance_s(mixed=True))

    def advance(self, vehicle_id: str, t_min: float) -> Assignment | None:
        """Move the reserved crossing of ``vehicle_id`` (:meth:`reserve_crossing`), not started yet,
        to the earliest start from ``t_min`` [s] at which its occupancies, the same after its start
        as reserved, overlap no other reservation (they shrink as the vehicles cross and the others
        are spent): the replacing assignment, or None where it cannot start sooner. ``t_min``
        keeps it behind the vehicle ahead of it on its lane (the caller's rule)."""
        a = next((x for x in self._reserved if x.vehicle_id == vehicle_id and x.occupancy is not None), None)
        if a is None or math.isnan(a.t_release) or a.t_release <= t_min or self.settings.conflict_model == "zone":
            return None  # (the zone model keeps its first-come order: nothing is moved sooner)
        rel = {o: (i - a.t_release, e - a.t_release) for o, (i, e) in a.occupancy.items()}
        t, _ = self._first_free(t_min, a.movement, 0.0, offsets=rel, driven_by_sumo=a.driven_by_sumo,
                                own=vehicle_id)
        if t >= a.t_release - 1e-6:
            return None
        d = t - a.t_release
        new = replace(a, t_merge=a.t_merge + d, t_exit=a.t_exit + d, t_release=t,
                      occupancy={o: (t + i, t + e) for o, (i, e) in rel.items()})
        self._reserved = [new if x is a else x for x in self._reserved]
        if self._last_on_lane.get(a.lane) is a:
            self._last_on_lane[a.lane] = new
        return new

    def cancel(self, vehicle_id: str) -> None:
        """Give up ``vehicle_id``'s plan or reservation; a lane's or movement's last is then the latest left."""
        self._reserved = [a for a in self._reserved if a.vehicle_id != vehicle_id]
        lasts = ((self._last_on_lane, "lane", "t_merge"), (self._last_on_movement, "movement", "t_exit"))
        for last, key, by in lasts:  # (by: as schedule_request orders them)
            for k in [k for k, a in last.items() if a.vehicle_id == vehicle_id]:
                left = [a for a in self._reserved if getattr(a, key) == k]
                last.pop(k)
                if left:
                    last[k] = max(left, key=lambda a: getattr(a, by))

    def last_on_lane(self, lane: str) -> Assignment | None:
        """The last assignment on entry lane ``lane`` (the one a new request there follows)."""
        return self._last_on_lane.get(lane)

    def reserved_after(self, t: float) -> bool:
        """Whether a reservation of a conflict area (a plan or a reserved crossing) ends after ``t`` [s]."""
        return any(a.t_exit > t for a in self._reserved)

    def reserve_crossing(self, vehicle_id: str, lane: str, movement: str, t0: float, offsets: dict,
                         merge_window: tuple[float, float], exit_window: tuple[float, float],
                         v_exit_min: float, start: tuple[float, float, float] | None = None,
                         driven_by_sumo: bool = False, platoon_headway_s: float = 1.0,
                         now_only: bool = False) -> Assignment | None:
        """Reserve the crossing of a vehicle that starts from rest (a human driver standing at the
        stop line, ``demand.controlled_share``, or a controlled car queued behind one), first come
        first served: the
        earliest start ``t >= t0`` at which its occupancy of every conflict area on its path,
        ``offsets[other] = (earliest entry, latest exit)`` [s after the start] of the area shared
        with movement ``other``, widened by the margin, overlaps no reservation; every later
        request must then keep clear of ``t + offsets``. ``merge_window`` and ``exit_window``: its
        earliest and latest merging-zone entry and exit [s after the start]; ``v_exit_min``: its
        lowest speed at the exit [m/s] (the spacing of a vehicle behind it on its lane, planned
        from its latest entry and exit); ``start``: ``(D, a, v_cap)``, its distance to the
        merging zone [m] and its slowest start from rest, which a vehicle planned behind it on its
        lane keeps behind (:func:`~nrtraffic.planning.profiles.standing_start`; without it, the
        barrier alone keeps the gap). Returns the assignment, ``t_release`` the start. Behind the
        last vehicle of its lane: :meth:`_lane_bound`. ``driven_by_sumo``: a human driver, whose
        margin to the others is :meth:`margin_between`.

        ``now_only``: a crossing that starts at ``t0`` or not at all (a driver on the move that goes
        on without stopping): None, and nothing reserved, where it would have to start later."""
        t_start, binding, pred, relation = t0, "earliest", None, "none"
        prev = self._last_on_lane.get(lane)
        if prev is not None:
            pred, relation = prev.vehicle_id, "same_lane"
            t_same = self._lane_bound(prev, t0, merge_window, exit_window, v_exit_min, start, driven_by_sumo,
                                      platoon_headway_s)
            if t_same > t_start:
                t_start, binding = t_same, "rear_end"
        t_clear, last = self._zone_clear(movement)  # (zone model: it enters once the zone is clear)
        if t_clear - merge_window[0] > t_start:
            t_start, binding, pred, relation = t_clear - merge_window[0], "conflict", last, "conflict"
        t, blocker = self._first_free(t_start, movement, 0.0, offsets=offsets, driven_by_sumo=driven_by_sumo)
        if now_only and t > t0 + _EPS_S:
            return None
        if blocker is not None:
            pred, relation, binding = blocker, "conflict", "conflict"
        occ = {o: (t + a, t + b) for o, (a, b) in offsets.items()}
        motion = None if start is None else standing_start(t0, t, *start)
        a = Assignment(vehicle_id, lane, t0, t + merge_window[1], Crossing(max(v_exit_min, 1e-3)), pred, relation,
                       binding, movement, t + exit_window[1], t_release=t, occupancy=occ, motion=motion,
                       driven_by_sumo=driven_by_sumo, follows=None if prev is None else prev.vehicle_id)
        return self._commit(a)

    def _lane_bound(self, prev: Assignment, t0: float, merge_window: tuple[float, float],
                    exit_window: tuple[float, float], v_exit_min: float, start, driven_by_sumo: bool,
                    platoon_headway_s: float) -> float:
        """The earliest start [s] of a crossing from rest (:meth:`reserve_crossing`, whose arguments
        these are) behind ``prev``, the last vehicle of its lane. Two human drivers
        (``driven_by_sumo``): ``platoon_headway_s`` after its start; SUMO's car following keeps the
        gap, and the one ahead holds it back no more than its bounds say (tests/test_mixed.py).
        Otherwise as :meth:`schedule` spaces a lane: its earliest entry ``h_min`` after prev's
        (latest) entry, its earliest exit ``delta / max(v_exit_min, v_min)`` after prev's (latest)
        exit; after prev's start where that starts from rest too (a standing queue), and not before
        its own start would run into prev's plan (:func:`start_behind`)."""
        if driven_by_sumo and prev.driven_by_sumo:  # a platoon of SUMO's drivers
            return prev.t_release + platoon_headway_s
        spacing_t = self.settings.rear_end_spacing_m / max(v_exit_min, self.bounds.v_min_mps)
        t_same = max(prev.t_merge + self.settings.min_merge_headway_s - merge_window[0],
                     prev.t_exit + spacing_t - exit_window[0])
        if not math.isnan(prev.t_release):  # it also starts from rest: not before it sets off
            t_same = max(t_same, prev.t_release + self.settings.min_merge_headway_s)
        if start is not None:  # and not before its start from rest would run into the plan ahead
            t_same = max(t_same, start_behind(prev, t0, *start, self.settings.rear_end_spacing_m))
        return t_same

    def _keep_behind(self, prof: Profile, prev: Assignment, t0: float, v0: float, D: float,
                     t_m: float, strict: bool = False) -> tuple[Profile, float]:
        """``prof``, or the rear-end constrained profile when ``prof`` runs into the gap behind the
        lane leader's plan before this vehicle merges; with the remaining intrusion [m] (<= 0: none).

        The gap is ``delta``, or, where no plan within the bounds can keep ``delta`` (a vehicle
        entering in a queue, closer than ``delta`` to its leader), the spacing the slowest such plan
        keeps, less half a metre (at least half a metre); the intrusion is measured against that
        gap. ``strict`` (a vehicle handed over from a junction upstream): always ``delta``."""
        if prev.occupancy is not None and prev.motion is None:  # a crossing without a plan: the barrier keeps the gap
            return prof, float("nan")
        lead = prev.profile if prev.motion is None else prev.motion  # (a start from rest: its slowest)
        shift = lead.D - D  # the leader's position in this vehicle's coordinates is p_lead - shift

        def leader_pos(t):
            return lead.evaluate(t)[0] - shift

        # behind a leader whose plan crawls at about v_min (a slow car's plan may go down to min(v_min,
        # v0)), or entering at about v_min, the follower may need to be slower than the leader for a
        # while: its lowest speed is then half the lower of the two
        bounds = self.bounds
        grid = np.linspace(t0, t_m, max(2, int(math.ceil((t_m - t0) / 0.1)) + 1))
        p_lead, v_lead, _ = lead.evaluate(grid)
        p_lead = p_lead - shift
        v_slow = min(v0, float(np.min(v_lead)))
        if v_slow < 1.5 * bounds.v_min_mps:
            bounds = replace(bounds, v_min_mps=max(0.5 * min(v_slow, bounds.v_min_mps), 1e-3))
        # delta, or less where no plan can keep delta (cars entering in a queue, closer than delta):
        # the spacing the slowest plan within the bounds keeps (braking at u_min to v_min, then at
        # v_min) less half a metre, at least half a metre; at the merging zone the merge-time spacing
        # gives delta
        gap = self.settings.rear_end_spacing_m
        tau = grid - t0
        u_lo, v_floor = bounds.u_min_mps2, bounds.v_min_mps
        t_brake = max(v0 - v_floor, 0.0) / -u_lo
        p_slow = np.where(tau <= t_brake, v0 * tau + 0.5 * u_lo * tau**2,
                          v0 * t_brake + 0.5 * u_lo * t_brake**2 + v_floor * (tau - t_brake))
        keepable = float(np.min(p_lead - p_slow)) - 0.5
        if keepable < gap and not strict:
            gap = max(keepable, 0.5)
        # up to this vehicle's own merge time: past its merge time the leader crosses the zone at
        # constant speed (the profile's continuation), as the merge-time spacing assumes
        intrusion = rear_end_violation(prof, leader_pos, t_m, gap)
        if intrusion <= 0.0:
            return prof, intrusion
        vm = None if (self.settings.terminal_speed == "free" and not prof.kind.startswith("fixed_speed")) else prof.v_m
        try:
            tq = time.perf_counter()
            safe = rear_end_constrained(t0, v0, D, t_m - t0, bounds, leader_pos, t_m, gap, vm=vm,
                                        solver=self.settings.qp_solver)
        except InfeasibleProfile:
            return prof, intrusion
        finally:
            self.qp_wall_s += time.perf_counter() - tq
        return safe, rear_end_violation(safe, leader_pos, t_m, gap)


def energy_optimal(settings: CoordinatorSettings, bounds: PlanBounds, vehicle_id: str, t0: float, v0: float, D: float,
                   t_m: float, v_limit: float) -> Profile:
    """The energy-optimal plan to reach the merging zone at ``t_m`` within the bounds: with a
    cruise at ``v_max`` or, for a long wait, at ``v_min`` where the bound is active; a slow or
    standing car never slower than it is. ScheduleInfeasible where none fits: the car is held
    (SUMO drives it on to its stop line, where its start from rest is reserved)."""
    b = bounds
    T = t_m - t0
    t_max = max_time(v0, D, b)
    if T > t_max + 1e-9:
        raise ScheduleInfeasible(
            f"vehicle {vehicle_id}: merge time {t_m:.2f} s needs {T:.2f} s for {D:.1f} m, "
            f"but at v >= {b.v_min_mps} m/s it arrives by {t_max:.2f} s"
        )
    try:
        if settings.terminal_speed == "fixed":
            return fixed_terminal(t0, v0, min(v_limit, b.v_max_mps), D, T, b)
        prof = free_terminal(t0, v0, D, T, b)
        if prof.v_m > v_limit + 1e-9:
            prof = fixed_terminal(t0, v0, v_limit, D, T, b)
    except InfeasibleProfile as exc:
        raise ScheduleInfeasible(f"vehicle {vehicle_id}: {exc}") from None
    return prof


def start_behind(prev: Assignment, t0: float, D: float, a: float, v_cap: float, delta: float) -> float:
    """The earliest start [s] of a car standing ``D`` [m] before its merging zone, from rest at
    ``a`` [m/s^2] up to ``v_cap`` [m/s], that keeps behind the plan of the car ahead of it on
    its lane (its profile, or its own slowest start from rest): a start at ``t`` covers
    ``f(tau - t)`` by ``tau``, which must stay within the leader's position less the gap,
    ``x(tau)``; with ``T(x)`` the time to cover ``x`` from rest (:func:`~nrtraffic.planning.
    crossing.travel_time`; 0 for ``x <= 0``), ``t >= max_tau (tau - T(x(tau)))``. The gap is
    ``delta`` [m], or the spacing it stands at less half a metre where that is less (a standing
    queue). ``t0`` where the car ahead has no plan (a human's crossing: the barrier keeps the
    gap)."""
    lead = prev.motion if prev.motion is not None else prev.profile
    if not isinstance(lead, Profile):
        return t0
    t_end = max(prev.t_exit, lead.t0 + lead.T) + travel_time(D, a, v_cap)
    grid = np.linspace(t0, t_end, max(2, int(math.ceil((t_end - t0) / 0.1)) + 1))
    spacing = D - lead.D + lead.evaluate(grid)[0]  # centre to centre if this car stood still [m]
    gap = min(delta, max(float(spacing.min()) - 0.5, 0.5))
    x = spacing - gap  # what it may have covered by each instant [m]
    T = travel_times(x, a, v_cap)
    return max(t0, float(np.max(grid - T)))


def snapshot(coord: Coordinator) -> tuple:
    """What :func:`restore` needs to put ``coord``'s reservations back as they are now."""
    return list(coord._reserved), dict(coord._last_on_lane), dict(coord._last_on_movement), dict(coord._passed)


def restore(coord: Coordinator, saved: tuple) -> None:
    """``coord``'s reservations as :func:`snapshot` found them."""
    coord._reserved, coord._last_on_lane, coord._last_on_movement, coord._passed = (
        list(saved[0]), dict(saved[1]), dict(saved[2]), dict(saved[3]))
