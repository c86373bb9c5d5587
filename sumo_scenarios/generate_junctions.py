"""Regenerate the plain XML and networks of the junction scenarios (cross4, cross4_2lane, tee3,
cross4_curved, corridor3, cross4_short), and convert the hand-drawn station_mill.

Every arm is one lane each way (cross4_2lane: two lanes out, and in two lanes and a left-turn
lane, with the lane use of ``net.con.xml``), 520 m long, 50 km/h (13.89 m/s); the junction node "C" is at the
origin. cross4_curved bends its north arm on an arc of radius 600 m. The networks are built with
junction type "priority" (the type nrtraffic runs on: the vehicles it controls pass the junction
under moveToXY); the baselines rebuild them with SUMO's own junction control. Each folder also
gets ``demand.rou.xml`` (its scenario's demand for its seed) and a ``.sumocfg`` that opens both in
sumo-gui.

Run:  python sumo_scenarios/generate_junctions.py
"""

from __future__ import annotations

import math
from pathlib import Path

from nrtraffic import scenario
from nrtraffic.demand import Demand
from nrtraffic.sumo.netbuild import build_network

HERE = Path(__file__).resolve().parent
ARM = 520.0  # [m]
SPEED = 13.89  # [m/s]
CURVE_R = 600.0  # [m]
SHORT_ARM = 50.0  # cross4_short: the link into the junction [m]


def _arc_points(n=130):
    """North arm of cross4_curved from C (0, 0) outwards, leaving C heading north."""
    th_max = ARM / CURVE_R
    return [(-CURVE_R + CURVE_R * math.cos(t), CURVE_R * math.sin(t)) for t in
            (th_max * k / n for k in range(n + 1))]


def write(name: str, arms: dict[str, tuple[float, float]], shapes: dict[str, list] | None = None,
          lanes_in: int = 1, lanes_out: int = 1, connections: str = "") -> None:
    d = HERE / name
    d.mkdir(exist_ok=True)
    shapes = shapes or {}
    nodes = ['    <node id="C" x="0.0" y="0.0" type="priority"/>']
    edges = []
    for arm, (x, y) in arms.items():
        nodes.append(f'    <node id="{arm}" x="{x:.4f}" y="{y:.4f}" type="priority"/>')
        shp_out = shp_in = ""
        if arm in shapes:
            pts = shapes[arm]
            shp_out = ' shape="' + " ".join(f"{px:.4f},{py:.4f}" for px, py in pts) + '"'
            shp_in = ' shape="' + " ".join(f"{px:.4f},{py:.4f}" for px, py in reversed(pts)) + '"'
        edges.append(f'    <edge id="{arm}_in" from="{arm}" to="C" numLanes="{lanes_in}" speed="{SPEED}"{shp_in}/>')
        edges.append(f'    <edge id="{arm}_out" from="C" to="{arm}" numLanes="{lanes_out}" speed="{SPEED}"{shp_out}/>')
    (d / "net.nod.xml").write_text("<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n")
    (d / "net.edg.xml").write_text("<edges>\n" + "\n".join(edges) + "\n</edges>\n")
    extra = []
    if connections:
        (d / "net.con.xml").write_text("<connections>\n" + connections + "</connections>\n")
        extra = ["--connection-files", str(d / "net.con.xml")]
    build_network(d / "net.nod.xml", d / "net.edg.xml", d / "net.net.xml", extra)
    write_view(name)


def write_view(name: str, network: str = "net.net.xml") -> None:
    """``demand.rou.xml`` and ``<name>.sumocfg`` of a scenario folder."""
    d = HERE / name
    # the scenario's demand for its own seed and duration, to watch under SUMO's own driving
    # (the junction as netconvert built it); runs are driven by `nrtraffic run`
    sc = scenario.load(d / "scenario.toml")
    Demand.of(sc).write(d / "demand.rou.xml", sc.vehicle.params())
    (d / f"{name}.sumocfg").write_text(
        "<configuration>\n    <!-- sumo-gui -c: the network with the scenario's demand for its seed, driven by SUMO;\n"
        "         runs are driven by `nrtraffic run` (make nets writes this file and demand.rou.xml) -->\n"
        f'    <input>\n        <net-file value="{network}"/>\n        <route-files value="demand.rou.xml"/>\n'
        '    </input>\n</configuration>\n'
    )


def two_lane_connections(arms: list[str]) -> str:
    """cross4_2lane's lane use: on every approach lane 0 turns right or goes straight, lane 1 goes
    straight, lane 2 is the left-turn lane; right turns end on the outer lane, left turns on the
    inner one, straight on keeps its lane."""
    order = {"N": 0, "E": 1, "S": 2, "W": 3}  # clockwise
    clockwise = sorted(arms, key=order.get)
    out = []
    for k, arm in enumerate(clockwise):
        # driving on the right: from N (heading south) the right turn goes to W, the left turn to E
        right, straight, left = clockwise[(k + 3) % 4], clockwise[(k + 2) % 4], clockwise[(k + 1) % 4]
        for fl, to, tl in ((0, right, 0), (0, straight, 0), (1, straight, 1), (2, left, 1)):
            out.append(f'    <connection from="{arm}_in" to="{to}_out" fromLane="{fl}" toLane="{tl}"/>\n')
    return "".join(out)


