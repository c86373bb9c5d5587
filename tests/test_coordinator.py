import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from nrtraffic.planning.conflicts import CONFLICT
from nrtraffic.planning.coordinator import Coordinator, CoordinatorSettings, Request, ScheduleInfeasible
from nrtraffic.planning.profiles import PlanBounds


def test_fifo_merge_times_on_one_lane_by_hand():
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=10.0, min_merge_headway_s=4.0), PlanBounds())
    D, v = 400.0, 13.4
    a1 = c.schedule("a", "L", 0.0, v, D)
    a2 = c.schedule("b", "L", 2.0, v, D)
    a3 = c.schedule("c", "L", 20.0, v, D)
    a4 = c.schedule("d", "other", 2.5, v, D)
    # hand-computed: free arrival t0 + D / v0; headway max(4 s, 10 m / v_m)
    assert a1.t_merge == pytest.approx(D / v) and a1.binding == "earliest"
    assert a2.t_merge == pytest.approx(D / v + 4.0) and a2.binding == "rear_end" and a2.predecessor == "a"
    assert a3.t_merge == pytest.approx(20.0 + D / v) and a3.binding == "earliest"
    assert a4.t_merge == pytest.approx(2.5 + D / v) and a4.predecessor is None
    # the car held back slows down and arrives at the speed the closed form gives
    T = a2.t_merge - 2.0
    assert a2.profile.v_m == pytest.approx((3 * D / T - v) / 2)


def test_distance_spacing_binds_at_low_merge_speed():
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=30.0, min_merge_headway_s=0.0), PlanBounds())
    a1 = c.schedule("a", "L", 0.0, 5.0, 100.0)
    a2 = c.schedule("b", "L", 0.5, 5.0, 100.0)
    assert a2.t_merge == pytest.approx(a1.t_merge + 30.0 / a1.profile.v_m)


def test_unmeetable_schedule_is_reported():
    c = Coordinator(CoordinatorSettings(min_merge_headway_s=500.0), PlanBounds())
    c.schedule("a", "L", 0.0, 13.4, 400.0)
    with pytest.raises(ScheduleInfeasible, match="vehicle b"):
        c.schedule("b", "L", 1.0, 13.4, 400.0)


# ---------------------------------------------------------------- batch sequencing

_REL = {("A", "B"): CONFLICT, ("B", "A"): CONFLICT, ("A", "C"): CONFLICT, ("C", "A"): CONFLICT,
        ("B", "C"): CONFLICT, ("C", "B"): CONFLICT}
_AREAS = {("A", "B"): (10.0, 20.0), ("B", "A"): (12.0, 22.0), ("A", "C"): (5.0, 12.0), ("C", "A"): (18.0, 26.0),
          ("B", "C"): (0.0, 8.0), ("C", "B"): (3.0, 9.0)}
_BOUNDS = PlanBounds(v_min_mps=1.0, v_max_mps=20.0, u_min_mps2=-3.0, u_max_mps2=2.5)


def _coordinator(policy="batch", cap=3, margin=1.0):
    s = CoordinatorSettings(rear_end_spacing_m=12.0, terminal_speed="fixed", conflict_model="conflict_points",
                            conflict_margin_s=margin, policy=policy, max_passed=cap)
    return Coordinator(s, _BOUNDS, _REL, areas=_AREAS)


def _req(vid, movement, D, lane=None, v=10.0):
    return Request(vid, lane or f"lane_{movement}", 0.0, v, D, movement, 30.0, v)


