"""Intersections: conflict classification, the coordinator with conflicts, a recorded cross4 run,
and the baselines' delay against SUMO's timeLoss."""

import json

import numpy as np
import pandas as pd
import pytest

from nrtraffic import scenario
from nrtraffic.planning.conflicts import CONFLICT
from nrtraffic.planning.coordinator import Coordinator, CoordinatorSettings
from nrtraffic.planning.profiles import PlanBounds
from runners.baseline import run_baseline
from runners.single import run_scenario

X, DOT, L = "conflict", "compatible", "same_lane"

# Hand-made, from the geometry of right-hand traffic (not from the code): opposite straights pass
# each other, right turns never meet, crossings and merges conflict. (Opposing left turns pass or
# touch depending on the junction's internal geometry; SUMO's own logic decides them in the next
# test.)
CROSS4_TABLE = {
    ("E_in.straight", "W_in.straight"): DOT, ("N_in.straight", "S_in.straight"): DOT,
    ("E_in.straight", "N_in.straight"): X, ("E_in.straight", "S_in.straight"): X,
    ("W_in.straight", "N_in.straight"): X, ("W_in.straight", "S_in.straight"): X,
    ("E_in.left", "N_in.left"): X, ("E_in.left", "S_in.left"): X,
    ("E_in.right", "N_in.right"): DOT, ("E_in.right", "W_in.right"): DOT, ("N_in.right", "S_in.right"): DOT,
    ("E_in.straight", "N_in.right"): X,  # both onto W_out
    ("E_in.straight", "S_in.left"): X,  # both onto W_out
    ("E_in.straight", "N_in.left"): X,  # the left turn crosses it
    ("E_in.straight", "S_in.right"): DOT, ("E_in.straight", "W_in.right"): DOT,
    ("E_in.right", "W_in.straight"): DOT,
    ("E_in.straight", "E_in.left"): L, ("N_in.right", "N_in.left"): L, ("S_in.straight", "S_in.right"): L,
}
TEE3_TABLE = {
    ("E_in.straight", "W_in.straight"): DOT,
    ("E_in.straight", "S_in.left"): X,  # both onto W_out
    ("E_in.left", "W_in.straight"): X,  # crosses
    ("W_in.right", "E_in.straight"): DOT,
    ("S_in.right", "W_in.straight"): X,  # both onto E_out
    ("E_in.left", "W_in.right"): X,  # both onto S_out
    ("S_in.right", "E_in.straight"): DOT,
    ("E_in.straight", "E_in.left"): L, ("S_in.left", "S_in.right"): L,
}


@pytest.fixture(scope="module")
def cross4_run(tmp_path_factory):
    from conftest import SCENARIOS

    sc = scenario.load(SCENARIOS / "cross4" / "scenario.toml",
                       ["scenario.duration_s=150.0", "demand.end_s=70.0"])
    out = tmp_path_factory.mktemp("cross4") / "run"
    return run_scenario(sc, out), out


def _relations(name, tmp_path_factory, overrides=()):
    from conftest import SCENARIOS

    sc = scenario.load(SCENARIOS / name / "scenario.toml", ["scenario.duration_s=0.5", *overrides])
    out = tmp_path_factory.mktemp(name)
    run_scenario(sc, out)
    return json.loads((out / "movements.json").read_text())


@pytest.mark.parametrize("name,table", [("cross4", CROSS4_TABLE), ("tee3", TEE3_TABLE)])
def test_conflict_classification_matches_the_hand_made_table(name, table, tmp_path_factory):
    """The tables say which bodies touch, so they are checked without the clearance band: with the
    bodies turning as they do (README, Intersections: Relations), a right turn's corner comes
    within cross4's 0.25 m band of the right turn from its left and of the straight from its
    right, which then conflict there."""
    doc = _relations(name, tmp_path_factory, ["junction.lateral_clearance_m=0"])
    rel = doc["relations"]
    for (a, b), expected in table.items():
        assert rel[a][b] == expected, (a, b)
        assert rel[b][a] == expected  # symmetric


