"""Mixed traffic (demand.controlled_share, README: Mixed traffic): the shares drawn by seed, the
bounds of a human driver's start from rest against SUMO's own driver, the reservation of a crossing
against the coordinator's rule, and a mixed run on cross4."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from nrtraffic import scenario
from nrtraffic.demand import Demand
from nrtraffic.engine import Engine
from nrtraffic.planning.coordinator import Coordinator, CoordinatorSettings, ScheduleInfeasible
from nrtraffic.planning.crossing import CrossingBounds, KraussBounds, human_crossing, speed_from_rest, travel_time
from nrtraffic.planning.profiles import PlanBounds, from_rest
from nrtraffic.scenario import ScenarioError
from nrtraffic.sumo.adapter import SumoSession, VehicleType, write_routes

CROSS4 = Path(__file__).resolve().parents[1] / "sumo_scenarios" / "cross4"


def _demand(share, seed=3, duration=600.0):
    sc = scenario.load(CROSS4, [f"demand.controlled_share={share}", f"scenario.duration_s={duration}"])
    return Demand.of(sc, seed=seed).departures()


def test_shares_are_drawn_by_seed_and_nested():
    runs = {share: _demand(share) for share in (0.0, 0.25, 0.5, 1.0)}
    # the arrivals themselves do not depend on the share
    base = [v[:5] for v in runs[1.0]]
    for d in runs.values():
        assert [v[:5] for v in d] == base
    humans = {share: {v[0] for v in d if v[5] == "human"} for share, d in runs.items()}
    assert humans[1.0] == set() and humans[0.0] == {v[0] for v in base}
    assert humans[0.5] <= humans[0.25] <= humans[0.0]  # controlled at one share, controlled above it
    assert _demand(0.5) == runs[0.5]  # reproducible for its seed
    assert _demand(0.5, seed=4) != runs[0.5]
    # the realised share of 0.25 controlled: a binomial draw, within 4 standard deviations
    n = len(base)
    k = n - len(humans[0.25])
    assert abs(k - 0.25 * n) < 4 * math.sqrt(n * 0.25 * 0.75)


def test_travel_time_closed_form_and_derivative():
    a, v_cap = 2.0, 10.0
    assert travel_time(9.0, a, v_cap) == pytest.approx(3.0)  # 1/2 a t^2 = 9
    # past the cap: 25 m to reach it in 5 s, then cruise
    assert travel_time(45.0, a, v_cap) == pytest.approx(5.0 + 20.0 / 10.0)
    for d in (1.0, 10.0, 24.9, 25.1, 60.0):  # dT/dd is 1 / speed there
        h = 1e-6
        dT = (travel_time(d + h, a, v_cap) - travel_time(d - h, a, v_cap)) / (2 * h)
        assert dT == pytest.approx(1.0 / speed_from_rest(d, a, v_cap), rel=1e-5)
    # on the move (a reservation refreshed as the driver crosses): 4 m/s, 10 m -> 4 t + t^2 = 10
    assert travel_time(10.0, a, v_cap, v0=4.0) == pytest.approx(-2.0 + math.sqrt(14.0))
    assert travel_time(30.0, a, v_cap, v0=12.0) == pytest.approx(3.0)  # above the cap: no later than at it
    assert travel_time(10.0, a, v_cap, v0=4.0) < travel_time(10.0, a, v_cap)
    prof = from_rest(2.0, 30.0, a, v_cap)  # the controlled vehicle's plan from the stop line
    p, v, u = prof.evaluate(2.0 + travel_time(30.0, a, v_cap))
    assert float(p) == pytest.approx(30.0) and float(v) == pytest.approx(10.0)
    assert prof.t_m == pytest.approx(2.0 + travel_time(30.0, a, v_cap))


def _released_from_the_stop(tmp_path, seed, sigma, followers=(), headway_s=1.0, lead_route="ws"):
    """Humans of the given sigma queued on cross4's west approach, the first standing at a stop
    on W_in, the others (routes ``followers``) behind it, held; the first is released, each
    follower ``headway_s`` after the one ahead (its stop dropped). Returns, per vehicle, its
    route, speed factor and (time since its release [s], distance covered [m]) at each step."""
    net = CROSS4 / "net.net.xml"
    routes = tmp_path / "r.rou.xml"
    human = VehicleType("human", 4.8, 1.9, 2.5, 2.6, 4.5, 13.89, sigma=sigma, tau_s=1.0)
    names = [lead_route, *followers]
    vehicles = [(f"h{i}", r, 2.0 * i, 13.89, -1.0, "human") for i, r in enumerate(names)]
    write_routes(routes, [VehicleType(), human], {"ws": ("W_in", "E_out"), "wr": ("W_in", "S_out")}, vehicles)
    h = 0.1
    with SumoSession(net, routes, h, seed) as sumo:
        v = sumo.traci.vehicle
        for _ in range(1200):
            sumo.step()
            for vid in sumo.departed():
                sumo.stop_at(vid, "W_in_0", 480.0)
            ids = v.getIDList()
            if len(ids) == len(names) and sumo.is_stopped("h0") and all(v.getSpeed(x) < 0.01 for x in ids):
                break
        assert sumo.is_stopped("h0") and len(v.getIDList()) == len(names)
        for _ in range(20):  # stands a while
            sumo.step()
        start = {x: v.getDistance(x) for x in v.getIDList()}
        factor = {x: sumo.speed_factor(x) for x in start}
        for x in start:
            if x != "h0":
                v.setSpeed(x, 0.0)
        t_rel = {"h0": sumo.time}
        sumo.resume("h0")
        track = {x: [] for x in start}
        for _ in range(300):
            for i in range(1, len(names)):
                x = f"h{i}"
                ahead = t_rel.get(f"h{i - 1}")
                if x not in t_rel and ahead is not None and sumo.time >= ahead + headway_s - 1e-9:
                    t_rel[x] = sumo.time
                    sumo.cancel_stop(x)
                    v.setSpeed(x, -1)
            sumo.step()
            here = set(v.getIDList())
            for x in start:
                if x in here and x in t_rel:
                    track[x].append((sumo.time - t_rel[x], v.getDistance(x) - start[x]))
    return {f"h{i}": (r, factor[f"h{i}"], np.array(track[f"h{i}"]).T) for i, r in enumerate(names)}


def _within(bounds, t, d, up_to_m, slack_s=0.0):
    """Each whole metre up to ``up_to_m`` covered no earlier than the bounds' earliest and no later
    than their latest (+ ``slack_s``)."""
    assert d[-1] > up_to_m
    for dist in np.arange(1.0, up_to_m, 1.0):
        reached = t[np.argmax(d >= dist)]  # the step at the end of which it has covered dist
        t_in, t_out = bounds.window(dist, dist)
        assert t_in - 1e-9 <= reached <= t_out + slack_s + 1e-9, (dist, reached, t_in, t_out)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_sumo_human_start_from_rest_lies_within_the_bounds(tmp_path, seed):
    """SUMO's Krauss driver (sigma 0.5) stops on cross4's west approach, is released, and goes
    straight across: the time it takes to cover every distance lies between the constant-
    acceleration bounds, and between the tighter bounds of Krauss's own speed update that the
    reservation uses."""
    (_, factor, (t, d)), = _released_from_the_stop(tmp_path, seed, 0.5).values()
    h = 0.1
    _within(CrossingBounds(0.5 * 2.6, 2.6, 13.89 * min(1.0, factor), 13.89, h), t, d, 60.0, slack_s=h)
    _within(KraussBounds(2.6, 0.5, 13.89 * min(1.0, factor), 13.89, h), t, d, 60.0)
    # the Krauss bounds are the tighter: half a second less at 15 m, as SUMO dawdles little below
    # 2.6 m/s
    k, c = KraussBounds(2.6, 0.5, 13.89, 13.89, h).window(15.0, 15.0), CrossingBounds(1.3, 2.6, 13.89, 13.89, h).window(15.0, 15.0)
    assert k[1] < c[1] - 0.4


def test_sumo_driver_without_dawdling_follows_the_krauss_update_to_the_step(tmp_path):
    """sigma 0: SUMO's driver is deterministic, and covers every distance in exactly the step the
    stepped Krauss update says (the earliest bound is that step less the one step of slack)."""
    (_, _, (t, d)), = _released_from_the_stop(tmp_path, 1, 0.0).values()
    b = KraussBounds(2.6, 0.0, 13.89, 13.89, 0.1)
    _within(b, t, d, 80.0)
    for dist in np.arange(1.0, 80.0, 1.0):
        reached = t[np.argmax(d >= dist)]
        assert reached == pytest.approx(b.window(dist, dist)[0] + 0.1, abs=1e-6), dist


@pytest.mark.parametrize("seed", [1, 2])
def test_a_queue_released_as_a_platoon_keeps_each_drivers_bounds(tmp_path, seed):
    """Three human drivers queued at the stop: the first turns right (slow), the two behind go
    straight, each released a second after the one ahead. Each covers every distance within its
    Krauss bounds, a follower's latest capped by its leader's speed limit (the rule of
    ``humans.human_bounds``): the car ahead does not hold it back beyond them."""
    runs = _released_from_the_stop(tmp_path, seed, 0.5, followers=("ws", "ws"), lead_route="wr")
    v_turn = 6.5075  # the speed limit of cross4's right turn (its internal lane :C_9_0)
    for _, factor, (t, d) in runs.values():
        v_lo = v_turn * min(1.0, factor)  # the leader's cap (its own, or inherited)
        _within(KraussBounds(2.6, 0.5, v_lo, 13.89, 0.1), t, d, 35.0)


def _coordinator():
    settings = CoordinatorSettings(terminal_speed="fixed", conflict_model="conflict_points", conflict_margin_s=1.0)
    # movement a crosses b: on a's path the shared area is 10-16 m into the zone, on b's 4-12 m
    areas = {("a", "b"): (10.0, 16.0), ("b", "a"): (4.0, 12.0)}
    return Coordinator(settings, PlanBounds(v_min_mps=1.0, v_max_mps=14.0, u_min_mps2=-3.0, u_max_mps2=2.5),
                       areas=areas)


def test_crossing_waits_for_a_reserved_vehicle_and_is_respected():
    c = _coordinator()
    # b: a steered vehicle entering the zone at t = 20 s at 10 m/s: in the shared area 20.4-21.2 s
    asg_b = c.schedule("b1", "lane_b", t0=0.0, v0=10.0, D=200.0, movement="b", zone_length_m=30.0, v_limit=10.0)
    assert asg_b.t_merge == pytest.approx(20.0)
    # a human on a, standing 3 m before the zone, asking at t = 19 s
    bounds = CrossingBounds(1.3, 2.6, 10.0, 14.0, 0.1)
    offsets, merge_w, exit_w, v_exit = human_crossing(bounds, {"b": (13.0, 19.0)}, 3.0, 33.0)
    asg = c.reserve_crossing("h1", "lane_a", "a", 19.0, offsets, merge_w, exit_w, v_exit)
    # it may only start once its earliest entry comes a margin after b has left: the closed form
    t_free = 20.0 + 12.0 / 10.0 + 1.0 - offsets["b"][0]
    assert asg.t_release == pytest.approx(t_free)
    assert asg.predecessor == "b1" and asg.relation == "conflict"
    assert asg.t_merge == pytest.approx(t_free + merge_w[1])
    # a steered vehicle on b asking later must clear the human's latest exit of the area + margin
    asg_b2 = c.schedule("b2", "lane_b", t0=19.5, v0=10.0, D=50.0, movement="b", zone_length_m=30.0, v_limit=10.0)
    h_in, h_out = asg.occupancy["b"]
    b_in, b_out = asg_b2.t_merge + 4.0 / 10.0, asg_b2.t_merge + 12.0 / 10.0
    assert b_in >= h_out + 1.0 - 1e-9 or b_out + 1.0 <= h_in + 1e-9
    assert asg_b2.predecessor == "h1" and asg_b2.binding == "conflict"  # (unhindered it would come at 24.5 s)


def test_a_waiting_crossing_starts_as_soon_as_the_one_before_it_has_shrunk():
    """A human driver's crossing reserved behind another's occupancy of their shared area starts
    sooner once that occupancy has shrunk (as it does while the other drives across faster than
    its slowest): at the closed-form first free time, never before ``t_min``; the margin between
    two human drivers is their own, between a human driver and a controlled vehicle theirs and the
    controlled vehicle's lateness allowance."""
    c = _coordinator()
    c.human_margin_s = 0.2
    assert c.margin_between(True, True) == 0.2
    # a human driver and a controlled vehicle: the humans' margin and the controlled vehicle's own
    # lateness allowance where human drivers take part (0.1 s: half the coordinator's margin, 1 s
    # here, where only controlled vehicles take part)
    assert c.settings.late_tolerance_s() == 0.5 and c.settings.late_tolerance_s(mixed=True) == 0.1
    assert c.margin_between(True, False) == c.margin_between(False, True) == pytest.approx(0.2 + 0.1)
    assert c.margin_between(False, False) == 1.0
    bounds = CrossingBounds(1.3, 2.6, 10.0, 14.0, 0.1)
    off_b, mw_b, ew_b, v_b = human_crossing(bounds, {"a": (5.0, 12.0)}, 0.0, 30.0)
    first = c.reserve_crossing("h_b", "lane_b", "b", 10.0, off_b, mw_b, ew_b, v_b, driven_by_sumo=True)
    off_a, mw_a, ew_a, v_a = human_crossing(bounds, {"b": (13.0, 19.0)}, 3.0, 33.0)
    second = c.reserve_crossing("h_a", "lane_a", "a", 10.5, off_a, mw_a, ew_a, v_a, driven_by_sumo=True)
    b_out = first.occupancy["a"][1]
    assert second.t_release == pytest.approx(b_out + 0.2 - off_a["b"][0])  # (the human drivers' margin)
    assert c.advance("h_a", 10.5) is None  # nothing has changed
    # the first driver is on its way, faster than its slowest: its occupancy of the area ends 0.5 s sooner
    first.occupancy["a"] = (first.occupancy["a"][0], b_out - 0.5)
    moved = c.advance("h_a", 10.5)
    assert moved.t_release == pytest.approx(b_out - 0.5 + 0.2 - off_a["b"][0]) and moved.t_release > 10.5
    assert moved.t_exit - moved.t_release == pytest.approx(second.t_exit - second.t_release)
    assert moved.occupancy["b"][0] - moved.t_release == pytest.approx(off_a["b"][0])
    assert c.last_on_lane("lane_a") is moved
    first.occupancy["a"] = (first.occupancy["a"][0], 0.0)  # spent: it may start at once, not before t_min
    assert c.advance("h_a", 10.6).t_release == pytest.approx(10.6)


