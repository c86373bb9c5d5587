"""One controlled junction: its movements, zones, relations, conflict areas and coordinator.

A run holds one :class:`Junction` per controlled junction (``[[junctions]]``; one for ``[junction]
id``, and one without a centre for a plain road of ``[[approaches]]``). Movement and lane names are
the network's, so they are unique across the junctions of a run: the engine keeps the movements'
paths in one table (the kernel reads them all) and each junction lists its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from nrtraffic.geometry import LanePath
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
    control zone. With ``policy = "batch"``, ``pending`` are the vehicles in its control zone
    waiting for the batch that closes at ``batch_closes`` [s].
    """

    id: str
    xy: tuple[float, float] | None
    control_zone_m: float
    merging_zone_m: float
    movements: list[str] = field(default_factory=list)
    relations: dict = field(default_factory=dict)
    conflict_areas: dict = field(default_factory=dict)
    coord: Coordinator | None = None
    pending: list[str] = field(default_factory=list)
    batch_closes: float = math.inf

    def in_merging_zone(self, xy: np.ndarray) -> np.ndarray:
        """Whether points ``xy`` (n x 2) [m] lie inside the merging zone's disc."""
        d = np.hypot(xy[:, 0] - self.xy[0], xy[:, 1] - self.xy[1])
        return d <= self.merging_zone_m / 2.0