@pytest.mark.parametrize("name", ["cross4", "cross4_2lane"])
def test_conflict_classification_agrees_with_sumo_junction_logic(name, tmp_path_factory):
    """SUMO's own foe links as an independent reference, lane by lane: every pair of movements
    whose junction-internal lanes SUMO calls foes conflicts here. The swept-body rule is stricter
    (SUMO lets cars pass closely at an angle): a pair it adds must at least come close enough on
    SUMO's own internal lanes for two widened bodies to touch (centre distance below the diagonal
    of length x (width + 2 clearance)). On cross4_2lane the movements are per lane (two straight
    lanes, a left-turn lane), so this also checks the lane-level movements' internal lanes."""
    import libsumo

    from conftest import SCENARIOS
    from nrtraffic.planning.conflicts import min_distance
    from nrtraffic.sumo.adapter import SumoSession, VehicleType, write_routes

    doc = _relations(name, tmp_path_factory)
    mv, rel = doc["movements"], doc["relations"]
    sc = scenario.load(SCENARIOS / name / "scenario.toml")
    reach = float(np.hypot(4.8, 1.9 + 2 * sc.junction.lateral_clearance_m))
    net = SCENARIOS / name / "net.net.xml"
    tmp = tmp_path_factory.mktemp("foes")
    routes = tmp / "r.rou.xml"
    write_routes(routes, VehicleType(), {k.replace(".", "-"): tuple(v["route"]) for k, v in mv.items()}, [])
    with SumoSession(net, routes, 0.1, 1):
        internal = {k: [ln for ln in v["lanes"] if ln.startswith(":")] for k, v in mv.items()}
        for k, v in mv.items():  # each movement's lanes are a chain of SUMO's own links
            for a, b in zip(v["lanes"], v["lanes"][1:]):
                assert b in {link[0] for link in libsumo.lane.getLinks(a)} | {link[4] for link in
                                                                               libsumo.lane.getLinks(a)}, (k, a, b)
        shapes = {k: np.concatenate([np.array(libsumo.lane.getShape(ln)) for ln in lns])
                  for k, lns in internal.items()}
        owner = {ln: k for k, lns in internal.items() for ln in lns}
        foes = {k: {owner[f] for ln in lns for f in libsumo.lane.getInternalFoes(ln) if f in owner}
                for k, lns in internal.items()}
    stricter = pairs = 0
    for a in mv:
        for b in mv:
            if a >= b or rel[a][b] == L:
                continue
            pairs += 1
            sumo_foe = b in foes[a] or a in foes[b]
            if sumo_foe:
                assert rel[a][b] == CONFLICT, (a, b)
            elif rel[a][b] == CONFLICT:
                assert min_distance(shapes[a], shapes[b]) < reach, (a, b)
                stricter += 1
    assert stricter <= 0.3 * pairs  # cross4: 13 of 66


def test_lane_level_movements_follow_sumo_connections(tmp_path_factory):
    """cross4_2lane's movements are SUMO's lane-to-lane connections (libsumo's links, an
    independent read of the network): lane 0 turns right or goes straight, lane 1 goes straight,
    lane 2 turns left; a vehicle's lane serves its turn, and SUMO's own trip record puts it on
    that lane at departure."""
    import libsumo

    from conftest import SCENARIOS
    from nrtraffic.sumo.adapter import SumoSession, VehicleType, write_routes
    from nrtraffic.sumo.network import TURNS

    doc = _relations("cross4_2lane", tmp_path_factory)
    mv = doc["movements"]
    got = {(v["lanes"][0], v["turn"]) for v in mv.values()}
    tmp = tmp_path_factory.mktemp("links")
    write_routes(tmp / "r.rou.xml", VehicleType(), {}, [])
    with SumoSession(SCENARIOS / "cross4_2lane" / "net.net.xml", tmp / "r.rou.xml", 0.1, 1):
        want = {(f"{appr}_in_{k}", TURNS[link[6]]) for appr in "NESW" for k in range(3)
                for link in libsumo.lane.getLinks(f"{appr}_in_{k}")}
    assert got == want
    assert {t for ln, t in got if ln == "N_in_0"} == {"right", "straight"}
    assert {t for ln, t in got if ln == "N_in_1"} == {"straight"}
    assert {t for ln, t in got if ln == "N_in_2"} == {"left"}
    # a short run: every vehicle on a lane that serves its turn, as SUMO inserted it
    from xml.etree import ElementTree as ET

    sc = scenario.load(SCENARIOS / "cross4_2lane" / "scenario.toml", ["scenario.duration_s=90.0"])
    out = tmp_path_factory.mktemp("run2l") / "run"
    run_scenario(sc, out)
    v = pd.read_csv(out / "vehicles.csv")
    assert len(v) > 50
    assert all((lane, turn) in got for lane, turn in zip(v["lane"], v["movement"]))
    assert set(v.loc[v["movement"] == "straight", "lane"].str[-1]) == {"0", "1"}  # both straight lanes used
    depart_lane = {t.get("id"): t.get("departLane") for t in ET.parse(out / "tripinfo.xml").getroot()}
    seen = [(depart_lane[i], ln) for i, ln in zip(v["vehicle_id"], v["lane"]) if i in depart_lane]
    assert seen and all(a == b for a, b in seen)
    s = json.loads((out / "summary.json").read_text())
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0


