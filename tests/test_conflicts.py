"""Swept-body conflict test (planning/conflicts.py) against closed-form geometry."""

import math

import numpy as np
import pytest

from nrtraffic.geometry import rectangles_touch, touching_pairs
from nrtraffic.planning.conflicts import COMPATIBLE, CONFLICT, SAME_LANE, MovementGeometry, boxes_overlap, classify

L, W = 4.8, 1.9


def _corners(c, h, length, width):
    u = np.array([math.cos(h), math.sin(h)])
    n = np.array([-u[1], u[0]])
    return [c + sx * length / 2 * u + sy * width / 2 * n for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1))]


def _inside(p, c, h, length, width, eps=1e-12):
    d = p - c
    return (abs(d @ [math.cos(h), math.sin(h)]) <= length / 2 + eps
            and abs(d @ [-math.sin(h), math.cos(h)]) <= width / 2 + eps)


def _overlap_by_sampling(c1, h1, c2, h2):
    """Independent reference: rectangles overlap iff a point of one's boundary or interior lies in
    the other; sampled densely on both rectangles' edges (convex shapes meet on an edge)."""
    for (ca, ha), (cb, hb) in (((c1, h1), (c2, h2)), ((c2, h2), (c1, h1))):
        k = _corners(ca, ha, L, W)
        for i in range(4):
            for s in np.linspace(0.0, 1.0, 200):
                if _inside(k[i] + s * (k[(i + 1) % 4] - k[i]), cb, hb, L, W):
                    return True
    return False


@pytest.mark.parametrize("compiled", [False, True])
def test_separating_axes_agree_with_sampled_geometry(compiled):
    rng = np.random.default_rng(3)
    agree = 0
    for _ in range(400):
        c1, c2 = rng.uniform(-3, 3, 2), rng.uniform(-3, 3, 2)
        h1, h2 = rng.uniform(-math.pi, math.pi, 2)
        if compiled:  # the own collision check's scalar twin
            got = rectangles_touch(c1[0], c1[1], h1, c2[0], c2[1], h2, L, W)
        else:
            got = bool(boxes_overlap(c1, h1, c2, h2, L, W))
        ref = _overlap_by_sampling(c1, h1, c2, h2)
        agree += got == ref
    assert agree >= 398  # sampling can miss a contact thinner than its 2.4 cm step


def test_touching_pairs_finds_every_overlapping_pair():
    rng = np.random.default_rng(5)
    c = rng.uniform(0, 30, (60, 2))
    h = rng.uniform(-math.pi, math.pi, 60)
    ii, jj = touching_pairs(c[:, 0], c[:, 1], h, L, W)
    got = set(zip(ii.tolist(), jj.tolist()))
    ref = {(i, j) for i in range(60) for j in range(i + 1, 60) if boxes_overlap(c[i], h[i], c[j], h[j], L, W)}
    assert len(ref) > 5 and got == ref


def test_touching_pairs_on_a_road_network_scale_matches_every_pair_tested():
    """400 cars on 2 km x 2 km with negative coordinates, some in dense clusters (queues): the
    pairs found on the grid of cells are those that every pair tested one by one gives, in order."""
    rng = np.random.default_rng(11)
    c = np.vstack([rng.uniform(-1000, 1000, (250, 2)), rng.normal((-300.0, 420.0), 6.0, (150, 2))])
    h = rng.uniform(-math.pi, math.pi, len(c))
    ii, jj = touching_pairs(c[:, 0], c[:, 1], h, L, W)
    ref = [(i, j) for i in range(len(c)) for j in range(i + 1, len(c)) if boxes_overlap(c[i], h[i], c[j], h[j], L, W)]
    assert len(ref) > 20 and list(zip(ii.tolist(), jj.tolist())) == ref


