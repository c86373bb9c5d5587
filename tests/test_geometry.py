import math

import numpy as np
import pytest

from nrtraffic.geometry import LanePath, path_point_near, project_local, segment_frames

R = 821.24


def _arc(n=431, length=430.0):
    th = np.linspace(0, length / R, n)
    return np.c_[R * np.sin(th), R * (1 - np.cos(th))]


def test_arc_length_and_heading_of_a_polyline_circle():
    path = LanePath.from_points(_arc())
    assert path.length == pytest.approx(430.0, abs=1e-3)  # chords of 1 m on R = 821 m
    assert path.heading_at(215.0) == pytest.approx(215.0 / R, abs=1e-3)


@pytest.mark.parametrize("smooth", [None, 0.25])
def test_projection_round_trips(smooth):
    path = LanePath.from_points(_arc(), smooth_spacing=smooth)
    rng = np.random.default_rng(3)
    for s, lat in zip(rng.uniform(1, 429, 200), rng.uniform(-2, 2, 200)):
        xy = path.xy_at(s)
        h = path.heading_at(s)
        q = xy + lat * np.array([-math.sin(h), math.cos(h)])
        s2, lat2 = path.project(q)
        assert s2 == pytest.approx(s, abs=5e-3) and lat2 == pytest.approx(lat, abs=5e-3)
        # the compiled local projection agrees
        i0 = int(np.searchsorted(path.s, s)) - 1
        s3, lat3, _ = project_local(path.xy, path.s, q[0], q[1], max(i0, 0), 3, 12)
        assert s3 == pytest.approx(s2, abs=1e-9) and lat3 == pytest.approx(lat2, abs=1e-9)


def test_projection_is_the_nearest_point_of_the_path():
    """Against a brute-force search over points 1 cm apart along a winding path: the projection's
    point is at least as near as the nearest of them, and no more than 1 cm nearer."""
    rng = np.random.default_rng(5)
    path = LanePath.from_points(np.cumsum(rng.normal(size=(12, 2)) * 15.0, axis=0), smooth_spacing=0.5)
    dense = path.xy_at(np.arange(0.0, path.length, 0.01))
    lo, hi = path.xy.min(axis=0), path.xy.max(axis=0)
    inside = 0
    for q in rng.uniform(lo, hi, size=(300, 2)):
        near = np.hypot(*(dense - q).T).min()
        s, _ = path.project(q)
        d = float(np.hypot(*(path.xy_at(s) - q)))
        if 0.0 < s < path.length:
            assert d <= near + 1e-9 and near - d <= 0.01
            inside += 1
    assert inside > 200  # (points beyond the ends project onto the extended end segments)


@pytest.mark.parametrize("points", [[(0, 0), (10, 0)], [(0, 0), (5, 0), (10, 0)]])
def test_projection_extends_the_first_and_last_segment(points):
    """Before the start ``s`` is negative, past the end above the length (one segment or more)."""
    path = LanePath.from_points(points)
    assert path.project((-3.0, 1.0)) == pytest.approx((-3.0, 1.0))
    assert path.project((14.0, -2.0)) == pytest.approx((14.0, -2.0))


def test_smoothed_path_passes_through_the_vertices_and_stays_on_the_circle():
    pts = _arc(44)  # 10 m chords
    path = LanePath.from_points(pts, smooth_spacing=0.25)
    for p in pts:
        assert np.min(np.hypot(*(path.xy - p).T)) < 1e-9
    # it stays within the chords' sagitta of the circle (10^2 / (8 R) = 1.5 cm): long segments are
    # densified before smoothing, so the spline only rounds the vertices
    r = np.hypot(path.xy[:, 0], path.xy[:, 1] - R)
    assert np.abs(r - R).max() < 10.0**2 / (8 * R) + 1e-4


@pytest.mark.parametrize("start", [0, 1, 2])
def test_compiled_path_point_matches_numpy_from_any_start_segment(start):
    path = LanePath.from_points([(0, 0), (10, 0), (20, 5), (25, 15)])
    s = np.linspace(0, path.length, 57)
    out = np.array([path_point_near(q, path.xy, path.s, start) for q in s])
    assert np.allclose(out, path.xy_at(s))


def test_path_needs_two_points():
    with pytest.raises(ValueError):
        LanePath.from_points([(1, 1), (1, 1)])


def test_smoothing_keeps_long_straights_straight():
    """A long straight lane followed by short junction pieces (a SUMO route into a turn): the
    smoothed path stays on the straight to the millimetre and only rounds the corner."""
    pts = [(1.6, -512.8), (1.6, -7.2), (1.95, -4.75), (3.0, -3.0), (4.75, -1.95), (7.2, -1.6), (512.8, -1.6)]
    path = LanePath.from_points(pts, smooth_spacing=0.25)
    on_in = path.xy[path.xy[:, 1] < -10.0]
    assert np.abs(on_in[:, 0] - 1.6).max() < 1e-3
    on_out = path.xy[path.xy[:, 0] > 10.0]
    assert np.abs(on_out[:, 1] + 1.6).max() < 1e-3


def test_a_split_internal_lane_does_not_bend_a_left_turn():
    """SUMO splits a left turn's internal lane where it waits for oncoming traffic (cross4's
    ``:C_8_0`` + ``:C_13_0``), 0.18 m after a vertex on a straight piece of the arc. The smoothed
    path must be the one without that extra knot. With the knot, the spline bent right inside the
    turn (curvature -0.25 1/m); what is left is the spline's slight overshoot where the straight
    approach meets the turn's first chord (-0.047 1/m, entering an arc of up to +0.18 1/m)."""
    approach = [(1.6, -512.8), (1.6, -7.2)]
    internal_a = [(1.6, -7.2), (1.05, -3.35), (0.9588, -3.1979)]
    internal_b = [(0.9588, -3.1979), (-0.6, -0.6), (-3.35, 1.05), (-7.2, 1.6)]
    exit_ = [(-7.2, 1.6), (-512.8, 1.6)]
    split = LanePath.from_points(approach + internal_a + internal_b + exit_, smooth_spacing=0.25)
    whole = LanePath.from_points(approach + internal_a[:2] + internal_b + exit_, smooth_spacing=0.25)
    assert split.length == pytest.approx(whole.length, abs=1e-9)
    assert np.abs(split.xy - whole.xy).max() < 1e-9
    curvature = segment_frames(split.xy, split.s)[:, 2]  # what the lateral barrier reads
    assert curvature.min() > -0.05 and curvature.max() < 0.2
    # and the knot itself is not lost where it carries shape: an arc's vertices stay
    bent = LanePath.from_points(approach + [(1.05, -3.35), (0.9, -3.0)] + internal_b + exit_, smooth_spacing=0.25)
    assert np.min(np.hypot(*(bent.xy - (0.9, -3.0)).T)) < 1e-9