def test_edge_of_a_lane_is_sumolibs():
    """``edge_of`` against sumolib's own lane -> edge map, over every lane of a public network
    (edge ids with '_' and '#', internal lanes included)."""
    import sumolib

    from conftest import SCENARIOS
    from nrtraffic.sumo.network import edge_of

    net = sumolib.net.readNet(str(SCENARIOS / "bologna_pasubio" / "net.net.xml"), withInternal=True)
    lanes = [ln for e in net.getEdges(withInternal=True) for ln in e.getLanes()]
    assert any(ln.getID().startswith(":") for ln in lanes) and any("_" in e.getID() for e in net.getEdges())
    assert all(edge_of(ln.getID()) == ln.getEdge().getID() for ln in lanes)


def test_coordinator_with_conflicts_by_hand():
    rel = {("A", "B"): CONFLICT, ("B", "A"): CONFLICT}
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=12.0, min_merge_headway_s=1.0), PlanBounds(v_max_mps=20.0),
                    rel)
    v, D, S = 13.4, 400.0, 30.0
    a1 = c.schedule("a1", "lane_A", 0.0, v, D, "A", S)
    b1 = c.schedule("b1", "lane_B", 1.0, v, D, "B", S)
    a2 = c.schedule("a2", "lane_A", 2.0, v, D, "A", S)
    # by hand: a1 free; b1 waits for a1 to leave the zone; a2 waits for b1 to leave
    t_a1 = D / v
    assert a1.t_merge == pytest.approx(t_a1)
    exit_a1 = t_a1 + S / v
    assert b1.t_merge == pytest.approx(exit_a1) and b1.binding == "conflict" and b1.predecessor == "a1"
    vm_b1 = (3 * D / (exit_a1 - 1.0) - v) / 2
    exit_b1 = exit_a1 + S / vm_b1
    assert a2.t_merge == pytest.approx(exit_b1) and a2.relation == "conflict"
    # the same-lane rule binds when the conflicting vehicle is long gone
    a3 = c.schedule("a3", "lane_A", 3.0, v, D, "A", S)
    vm2 = a2.profile.v_m
    assert vm2 == pytest.approx((3 * D / (exit_b1 - 2.0) - v) / 2)
    exit_a2 = exit_b1 + S / vm2
    assert a3.t_merge == pytest.approx(max(3.0 + D / v, exit_b1 + max(1.0, 12.0 / vm2),
                                           exit_a2 + 12.0 / vm2 - S / 20.0))
    assert a3.binding == "rear_end"
    # a turn slower than the entry speed: fixed-terminal profile to the turn speed, the earliest
    # arrival cruising at the entry speed and braking on the arc whose deceleration peaks at 3 m/s^2
    t1 = c.schedule("t1", "lane_T", 50.0, v, D, "T", 25.0, v_limit=6.5)
    assert t1.profile.v_m == pytest.approx(6.5) and t1.profile.kind.startswith("fixed_speed")
    s_arc = 2 * (v - 6.5) / 3.0
    assert t1.t_merge == pytest.approx(50.0 + (D + s_arc * (v - 6.5) / 3.0) / v)
    _, _, u = t1.profile.evaluate(np.linspace(50.0, t1.t_merge - 1e-9, 5001))
    assert u.min() >= -3.0 - 1e-9 and t1.binding == "earliest"