def test_mixed_traffic_settings_are_checked():
    with pytest.raises(ScenarioError, match="controlled_share"):
        scenario.load(CROSS4, ["demand.controlled_share=1.5"])
    with pytest.raises(ScenarioError, match="conflict_points"):
        scenario.load(CROSS4, ["demand.controlled_share=0.5", 'coordinator.conflict_model="zone"',
                               'coordinator.policy="fifo"', 'coordinator.terminal_speed="free"'])
    with pytest.raises(ScenarioError, match="human.sigma"):
        scenario.load(CROSS4, ["human.sigma=1.0"])
    with pytest.raises(ScenarioError, match="unknown key human.reaction"):
        scenario.load(CROSS4, ["human.reaction=1.0"])


@pytest.fixture(scope="module")
def mixed_run(tmp_path_factory):
    """cross4 at half penetration for 300 s, with every reserved crossing recorded."""
    out = tmp_path_factory.mktemp("mixed")
    sc = scenario.load(CROSS4, ["demand.controlled_share=0.5", "outputs.warmup_s=0"])
    reserved = {}
    original = Coordinator.reserve_crossing

    def record(self, vehicle_id, *args, **kwargs):
        asg = original(self, vehicle_id, *args, **kwargs)
        if asg is not None:  # (None: a driver that could not go on without stopping, not reserved)
            reserved[vehicle_id] = asg
        return asg

    advance = Coordinator.advance

    def record_advance(self, vehicle_id, *args, **kwargs):  # (a start moved sooner: its new latest exit)
        asg = advance(self, vehicle_id, *args, **kwargs)
        if asg is not None:
            reserved[vehicle_id] = asg
        return asg

    from nrtraffic.junction import yielding

    put_back = yielding.restore
    replan, schedule = yielding.replan_behind, Coordinator.schedule_request
    infeasible = [0]  # (plans that could not be made again)
    gave_way = []  # (whether a vehicle could not be planned again, whether the others gave way)

    def record_schedule(self, *args, **kwargs):
        try:
            return schedule(self, *args, **kwargs)
        except ScheduleInfeasible:
            infeasible[0] += 1
            raise

    def record_replan(st, junction, reserve_first):
        before = infeasible[0]
        done = replan(st, junction, reserve_first)
        gave_way.append((infeasible[0] > before, done))
        return done

    def record_restore(coord, saved):  # (a crossing reserved again for nothing: the one before holds)
        put_back(coord, saved)
        for asg in saved[0]:
            if asg.occupancy is not None:
                reserved[asg.vehicle_id] = asg

    Coordinator.reserve_crossing = record
    Coordinator.advance = record_advance
    yielding.restore = record_restore
    yielding.replan_behind = record_replan
    Coordinator.schedule_request = record_schedule
    try:
        res = Engine(sc, out, seed=2, duration_s=300.0).run()
    finally:
        Coordinator.reserve_crossing = original
        Coordinator.advance = advance
        yielding.restore = put_back
        yielding.replan_behind = replan
        Coordinator.schedule_request = schedule
    res.gave_way = gave_way
    return res, sc, reserved