def test_a_handed_over_follower_that_cannot_keep_behind_its_leader_is_not_committed():
    """A follower 13 m/s fast, close behind a 4 m/s leader on its lane: keeping the 12 m spacing
    needs (13 - 4)^2 / (2 * 3 m/s^2) = 13.5 m of room to shed the speed difference at the planning
    bound u_min (closed form). With 8 m of room no plan exists. A vehicle handed over from a
    junction upstream is then refused and nothing is committed (the leader stays the lane's last);
    with 28 m of room it is planned behind the leader, keeping the gap everywhere. Any other
    vehicle is planned as close as the bounds allow: the slowest plan (braking at u_min to the
    leader's 4 m/s) comes within 20 - 13.5 = 6.5 m of it, so its plan keeps 6.5 - 0.5 = 6.0 m."""
    from nrtraffic.planning.profiles import rear_end_violation

    bounds = PlanBounds(u_min_mps2=-3.0)
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=12.0, min_merge_headway_s=1.0), bounds)
    lead = c.schedule("lead", "L", 0.0, 4.0, 200.0)
    with pytest.raises(ScheduleInfeasible, match="keeps 12 m behind lead"):
        c.schedule_request(Request("fast", "L", 0.0, 13.0, 200.0 + 20.0, handed_over=True))  # 8 m of room
    ok = c.schedule_request(Request("far", "L", 0.0, 13.0, 200.0 + 40.0, handed_over=True))  # 28 m of room
    assert ok.predecessor == "lead"  # the refused request left no trace on the lane
    shift = lead.profile.D - ok.profile.D
    assert rear_end_violation(ok.profile, lambda t: lead.profile.evaluate(t)[0] - shift, ok.t_merge, 12.0) <= 0.05
    c2 = Coordinator(CoordinatorSettings(rear_end_spacing_m=12.0, min_merge_headway_s=1.0), bounds)
    lead2 = c2.schedule("lead", "L", 0.0, 4.0, 200.0)
    kept = c2.schedule("fast", "L", 0.0, 13.0, 200.0 + 20.0)
    assert kept.profile.kind == "rear_end" and kept.plan_intrusion_m <= 0.05
    t = np.linspace(0.0, kept.t_merge, 2001)
    spacing = lead2.profile.evaluate(t)[0] + 20.0 - kept.profile.evaluate(t)[0]  # centre to centre [m]
    assert spacing.min() >= 6.0 - 0.06
    assert spacing.min() <= 6.5  # and no more room than the bounds give


def test_batch_serves_a_lane_mate_before_the_cross_flow_by_hand():
    """a1 and a2 (movement A, one lane) and b1 (B, crossing A: A's area [10, 20] m, B's [12, 22] m),
    all at 10 m/s, 1 s margin; at the batch's close a1 is 390 m, b1 395 m and a2 398 m from the zone
    (earliest merges 39.0, 39.5, 39.8 s). First in, first out: a1 39.0, b1 40.8 (B's area from
    42.0 s, after a1's [40, 41] s and the margin), a2 43.0 (A's area after b1's [42, 43] s + 1 s):
    4.5 s lost. Batch: a1 goes first (b1 first would cost a1 2.7 s), then a2 (0.4 s behind a1 on
    its lane; b1 then loses 2.5 s) rather than b1 (1.3 s, and a2 then loses 3.2 s): 2.9 s lost."""
    reqs = [_req("a1", "A", 390.0), _req("b1", "B", 395.0), _req("a2", "A", 398.0)]
    fifo = _coordinator(cap=0).schedule_batch(reqs)
    assert [r.vehicle_id for r, _ in fifo] == ["a1", "b1", "a2"]
    assert [a.t_merge for _, a in fifo] == pytest.approx([39.0, 40.8, 43.0])
    one_by_one = _coordinator(policy="fifo")  # the same as scheduling each on arrival
    assert [one_by_one.schedule(r.vehicle_id, r.lane, 0.0, 10.0, r.D, r.movement, 30.0, 10.0).t_merge
            for r in reqs] == pytest.approx([39.0, 40.8, 43.0])
    batch = _coordinator(cap=1).schedule_batch(reqs)
    assert [r.vehicle_id for r, _ in batch] == ["a1", "a2", "b1"]
    assert [a.t_merge for _, a in batch] == pytest.approx([39.0, 40.2, 42.0])
    assert [a.binding for _, a in batch] == ["earliest", "rear_end", "conflict"]


