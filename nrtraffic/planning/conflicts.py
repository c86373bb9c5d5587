"""Movement relations at a junction, decided from the paths themselves (pure geometry).

Two movements are

- ``same_lane`` when they enter on the same lane (rear-end spacing applies),
- ``conflict`` when they leave on the same lane (they merge), or when the areas their car bodies
  sweep inside the merging zone overlap (they cross or pass too close): only one of them may be in
  the merging zone at a time,
- ``compatible`` otherwise (no constraint between them).

The swept area of a movement is the union of the car's rectangle (length x width, widened by a
lateral clearance on each side: the band the car may leave its centre line by) placed at every
sampled point of the path inside the zone, along the path's heading. A test of centre-line
distance alone is not enough: two cars crossing at an angle touch corner to side while their
centre lines stay more than a car width apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from nrtraffic.geometry import rectangles_touch

SAME_LANE, CONFLICT, COMPATIBLE = "same_lane", "conflict", "compatible"


@dataclass(frozen=True)
class MovementGeometry:
    """What the classification needs of a movement: its entry lane, exit lane and the points of
    its path (the car's centre) inside the merging zone [m], densely sampled (no more than about
    a quarter of the car's width apart)."""

    name: str
    entry_lane: str
    exit_lane: str
    zone_points: np.ndarray  # (n, 2)
    zone_s: np.ndarray | None = None  # (n,) path position of each point [m] (for conflict areas)
    # (n,) the body's heading at each point [rad]; None: the heading of the polyline of centres (a
    # body whose centre follows the path); given for a body placed otherwise (a SUMO-driven car,
    # whose front bumper follows the lane with the lane's heading)
    zone_heading: np.ndarray | None = None

    @property
    def body_headings(self) -> np.ndarray:
        return headings(self.zone_points) if self.zone_heading is None else self.zone_heading


def min_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance [m] between two densely sampled polylines (point to point)."""
    if len(a) == 0 or len(b) == 0:
        return np.inf
    d = a[:, None, :] - b[None, :, :]
    return float(np.sqrt(np.min(np.einsum("ijk,ijk->ij", d, d))))


def headings(points: np.ndarray) -> np.ndarray:
    """Heading [rad] of a polyline at each point (central differences)."""
    if len(points) < 2:
        return np.zeros(len(points))
    d = np.gradient(points, axis=0)
    return np.arctan2(d[:, 1], d[:, 0])


def boxes_overlap(c1: np.ndarray, h1: np.ndarray, c2: np.ndarray, h2: np.ndarray, length: float,
                  width: float) -> np.ndarray:
    """Separating-axis test of rectangles of one size (``length`` x ``width`` [m]) with centres
    ``c1``, ``c2`` (..., 2) [m] and headings ``h1``, ``h2`` [rad], broadcast against each other.
    True where they overlap (touching counts)."""
    u1 = np.stack([np.cos(h1), np.sin(h1)], -1)
    u2 = np.stack([np.cos(h2), np.sin(h2)], -1)
    n1 = np.stack([-u1[..., 1], u1[..., 0]], -1)
    n2 = np.stack([-u2[..., 1], u2[..., 0]], -1)
    d = c2 - c1
    hl, hw = 0.5 * length, 0.5 * width
    overlap = np.ones(np.broadcast_shapes(d.shape[:-1], u1.shape[:-1], u2.shape[:-1]), dtype=bool)
    for ax in (u1, n1, u2, n2):
        r1 = hl * np.abs(np.sum(u1 * ax, -1)) + hw * np.abs(np.sum(n1 * ax, -1))
        r2 = hl * np.abs(np.sum(u2 * ax, -1)) + hw * np.abs(np.sum(n2 * ax, -1))
        overlap &= np.abs(np.sum(d * ax, -1)) <= r1 + r2
    return overlap


def swept_overlap(a: np.ndarray, b: np.ndarray, length: float, width: float, ha: np.ndarray | None = None,
                  hb: np.ndarray | None = None) -> bool:
    """Whether a car of ``length`` x ``width`` [m] following polyline ``a`` and one following
    ``b`` can touch anywhere along them (each at any of its sampled positions); ``ha``, ``hb``
    the bodies' headings [rad] (default: the polylines')."""
    if len(a) == 0 or len(b) == 0:
        return False
    ha = headings(a) if ha is None else ha
    hb = headings(b) if hb is None else hb
    return _touch_span(np.ascontiguousarray(a), np.ascontiguousarray(ha), np.ascontiguousarray(b),
                       np.ascontiguousarray(hb), length, width)[0] >= 0


def classify(movements: list[MovementGeometry], length_m: float, width_m: float,
             lateral_clearance_m: float) -> dict[tuple[str, str], str]:
    """Relation of every ordered pair of distinct movements, for cars of ``length_m`` x
    ``width_m`` [m] that may leave their centre line by up to ``lateral_clearance_m`` [m]."""
    width = width_m + 2.0 * lateral_clearance_m
    out: dict[tuple[str, str], str] = {}
    for i, a in enumerate(movements):
        for b in movements[i + 1:]:
            if a.entry_lane == b.entry_lane:
                rel = SAME_LANE
            elif a.exit_lane == b.exit_lane:
                rel = CONFLICT
            elif swept_overlap(a.zone_points, b.zone_points, length_m, width, a.body_headings, b.body_headings):
                rel = CONFLICT
            else:
                rel = COMPATIBLE
            out[(a.name, b.name)] = out[(b.name, a.name)] = rel
    return out


def conflict_areas(movements: list[MovementGeometry], relations: dict, length_m: float, width_m: float,
                   lateral_clearance_m: float) -> dict[tuple[str, str], tuple[float, float]]:
    """For every ordered pair ``(a, b)`` of conflicting movements whose bodies can touch, the
    conflict area on ``a``'s path: the stretch ``[s_in, s_out]`` of ``a``'s positions (its
    ``zone_s``) at which its body, widened by the clearance as in :func:`classify`, touches a body
    anywhere on ``b``'s path inside the zone. ``a`` occupies the area from reaching ``s_in`` until
    leaving ``s_out``."""
    width = width_m + 2.0 * lateral_clearance_m
    by_name = {m.name: m for m in movements}
    out = {}
    for (a, b), rel in relations.items():
        if rel != CONFLICT:
            continue
        ma, mb = by_name[a], by_name[b]
        if ma.zone_s is None or len(ma.zone_points) == 0 or len(mb.zone_points) == 0:
            continue
        i0, i1 = _touch_span(np.ascontiguousarray(ma.zone_points), np.ascontiguousarray(ma.body_headings),
                             np.ascontiguousarray(mb.zone_points), np.ascontiguousarray(mb.body_headings), length_m,
                             width)
        if i0 >= 0:
            out[(a, b)] = (float(ma.zone_s[i0]), float(ma.zone_s[i1]))
    return out


@njit(cache=True, error_model="numpy")
def _touch_span(a, ha, b, hb, length, width):
    """First and last index of ``a``'s points whose rectangle touches one at any of ``b``'s points
    ((-1, -1) when none does)."""
    r2 = length * length + width * width
    first = -1
    last = -1
    for i in range(a.shape[0]):
        for j in range(b.shape[0]):
            dx = b[j, 0] - a[i, 0]
            dy = b[j, 1] - a[i, 1]
            if dx * dx + dy * dy <= r2 and rectangles_touch(a[i, 0], a[i, 1], ha[i], b[j, 0], b[j, 1], hb[j],
                                                             length, width):
                if first < 0:
                    first = i
                last = i
                break
    return first, last
