"""What every phase of a run's tick reads and writes: the vehicles' records and lifecycle, SUMO's
view of the step, the junctions and their paths, and the controlled vehicles' kernel.

One :class:`RunState` per run, made by the engine; the junctions' admission
(:mod:`nrtraffic.junction.admission`, :mod:`nrtraffic.junction.humans`), the measurements
(:mod:`nrtraffic.measure`) and the results (:mod:`nrtraffic.results`) take it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from nrtraffic.junction import Junction, Layout, Movement
from nrtraffic.lifecycle import Lifecycle, VehicleRecord


@dataclass
class RunState:
    sc: object  # the scenario
    params: object  # the controlled vehicle's VehicleParams
    layout: Layout
    control: bool  # False: a baseline, SUMO drives every vehicle
    records: dict[str, VehicleRecord] = field(default_factory=dict)  # each vehicle's crossing now (or its last)
    crossings: list[VehicleRecord] = field(default_factory=list)  # a corridor's finished crossings before the last
    life: Lifecycle = None
    t: float = 0.0  # simulated time of the step [s]
    snap: object = None  # SUMO's vehicles at t (:class:`~nrtraffic.sumo.adapter.VehicleTable`)
    sumo: object = None  # the SumoSession
    kernel: object = None  # the Kernel (controlled vehicles)
    paths: dict[str, Movement] = field(default_factory=dict)
    stop_line: dict = field(default_factory=dict)  # (movement, driver) -> (lane, position [m])
    conflict_areas: dict = field(default_factory=dict)
    itineraries: dict = field(default_factory=dict)  # a corridor trip's route -> its turning movements
    reservations: dict = field(default_factory=dict)  # human driver -> (its reserved crossing, its bounds)
    mixed: bool = False  # human drivers take part (demand.controlled_share < 1, or a file's other types)

    def __post_init__(self):
        if self.life is None:
            self.life = Lifecycle(self.records)
        self.junctions: dict[str, Junction] = self.layout.junctions

    def cg_on_path(self, vid: str) -> float | None:
        """Where a SUMO-driven vehicle's centre of gravity is on its movement's path now [m] (None
        off the path's lanes)."""
        mv = self.paths[self.records[vid].movement]
        k = self.snap.row[vid]
        if self.snap.lane[k] not in mv.lane_offset:
            return None
        return mv.s_of(self.snap.lane[k], float(self.snap.lane_pos[k])) - self.params.cg_to_front

    def where_on_path(self, vid: str) -> float:
        """:meth:`cg_on_path`, -inf where SUMO does not have the vehicle on its path's lanes now."""
        s = self.cg_on_path(vid) if vid in self.snap.row else None
        return -math.inf if s is None else s

    def choose_lane(self, vid: str, lane: str) -> bool:
        """A vehicle that SUMO lets change lanes (``lane_kept`` false) is on ``lane`` now: where a
        movement of its turn (its record's ``route``) starts there, that becomes its movement and
        entry lane (True); False on a lane that does not serve its turn. Lanes are chosen by SUMO's
        driver upstream of the control zone and kept inside it."""
        rec = self.records[vid]
        for ln, name, _, _ in self.layout.lane_movements[rec.route]:
            if ln == lane:
                rec.movement, rec.lane = name, lane
                return True
        return False

    def standing_at_stop(self, vid: str) -> bool:
        """Whether a vehicle stands at the stop :func:`~nrtraffic.junction.build.stop_lines` gives
        it (and SUMO says so)."""
        rec = self.records[vid]
        k = self.snap.row.get(vid)
        lane, pos = self.stop_line[rec.movement, rec.driver]
        return (k is not None and self.snap.lane[k] == lane and self.snap.lane_pos[k] >= pos - 1.0
                and self.snap.speed[k] < 0.1 and self.sumo.is_stopped(vid))