def _occupancy(a, other):
    lo, hi = _AREAS[(a.movement, other)]
    return a.t_merge + lo / a.profile.v_m, a.t_merge + hi / a.profile.v_m


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from("ABC"), st.integers(0, 1), st.floats(0.0, 1.5)), min_size=1, max_size=9),
       st.integers(0, 4), st.floats(0.0, 2.0))
@example([("A", 0, 0.0), ("A", 0, 0.03125), ("A", 0, 0.0), ("A", 1, 0.0), ("A", 0, 0.0)], 0, 0.0)  # cars 0.3 m apart
def test_batch_keeps_lane_order_the_cap_and_every_reservation(arrivals, cap, margin):
    """Any batch: same-lane order never changes, no vehicle is served after more than ``cap``
    vehicles that arrived later, and (checked from the assignments alone) no two conflicting
    vehicles' occupancies of their shared area, widened by the margin, overlap; same-lane
    vehicles merge at least the spacing apart. A vehicle is held (no assignment) only where it is
    closer to the one ahead on its lane than a car's length and the barrier's gap (7 m), where no
    plan can keep behind it; the rest of its lane waits behind it."""
    reqs, D, last = [], 380.0, {}
    close = set()  # vehicles closer than 7 m behind the one ahead on their lane
    for k, (mv, lane, gap) in enumerate(arrivals):
        D += gap * 10.0  # later arrivals are further from the zone when the batch closes
        key = f"{mv}{lane}"
        if key in last and D - last[key] < 7.0:
            close.add(f"v{k}")
        last[key] = D
        reqs.append(_req(f"v{k}", mv, D, lane=key))
    c = _coordinator(cap=cap, margin=margin)
    out = c.schedule_batch(reqs)
    assert sorted(r.vehicle_id for r, _ in out) == sorted(r.vehicle_id for r in reqs)
    rank = {r.vehicle_id: k for k, r in enumerate(reqs)}
    held = {r.vehicle_id: r.lane for r, a in out if isinstance(a, ScheduleInfeasible)}
    first_held = {}
    for vid, lane in held.items():
        if lane not in first_held or rank[vid] < rank[first_held[lane]]:
            first_held[lane] = vid
    assert set(first_held.values()) <= close
    for vid, lane in held.items():  # the rest of its lane waits behind it
        assert rank[vid] >= rank[first_held[lane]]
    for r in reqs:
        if r.lane in first_held and rank[r.vehicle_id] > rank[first_held[r.lane]]:
            assert r.vehicle_id in held
    out = [(r, a) for r, a in out if not isinstance(a, ScheduleInfeasible)]
    served = [r.vehicle_id for r, _ in out]
    for k, vid in enumerate(served):
        assert sum(rank[w] > rank[vid] for w in served[:k]) <= cap
    by_lane: dict = {}
    for r, a in out:
        by_lane.setdefault(r.lane, []).append(a)
    for lane_asg in by_lane.values():
        assert [a.vehicle_id for a in lane_asg] == sorted((a.vehicle_id for a in lane_asg), key=rank.get)
        for p, q in zip(lane_asg, lane_asg[1:]):
            assert q.t_merge - p.t_merge >= 12.0 / 10.0 - 1e-9
    asg = [a for _, a in out]
    for i, a in enumerate(asg):
        for b in asg[i + 1:]:
            if (a.movement, b.movement) in _AREAS:
                a_in, a_out = _occupancy(a, b.movement)
                b_in, b_out = _occupancy(b, a.movement)
                assert a_out + margin <= b_in + 1e-6 or b_out + margin <= a_in + 1e-6, (a, b)


def test_batch_needs_conflict_points():
    with pytest.raises(ValueError, match="conflict_points"):
        CoordinatorSettings(terminal_speed="fixed", policy="batch")


