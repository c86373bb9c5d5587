"""Movements as a real network has them. Two roads leaving one approach with the same turn (SUMO's
"r" and "R", "l" and "L"): each is its own turning movement, with its own path and its own share of
the approach's count, and a vehicle on either crosses on its own road. U-turns (SUMO's "t") are
movements: counts for them are taken, and a U-turn that the car cannot drive refuses the junction
only where some vehicle makes it."""

import subprocess
import sys

import pandas as pd
import sumolib

from conftest import ROOT, copy_scenario
from nrtraffic.sumo.netbuild import sumo_binary

NODES = """<nodes>
  <node id="C" x="0" y="0" type="priority"/>
  <node id="W" x="-300" y="0"/> <node id="E" x="300" y="0"/> <node id="N" x="0" y="300"/>
  <node id="NE" x="285" y="95"/> <node id="S" x="0" y="-300"/>
</nodes>
"""
EDGES = "<edges>\n" + "".join(
    f'  <edge id="{a}_{b}" from="{a}" to="{b}" numLanes="1" speed="13.89"/>\n'
    for a, b in [("W", "C"), ("C", "E"), ("C", "N"), ("C", "NE"), ("S", "C"), ("C", "S")]) + "</edges>\n"


def _five_legs(tmp_path, extra="", turnarounds=False):
    d = copy_scenario("cross4", tmp_path / "sc", "rate_veh_h = 400.0", "rate_veh_h = 0.0", extra)
    (d / "n.nod.xml").write_text(NODES)
    (d / "n.edg.xml").write_text(EDGES)
    subprocess.run([sumo_binary("netconvert"), "-n", str(d / "n.nod.xml"), "-e", str(d / "n.edg.xml"), "-o",
                    str(d / "net.net.xml"), "--no-turnarounds", str(not turnarounds).lower()], check=True, capture_output=True)
    return d


def test_two_roads_of_one_turn_are_two_movements_that_share_its_count(tmp_path):
    from nrtraffic import scenario
    from nrtraffic.demand import Demand

    d = _five_legs(tmp_path, '\n[[demand.flows]]\napproach = "S_C"\nright = 600.0\nstraight = 100.0\n')
    net = sumolib.net.readNet(str(d / "net.net.xml"))
    dirs = {c.getTo().getID(): c.getDirection() for ln in net.getEdge("S_C").getLanes() for c in ln.getOutgoing()}
    assert dirs["C_E"] in "rR" and dirs["C_NE"] in "rR"  # (the network has the twins this test is about)
    dem = Demand.of(scenario.load(d / "scenario.toml"), duration_s=3600.0)
    mt = dem.movement_table
    assert mt["S_C.right.C_E"][2] == ("S_C", "C_E") and mt["S_C.right.C_NE"][2] == ("S_C", "C_NE")
    assert "S_C.right" not in mt and mt["S_C.straight"][2] == ("S_C", "C_N")
    rate, names, share = dem.approach_rates()["S_C"]
    got = dict(zip(names, share))
    assert rate == 700.0 and got["S_C.right.C_E"] == got["S_C.right.C_NE"] == 300.0 and got["S_C.straight"] == 100.0


def test_a_vehicle_on_either_twin_crosses_on_its_own_road(tmp_path):
    d = _five_legs(tmp_path, '\n[[vehicles]]\nid = "east"\napproach = "S_C.right.C_E"\ndepart_s = 1.0\n'
                             '\n[[vehicles]]\nid = "northeast"\napproach = "S_C.right.C_NE"\ndepart_s = 4.0\n')
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "runners.cli", "run", str(d / "scenario.toml"), "--duration", "60",
                        "--set", "outputs.warmup_s=0", "--out", str(out), "--no-progress"], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    import xml.etree.ElementTree as ET

    trips = {t.get("id"): t for t in ET.parse(out / "tripinfo.xml").getroot().iter("tripinfo")}
    assert trips["east"].get("arrivalLane") == "C_E_0" and trips["northeast"].get("arrivalLane") == "C_NE_0"
    v = pd.read_csv(out / "vehicles.csv").set_index("vehicle_id")
    assert v.loc[["east", "northeast"], "t_exit_s"].notna().all()
    assert (v.loc[["east", "northeast"], "plant_steps"] > 0).all()  # driven under control


def test_u_turns_are_movements_refused_only_where_driven_and_the_car_cannot(tmp_path):
    from nrtraffic import scenario
    from nrtraffic.demand import Demand

    flows = '\n[[demand.flows]]\napproach = "S_C"\nstraight = 300.0\nu_turn = 60.0\n'
    d = _five_legs(tmp_path / "a", flows, turnarounds=True)
    net = sumolib.net.readNet(str(d / "net.net.xml"))
    assert any(c.getDirection() == "t" for ln in net.getEdge("S_C").getLanes() for c in ln.getOutgoing())
    dem = Demand.of(scenario.load(d / "scenario.toml"), duration_s=3600.0)
    uturn = [r for r, (a, t, _) in dem.movement_table.items() if a == "S_C" and t == "uturn"]
    assert len(uturn) == 1 and dem.movement_table[uturn[0]][2][1] == "C_S"
    rate, names, share = dem.approach_rates()["S_C"]
    assert dict(zip(names, share))[uturn[0]] == 60.0
    assert sum(1 for _, r, *_ in dem.departures() if r == uturn[0]) > 20  # about 60 in the hour
    # one lane each way: the U-turn's radius is half a lane width, tighter than the car's smallest
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "runners.cli", "run", str(d / "scenario.toml"), "--duration", "600",
                        "--out", str(out), "--no-progress"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2 and f"movement {uturn[0]}: its path turns on a radius of" in r.stderr, r.stderr
    assert "leave the U-turn out of the demand" in r.stderr
    # the same junction without U-turn demand runs: the U-turns no vehicle makes are left out
    d2 = _five_legs(tmp_path / "b", '\n[[demand.flows]]\napproach = "S_C"\nstraight = 300.0\n', turnarounds=True)
    out2 = tmp_path / "run2"
    r = subprocess.run([sys.executable, "-m", "runners.cli", "run", str(d2 / "scenario.toml"), "--duration", "60",
                        "--set", "outputs.warmup_s=0", "--out", str(out2), "--no-progress"], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