@pytest.mark.parametrize("clearance", [0.0, 0.3, 0.6, 0.7, 1.0])
def test_parallel_lanes_conflict_exactly_when_the_widened_bodies_touch(clearance):
    """Two straight paths 3.2 m apart (a lane width): the widened bodies touch when
    W + 2 clearance >= 3.2, i.e. clearance >= 0.65 m."""
    x = np.arange(-15.0, 15.0, 0.25)
    a = MovementGeometry("a", "la", "oa", np.c_[x, np.zeros_like(x)])
    b = MovementGeometry("b", "lb", "ob", np.c_[x[::-1], np.full_like(x, 3.2)])  # opposite direction
    rel = classify([a, b], L, W, clearance)[("a", "b")]
    assert rel == (CONFLICT if W + 2 * clearance >= 3.2 else COMPATIBLE)


@pytest.mark.parametrize("clearance,expected", [(0.1, COMPATIBLE), (0.3, CONFLICT)])
def test_front_reaching_a_crossing_path(clearance, expected):
    """Path a ends at the origin heading +x (the car's front is then at x = 2.4 m); path b runs
    along x = 3.55 m. Centre lines stay 3.55 m apart, yet the bodies touch once b's widened half
    width reaches a's front: 0.95 + clearance >= 3.55 - 2.4, i.e. clearance >= 0.2 m."""
    x = np.arange(-15.0, 1e-9, 0.25)
    y = np.arange(-15.0, 15.0, 0.25)
    a = MovementGeometry("a", "la", "oa", np.c_[x, np.zeros_like(x)])
    b = MovementGeometry("b", "lb", "ob", np.c_[np.full_like(y, 3.55), y])
    assert classify([a, b], L, W, clearance)[("a", "b")] == expected


def test_same_entry_and_same_exit_lanes():
    p = np.c_[np.arange(0.0, 10.0, 0.25), np.zeros(40)]
    far = p + [0.0, 50.0]
    rel = classify([MovementGeometry("a", "in", "o1", p), MovementGeometry("b", "in", "o2", far),
                    MovementGeometry("c", "in2", "o1", far + [0.0, 50.0])], L, W, 0.0)
    assert rel[("a", "b")] == rel[("b", "a")] == SAME_LANE
    assert rel[("a", "c")] == CONFLICT  # merge onto one exit lane, however far apart in the zone
    assert rel[("b", "c")] == COMPATIBLE


@pytest.mark.parametrize("clearance", [0.0, 0.25, 0.5])
def test_conflict_area_of_a_right_angle_crossing_is_the_closed_form(clearance):
    """Movement a runs along y = 0, b along x = 0 (bodies' centres, sampled every 5 cm). a's body
    (length L) touches b's swept strip (half-width W'/2, W' = W + 2 clearance) exactly while its
    centre is within (L + W') / 2 of the crossing."""
    from nrtraffic.planning.conflicts import conflict_areas

    s = np.arange(-15.0, 15.0 + 1e-9, 0.05)
    a = MovementGeometry("a", "la", "xa", np.c_[s, np.zeros_like(s)], s + 15.0)
    b = MovementGeometry("b", "lb", "xb", np.c_[np.zeros_like(s), s], s + 15.0)
    rel = classify([a, b], L, W, clearance)
    assert rel[("a", "b")] == CONFLICT
    areas = conflict_areas([a, b], rel, L, W, clearance)
    half = (L + W + 2 * clearance) / 2.0
    for key in (("a", "b"), ("b", "a")):
        lo, hi = areas[key]
        assert lo == pytest.approx(15.0 - half, abs=0.051) and hi == pytest.approx(15.0 + half, abs=0.051)


def test_compatible_movements_have_no_conflict_area():
    from nrtraffic.planning.conflicts import conflict_areas

    s = np.arange(-15.0, 15.0, 0.05)
    a = MovementGeometry("a", "la", "xa", np.c_[s, np.zeros_like(s)], s)
    b = MovementGeometry("b", "lb", "xb", np.c_[s, np.full_like(s, 5.0)], s)  # parallel, 5 m apart
    rel = classify([a, b], L, W, 0.25)
    assert rel[("a", "b")] == COMPATIBLE and conflict_areas([a, b], rel, L, W, 0.25) == {}