def test_a_standing_queue_sets_off_front_first_and_a_car_behind_it_is_planned_behind_its_start():
    """Two cars standing on one lane, 20 m and 60 m before the zone, start from rest (2.5 m/s^2 up
    to 10 m/s). The one farther back could reach the zone in time for a start before the front
    one's, but starts no sooner than h_min = 1 s after it. A car arriving at 10 m/s, 15 m behind the
    second one (75 m before the zone), is planned behind the second one's start (standing_start,
    closed form): it cannot keep 12 m (braking from 10 m/s at 3 m/s^2 takes 16.7 m), but its plan
    stays more than half a metre behind it everywhere, where the closed-form plan to the same merge
    time would run into the standing car."""
    from nrtraffic.planning.crossing import CrossingBounds, human_crossing
    from nrtraffic.planning.profiles import fixed_terminal, standing_start

    b = CrossingBounds(2.5, 2.5, 10.0, 10.0, 0.0)
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=12.0, min_merge_headway_s=1.0, terminal_speed="fixed",
                                        conflict_model="conflict_points", policy="batch"), PlanBounds())

    def stand(vid, D, t0):
        offsets, mw, ew, v_exit = human_crossing(b, {}, D, D + 30.0)
        return c.reserve_crossing(vid, "L", "a", t0, offsets, mw, ew, v_exit, start=(D, 2.5, 10.0))

    front = stand("front", 20.0, 5.0)
    back = stand("back", 60.0, 5.0)
    assert front.t_release == pytest.approx(5.0)
    assert back.t_release == pytest.approx(front.t_release + 1.0)
    moving = c.schedule_request(Request("moving", "L", 5.0, 10.0, 75.0, "a", 30.0, 10.0))
    lead = standing_start(5.0, back.t_release, 60.0, 2.5, 10.0)  # independent of the coordinator's copy
    # (12 m is more than the 15 m it has can keep while braking from 10 m/s: the spacing the slowest
    # plan keeps, less half a metre, is its gap)
    t = np.linspace(5.0, moving.t_merge, 2001)
    spacing = lead.evaluate(t)[0] + 15.0 - moving.profile.evaluate(t)[0]
    assert moving.profile.kind == "rear_end" and spacing.min() > 0.5
    free = fixed_terminal(5.0, 10.0, 10.0, 75.0, moving.t_merge - 5.0, PlanBounds())
    assert (lead.evaluate(t)[0] + 15.0 - free.evaluate(t)[0]).min() < 0.0  # (it would run into it)


def test_a_car_close_behind_a_standing_queue_whose_start_is_far_off_is_held_or_kept_behind_it():
    """A car stands 335 m before the zone; cross traffic holds its conflict area for 106 s, so its
    start from rest (2.5 m/s^2 up to 13.89 m/s) is reserved about 80 s on. A car arrives at 4.4 m/s,
    13 m behind it (a standing queue reaching back past the zone entry, past capacity). The
    closed-form plan to its merge time crawls at v_min while the standing car waits: it would run
    tens of metres into it. The coordinator either plans it behind the standing start (never
    within half a metre of it, centre to centre) or refuses it, committing nothing (it is then
    held, stops behind the queue and starts from rest after it); it never hands out a plan that
    runs into the standing car."""
    from nrtraffic.planning.crossing import CrossingBounds, human_crossing
    from nrtraffic.planning.profiles import fixed_terminal, standing_start

    bounds = PlanBounds(v_min_mps=1.0, v_max_mps=13.89, u_min_mps2=-3.0, u_max_mps2=2.5)
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=12.0, min_merge_headway_s=1.0, terminal_speed="fixed",
                                        conflict_model="conflict_points", policy="batch"), bounds)
    c.areas = {("a", "b"): (0.0, 5.0), ("b", "a"): (0.0, 5.0)}
    c.reserve_crossing("cross", "M", "b", 0.0, {"a": (0.0, 106.0)}, (0.0, 0.0), (106.0, 106.0), 13.89)
    b = CrossingBounds(2.5, 2.5, 13.89, 13.89, 0.0)
    offsets, mw, ew, v_exit = human_crossing(b, {"b": (335.3, 340.3)}, 335.3, 365.3)
    stand = c.reserve_crossing("stand", "L", "a", 0.0, offsets, mw, ew, v_exit, start=(335.3, 2.5, 13.89))
    assert stand.t_release > 70.0
    lead = standing_start(0.0, stand.t_release, 335.3, 2.5, 13.89)  # independent of the coordinator's copy
    t0, v0, D = 3.1, 4.36, 348.4
    try:
        got = c.schedule_request(Request("close", "L", t0, v0, D, "a", 30.0, 13.89, hindered=True))
    except ScheduleInfeasible:
        assert c._last_on_lane["L"] is stand  # nothing committed
        t_m = stand.t_merge + 1.0
        free = fixed_terminal(t0, v0, 13.89, D, t_m - t0, bounds)
        t = np.linspace(t0, t_m, 4001)
        assert (lead.evaluate(t)[0] + (D - 335.3) - free.evaluate(t)[0]).min() < -20.0  # (the closed form runs into it)
        return
    t = np.linspace(t0, got.t_merge, 4001)
    assert (lead.evaluate(t)[0] + (D - 335.3) - got.profile.evaluate(t)[0]).min() > 0.5