def test_mixed_run_is_safe_and_keeps_its_reservations(mixed_run):
    res, sc, reserved = mixed_run
    s, v = res.summary, res.vehicles
    assert s["status"] == "ok"
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert set(v["driver"]) == {"automated", "human"}
    assert s["vehicles_automated"] + s["vehicles_human"] == s["vehicles_admitted"]
    crossed = v[(v["driver"] == "human") & v["t_merge_actual_s"].notna()]
    assert len(crossed) > 10
    # every vehicle whose crossing was reserved (humans, and controlled ones starting from the
    # stop line) left the merging zone after its release and no later than the latest exit its
    # reservation promised, which the others were scheduled around
    done = v.set_index("vehicle_id").loc[[k for k in reserved if k in set(v["vehicle_id"])]]
    done = done[done["t_exit_s"].notna()]
    assert len(done) > 10 and set(done["driver"]) == {"automated", "human"}
    latest = done.index.map(lambda k: reserved[k].t_exit)
    assert (done["t_exit_s"] <= latest + 1e-6).all()
    assert (done["t_exit_s"] > done["t_release_s"]).all()
    # controlled vehicles: the barrier's distance to the vehicle ahead (humans included) held
    ctl = v[(v["driver"] == "automated") & v["min_center_distance_m"].notna()]
    d0 = sc.barriers.min_gap_m + sc.vehicle.params().length
    assert len(ctl) > 10 and (ctl["min_center_distance_m"] >= d0 - 0.05).all()
    assert set(ctl["profile"]) >= {"from_rest"}  # some queued behind a human and started from the line


