"""Regenerate the plain XML and the network of the paper_cbf scenario (paper section 4.2):
a straight 300 m road along +x from the origin, then a 60 m exit.

Run:  python sumo_scenarios/paper_cbf/generate.py
"""

from __future__ import annotations

from pathlib import Path

from nrtraffic.sumo.netbuild import build_network

HERE = Path(__file__).resolve().parent


def main() -> None:
    nodes = HERE / "straight.nod.xml"
    edges = HERE / "straight.edg.xml"
    nodes.write_text(
        "<nodes>\n"
        '    <node id="start" x="0.0" y="0.0" type="priority"/>\n'
        '    <node id="end" x="300.0" y="0.0" type="priority" radius="0"/>\n'
        '    <node id="exit" x="360.0" y="0.0" type="priority"/>\n'
        "</nodes>\n"
    )
    edges.write_text(
        "<edges>\n"
        '    <edge id="road" from="start" to="end" numLanes="1" speed="13.9" spreadType="center"/>\n'
        '    <edge id="exit" from="end" to="exit" numLanes="1" speed="13.9" spreadType="center"/>\n'
        "</edges>\n"
    )
    build_network(nodes, edges, HERE / "straight.net.xml", ["--junctions.corner-detail", "0"])


if __name__ == "__main__":
    main()