def test_a_start_from_rest_behind_a_crawling_plan_never_runs_into_it():
    """A car that entered nearly standing (0.05 m/s) 200 m before the zone, planned to its merge time
    behind cross traffic that holds the conflict area for 40 s, and a car standing 7.5 m behind it
    whose start from rest is reserved (2.5 m/s^2 up to a turn's 6.5 m/s). The start that only
    spaces the merge times sets off while the car ahead still crawls, and runs into its plan (by
    tens of metres). The reserved start keeps the standing spacing less half a metre (7 m, below
    delta) behind the plan ahead everywhere, checked on the two profiles (from_rest: closed form)."""
    from nrtraffic.planning.crossing import CrossingBounds, human_crossing
    from nrtraffic.planning.profiles import from_rest

    bounds = PlanBounds(v_min_mps=1.0, v_max_mps=13.89, u_min_mps2=-3.0, u_max_mps2=2.5)
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=12.0, min_merge_headway_s=1.0, terminal_speed="fixed",
                                        conflict_model="conflict_points", policy="batch"), bounds)
    c.areas = {("a", "b"): (0.0, 5.0), ("b", "a"): (0.0, 5.0)}
    c.reserve_crossing("cross", "M", "b", 0.0, {"a": (0.0, 40.0)}, (0.0, 0.0), (40.0, 40.0), 13.89)
    lead = c.schedule_request(Request("crawl", "L", 0.0, 0.05, 200.0, "a", 30.0, 13.89, hindered=True))
    D = 207.5
    b = CrossingBounds(2.5, 2.5, 6.5, 6.5, 0.0)
    offsets, mw, ew, v_exit = human_crossing(b, {}, D, D + 30.0)
    got = c.reserve_crossing("stand", "L", "a", 0.0, offsets, mw, ew, v_exit, start=(D, 2.5, 6.5))

    def spacing(t_start):
        t = np.linspace(t_start, lead.t_merge, 4001)
        return ((D - from_rest(t_start, D, 2.5, 6.5).evaluate(t)[0]) - (200.0 - lead.profile.evaluate(t)[0])).min()

    assert spacing(got.t_release) >= 7.0 - 0.05
    naive = max(lead.t_merge + 1.0 - mw[0], lead.t_exit + 12.0 / max(v_exit, 1.0) - ew[0], 0.0)
    assert spacing(naive) < -10.0  # (spacing the merge times alone: it would run into it)


# ---------------------------------------------------------------- the zone model with starts from rest

