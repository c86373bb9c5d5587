"""Regenerate the grid4 scenario's network and demand: SUMO's netgenerate 4 x 4 grid, 250 m
blocks, two lanes each way (13.89 m/s), 250 m roads in from each side; one hour of trips from every
entry to a random exit (SUMO's randomTrips.py, routed by duarouter on the shortest path), the same
departure rate at every entry.

Run:  python sumo_scenarios/grid4/generate.py [--rate VEH_H_PER_ENTRY] [--routes FILE]

``make nets`` writes demand.rou.xml (200 veh/h per entry) and demand_high.rou.xml (300 veh/h per
entry, 1.5 times as much: ``--set 'demand.sumo_routes="demand_high.rou.xml"'``).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

from nrtraffic.sumo.netbuild import sumo_binary

HERE = Path(__file__).resolve().parent
ENTRIES = 16  # roads into the grid: four on each side
SEED = 42


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=200.0, help="departures per hour at each entry (default 200)")
    ap.add_argument("--routes", default="demand.rou.xml", help="route file to write (default demand.rou.xml)")
    ap.add_argument("--no-network", action="store_true", help="keep net.net.xml as it is")
    args = ap.parse_args(argv)
    net = HERE / "net.net.xml"
    if not args.no_network:
        subprocess.run([sumo_binary("netgenerate"), "--grid", "--grid.number", "4", "--grid.length", "250",
                        "--grid.attach-length", "250", "--default.lanenumber", "2", "--default.speed", "13.89",
                        "--no-turnarounds", "true", "--seed", str(SEED), "-o", str(net)], check=True)
    import sumo

    tools = Path(sumo.__file__).parent / "tools"
    period = 3600.0 / (args.rate * ENTRIES)  # one departure every `period` seconds over all entries
    subprocess.run([sys.executable, str(tools / "randomTrips.py"), "-n", str(net), "--fringe-factor", "max",
                    "--period", f"{period:.6f}", "--begin", "0", "--end", "3600", "--seed", str(SEED),
                    "--trip-attributes", 'departLane="best" departSpeed="max"', "--prefix", "g",
                    "--min-distance", "300", "-o", str(HERE / "trips.trips.xml"),
                    "--route-file", str(HERE / args.routes), "--validate"], check=True)
    (HERE / "trips.trips.xml").unlink()
    routes = HERE / args.routes  # (without the tools' comments, which hold this machine's paths)
    routes.write_text(re.sub(r"<!--.*?-->\s*", "", routes.read_text(), flags=re.S))


if __name__ == "__main__":
    main()
