"""Lane paths built from SUMO lane shapes (polylines).

A :class:`LanePath` maps arc length ``s`` [m] along a vehicle's path to position ``(x, y)`` [m] and
heading [rad, counter-clockwise from +x], and projects a point back to ``(s, signed lateral offset)``
(positive to the left of the direction of travel). The compiled kernels use the packed arrays
through :func:`path_point_near`, :func:`project_local` and :func:`segment_frames`;
:meth:`LanePath.project` is :func:`project_local` over the whole path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class LanePath:
    """A polyline path with cumulative arc length.

    Attributes
    ----------
    xy : (n, 2) vertices [m].
    s : (n,) cumulative arc length at the vertices [m], ``s[0] = 0``.
    """

    xy: np.ndarray
    s: np.ndarray

    @classmethod
    def from_points(cls, points, min_spacing: float = 1e-3, smooth_spacing: float | None = None) -> "LanePath":
        """Build from vertices, dropping consecutive near-duplicates (closer than ``min_spacing`` m).

        With ``smooth_spacing`` the vertices are joined by a centripetal Catmull-Rom spline (C^1,
        through every vertex, no overshoot or cusps) sampled about every ``smooth_spacing`` m: SUMO's
        lane shapes are polylines whose heading jumps at every vertex, which a tracker following
        them would feel as steering kicks.
        """
        pts = _dedupe(np.asarray(points, dtype=np.float64).reshape(-1, 2), min_spacing)
        if len(pts) < 2:
            raise ValueError("a lane path needs at least two distinct points")
        if smooth_spacing is not None and len(pts) > 2:
            # knots that add no shape (where SUMO splits a junction's internal lane on a straight
            # piece) would pinch the spline between two close vertices into an S-bend
            pts = _drop_collinear(pts, COLLINEAR_TOL_M)
        if smooth_spacing is not None and len(pts) == 2:  # a straight: sampled like a smoothed path
            n = max(1, int(np.ceil(np.hypot(*(pts[1] - pts[0])) / smooth_spacing)))
            pts = pts[0] + np.linspace(0.0, 1.0, n + 1)[:, None] * (pts[1] - pts[0])
        elif smooth_spacing is not None and len(pts) > 2:
            # densify first: a spline through a 500 m straight followed by a 2 m junction piece bows
            # the straight by most of a metre; with short segments it only rounds the corners
            pts = _dedupe(_catmull_rom(_densify(pts, SMOOTH_MAX_SEGMENT_M), smooth_spacing), min_spacing)
        seg = np.hypot(*np.diff(pts, axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        pts.setflags(write=False)
        s.setflags(write=False)
        return cls(pts, s)

    @property
    def length(self) -> float:
        """Total arc length [m]."""
        return float(self.s[-1])

    def _segment(self, s):
        s = np.asarray(s, dtype=np.float64)
        i = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 2)
        return s, i

    def xy_at(self, s) -> np.ndarray:
        """Position at arc length ``s`` (scalar or array) [m]; linear extrapolation past the ends."""
        s, i = self._segment(s)
        d = self.xy[i + 1] - self.xy[i]
        seg = self.s[i + 1] - self.s[i]
        frac = (s - self.s[i]) / seg
        return self.xy[i] + frac[..., None] * d

    def heading_at(self, s) -> np.ndarray:
        """Heading of the segment containing ``s`` [rad]."""
        _, i = self._segment(s)
        d = self.xy[i + 1] - self.xy[i]
        return np.arctan2(d[..., 1], d[..., 0])

    def project(self, point) -> tuple[float, float]:
        """Closest point on the path: returns ``(s, lateral)`` [m], lateral positive to the left.

        Beyond the ends the first/last segment is extended, so ``s`` may be negative or exceed
        :attr:`length`.
        """
        q = np.asarray(point, dtype=np.float64)
        s, lateral, _ = project_local(self.xy, self.s, float(q[0]), float(q[1]), 0, 0, len(self.s) - 2)
        return float(s), float(lateral)


SMOOTH_MAX_SEGMENT_M = 2.0  # longest segment the spline sees [m]
COLLINEAR_TOL_M = 2e-4  # a vertex this close to the chord of its neighbours adds no shape [m] (the networks carry 4 decimals)


def _drop_collinear(pts: np.ndarray, tol: float) -> np.ndarray:
    """Drop interior vertices that lie on the segment between the last kept vertex and the next
    one (within ``tol`` m of it, and between its ends). SUMO splits a left turn's internal lane
    where the turn waits for oncoming traffic, 0.18 m after a vertex on a straight piece of the
    same arc: a spline through every vertex turns two such close knots into an S-bend (curvature
    -0.25 1/m inside a left turn of +0.12 1/m, which the tracker followed with a steering kick). A
    genuine arc vertex is far from its neighbours' chord (a 9 m radius sampled every 3 m: 0.13 m;
    a 600 m radius every 1 m: 0.8 mm); the split point is 0.05 mm off it, the networks' rounding."""
    keep = [0]
    for i in range(1, len(pts) - 1):
        a, b, c = pts[keep[-1]], pts[i], pts[i + 1]
        d = c - a
        L2 = float(d @ d)
        t = float((b - a) @ d) / L2
        off = abs(d[0] * (b[1] - a[1]) - d[1] * (b[0] - a[0])) / math.sqrt(L2)
        if not (0.0 < t < 1.0 and off < tol):
            keep.append(i)
    keep.append(len(pts) - 1)
    return pts[keep]


