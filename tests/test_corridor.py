"""Corridors: several junctions, each with its own zones and coordinator (corridor3). The control
zone cut where the junction upstream hands vehicles over, the hand-over itself, and the
corridor's figures against SUMO's own trip records."""

import json
import math
import tomllib
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest

from conftest import SCENARIOS, conflict_gaps, copy_scenario
from nrtraffic import scenario
from nrtraffic.sumo.network import edge_nodes
from runners.single import run_scenario

CORRIDOR = SCENARIOS / "corridor3"


@pytest.fixture(scope="module")
def corridor_run(tmp_path_factory):
    sc = scenario.load(CORRIDOR / "scenario.toml", ["scenario.duration_s=240.0", "demand.end_s=150.0",
                                                    "outputs.warmup_s=0.0"])
    out = tmp_path_factory.mktemp("corridor3") / "run"
    return run_scenario(sc, out), out


def _junction_xy(name):
    root = ET.parse(CORRIDOR / "net.net.xml").getroot()
    el = next(j for j in root.iter("junction") if j.get("id") == name)
    return float(el.get("x")), float(el.get("y"))


def test_control_zone_is_cut_where_the_junction_upstream_hands_over(corridor_run):
    """On the arterial between J1 and J2 (280 m apart, straight), J2's 300 m control zone reaches
    back into J1's merging zone: it is cut where the path leaves J1's merging disc. On a straight
    road that leaves the distance between the junctions less the two merging radii (closed form);
    the links to J3 (380 m) keep their zones whole."""
    res, out = corridor_run
    doc = json.loads((out / "movements.json").read_text())
    cfg = tomllib.loads((out / "scenario.resolved.toml").read_text())
    r = cfg["zones"]["merging_zone_m"] / 2.0
    spacing = math.dist(_junction_xy("J1"), _junction_xy("J2"))
    cuts = res.summary["control_zones_cut_m"]
    assert set(cuts) == {f"{a}.{t}" for a in ("J1_J2", "J2_J1") for t in ("left", "straight", "right")}
    for name, length in cuts.items():
        m = doc["movements"][name]
        assert length == pytest.approx(m["merge_entry_m"] - m["control_zone_start_m"], abs=1e-3)
        assert length == pytest.approx(spacing - 2 * r, abs=0.6), name
    for name in ("J2_J3.straight", "J3_J2.straight", "W_J1.straight"):
        m = doc["movements"][name]
        assert m["merge_entry_m"] - m["control_zone_start_m"] == pytest.approx(cfg["zones"]["control_zone_m"])


def test_vehicles_are_handed_from_one_coordinator_to_the_next(corridor_run):
    """A trip's crossings come in the order of its route: each next junction is the one the
    previous movement's outgoing road leads into (read from the network), its crossing starts
    after the previous one ended, no sooner than the road between them allows at the speed limit,
    and each junction's coordinator planned its own merge time, which the vehicle met."""
    res, out = corridor_run
    veh = pd.read_csv(out / "vehicles.csv")
    nodes = edge_nodes(CORRIDOR / "net.net.xml")
    multi = veh[veh["legs"] > 1]
    assert multi["vehicle_id"].nunique() > 30
    handed = 0
    for vid, g in multi.groupby("vehicle_id"):
        g = g.sort_values("leg")
        assert list(g["leg"]) == list(range(len(g)))
        for a, b in zip(g.to_dict("records"), g.to_dict("records")[1:]):
            assert nodes[b["approach"]] == (a["junction"], b["junction"])  # the road from a's junction to b's
            if math.isnan(a["t_exit_s"]) or math.isnan(b["t_arrive_s"]):
                continue
            # from a's merging zone to b's: the road between them less the two merging radii (15 m)
            road = math.dist(_junction_xy(a["junction"]), _junction_xy(b["junction"])) - 30.0
            assert b["t_arrive_s"] >= a["t_exit_s"] - 1e-6
            assert b["t_merge_actual_s"] - a["t_exit_s"] >= road / 13.89 - 0.2
            handed += 1
    assert handed > 30
    done = veh[veh["t_merge_actual_s"].notna()]
    assert (done["t_merge_actual_s"] - done["t_merge_planned_s"]).abs().max() < 0.3
    s = res.summary
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert set(s["junctions"]) == {"J1", "J2", "J3"}
    assert sum(j["vehicles"] for j in s["junctions"].values()) == int(veh["t_exit_s"].notna().sum())


def test_each_junction_keeps_its_conflicting_crossings_apart(corridor_run):
    """As on one junction (tests/test_junction.py), for every junction of the corridor: two
    crossings of conflicting movements held their conflict area at least the margin apart."""
    res, out = corridor_run
    gaps, margin = conflict_gaps(out)
    for _, a, b, gap in gaps:
        assert gap > margin - 0.1, (a, b, gap)
    assert min(sum(j == name for j, *_ in gaps) for name in ("J1", "J2", "J3")) > 5


