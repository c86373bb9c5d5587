"""Movement relations at a junction, decided from the paths themselves (pure geometry).

Two movements are

- ``same_lane`` when they enter on the same lane (rear-end spacing applies),
- ``conflict`` when their centre lines inside the merging zone come closer than a distance (they
  cross) or they leave on the same lane (they merge): only one of them may be in the merging zone
  at a time,
- ``compatible`` otherwise (no constraint between them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SAME_LANE, CONFLICT, COMPATIBLE = "same_lane", "conflict", "compatible"


@dataclass(frozen=True)
class MovementGeometry:
    """What the classification needs of a movement: its entry lane, exit lane and the points of
    its path inside the merging zone [m]."""

    name: str
    entry_lane: str
    exit_lane: str
    zone_points: np.ndarray  # (n, 2)


def min_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance [m] between two densely sampled polylines (point to point)."""
    if len(a) == 0 or len(b) == 0:
        return np.inf
    d = a[:, None, :] - b[None, :, :]
    return float(np.sqrt(np.min(np.einsum("ijk,ijk->ij", d, d))))


def classify(movements: list[MovementGeometry], conflict_distance_m: float) -> dict[tuple[str, str], str]:
    """Relation of every ordered pair of distinct movements."""
    out: dict[tuple[str, str], str] = {}
    for i, a in enumerate(movements):
        for b in movements[i + 1:]:
            if a.entry_lane == b.entry_lane:
                rel = SAME_LANE
            elif a.exit_lane == b.exit_lane:
                rel = CONFLICT
            elif min_distance(a.zone_points, b.zone_points) < conflict_distance_m:
                rel = CONFLICT
            else:
                rel = COMPATIBLE
            out[(a.name, b.name)] = out[(b.name, a.name)] = rel
    return out