def _densify(pts: np.ndarray, max_segment: float) -> np.ndarray:
    """On every segment longer than ``3 max_segment``, insert a point ``max_segment`` from each end.

    A Catmull-Rom piece depends on four consecutive points: the long middle part then has
    collinear neighbours and stays straight, and the rounding of each corner is confined to the
    short end pieces. Short segments (the vertices of a junction's arcs) are left alone, so the
    spline follows the arc through them; splitting those too would put straight chords between
    sharp corners."""
    out = [pts[:1]]
    for a, b in zip(pts[:-1], pts[1:]):
        L = float(np.hypot(*(b - a)))
        if L > 3.0 * max_segment:
            f = max_segment / L
            out.append(np.vstack([a + f * (b - a), b - f * (b - a)]))
        out.append(b[None, :])
    return np.vstack(out)


def _dedupe(pts: np.ndarray, min_spacing: float) -> np.ndarray:
    keep = [0]
    xy = pts.tolist()
    for i in range(1, len(xy)):
        kx, ky = xy[keep[-1]]
        if math.hypot(xy[i][0] - kx, xy[i][1] - ky) > min_spacing:
            keep.append(i)
    if keep[-1] != len(pts) - 1 and len(keep) > 1:
        keep[-1] = len(pts) - 1  # keep the true end point
    return pts[keep]


