"""Roads as OpenStreetMap imports draw them: sidewalks, cycle lanes and pedestrian crossings at the
controlled junction, and a city's route file, most of whose vehicles never pass it. The network is
built by SUMO's netconvert; what is a car's lane, which vehicles SUMO inserted and which finished
their trips are read from the network file and SUMO's own outputs."""

import json
import math
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest

from nrtraffic import scenario
from nrtraffic.engine import Engine
from nrtraffic.sumo.demandfile import read_sumo_demand
from nrtraffic.sumo.netbuild import sumo_binary
from nrtraffic.sumo.network import give_way_room, junction_movements, read_net, safe_depart_speed
from runners.single import run_scenario

NODES = """<nodes>
  <node id="C" x="0" y="0" type="priority"/>
  <node id="N" x="0" y="300"/> <node id="S" x="0" y="-300"/> <node id="E" x="300" y="0"/> <node id="W" x="-300" y="0"/>
  <node id="WW" x="-600" y="0"/>
  <node id="X1" x="0" y="900"/> <node id="X2" x="400" y="900"/>
</nodes>"""
# every arm has a sidewalk; the north-south road also a cycle lane; W_C is fed by a 30 km/h street;
# X1_X2 is a road of its own, nowhere near the junction
EDGES = """<edges>
  <edge id="N_C" from="N" to="C" numLanes="1" speed="13.89" sidewalkWidth="2.0" bikeLaneWidth="1.5"/>
  <edge id="C_N" from="C" to="N" numLanes="1" speed="13.89" sidewalkWidth="2.0" bikeLaneWidth="1.5"/>
  <edge id="S_C" from="S" to="C" numLanes="1" speed="13.89" sidewalkWidth="2.0" bikeLaneWidth="1.5"/>
  <edge id="C_S" from="C" to="S" numLanes="1" speed="13.89" sidewalkWidth="2.0" bikeLaneWidth="1.5"/>
  <edge id="E_C" from="E" to="C" numLanes="1" speed="13.89" sidewalkWidth="2.0"/>
  <edge id="C_E" from="C" to="E" numLanes="1" speed="13.89" sidewalkWidth="2.0"/>
  <edge id="W_C" from="W" to="C" numLanes="1" speed="13.89" sidewalkWidth="2.0"/>
  <edge id="C_W" from="C" to="W" numLanes="1" speed="13.89" sidewalkWidth="2.0"/>
  <edge id="WW_W" from="WW" to="W" numLanes="1" speed="8.33" sidewalkWidth="2.0"/>
  <edge id="X1_X2" from="X1" to="X2" numLanes="1" speed="13.89"/>
</edges>"""


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    """A scenario folder: the junction C of a netconvert network with sidewalks, cycle lanes and
    crossings (turning radius 10 m, as an engineer would draw it), and a route file."""
    d = tmp_path_factory.mktemp("city")
    (d / "n.nod.xml").write_text(NODES)
    (d / "n.edg.xml").write_text(EDGES)
    _netconvert(d, "--crossings.guess", "--walkingareas")
    return d


def _netconvert(d, *options: str) -> None:
    """``d/net.net.xml`` from ``d``'s n.nod.xml and n.edg.xml, turning radius 10 m, no U-turns."""
    subprocess.run([str(sumo_binary("netconvert")), "-n", str(d / "n.nod.xml"), "-e", str(d / "n.edg.xml"), *options,
                    "--no-turnarounds", "--default.junctions.radius", "10", "--junctions.internal-link-detail", "20",
                    "-o", str(d / "net.net.xml")], check=True, capture_output=True)


def _car_lanes(net_file) -> set[str]:
    """The lanes a passenger car may use, from the network file's allow/disallow attributes."""
    cars = set()
    for edge in ET.parse(net_file).getroot().iter("edge"):
        for lane in edge.iter("lane"):
            allow, disallow = lane.get("allow"), lane.get("disallow", "")
            if (allow is None or "passenger" in allow.split()) and "passenger" not in disallow.split():
                cars.add(lane.get("id"))
    return cars


