"""Regenerate the plain XML and the networks of the paper_curved scenario.

Paper section 4.1: a 430 m, 30 degree arc of the circle z1^2 + (z2 - R)^2 = R^2, R = 430/(pi/6)
= 821.24 m, starting at the origin heading east (+x): 400 m control zone + 30 m merging zone. A 60 m
straight lead-in (where SUMO inserts the vehicles) and a 150 m straight exit continue it
tangentially. ``straight.net.xml`` is the same road with the arc straightened (paper's variant).

Run:  python sumo_scenarios/paper_curved/generate.py
"""

from __future__ import annotations

import math
from pathlib import Path

from nrtraffic.sumo.netbuild import build_network

HERE = Path(__file__).resolve().parent
ARC_LENGTH = 430.0  # [m]
RADIUS = ARC_LENGTH / (math.pi / 6.0)  # [m] = 821.24
LEAD_IN = 60.0  # [m]
EXIT = 150.0  # [m]
SPEED = 20.0  # [m/s] lane speed limit (above the 13.4 m/s entry speed)
POINT_SPACING = 1.0  # [m] between shape points of the arc


def _write(name: str, curved: bool) -> None:
    n = int(round(ARC_LENGTH / POINT_SPACING))
    if curved:
        th = [ARC_LENGTH / RADIUS * k / n for k in range(n + 1)]
        arc = [(RADIUS * math.sin(t), RADIUS * (1.0 - math.cos(t))) for t in th]
        end_heading = ARC_LENGTH / RADIUS
    else:
        arc = [(ARC_LENGTH * k / n, 0.0) for k in range(n + 1)]
        end_heading = 0.0
    ex, ey = arc[-1]
    out = (ex + EXIT * math.cos(end_heading), ey + EXIT * math.sin(end_heading))
    nodes = HERE / f"{name}.nod.xml"
    edges = HERE / f"{name}.edg.xml"
    nodes.write_text(
        "<nodes>\n"
        f'    <node id="entry" x="{-LEAD_IN:.3f}" y="0.000" type="priority"/>\n'
        '    <node id="cz" x="0.000" y="0.000" type="priority" radius="0"/>\n'
        f'    <node id="mz_end" x="{ex:.4f}" y="{ey:.4f}" type="priority" radius="0"/>\n'
        f'    <node id="exit" x="{out[0]:.4f}" y="{out[1]:.4f}" type="priority"/>\n'
        "</nodes>\n"
    )
    shape = " ".join(f"{x:.4f},{y:.4f}" for x, y in arc)
    common = f'numLanes="1" speed="{SPEED}" spreadType="center"'
    edges.write_text(
        "<edges>\n"
        f'    <edge id="lead_in" from="entry" to="cz" {common}/>\n'
        f'    <edge id="road" from="cz" to="mz_end" {common} shape="{shape}"/>\n'
        f'    <edge id="exit" from="mz_end" to="exit" {common}/>\n'
        "</edges>\n"
    )
    build_network(nodes, edges, HERE / f"{name}.net.xml", ["--junctions.corner-detail", "0"])


if __name__ == "__main__":
    _write("curved", curved=True)
    _write("straight", curved=False)