def test_corridor_travel_time_is_sumo_trip_duration(corridor_run):
    """summary.json ``corridor``: the trips straight along the arterial, per direction, with their
    travel time and stops as SUMO's tripinfo records them (an independent record)."""
    res, out = corridor_run
    veh = pd.read_csv(out / "vehicles.csv")
    trips = {t.get("id"): t for t in ET.parse(out / "tripinfo.xml").getroot().iter("tripinfo")}
    through = veh.groupby("vehicle_id").filter(lambda g: len(g) == 3 and (g["movement"] == "straight").all())
    first = through.drop_duplicates("vehicle_id").set_index("vehicle_id")
    corridor = res.summary["corridor"]
    assert set(corridor) == {"W_J1", "E_J3"}
    for appr, fig in corridor.items():
        ids = [v for v in first.index if first.at[v, "approach"] == appr and v in trips]
        assert fig["vehicles"] == len(ids) > 3
        tt = np.mean([float(trips[v].get("duration")) + first.at[v, "depart_delay_s"] for v in ids])
        assert fig["travel_time_s"] == pytest.approx(tt, abs=1e-3)  # (written to 0.001 s)
        # a signal-free arterial: no stops, and the trip takes about its length at the speed limit
        length = np.mean([float(trips[v].get("routeLength")) for v in ids])
        assert fig["stops_per_vehicle"] == 0.0
        assert length / 13.89 <= fig["travel_time_s"] < length / 13.89 + 15.0


def test_mixed_traffic_on_a_corridor_waits_for_the_humans_ahead_on_the_lane(tmp_path):
    """Half the vehicles human: on the arterial between junctions the vehicles on a lane come from
    several roads, so who is ahead is decided by position, not by the order of departure. A
    controlled car behind a human standing at the next stop line waits for it instead of being
    scheduled into it: no collision, and the cars track their plans."""
    sc = scenario.load(CORRIDOR / "scenario.toml", ["scenario.duration_s=200.0", "demand.controlled_share=0.5",
                                                    "outputs.warmup_s=0.0"])
    res = run_scenario(sc, tmp_path / "run")
    s = res.summary
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert s["vehicles_human"] > 20 and s["vehicles_automated"] > 20
    assert s["max_tracking_error_m"] < 0.5
    veh = res.vehicles
    assert ((veh["driver"] == "human") & (veh["leg"] > 0) & veh["t_exit_s"].notna()).sum() > 5


@pytest.mark.parametrize("old, new, message", [
    ('id = "J3"', 'id = "J9"', "junction 'J9' is not in it"),
    ('id = "J3"', 'id = "E"', "junction 'E' (dead_end) has no movements"),
])
def test_a_corridor_naming_a_junction_it_cannot_control_exits_2(old, new, message, tmp_path, capsys):
    from runners.cli import main

    d = copy_scenario("corridor3", tmp_path / "scen", old, new)
    assert main(["run", str(d), "--out", str(tmp_path / "o"), "--duration", "5", "--no-progress"]) == 2
    assert message in capsys.readouterr().err


def test_first_in_first_out_on_a_corridor_keeps_the_plans_behind_turning_leaders(tmp_path):
    """coordinator.policy = "fifo": a car is scheduled the moment it is handed over, often close
    behind a slow car that turned onto the arterial. It is planned behind it, or left to SUMO's
    driver until it can be; a car that gets no merge time drives on to a stop short of the
    merging zone instead of stopping at the junction upstream. The plans are kept: no car runs
    tens of metres behind its plan held back by the barrier at its 2 m minimum (before, in this
    run: 27-32 m behind, at 2.0 m). First in, first out still leaves followers a few metres off
    their plans where a leader is late on its own (the barrier's work; batch sequencing, the
    default, has none of it)."""
    sc = scenario.load(CORRIDOR / "scenario.toml", ["scenario.duration_s=200.0", 'coordinator.policy="fifo"',
                                                    "outputs.warmup_s=0.0"])
    s = run_scenario(sc, tmp_path / "run").summary
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert s["max_tracking_error_m"] < 5.0
    assert s["min_bumper_gap_m"] > 4.0


def _two_lane_pair(tmp_path, routes: str):
    """netgenerate's 2x1 grid of two-lane roads (300 m between A0 and B0), both junctions
    controlled, the demand ``routes`` (a route file's vehicles); returns the scenario folder and
    the network."""
    import subprocess

    import sumolib

    from nrtraffic.sumo.netbuild import sumo_binary

    d = copy_scenario("cross4", tmp_path / "sc", 'id = "C"', "",
                      '\n[[junctions]]\nid = "A0"\ncontrol_zone_m = 150.0\n\n[[junctions]]\nid = "B0"\n'
                      'control_zone_m = 150.0\n')
    text = (d / "scenario.toml").read_text()
    text = text.replace("rate_veh_h = 400.0          # per approach\n", 'sumo_routes = "pair.rou.xml"\n')
    text = text.replace("turn_left = 0.2\nturn_right = 0.2\n", "").replace("warmup_s = 60.0", "warmup_s = 0.0")
    (d / "scenario.toml").write_text(text)
    subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.x-number", "2", "--grid.y-number", "1",
                    "--grid.length", "300", "--grid.attach-length", "300", "--default.lanenumber", "2",
                    "--no-turnarounds", "true", "-o", str(d / "net.net.xml")], check=True, capture_output=True)
    (d / "pair.rou.xml").write_text(f"<routes>\n{routes}</routes>\n")
    return d, sumolib.net.readNet(str(d / "net.net.xml"))