def test_recorded_run_keeps_conflicting_vehicles_apart(cross4_run):
    """Every two vehicles of conflicting movements held their shared conflict area at times at
    least the margin apart, by the times they actually entered the merging zone (the zone is
    crossed at the planned constant speed)."""
    from conftest import conflict_gaps

    res, out = cross4_run
    assert res.vehicles["t_exit_s"].notna().sum() > 20
    gaps, margin = conflict_gaps(out)
    for _, a, b, gap in gaps:
        assert gap > margin - 0.1, (a, b, gap)  # > 0: held one after the other
    assert len(gaps) > 20


def test_short_cross4_run_is_safe_and_complete(cross4_run):
    res, out = cross4_run
    s = res.summary
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0
    veh = res.vehicles
    admitted = veh[veh["t_enter_s"].notna()]
    assert len(admitted) > 20
    assert admitted["t_exit_s"].notna().all()  # every admitted vehicle left the merging zone
    assert (admitted["min_bumper_gap_m"].dropna() > 0).all()
    # planned merge times are met
    assert (admitted["t_merge_actual_s"] - admitted["t_merge_planned_s"]).abs().max() < 0.3
    # turning vehicles crossed the zone at their turn speed: tracking stays close
    assert s["max_lateral_dev_m"] <= 0.5


@pytest.mark.parametrize("junction", ["traffic_light", "allway_stop"])
def test_baseline_delay_agrees_with_sumo_time_loss(junction, tmp_path):
    """Our delay (control-zone entry to merging-zone exit, against the entry speed = the lane
    limit) against SUMO's timeLoss (whole route, against the lane limit): for straight-through
    vehicles, which lose no time outside the window, they agree within 1 s per vehicle on the
    median and 0.5 s on the mean."""
    from conftest import SCENARIOS

    sc = scenario.load(SCENARIOS / "cross4" / "scenario.toml", ["demand.end_s=200.0"])
    res = run_baseline(sc, junction, tmp_path / junction, duration_s=320.0)
    veh = res.vehicles
    st = veh[(veh["movement"] == "straight") & veh["delay_s"].notna() & veh["sumo_time_loss_s"].notna()]
    assert len(st) > 20
    diff = st["delay_s"] - st["depart_delay_s"] - st["sumo_time_loss_s"]  # timeLoss leaves out departDelay
    assert diff.abs().median() < 1.0
    assert abs(diff.mean()) < 0.5
    assert res.summary["max_tracking_error_m"] is None  # not applicable to a baseline


@pytest.mark.parametrize("movement", ["N_in.left", "N_in.right", "W_in.straight"])
def test_an_unhindered_vehicle_loses_no_more_than_physics_requires(movement, tmp_path):
    """A lone vehicle, bound by nothing but its own earliest arrival: its delay is at most 0.5 s
    above cruising at the entry speed, braking at |u_min| to its crossing speed just in time and
    crossing the merging zone at it (docs/method.md)."""
    from conftest import copy_scenario

    d = copy_scenario("cross4", tmp_path / "scen", "rate_veh_h = 400.0", "rate_veh_h = 0.0\nmean_headway_s = 0.0",
                      f'\n[[vehicles]]\nid = "lone"\napproach = "{movement}"\ndepart_s = 1.0\n'
                      'depart_speed_mps = 13.89\n')
    sc = scenario.load(d / "scenario.toml", ["scenario.duration_s=75.0", "outputs.warmup_s=0.0"])
    out = tmp_path / "run"
    res = run_scenario(sc, out)
    v = res.vehicles.set_index("vehicle_id").loc["lone"]
    mv = json.loads((out / "movements.json").read_text())["movements"][movement]
    assert v["binding"] == "earliest" and np.isfinite(v["delay_s"])
    v0, u = v["v_enter_mps"], -sc.planning.u_min_mps2
    vm = min(mv["v_limit_mps"] or np.inf, sc.planning.v_max_mps, v0)
    D = mv["merge_entry_m"] - mv["control_zone_start_m"]
    S = mv["zone_length_m"]
    tb = (v0 - vm) / u
    t_phys = (D - (v0 + vm) / 2.0 * tb) / v0 + tb + S / vm
    delay_min = t_phys - (D + S) / v0
    assert delay_min - 0.05 <= v["delay_s"] <= delay_min + 0.5, (v["delay_s"], delay_min)
    assert res.summary["collisions"] == 0 and res.summary["max_lateral_dev_m"] < 0.5


