"""Admission at the controlled junctions: each step, which vehicles in a control zone are
scheduled, batched, held or started from rest, and the hand-over from one junction to the next.

A vehicle SUMO inserts (``waiting``) is ``approaching``; once its centre of gravity crosses the
control-zone entry the coordinator of its junction is asked for a merge time, one vehicle at a time
(``policy = "fifo"``) or a batch of them (``"batch"``: ``batched`` until the batch closes, or
earlier where a vehicle of it would otherwise come too close to the merging zone to stop: a short
control zone). A vehicle that enters slower than ``QUEUED_SPEED_SHARE`` of its free-flow speed
(in a queue) is asked for its earliest arrival within the bounds, not at its entry speed. With a
merge time it is ``controlled``: the kernel drives it on its energy-optimal profile (or, for a long
wait, a stop before the zone and a start from rest). Without one it is ``held``: SUMO drives it on
to its stop line, asking again on the way; standing there its start from rest is reserved, which
always finds a slot, so every vehicle that arrives is served. A vehicle behind a human driver
on its lane, whose crossing is not reserved yet, waits for it: SUMO stops it at the stop line, and
standing there its start from rest is reserved (``starting``). Released past the merging zone, a
vehicle whose trip goes on to another controlled junction starts a new record there.
"""

from __future__ import annotations

import math

import numpy as np

from nrtraffic.control import batch as kb
from nrtraffic.control.table import N_PROFILE_SEG
from nrtraffic.junction import exits, humans, order
from nrtraffic.lifecycle import State, VehicleRecord
from nrtraffic.planning.coordinator import Assignment, Request, ScheduleInfeasible
from nrtraffic.planning.crossing import CrossingBounds
from nrtraffic.planning.profiles import from_rest
from nrtraffic.vehicle.fuel import fuel_rate

# slack of a reserved start from rest of a controlled vehicle (its tracking error, in time) [s]
FROM_REST_SLACK_S = 0.3
# a vehicle entering the control zone slower than this share of its free-flow speed has been slowed
# by the traffic ahead (a queue reaching back past the zone entry): it does not keep its entry speed
QUEUED_SPEED_SHARE = 0.9
# no car drives faster than this: a car before its control zone is looked at again when it could
# have reached the zone at this speed (admission's work grows with the cars near zone entries) [m/s]
SPEED_BOUND_MPS = 70.0
# a batch closes early when one of its vehicles comes within this time of the last point where it
# can still stop before the merging zone [s]
BATCH_CLOSE_S = 1.0


# slower than this at insertion [m/s], a vehicle is not held at its speed on its way (SUMO's driver sets
# off with it) and its free-flow time is at the entry speed
MIN_CRUISE_MPS = 1.0


