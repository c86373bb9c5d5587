"""The junctions built once SUMO has read the network, before anything is simulated: each
movement's path and zones, the checks that the car can drive it, where vehicles stop before they
cross, the relations and conflict areas of the movements, ``movements.json`` and the queue
detectors.

Every check raises ValueError naming the movement and the key or the network change that fixes it;
the run turns it into a :class:`~nrtraffic.sumo.network.NetworkError` (exit 2, nothing simulated).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from nrtraffic.geometry import LanePath
from nrtraffic.junction import Junction, Layout, Movement
from nrtraffic.planning.conflicts import MovementGeometry, classify, conflict_areas
from nrtraffic.scenario import MIN_CONTROL_ZONE_M
from nrtraffic.sumo.network import edge_of

# on a road with several lanes between two controlled junctions, where the lane decides the turn:
# the stretch after the upstream merging zone where SUMO's driver changes lanes for its next turn,
# before the control zone begins (about 4 s at 50 km/h) [m]
LANE_CHANGE_M = 60.0
PATH_SPACING_M = 0.25  # sampling of the smoothed lane paths [m]
STOP_BEFORE_M = 0.5  # a vehicle that must stand before it crosses stops this far short of its limit (stop_lines) [m]
HUMAN_BODY = "~human"  # suffix of a movement's name for a human driver's body on it (conflict areas)
QUEUE_PERIOD_S = 10.0  # aggregation period of the queue detectors [s]


def max_curvature(path, s_from: float, s_to: float, window_m: float = 2.0) -> float:
    """Largest curvature [1/m] of ``path`` on ``[s_from, s_to]`` [m], the heading's change averaged
    over ``window_m`` (0 where the stretch is shorter than that)."""
    sel = (path.s >= s_from) & (path.s <= s_to)
    if sel.sum() < 3:
        return 0.0
    s = path.s[sel]
    h = np.unwrap(path.heading_at(s))
    n = max(1, int(round(window_m / max(float(np.median(np.diff(s))), 1e-6))))
    if len(s) <= n:
        return 0.0
    return float((np.abs(h[n:] - h[:-n]) / (s[n:] - s[:-n])).max())


def curve_speed(path, s_from: float, s_to: float, a_lat: float, window_m: float = 2.0) -> float:
    """Highest constant speed [m/s] on ``[s_from, s_to]`` of ``path`` at lateral acceleration
    ``a_lat`` [m/s^2]: ``sqrt(a_lat / kappa_max)``, the curvature [1/m] averaged over ``window_m``
    (inf when ``a_lat`` is 0, no bound, or the path is straight)."""
    if a_lat <= 0.0:
        return math.inf
    k_max = max_curvature(path, s_from, s_to, window_m)
    return math.sqrt(a_lat / k_max) if k_max > 1e-9 else math.inf


def build_paths(sc, layout: Layout, sumo, params, control: bool) -> tuple[dict[str, Movement], dict[str, float]]:
    """Every movement's path (its lanes from SUMO, smoothed) and zones, of every junction; each
    junction lists its own (:attr:`Junction.movements`). Returns the paths by movement name and the
    control zones cut short (movement -> the length left [m]). Raises ValueError naming the
    movement where a zone does not fit, or (``control``) the car cannot drive its turn."""
    out, zone_cuts = {}, {}
    merge_at = {a.name: a for a in sc.approaches}
    moves = [(rname, *lm) for rname in layout.movement_table for lm in layout.lane_movements[rname]]
    for rname, _lane, name, lane_in, lane_out in moves:
        appr, turn, route = layout.movement_table[rname]
        j = layout.junctions[layout.movement_junction[rname]]
        key = f"merging_zone_m of [[junctions]] {j.id}" if len(layout.junctions) > 1 else "zones.merging_zone_m"
        lanes = sumo.route_lanes(route, lane_in, lane_out)
        pts = [pt for _, shape, _ in lanes for pt in shape]
        path = LanePath.from_points(pts, smooth_spacing=PATH_SPACING_M)
        # arc length of each lane's start on the (smoothed) path; lane positions scale linearly
        starts = [path.project(shape[0])[0] for _, shape, _ in lanes] + [path.length]
        offsets = {lane: (starts[k], (starts[k + 1] - starts[k]) / length if length > 0 else 1.0)
                   for k, (lane, _, length) in enumerate(lanes)}
        # how far the junction's internal lanes (where the paths cross and turn) reach from its centre [m]
        internal = [shape for ln, shape, _ in lanes if ln.startswith(":")]
        reach = (max(float(np.hypot(*(np.asarray(sh) - j.xy).T).max()) for sh in internal)
                 if j.xy is not None and internal else None)
        if j.xy is not None:
            # merging zone: the disc of diameter merging_zone_m around the junction centre
            inside = np.flatnonzero(j.in_merging_zone(path.xy))
            if inside.size == 0:
                raise ValueError(f"movement {name}: its path does not reach junction {j.id}'s merging zone ({key} "
                                 f"= {j.merging_zone_m:g} m around its centre)")
            if inside[0] == 0:  # (its approach starts inside the zone: a short link from the node before it)
                r0 = float(np.hypot(*(path.xy[0] - np.asarray(j.xy))))
                fix = (f"set {key} to at most {2.0 * math.floor(r0 - 1.0):g} m" if (reach or 0.0) + 1.0 < r0 - 1.0 else
                       f"the junction's own lanes reach {reach:.1f} m from its centre, so no merging zone fits both: "
                       f"join it with the node before it into one junction (netconvert --junctions.join, or a "
                       f"<join nodes=...> in a node file) and control that one")
                raise ValueError(f"movement {name}: its approach {appr} starts {r0:.1f} m from junction {j.id}'s "
                                 f"centre, inside the merging zone ({key} = {j.merging_zone_m:g} m): {fix}")
            s_m, s_x = float(path.s[inside[0]]), float(path.s[min(inside[-1], len(path.s) - 1)])
        else:
            a = merge_at[rname]
            lane_m = f"{a.merge_entry_edge}_0"
            s_m = offsets[lane_m][0] + a.merge_entry_pos_m * offsets[lane_m][1]
            s_x = s_m + j.merging_zone_m
        s_c = s_m - j.control_zone_m
        # a car inserted at the route's start has its centre of gravity behind one car length;
        # on a corridor the road starts at the junction upstream, which hands the car over where
        # it leaves that junction's merging zone: a zone reaching further back is cut there (and,
        # where the lane decides the turn, LANE_CHANGE_M further on, for SUMO's lane changes, if
        # the zone left is long enough), and the cut reported
        first = params.length
        up = layout.junctions.get(layout.upstream_junction.get(appr, ""))
        if up is not None and up.xy is not None:
            near = np.flatnonzero(up.in_merging_zone(path.xy))
            if near.size:
                first = max(first, float(path.s[min(near[-1] + 1, len(path.s) - 1)]))
                if len(layout.entry_lanes(appr)) > 1 and s_m - first - LANE_CHANGE_M >= MIN_CONTROL_ZONE_M:
                    first += LANE_CHANGE_M
        if s_c < first:
            if s_m - first < MIN_CONTROL_ZONE_M:
                raise ValueError(f"movement {name}: only {s_m - first:.1f} m of its route lie before the merging "
                                 f"zone, less than the {MIN_CONTROL_ZONE_M:g} m a control zone needs")
            s_c = first
            zone_cuts[name] = s_m - s_c
        if s_x > path.length:
            raise ValueError(f"movement {name}: the merging zone runs past the end of the route")
        if reach is not None and reach > j.merging_zone_m / 2.0 + 0.5:
            # the junction lies inside the merging zone: the coordinator plans the crossings there,
            # the stop lines lie before it
            raise ValueError(f"movement {name}: junction {j.id}'s internal lanes reach "
                             f"{reach:.1f} m from its centre, beyond the merging zone ({key} = "
                             f"{j.merging_zone_m:g} m); set it to at least {2.0 * math.ceil(reach + 1.0):g} m")
        if control:  # (SUMO drives a baseline's vehicles: the path only measures them)
            check_turn_radius(name, path, s_c, s_x, params, sc.controller.steer_max_rad)
        v_lim = min(sumo.lane_speed(ln) for ln, _, _ in lanes) if j.xy is not None else math.inf
        v_lim = min(v_lim, curve_speed(path, s_m, s_x, sc.planning.max_lateral_accel_mps2))
        roads = {ln: edge_of(ln) for ln, _, _ in lanes if not ln.startswith(":")}
        exit_edges = frozenset(e for ln, e in roads.items()
                               if offsets[ln][0] + sumo.edge_length(e) * offsets[ln][1] > s_x)
        out[name] = Movement(name, appr, turn, route, path, [ln for ln, _, _ in lanes], offsets, s_c, s_m, s_x,
                             v_lim, rname, j.id, exit_edges)
        j.movements.append(name)
    if zone_cuts:
        print(f"{sc.general.name}: control zones reach back past where routes start or past the junction "
              f"upstream; cut there: " + ", ".join(f"{k} {v:.0f} m" for k, v in zone_cuts.items()),
              file=sys.stderr)
    return out, zone_cuts


def check_turn_radius(name: str, path: LanePath, s_from: float, s_to: float, params, steer_max_rad: float) -> None:
    """Raise ValueError when movement ``name``'s path between ``s_from`` and ``s_to`` [m] turns
    tighter than the controlled car can steer: the curvature averaged over 2 m [1/m] above the
    kinematic bound ``tan(steer_max) / (l_f + l_r)``. (netconvert draws a junction's turns
    with the node's ``radius``, 4 m by default; at a sharply skewed corner that can leave a
    turn tighter than any car's.)"""
    kappa = max_curvature(path, s_from, s_to)
    k_max = math.tan(steer_max_rad) / (params.lf + params.lr)
    if kappa > k_max:
        raise ValueError(f"movement {name}: its path turns on a radius of {1.0 / kappa:.1f} m, tighter than "
                         f"the vehicle's smallest ({1.0 / k_max:.1f} m at controller.steer_max_rad = "
                         f"{steer_max_rad:.3g} rad); give the junction a larger turning radius "
                         f"in the network (netconvert: the node's radius, or --default.junctions.radius)"
                         + (", or leave the U-turn out of the demand (a U-turn needs a road wide enough to turn "
                            "in)" if ".uturn" in name else ""))


def stop_lines(paths: dict[str, Movement], areas: dict, junctions: dict[str, Junction],
               params) -> dict[tuple[str, str], tuple[str, float]]:
    """Where a vehicle that must stand before it crosses stops, per movement and driver: the
    lane and lane position [m] of its front bumper.

    - A human driver: at SUMO's stop line (the end of its approach lane), or, where its body
      would touch a conflict area of its own there (``<movement>~human``), ``STOP_BEFORE_M``
      short of the first: standing, it blocks no one, and it starts as close to the conflict
      areas as it may.
    - A controlled vehicle queued behind a human ("automated"): ``STOP_BEFORE_M`` before the
      merging-zone entry of its centre of gravity, outside the zone (its start from rest is
      planned from there).

    Raises ValueError when a stop falls inside the junction (the merging zone is smaller than
    the junction)."""
    out = {}
    cg = params.cg_to_front
    for name, m in paths.items():
        internal = [m.lane_offset[ln][0] for ln in m.lanes if ln.startswith(":")]
        s_end = internal[0] if internal else m.path.length
        firsts = [lo for (a, _), (lo, _hi) in areas.items() if a == name + HUMAN_BODY]
        s_area = m.s_merge + min(firsts) + cg - STOP_BEFORE_M if firsts else math.inf
        for driver, s_front in (("automated", m.s_merge - STOP_BEFORE_M), ("human", min(s_end - 0.1, s_area))):
            lane = None
            for ln in m.lanes:
                if m.lane_offset[ln][0] <= s_front + 1e-9:
                    lane = ln
            if lane is None or lane.startswith(":"):
                raise ValueError(f"movement {name}: its merging-zone entry lies inside the junction, where a "
                                 f"vehicle cannot stop (the merging zone, "
                                 f"{junctions[m.junction].merging_zone_m:g} m, is smaller than the junction)")
            off, scale = m.lane_offset[lane]
            out[(name, driver)] = (lane, (s_front - off) / scale)
    return out


def body_headings(m: Movement, s: np.ndarray, params, crossing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The controlled car's body heading [rad] at centre-of-gravity positions ``s`` [m] of
    movement ``m``, at the two ends of its range: the kinematic one (a slow car: its rear axle
    moves along the body, so the body turns less than the path, by ``asin(l_r kappa)``), and
    ``crossing``, the one the kernel gives crossing at the movement's crossing speed (its tyres
    slip besides; :meth:`~nrtraffic.control.kernel.Kernel.crossing_headings`). On cross4's turns
    both differ from the path's heading by up to 0.3 rad (left) and 0.46 rad (right), which turns
    the body's corners out by most of a metre."""
    h = np.unwrap(m.path.heading_at(m.path.s))
    n = max(1, int(round(1.0 / PATH_SPACING_M)))  # curvature over 2 m
    kappa = np.zeros_like(h)
    if len(h) > 2 * n:
        kappa[n:-n] = (h[2 * n:] - h[:-2 * n]) / (m.path.s[2 * n:] - m.path.s[:-2 * n])
    kin = np.interp(s, m.path.s, h - np.arcsin(np.clip(params.lr * kappa, -1.0, 1.0)))
    return kin, crossing


def relations(junctions: dict[str, Junction], paths: dict[str, Movement], params, lateral_clearance_m: float,
              crossing_headings, human_bodies: bool) -> tuple[dict, dict]:
    """Relations and conflict areas of each junction's movements among themselves (set on each
    :class:`Junction`); returns every junction's relations and areas in one table each (the names
    do not repeat). ``crossing_headings(m, s)``: the body's heading crossing movement ``m`` at
    positions ``s``; ``human_bodies``: add a human driver's body on every movement."""
    rel, areas = {}, {}
    for j in junctions.values():
        j.relations, j.conflict_areas = _junction_relations([paths[n] for n in j.movements], params,
                                                            lateral_clearance_m, crossing_headings, human_bodies)
        rel.update(j.relations)
        areas.update(j.conflict_areas)
    return rel, areas


def _junction_relations(movements: list[Movement], params, clearance: float, crossing_headings,
                        human_bodies: bool) -> tuple[dict, dict]:
    """Relations and conflict areas of ``movements`` (one junction's): the bodies swept along
    their paths through the merging zone (:func:`~nrtraffic.planning.conflicts.classify`)."""
    geo = []
    for m in movements:
        sel = (m.path.s >= m.s_merge) & (m.path.s <= m.s_exit)
        # the path carries the centre of gravity; the body's centre is ahead of it by this [m],
        # along the body's heading, which lies between its two ends (body_headings): both are
        # swept, interleaved so that the points stay in order of the path
        ahead = params.cg_to_front - 0.5 * params.length
        s_zone = m.path.s[sel]
        h2 = np.stack(body_headings(m, s_zone, params, crossing_headings(m, s_zone)), -1).reshape(-1)
        xy2 = np.repeat(m.path.xy[sel], 2, axis=0)
        centre = xy2 + ahead * np.stack([np.cos(h2), np.sin(h2)], -1)
        geo.append(MovementGeometry(m.name, m.lanes[0], m.lanes[-1], centre, np.repeat(s_zone - m.s_merge, 2), h2))
        if human_bodies:
            # a human driver's body: SUMO moves its front bumper along the lane and places its
            # rear on the lane one length behind (the body is that chord), so on a curve it
            # cuts further inside than the controlled car's (centre of gravity on the path,
            # heading along it); indexed by the same centre-of-gravity positions
            s_front = np.minimum(m.path.s[sel] + params.cg_to_front, m.path.length)
            front = m.path.xy_at(s_front)
            rear = m.path.xy_at(np.maximum(s_front - params.length, 0.0))
            chord = front - rear
            geo.append(MovementGeometry(m.name + HUMAN_BODY, m.lanes[0], m.lanes[-1], 0.5 * (front + rear),
                                        m.path.s[sel] - m.s_merge, np.arctan2(chord[:, 1], chord[:, 0])))
    rel = classify(geo, params.length, params.width, clearance)
    return rel, conflict_areas(geo, rel, params.length, params.width, clearance)


def zone_path(m: Movement, margin_m: float = 10.0, step_m: float = 0.5):
    """Positions from the merging-zone entry [m] and the path's points there, from ``margin_m``
    before the zone to ``margin_m`` after it, every ``step_m``."""
    d = np.arange(-margin_m, m.s_exit - m.s_merge + margin_m + 1e-9, step_m)
    return d, m.path.xy_at(m.s_merge + d)


def write_movements(path: Path, paths: dict[str, Movement], junctions: dict[str, Junction], rel: dict,
                    areas: dict) -> None:
    """``movements.json``: each movement's route, zone boundaries, its relation to the others and
    its conflict areas (the stretch of its path, from its merging-zone entry, on which its body
    can touch the other movement's)."""
    doc = {
        "movements": {
            m.name: {**({"junction": m.junction} if len(junctions) > 1 else {}),
                     "approach": m.approach, "turn": m.turn, "route": list(m.route), "lanes": m.lanes,
                     "control_zone_start_m": m.s_control, "merge_entry_m": m.s_merge, "merge_exit_m": m.s_exit,
                     "zone_length_m": m.s_exit - m.s_merge,
                     "v_limit_mps": None if not math.isfinite(m.v_limit) else m.v_limit,
                     # the path of its centre of gravity from 10 m before the merging zone to 10 m
                     # after it, every 0.5 m: [s from the merging-zone entry, x, y] [m]
                     "zone_path": [[round(float(d), 3), round(float(x), 3), round(float(y), 3)]
                                   for d, (x, y) in zip(*zone_path(m))]}
            for m in paths.values()
        },
        # between the movements of the same junction
        "relations": {a: {b: rel[(a, b)] for b in junctions[m.junction].movements if b != a}
                      for a, m in paths.items()},
        # on a's path, measured from its merging-zone entry [m]: where its body can touch b's
        "conflict_areas": [{"movement": a, "with": b, "from_m": lo, "to_m": hi}
                           for (a, b), (lo, hi) in sorted(areas.items()) if HUMAN_BODY not in a + b],
    }
    human = [{"movement": a, "with": b, "from_m": lo, "to_m": hi}
             for (a, b), (lo, hi) in sorted(areas.items()) if HUMAN_BODY in a + b]
    if human:  # with human drivers: the areas of their bodies ("<movement>~human") against every body
        doc["conflict_areas_human"] = human
    zones = {j.id: {"centre_xy": [float(c) for c in j.xy], "diameter_m": j.merging_zone_m}
             for j in junctions.values() if j.xy is not None}
    if len(zones) == 1:
        doc["merging_zone"] = next(iter(zones.values()))
    elif zones:
        doc["merging_zones"] = zones
    tmp = path.with_name(path.name + ".tmp")  # (whole or not at all: a full disk leaves no half of it)
    try:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
        tmp.replace(path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def queue_detectors(sc, layout: Layout, network_path: Path, workdir: Path, sdir: Path,
                    additional: tuple = ()) -> tuple[str, ...]:
    """At a junction: one SUMO lane-area (E2) detector over every lane of every approach, with
    SUMO's default halting and jam thresholds, written every ``QUEUE_PERIOD_S`` to
    ``queues.xml`` (:func:`~nrtraffic.results.approach_table`); the SUMO arguments that load them
    (with the ``additional`` files)."""
    if not sc.controlled_junctions():
        return ("--additional-files", ",".join(map(str, additional))) if additional else ()
    from nrtraffic.results import QUEUE_DETECTOR
    from nrtraffic.sumo.network import edge_lanes

    import os
    from xml.sax.saxutils import quoteattr

    # (relative to the additional file, as SUMO reads it, and escaped: a run folder's path may hold
    # an & or a <, which SUMO would read as XML)
    out = os.path.relpath((workdir / "queues.xml").resolve(), Path(sdir).resolve())
    # (with its schema declared and ids that it allows, SUMO's --xml-validation always accepts the file)
    lines = ['<additional xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
             'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/additional_file.xsd">']
    for _, lane, length in edge_lanes(network_path, layout.approaches):
        lines.append(f'    <laneAreaDetector id="{QUEUE_DETECTOR}{lane}" lanes="{lane}" pos="0" '
                     f'endPos="{length:.3f}" friendlyPos="true" period="{QUEUE_PERIOD_S:g}" file={quoteattr(out)}/>')
    lines.append("</additional>")
    path = sdir / "queues.add.xml"
    path.write_text("\n".join(lines) + "\n")
    return ("--additional-files", ",".join(map(str, (path, *additional))))