def test_conflict_points_reserve_the_areas_not_the_zone():
    """Movements A and B cross: A's conflict area is [10, 20] m past its zone entry, B's [12, 22] m.
    Everyone crosses at 10 m/s, 1 s margin. b1 (B) waits only until a1 (A) has left the shared area
    plus the margin, not until a1 has left the whole 30 m zone (the zone model)."""
    rel = {("A", "B"): CONFLICT, ("B", "A"): CONFLICT}
    areas = {("A", "B"): (10.0, 20.0), ("B", "A"): (12.0, 22.0)}
    bounds = PlanBounds(v_min_mps=1.0, v_max_mps=20.0, u_min_mps2=-3.0, u_max_mps2=2.5)
    settings = CoordinatorSettings(rear_end_spacing_m=12.0, terminal_speed="fixed", conflict_model="conflict_points",
                                   conflict_margin_s=1.0)
    c = Coordinator(settings, bounds, rel, areas=areas)
    v, D, S = 10.0, 400.0, 30.0
    a1 = c.schedule("a1", "lane_A", 0.0, v, D, "A", S, v_limit=v)
    b1 = c.schedule("b1", "lane_B", 0.5, v, D, "B", S, v_limit=v)
    assert a1.t_merge == pytest.approx(40.0) and a1.binding == "earliest"
    # a1 holds A's area over [41, 42] s; b1 enters B's area 1.2 s after its merge time
    assert b1.t_merge == pytest.approx(42.0 + 1.0 - 1.2) and b1.binding == "conflict" and b1.predecessor == "a1"
    zone = Coordinator(CoordinatorSettings(rear_end_spacing_m=12.0, terminal_speed="fixed"), bounds, rel)
    zone.schedule("a1", "lane_A", 0.0, v, D, "A", S, v_limit=v)
    assert zone.schedule("b1", "lane_B", 0.5, v, D, "B", S, v_limit=v).t_merge == pytest.approx(43.0)
    # a later A vehicle on another lane is kept out of b1's occupancy [43, 44] s of the area
    a2 = c.schedule("a2", "lane_A2", 1.0, v, D, "A", S, v_limit=v)
    assert a2.t_merge == pytest.approx(44.0 + 1.0 - 1.0) and a2.predecessor == "b1"
    # a gap between reservations is used: a3 (A) reserved [51, 52] s; b3 (B), scheduled after it,
    # is pushed past a2's [45, 46] s only, and crosses before a3
    a3 = c.schedule("a3", "lane_A3", 10.0, v, D, "A", S, v_limit=v)
    assert a3.t_merge == pytest.approx(50.0) and a3.binding == "earliest"
    b3 = c.schedule("b3", "lane_B3", 5.0, v, D, "B", S, v_limit=v)
    assert b3.t_merge == pytest.approx(46.0 + 1.0 - 1.2) and b3.predecessor == "a2"
    assert b3.t_merge + 2.2 + 1.0 <= a3.t_merge + 1.0 + 1e-9  # out of its area a margin before a3 enters


@pytest.mark.parametrize("delay, signalised, letter", [
    (0.0, False, "A"), (10.0, False, "A"), (10.01, False, "B"), (15.0, False, "B"), (24.9, False, "C"),
    (35.0, False, "D"), (49.0, False, "E"), (50.5, False, "F"), (19.9, True, "B"), (20.1, True, "C"),
    (55.0, True, "D"), (79.0, True, "E"), (81.0, True, "F"),
])
def test_level_of_service_thresholds_are_the_hcm_ones(delay, signalised, letter):
    # Highway Capacity Manual: signalised A <= 10 < B <= 20 < C <= 35 < D <= 55 < E <= 80 < F;
    # unsignalised A <= 10 < B <= 15 < C <= 25 < D <= 35 < E <= 50 < F
    from nrtraffic.metrics import level_of_service

    assert level_of_service(delay, signalised) == letter


