"""The series of a run's time-space diagrams, from its run directory.

Per approach road (:func:`time_space_series`): each vehicle's position along the road, from the
start of the approach edge through the junction to the end of the merging zone, against time;
one series per vehicle and road, so a trip through several junctions appears once in the panel of
each road it enters a junction by, never with its legs joined. Along a corridor
(:func:`arterial_series`): each vehicle's position along the arterial, per direction, against time.

Where the run wrote SUMO's floating-car data (``outputs.sumo_fcd = true``, ``fcd.xml``) every
vehicle is drawn, SUMO-driven ones too, by the position of its front bumper on its lane (SUMO's
``pos``) added to the length of the lanes before it on the path. Otherwise only the controlled
vehicles while under control are known: their distance along the path from
``trajectories.parquet`` (of the centre of gravity), split into legs by the times they entered
each control zone (``vehicles.csv``). Positions in metres, times in seconds.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from nrtraffic.sumo.network import edge_of, open_xml

PAST_ZONE_M = 10.0  # a road's panel goes on this far past the end of its merging zone [m]
SERIES_COLUMNS = ["vehicle_id", "segment", "t", "s_m", "movement", "driver"]


def read_fcd_lanes(path: Path, t0_s: float = 0.0) -> pd.DataFrame:
    """SUMO's floating-car data (``fcd.xml``) as rows ``t, vehicle_id, lane, pos``: time from the
    run's start, SUMO's clock less ``t0_s`` (``scenario.begin_s``) [s], and the front bumper's
    distance from the start of the lane [m]."""
    rows = []
    for _, el in ET.iterparse(path, events=("end",)):
        if el.tag == "timestep":
            t = float(el.get("time")) - t0_s
            rows += [(t, v.get("id"), v.get("lane"), float(v.get("pos"))) for v in el.iter("vehicle")
                     if v.get("lane") is not None]
            el.clear()
    return pd.DataFrame(rows, columns=["t", "vehicle_id", "lane", "pos"])


def lane_lengths(run_dir: Path) -> dict[str, float]:
    """Length [m] of every lane of the network SUMO ran (``sumo/run.sumocfg``'s net-file, else the
    run's ``scenario.resolved.toml`` network)."""
    run_dir = Path(run_dir)
    net = None
    cfg = run_dir / "sumo" / "run.sumocfg"
    if cfg.is_file():
        el = ET.parse(cfg).getroot().find("./input/net-file")
        if el is not None:
            net = cfg.parent / el.get("value")
    if net is None or not net.is_file():
        import tomllib

        rel = tomllib.loads((run_dir / "scenario.resolved.toml").read_text())["scenario"]["network"]
        net = run_dir / rel
    out = {}
    with open_xml(net) as f:
        for _, el in ET.iterparse(f, events=("end",)):
            if el.tag == "lane":
                out[el.get("id")] = float(el.get("length"))
            elif el.tag == "edge":
                el.clear()
    return out


@dataclass
class Road:
    """One approach road's panel: its movements' lanes at their distance from the start of the
    approach edge, and the zones, all in the path's coordinates [m]."""

    approach: str
    junction: str
    lane_offset: dict[str, tuple[str, float]] = field(default_factory=dict)  # lane -> (movement, offset)
    edge_offset: dict[str, tuple[str, float]] = field(default_factory=dict)  # edge -> (movement, offset)
    control_zone_start_m: float = 0.0
    merge_entry_m: float = 0.0
    merge_exit_m: float = 0.0

    @property
    def top_m(self) -> float:
        return self.merge_exit_m + PAST_ZONE_M

    def offset(self, lane: str) -> tuple[str, float] | None:
        return self.lane_offset.get(lane) or self.edge_offset.get(edge_of(lane))


def roads(movements: dict, lengths: dict[str, float]) -> dict[str, Road]:
    """The approach roads of ``movements.json`` with their lanes' offsets along each movement's
    path (sums of SUMO's lane lengths ``lengths``)."""
    out: dict[str, Road] = {}
    for name, m in movements["movements"].items():
        r = out.setdefault(m["approach"], Road(m["approach"], m.get("junction", ""),
                                               control_zone_start_m=m["control_zone_start_m"],
                                               merge_entry_m=m["merge_entry_m"], merge_exit_m=m["merge_exit_m"]))
        r.control_zone_start_m = min(r.control_zone_start_m, m["control_zone_start_m"])
        r.merge_entry_m = min(r.merge_entry_m, m["merge_entry_m"])
        r.merge_exit_m = max(r.merge_exit_m, m["merge_exit_m"])
        off = 0.0
        for k, lane in enumerate(m["lanes"]):
            mv = None if k == 0 else m["turn"]  # (the approach lane is every movement's)
            r.lane_offset.setdefault(lane, (mv, off))
            r.edge_offset.setdefault(edge_of(lane), (mv, off))
            off += lengths.get(lane, np.nan)
    return out


def _segments_from_fcd(fcd: pd.DataFrame, places: dict[str, object], is_start) -> dict[str, list]:
    """Cut each vehicle's fcd rows into one segment per place it travels along: ``places[name]``
    has ``offset(lane) -> (movement, offset) | None`` and ``top_m``; a segment opens where
    ``is_start(name, lane)`` and lasts while the vehicle stays on the place's lanes below its top
    (so a vehicle can be on two places at once: the end of one junction's path and the start of
    the next road). Returns ``{name: [(vehicle, segment, t, s, movement)]}``."""
    out: dict[str, list] = {name: [] for name in places}
    seg_no = 0
    fcd = fcd.sort_values(["vehicle_id", "t"], kind="stable")
    for vid, g in fcd.groupby("vehicle_id", sort=False):
        open_: dict[str, list] = {}  # place -> [segment, movement]
        for t, lane, pos in zip(g["t"].to_numpy(), g["lane"].to_numpy(), g["pos"].to_numpy()):
            for name in list(open_):
                hit = places[name].offset(lane)
                s = None if hit is None else hit[1] + pos
                if s is None or not s <= places[name].top_m:
                    del open_[name]
                    continue
                if hit[0] is not None:
                    open_[name][1] = hit[0]
                out[name].append((vid, open_[name][0], t, s, open_[name][1]))
            for name in places:
                if name not in open_ and is_start(name, lane):
                    seg_no += 1
                    hit = places[name].offset(lane)
                    open_[name] = [seg_no, hit[0]]
                    out[name].append((vid, seg_no, t, hit[1] + pos, hit[0]))
    return out


def _legs(run_dir: Path) -> pd.DataFrame:
    return pd.read_csv(Path(run_dir) / "vehicles.csv", dtype={"vehicle_id": str})


def movement_names(movements: dict, vehicles: pd.DataFrame) -> pd.Series:
    """The name in ``movements.json`` of each crossing of ``vehicles.csv``: the movement of its
    approach and turn that starts on its lane (a wider approach, or two roads of one turn, has
    several of that approach and turn), else the first of that approach and turn."""
    exact, loose = {}, {}
    for name, m in movements["movements"].items():
        exact.setdefault((m["approach"], m["turn"], m["lanes"][0]), name)
        loose.setdefault((m["approach"], m["turn"]), name)
    return pd.Series([exact.get((a, t, ln), loose.get((a, t))) for a, t, ln in
                      zip(vehicles["approach"], vehicles["movement"], vehicles["lane"].astype(str))],
                     index=vehicles.index, dtype=object)


def _traj_by_leg(run_dir: Path, vehicles: pd.DataFrame, movements: dict) -> pd.DataFrame:
    """The controlled vehicles' trajectory rows, each with the leg it belongs to (the crossing
    whose control zone the vehicle entered last): ``approach``, ``movement`` (the turn), ``name``
    (its movement in ``movements.json``), ``segment``, and ``s_m`` from the start of the approach
    edge (the trajectories' is from the control-zone entry) [m]."""
    from nrtraffic.results import read_trajectories

    traj = read_trajectories(run_dir)[["t", "vehicle_id", "s_m"]].copy()
    traj["vehicle_id"] = traj["vehicle_id"].astype(str)
    legs = vehicles[vehicles["t_enter_s"].notna()].copy()
    legs["name"] = movement_names(movements, legs)
    legs = legs[["vehicle_id", "approach", "movement", "name", "t_enter_s"]].sort_values("t_enter_s")
    legs = legs.reset_index(drop=True)
    legs["segment"] = legs.index + 1
    if traj.empty or legs.empty:
        return traj.iloc[0:0]
    traj = pd.merge_asof(traj.sort_values("t"), legs, left_on="t", right_on="t_enter_s", by="vehicle_id",
                         direction="backward")
    first = legs.drop_duplicates("vehicle_id").set_index("vehicle_id")  # rows before the first entry
    for col in ("approach", "movement", "name", "segment"):
        traj[col] = traj[col].fillna(traj["vehicle_id"].map(first[col]))
    traj = traj.dropna(subset=["segment", "name"])
    start = {k: m["control_zone_start_m"] for k, m in movements["movements"].items()}
    traj["s_m"] = traj["s_m"] + traj["name"].map(start)
    return traj


def _frame(rows: list, drivers: dict) -> pd.DataFrame:
    df = pd.DataFrame(rows, columns=SERIES_COLUMNS[:5])
    df["driver"] = df["vehicle_id"].map(drivers).fillna("sumo")
    return df.sort_values(["segment", "t"], kind="stable").reset_index(drop=True)


def _fcd(run_dir: Path) -> pd.DataFrame:
    """The run's fcd.xml, its times from the run's start (summary.json ``begin_s``)."""
    try:
        t0 = float(json.loads((Path(run_dir) / "summary.json").read_text()).get("begin_s") or 0.0)
    except (OSError, ValueError):
        t0 = 0.0
    return read_fcd_lanes(Path(run_dir) / "fcd.xml", t0)


def source_of(run_dir: Path) -> str:
    """``fcd`` where the run wrote SUMO's floating-car data, else ``trajectories``."""
    return "fcd" if (Path(run_dir) / "fcd.xml").is_file() else "trajectories"


def _drivers(vehicles: pd.DataFrame) -> dict:
    return dict(zip(vehicles["vehicle_id"], vehicles["driver"]))


def time_space_series(run_dir: Path, source: str | None = None) -> dict[str, pd.DataFrame]:
    """Per approach road of the run's junctions, the series its time-space panel draws: rows
    ``vehicle_id, segment, t [s], s_m [m], movement, driver`` (``driver``: automated, human, or
    ``sumo`` for a vehicle of the scenario's own that is in no table), one ``segment`` per vehicle
    and road, ordered by time. ``s_m``: distance from the start of the approach edge along the
    vehicle's path, up to :data:`PAST_ZONE_M` past the end of the merging zone (see the module
    docstring for where it comes from; ``source``: ``fcd`` or ``trajectories``, by default
    :func:`source_of` the run)."""
    run_dir = Path(run_dir)
    doc = json.loads((run_dir / "movements.json").read_text())
    vehicles = _legs(run_dir)
    source = source or source_of(run_dir)
    panels = roads(doc, lane_lengths(run_dir) if source == "fcd" else {})
    drivers = _drivers(vehicles)
    if source == "fcd":
        fcd = _fcd(run_dir)
        rows = _segments_from_fcd(fcd, panels, lambda name, lane: edge_of(lane) == name)
        # a vehicle's turn where its path never left the approach edge: from vehicles.csv
        turn = {(v, a): m for v, a, m in zip(vehicles["vehicle_id"], vehicles["approach"], vehicles["movement"])}
        out = {}
        for name, r in rows.items():
            df = _frame(r, drivers)
            known = [turn.get((v, name)) for v in df["vehicle_id"]]
            df["movement"] = [k if isinstance(k, str) and k else m for k, m in zip(known, df["movement"])]
            out[name] = df
        return out
    traj = _traj_by_leg(run_dir, vehicles, doc)
    if traj.empty:
        return {name: _frame([], drivers) for name in panels}
    out = {}
    for name, road in panels.items():
        g = traj[(traj["approach"] == name) & (traj["s_m"] <= road.top_m)]
        out[name] = _frame(list(zip(g["vehicle_id"], g["segment"].astype(int), g["t"], g["s_m"], g["movement"])),
                           drivers)
    return out


@dataclass
class Arterial:
    """One direction of a corridor: its straight movements in order, the offset of each of its
    lanes along it [m], and each junction's merging zone along it [m]."""

    name: str  # the road it enters the corridor by
    lane_offset: dict[str, tuple[str, float]]
    edge_offset: dict[str, tuple[str, float]]
    zones: list[tuple[str, float, float]]  # (junction, merging-zone entry, exit) [m]
    approaches: dict[str, float]  # each junction's approach road -> its offset [m]
    top_m: float = np.inf

    def offset(self, lane: str) -> tuple[str, float] | None:
        return self.lane_offset.get(lane) or self.edge_offset.get(edge_of(lane))


def arterials(movements: dict, lengths: dict[str, float]) -> dict[str, Arterial]:
    """The corridor's directions: chains of straight movements, each leaving by the road the next
    enters its junction by, through two or more junctions; keyed by the road the chain enters by."""
    mvs = {k: m for k, m in movements["movements"].items() if m["turn"] in ("straight", "through")}
    by_approach = {m["approach"]: k for k, m in mvs.items()}
    exit_of = {k: edge_of(m["lanes"][-1]) for k, m in mvs.items()}
    fed = set(exit_of.values())
    out = {}
    for k, m in mvs.items():
        if m["approach"] in fed:
            continue  # (not the first of its chain)
        chain = [k]
        while exit_of[chain[-1]] in by_approach and by_approach[exit_of[chain[-1]]] not in chain:
            chain.append(by_approach[exit_of[chain[-1]]])
        if len(chain) < 2:
            continue
        lanes, edges, zones, appr = {}, {}, [], {}
        base = 0.0
        for i, name in enumerate(chain):
            mv = mvs[name]
            appr[mv["approach"]] = base
            zones.append((mv.get("junction", ""), base + mv["merge_entry_m"], base + mv["merge_exit_m"]))
            off = base
            last = i == len(chain) - 1
            for j, lane in enumerate(mv["lanes"]):
                if j == len(mv["lanes"]) - 1 and not last:
                    base = off  # the exit edge is the next movement's approach
                    break
                lanes.setdefault(lane, (name, off))
                edges.setdefault(edge_of(lane), (name, off))
                off += lengths.get(lane, np.nan)
            if last:
                top = off
        out[m["approach"]] = Arterial(m["approach"], lanes, edges, zones, appr, top)
    return out


def arterial_series(run_dir: Path, source: str | None = None) -> tuple[dict[str, pd.DataFrame],
                                                                              dict[str, Arterial]]:
    """Per direction of a corridor (:func:`arterials`, none for a single junction), the series its
    arterial diagram draws: rows ``vehicle_id, segment, t [s], s_m [m], movement, driver`` with
    ``s_m`` the distance along the arterial from the start of the road it enters by (``movement``
    empty: the diagram does not colour by movement); one segment
    per vehicle and stretch it travels along the arterial (with fcd: its whole time on it;
    otherwise: each of its controlled legs on it). Returns the series and the directions."""
    run_dir = Path(run_dir)
    doc = json.loads((run_dir / "movements.json").read_text())
    lengths = lane_lengths(run_dir)
    arts = arterials(doc, lengths)
    if not arts:
        return {}, {}
    vehicles = _legs(run_dir)
    drivers = _drivers(vehicles)
    if (source or source_of(run_dir)) == "fcd":
        fcd = _fcd(run_dir)
        rows = _segments_from_fcd(fcd, arts, lambda name, lane: arts[name].offset(lane) is not None)
        return {name: _frame(r, drivers).assign(movement="") for name, r in rows.items()}, arts
    traj = _traj_by_leg(run_dir, vehicles, doc)
    if traj.empty:
        return {name: _frame([], drivers) for name in arts}, arts
    out = {}
    for name, art in arts.items():
        g = traj[traj["name"].isin({mv for mv, _ in art.lane_offset.values()})]
        s = g["approach"].map(art.approaches).astype(float) + g["s_m"]  # (float: a direction no one drove)
        out[name] = _frame(list(zip(g["vehicle_id"], g["segment"].astype(int), g["t"], s, g["movement"])),
                           drivers).assign(movement="")
    return out, arts