class Admission:
    """The admission decisions of every controlled junction of a run (``st``: its
    :class:`~nrtraffic.state.RunState`; ``departures``: vehicle id -> ``(route, depart_s,
    speed_mps)`` of the demand, ``human_ids`` its human drivers, ``listed`` the ``[[vehicles]]``,
    ``paced`` those :attr:`~nrtraffic.demand.Demand.paced`)."""

    def __init__(self, st, departures: dict, human_ids: set, listed: dict, paced: set = frozenset()):
        self.st = st
        self.scheduled = departures  # not inserted yet; a vehicle's record is made when SUMO inserts it
        self.paced = paced  # sent in slower than the entry speed by its first road (Demand.paced)
        self.human_ids = human_ids
        self.listed = listed
        self.batch = st.sc.coordinator.policy == "batch"

    # ------------------------------------------------------------ into the run
    def depart(self, vid: str, dt: float) -> None:
        """A vehicle SUMO has just inserted: its record, and on its way (``approaching`` under
        control; ``sumo``, or a human driver sent to its stop line, otherwise)."""
        st = self.st
        if vid not in self.scheduled:  # not of the demand
            return
        trip, t, speed = self.scheduled.pop(vid)
        paced = vid in self.paced or speed < MIN_CRUISE_MPS  # (inserted standing, or slowed at its start)
        speed = speed if not paced else st.sc.demand.entry_speed_mps
        lv = self.listed.get(vid)
        human = vid in self.human_ids
        legs = st.itineraries.get(trip, (trip,))
        lane, mv, on_it = lane_movement(st, vid, legs[0])
        if not on_it:  # (inserted on a lane that does not serve its first turn: it changes lanes for it)
            st.sumo.free_lane(vid)
        elif any(len(st.layout.lane_movements[leg]) > 1 for leg in legs):
            # SUMO inserted it on the least occupied lane its route can take (departLane="best"); it
            # keeps that lane, which decides its lane-level movement
            st.sumo.keep_lane(vid)
        rec = st.records[vid] = VehicleRecord(
            vid, st.layout.movement_table[legs[0]][0], t, movement=mv, route=legs[0], lane=lane, v_free=speed,
            controlled=(lv.controlled if lv else True) and st.control and not human,
            driver="human" if human else "automated",
            heading_offset=lv.entry_heading_offset_rad if lv else 0.0,
            speed_profile=lv.speed_profile if lv else (), junction=st.layout.movement_junction[legs[0]], legs=legs,
            lane_kept=on_it)
        st.life.add(vid, rec.junction)
        # SUMO's departDelay, less the part that is only the wait for the next step
        desired = round(rec.t_depart, 2)  # as the route file gives it
        step_wait = math.ceil(desired / dt - 1e-9) * dt - desired
        rec.depart_delay = max(0.0, st.sumo.depart_delay(vid) - step_wait)
        if rec.controlled:
            st.life.move(vid, State.APPROACHING)
            st.sumo.colour(vid, "approaching")
            if not paced and (v0 := st.sumo.speed(vid)) >= MIN_CRUISE_MPS:  # (cruising to its zone; one inserted
                st.sumo.hold_speed(vid, v0)  # standing, or slowed at its start, is driven there by SUMO)
        else:
            st.life.move(vid, State.SUMO)
            if rec.driver == "human" and st.control:
                humans.to_stop_line(st, vid)

    def next_leg(self, vid: str) -> bool:
        """A vehicle that left a junction's merging zone with a next junction on its trip (a
        corridor): its crossing is kept (``crossings``) and a new record starts for the next one,
        which that junction admits when the vehicle enters its control zone (SUMO drives it until
        then; a human driver is told to stop at that junction's stop line). False when the trip
        has no next junction: a vehicle kept on its lane then changes lanes for its route again
        (:meth:`~nrtraffic.sumo.adapter.SumoSession.lanes_for_route`)."""
        st = self.st
        rec = st.records[vid]
        if rec.leg + 1 >= len(rec.legs):
            st.sumo.lanes_for_route(vid)
            return False
        st.crossings.append(rec)
        route = rec.legs[rec.leg + 1]
        lane, mv, on_it = lane_movement(st, vid, route)
        if not on_it:  # SUMO's driver changes lanes for its next turn, until its control zone
            st.sumo.free_lane(vid)
        new = st.records[vid] = VehicleRecord(
            vid, st.layout.movement_table[route][0], rec.t_depart, movement=mv, route=route, lane=lane,
            v_free=rec.v_free, controlled=rec.controlled, driver=rec.driver, speed_profile=rec.speed_profile,
            junction=st.layout.movement_junction[route], legs=rec.legs, leg=rec.leg + 1, lane_kept=on_it)
        if new.controlled:
            st.life.move(vid, State.APPROACHING, junction=new.junction)
            st.sumo.colour(vid, "approaching")
        elif new.driver == "human" and st.control:
            st.reservations.pop(vid, None)  # (its last crossing's, spent)
            humans.to_stop_line(st, vid)
        else:
            st.life.move(vid, State.SUMO, junction=new.junction)
        return True

    # ------------------------------------------------------------ each step
    def step(self, dt: float) -> None:
        """This step's admission at every junction: reserved starts that have come, then the
        vehicles in the control zones scheduled (one by one, or by batch)."""
        self.start()
        if self.batch:
            self.admit_batch(dt)
            return
        life = self.st.life
        # lanes whose first waiting vehicle could not be admitted -> where it is [m]: those behind it
        # wait (one ahead of it may come later in this order: a held vehicle departed after them)
        blocked: dict[str, float] = {}
        for vid in life.members(State.APPROACHING, State.HELD):
            rec = self.st.records[vid]
            if rec.lane in blocked and self.st.where_on_path(vid) <= blocked[rec.lane]:
                continue
            if ((rec.hindered or self.blocked_ahead(vid)) and self.request(vid, entry_only=True)
                    and self.hindered(vid)):  # waits for a human ahead, or starts from the stop line
                if rec.status != "starting":
                    blocked[rec.lane] = self.st.where_on_path(vid)
                continue
            state = self.try_admit(vid)
            if state == "held":
                blocked[rec.lane] = self.st.where_on_path(vid)
                rec.t_held += dt
        account_waiting(self.st, life.members(State.HELD) + life.members(State.STARTING), dt)

    def request(self, vid: str, entry_only: bool = False):
        """What a vehicle whose centre of gravity crossed the control-zone entry asks of the
        coordinator, from SUMO's view of it now: ``(Request, x0, s, lateral offset)``; None while it
        has not crossed. ``entry_only``: only whether it crossed (True or None)."""
        st = self.st
        rec = st.records[vid]
        if st.t < rec.look_after:  # (it cannot have reached its zone yet)
            return None
        mv = st.paths[rec.movement]
        tab = st.snap
        k = tab.row.get(vid)
        if k is None:
            return None
        lane, pos = tab.lane[k], float(tab.lane_pos[k])
        if lane not in mv.lane_offset:
            if rec.lane_kept or not st.choose_lane(vid, lane):
                return None  # (before its approach, or on a lane that does not serve its turn yet)
            mv = st.paths[rec.movement]
        s_cg = mv.s_of(lane, pos) - st.params.cg_to_front
        if s_cg < mv.s_control - 1e-6:
            if rec.lane_kept:  # (one that may change lanes is looked at each step: its movement may change)
                rec.look_after = st.t + (mv.s_control - s_cg) / SPEED_BOUND_MPS
            return None
        if not rec.lane_kept:  # in the control zone: lanes are kept
            st.sumo.keep_lane(vid)
            rec.lane_kept = True
        if math.isnan(rec.t_arrive):
            rec.t_arrive, rec.s_arrive = st.t, s_cg
        if entry_only:
            return True
        cg = st.params.cg_to_front
        xf, yf, psi = float(tab.x[k]), float(tab.y[k]), float(tab.psi[k])
        v = float(tab.speed[k])
        x0 = np.array([xf - cg * math.cos(psi), yf - cg * math.sin(psi), v, 0.0, psi + rec.heading_offset, 0.0])
        s_proj, lat0 = mv.path.project(x0[:2])
        D = mv.s_merge - s_proj
        v_lim = mv.v_limit
        if rec.hindered:  # slowed behind a human: cross no faster than half the bound's acceleration reaches
            v_lim = min(v_lim, math.sqrt(v * v + st.sc.planning.u_max_mps2 * max(D, 0.0)))
        v_free = min(rec.v_free, st.sc.planning.v_max_mps) if rec.v_free > 0.0 else st.sc.planning.v_max_mps
        queued = v < QUEUED_SPEED_SHARE * v_free
        req = Request(vid, rec.lane, st.t, v, D, rec.movement, mv.s_exit - mv.s_merge, v_lim, rec.hindered or queued,
                      rec.approach in st.layout.upstream_junction)
        return req, x0, s_proj, lat0

    def try_admit(self, vid: str) -> str:
        """Admit a vehicle whose centre of gravity crossed the control-zone entry: "waiting" (not
        there yet), "admitted", or "held" (no merge time meets the bounds: :meth:`hold`; admission
        is tried again every step, and the lane behind it waits, so that its FIFO order is kept)."""
        got = self.request(vid)
        if got is None:
            return "waiting"
        req = got[0]
        try:
            if req.D <= 0.5:
                raise ScheduleInfeasible(f"vehicle {vid} is already at the merging zone")
            asg = self.st.junctions[self.st.records[vid].junction].coord.schedule_request(req)
        except ScheduleInfeasible:
            self.hold(vid)
            return "held"
        self.admit(got, asg)
        return "admitted"

    def admit_batch(self, dt: float) -> None:
        """``policy = "batch"``: vehicles that crossed the control-zone entry wait (driven on by
        SUMO at their speed) until ``batch_window_s`` after the first of them; then all waiting
        are scheduled together (:meth:`Coordinator.schedule_batch`) from their state at that
        moment. Held ones (no feasible merge time, :meth:`hold`) wait for the next batch, which
        closes a window after they were held, or for their start from rest at the stop line."""
        st = self.st
        for vid in st.life.members(State.APPROACHING):
            if self.request(vid, entry_only=True):
                j = st.junctions[st.records[vid].junction]
                if not self.pending(j):
                    j.batch_closes = st.t + st.sc.coordinator.batch_window_s
                st.life.move(vid, State.BATCHED)
                st.sumo.colour(vid, "pending")
        pending = st.life.by_junction(State.BATCHED, State.HELD) if len(st.junctions) > 1 else None
        for j in st.junctions.values():
            self.close_batch(j, dt, pending.get(j.id, []) if pending is not None else None)
        if st.life.count(State.STARTING):
            account_waiting(st, st.life.members(State.STARTING), dt)

    def pending(self, j) -> list[str]:
        """Junction ``j``'s batch: its vehicles waiting for it to close (held ones too)."""
        return self.st.life.members(State.BATCHED, State.HELD, junction=j.id if len(self.st.junctions) > 1 else None)

    def close_batch(self, j, dt: float, pending: list[str] | None = None) -> None:
        """Junction ``j``'s batch (``pending``, default :meth:`pending`): its waiting vehicles
        accounted for, and all scheduled together when the batch closes (:meth:`admit_batch`)."""
        st = self.st
        pending = self.pending(j) if pending is None else pending
        if not pending:
            return
        # behind a human: checked each step, until its start is reserved (then it leaves the batch)
        waiting = {vid for vid in pending if self.hindered(vid)}
        if waiting:
            pending = [v for v in pending if st.records[v].status != "starting"]
        for vid in pending:
            rec = st.records[vid]
            if rec.status == "held":
                rec.t_held += dt
        account_waiting(st, pending, dt)
        if not pending or (st.t < j.batch_closes - 1e-9 and not must_close(st, pending, waiting)):
            return
        got = {}
        for vid in pending:
            if vid in waiting:  # waits for a human ahead, or for its stop at the stop line
                continue
            g = self.request(vid)
            if g is not None and g[0].D > 0.5:
                got[vid] = g
            else:
                self.hold(vid)  # at the zone already, or no longer seen on its path
        results = j.coord.schedule_batch([got[v][0] for v in pending if v in got])
        held = [req.vehicle_id for req, a in results if isinstance(a, ScheduleInfeasible)]
        for req, a in results:
            if not isinstance(a, ScheduleInfeasible):
                self.admit(got[req.vehicle_id], a)
        for vid in held:
            self.hold(vid)
        j.batch_closes = st.t + st.sc.coordinator.batch_window_s if self.pending(j) else math.inf

    def hold(self, vid: str) -> None:
        """No merge time for a vehicle in the control zone now (``held``): SUMO drives it on to a
        stop short of the merging zone, at its stop line; on the way it is asked for again, and
        standing there its start from rest is reserved, which always finds a slot
        (:meth:`hindered`, :meth:`reserve_from_rest`). The vehicles behind it on its lane queue
        behind it, in their order. (Stopping it where it is instead would leave it standing in the
        control zone with no plan that starts from rest: the junction could lock up.)"""
        st = self.st
        rec = st.records[vid]
        if st.life.state(vid) in (State.APPROACHING, State.BATCHED):
            st.life.move(vid, State.HELD)
        if not rec.hindered:
            self.wait_at_stop_line(vid, "held")

    def live(self, j) -> bool:
        """The junction's liveness invariant: while vehicles wait at junction ``j``, some conflict
        area is in use or reserved ahead (a vehicle under control or crossing, a reservation that
        ends after now), or a waiting vehicle is still on its way to its stop line, where its start
        from rest will be reserved. Held vehicles are never left standing without one of these."""
        st = self.st
        waiting = self.waiting(j)
        if not waiting:
            return True
        jid = j.id if len(st.junctions) > 1 else None
        if st.life.members(State.CONTROLLED, State.CROSSING, junction=jid):
            return True
        if j.coord.reserved_after(st.t):
            return True
        tab = st.snap
        return any(tab.row.get(v) is not None and tab.speed[tab.row[v]] >= 0.1 for v in waiting)

    def waiting(self, j) -> list[str]:
        """The vehicles waiting at junction ``j``: in its control zone, neither under control nor
        crossing (scheduled nowhere yet, or standing for a reserved start)."""
        life, recs = self.st.life, self.st.records
        jid = j.id if len(self.st.junctions) > 1 else None
        out = [v for v in life.members(State.APPROACHING, State.HUMAN, junction=jid)
               if not (math.isnan(recs[v].t_arrive) and math.isnan(recs[v].t_enter))]
        return out + life.members(State.BATCHED, State.HELD, State.STARTING, State.RESERVED, junction=jid)

    def admit(self, got, asg) -> None:
        """Take a scheduled vehicle over: from now on the kernel drives it."""
        st = self.st
        req, x0, s_proj, lat0 = got
        vid = req.vehicle_id
        rec = st.records[vid]
        if rec.hindered and st.life.state(vid) is not State.STARTING:  # scheduled on the move after all: no stop
            st.sumo.cancel_stop(vid)
        st.life.move(vid, State.CONTROLLED)
        st.sumo.take_over(vid)
        st.sumo.colour(vid, "controlled")
        rec.t_enter, rec.v_enter, rec.s_enter = st.t, req.v0, s_proj
        rec.t_merge_planned, rec.v_merge_planned = asg.t_merge, asg.profile.v_m
        rec.predecessor, rec.relation, rec.binding = asg.predecessor, asg.relation, asg.binding
        rec.profile_kind = asg.profile.kind
        rec.plan_intrusion = asg.plan_intrusion_m
        # (with what it used while SUMO drove it in the control zone)
        st.kernel.take(vid, x0, asg.profile.packed(N_PROFILE_SEG), st.t, s_proj, lat0, st.paths[rec.movement],
                       rec.acc, asg.t_merge, again=rec.replans > 0)

    # ------------------------------------------------------------ behind a human driver
    def blocked_ahead(self, vid: str) -> bool:
        """Whether a vehicle whose crossing is not reserved yet, a human driver or a controlled
        vehicle queued behind one, is ahead of ``vid`` on its entry lane, by where SUMO has them
        now (on a corridor the vehicles on a lane come from several roads upstream, so the order
        of departure is not the lane's order)."""
        st = self.st
        q = st.life.waiting_at_line(st.records[vid].lane)
        if not q or (len(q) == 1 and vid in q):
            return False
        here = st.where_on_path(vid)
        if here == -math.inf:
            return True  # (not on its path's lanes yet: everyone on the lane is ahead of it)
        return any(u != vid and st.where_on_path(u) > here for u in q)

    def wait_at_stop_line(self, vid: str, colour: str) -> None:
        """A controlled vehicle that is not scheduled yet and must not cross unplanned: SUMO drives
        it on to a stop short of the merging zone; until its crossing is scheduled or reserved it
        waits at its lane's stop line (the vehicles behind it wait for it, :meth:`hindered`)."""
        st = self.st
        rec = st.records[vid]
        rec.hindered = True
        st.sumo.stop_at(vid, *st.stop_line[rec.movement, "automated"])
        st.sumo.colour(vid, colour)
        st.life.wait_at_line(vid, rec.lane)

    def hindered(self, vid: str) -> bool:
        """Whether a controlled vehicle in the control zone must wait for a human driver instead of
        being scheduled now. When it is first found with an unreserved vehicle ahead on its lane
        (:meth:`blocked_ahead`), SUMO is told to stop it at the stop line, and the vehicles behind
        it wait for it too. Once nothing unreserved is ahead: moving, it is scheduled as any other
        (:meth:`admit` cancels the stop; when no merge time fits it drives on to the stop line);
        standing at the stop line, its start from rest is reserved (:meth:`reserve_from_rest`,
        ``starting``)."""
        rec = self.st.records[vid]
        if self.st.life.state(vid) is State.STARTING:
            return True
        if not rec.hindered:
            if not self.blocked_ahead(vid):
                return False
            self.wait_at_stop_line(vid, "pending")
            return True
        if self.blocked_ahead(vid):
            return True
        if self.standing(vid):
            self.reserve_from_rest(vid)
            return True
        return False

    def standing(self, vid: str) -> bool:
        """Whether a controlled vehicle waiting at its lane's stop line stands: at the stop line, or
        anywhere on its path in a standing queue (its start from rest is then reserved from there:
        the queue sets off as a platoon, not one car at a time from the line), or, where it could
        not stop before it, in the merging zone."""
        st = self.st
        k = st.snap.row.get(vid)
        if k is None or st.snap.speed[k] >= 0.1:
            return False
        s = st.cg_on_path(vid)
        # (a vehicle that could not stop before the merging zone stands in it: it starts from there)
        return s is not None and st.paths[st.records[vid].movement].s_exit - s > 0.0

    def reserve_from_rest(self, vid: str) -> None:
        """Reserve the start of a controlled vehicle standing at the stop line: from rest at the
        planning's ``u_max_mps2`` up to its crossing speed (:func:`~nrtraffic.planning.profiles.
        from_rest`, the plan the kernel will track), its occupancy of each conflict area bounded
        with ``FROM_REST_SLACK_S`` each side."""
        st = self.st
        self._reserve_start(vid)
        st.life.move(vid, State.STARTING)
        st.sumo.hold_speed(vid, 0.0)  # it stands where its start was reserved from until the start
        st.sumo.colour(vid, "held")

    def _reserve_start(self, vid: str) -> None:
        st = self.st
        rec = st.records[vid]
        mv = st.paths[rec.movement]
        a, v_c = st.sc.planning.u_max_mps2, min(mv.v_limit, st.sc.planning.v_max_mps)
        humans.reserve(st, vid, CrossingBounds(a, a, v_c, v_c, FROM_REST_SLACK_S))
        rec.profile_kind = "from_rest"

    def _reserve_unless_held(self, vid: str) -> None:
        """Reserve the start of a vehicle that waited for one, unless a vehicle with no crossing
        arranged stands in its way (:func:`~nrtraffic.junction.order.standing_ahead`)."""
        if order.standing_ahead(self.st, vid) is None:
            self._reserve_start(vid)

    def start(self) -> None:
        """Controlled vehicles whose reserved start from rest has come: the kernel takes them over
        (not while their exit is queued: :func:`~nrtraffic.junction.exits.wait_for_room`), in
        their lane's order, and not while a vehicle with no crossing arranged stands in their way
        (:mod:`nrtraffic.junction.order`)."""
        st = self.st
        if not st.life.count(State.STARTING):
            return
        starting = st.life.members(State.STARTING)
        ahead = order.starting_ahead(st, starting) if len(starting) > 1 else {}
        for vid in starting:
            rec = st.records[vid]
            if vid in ahead and order.after_leader(st, vid, ahead[vid]):
                continue
            if st.t >= rec.t_release - 1e-9 and order.way_held(st, vid):  # (one that waits: when its exit clears)
                continue
            if exits.wait_for_room(st, vid, self._reserve_unless_held) or st.t < rec.t_release - 1e-9:
                continue
            got = self.request(vid)
            if got is None:  # no longer seen on its path (not expected)
                st.life.move(vid, State.LOST)
                continue
            req = got[0]
            mv = st.paths[rec.movement]
            prof = from_rest(st.t, max(req.D, 0.0), st.sc.planning.u_max_mps2,
                             min(mv.v_limit, st.sc.planning.v_max_mps))
            if st.sumo.is_stopped(vid):  # at its stop line; else in a queue before it: the stop is dropped
                st.sumo.resume(vid)
            else:
                st.sumo.cancel_stop(vid)
            self.admit(got, Assignment(vid, rec.lane, st.t, prof.t_m, prof, rec.predecessor, rec.relation,
                                       rec.binding, rec.movement))