def test_conflict_point_search_ends_when_rounding_puts_a_pushed_time_on_the_boundary():
    """Pushed to ``r_out + margin - from / v``, the vehicle's entry ``t + from / v`` can land a
    rounding error before ``r_out + margin``: that counts as apart, and the search ends."""
    rel = {("A", "B"): CONFLICT, ("B", "A"): CONFLICT}
    settings = CoordinatorSettings(rear_end_spacing_m=12.0, terminal_speed="fixed", conflict_model="conflict_points",
                                   conflict_margin_s=0.7)
    bounds = PlanBounds(v_min_mps=1.0, v_max_mps=13.89, u_min_mps2=-3.0, u_max_mps2=2.5)
    rng = np.random.default_rng(1)
    for _ in range(200):
        areas = {("A", "B"): tuple(sorted(rng.uniform(0.0, 30.0, 2))), ("B", "A"): tuple(sorted(rng.uniform(0.0, 30.0, 2)))}
        c = Coordinator(settings, bounds, rel, areas=areas)
        t = 0.0
        for k in range(6):
            mv = "AB"[k % 2]
            t += rng.uniform(0.0, 2.0)
            a = c.schedule(f"v{k}", f"lane{k}", t, 13.89, 400.0, mv, 30.0, v_limit=rng.choice([6.5, 8.0, 13.89]))
            assert np.isfinite(a.t_merge)


def test_leader_search_by_hand():
    """Two paths that merge onto one exit lane (lanes 0 -> 2 and 1 -> 2, 100 m and 20 m long, the
    exit lane scaled 1:1): each controlled car's leader is the nearest car ahead on its own lanes,
    whichever path that car is on; a car on the other entry lane is no leader; nothing ahead within
    the look-ahead leaves none."""
    import numpy as np

    from nrtraffic.control import batch as kb
    from nrtraffic.control.leaders import find_leaders

    pl_off = np.array([0, 2, 4], dtype=np.int64)
    pl_lane = np.array([0, 2, 1, 2], dtype=np.int64)
    pl_start = np.array([0.0, 100.0, 0.0, 20.0])
    pl_scale = np.ones(4)
    # table: a on lane 0 at 50 m, b on lane 0 at 80 m, c on lane 1 at 10 m, d (SUMO-driven) on lane 2
    # at 30 m, e on lane 1 at 15 m (controlled)
    lane_id = np.array([0, 0, 1, 2, 1], dtype=np.int64)
    lane_pos = np.array([50.0, 80.0, 10.0, 30.0, 15.0])
    x, y = np.array([50.0, 80.0, 5.0, 130.0, 8.0]), np.zeros(5)
    psi, speed, accel = np.zeros(5), np.full(5, 10.0), np.array([0.0, 0.0, 0.0, -1.0, 0.0])
    rows = np.array([0, 1, 2, 4], dtype=np.int64)  # batch: a, b, c, e
    path_id = np.array([0, 0, 1, 1], dtype=np.int64)
    lead_idx, lead_ext, gap = np.zeros(4, dtype=np.int64), np.zeros((4, 6)), np.zeros(4)
    length = 4.8
    find_leaders(lane_id, lane_pos, x, y, psi, speed, accel, rows, path_id, pl_off, pl_lane, pl_start, pl_scale,
                 200.0, 2.4, length, lead_idx, lead_ext, gap)
    # a -> b (batch 1), 30 m ahead; b -> d (external) on the exit lane at s = 130; c -> e; e -> d
    assert lead_idx.tolist() == [1, kb.EXTERNAL_LEADER, 3, kb.EXTERNAL_LEADER]
    assert gap == pytest.approx([30.0 - length, 130.0 - 80.0 - length, 5.0 - length, 50.0 - 15.0 - length])
    assert lead_ext[1] == pytest.approx([130.0 - 2.4, 0.0, 10.0, 0.0, -1.0, 0.0])
    # the look-ahead: with 10 m of it, b's search stops after its own 100 m lane, short of d
    find_leaders(lane_id, lane_pos, x, y, psi, speed, accel, rows, path_id, pl_off, pl_lane, pl_start, pl_scale,
                 10.0, 2.4, length, lead_idx, lead_ext, gap)
    assert lead_idx[1] == kb.NO_LEADER and np.isnan(gap[1]) and lead_idx[0] == 1