def test_a_two_lane_road_between_controlled_junctions_changes_lanes_for_the_next_turn(tmp_path):
    """Two controlled junctions joined by two-lane roads (netgenerate's 2x1 grid). A car that turns
    left at A0 leaves it on the left lane of A0B0 and turns right at B0, which only the right lane
    serves (and the other way round); a car that goes straight on through A0 on the left lane keeps
    it through A0 and turns right at B0 (and the other way round): SUMO's driver changes lanes
    between the two control zones.
    Every car crosses both junctions under control and on plan, with no collision; by SUMO's own
    fcd output, each keeps one lane from B0's control-zone entry on, that lane is the entry lane of
    its movement there (a lane that serves its turn, by the network's connections), and every car
    changed lanes to get there."""
    routes, n = [], 0
    trips = (("top0A0 A0B0 B0bottom1", "best"), ("bottom0A0 A0B0 B0top1", "best"),  # left-right, right-left
             ("left0A0 A0B0 B0bottom1", "1"), ("left0A0 A0B0 B0top1", "0"))  # straight on the other lane first
    for k in range(5):  # every 12 s
        for i, (edges, lane) in enumerate(trips):
            routes.append(f'  <vehicle id="v{n}" depart="{12.0 * k + 3.0 * i:.1f}" departSpeed="max" '
                          f'departLane="{lane}"><route edges="{edges}"/></vehicle>\n')
            n += 1
    d, net = _two_lane_pair(tmp_path, "".join(routes))
    sc = scenario.load(d / "scenario.toml", ["scenario.duration_s=150.0", "outputs.sumo_fcd=true"])
    res = run_scenario(sc, tmp_path / "run")
    s, veh = res.summary, res.vehicles
    assert s["status"] == "ok" and s["collisions"] == 0 and s["collisions_geometric"] == 0
    at_b = veh[veh.junction == "B0"].set_index("vehicle_id")
    assert len(at_b) == n and at_b.t_exit_s.notna().all() and (at_b.status == "released").all()
    assert veh.max_tracking_error_m.max() < 1.0
    lanes: dict[str, list[tuple[float, str]]] = {}  # SUMO's lane of each car on A0B0, in time
    for step in ET.parse(tmp_path / "run" / "fcd.xml").getroot():
        for v in step:
            if v.get("lane", "").startswith("A0B0_"):
                lanes.setdefault(v.get("id"), []).append((float(step.get("time")), v.get("lane")))
    changed = 0
    for vid, seq in lanes.items():
        rec = at_b.loc[vid]
        entered = [ln for t, ln in seq if t >= rec.t_enter_s - 1e-6]
        assert entered and len(set(entered)) == 1, (vid, entered)  # the zone's lane is kept
        assert entered[0] == rec.lane, (vid, entered[0], rec.lane)  # the entry lane of its movement
        serves = {c.getFromLane().getID() for c in net.getEdge("A0B0").getOutgoing()[
            net.getEdge(_exit_of(vid, routes))]}
        assert rec.lane in serves, (vid, rec.lane, serves)
        changed += seq[0][1] != entered[0]
    assert changed == n  # every car changed lanes between the junctions


def _exit_of(vid: str, routes: list[str]) -> str:
    """The last edge of vehicle ``vid``'s route in the route-file lines ``routes``."""
    line = next(r for r in routes if f'id="{vid}"' in r)
    return line.split('edges="')[1].split('"')[0].split()[-1]


def test_the_shipped_two_lane_grid_runs_with_every_junction_controlled(tmp_path):
    """grid4: netgenerate's 4 x 4 grid of two-lane roads, all 16 junctions controlled, its route
    file of trips routed by duarouter, for 240 s: no collision (SUMO's check and the own), every
    junction crossed, at least 97 % of the demand of the window served, and every controlled car
    on its plan (each car's movement is the one of the lane SUMO has it on, or it would be tens of
    metres off it)."""
    sc = scenario.load(SCENARIOS / "grid4" / "scenario.toml", ["scenario.duration_s=240.0", "outputs.warmup_s=60.0"])
    s = run_scenario(sc, tmp_path / "run").summary
    assert s["status"] == "ok"
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert len(s["junctions"]) == 16 and all(j["vehicles"] > 0 for j in s["junctions"].values())
    assert s["served_share"] >= 0.97
    assert s["max_tracking_error_m"] < 3.2