def test_sidewalks_cycle_lanes_and_crossings_are_not_movements(city):
    net = city / "net.net.xml"
    cars = _car_lanes(net)
    expected = set()
    for c in ET.parse(net).getroot().iter("connection"):
        frm, to = f"{c.get('from')}_{c.get('fromLane')}", f"{c.get('to')}_{c.get('toLane')}"
        if not c.get("from").startswith(":") and frm.startswith(("N_C", "S_C", "E_C", "W_C")) and frm in cars \
                and to in cars:
            expected.add((c.get("from"), c.get("to"), int(c.get("fromLane"))))
    moves, _ = junction_movements(net, "C")
    assert {(m.in_edge, m.out_edge, m.in_lane) for m in moves} == expected
    assert len(expected) == 12  # (four arms, three turns each: no U-turns)
    # an approach with a sidewalk (and a cycle lane) beside its one car lane is a one-lane approach
    assert all(m.in_lanes == 1 and m.name == m.route for m in moves)
    assert all(m.lane in cars and m.in_lane > 0 for m in moves)  # (lane 0 is the sidewalk)


def _scenario(city, body: str = "") -> scenario.Scenario:
    (city / "scenario.toml").write_text(f"""
[scenario]
name = "city"
network = "net.net.xml"
duration_s = 150.0

[junction]
id = "C"

[zones]
control_zone_m = 250.0
merging_zone_m = 40.0
{body}""")
    return scenario.load(city / "scenario.toml")


def test_a_junction_with_sidewalks_and_crossings_runs_on_its_car_lanes(city, tmp_path):
    # (the entry speed within the 30 km/h of the street that feeds the west arm)
    sc = _scenario(city, "\n[demand]\nrate_veh_h = 400.0\nturn_left = 0.2\nturn_right = 0.2\nentry_speed_mps = 8.0\n")
    s = run_scenario(sc, tmp_path / "run").summary
    assert s["status"] == "ok" and s["collisions"] == 0 and s["collisions_geometric"] == 0
    # (at 8 m/s a car takes about 30 s through its zone: those entering at the window's end are not served)
    assert s["vehicles_demanded"] > 25 and s["served_share"] > 0.75
    cars = _car_lanes(city / "net.net.xml")
    paths = json.loads((tmp_path / "run" / "movements.json").read_text())
    lanes = [ln for m in paths["movements"].values() for ln in m["lanes"]]
    # every path runs on car lanes, and through the junction on its internal lanes for cars
    assert lanes and all(ln in cars for ln in lanes)
    # SUMO's own record: the vehicles that finished their trips all crossed the junction in the run
    trips = {t.get("id") for t in ET.parse(tmp_path / "run" / "tripinfo.xml").getroot().iter("tripinfo")}
    crossed = pd.read_csv(tmp_path / "run" / "vehicles.csv").dropna(subset=["t_exit_s"])["vehicle_id"]
    assert trips and trips <= set(crossed)


ROUTES = """<routes>
  <vehicle id="through.0" depart="0"><route edges="WW_W W_C C_E"/></vehicle>
  <vehicle id="through.1" depart="4"><route edges="N_C C_S"/></vehicle>
  <vehicle id="through.2" depart="8"><route edges="WW_W W_C C_N"/></vehicle>
  <vehicle id="away.0" depart="1"><route edges="X1_X2"/></vehicle>
  <vehicle id="away.1" depart="6"><route edges="X1_X2"/></vehicle>
  <vehicle id="exit.0" depart="2" departSpeed="5"><route edges="C_E"/></vehicle>
</routes>"""


def test_vehicles_that_cross_no_controlled_junction_are_driven_by_sumo_and_left_out(city, tmp_path):
    """A city's route file: SUMO drives the vehicles that never pass the junction (they finish
    their trips, in SUMO's tripinfo), the run's figures leave them out, and those nowhere near the
    junction are never read."""
    (city / "city.rou.xml").write_text(ROUTES)
    sc = _scenario(city, '\n[demand]\nsumo_routes = "city.rou.xml"\n')
    eng = Engine(sc, tmp_path / "run", duration_s=150.0)
    eng.run()
    trips = {t.get("id") for t in ET.parse(tmp_path / "run" / "tripinfo.xml").getroot().iter("tripinfo")}
    assert {"away.0", "away.1", "exit.0", "through.0", "through.1", "through.2"} <= trips  # (all arrived)
    assert eng.st.sumo.unread == {"away.0", "away.1"}  # (X1_X2 is no road of the junction's paths)
    assert sorted(eng.st.records) == ["through.0", "through.1", "through.2"]
    assert any("3 of its vehicles cross no controlled junction" in n for n in eng.demand.notes)
    assert all(r.t_exit > 0 for r in eng.st.records.values())


