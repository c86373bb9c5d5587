"""The road that feeds an approach: demand starts at its beginning, across nodes that only join
two roads, and the network file says which edges those are (read with sumolib, independently)."""

import sumolib

from conftest import ROOT
from nrtraffic import scenario
from nrtraffic.demand import Demand
from nrtraffic.junction import Layout

SCENARIOS = ROOT / "sumo_scenarios"


def test_a_short_arm_fed_through_a_node_starts_its_routes_upstream():
    sc = scenario.load(SCENARIOS / "cross4_short" / "scenario.toml")
    layout = Layout(sc, sc.network_path)
    net = sumolib.net.readNet(str(sc.network_path))
    for route, (edge, _, (e_in, e_out)) in layout.movement_table.items():
        (feeder,) = layout.feeders[route]
        # the feeder ends where the approach begins, at a node of two roads only, and leads into it
        f, a = net.getEdge(feeder), net.getEdge(e_in)
        assert f.getToNode() is a.getFromNode()
        assert {e.getID() for e in f.getOutgoing()} >= {e_in}
        assert f.getFromNode().getID() in {"N", "E", "S", "W"}  # the network's edge: nothing feeds it
        assert Demand.of(sc).route_edges(route) == (feeder, e_in, e_out)


def test_approaches_that_start_at_a_junction_or_the_network_edge_have_no_feeder():
    for name in ("cross4", "corridor3", "cross4_2lane"):
        sc = scenario.load(SCENARIOS / name / "scenario.toml")
        layout = Layout(sc, sc.network_path)
        assert all(f == () for f in layout.feeders.values()), name