def lane_movement(st, vid: str, route: str) -> tuple[str, str, bool]:
    """``(entry lane, lane-level movement, on it)`` of a vehicle on turning movement ``route``:
    the one of the lane SUMO has it on; where it is on none of them (it left the junction
    upstream on a lane that does not serve its next turn, or its road has more edges before
    the approach), the first, and ``on it`` false: the movement is then chosen where the
    vehicle enters the control zone (:meth:`~nrtraffic.state.RunState.choose_lane`)."""
    lanes = st.layout.lane_movements[route]
    here = st.sumo.lane_position(vid)[0]
    return next(((ln, name, True) for ln, name, _, _ in lanes if ln == here), (*lanes[0][:2], False))



def account_waiting(st, vids: list[str], dt: float) -> None:
    """Energy and fuel of vehicles in the control zone that SUMO still drives (waiting for their
    batch, or held), from SUMO's speed and acceleration; carried over when they are admitted."""
    tab = st.snap
    for vid in vids:
        k = tab.row.get(vid)
        if k is None:
            continue
        v, a = float(tab.speed[k]), float(tab.accel[k])
        acc = st.records[vid].acc
        acc[kb.ACC_ENERGY] += 0.5 * a * a * dt
        acc[kb.ACC_FUEL] += fuel_rate(v, a) * dt


def must_close(st, pending: list[str], waiting: set[str]) -> bool:
    """Whether a batch (``pending``, of run ``st``; ``waiting`` those behind a human) must close
    before its window ends: a vehicle in it (driven on by SUMO at its speed) comes within
    ``BATCH_CLOSE_S`` of the last point where it can still stop before the merging zone at the
    planning's ``u_min`` (on a short control zone that is as soon as it enters: it is scheduled
    from its state on entry)."""
    tab = st.snap
    brake = -st.sc.planning.u_min_mps2
    for vid in pending:
        k = tab.row.get(vid)
        if vid in waiting or k is None:
            continue
        s = st.cg_on_path(vid)
        if s is None:
            continue
        v = float(tab.speed[k])
        if st.paths[st.records[vid].movement].s_merge - s <= v * v / (2.0 * brake) + v * BATCH_CLOSE_S:
            return True
    return False