def test_a_file_whose_first_road_is_slower_departs_at_its_limit(city):
    """No departSpeed: the entry speed, at most the first edge's limit (8.33 m/s on WW_W); such a
    vehicle's free-flow speed stays the entry speed (Demand.paced)."""
    p = city / "slow.rou.xml"
    p.write_text(ROUTES)
    moves = {(m.in_edge, m.out_edge): m.route for m in junction_movements(city / "net.net.xml", "C")[0]}
    dep = {v[0]: v for v in read_sumo_demand(p, moves, np.random.default_rng(1), math.inf, 13.4,
                                             net=read_net(city / "net.net.xml"))}
    assert dep["through.0"][3] == pytest.approx(8.33) and dep["through.1"][3] == 13.4
    assert dep["exit.0"][3] == 5.0 and dep["away.0"][1] == ()  # (a number is kept; no crossing)
    assert {vid for vid, v in dep.items() if v[8]} == {"through.0", "through.2"}  # (slowed)


YIELD_NODES = """<nodes>
  <node id="M1" x="-200" y="0"/> <node id="J" x="0" y="0" type="priority"/> <node id="M2" x="200" y="0"/>
  <node id="A" x="0" y="-200"/>
</nodes>"""
YIELD_EDGES = """<edges>
  <edge id="M1_J" from="M1" to="J" priority="10" numLanes="1" speed="13.89"/>
  <edge id="J_M2" from="J" to="M2" priority="10" numLanes="1" speed="13.89"/>
  <edge id="A_J" from="A" to="J" priority="1" numLanes="1" speed="13.89"/>
</edges>"""


@pytest.mark.parametrize("room", [6.0, 12.0, 25.0])
def test_sumo_inserts_a_car_at_its_safe_speed_before_a_link_where_it_gives_way(room, tmp_path):
    """SUMO itself is the reference: a car departing ``room`` metres before a minor link (found by
    give_way_room on the network) at safe_depart_speed is inserted; 0.5 m/s faster, SUMO discards
    it ("will not be able to depart"). (The bound is SUMO's with a whole step of reaction where
    SUMO counts half: conservative by about 0.2 m/s at a 0.1 s step.)"""
    (tmp_path / "n.nod.xml").write_text(YIELD_NODES)
    (tmp_path / "n.edg.xml").write_text(YIELD_EDGES)
    _netconvert(tmp_path)
    net_file = tmp_path / "net.net.xml"
    net = read_net(net_file)
    pos = net.getEdge("A_J").getLength() - room
    found = give_way_room(net, ("A_J", "J_M2"), pos)
    assert found is not None and found[0] == pytest.approx(room) and found[1] == "J"
    v = safe_depart_speed(found[0], 4.5, 0.1)

    def inserted(speed: float) -> bool:
        (tmp_path / "r.rou.xml").write_text(
            f'<routes><vType id="t" decel="4.5" length="5" sigma="0"/><vehicle id="x" type="t" depart="0" '
            f'departPos="{pos:.3f}" departSpeed="{speed:.3f}"><route edges="A_J J_M2"/></vehicle></routes>')
        subprocess.run([str(sumo_binary("sumo")), "-n", str(net_file), "-r", str(tmp_path / "r.rou.xml"), "--end", "60",
                        "--step-length", "0.1", "--tripinfo-output", str(tmp_path / "ti.xml"), "--no-step-log"],
                       check=True, capture_output=True)
        return any(True for _ in ET.parse(tmp_path / "ti.xml").getroot().iter("tripinfo"))

    assert inserted(math.floor(1000.0 * v) / 1000.0) and not inserted(v + 0.5)