def test_mixed_run_writes_the_human_bodies(mixed_run):
    res, _, _ = mixed_run
    doc = json.loads((res.run_dir / "movements.json").read_text())
    assert doc["conflict_areas_human"]
    assert all(a["movement"] in doc["movements"] for a in doc["conflict_areas"])


def test_controlled_vehicles_that_gave_way_keep_their_new_plans(mixed_run):
    """In the half-automated run, controlled vehicles still far from their merging zone gave way
    to crossings from rest that would otherwise have started late (nrtraffic.junction.yielding):
    each entered its merging zone when its last plan said."""
    res, _, _ = mixed_run
    v = res.vehicles
    moved = v[(v["driver"] == "automated") & (v["replans"] > 0) & v["t_merge_actual_s"].notna()]
    assert len(moved) > 5
    assert ((moved["t_merge_actual_s"] - moved["t_merge_planned_s"]).abs() < 0.3).all()


def test_controlled_vehicles_enter_their_merging_zone_within_their_lateness_allowance(mixed_run):
    """The margin between a human driver's and a controlled vehicle's occupancy is the humans'
    margin plus the controlled vehicle's lateness allowance only (Coordinator.margin_between):
    that rests on every controlled vehicle entering its merging zone never early and no later
    than the allowance after its last plan, measured here from where the run saw it enter."""
    res, sc, _ = mixed_run
    v = res.vehicles
    ctl = v[(v["driver"] == "automated") & v["t_merge_actual_s"].notna()]
    late = ctl["t_merge_actual_s"] - ctl["t_merge_planned_s"]
    assert len(ctl) > 20
    assert late.min() >= -sc.sumo.step_length_s and late.max() <= sc.coordinator.late_tolerance_s(mixed=True)


def test_controlled_vehicles_give_way_a_bounded_number_of_times(mixed_run):
    """Controlled vehicles far out were planned again to let crossings from rest start sooner
    (nrtraffic.junction.yielding), also where one of them could not be planned again (it kept its
    plan, the others gave way without it); and no controlled vehicle gave way more than
    MAX_REPLANS times (none waits without end behind the crossings that come after it)."""
    from nrtraffic.junction.yielding import MAX_REPLANS

    res, _, _ = mixed_run
    assert sum(done for _, done in res.gave_way) > 2
    assert (True, True) in res.gave_way
    v = res.vehicles
    assert (v.loc[v["driver"] == "automated", "replans"] <= MAX_REPLANS).all()
    assert (v.loc[v["replans"] > 0, "driver"] == "automated").all()
