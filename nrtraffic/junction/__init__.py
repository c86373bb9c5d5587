"""The controlled junctions of a run: what they are, how they are built from the network, and
how they admit vehicles.

A run holds one :class:`Junction` per controlled junction (``[[junctions]]``; one for ``[junction]
id``, and one without a centre for a plain road of ``[[approaches]]``). Movement and lane names are
the network's, so they are unique across the junctions of a run: the run keeps the movements'
paths in one table (the kernel reads them all) and each junction lists its own.

- :class:`Layout`: the junctions and their movements as the network file gives them, before SUMO
  starts (the demand's unit, the turning movement, and its lanes);
- :mod:`nrtraffic.junction.build`: once SUMO has read the network, each movement's path and zones,
  the stop lines, the relations and conflict areas, the queue detectors;
- :mod:`nrtraffic.junction.admission` and :mod:`nrtraffic.junction.humans`: each step, who is
  scheduled, batched, held, started from rest; human drivers' reserved crossings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nrtraffic.geometry import LanePath
from nrtraffic.sumo.network import edge_nodes, feeder_roads, junction_movements
from nrtraffic.planning.coordinator import Coordinator


@dataclass
class Movement:
    """A movement's lane path and its zone boundaries (arc length of the centre of gravity) [m].

    A movement is one lane-to-lane connection: ``approach`` is the incoming road, ``turn`` the
    turning movement (left, straight, right; ``through`` on a plain road), ``route_name`` the
    turning movement it belongs to (the demand's unit: ``<approach>.<turn>``, several lanes may
    serve it), ``junction`` the id of the junction it crosses, and ``lanes[0]`` its entry lane, the
    coordinator's lane key.
    """

    name: str
    approach: str
    turn: str
    route: tuple[str, ...]
    path: LanePath
    lanes: list  # lane ids in driving order
    lane_offset: dict  # lane id -> (s at lane start, path length / SUMO length)
    s_control: float
    s_merge: float
    s_exit: float
    v_limit: float = math.inf  # lowest lane speed limit along the path (SUMO's turn speeds) [m/s]
    route_name: str = ""
    junction: str = ""
    # the roads of the path (not the junction's own lanes) on which a car's front, on any of their
    # lanes, can lie past s_exit: where a queue can block its exit (nrtraffic.junction.exits)
    exit_edges: frozenset = frozenset()

    def s_of(self, lane: str, pos: float) -> float:
        off, scale = self.lane_offset[lane]
        return off + pos * scale


@dataclass
class Junction:
    """A controlled junction and the state of its coordination.

    ``xy`` is its centre [m] (None on a plain road, whose merging zone starts at each approach's
    ``merge_entry_edge``); ``merging_zone_m`` the diameter of its merging zone (the length of the
    zone on a plain road) and ``control_zone_m`` the length of its control zone before it [m].
    ``movements`` are the names of its movements (keys of the engine's paths); ``relations`` and
    ``conflict_areas`` relate them to each other only; ``coord`` schedules the vehicles entering its
    control zone. With ``policy = "batch"``, its batch closes at ``batch_closes`` [s]. ``idle_since``,
    ``looked_at`` and the ``lane_`` tables are the watchdog's (:func:`nrtraffic.watchdog.watch_junctions`).
    """

    id: str
    xy: tuple[float, float] | None
    control_zone_m: float
    merging_zone_m: float
    movements: list[str] = field(default_factory=list)
    relations: dict = field(default_factory=dict)
    conflict_areas: dict = field(default_factory=dict)
    coord: Coordinator | None = None
    batch_closes: float = math.inf
    idle_since: float = 0.0  # since when no vehicle left its merging zone while vehicles waited [s]
    looked_at: float = -math.inf  # when the watchdog last looked [s]
    lane_exit: dict = field(default_factory=dict)  # entry lane -> when a vehicle of it last left the zone [s]
    lane_waiting: dict = field(default_factory=dict)  # entry lane -> since when vehicles have waited on it [s]

    def left_zone(self, lane: str, t: float) -> None:
        """A vehicle that entered on ``lane`` left the merging zone at ``t`` [s] (for the watchdog)."""
        self.lane_exit[lane] = t

    def in_merging_zone(self, xy: np.ndarray) -> np.ndarray:
        """Whether points ``xy`` (n x 2) [m] lie inside the merging zone's disc."""
        d = np.hypot(xy[:, 0] - self.xy[0], xy[:, 1] - self.xy[1])
        return d <= self.merging_zone_m / 2.0


class Layout:
    """The run's junctions and movements known from the network file alone (SUMO is not started).

    ``junctions``: id -> :class:`Junction` (its zones; its movements, relations and coordinator
    follow once SUMO runs); ``movement_table``: turning movement (``<approach>.<turn>``, the
    demand's unit) -> (approach, turn, route edges); ``lane_movements``: turning movement -> its
    lane-level movements ``(entry lane, name, entry lane index, exit lane index)``, one per lane
    that serves it (a one-lane approach: one, of the same name); ``movement_junction``: turning
    movement -> the junction it crosses; ``next_junction`` / ``upstream_junction``: edge -> the
    controlled junction it leads into / comes from, where there is one (a corridor);
    ``entry_approaches``: where demand enters (the approaches that do not come from another
    controlled junction); ``feeders``: turning movement -> the road upstream of its approach
    that only feeds it (:func:`~nrtraffic.sumo.network.feeder_roads`), where the demand's
    vehicles start.
    """

    def __init__(self, sc, network_path):
        self.movement_table: dict[str, tuple[str, str, tuple[str, ...]]] = {}
        self.lane_movements: dict[str, list[tuple[str, str, int, int | None]]] = {}
        self.movement_junction: dict[str, str] = {}
        self.junctions: dict[str, Junction] = {}
        self.next_junction: dict[str, str] = {}
        self.upstream_junction: dict[str, str] = {}
        self.feeders: dict[str, tuple[str, ...]] = {}
        specs = sc.controlled_junctions()
        for j in specs:
            moves, xy = junction_movements(network_path, j.id)
            self.junctions[j.id] = Junction(j.id, xy, j.control_zone_m, j.merging_zone_m)
            for m in moves:
                self.movement_table[m.route] = (m.in_edge, m.turn, (m.in_edge, m.out_edge))
                self.lane_movements.setdefault(m.route, []).append((m.lane, m.name, m.in_lane, m.out_lane))
                self.movement_junction[m.route] = j.id
        if specs:
            ids = {j.id for j in specs}
            for route, (edge, _, _) in self.movement_table.items():
                self.feeders[route] = feeder_roads(network_path, edge, ids)
        if len(specs) > 1:
            nodes = edge_nodes(network_path)
            self.next_junction = {e: to for e, (_, to) in nodes.items() if to in self.junctions}
            self.upstream_junction = {e: fr for e, (fr, _) in nodes.items() if fr in self.junctions}
        if not specs:
            z = sc.zones
            self.junctions[""] = Junction("", None, z.control_zone_m, z.merging_zone_m)
            for a in sc.approaches:
                self.movement_table[a.name] = (a.name, "through", a.route)
                self.lane_movements[a.name] = [(f"{a.route[0]}_0", a.name, 0, None)]
                self.movement_junction[a.name] = ""
        self.entry_approaches = {a for a, _, _ in self.movement_table.values() if a not in self.upstream_junction}

    def drop_unused_uturns(self, used: set[str]) -> None:
        """Leave out the U-turns no vehicle of the run takes: a junction is controlled on the paths
        its traffic drives (a U-turn the car cannot drive refuses the junction only where some
        vehicle would make it)."""
        for route in [r for r, (_, turn, _) in self.movement_table.items() if turn == "uturn" and r not in used]:
            del self.movement_table[route], self.lane_movements[route], self.movement_junction[route]
            self.feeders.pop(route, None)

    def entry_lanes(self, approach: str) -> set[str]:
        """The lanes of ``approach`` that some movement starts from."""
        return {lm[0] for route, (a, _, _) in self.movement_table.items() if a == approach
                for lm in self.lane_movements[route]}

    @property
    def approaches(self) -> list[str]:
        """Every approach of every junction, sorted."""
        return sorted({a for a, _, _ in self.movement_table.values()})