def test_a_city_junction_in_its_calibrated_demand_keeps_every_lane_moving(tmp_path):
    """sumo_scenarios/doerpfeldstr, a cut of a public city scenario, its first 300 s, first come
    first served (``coordinator.policy = "fifo"``, the default) under the zone model: on an approach
    fed by several roads, a car ahead may have departed after the cars behind it. One such car,
    held at its stop line, had been passed over for ever behind the cars that waited for it, and
    its lane stood still from 205 s on while the run said "ok" (the other arms kept the junction
    crossing). Now every held car crosses, and every car that entered the control zone more than
    a minute before the end left it."""
    from conftest import SCENARIOS

    # (first come first served, where the lane's order matters; the scenario's own batches hold none)
    sc = scenario.load(SCENARIOS / "doerpfeldstr" / "scenario.toml",
                       ['coordinator.conflict_model="zone"', 'coordinator.policy="fifo"'])
    out = tmp_path / "run"
    s = run_scenario(sc, out, duration_s=300.0).summary
    assert s["status"] == "ok" and s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert any("of its vehicles cross no controlled junction" in w for w in s["warnings"])
    v = pd.read_csv(out / "vehicles.csv")
    late = v[(v["t_arrive_s"] < 240.0) & v["t_exit_s"].isna()]
    assert late.empty, late[["vehicle_id", "lane", "t_arrive_s", "status"]]
    assert (v["t_held_s"] > 0).sum() >= 5  # (the situation arises)
    assert s["vehicles_waiting_to_enter"] == 0


def test_a_background_vehicle_too_fast_for_its_first_road_is_refused_before_sumo_starts(city, tmp_path, capsys):
    """SUMO refuses a departure faster than its edge's limit mid-run: a background vehicle's is
    checked with the others', before SUMO starts (exit 2, naming it)."""
    from runners.cli import main

    (city / "fast.rou.xml").write_text(ROUTES.replace('id="away.1" depart="6"', 'id="away.1" depart="6" departSpeed="20"'))
    _scenario(city, '\n[demand]\nsumo_routes = "fast.rou.xml"\n')
    out = tmp_path / "run"
    assert main(["run", str(city / "scenario.toml"), "--out", str(out), "--duration", "30", "--no-progress"]) == 2
    assert "vehicle away.1 departs at 20 m/s on edge X1_X2" in capsys.readouterr().err
    assert not out.exists()


def test_under_the_zone_model_held_cars_that_start_from_rest_never_share_the_zone_with_cross_traffic(tmp_path):
    """tests/data/doerpfeldstr_1906421964, a cut of a public city scenario, its first 300 s under the
    paper's conflict rule (``coordinator.conflict_model = "zone"``): no two vehicles of conflicting
    movements in the merging zone at once. Its approaches are short, so cars are held and start
    from rest at their stop lines. Such a start had been reserved without regard to the cars
    planned through the zone, and those planned after it without regard to it: a car setting off
    from rest ran into a slow left turn merging with it, four times in these 300 s. Checked on the
    times the run measured (each vehicle's merging-zone entry and exit), for every pair of
    conflicting movements (movements.json), and with SUMO's own collision check."""
    from conftest import ROOT

    sc = scenario.load(ROOT / "tests" / "data" / "doerpfeldstr_1906421964" / "scenario.toml")
    assert sc.coordinator.conflict_model == "zone"
    out = tmp_path / "run"
    s = run_scenario(sc, out, duration_s=300.0).summary
    assert s["status"] == "ok" and s["collisions"] == 0 and s["collisions_geometric"] == 0
    v = pd.read_csv(out / "vehicles.csv", dtype={"vehicle_id": str}).dropna(subset=["t_merge_actual_s", "t_exit_s"])
    assert (v["profile"] == "from_rest").sum() >= 3  # (the situation arises)
    doc = json.loads((out / "movements.json").read_text())
    relations = doc["relations"]
    name = {(m["lanes"][0], m["turn"]): n for n, m in doc["movements"].items()}  # (entry lane, turn) -> movement
    crossed = list(zip(v["vehicle_id"], [name[k] for k in zip(v["lane"], v["movement"])], v["t_merge_actual_s"],
                       v["t_exit_s"]))
    shared = [(a, b, min(ea, eb) - max(ia, ib))
              for k, (a, ma, ia, ea) in enumerate(crossed) for b, mb, ib, eb in crossed[k + 1:]
              if relations[ma].get(mb) == "conflict" and min(ea, eb) > max(ia, ib)]
    assert not shared, shared