def _zone_coordinator():
    s = CoordinatorSettings(rear_end_spacing_m=12.0, min_merge_headway_s=1.0, terminal_speed="fixed")
    assert s.conflict_model == "zone"  # (the paper's, and the default)
    return Coordinator(s, PlanBounds(v_min_mps=1.0, v_max_mps=13.89, u_min_mps2=-3.0, u_max_mps2=2.5),
                       {("a", "b"): CONFLICT, ("b", "a"): CONFLICT},
                       areas={("a", "b"): (10.0, 20.0), ("b", "a"): (12.0, 22.0)})


def _stand(c, vid, lane, movement, t0, D=5.0):
    """A car standing ``D`` m before the zone, its start from rest reserved (2.5 m/s^2 up to 8 m/s);
    its earliest merging-zone entry and latest exit [s], from the crossing's own windows."""
    from nrtraffic.planning.crossing import CrossingBounds, human_crossing

    other = "b" if movement == "a" else "a"
    lo, hi = c.areas[(movement, other)]
    offsets, mw, ew, v_exit = human_crossing(CrossingBounds(2.5, 2.5, 8.0, 8.0, 0.0), {other: (D + lo, D + hi)}, D,
                                             D + 30.0)
    a = c.reserve_crossing(vid, lane, movement, t0, offsets, mw, ew, v_exit, start=(D, 2.5, 8.0))
    return a, a.t_release + mw[0], a.t_release + ew[1]


def test_zone_model_a_start_from_rest_waits_until_the_steered_cross_flow_has_left_the_zone():
    """Under the zone model no two vehicles of conflicting movements are in the merging zone at once
    (eq. 6 of the paper). A car planned through the zone on movement a (10 m/s, 100 m out, 30 m of
    zone: in it from 10 s to 13 s), then a car standing 5 m before the zone on movement b, whose
    start from rest is reserved at 2 s: it enters the zone no sooner than the first has left it."""
    c = _zone_coordinator()
    steered = c.schedule_request(Request("s", "La", 0.0, 10.0, 100.0, "a", 30.0, 10.0))
    assert steered.t_merge == pytest.approx(10.0) and steered.t_exit == pytest.approx(13.0)
    start, enter, leave = _stand(c, "r", "Lb", "b", 2.0)
    assert enter >= steered.t_exit - 1e-9
    assert start.binding == "conflict" and start.predecessor == "s"


def test_zone_model_a_car_planned_after_a_reserved_start_enters_once_it_has_left():
    """The other way round: the standing car's start is reserved first (at 2 s, no one in its way),
    then a car on the conflicting movement is planned (10 m/s, 100 m out at -5 s: free, it would merge at
    5 s, while the first may still be in the zone): its merge time is no sooner than the latest exit
    the reserved start allows."""
    c = _zone_coordinator()
    start, enter, leave = _stand(c, "r", "Lb", "b", 2.0)
    assert start.t_release == pytest.approx(2.0) and enter < 5.0 < leave
    steered = c.schedule_request(Request("s", "La", -5.0, 10.0, 100.0, "a", 30.0, 10.0))  # (free: at 5 s)
    assert steered.t_merge >= leave - 1e-9 and steered.predecessor == "r"


def test_zone_model_a_cancelled_start_leaves_the_steered_car_ahead_of_it_in_the_way():
    """A car planned through the zone on movement a (in it until 13 s), a car standing behind it on
    its lane whose start is reserved after it, then cancelled (its exit was queued): a car on the
    conflicting movement planned next still waits for the first one to leave the zone."""
    c = _zone_coordinator()
    first = c.schedule_request(Request("s", "La", 0.0, 10.0, 100.0, "a", 30.0, 10.0))
    _stand(c, "r", "La", "a", 2.0, D=60.0)
    c.cancel("r")
    later = c.schedule_request(Request("x", "Lb", 0.0, 13.0, 150.0, "b", 30.0, 13.0))  # (free: at 11.5 s)
    assert later.t_merge >= first.t_exit - 1e-9 and later.predecessor == "s"
