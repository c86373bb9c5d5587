"""Reading SUMO networks before a simulation starts (sumolib)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

TURNS = {"l": "left", "L": "left", "s": "straight", "r": "right", "R": "right", "t": "uturn"}


class NetworkError(ValueError):
    """The network does not have what the scenario names."""


@dataclass(frozen=True)
class JunctionMovement:
    """One connection through a junction: incoming edge -> outgoing edge, with SUMO's direction."""

    in_edge: str
    out_edge: str
    turn: str  # left | straight | right | uturn

    @property
    def name(self) -> str:
        return f"{self.in_edge}.{self.turn}"


def junction_movements(net_path: Path, junction_id: str) -> tuple[list[JunctionMovement], tuple[float, float]]:
    """The movements through ``junction_id`` (lane 0 of every incoming edge) and its position."""
    import sumolib

    net = sumolib.net.readNet(str(net_path), withInternal=True)
    if not net.hasNode(junction_id):
        raise NetworkError(f"junction {junction_id!r} is not in {net_path}")
    node = net.getNode(junction_id)
    out = []
    for edge in node.getIncoming():
        if edge.getFunction() == "internal":
            continue
        lane = edge.getLanes()[0]
        for con in lane.getOutgoing():
            turn = TURNS.get(con.getDirection(), con.getDirection())
            if turn == "uturn":
                continue
            out.append(JunctionMovement(edge.getID(), con.getTo().getID(), turn))
    if not out:
        raise NetworkError(f"junction {junction_id!r} has no movements")
    x, y = node.getCoord()
    return out, (float(x), float(y))