# corridor3: an arterial west-east through J1, J2 and J3 (280 m and 380 m apart), a side street
# north and south at each; the arterial has the higher priority (SUMO's priority baseline)
CORRIDOR_J = {"J1": 0.0, "J2": 280.0, "J3": 660.0}  # x of the junctions [m]
CORRIDOR_ENDS = 450.0  # length of the arterial beyond J1 and J3 [m]
CORRIDOR_SIDE = {"J1": (350.0, 350.0), "J2": (360.0, 340.0), "J3": (350.0, 370.0)}  # north, south arm [m]


def corridor3() -> None:
    d = HERE / "corridor3"
    d.mkdir(exist_ok=True)
    xs = CORRIDOR_J
    nodes = [f'    <node id="{j}" x="{x:.1f}" y="0.0" type="priority"/>' for j, x in xs.items()]
    nodes += [f'    <node id="W" x="{-CORRIDOR_ENDS:.1f}" y="0.0" type="priority"/>',
              f'    <node id="E" x="{xs["J3"] + CORRIDOR_ENDS:.1f}" y="0.0" type="priority"/>']
    edges = []

    def both(a, b, prio):
        for f, t in ((a, b), (b, a)):
            edges.append(f'    <edge id="{f}_{t}" from="{f}" to="{t}" numLanes="1" speed="{SPEED}" priority="{prio}"/>')

    chain = ["W", *xs, "E"]
    for a, b in zip(chain, chain[1:]):
        both(a, b, 3)
    for k, (j, x) in enumerate(xs.items(), start=1):
        north, south = CORRIDOR_SIDE[j]
        nodes.append(f'    <node id="N{k}" x="{x:.1f}" y="{north:.1f}" type="priority"/>')
        nodes.append(f'    <node id="S{k}" x="{x:.1f}" y="{-south:.1f}" type="priority"/>')
        both(f"N{k}", j, 1)
        both(f"S{k}", j, 1)
    (d / "net.nod.xml").write_text("<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n")
    (d / "net.edg.xml").write_text("<edges>\n" + "\n".join(edges) + "\n</edges>\n")
    build_network(d / "net.nod.xml", d / "net.edg.xml", d / "net.net.xml")
    write_view("corridor3")


def cross4_short() -> None:
    """cross4 whose arms are 50 m links fed by 470 m roads upstream (a node between them, as at a
    minor side road or a change of road type): the control zone can only be as long as the 50 m
    link allows."""
    d = HERE / "cross4_short"
    d.mkdir(exist_ok=True)
    nodes = ['    <node id="C" x="0.0" y="0.0" type="priority"/>']
    edges = []
    for arm, (ux, uy) in {"N": (0, 1), "E": (1, 0), "S": (0, -1), "W": (-1, 0)}.items():
        nodes.append(f'    <node id="{arm}" x="{ux * ARM:.1f}" y="{uy * ARM:.1f}" type="priority"/>')
        nodes.append(f'    <node id="{arm}m" x="{ux * SHORT_ARM:.1f}" y="{uy * SHORT_ARM:.1f}" type="priority"/>')
        for f, t, name in ((arm, f"{arm}m", f"{arm}_up_in"), (f"{arm}m", "C", f"{arm}_in"),
                           ("C", f"{arm}m", f"{arm}_out"), (f"{arm}m", arm, f"{arm}_up_out")):
            edges.append(f'    <edge id="{name}" from="{f}" to="{t}" numLanes="1" speed="{SPEED}"/>')
    (d / "net.nod.xml").write_text("<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n")
    (d / "net.edg.xml").write_text("<edges>\n" + "\n".join(edges) + "\n</edges>\n")
    build_network(d / "net.nod.xml", d / "net.edg.xml", d / "net.net.xml")
    write_view("cross4_short")


def station_mill() -> None:
    """station_mill is drawn by hand (its plain XML is the source, not written here): only
    converted, with netconvert's options of ``station_mill/README.md``."""
    d = HERE / "station_mill"
    build_network(d / "station_mill.nod.xml", d / "station_mill.edg.xml", d / "station_mill.net.xml",
                  ["--junctions.internal-link-detail", "20"])
    write_view("station_mill", "station_mill.net.xml")


def main() -> None:
    four = {"N": (0.0, ARM), "E": (ARM, 0.0), "S": (0.0, -ARM), "W": (-ARM, 0.0)}
    write("cross4", four)
    write("cross4_2lane", four, lanes_in=3, lanes_out=2, connections=two_lane_connections(list(four)))
    write("tee3", {"E": (ARM, 0.0), "S": (0.0, -ARM), "W": (-ARM, 0.0)})
    arc = _arc_points()
    curved = dict(four, N=arc[-1])
    write("cross4_curved", curved, shapes={"N": arc})
    corridor3()
    cross4_short()
    station_mill()


if __name__ == "__main__":
    main()
