"""The co-simulation loop: SUMO + coordinator + profiles + NR-flow tracking + barriers + plant.

Per SUMO step (``sumo.step_length_s``), at time ``t`` with SUMO and the embedded models in step:
vehicles SUMO inserted drive at their entry speed until their centre of gravity crosses the
control-zone entry; then they are admitted (coordinator -> merge time -> energy-optimal profile ->
reference on their lane path). The leader of every controlled vehicle on its path is found and its
state handed to the kernel; the state at ``t`` is logged; the compiled kernel advances every
controlled vehicle to ``t + dt`` through the plant sub-steps; the poses are pushed to SUMO, and
vehicles past the merging zone are handed back to SUMO; then SUMO steps. The loop composes the
pieces; the maths lives in ``vehicle``, ``control``, ``planning`` and ``geometry``.

A run controls one junction or several (:class:`~nrtraffic.junction.Junction`: zones, relations,
coordinator each); a vehicle's record is one crossing, and on a corridor a vehicle released by one
junction starts a new record for the next on its route. The vehicles under control are the
:class:`~nrtraffic.control.table.ControlledTable` the kernel reads.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from nrtraffic import __version__, metrics
from nrtraffic.control import batch as kb
from nrtraffic.control.leaders import find_leaders, pack_path_lanes
from nrtraffic.control.nr_flow import PREDICTORS
from nrtraffic.control.table import N_PROFILE_SEG, ControlledTable
from nrtraffic.demand import shifted_exponential_arrivals
from nrtraffic.geometry import LanePath, segment_frames, touching_pairs
from nrtraffic.junction import Junction, Movement
from nrtraffic.planning.conflicts import MovementGeometry, classify, conflict_areas
from nrtraffic.planning.coordinator import REAR_END_TOL_M, Assignment, Coordinator, Request, ScheduleInfeasible
from nrtraffic.planning.crossing import CrossingBounds, human_crossing
from nrtraffic.planning.profiles import from_rest, packed_position
from nrtraffic.results import VEHICLE_COLUMNS, RunResult, TrajectoryWriter, parse_queues
from nrtraffic.scenario import TURNS, Scenario
from nrtraffic.sumo.adapter import SumoSession, VehicleType, sumo_version, write_routes, write_sumocfg
from nrtraffic.sumo.network import NetworkError, edge_nodes, junction_movements
from nrtraffic.vehicle.fuel import fuel_rate

MIN_CONTROL_ZONE_M = 20.0  # shortest control zone a route may leave after a cut [m]
STEADY_AFTER_S = 3.0  # DESIGN.md: steady-state tracking error counts after 3 s under control
PATH_SPACING_M = 0.25  # sampling of the smoothed lane paths [m]
LEADER_LOOKAHEAD_M = 200.0  # how far along its path a vehicle looks for its leader [m]
STOP_BEFORE_M = 0.5  # a vehicle that must stand before it crosses stops this far short of its limit (_stop_lines) [m]
# slack of a reserved start from rest of a controlled vehicle (its tracking error, in time) [s]
FROM_REST_SLACK_S = 0.3
HUMAN_BODY = "~human"  # suffix of a movement's name for a human driver's body on it (conflict areas)
SHARE_STREAM = 0x6875_6D61_6E  # the run seed's stream that draws which vehicles are controlled ("human")
ROUTE_STREAM = 0x726F_757465  # the run seed's stream that draws a vehicle's turns after its first junction ("route")
CHECKPOINT_WALL_S = 10.0  # wall time between checkpoints of the figures (``checkpoint``) [s]
# parts of the loop timed for ``wall_time_breakdown_s``: the compiled kernel (with the Python that
# reads its results), SUMO's step (with its collision list), reading and writing SUMO's vehicles,
# admission (coordinator; its rear-end QPs also as ``qp``), leader search, the own collision check,
# and trajectory logging
WALL_PHASES = ("kernel", "sumo_step", "sumo_io", "admission", "qp", "leaders", "collision_check", "logging")


def _max_curvature(path, s_from: float, s_to: float, window_m: float = 2.0) -> float:
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


def _curve_speed(path, s_from: float, s_to: float, a_lat: float, window_m: float = 2.0) -> float:
    """Highest constant speed [m/s] on ``[s_from, s_to]`` of ``path`` at lateral acceleration
    ``a_lat`` [m/s^2]: ``sqrt(a_lat / kappa_max)``, the curvature [1/m] averaged over ``window_m``
    (inf when ``a_lat`` is 0, no bound, or the path is straight)."""
    if a_lat <= 0.0:
        return math.inf
    k_max = _max_curvature(path, s_from, s_to, window_m)
    return math.sqrt(a_lat / k_max) if k_max > 1e-9 else math.inf


class RunFailed(RuntimeError):
    """A run stopped early; ``result`` holds what was finished."""

    def __init__(self, message: str, result: RunResult):
        super().__init__(message)
        self.result = result


@dataclass
class VehicleRecord:
    vehicle_id: str
    approach: str
    t_depart: float
    movement: str = ""  # its lane-level movement (a key of Engine.paths), from the lane SUMO gives it
    route: str = ""  # its turning movement (the demand's route name)
    lane: str = ""  # its entry lane: the coordinator's lane key
    junction: str = ""  # the junction it crosses (a record is one crossing; a corridor trip has several)
    legs: tuple = ()  # the turning movements of its trip, one per junction, in order
    leg: int = 0  # which of them this record is
    v_free: float = math.nan  # its free-flow speed: the speed it was sent in with [m/s]
    controlled: bool = True
    driver: str = "automated"  # or "human" (demand.controlled_share): what kind of vehicle it is
    heading_offset: float = 0.0
    speed_profile: tuple = ()
    # waiting -> approaching -> controlled -> released | lost; "sumo" if not controlled; a human driver:
    # human (to the stop line) -> reserved (standing, its crossing reserved) -> crossing
    status: str = "waiting"
    t_enter: float = math.nan
    v_enter: float = math.nan
    s_enter: float = math.nan
    t_merge_planned: float = math.nan
    v_merge_planned: float = math.nan
    t_merge_actual: float = math.nan
    t_exit: float = math.nan
    predecessor: str | None = None
    relation: str = ""
    binding: str = ""
    profile_kind: str = ""
    plan_intrusion: float = math.nan
    acc: np.ndarray = field(default_factory=lambda: kb.new_acc(1)[0])
    min_gap: float = math.inf
    s_last: float = math.nan
    t_held: float = 0.0  # time held at the control-zone entry for want of a feasible schedule [s]
    hindered: bool = False  # its scheduling waited for a human driver ahead on its lane
    t_release: float = math.nan  # a human driver: when its reserved crossing starts [s]
    depart_delay: float = 0.0  # SUMO's wait to insert it past its desired departure (a backed-up lane) [s]
    t_arrive: float = math.nan  # when its centre of gravity crossed the control-zone entry [s] ...
    s_arrive: float = math.nan  # ... and where on its path it was then [m] (delay is counted from there)


class Engine:
    """One co-simulation run.

    Parameters
    ----------
    scenario : validated scenario.
    workdir : where SUMO's inputs (``sumo/``) and outputs are written.
    seed : random seed (arrivals and SUMO's ``--seed``); default the scenario's.
    duration_s : simulated time [s]; default the scenario's (0: until every vehicle has left).
    trajectories : optional streaming writer for per-step vehicle rows.
    progress : show a progress bar.
    control : False runs the same demand with SUMO driving every vehicle (a baseline); the zone
        crossings and figures are measured the same way.
    network : a network to use instead of the scenario's (the baselines' junction control).
    label : what drove the vehicles, for the summary ("nrtraffic" or the baseline's name).
    additional : further SUMO additional files (a baseline's coordinated signal offsets).
    checkpoint : called with the figures so far (a :class:`RunResult` whose summary says
        ``"status": "running"``) about every ``CHECKPOINT_WALL_S`` seconds of wall time, so that a
        run killed outright leaves its last checkpoint on disk. Wall-clock timing only decides
        when files are written, never what is simulated.
    """

    def __init__(self, scenario: Scenario, workdir: Path, seed: int | None = None, duration_s: float | None = None,
                 trajectories: TrajectoryWriter | None = None, progress: bool = False, control: bool = True,
                 network: Path | None = None, label: str = "nrtraffic", checkpoint=None, gui: bool = False,
                 additional: tuple = ()):
        self.sc = scenario
        self.additional = tuple(additional)
        self.control = control
        self.network_path = Path(network) if network is not None else scenario.network_path
        self.label = label
        self.checkpoint = checkpoint
        self.gui = gui
        self.seed = scenario.general.seed if seed is None else int(seed)
        self.duration = scenario.general.duration_s if duration_s is None else float(duration_s)
        self.workdir = Path(workdir)
        self.traj = trajectories
        self.progress = progress
        self.params = scenario.vehicle.params()
        c, b = scenario.controller, scenario.barriers
        self.plant_p = self.params.as_array()
        self.pred_p = self.params.with_mass_factor(c.predictor_mass_factor).as_array()
        self.u_lo = np.array([c.a_min_mps2, -c.steer_max_rad])
        self.u_hi = np.array([c.a_max_mps2, c.steer_max_rad])
        self.n_sub = int(round(scenario.sumo.step_length_s / c.plant_step_s))
        cfg = np.zeros(kb.N_CFG)
        cfg[kb.CFG_H] = c.plant_step_s
        cfg[kb.CFG_HORIZON] = c.horizon_s
        cfg[kb.CFG_DT_PRED] = c.predictor_step_s
        cfg[kb.CFG_PREDICTOR] = PREDICTORS[c.predictor]
        cfg[kb.CFG_ALPHA] = c.alpha
        cfg[kb.CFG_DAMPING] = c.damping
        cfg[kb.CFG_STEADY_AFTER] = STEADY_AFTER_S
        cfg[kb.CFG_CBF_LONG] = float(b.longitudinal)
        cfg[kb.CFG_CBF_LAT] = float(b.lateral)
        # centre distance, same vehicle type; the margins leave room for measurement error
        cfg[kb.CFG_D0] = b.min_gap_m + self.params.length + b.gap_margin_m
        cfg[kb.CFG_A_BAR] = b.max_braking_mps2
        cfg[kb.CFG_LONG_GAIN] = b.longitudinal_gain
        cfg[kb.CFG_ROOT_C] = b.root_smoothing_mps
        cfg[kb.CFG_Y_MAX] = b.max_lateral_dev_m - b.lateral_margin_m
        cfg[kb.CFG_K_LAT] = 1.0 / (2.0 * b.max_lateral_accel_mps2)
        cfg[kb.CFG_GAMMA] = b.lateral_gamma
        cfg[kb.CFG_BISECT_TOL] = b.bisection_tol_rad
        cfg[kb.CFG_ANTI_WINDUP] = float(b.anti_windup)
        cfg[kb.CFG_QP_MODE] = 0.0 if b.qp_solver == "closed_form" else 1.0
        if b.qp_solver != "closed_form":
            kb.QP_SOLVER[0] = b.qp_solver
        dist = scenario.disturbances
        cfg[kb.CFG_LAG_TAU] = dist.actuator_lag_s
        cfg[kb.CFG_FORCE_LONG] = dist.longitudinal_accel_mps2
        cfg[kb.CFG_FORCE_LAT] = dist.lateral_accel_mps2
        cfg[kb.CFG_OBSERVER_TAU] = dist.observer_time_s
        self.cfg = cfg
        # measurement noise: its own stream of the run's seed (arrivals are drawn from another), one
        # draw per controlled vehicle and plant step in the order of the batch
        self.noise_sd = np.zeros(kb.N_NOISE)  # standard deviation of each column of the noise
        self.noise_sd[[kb.NZ_X, kb.NZ_Y, kb.NZ_LX, kb.NZ_LY]] = dist.position_noise_m
        self.noise_sd[[kb.NZ_VL, kb.NZ_VN, kb.NZ_LVX, kb.NZ_LVY]] = dist.speed_noise_mps
        self.noise_sd[kb.NZ_PSI] = dist.heading_noise_rad
        self.noise_rng = np.random.default_rng([self.seed, 0x6E6F697365]) if dist.noisy else None
        self.records: dict[str, VehicleRecord] = {}  # each vehicle's crossing now (or its last)
        self.crossings: list[VehicleRecord] = []  # a corridor's finished crossings of junctions before the last
        self.zone_cuts: dict[str, float] = {}  # movement -> its control zone's length where it was cut [m]
        self.collision_pairs: set[tuple[str, str]] = set()
        self.geometric_collisions: set[tuple[str, str]] = set()
        self.collision_log: list[dict] = []  # first contact of each pair: time, ids, who saw it
        self.t = 0.0
        # wall time per part of the loop [s] (summary.json ``wall_time_breakdown_s``; benchmarks)
        self.wall_breakdown = dict.fromkeys(WALL_PHASES, 0.0)

    # ------------------------------------------------------------------ set-up
    def _movement_table(self) -> None:
        """Junctions and movements known before SUMO starts. ``junctions``: id -> :class:`Junction`
        (its zones; its movements, relations and coordinator follow once SUMO runs);
        ``movement_table``: turning movement (``<approach>.<turn>``, the demand's unit) ->
        (approach, turn, route edges); ``lane_movements``: turning movement -> its lane-level
        movements ``(entry lane, name, entry lane index, exit lane index)``, one per lane that serves
        it (a one-lane approach: one, of the same name); ``movement_junction``: turning movement ->
        the junction it crosses; ``next_junction``: outgoing edge -> the controlled junction it
        leads into, where there is one (a corridor)."""
        sc = self.sc
        self.movement_table: dict[str, tuple[str, str, tuple[str, ...]]] = {}
        self.lane_movements: dict[str, list[tuple[str, str, int, int | None]]] = {}
        self.movement_junction: dict[str, str] = {}
        self.junctions: dict[str, Junction] = {}
        self.next_junction: dict[str, str] = {}
        specs = sc.controlled_junctions()
        for j in specs:
            moves, xy = junction_movements(self.network_path, j.id)
            self.junctions[j.id] = Junction(j.id, xy, j.control_zone_m, j.merging_zone_m)
            for m in moves:
                self.movement_table[m.route] = (m.in_edge, m.turn, (m.in_edge, m.out_edge))
                self.lane_movements.setdefault(m.route, []).append((m.lane, m.name, m.in_lane, m.out_lane))
                self.movement_junction[m.route] = j.id
        if len(specs) > 1:
            nodes = edge_nodes(self.network_path)
            self.next_junction = {e: to for e, (_, to) in nodes.items() if to in self.junctions}
            self.upstream_junction = {e: fr for e, (fr, _) in nodes.items() if fr in self.junctions}
        else:
            self.upstream_junction = {}
        if not specs:
            z = sc.zones
            self.junctions[""] = Junction("", None, z.control_zone_m, z.merging_zone_m)
            for a in sc.approaches:
                self.movement_table[a.name] = (a.name, "through", a.route)
                self.lane_movements[a.name] = [(f"{a.route[0]}_0", a.name, 0, None)]
                self.movement_junction[a.name] = ""
        # where demand enters: the approaches that do not come from another controlled junction
        self.entry_approaches = {a for a, _, _ in self.movement_table.values() if a not in self.upstream_junction}

    def _demand(self) -> list[tuple]:
        """Departures ``(vehicle_id, movement, depart_s, depart_speed, depart_pos, type)`` from the
        run's random generator: per approach, shifted-exponential headways at the approach's rate
        (times the scale of each ``[[demand.intervals]]`` period); each vehicle draws its movement
        from the approach's turning movement counts (``[[demand.flows]]``) or the global turning
        shares. ``type`` is "auto" or "human": in order of departure, each vehicle draws a uniform
        number from its own stream of the seed (the arrivals do not change with the share) and is
        a human driver when it is at least ``demand.controlled_share``; a vehicle controlled at one
        share is controlled at every higher one. ``[[vehicles]]`` keep their ``controlled``."""
        d = self.sc.demand
        rng = np.random.default_rng(self.seed)
        veh = []
        if d.sumo_routes:
            from nrtraffic.sumo.demandfile import read_sumo_demand

            end = d.end_s if d.end_s > 0 else (self.duration if self.duration > 0 else math.inf)
            by_edges = {(r[0], r[1]): name for name, (_, _, r) in self.movement_table.items()}
            veh = read_sumo_demand(self.sc.base_dir / d.sumo_routes, by_edges, rng, end, d.entry_speed_mps)
        rates = self._approach_rates() if not d.sumo_routes else {}
        if rates:
            end = d.end_s if d.end_s > 0 else (self.duration if self.duration > 0 else math.inf)
            if d.max_vehicles == 0 and not math.isfinite(end):
                raise ValueError("random demand needs demand.max_vehicles, demand.end_s or scenario.duration_s")
            for appr, (rate, names, share) in rates.items():
                if rate <= 0 or appr not in self.entry_approaches:  # (a corridor's inner approach: shares only)
                    continue
                if not d.intervals:
                    headway = 3600.0 / rate if d.flows else d.headway_s  # (as given: the same draws)
                    times = shifted_exponential_arrivals(rng, d.begin_s, end, headway, d.min_headway_s,
                                                         d.max_vehicles)
                else:
                    pieces, last = [], d.begin_s
                    cuts = d.breakpoints(d.begin_s, end)
                    for b, e in zip(cuts, cuts[1:]):
                        scale = d.scale_at(b)
                        if scale > 0:
                            left = d.max_vehicles - sum(len(x) for x in pieces) if d.max_vehicles else 0
                            if d.max_vehicles and left <= 0:
                                break
                            got = shifted_exponential_arrivals(rng, max(b, last), e, 3600.0 / (rate * scale),
                                                               d.min_headway_s, left)
                            pieces.append(got)
                            last = got[-1] if len(got) else last
                    times = np.concatenate(pieces) if pieces else np.zeros(0)
                picks = rng.choice(len(names), size=len(times), p=share / share.sum())
                veh += [(f"{appr}.{k}", names[j], float(t), d.entry_speed_mps, -1.0)
                        for k, (t, j) in enumerate(zip(times, picks))]
        for v in self.sc.vehicles:
            mv = v.approach
            if mv not in self.movement_table:
                raise ValueError(f"vehicle {v.id}: {mv!r} is not a movement ({', '.join(self.movement_table)})")
            veh.append((v.id, mv, v.depart_s, v.depart_speed_mps, v.depart_pos_m))
        veh.sort(key=lambda v: v[2])
        self.itineraries: dict[str, tuple[str, ...]] = {}
        if self.next_junction:
            veh = self._extend_routes(veh, rates)
        u = np.random.default_rng([self.seed, SHARE_STREAM]).random(len(veh))
        share = d.controlled_share
        listed = {v.id for v in self.sc.vehicles}
        return [(*v, "human" if (x >= share and v[0] not in listed) else "auto") for v, x in zip(veh, u)]

    def _extend_routes(self, veh: list[tuple], rates: dict) -> list[tuple]:
        """A corridor: each departure's route continues through every controlled junction its last
        movement leads into, with a turn drawn there (its own stream of the seed, in order of
        departure) from that approach's shares (``[[demand.flows]]`` of the approach, as turning
        movement counts, else the global turning shares). The route of a trip through several
        junctions is named by its movements joined with "+" (:attr:`itineraries`)."""
        rng = np.random.default_rng([self.seed, ROUTE_STREAM])
        shares = {}
        for appr in {a for a, _, _ in self.movement_table.values()}:
            if appr in rates:
                _, names, share = rates[appr]
            else:
                names = [n for n, (a, _, _) in self.movement_table.items() if a == appr]
                share = self._default_shares(names)
            if share.sum() <= 0:
                share = np.ones(len(names))
            shares[appr] = (names, share / share.sum())
        out = []
        for vid, first, *rest in veh:
            legs = [first]
            while len(legs) <= len(self.junctions):
                edge_out = self.movement_table[legs[-1]][2][-1]
                if edge_out not in self.next_junction:
                    break
                names, p = shares[edge_out]
                legs.append(names[int(rng.choice(len(names), p=p))])
            key = "+".join(legs)
            self.itineraries[key] = tuple(legs)
            out.append((vid, key, *rest))
        return out

    def route_edges(self, route: str) -> tuple[str, ...]:
        """The edges of a demand route: a turning movement's, or a corridor trip's (:attr:`itineraries`)."""
        legs = self.itineraries.get(route, (route,))
        edges = list(self.movement_table[legs[0]][2])
        for leg in legs[1:]:
            edges += list(self.movement_table[leg][2][1:])
        return tuple(edges)

    QUEUE_PERIOD_S = 10.0  # aggregation period of the queue detectors [s]

    def _queue_detectors(self, sdir: Path) -> tuple[str, ...]:
        """At a junction: one SUMO lane-area (E2) detector over every lane of every approach, with
        SUMO's default halting and jam thresholds, written every ``QUEUE_PERIOD_S`` to
        ``queues.xml`` (:meth:`approach_table`); the SUMO arguments that load them."""
        if not self.sc.controlled_junctions():
            return ("--additional-files", ",".join(map(str, self.additional))) if self.additional else ()
        from nrtraffic.sumo.network import edge_lanes

        out = (self.workdir / "queues.xml").resolve()
        lines = ["<additional>"]
        approaches = sorted({a for a, _, _ in self.movement_table.values()})
        for appr, lane, length in edge_lanes(self.network_path, approaches):
            lines.append(f'    <laneAreaDetector id="queue|{appr}|{lane}" lanes="{lane}" pos="0" '
                         f'endPos="{length:.3f}" friendlyPos="true" period="{self.QUEUE_PERIOD_S:g}" file="{out}"/>')
        lines.append("</additional>")
        path = sdir / "queues.add.xml"
        path.write_text("\n".join(lines) + "\n")
        return ("--additional-files", ",".join(map(str, (path, *self.additional))))

    def queue_series(self) -> pd.DataFrame:
        """Queues per approach and detector period (:func:`parse_queues` of ``queues.xml``)."""
        return parse_queues(self.workdir / "queues.xml")

    def approach_table(self, vehicles: pd.DataFrame, t_from: float, t_to: float) -> pd.DataFrame:
        """``approaches.csv``: per approach, its demand and served flow over the window [veh/h]
        (vehicles of the approach leaving the merging zone in it), and its queue from SUMO's
        detectors over the detector periods inside the window: mean and maximum, in vehicles and
        metres."""
        cols = ["approach", "demand_veh_h", "served_veh_h", "mean_queue_veh", "max_queue_veh", "mean_queue_m",
                "max_queue_m"]
        q = self.queue_series()
        if len(q):
            q = q[(q["begin_s"] >= t_from - 1e-9) & (q["end_s"] <= t_to + 1e-9)]
        hours = max(t_to - t_from, 0.0) / 3600.0
        rows = []
        for appr in sorted({a for a, _, _ in self.movement_table.values()}):
            demand = self.demand_veh_h(t_from, t_to, appr) if hours > 0 else math.nan
            served = vehicles[(vehicles["approach"] == appr) & vehicles["t_exit_s"].between(t_from, t_to)]
            g = q[q["approach"] == appr] if len(q) else q
            rows.append({"approach": appr, "demand_veh_h": demand,
                         "served_veh_h": len(served) / hours if hours > 0 else math.nan,
                         "mean_queue_veh": g["mean_queue_veh"].mean() if len(g) else math.nan,
                         "max_queue_veh": g["max_queue_veh"].max() if len(g) else math.nan,
                         "mean_queue_m": g["mean_queue_m"].mean() if len(g) else math.nan,
                         "max_queue_m": g["max_queue_m"].max() if len(g) else math.nan})
        return pd.DataFrame(rows, columns=cols)

    def _approach_rates(self) -> dict[str, tuple[float, list[str], np.ndarray]]:
        """Per approach: its arrival rate [veh/h] (before the intervals' scale), its movements and
        their shares of it; empty without random demand. Raises ValueError naming the key when
        ``[[demand.flows]]`` names an approach or a turn the junction does not have."""
        d = self.sc.demand
        approaches: dict[str, list[str]] = {}
        for name, (appr, _, _) in self.movement_table.items():
            approaches.setdefault(appr, []).append(name)
        out = {}
        if d.flows:
            known = {f.approach for f in d.flows}
            unknown = sorted(known - set(approaches))
            if unknown:
                raise ValueError(f"demand.flows: {', '.join(unknown)} is not an approach of the junction "
                                 f"({', '.join(approaches)})")
            for f in d.flows:
                names = approaches[f.approach]
                turns = {self.movement_table[n][1]: n for n in names}
                for key in TURNS:
                    turn = "uturn" if key == "u_turn" else key
                    if getattr(f, key) > 0 and turn not in turns:
                        raise ValueError(f"demand.flows.{f.approach}.{key}: the approach has no such movement "
                                         f"(it has {', '.join(sorted(turns))})")
                share = np.array([getattr(f, "u_turn" if self.movement_table[n][1] == "uturn" else
                                          self.movement_table[n][1], 0.0) for n in names], dtype=float)
                out[f.approach] = (f.total_veh_h, names, share)
            return out
        if d.headway_s <= 0:
            return {}
        for appr, names in approaches.items():
            out[appr] = (3600.0 / d.headway_s, names, self._default_shares(names))
        return out

    def _default_shares(self, names: list[str]) -> np.ndarray:
        """The global turning shares (``demand.turn_left``, ``turn_right``, the rest straight) of
        turning movements ``names`` of one approach; equal shares where they give none."""
        d = self.sc.demand
        share = np.array([{"left": d.turn_left, "right": d.turn_right}.get(self.movement_table[n][1],
                          1.0 - d.turn_left - d.turn_right) for n in names])
        return share if share.sum() > 0 else np.ones(len(names))

    def demand_veh_h(self, begin: float, end: float, approach: str | None = None) -> float:
        """Mean demand into the junctions (or one approach) over ``[begin, end]`` [veh/h]: every
        entry approach's rate times the intervals' scale, averaged over the window (not the sampled
        arrivals); with ``demand.sumo_routes``, the file's departures in the window."""
        if self.sc.demand.sumo_routes:
            times = [t for vid, (mv, t, _) in self._all_departures.items()
                     if begin <= t <= end and (approach is None or self.movement_table[mv][0] == approach)]
            return len(times) / (end - begin) * 3600.0 if end > begin else 0.0
        if approach is not None and approach not in self.entry_approaches:
            return math.nan  # a corridor's inner approach: fed by the junction upstream, not by demand
        rates = {a: r for a, r in self._approach_rates().items() if a in self.entry_approaches}
        if approach is not None:
            rates = {a: r for a, r in rates.items() if a == approach}
        total = sum(r for r, _, _ in rates.values())
        d = self.sc.demand
        lo, hi = max(begin, d.begin_s), min(end, d.end_s if d.end_s > 0 else end)
        if end <= begin or hi <= lo:
            return 0.0
        cuts = d.breakpoints(lo, hi)
        return total * sum((b - a) * d.scale_at(a) for a, b in zip(cuts, cuts[1:])) / (end - begin)

    def _paths(self, sumo: SumoSession) -> dict[str, Movement]:
        """Every movement's path (its lanes from SUMO, smoothed) and zones, of every junction;
        each junction lists its own (:attr:`Junction.movements`). Raises ValueError naming the
        movement where a zone does not fit, or the car cannot drive its turn."""
        out = {}
        merge_at = {a.name: a for a in self.sc.approaches}
        moves = [(rname, *lm) for rname in self.movement_table for lm in self.lane_movements[rname]]
        for rname, _lane, name, lane_in, lane_out in moves:
            appr, turn, route = self.movement_table[rname]
            j = self.junctions[self.movement_junction[rname]]
            key = f"merging_zone_m of [[junctions]] {j.id}" if len(self.junctions) > 1 else "zones.merging_zone_m"
            lanes = sumo.route_lanes(route, lane_in, lane_out)
            pts = [pt for _, shape, _ in lanes for pt in shape]
            path = LanePath.from_points(pts, smooth_spacing=PATH_SPACING_M)
            # arc length of each lane's start on the (smoothed) path; lane positions scale linearly
            starts = [path.project(shape[0])[0] for _, shape, _ in lanes] + [path.length]
            offsets = {lane: (starts[k], (starts[k + 1] - starts[k]) / length if length > 0 else 1.0)
                       for k, (lane, _, length) in enumerate(lanes)}
            if j.xy is not None:
                # merging zone: the disc of diameter merging_zone_m around the junction centre
                inside = np.flatnonzero(j.in_merging_zone(path.xy))
                if inside.size == 0 or inside[0] == 0:
                    raise ValueError(f"movement {name}: its path does not enter the merging zone from outside")
                s_m, s_x = float(path.s[inside[0]]), float(path.s[min(inside[-1], len(path.s) - 1)])
            else:
                a = merge_at[rname]
                lane_m = f"{a.merge_entry_edge}_0"
                s_m = offsets[lane_m][0] + a.merge_entry_pos_m * offsets[lane_m][1]
                s_x = s_m + j.merging_zone_m
            s_c = s_m - j.control_zone_m
            # a car inserted at the route's start has its centre of gravity behind one car length;
            # on a corridor the road starts at the junction upstream, which hands the car over where
            # it leaves that junction's merging zone: a zone reaching further back is cut there, and
            # the cut reported
            first = self.params.length
            up = self.junctions.get(self.upstream_junction.get(appr, ""))
            if up is not None and up.xy is not None:
                near = np.flatnonzero(up.in_merging_zone(path.xy))
                if near.size:
                    first = max(first, float(path.s[min(near[-1] + 1, len(path.s) - 1)]))
            if s_c < first:
                if s_m - first < MIN_CONTROL_ZONE_M:
                    raise ValueError(f"movement {name}: only {s_m - first:.1f} m of its route lie before the merging "
                                     f"zone, less than the {MIN_CONTROL_ZONE_M:g} m a control zone needs")
                s_c = first
                self.zone_cuts[name] = s_m - s_c
            if s_x > path.length:
                raise ValueError(f"movement {name}: the merging zone runs past the end of the route")
            internal = [k for k, (ln, _, _) in enumerate(lanes) if ln.startswith(":")]
            if j.xy is not None and internal:
                # the junction (its internal lanes, where the paths cross and turn) lies inside the
                # merging zone: the coordinator plans the crossings there, the stop lines lie before it
                r = max(float(np.hypot(*(np.asarray(lanes[k][1]) - j.xy).T).max()) for k in internal)
                if r > j.merging_zone_m / 2.0 + 0.5:
                    raise ValueError(f"movement {name}: junction {j.id}'s internal lanes reach "
                                     f"{r:.1f} m from its centre, beyond the merging zone ({key} = "
                                     f"{j.merging_zone_m:g} m); set it to at least {2.0 * math.ceil(r + 1.0):g} m")
            if self.control:  # (SUMO drives a baseline's vehicles: the path only measures them)
                self._check_turn_radius(name, path, s_c, s_x)
            v_lim = min(sumo.lane_speed(ln) for ln, _, _ in lanes) if j.xy is not None else math.inf
            v_lim = min(v_lim, _curve_speed(path, s_m, s_x, self.sc.planning.max_lateral_accel_mps2))
            out[name] = Movement(name, appr, turn, route, path, [ln for ln, _, _ in lanes], offsets, s_c, s_m, s_x,
                                 v_lim, rname, j.id)
            j.movements.append(name)
        if self.zone_cuts:
            print(f"{self.sc.general.name}: control zones reach back past where routes start or past the junction "
                  f"upstream; cut there: " + ", ".join(f"{k} {v:.0f} m" for k, v in self.zone_cuts.items()),
                  file=sys.stderr)
        return out

    def _check_turn_radius(self, name: str, path: LanePath, s_from: float, s_to: float) -> None:
        """Raise ValueError when movement ``name``'s path between ``s_from`` and ``s_to`` [m] turns
        tighter than the controlled car can steer: the curvature averaged over 2 m [1/m] above the
        kinematic bound ``tan(steer_max) / (l_f + l_r)``. (netconvert draws a junction's turns
        with the node's ``radius``, 4 m by default; at a sharply skewed corner that can leave a
        turn tighter than any car's.)"""
        kappa = _max_curvature(path, s_from, s_to)
        p = self.params
        k_max = math.tan(self.sc.controller.steer_max_rad) / (p.lf + p.lr)
        if kappa > k_max:
            raise ValueError(f"movement {name}: its path turns on a radius of {1.0 / kappa:.1f} m, tighter than "
                             f"the vehicle's smallest ({1.0 / k_max:.1f} m at controller.steer_max_rad = "
                             f"{self.sc.controller.steer_max_rad:.3g} rad); give the junction a larger turning radius "
                             f"in the network (netconvert: the node's radius, or --default.junctions.radius)")

    def _stop_lines(self) -> dict[tuple[str, str], tuple[str, float]]:
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
        cg = self.params.cg_to_front
        for name, m in self.paths.items():
            internal = [m.lane_offset[ln][0] for ln in m.lanes if ln.startswith(":")]
            s_end = internal[0] if internal else m.path.length
            firsts = [lo for (a, _), (lo, _hi) in self.conflict_areas.items() if a == name + HUMAN_BODY]
            s_area = m.s_merge + min(firsts) + cg - STOP_BEFORE_M if firsts else math.inf
            for driver, s_front in (("automated", m.s_merge - STOP_BEFORE_M), ("human", min(s_end - 0.1, s_area))):
                lane = None
                for ln in m.lanes:
                    if m.lane_offset[ln][0] <= s_front + 1e-9:
                        lane = ln
                if lane is None or lane.startswith(":"):
                    raise ValueError(f"movement {name}: its merging-zone entry lies inside the junction, where a "
                                     f"vehicle cannot stop (the merging zone, "
                                     f"{self.junctions[m.junction].merging_zone_m:g} m, is smaller than the junction)")
                off, scale = m.lane_offset[lane]
                out[(name, driver)] = (lane, (s_front - off) / scale)
        return out

    def _write_movements(self) -> None:
        """``movements.json``: each movement's route, zone boundaries, its relation to the others and
        its conflict areas (the stretch of its path, from its merging-zone entry, on which its body
        can touch the other movement's)."""
        import json

        doc = {
            "movements": {
                m.name: {**({"junction": m.junction} if len(self.junctions) > 1 else {}),
                         "approach": m.approach, "turn": m.turn, "route": list(m.route), "lanes": m.lanes,
                         "control_zone_start_m": m.s_control, "merge_entry_m": m.s_merge, "merge_exit_m": m.s_exit,
                         "zone_length_m": m.s_exit - m.s_merge,
                         "v_limit_mps": None if not math.isfinite(m.v_limit) else m.v_limit,
                         # the path of its centre of gravity from 10 m before the merging zone to 10 m
                         # after it, every 0.5 m: [s from the merging-zone entry, x, y] [m]
                         "zone_path": [[round(float(d), 3), round(float(x), 3), round(float(y), 3)]
                                       for d, (x, y) in zip(*self._zone_path(m))]}
                for m in self.paths.values()
            },
            # between the movements of the same junction
            "relations": {a: {b: self.relations[(a, b)] for b in self.junctions[m.junction].movements if b != a}
                          for a, m in self.paths.items()},
            # on a's path, measured from its merging-zone entry [m]: where its body can touch b's
            "conflict_areas": [{"movement": a, "with": b, "from_m": lo, "to_m": hi}
                               for (a, b), (lo, hi) in sorted(getattr(self, "conflict_areas", {}).items())
                               if HUMAN_BODY not in a + b],
        }
        human = [{"movement": a, "with": b, "from_m": lo, "to_m": hi}
                 for (a, b), (lo, hi) in sorted(getattr(self, "conflict_areas", {}).items()) if HUMAN_BODY in a + b]
        if human:  # with human drivers: the areas of their bodies ("<movement>~human") against every body
            doc["conflict_areas_human"] = human
        zones = {j.id: {"centre_xy": [float(c) for c in j.xy], "diameter_m": j.merging_zone_m}
                 for j in self.junctions.values() if j.xy is not None}
        if len(zones) == 1:
            doc["merging_zone"] = next(iter(zones.values()))
        elif zones:
            doc["merging_zones"] = zones
        (self.workdir / "movements.json").write_text(json.dumps(doc, indent=1) + "\n")

    @staticmethod
    def _zone_path(m, margin_m: float = 10.0, step_m: float = 0.5):
        d = np.arange(-margin_m, m.s_exit - m.s_merge + margin_m + 1e-9, step_m)
        return d, m.path.xy_at(m.s_merge + d)

    def _body_headings(self, m: Movement, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The controlled car's body heading [rad] at centre-of-gravity positions ``s`` [m] of
        movement ``m``, at the two ends of its range: the kinematic one (a slow car: its rear axle
        moves along the body, so the body turns less than the path, by ``asin(l_r kappa)``), and
        the one the kernel gives crossing at the movement's crossing speed (its tyres slip
        besides). On cross4's turns both differ from the path's heading by up to 0.3 rad (left)
        and 0.46 rad (right), which turns the body's corners out by most of a metre."""
        p = self.params
        h = np.unwrap(m.path.heading_at(m.path.s))
        n = max(1, int(round(1.0 / PATH_SPACING_M)))  # curvature over 2 m
        kappa = np.zeros_like(h)
        if len(h) > 2 * n:
            kappa[n:-n] = (h[2 * n:] - h[:-2 * n]) / (m.path.s[2 * n:] - m.path.s[:-2 * n])
        kin = np.interp(s, m.path.s, h - np.arcsin(np.clip(p.lr * kappa, -1.0, 1.0)))
        return kin, self._crossing_headings(m, s)

    def _crossing_headings(self, m: Movement, s: np.ndarray) -> np.ndarray:
        """Body heading [rad] at positions ``s`` of a controlled car that the kernel drives through
        movement ``m``'s merging zone at its crossing speed (``min(v_limit, v_max)``, the plan of
        ``terminal_speed = "fixed"``), alone, barriers on, entering 30 m before the zone on the
        path."""
        v = min(m.v_limit, self.sc.planning.v_max_mps)
        pid = self.path_index[m.name]
        s0 = max(m.s_merge - 30.0, float(m.path.s[0]))
        xy0 = m.path.xy_at(np.array([s0]))[0]
        X = np.array([[xy0[0], xy0[1], v, 0.0, float(m.path.heading_at(np.array([s0]))[0]), 0.0]])
        prof = np.zeros((1, N_PROFILE_SEG, 5))
        prof[0, :, 0] = np.arange(N_PROFILE_SEG) * 1e9
        prof[0, :, 2] = v  # constant speed
        out = np.full((1, kb.N_OUT), np.nan)
        out[0, kb.OUT_S] = s0
        args = (self.cfg, self.plant_p, self.pred_p, self.u_lo, self.u_hi, prof, np.zeros(1), np.array([s0]),
                np.array([pid], dtype=np.int64), self.path_off, self.path_xy, self.path_s, self.path_frames,
                np.array([max(0, int(np.searchsorted(m.path.s, s0)) - 1)], dtype=np.int64),
                np.full(1, kb.NO_LEADER, dtype=np.int64), np.zeros((1, 6)), kb.new_acc(1), out,
                np.zeros((1, 1, 0)), np.zeros((1, 2)), X.copy())
        U = np.zeros((1, 2))
        ss, hs = [s0], [X[0, 4]]
        t, dt = 0.0, self.sc.sumo.step_length_s  # sampled every SUMO step (well under a metre)
        while ss[-1] < m.s_exit + 1.0 and t < 600.0:
            kb.advance(X, U, t, self.n_sub, *args)
            t += dt
            ss.append(float(out[0, kb.OUT_S]))
            hs.append(float(X[0, 4]))
        hs = np.unwrap(np.array(hs))
        return np.interp(s, np.array(ss), hs)

    def _relations(self) -> dict:
        """Relations and conflict areas of each junction's movements among themselves (set on each
        :class:`Junction`); returns every junction's relations in one table, as
        :attr:`conflict_areas` holds every junction's areas (the names do not repeat)."""
        relations, self.conflict_areas = {}, {}
        for j in self.junctions.values():
            j.relations, j.conflict_areas = self._junction_relations([self.paths[n] for n in j.movements])
            relations.update(j.relations)
            self.conflict_areas.update(j.conflict_areas)
        return relations

    def _junction_relations(self, movements: list[Movement]) -> tuple[dict, dict]:
        """Relations and conflict areas of ``movements`` (one junction's): the bodies swept along
        their paths through the merging zone (:func:`~nrtraffic.planning.conflicts.classify`)."""
        geo = []
        for m in movements:
            sel = (m.path.s >= m.s_merge) & (m.path.s <= m.s_exit)
            # the path carries the centre of gravity; the body's centre is ahead of it by this [m],
            # along the body's heading, which lies between its two ends (_body_headings): both are
            # swept, interleaved so that the points stay in order of the path
            ahead = self.params.cg_to_front - 0.5 * self.params.length
            s_zone = m.path.s[sel]
            h2 = np.stack(self._body_headings(m, s_zone), -1).reshape(-1)
            xy2 = np.repeat(m.path.xy[sel], 2, axis=0)
            centre = xy2 + ahead * np.stack([np.cos(h2), np.sin(h2)], -1)
            geo.append(MovementGeometry(m.name, m.lanes[0], m.lanes[-1], centre, np.repeat(s_zone - m.s_merge, 2),
                                        h2))
            if self._humans and self.control:
                # a human driver's body: SUMO moves its front bumper along the lane and places its
                # rear on the lane one length behind (the body is that chord), so on a curve it
                # cuts further inside than the controlled car's (centre of gravity on the path,
                # heading along it); indexed by the same centre-of-gravity positions
                s_front = np.minimum(m.path.s[sel] + self.params.cg_to_front, m.path.length)
                front = m.path.xy_at(s_front)
                rear = m.path.xy_at(np.maximum(s_front - self.params.length, 0.0))
                chord = front - rear
                geo.append(MovementGeometry(m.name + HUMAN_BODY, m.lanes[0], m.lanes[-1], 0.5 * (front + rear),
                                            m.path.s[sel] - m.s_merge, np.arctan2(chord[:, 1], chord[:, 0])))
        p, clearance = self.params, self.sc.junction.lateral_clearance_m
        relations = classify(geo, p.length, p.width, clearance)
        return relations, conflict_areas(geo, relations, p.length, p.width, clearance)

    def write_demand(self, path: Path) -> list[tuple]:
        """The run's departures (:meth:`_demand`) as a SUMO route file, in nrtraffic's vehicle
        type; returns them."""
        self._movement_table()
        demand = self._demand()
        p = self.params
        v_max = max(self.sc.planning.v_max_mps, 1.0)
        types = [VehicleType(length_m=p.length, width_m=p.width, max_speed_mps=v_max)]
        if any(v[5] == "human" for v in demand):
            h = self.sc.human
            types.append(VehicleType("human", p.length, p.width, h.min_gap_m, h.accel_mps2, h.decel_mps2, v_max,
                                     h.sigma, h.tau_s, h.speed_dev, h.car_follow_model))
        routes = {k: v[2] for k, v in self.movement_table.items()}
        routes.update({k: self.route_edges(k) for k in self.itineraries})
        write_routes(path, types, routes, demand)
        return demand

    # ------------------------------------------------------------------ run
    def run(self) -> RunResult:
        """Run the simulation; returns a :class:`RunResult` or raises :class:`RunFailed` (with the
        partial result) when SUMO or a component fails mid-run, and
        :class:`~nrtraffic.sumo.network.NetworkError` when the junction and its zones do not suit
        (found once SUMO has read the network, before anything is simulated)."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        sdir = self.workdir / "sumo"
        sdir.mkdir(exist_ok=True)
        wall0 = self.wall0 = time.perf_counter()
        error = None
        try:
            routes = sdir / "routes.rou.xml"
            demand = self.write_demand(routes)
            # a vehicle's record is made when SUMO inserts it: memory grows with the vehicles that
            # entered so far, not with the whole demand of the run
            self._scheduled = {vid: (mv, t, speed) for vid, mv, t, speed, *_ in demand}
            self._humans = {v[0] for v in demand if v[5] == "human"}
            self._all_departures = dict(self._scheduled)
            self._listed = {v.id: v for v in self.sc.vehicles}
            copy = sdir / self.network_path.name  # the run directory's own copy, where there is one
            write_sumocfg(sdir / "run.sumocfg", copy if copy.is_file() else self.network_path, routes,
                          self.sc.sumo.step_length_s)
            o = self.sc.outputs
            self.sumo = SumoSession(
                self.network_path, routes, self.sc.sumo.step_length_s, self.seed,
                self.sc.sumo.lateral_resolution_m,
                tripinfo=self.workdir / "tripinfo.xml" if o.sumo_tripinfo else None,
                collisions=self.workdir / "collisions.xml" if o.sumo_collisions else None,
                fcd=self.workdir / "fcd.xml" if o.sumo_fcd else None,
                extra_args=self.sc.sumo.extra_args + self._queue_detectors(sdir),
                gui=self.gui,
            )
            with self.sumo:
                try:
                    self.paths = self._paths(self.sumo)
                    self._pack_paths()
                    self.relations = self._relations()
                    # where vehicles stop before they cross: human drivers, cars queued behind them,
                    # and on a corridor cars with no merge time yet (_hold)
                    self.stop_line = (self._stop_lines() if self.control and (self._humans or self.upstream_junction)
                                      else {})
                except ValueError as exc:  # the junction or its zones do not suit: nothing was run
                    raise NetworkError(f"{self.sc.general.name}: {exc}") from None
                self._write_movements()
                for j in self.junctions.values():
                    j.coord = Coordinator(self.sc.coordinator, self.sc.planning, j.relations, areas=j.conflict_areas)
                self._loop()
        except NetworkError:
            if self.traj is not None:
                self.traj.close()
            raise
        except (Exception, KeyboardInterrupt) as exc:  # keep what was finished
            error = exc
        wall = time.perf_counter() - wall0
        if self.traj is not None:
            try:
                self.traj.close()
            except OSError as exc:  # a full disk, say: the figures below are still returned
                error = error or exc
        result = self._result(wall, error)
        if error is not None:
            raise RunFailed(f"run stopped at t={self.t:.2f} s: {type(error).__name__}: {error}", result) from error
        return result

    def _loop(self) -> None:
        from tqdm import tqdm

        sc = self.sc
        dt = sc.sumo.step_length_s
        log_every = max(1, int(round(sc.outputs.trajectory_interval_s / dt)))
        self.uncontrolled: list[str] = []
        self.released: list[str] = []  # handed back to SUMO, still read every step (_forget_far)
        self.humans: list[str] = []  # human drivers until they leave the merging zone
        self.reservations: dict = {}  # human driver -> (its reserved crossing, the bounds it was reserved with)
        self.starting: list[str] = []  # controlled vehicles standing at the stop line, their start reserved
        # entry lane -> its vehicles whose crossing is not reserved yet (who is ahead: _blocked_ahead)
        self.unreserved: dict[str, list[str]] = {}
        self.ctl = ControlledTable()  # the vehicles under control: the table the kernel reads
        self.approaching: list[str] = []  # controlled vehicles SUMO drives towards their next control zone
        approaching = self.approaching
        scripted: list[str] = []
        batch = self.sc.coordinator.policy == "batch"
        step = 0
        total = self.duration if self.duration > 0 else None
        fmt = ("{l_bar}{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]" if total
               else "{desc}: {n:.0f} sim s [{elapsed}, {rate_fmt}]")
        bar = tqdm(total=total, desc=sc.general.name, unit="sim s", disable=None if self.progress else True, leave=False,
                   bar_format=fmt)
        clock = time.perf_counter
        wall = self.wall_breakdown
        plain_progress = bool(self.progress and total and not sys.stderr.isatty())
        next_report = 0.1 * total if total else math.inf
        next_checkpoint = clock() + CHECKPOINT_WALL_S
        try:
            while True:
                self.t = self.sumo.time
                if self.duration > 0 and self.t >= self.duration - 1e-9:
                    break
                if self.t > 0 and self.sumo.pending() == 0 and not self.ctl.ids:
                    break
                t0 = clock()
                for vid in self.sumo.departed():
                    rec = self._record(vid)
                    if rec is None:
                        continue
                    # SUMO's departDelay, less the part that is only the wait for the next step
                    desired = round(rec.t_depart, 2)  # as the route file gives it
                    step_wait = math.ceil(desired / dt - 1e-9) * dt - desired
                    rec.depart_delay = max(0.0, self.sumo.depart_delay(vid) - step_wait)
                    if rec.controlled:
                        rec.status = "approaching"
                        self.sumo.colour(vid, "approaching")
                        self.sumo.hold_speed(vid, self.sumo.speed(vid))
                        approaching.append(vid)
                    else:
                        rec.status = "sumo"
                        self.uncontrolled.append(vid)
                        if rec.speed_profile:
                            scripted.append(vid)
                        if rec.driver == "human" and self.control:
                            self._to_stop_line(vid)
                self.snap = self.sumo.snapshot()
                self._track_uncontrolled(dt)
                self._humans_step()
                self._start()
                t1 = clock()
                if batch:
                    self._admit_batch(approaching, dt)
                else:
                    blocked: set[str] = set()  # lanes whose first waiting vehicle could not be admitted
                    for vid in list(approaching):
                        rec = self.records[vid]
                        if rec.lane in blocked:
                            continue
                        if ((rec.hindered or self._blocked_ahead(vid)) and self._request(vid, entry_only=True)
                                and self._hindered(vid)):  # waits for a human ahead, or starts from the stop line
                            if rec.status == "starting":
                                approaching.remove(vid)
                            else:
                                blocked.add(rec.lane)
                            continue
                        state = self._try_admit(vid)
                        if state == "admitted":
                            approaching.remove(vid)
                        elif state == "held":
                            blocked.add(rec.lane)
                            rec.t_held += dt
                    self._account_waiting([v for v in approaching if self.records[v].status == "held"]
                                          + self.starting, dt)
                t2 = clock()
                self._leaders()
                t3 = clock()
                self._collisions_geometric()
                t4 = clock()
                if step % log_every == 0:
                    self._log()
                if step % 10 == 0:
                    self._forget_far()
                t5 = clock()
                self._advance(dt)
                t6 = clock()
                self._push_and_release()
                self._script(scripted, self.t + dt)
                t7 = clock()
                self.sumo.step()
                for a, b, kind in self.sumo.collisions():
                    pair = tuple(sorted((a, b)))
                    if pair not in self.collision_pairs:
                        self.collision_pairs.add(pair)
                        self.collision_log.append({"t": self.sumo.time, "pair": list(pair), "source": f"sumo:{kind}"})
                t8 = clock()
                wall["sumo_io"] += (t1 - t0) + (t7 - t6)
                wall["admission"] += t2 - t1
                wall["leaders"] += t3 - t2
                wall["collision_check"] += t4 - t3
                wall["logging"] += t5 - t4
                wall["kernel"] += t6 - t5
                wall["sumo_step"] += t8 - t7
                step += 1
                bar.update(dt)
                if plain_progress and self.t + dt >= next_report:  # not a terminal: a line every 10 %
                    print(f"{sc.general.name}: {self.t + dt:.0f}/{total:.0f} sim s "
                          f"({100 * (self.t + dt) / total:.0f} %), {clock() - self.wall0:.0f} s wall",
                          file=sys.stderr, flush=True)
                    next_report += 0.1 * total
                if self.checkpoint is not None and t8 >= next_checkpoint:
                    if self.traj is not None:
                        self.traj.flush()
                    self.checkpoint(self._result(t8 - self.wall0, None, final=False))
                    next_checkpoint = clock() + CHECKPOINT_WALL_S
            self.t = self.sumo.time
        finally:
            bar.close()

    # ------------------------------------------------------------------ paths, packed for the kernel
    def _pack_paths(self) -> None:
        self.path_names = list(self.paths)
        self.path_index = {k: i for i, k in enumerate(self.path_names)}
        xy = [self.paths[k].path.xy for k in self.path_names]
        self.path_off = np.concatenate([[0], np.cumsum([len(a) for a in xy])]).astype(np.int64)
        self.path_xy = np.ascontiguousarray(np.concatenate(xy))
        self.path_s = np.ascontiguousarray(np.concatenate([self.paths[k].path.s for k in self.path_names]))
        self.path_frames = np.ascontiguousarray(np.concatenate(
            [segment_frames(self.paths[k].path.xy, self.paths[k].path.s) for k in self.path_names]))
        # the lanes of the paths, for the leader search
        self.lane_index, self.pl_off, self.pl_lane, self.pl_start, self.pl_scale = pack_path_lanes(
            [self.paths[k] for k in self.path_names])

    # ------------------------------------------------------------------ steps
    def _record(self, vid: str) -> VehicleRecord | None:
        """The record of a vehicle SUMO has just inserted (None for one not of the demand)."""
        if vid not in self._scheduled:
            return None
        trip, t, speed = self._scheduled.pop(vid)
        lv = self._listed.get(vid)
        human = vid in self._humans
        legs = self.itineraries.get(trip, (trip,))
        if any(len(self.lane_movements[leg]) > 1 for leg in legs):
            # SUMO inserted it on the least occupied lane its route can take (departLane="best"); it
            # keeps that lane, which decides its lane-level movement
            self.sumo.keep_lane(vid)
        lane, mv = self._lane_movement(vid, legs[0])
        rec = self.records[vid] = VehicleRecord(
            vid, self.movement_table[legs[0]][0], t, movement=mv, route=legs[0], lane=lane, v_free=speed,
            controlled=(lv.controlled if lv else True) and self.control and not human,
            driver="human" if human else "automated",
            heading_offset=lv.entry_heading_offset_rad if lv else 0.0,
            speed_profile=lv.speed_profile if lv else (), junction=self.movement_junction[legs[0]], legs=legs)
        return rec

    def _lane_movement(self, vid: str, route: str) -> tuple[str, str]:
        """``(entry lane, lane-level movement)`` of a vehicle on turning movement ``route``: the
        one of the lane SUMO has it on (the first where it is on none of them yet)."""
        lanes = self.lane_movements[route]
        if len(lanes) == 1:
            return lanes[0][:2]
        here = self.sumo.lane_position(vid)[0]
        return next(((ln, name) for ln, name, _, _ in lanes if ln == here), lanes[0][:2])

    def _next_leg(self, vid: str) -> bool:
        """A vehicle that left a junction's merging zone with a next junction on its trip (a
        corridor): its crossing is kept (:attr:`crossings`) and a new record starts for the next
        one, which that junction admits when the vehicle enters its control zone (SUMO drives it
        until then; a human driver is told to stop at that junction's stop line). False when the
        trip has no next junction."""
        rec = self.records[vid]
        if rec.leg + 1 >= len(rec.legs):
            return False
        self.crossings.append(rec)
        route = rec.legs[rec.leg + 1]
        lane, mv = self._lane_movement(vid, route)
        new = self.records[vid] = VehicleRecord(
            vid, self.movement_table[route][0], rec.t_depart, movement=mv, route=route, lane=lane, v_free=rec.v_free,
            controlled=rec.controlled, driver=rec.driver, speed_profile=rec.speed_profile,
            junction=self.movement_junction[route], legs=rec.legs, leg=rec.leg + 1)
        if new.controlled:
            new.status = "approaching"
            self.sumo.colour(vid, "approaching")
            self.approaching.append(vid)
        elif new.driver == "human" and self.control:
            self.reservations.pop(vid, None)  # (its last crossing's, spent)
            self._to_stop_line(vid)
        else:
            new.status = "sumo"
        return True

    def _to_stop_line(self, vid: str) -> None:
        """A human driver on its way to a junction: SUMO stops it at the stop line of its movement
        there, where its crossing will be reserved (:meth:`_humans_step`)."""
        rec = self.records[vid]
        rec.status = "human"
        self.sumo.stop_at(vid, *self.stop_line[rec.movement, rec.driver])
        self.sumo.colour(vid, "human")
        if vid not in self.humans:
            self.humans.append(vid)
        self.unreserved.setdefault(rec.lane, []).append(vid)

    def _request(self, vid: str, entry_only: bool = False):
        """What a vehicle whose centre of gravity crossed the control-zone entry asks of the
        coordinator, from SUMO's view of it now: ``(Request, x0, s, lateral offset)``; None while it
        has not crossed. ``entry_only``: only whether it crossed (True or None)."""
        rec = self.records[vid]
        mv = self.paths[rec.movement]
        tab = self.snap
        k = tab.row.get(vid)
        if k is None:
            return None
        lane, pos = tab.lane[k], float(tab.lane_pos[k])
        if lane not in mv.lane_offset:
            return None
        s_cg = mv.s_of(lane, pos) - self.params.cg_to_front
        if s_cg < mv.s_control - 1e-6:
            return None
        if math.isnan(rec.t_arrive):
            rec.t_arrive, rec.s_arrive = self.t, s_cg
        if entry_only:
            return True
        xf, yf, psi = float(tab.x[k]), float(tab.y[k]), float(tab.psi[k])
        v = float(tab.speed[k])
        cg = self.params.cg_to_front
        x0 = np.array([xf - cg * math.cos(psi), yf - cg * math.sin(psi), v, 0.0, psi + rec.heading_offset, 0.0])
        s_proj, lat0 = mv.path.project(x0[:2])
        D = mv.s_merge - s_proj
        v_lim = mv.v_limit
        if rec.hindered:  # slowed behind a human: cross no faster than half the bound's acceleration reaches
            v_lim = min(v_lim, math.sqrt(v * v + self.sc.planning.u_max_mps2 * max(D, 0.0)))
        req = Request(vid, rec.lane, self.t, v, D, rec.movement, mv.s_exit - mv.s_merge, v_lim, rec.hindered,
                      rec.approach in self.upstream_junction)
        return req, x0, s_proj, lat0

    def _try_admit(self, vid: str) -> str:
        """Admit a vehicle whose centre of gravity crossed the control-zone entry: "waiting" (not
        there yet), "admitted", or "held" (no merge time meets the bounds: SUMO stops it at the
        entry and admission is tried again every step, so that the lane's FIFO order is kept)."""
        got = self._request(vid)
        if got is None:
            return "waiting"
        req = got[0]
        try:
            if req.D <= 0.5:
                raise ScheduleInfeasible(f"vehicle {vid} is already at the merging zone")
            asg = self.junctions[self.records[vid].junction].coord.schedule_request(req)
        except ScheduleInfeasible:
            self._hold(vid)
            return "held"
        self._admit(got, asg)
        return "admitted"

    def _admit_batch(self, approaching: list[str], dt: float) -> None:
        """``policy = "batch"``: vehicles that crossed the control-zone entry wait (driven on by
        SUMO at their speed) until ``batch_window_s`` after the first of them; then all waiting
        are scheduled together (:meth:`Coordinator.schedule_batch`) from their state at that
        moment. Held ones (no feasible merge time) are stopped by SUMO and wait for the next batch,
        which closes a window after they were held."""
        for vid in list(approaching):
            if self._request(vid, entry_only=True):
                approaching.remove(vid)
                j = self.junctions[self.records[vid].junction]
                if not j.pending:
                    j.batch_closes = self.t + self.sc.coordinator.batch_window_s
                j.pending.append(vid)
                self.sumo.colour(vid, "pending")
        for j in self.junctions.values():
            self._close_batch(j, dt)
        self._account_waiting(self.starting, dt)

    def _close_batch(self, j: Junction, dt: float) -> None:
        """Junction ``j``'s batch: its waiting vehicles accounted for, and all scheduled together
        when the batch closes (:meth:`_admit_batch`)."""
        # behind a human: checked each step, until its start is reserved (then it leaves the batch)
        waiting = {vid for vid in j.pending if self._hindered(vid)}
        j.pending = [v for v in j.pending if self.records[v].status != "starting"]
        for vid in j.pending:
            if self.records[vid].status == "held":
                self.records[vid].t_held += dt
        self._account_waiting(j.pending, dt)
        if not j.pending or self.t < j.batch_closes - 1e-9:
            return
        got = {}
        for vid in j.pending:
            if vid in waiting:  # waits for a human ahead, or for its stop at the stop line
                continue
            g = self._request(vid)
            if g is not None and g[0].D > 0.5:
                got[vid] = g
            else:
                self._hold(vid)  # at the zone already, or no longer seen on its path
        results = j.coord.schedule_batch([got[v][0] for v in j.pending if v in got])
        held = [req.vehicle_id for req, a in results if isinstance(a, ScheduleInfeasible)]
        for req, a in results:
            if not isinstance(a, ScheduleInfeasible):
                self._admit(got[req.vehicle_id], a)
        for vid in held:
            self._hold(vid)
        j.pending = [v for v in j.pending if v in held or v not in got]
        j.batch_closes = self.t + self.sc.coordinator.batch_window_s if j.pending else math.inf

    def _account_waiting(self, vids: list[str], dt: float) -> None:
        """Energy and fuel of vehicles in the control zone that SUMO still drives (waiting for their
        batch, or held), from SUMO's speed and acceleration; carried over when they are admitted."""
        tab = self.snap
        for vid in vids:
            k = tab.row.get(vid)
            if k is None:
                continue
            v, a = float(tab.speed[k]), float(tab.accel[k])
            acc = self.records[vid].acc
            acc[kb.ACC_ENERGY] += 0.5 * a * a * dt
            acc[kb.ACC_FUEL] += fuel_rate(v, a) * dt

    def _hold(self, vid: str) -> None:
        """No merge time for a vehicle in the control zone now: SUMO stops it at the control-zone
        entry and admission is tried again. Where that entry is the hand-over from a junction
        upstream (a corridor), stopping there would block that junction's exit: SUMO drives it on
        instead, to a stop short of the merging zone, and it is scheduled on the way or started
        from that stop, as a car queued behind a human driver is (:meth:`_hindered`)."""
        rec = self.records[vid]
        if rec.hindered:  # it drives on to its stop at the stop line (_hindered)
            return
        if rec.approach in self.upstream_junction:
            self._wait_at_stop_line(vid, "held")
            return
        if rec.status != "held":
            rec.status = "held"
            self.sumo.hold_speed(vid, 0.0)
            self.sumo.colour(vid, "held")

    def _admit(self, got, asg) -> None:
        """Take a scheduled vehicle over: from now on the kernel drives it."""
        req, x0, s_proj, lat0 = got
        vid = req.vehicle_id
        rec = self.records[vid]
        mv = self.paths[rec.movement]
        if rec.hindered and rec.status != "starting":  # scheduled on the move after all: no stop
            self.sumo.cancel_stop(vid)
            self.unreserved[rec.lane].remove(vid)
        rec.status = "controlled"
        self.sumo.take_over(vid)
        self.sumo.colour(vid, "controlled")
        rec.t_enter, rec.v_enter, rec.s_enter = self.t, req.v0, s_proj
        rec.t_merge_planned, rec.v_merge_planned = asg.t_merge, asg.profile.v_m
        rec.predecessor, rec.relation, rec.binding = asg.predecessor, asg.relation, asg.binding
        rec.profile_kind = asg.profile.kind
        rec.plan_intrusion = asg.plan_intrusion_m
        hint = int(np.clip(np.searchsorted(mv.path.s, s_proj) - 1, 0, len(mv.path.s) - 2))
        self.ctl.append(vid, x0, asg.profile.packed(N_PROFILE_SEG), self.t, s_proj, lat0, mv.path.xy_at(s_proj),
                        self.path_index[rec.movement], hint, (mv.s_merge, mv.s_exit))
        for k in (kb.ACC_ENERGY, kb.ACC_FUEL):  # what it used while SUMO drove it in the control zone
            self.ctl.acc[-1, k] = rec.acc[k]

    def _track_uncontrolled(self, dt: float) -> None:
        """Zone crossings and figures of SUMO-driven vehicles (baselines, scripted leaders), from
        their lane positions, speeds and accelerations each step."""
        if not self.uncontrolled:
            return
        tab = self.snap
        cg = self.params.cg_to_front
        for vid in list(self.uncontrolled):
            rec = self.records[vid]
            k = tab.row.get(vid)
            if k is None:
                self.uncontrolled.remove(vid)
                continue
            mv = self.paths[rec.movement]
            lane, pos = tab.lane[k], float(tab.lane_pos[k])
            if lane not in mv.lane_offset:
                continue
            s_new = mv.s_of(lane, pos) - cg
            v, a = float(tab.speed[k]), float(tab.accel[k])
            s_prev = rec.s_last
            if math.isnan(rec.t_enter) and s_new >= mv.s_control:
                frac = 0.0 if math.isnan(s_prev) or s_new <= s_prev else (mv.s_control - s_prev) / (s_new - s_prev)
                rec.t_enter = self.t - dt + dt * min(max(frac, 0.0), 1.0) if not math.isnan(s_prev) else self.t
                rec.v_enter, rec.s_enter = v, mv.s_control
            if not math.isnan(s_prev) and s_new > s_prev:
                if math.isnan(rec.t_merge_actual) and s_new >= mv.s_merge > s_prev:
                    rec.t_merge_actual = self.t - dt + dt * (mv.s_merge - s_prev) / (s_new - s_prev)
                if math.isnan(rec.t_exit) and s_new >= mv.s_exit > s_prev:
                    rec.t_exit = self.t - dt + dt * (mv.s_exit - s_prev) / (s_new - s_prev)
                    rec.s_last = s_new
                    if self._next_leg(vid):  # (a corridor: on to the next junction)
                        continue
            if not math.isnan(rec.t_enter) and math.isnan(rec.t_exit):
                acc = rec.acc
                acc[kb.ACC_ENERGY] += 0.5 * a * a * dt
                acc[kb.ACC_FUEL] += fuel_rate(v, a) * dt
                acc[kb.ACC_MAX_ABS_A] = max(acc[kb.ACC_MAX_ABS_A], abs(a))
                acc[kb.ACC_STEPS] += 1
            rec.s_last = s_new

    def _blocked_ahead(self, vid: str) -> bool:
        """Whether a vehicle whose crossing is not reserved yet, a human driver or a controlled
        vehicle queued behind one, is ahead of ``vid`` on its entry lane, by where SUMO has them
        now (on a corridor the vehicles on a lane come from several roads upstream, so the order
        of departure is not the lane's order)."""
        q = self.unreserved.get(self.records[vid].lane)
        if not q or q == [vid]:
            return False
        here = self._cg_on_path(vid) if vid in self.snap.row else None
        if here is None:
            return True  # (not on its path's lanes yet: everyone on the lane is ahead of it)
        for u in q:
            if u != vid and u in self.snap.row:
                s = self._cg_on_path(u)
                if s is not None and s > here:
                    return True
        return False

    def _wait_at_stop_line(self, vid: str, colour: str) -> None:
        """A controlled vehicle that is not scheduled yet and must not cross unplanned: SUMO drives
        it on to a stop short of the merging zone; until its crossing is scheduled or reserved it
        counts as unreserved on its lane (the vehicles behind it wait for it, :meth:`_hindered`)."""
        rec = self.records[vid]
        rec.hindered = True
        self.sumo.stop_at(vid, *self.stop_line[rec.movement, "automated"])
        self.sumo.colour(vid, colour)
        self.unreserved.setdefault(rec.lane, []).append(vid)

    def _hindered(self, vid: str) -> bool:
        """Whether a controlled vehicle in the control zone must wait for a human driver instead of
        being scheduled now. When it is first found with an unreserved vehicle ahead on its lane
        (:meth:`_blocked_ahead`), SUMO is told to stop it at the stop line, and the vehicles behind
        it wait for it too. Once nothing unreserved is ahead: moving, it is scheduled as any other
        (:meth:`_admit` cancels the stop; when no merge time fits it drives on to the stop line);
        standing at the stop line, its start from rest is reserved (:meth:`_reserve_from_rest`,
        status ``starting``)."""
        rec = self.records[vid]
        if rec.status == "starting":
            return True
        if not rec.hindered:
            if not self._blocked_ahead(vid):
                return False
            self._wait_at_stop_line(vid, "pending")
            return True
        if self._blocked_ahead(vid):
            return True
        if self._standing_at_stop(vid):
            self._reserve_from_rest(vid)
            return True
        return False

    def _standing_at_stop(self, vid: str) -> bool:
        """Whether a vehicle stands at the stop :meth:`_stop_lines` gives it (and SUMO says so)."""
        rec = self.records[vid]
        k = self.snap.row.get(vid)
        lane, pos = self.stop_line[rec.movement, rec.driver]
        return (k is not None and self.snap.lane[k] == lane and self.snap.lane_pos[k] >= pos - 1.0
                and self.snap.speed[k] < 0.1 and self.sumo.is_stopped(vid))

    def _reserve_from_rest(self, vid: str) -> None:
        """Reserve the start of a controlled vehicle standing at the stop line: from rest at the
        planning's ``u_max_mps2`` up to its crossing speed (:func:`~nrtraffic.planning.profiles.
        from_rest`, the plan the kernel will track), its occupancy of each conflict area bounded
        with ``FROM_REST_SLACK_S`` each side."""
        rec = self.records[vid]
        mv = self.paths[rec.movement]
        a, v_c = self.sc.planning.u_max_mps2, min(mv.v_limit, self.sc.planning.v_max_mps)
        self._reserve(vid, CrossingBounds(a, a, v_c, v_c, FROM_REST_SLACK_S))
        rec.status = "starting"
        rec.profile_kind = "from_rest"
        self.unreserved[rec.lane].remove(vid)
        self.starting.append(vid)
        self.sumo.colour(vid, "held")

    def _start(self) -> None:
        """Controlled vehicles whose reserved start from rest has come: the kernel takes them over."""
        keep = []
        for vid in self.starting:
            rec = self.records[vid]
            if self.t < rec.t_release - 1e-9:
                keep.append(vid)
                continue
            got = self._request(vid)
            if got is None:  # no longer seen on its path (not expected)
                rec.status = "lost"
                continue
            req = got[0]
            mv = self.paths[rec.movement]
            prof = from_rest(self.t, req.D, self.sc.planning.u_max_mps2, min(mv.v_limit, self.sc.planning.v_max_mps))
            self.sumo.resume(vid)
            self._admit(got, Assignment(vid, rec.lane, self.t, prof.t_m, prof, rec.predecessor, rec.relation,
                                        rec.binding, rec.movement))
        self.starting = keep

    def _humans_step(self) -> None:
        """Human drivers at the stop line: a driver standing at its stop (``human`` -> ``reserved``)
        has its crossing reserved (:meth:`_reserve_human`); a reserved driver sets off when its
        reservation starts (-> ``crossing``: SUMO drives it on, the figures follow it as any
        SUMO-driven vehicle)."""
        if not self.humans:
            return
        keep = []
        for vid in self.humans:
            rec = self.records[vid]
            if vid not in self.snap.row:  # left the network (not expected before its crossing)
                if vid in self.unreserved.get(rec.lane, ()):
                    self.unreserved[rec.lane].remove(vid)
                continue
            if rec.status == "human" and self._standing_at_stop(vid):
                self._reserve_human(vid)
            if rec.status == "reserved" and self.t >= rec.t_release - 1e-9:
                self.sumo.resume(vid)
                rec.status = "crossing"
                self.sumo.colour(vid, "released")
            if rec.status == "crossing":
                if not math.isnan(rec.t_exit):  # past the merging zone: its reservation is spent
                    self.reservations.pop(vid, None)
                    continue
                self._refresh(vid)
            keep.append(vid)
        self.humans = keep

    def _refresh(self, vid: str) -> None:
        """Shrink the reservation of a human driver on its way across to what its bounds allow from
        where it is and how fast it goes now: its latest exit of each conflict area comes no later
        than reserved, and sooner when it drives faster than the slowest the bounds allowed, which
        frees the area for the requests that come after. (Entries only move later.)"""
        rec = self.records[vid]
        asg, bounds = self.reservations[vid]
        mv = self.paths[rec.movement]
        s_cg = self._cg_on_path(vid)
        if s_cg is None:
            return
        v = float(self.snap.speed[self.snap.row[vid]])
        for other, (lo, hi) in self._areas_of(rec).items():
            t_in, t_out = bounds.window(mv.s_merge + lo - s_cg, mv.s_merge + hi - s_cg, v)
            old_in, old_out = asg.occupancy[other]
            asg.occupancy[other] = (max(old_in, self.t + t_in), min(old_out, self.t + t_out))

    def _reserve_human(self, vid: str) -> None:
        """Reserve the crossing of a human driver standing at its stop
        (:meth:`Coordinator.reserve_crossing`): its occupancy of each conflict area
        bounded by :class:`~nrtraffic.planning.crossing.CrossingBounds` from the ``[human]``
        section, its drawn speed factor and its path's speed limit."""
        rec = self.records[vid]
        mv = self.paths[rec.movement]
        h, v_max = self.sc.human, self.sc.planning.v_max_mps
        factor = self.sumo.speed_factor(vid)
        bounds = CrossingBounds(a_lo=(1.0 - h.sigma) * h.accel_mps2, a_hi=h.accel_mps2,
                                v_lo=min(mv.v_limit, v_max) * min(1.0, factor), v_hi=v_max,
                                step_s=self.sc.sumo.step_length_s)
        self._reserve(vid, bounds)
        rec.status = "reserved"
        rec.profile_kind = "human"
        self.unreserved[rec.lane].remove(vid)
        self.sumo.colour(vid, "human_reserved")

    def _reserve(self, vid: str, bounds: CrossingBounds):
        """Reserve the crossing from rest of a vehicle standing where SUMO has it now, within
        ``bounds`` (:meth:`Coordinator.reserve_crossing`); its record takes the start, the planned
        merging-zone entry (latest) and its predecessor."""
        rec = self.records[vid]
        mv = self.paths[rec.movement]
        s_cg = self._cg_on_path(vid)
        areas = {other: (mv.s_merge + lo - s_cg, mv.s_merge + hi - s_cg)
                 for other, (lo, hi) in self._areas_of(rec).items()}
        offsets, merge_w, exit_w, v_exit = human_crossing(bounds, areas, mv.s_merge - s_cg, mv.s_exit - s_cg)
        asg = self.junctions[rec.junction].coord.reserve_crossing(vid, rec.lane, self._body(rec), self.t, offsets, merge_w, exit_w,
                                          v_exit)
        rec.t_release = asg.t_release
        rec.t_merge_planned, rec.v_merge_planned = asg.t_merge, asg.profile.v_m
        rec.predecessor, rec.relation, rec.binding = asg.predecessor, asg.relation, asg.binding
        if rec.driver == "human":
            self.reservations[vid] = (asg, bounds)  # refreshed as it crosses (_refresh)
        return asg

    def _cg_on_path(self, vid: str) -> float | None:
        """Where a SUMO-driven vehicle's centre of gravity is on its movement's path now [m] (None
        off the path's lanes)."""
        mv = self.paths[self.records[vid].movement]
        k = self.snap.row[vid]
        if self.snap.lane[k] not in mv.lane_offset:
            return None
        return mv.s_of(self.snap.lane[k], float(self.snap.lane_pos[k])) - self.params.cg_to_front

    @staticmethod
    def _body(rec: VehicleRecord) -> str:
        """The name its body's conflict areas go by: its movement's, or ``<movement>~human``."""
        return rec.movement + (HUMAN_BODY if rec.driver == "human" else "")

    def _areas_of(self, rec: VehicleRecord) -> dict[str, tuple[float, float]]:
        """The conflict areas of a vehicle's body on its movement: other movement -> (from, to) [m
        from its merging-zone entry]."""
        key = self._body(rec)
        return {other: area for (a, other), area in self.conflict_areas.items() if a == key}

    def _sumo_gaps(self) -> None:
        """The bumper gap [m] of every SUMO-driven vehicle between its control-zone entry and its
        merging-zone exit to the vehicle ahead on its path (the leader search of the controlled
        vehicles), for the figures: human drivers, and every vehicle of a baseline."""
        vids = [v for v in self.uncontrolled
                if not math.isnan(self.records[v].t_enter) and math.isnan(self.records[v].t_exit)]
        if not vids:
            return
        tab = self.snap
        lane_id = self._lane_ids
        rows = np.array([tab.row.get(v, -1) for v in vids], dtype=np.int64)
        pid = np.array([self.path_index[self.records[v].movement] for v in vids], dtype=np.int64)
        n = len(vids)
        idx, ext, gap = np.empty(n, dtype=np.int64), np.empty((n, 6)), np.empty(n)
        p = self.params
        find_leaders(lane_id, tab.lane_pos, tab.x, tab.y, tab.psi, tab.speed, tab.accel, rows, pid,
                     self.pl_off, self.pl_lane, self.pl_start, self.pl_scale, LEADER_LOOKAHEAD_M, p.cg_to_front,
                     p.length, idx, ext, gap)
        for vid, g in zip(vids, gap.tolist()):
            if g == g:
                rec = self.records[vid]
                rec.min_gap = min(rec.min_gap, g)

    def _leaders(self) -> None:
        """For each controlled vehicle, the nearest vehicle ahead on the lanes of its own path
        (controlled or SUMO-driven, of any movement: the same lane before a diverge, the same
        outgoing lane after a merge; :func:`nrtraffic.control.leaders.find_leaders`): its batch
        index or its state, and the bumper gap [m] to it, all at time ``t``. Vehicles on other
        lanes (crossing movements) are kept apart by the coordinator, not by the barrier."""
        tab = self.snap
        lane_id = self._lane_ids = np.array([self.lane_index.get(ln, -1) for ln in tab.lane], dtype=np.int64)
        self._sumo_gaps()
        n = len(self.ctl.ids)
        if n == 0:
            return
        p = self.params
        # each controlled vehicle's row in the table (-1: SUMO no longer lists it), also read by
        # _push_and_release later in the step
        rows = self.ctl.rows = np.array([tab.row.get(v, -1) for v in self.ctl.ids], dtype=np.int64)
        find_leaders(lane_id, tab.lane_pos, tab.x, tab.y, tab.psi, tab.speed, tab.accel, rows, self.ctl.path_id,
                     self.pl_off, self.pl_lane, self.pl_start, self.pl_scale, LEADER_LOOKAHEAD_M, p.cg_to_front,
                     p.length, self.ctl.lead_idx, self.ctl.lead_ext, self.ctl.gap)
        for vid, g in zip(self.ctl.ids, self.ctl.gap.tolist()):
            if g == g:  # a leader
                rec = self.records[vid]
                rec.min_gap = min(rec.min_gap, g)

    def _forget_far(self) -> None:
        """Released vehicles more than ``LEADER_LOOKAHEAD_M`` along their last lane can be nobody's
        leader any more: every controlled vehicle is still before its merging-zone exit, a few metres
        into that lane, and a single lane keeps its order. They leave the batched read, which then
        grows with the traffic near the junction, not with the length of the exit roads (SUMO's own
        collision check still covers them)."""
        tab = self.snap
        keep = []
        for vid in self.released:
            k = tab.row.get(vid)
            if k is None:  # it left the network
                continue
            last_lane = self.paths[self.records[vid].movement].lanes[-1]
            if tab.lane[k] == last_lane and tab.lane_pos[k] > LEADER_LOOKAHEAD_M:
                self.sumo.forget(vid)
            else:
                keep.append(vid)
        self.released = keep

    def _collisions_geometric(self) -> None:
        """Own collision check: oriented rectangles (length x width) of every pair of vehicles
        whose circumscribed circles meet, separating-axis test; counted once per pair. It covers
        the vehicles of the batched read: all but released ones far down their exit road
        (:meth:`_forget_far`), which only SUMO drives and checks."""
        tab = self.snap
        ids = tab.ids
        if len(ids) < 2:
            return
        p = self.params
        psi = tab.psi
        c, sn = np.cos(psi), np.sin(psi)
        cx = tab.x - 0.5 * p.length * c
        cy = tab.y - 0.5 * p.length * sn
        ii, jj = touching_pairs(cx, cy, psi, p.length, p.width)
        for i, j in zip(ii.tolist(), jj.tolist()):
            pair = tuple(sorted((ids[i], ids[j])))
            if pair not in self.geometric_collisions:
                self.geometric_collisions.add(pair)
                self.collision_log.append({"t": self.t, "pair": list(pair), "source": "geometric"})

    def _advance(self, dt: float) -> None:
        if not self.ctl.ids:
            return
        n = len(self.ctl.ids)
        if self.noise_rng is None:
            noise = np.zeros((n, self.n_sub, 0))
        else:
            noise = self.noise_rng.standard_normal((n, self.n_sub, kb.N_NOISE)) * self.noise_sd
        kb.advance(self.ctl.X, self.ctl.U, self.t, self.n_sub, self.cfg, self.plant_p, self.pred_p, self.u_lo, self.u_hi,
                   self.ctl.prof, self.ctl.t_enter, self.ctl.s_enter, self.ctl.path_id, self.path_off, self.path_xy, self.path_s,
                   self.path_frames, self.ctl.hint, self.ctl.lead_idx, self.ctl.lead_ext, self.ctl.acc, self.ctl.out, noise, self.ctl.act,
                   self.ctl.xe)
        if not math.isfinite(float(self.ctl.X.sum())):  # a NaN or an infinity anywhere makes the sum one
            bad = [v for v, ok in zip(self.ctl.ids, np.isfinite(self.ctl.X).all(axis=1)) if not ok]
            raise FloatingPointError(f"vehicle state became non-finite at t={self.t:.2f} s: {', '.join(bad)}")
        # merging-zone entry and exit crossed in this step: times interpolated within it
        s_prev, s_new = self.ctl.s_last, self.ctl.out[:, kb.OUT_S]
        for i in np.flatnonzero(s_new >= self.ctl.s_zone[:, 0]):
            for k in (0, 1):
                if s_new[i] >= self.ctl.s_zone[i, k] > s_prev[i]:
                    rec = self.records[self.ctl.ids[i]]
                    t_cross = self.t + dt * (self.ctl.s_zone[i, k] - s_prev[i]) / (s_new[i] - s_prev[i])
                    if k == 0 and math.isnan(rec.t_merge_actual):
                        rec.t_merge_actual = t_cross
                    elif k == 1 and math.isnan(rec.t_exit):
                        rec.t_exit = t_cross
        self.ctl.s_last[:] = s_new

    def _log(self) -> None:
        if self.traj is None or not self.ctl.ids:
            return
        X, U, o = self.ctl.X, self.ctl.U, self.ctl.out
        ref_s = np.array([self.ctl.s_enter[i] + packed_position(self.ctl.prof[i], self.t - self.ctl.t_enter[i])
                          for i in range(len(self.ctl.ids))])
        s_c = np.array([self.paths[self.records[v].movement].s_control for v in self.ctl.ids])
        self.traj.append(
            t=np.full(len(self.ctl.ids), self.t), vehicle_id=list(self.ctl.ids), s_m=o[:, kb.OUT_S] - s_c,
            x=X[:, 0], y=X[:, 1], v_l=X[:, 2], v_n=X[:, 3], psi=X[:, 4], psi_dot=X[:, 5], a_cmd=o[:, kb.OUT_A],
            delta_cmd=o[:, kb.OUT_D], a_track=U[:, 0], delta_track=U[:, 1], ref_x=o[:, kb.OUT_REFX],
            ref_y=o[:, kb.OUT_REFY], ref_s_m=ref_s - s_c, tracking_error_m=o[:, kb.OUT_ERR],
            lateral_dev_m=o[:, kb.OUT_LAT],
            center_distance_m=np.where(self.ctl.lead_idx != kb.NO_LEADER, self._centre_now(), np.nan),
            bumper_gap_m=self.ctl.gap, cbf_long_active=o[:, kb.OUT_LONG_FRAC], cbf_lat_active=o[:, kb.OUT_LAT_FRAC],
            h_long=o[:, kb.OUT_H_LONG], h_lat=o[:, kb.OUT_H_LAT],
        )

    def _centre_now(self) -> np.ndarray:
        out = np.full(len(self.ctl.ids), np.nan)
        for i in range(len(self.ctl.ids)):
            j = self.ctl.lead_idx[i]
            if j >= 0:
                out[i] = math.hypot(self.ctl.X[j, 0] - self.ctl.X[i, 0], self.ctl.X[j, 1] - self.ctl.X[i, 1])
            elif j == kb.EXTERNAL_LEADER:
                out[i] = math.hypot(self.ctl.lead_ext[i, 0] - self.ctl.X[i, 0], self.ctl.lead_ext[i, 1] - self.ctl.X[i, 1])
        return out

    def _push_and_release(self) -> None:
        if not self.ctl.ids:
            return
        cg = self.params.cg_to_front
        ids = self.ctl.ids
        lost = self.ctl.rows < 0  # left SUMO's network (rare); rows found by _leaders this step
        X = self.ctl.X
        front_x = X[:, 0] + cg * np.cos(X[:, 4])
        front_y = X[:, 1] + cg * np.sin(X[:, 4])
        speed = np.hypot(X[:, 2], X[:, 3])
        keep = ~lost
        if keep.all():
            self.sumo.push_poses(ids, front_x, front_y, X[:, 4], speed)
        else:
            self.sumo.push_poses([v for v, k in zip(ids, keep) if k], front_x[keep], front_y[keep], X[keep, 4],
                                 speed[keep])
        done = keep & (self.ctl.out[:, kb.OUT_S] >= self.ctl.s_zone[:, 1])
        gone = lost | done
        if not gone.any():
            return
        for i in np.flatnonzero(gone).tolist():
            vid = ids[i]
            rec = self.records[vid]
            rec.acc = self.ctl.acc[i].copy()
            if done[i]:
                self.sumo.release(vid)
                rec.status = "released"
                self.sumo.colour(vid, "released")
                if not self._next_leg(vid):  # (a corridor: on to the next junction)
                    self.released.append(vid)
            else:
                rec.status = "lost"
        self.ctl.keep(~gone)

    def _script(self, scripted: list[str], t_next: float) -> None:
        """SUMO-driven vehicles with a speed profile: the desired speed for the next step."""
        if not scripted:
            return
        live = self.snap.row
        for vid in list(scripted):
            if vid not in live:
                scripted.remove(vid)
                continue
            prof = np.asarray(self.records[vid].speed_profile, dtype=float)
            self.sumo.hold_speed(vid, float(np.interp(t_next, prof[:, 0], prof[:, 1])))

    # ------------------------------------------------------------------ results
    def _tripinfo(self, final: bool = True) -> dict[str, tuple[float, float]]:
        """Per finished trip, SUMO's own timeLoss [s], number of stops (``waitingCount``: times
        its speed fell below 0.1 m/s) and travel time (``duration``) [s] from tripinfo.xml; nothing
        while SUMO still writes it (``final`` false)."""
        path = self.workdir / "tripinfo.xml"
        if not final or not self.sc.outputs.sumo_tripinfo or not path.is_file():
            return {}
        import xml.etree.ElementTree as ET

        try:
            return {t.get("id"): (float(t.get("timeLoss")), float(t.get("waitingCount")), float(t.get("duration")))
                    for t in ET.parse(path).getroot().iter("tripinfo")}
        except ET.ParseError:  # a run that stopped early may leave it unterminated
            return {}

    @staticmethod
    def _trips(veh: pd.DataFrame) -> pd.DataFrame:
        """One row per trip: ``veh`` itself when every vehicle crosses one junction; on a corridor,
        a vehicle's crossings added up (delay, energy, fuel), its first crossing's arrival and
        wait to enter, and its last crossing's exit (NaN, as is the delay, until it has crossed
        every junction of its trip)."""
        if veh.empty or (veh["legs"] <= 1).all():
            return veh
        out = veh.drop_duplicates("vehicle_id", keep="first").set_index("vehicle_id")
        last = veh.drop_duplicates("vehicle_id", keep="last").set_index("vehicle_id")
        complete = (last["leg"] == last["legs"] - 1) & last["t_exit_s"].notna()
        out["t_exit_s"] = last["t_exit_s"].where(complete)
        sums = veh.groupby("vehicle_id", sort=False)[["delay_s", "energy_u2", "fuel_ml"]].sum(min_count=1)
        out["delay_s"] = sums["delay_s"].where(complete)
        out["energy_u2"], out["fuel_ml"] = sums["energy_u2"], sums["fuel_ml"]
        return out.reset_index()[veh.columns]

    def _corridor_table(self, veh: pd.DataFrame, trips: dict, w0: float, w1: float) -> dict:
        """summary.json ``corridor`` (several junctions): the trips straight through every
        controlled junction, per road they enter by (a direction of the arterial), that entered
        their first control zone in the window and left the network: how many, their mean travel
        time (SUMO's tripinfo duration, from insertion to arrival, plus the wait to be inserted)
        [s], stops per vehicle (SUMO's waitingCount) and delay (the crossings' delays added up)
        [s]."""
        if len(getattr(self, "junctions", {})) < 2 or veh.empty:
            return {}
        n = len(self.junctions)
        g = veh.groupby("vehicle_id", sort=False)
        through = g["movement"].agg(lambda m: bool((m == "straight").all())) & (g["leg"].count() == n)
        first = veh.drop_duplicates("vehicle_id").set_index("vehicle_id")
        ok = through & first["t_arrive_s"].between(w0, w1) & first.index.isin(list(trips))
        delay = g["delay_s"].sum(min_count=n)
        out = {}
        for appr in sorted(set(first.loc[ok[ok].index, "approach"])):
            ids = [v for v in ok[ok].index if first.at[v, "approach"] == appr]
            tt = [trips[v][2] + first.at[v, "depart_delay_s"] for v in ids]
            out[appr] = {"vehicles": len(ids), "travel_time_s": float(np.mean(tt)),
                         "stops_per_vehicle": float(np.mean([trips[v][1] for v in ids])),
                         "delay_s": metrics.mean_or_none(delay[ids])}
        return out

    def _junction_table(self, veh: pd.DataFrame, w0: float, w1: float) -> dict:
        """summary.json ``junctions``: per controlled junction, the crossings that entered its
        control zone in the window and left its merging zone: how many, their throughput [veh/h],
        mean and 95th-percentile delay [s] and the HCM letter, and the control zone cuts."""
        out = {}
        hours = max(w1 - w0, 0.0) / 3600.0
        for jid, j in getattr(self, "junctions", {}).items():
            g = veh[(veh["junction"] == jid) & veh["t_arrive_s"].between(w0, w1) & veh["t_exit_s"].notna()]
            mean = metrics.mean_or_none(g["delay_s"])
            out[jid] = {"vehicles": int(len(g)), "throughput_veh_h": len(g) / hours if hours > 0 else None,
                        "mean_delay_s": mean, "p95_delay_s": metrics.percentile_or_none(g["delay_s"], 95),
                        "los": (metrics.level_of_service(mean, metrics.is_signalised(self.label))
                                if mean is not None else None),
                        "control_zone_m": j.control_zone_m, "merging_zone_m": j.merging_zone_m}
        return out

    def _driver_figures(self, adm: pd.DataFrame, done: pd.DataFrame) -> dict:
        """Figures split by driver (``demand.controlled_share``): the share of human drivers among
        the vehicles that entered the control zone in the window, mean delay and smallest bumper
        gap of each kind, and the pairs that collided (SUMO's check or the own one) by the kinds
        of the two vehicles."""
        kind = {r.vehicle_id: r.driver for r in self.records.values()}
        pairs = self.collision_pairs | self.geometric_collisions
        n_pair = {"automated": 0, "mixed": 0, "human": 0}
        for a, b in pairs:
            ka, kb_ = kind.get(a, "automated"), kind.get(b, "automated")
            n_pair[ka if ka == kb_ else "mixed"] += 1
        out = {"human_share": float((adm["driver"] == "human").mean()) if len(adm) else None}
        for d in ("automated", "human"):
            out[f"vehicles_{d}"] = int((adm["driver"] == d).sum())
            out[f"mean_delay_{d}_s"] = metrics.mean_or_none(done.loc[done["driver"] == d, "delay_s"])
            out[f"min_bumper_gap_{d}_m"] = metrics.min_or_none(adm.loc[adm["driver"] == d, "min_bumper_gap_m"])
        out.update({f"collisions_{k}": v for k, v in n_pair.items()})
        return out

    def _result(self, wall: float, error: BaseException | None, final: bool = True) -> RunResult:
        """The figures so far; ``final`` false for a checkpoint of a run still going (status
        "running", no SUMO timeLoss yet)."""
        ctl = getattr(self, "ctl", None)
        for i, vid in enumerate(ctl.ids if ctl is not None else []):
            self.records[vid].acc = ctl.acc[i].copy()
        rows = []
        paths = getattr(self, "paths", {})
        trips = self._tripinfo(final)
        # in order of departure (a corridor trip's crossings in order)
        for rec in sorted(self.crossings + list(self.records.values()), key=lambda r: (r.t_depart, r.leg)):
            if rec.status == "waiting" or (self.control and not rec.controlled and rec.driver != "human"):
                continue  # (a SUMO-driven vehicle of the scenario's own, e.g. a scripted leader)
            ap = paths.get(rec.movement)
            delay = math.nan
            if ap is not None and not math.isnan(rec.t_exit):
                if math.isnan(rec.t_arrive):  # SUMO-driven: t_enter is when it crossed the entry
                    t_from, s_from = rec.t_enter, rec.s_enter
                else:  # controlled: from crossing the entry, before any wait for its batch or a merge time
                    t_from, s_from = rec.t_arrive, rec.s_arrive
                # plus the wait to enter the network at all, so that a control whose queues back up to
                # the insertion point is not credited with the demand it kept out
                delay = float(metrics.free_flow_delay(t_from, rec.t_exit, ap.s_exit - s_from, rec.v_free)) \
                    + rec.depart_delay
            admitted = not math.isnan(rec.t_enter)
            a = rec.acc.copy() if admitted else np.full(kb.N_ACC, np.nan)
            if not rec.controlled:  # SUMO drove it: no tracking, no barriers
                for k in (kb.ACC_MAX_ERR, kb.ACC_MAX_ERR_STEADY, kb.ACC_MAX_ERR_TRANSIENT, kb.ACC_MAX_LAT,
                          kb.ACC_LONG_ACTIVE, kb.ACC_LAT_ACTIVE, kb.ACC_LONG_FALLBACK, kb.ACC_LAT_FALLBACK):
                    a[k] = math.nan
            steps = a[kb.ACC_STEPS]

            def fin(v):
                return v if np.isfinite(v) else math.nan

            rows.append({
                "vehicle_id": rec.vehicle_id, "junction": rec.junction, "leg": rec.leg, "legs": len(rec.legs) or 1,
                "approach": rec.approach, "driver": rec.driver,
                "movement": ap.turn if ap is not None else "", "lane": rec.lane,
                "t_arrive_s": rec.t_enter if math.isnan(rec.t_arrive) else rec.t_arrive,
                "depart_delay_s": rec.depart_delay,
                "t_enter_s": rec.t_enter, "v_enter_mps": rec.v_enter, "t_merge_planned_s": rec.t_merge_planned,
                "t_merge_actual_s": rec.t_merge_actual, "t_exit_s": rec.t_exit, "delay_s": delay,
                "max_tracking_error_m": a[kb.ACC_MAX_ERR], "steady_tracking_error_m": a[kb.ACC_MAX_ERR_STEADY],
                "transient_tracking_error_m": a[kb.ACC_MAX_ERR_TRANSIENT], "max_lateral_dev_m": a[kb.ACC_MAX_LAT],
                "min_bumper_gap_m": fin(rec.min_gap), "energy_u2": a[kb.ACC_ENERGY], "fuel_ml": a[kb.ACC_FUEL],
                "predecessor": rec.predecessor or "", "relation": rec.relation, "binding": rec.binding,
                "profile": rec.profile_kind, "plan_rear_end_intrusion_m": rec.plan_intrusion,
                "v_merge_planned_mps": rec.v_merge_planned,
                "min_center_distance_m": fin(a[kb.ACC_MIN_CENTER]), "max_abs_accel_mps2": a[kb.ACC_MAX_ABS_A],
                "cbf_long_active_frac": a[kb.ACC_LONG_ACTIVE] / steps if steps else math.nan,
                "cbf_lat_active_frac": a[kb.ACC_LAT_ACTIVE] / steps if steps else math.nan,
                "cbf_long_fallbacks": a[kb.ACC_LONG_FALLBACK], "cbf_lat_fallbacks": a[kb.ACC_LAT_FALLBACK],
                "min_h_long": fin(a[kb.ACC_MIN_H_LONG]), "min_h_lat": fin(a[kb.ACC_MIN_H_LAT]),
                "plant_steps": steps if rec.controlled else 0.0,
                "t_held_s": rec.t_held, "t_release_s": rec.t_release, "sumo_time_loss_s": trips.get(rec.vehicle_id, (math.nan,))[0],
                "stops": trips.get(rec.vehicle_id, (math.nan, math.nan))[1],
                "status": rec.status,
            })
        veh = pd.DataFrame(rows, columns=VEHICLE_COLUMNS)
        sim_t = float(self.t)
        o = self.sc.outputs
        w0, w1 = o.warmup_s, (o.measure_end_s or sim_t)
        w1 = min(w1, sim_t)
        # the measurement window: vehicles that entered the control zone inside it
        inside = veh["t_arrive_s"].between(w0, w1)
        adm_all = veh[veh["t_enter_s"].notna() & inside]
        # the trips (a corridor: a vehicle's crossings added up; one junction: its crossing)
        trip = self._trips(veh)
        done = trip[trip["t_exit_s"].notna() & trip["t_arrive_s"].between(w0, w1)]
        # the vehicles' own figures (tracking, barriers, gaps) are the automated vehicles'; human
        # drivers have theirs apart (by_driver)
        adm = adm_all[adm_all["driver"] == "automated"]
        steps = adm["plant_steps"].sum()
        window = max(w1 - w0, 0.0)
        exits = int(trip["t_exit_s"].between(w0, w1).sum())
        throughput = exits / window * 3600.0 if window > 0 else None
        demand = self.demand_veh_h(w0, w1) if window > 0 and hasattr(self, "movement_table") else 0.0
        # demand not yet in the network at the end: due to depart, but SUMO could not insert it
        due = [t for vid, (mv, t, _) in getattr(self, "_scheduled", {}).items() if t <= sim_t]
        mean_delay = metrics.mean_or_none(done["delay_s"])
        controlled = self.control
        summary = {
            "scenario": self.sc.general.name,
            "control": self.label,
            "seed": self.seed,
            "status": ("ok" if error is None else "failed") if final else "running",
            "error": None if error is None else f"{type(error).__name__}: {error}",
            "sim_time_s": sim_t,
            "wall_time_s": wall,
            "real_time_factor": sim_t / wall if wall > 0 else None,
            "measure_from_s": w0,
            "measure_to_s": w1,
            "vehicles_spawned": int(sum(r.status != "waiting" for r in self.records.values())),
            "vehicles_admitted": int(len(adm_all)),
            "vehicles_completed": int(len(done)),
            "throughput_veh_h": throughput,
            "demand_veh_h": demand or None,
            "served_share": throughput / demand if demand and throughput is not None else None,
            "control_zones_cut_m": {k: round(v, 3) for k, v in self.zone_cuts.items()},
            "junctions": self._junction_table(veh, w0, w1),
            "corridor": self._corridor_table(veh, trips, w0, w1),
            "vehicles_waiting_to_enter": len(due),
            "mean_wait_to_enter_s": float(np.mean([sim_t - t for t in due])) if due else None,
            "mean_depart_delay_s": metrics.mean_or_none(done["depart_delay_s"]),
            "mean_delay_s": mean_delay,
            "los": (metrics.level_of_service(mean_delay, metrics.is_signalised(self.label))
                    if mean_delay is not None else None),
            "mean_sumo_time_loss_s": metrics.mean_or_none(done["sumo_time_loss_s"]),
            "vehicles_held": int((veh.loc[inside, "t_held_s"] > 0).sum()),
            "plans_rear_end_constrained": int((adm["profile"] == "rear_end").sum()),
            "plans_rear_end_unresolved": int((adm["plan_rear_end_intrusion_m"] > REAR_END_TOL_M).sum()),
            "p95_delay_s": metrics.percentile_or_none(done["delay_s"], 95),
            "collisions": len(self.collision_pairs),
            "collisions_geometric": len(self.geometric_collisions),
            "collision_events": self.collision_log[:100],
            "min_center_distance_m": metrics.min_or_none(adm["min_center_distance_m"]),
            "min_bumper_gap_m": metrics.min_or_none(adm["min_bumper_gap_m"]),
            "max_tracking_error_m": metrics.max_or_none(adm["max_tracking_error_m"]),
            "steady_tracking_error_m": metrics.max_or_none(adm["steady_tracking_error_m"]),
            "transient_tracking_error_m": metrics.max_or_none(adm["transient_tracking_error_m"]),
            "max_lateral_dev_m": metrics.max_or_none(adm["max_lateral_dev_m"]),
            "max_abs_accel_mps2": metrics.max_or_none(adm["max_abs_accel_mps2"]),
            "mean_energy_u2": metrics.mean_or_none(done["energy_u2"]),
            "mean_fuel_ml": metrics.mean_or_none(done["fuel_ml"]),
            # what only a controlled run has: null for a baseline
            "barriers_longitudinal": bool(self.sc.barriers.longitudinal) if controlled else None,
            "barriers_lateral": bool(self.sc.barriers.lateral) if controlled else None,
            "cbf_long_active_frac": float((adm["cbf_long_active_frac"] * adm["plant_steps"]).sum() / steps) if steps else None,
            "cbf_lat_active_frac": float((adm["cbf_lat_active_frac"] * adm["plant_steps"]).sum() / steps) if steps else None,
            "cbf_long_fallbacks": int(adm["cbf_long_fallbacks"].sum()) if controlled else None,
            "cbf_lat_fallbacks": int(adm["cbf_lat_fallbacks"].sum()) if controlled else None,
            **self._driver_figures(adm_all, done),
            "wall_time_breakdown_s": {**self.wall_breakdown,
                                      "qp": sum(j.coord.qp_wall_s for j in getattr(self, "junctions", {}).values()
                                                if j.coord is not None)},
            "nrtraffic_version": __version__,
            "sumo_version": sumo_version(),
        }
        extra = {}
        if final and self.sc.controlled_junctions() and hasattr(self, "movement_table"):
            extra["approaches"] = self.approach_table(veh, w0, w1)
            extra["queues"] = self.queue_series()
        return RunResult(summary, veh, self.workdir, extra)