def _catmull_rom(pts: np.ndarray, spacing: float) -> np.ndarray:
    """Centripetal Catmull-Rom spline through ``pts`` (at least 3), sampled so that consecutive
    samples are about ``spacing`` apart. The phantom end points are quadratic extrapolations, which
    keep the end segments on a curve of the neighbouring curvature (straight ends stay straight)."""
    ext = np.vstack([3 * pts[0] - 3 * pts[1] + pts[2], pts, 3 * pts[-1] - 3 * pts[-2] + pts[-3]])
    out = [pts[:1]]
    for i in range(1, len(ext) - 2):
        p0, p1, p2, p3 = ext[i - 1], ext[i], ext[i + 1], ext[i + 2]
        d01 = max(np.hypot(*(p1 - p0)), 1e-9) ** 0.5
        d12 = max(np.hypot(*(p2 - p1)), 1e-9) ** 0.5
        d23 = max(np.hypot(*(p3 - p2)), 1e-9) ** 0.5
        t0, t1 = 0.0, d01
        t2, t3 = t1 + d12, t1 + d12 + d23
        n = max(1, int(np.ceil(np.hypot(*(p2 - p1)) / spacing)))
        t = np.linspace(t1, t2, n + 1)[1:, None]
        a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
        a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
        a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
        b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
        b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
        out.append((t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2)
    return np.vstack(out)


@njit(cache=True, error_model="numpy")
def path_point_near(q, xy, s, i):
    """Compiled :meth:`LanePath.xy_at` for one packed path: position ``(x, y)`` [m] at arc length
    ``q`` [m], the segment found by walking from segment ``i`` (a nearby one, e.g. the vehicle's
    own; the last ``i`` with ``s[i] <= q``, within the path), in a few steps when ``q`` is close."""
    n = s.shape[0]
    while i < n - 2 and s[i + 1] <= q:
        i += 1
    while i > 0 and s[i] > q:
        i -= 1
    frac = (q - s[i]) / (s[i + 1] - s[i])
    return xy[i, 0] + frac * (xy[i + 1, 0] - xy[i, 0]), xy[i, 1] + frac * (xy[i + 1, 1] - xy[i, 1])


@njit(cache=True, error_model="numpy")
def segment_frames(xy, s):
    """Per segment ``i`` of a path: unit tangent ``(tx, ty)`` and the curvature [1/m] around it
    (heading change between the neighbouring segments over the distance between their midpoints).
    Returns ``(len(s), 3)``; the last row repeats the last segment's, so rows align with points."""
    n = s.shape[0] - 1
    out = np.empty((n + 1, 3))
    for i in range(n):
        dx = xy[i + 1, 0] - xy[i, 0]
        dy = xy[i + 1, 1] - xy[i, 1]
        L = math.sqrt(dx * dx + dy * dy)
        i0 = max(i - 1, 0)
        i1 = min(i + 1, n - 1)
        out[i, 0] = dx / L
        out[i, 1] = dy / L
        if i1 == i0:
            out[i, 2] = 0.0
            continue
        th0 = math.atan2(xy[i0 + 1, 1] - xy[i0, 1], xy[i0 + 1, 0] - xy[i0, 0])
        th1 = math.atan2(xy[i1 + 1, 1] - xy[i1, 1], xy[i1 + 1, 0] - xy[i1, 0])
        dth = (th1 - th0 + math.pi) % (2.0 * math.pi) - math.pi
        ds = 0.5 * (s[i1] + s[i1 + 1]) - 0.5 * (s[i0] + s[i0 + 1])
        out[i, 2] = dth / ds
    out[n] = out[n - 1]
    return out


@njit(cache=True, error_model="numpy")
def project_local(xy, s, qx, qy, hint, back, ahead):
    """Compiled projection of ``(qx, qy)`` onto the segments ``hint-back .. hint+ahead`` of a packed
    path; returns ``(s, lateral, segment)`` (lateral positive to the left)."""
    n = s.shape[0] - 1
    lo = max(hint - back, 0)
    hi = min(hint + ahead, n - 1)
    best = 1e300
    best_s = 0.0
    best_lat = 0.0
    best_i = lo
    for i in range(lo, hi + 1):
        ax = xy[i, 0]
        ay = xy[i, 1]
        dx = xy[i + 1, 0] - ax
        dy = xy[i + 1, 1] - ay
        seg2 = dx * dx + dy * dy
        t = ((qx - ax) * dx + (qy - ay) * dy) / seg2
        if i > 0 and t < 0.0:
            t = 0.0
        if i < n - 1 and t > 1.0:
            t = 1.0
        fx = ax + t * dx
        fy = ay + t * dy
        d2 = (qx - fx) ** 2 + (qy - fy) ** 2
        if d2 < best:
            best = d2
            seg = math.sqrt(seg2)
            best_s = s[i] + t * seg
            best_lat = (dx * (qy - ay) - dy * (qx - ax)) / seg
            best_i = i
    return best_s, best_lat, best_i


@njit(cache=True, error_model="numpy")
def rectangles_touch(x1, y1, h1, x2, y2, h2, length, width):
    """Separating-axis test of two ``length`` x ``width`` [m] rectangles with centres ``(x, y)``
    [m] and headings ``h`` [rad] (compiled scalar twin of
    :func:`nrtraffic.planning.conflicts.boxes_overlap`); touching counts."""
    c1 = math.cos(h1)
    s1 = math.sin(h1)
    c2 = math.cos(h2)
    s2 = math.sin(h2)
    dx = x2 - x1
    dy = y2 - y1
    hl = 0.5 * length
    hw = 0.5 * width
    for k in range(4):
        if k == 0:
            ax, ay = c1, s1
        elif k == 1:
            ax, ay = -s1, c1
        elif k == 2:
            ax, ay = c2, s2
        else:
            ax, ay = -s2, c2
        r1 = hl * abs(c1 * ax + s1 * ay) + hw * abs(-s1 * ax + c1 * ay)
        r2 = hl * abs(c2 * ax + s2 * ay) + hw * abs(-s2 * ax + c2 * ay)
        if abs(dx * ax + dy * ay) > r1 + r2:
            return False
    return True


@njit(cache=True, error_model="numpy")
def touching_pairs(cx, cy, psi, length, width):
    """Index pairs ``i < j`` of rectangles (centres ``(cx, cy)`` [m], headings ``psi`` [rad], all
    ``length`` x ``width`` [m]) that touch. Returns two int arrays, ordered by ``i`` then ``j``.

    Only pairs whose circumscribed circles meet are tested, and those are found on a uniform grid
    of cells one circle diameter wide: each rectangle is compared with the ones in its own cell and
    the eight around it, so the work grows with the number of rectangles, not with its square."""
    n = cx.shape[0]
    r2 = length * length + width * width  # (the circles' diameter, squared)
    ii = np.empty(8, dtype=np.int64)
    jj = np.empty(8, dtype=np.int64)
    if n < 2:
        return ii[:0], jj[:0]
    cell = math.sqrt(r2)
    gx = np.floor((cx - cx.min()) / cell).astype(np.int64) + 1
    gy = np.floor((cy - cy.min()) / cell).astype(np.int64) + 1
    rows = gy.max() + 2
    key = gx * rows + gy  # (cells 0 and max + 1 of each axis stay empty: no neighbour wraps round)
    order = np.argsort(key)
    skey = key[order]
    cnt = 0
    for i in range(n):
        for dgx in range(-1, 2):
            for dgy in range(-1, 2):
                k = (gx[i] + dgx) * rows + gy[i] + dgy
                b = np.searchsorted(skey, k)
                while b < n and skey[b] == k:
                    j = order[b]
                    b += 1
                    if j <= i:
                        continue
                    dx = cx[j] - cx[i]
                    dy = cy[j] - cy[i]
                    if dx * dx + dy * dy > r2:
                        continue
                    if not rectangles_touch(cx[i], cy[i], psi[i], cx[j], cy[j], psi[j], length, width):
                        continue
                    if cnt == ii.shape[0]:
                        ii = np.concatenate((ii, np.empty(cnt, dtype=np.int64)))
                        jj = np.concatenate((jj, np.empty(cnt, dtype=np.int64)))
                    ii[cnt] = i
                    jj[cnt] = j
                    cnt += 1
    ii, jj = ii[:cnt], jj[:cnt]
    o = np.argsort(ii * n + jj)
    return ii[o], jj[o]
