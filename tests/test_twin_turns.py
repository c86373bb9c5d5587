"""Two roads leaving one approach with the same turn (SUMO's "r" and "R", "l" and "L"): each is its
own turning movement, with its own path and its own share of the approach's count, and a route file's
vehicle on either is mapped to the one its route takes."""

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
    for a, b in [("W", "C"), ("C", "E"), ("C", "N"), ("C", "NE"), ("S", "C")]) + "</edges>\n"


def _five_legs(tmp_path, extra=""):
    d = copy_scenario("cross4", tmp_path / "sc", "rate_veh_h = 400.0", "rate_veh_h = 0.0", extra)
    (d / "n.nod.xml").write_text(NODES)
    (d / "n.edg.xml").write_text(EDGES)
    subprocess.run([sumo_binary("netconvert"), "-n", str(d / "n.nod.xml"), "-e", str(d / "n.edg.xml"), "-o",
                    str(d / "net.net.xml"), "--no-turnarounds", "true"], check=True, capture_output=True)
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