# two lanes from the west straight on through C onto the two lanes of the road to X, where lane 0
# turns right and lane 1 goes straight on
LANE_NODES = """<nodes>
  <node id="C" x="0" y="0" type="priority"/>
  <node id="W" x="-300" y="0"/> <node id="N" x="0" y="300"/> <node id="S" x="0" y="-300"/>
  <node id="X" x="300" y="0" type="priority"/> <node id="XE" x="600" y="0"/> <node id="XS" x="300" y="-300"/>
</nodes>"""
LANE_EDGES = """<edges>
  <edge id="W_C" from="W" to="C" numLanes="2" speed="13.89"/>
  <edge id="N_C" from="N" to="C" numLanes="1" speed="13.89"/> <edge id="C_N" from="C" to="N" numLanes="1" speed="13.89"/>
  <edge id="S_C" from="S" to="C" numLanes="1" speed="13.89"/> <edge id="C_S" from="C" to="S" numLanes="1" speed="13.89"/>
  <edge id="C_X" from="C" to="X" numLanes="2" speed="13.89"/>
  <edge id="X_XE" from="X" to="XE" numLanes="1" speed="13.89"/> <edge id="X_XS" from="X" to="XS" numLanes="1" speed="13.89"/>
</edges>"""
LANE_CONNECTIONS = """<connections>
  <connection from="W_C" to="C_X" fromLane="0" toLane="0"/> <connection from="W_C" to="C_X" fromLane="1" toLane="1"/>
  <connection from="C_X" to="X_XS" fromLane="0" toLane="0"/> <connection from="C_X" to="X_XE" fromLane="1" toLane="0"/>
</connections>"""


@pytest.mark.parametrize("control", ["nrtraffic", "priority"])
def test_past_its_last_junction_a_car_kept_on_its_lane_changes_lanes_for_its_route_again(tmp_path, control):
    """Where a turn can be made from more than one lane, a car keeps the lane it is on through
    the control zone. Past the junction, its lane may not lead where its route goes: here every car
    from the west departs on the right lane (its route file says so), leaves C on the right lane of
    C_X, which turns right at X, and half of them go straight on at X. Kept on its lane for ever,
    such a car stopped at X for good, with no
    teleport, and the queue behind it reached back through C (found on a city network, where it
    stopped a lane of the controlled junction). Past its last controlled junction, SUMO's driver
    makes the lane changes its route needs again: every car finishes its trip, in SUMO's own
    tripinfo, under nrtraffic and under SUMO's priority rule."""
    from runners.baseline import run_baseline

    for name, text in (("n.nod.xml", LANE_NODES), ("n.edg.xml", LANE_EDGES), ("n.con.xml", LANE_CONNECTIONS)):
        (tmp_path / name).write_text(text)
    _netconvert(tmp_path, "-x", str(tmp_path / "n.con.xml"))
    routes = "".join(f'  <vehicle id="w.{k}" depart="{4 * k}" departLane="0" departSpeed="13.89"><route '
                     f'edges="W_C C_X {"X_XE" if k % 2 else "X_XS"}"/></vehicle>\n' for k in range(10))
    (tmp_path / "d.rou.xml").write_text(f"<routes>\n{routes}</routes>\n")
    sc = _scenario(tmp_path, '\n[demand]\nsumo_routes = "d.rou.xml"\n')
    out = tmp_path / control
    res = run_scenario(sc, out) if control == "nrtraffic" else run_baseline(sc, control, out)
    assert res.summary["status"] == "ok" and res.summary["collisions"] == 0
    v = pd.read_csv(out / "vehicles.csv")
    assert set(v["lane"]) == {"W_C_0"}  # (every car on the right lane)
    trips = {t.get("id") for t in ET.parse(out / "tripinfo.xml").getroot().iter("tripinfo")}
    assert trips == {f"w.{k}" for k in range(10)}
