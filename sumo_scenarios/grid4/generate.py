"""Regenerate the grid4 scenario's network and demand: SUMO's netgenerate 4 x 4 grid, 250 m
blocks, two lanes each way (13.89 m/s), 250 m roads in from each side; one hour of trips from every
entry to a random exit (SUMO's randomTrips.py, routed by duarouter on the shortest path), the same
departure rate at every entry.

Run:  python sumo_scenarios/grid4/generate.py [--rate VEH_H_PER_ENTRY] [--routes FILE] [--no-network]

``make nets`` writes demand.rou.xml (200 veh/h per entry) and demand_high.rou.xml (300 veh/h per
entry, 1.5 times as much: ``--set 'demand.sumo_routes="demand_high.rou.xml"'``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nrtraffic.sumo.netbuild import grid_network, random_trips

HERE = Path(__file__).resolve().parent


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=200.0, help="departures per hour at each entry (default 200)")
    ap.add_argument("--routes", default="demand.rou.xml", help="route file to write (default demand.rou.xml)")
    ap.add_argument("--no-network", action="store_true", help="keep net.net.xml as it is")
    args = ap.parse_args(argv)
    net = HERE / "net.net.xml"
    if not args.no_network:
        grid_network(4, net)
    random_trips(net, HERE / args.routes, args.rate, entries=16, end_s=3600.0)


if __name__ == "__main__":
    main()
