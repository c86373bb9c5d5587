"""Scenario files (TOML) -> validated, frozen configuration objects.

A scenario file has the sections below (every key optional unless marked); unknown sections and
keys are errors naming the key, and so are values of the wrong type or out of range.
See ``sumo_scenarios/paper_curved/scenario.toml`` for a commented example.

Units are in the key names: ``_s`` seconds, ``_m`` metres, ``_mps`` m/s, ``_mps2`` m/s^2,
``_rad`` radians.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, get_type_hints

from nrtraffic.limits import MAX_DURATION_S, MAX_SEED, sumo_id_problem, sumo_time  # noqa: F401  (re-exported)
from nrtraffic.planning.coordinator import CoordinatorSettings
from nrtraffic.planning.profiles import PlanBounds
from nrtraffic.vehicle.params import BicycleParams, preset


class ScenarioError(ValueError):
    """A scenario file is malformed, names an unknown key, or has an invalid value."""




@dataclass(frozen=True)
class General:
    """``[scenario]``: name, network and run length."""

    name: str = "unnamed"  # the scenario's name in summaries and sweep tables
    description: str = ""  # free text
    network: str = ""  # path of the .net.xml, relative to the scenario file (required)
    seed: int = 1  # random seed of arrivals and SUMO (--seed overrides it)
    duration_s: float = 0.0  # simulated time; 0 runs until every vehicle has left
    sumocfg: str = ""  # a SUMO configuration (.sumocfg) to take the network, route files, begin and end from (keys given here win)
    begin_s: float = 0.0  # SUMO's clock at the run's start (--begin), e.g. 25200 for 07:00; route files give absolute times, every other time of the run is measured from it

    def validate(self) -> None:
        if not self.network:
            raise ScenarioError("scenario.network is required (path of the SUMO .net.xml)")
        if not self.name.strip() or not self.name.isprintable():  # (it names the run's folder and its tables' rows)
            raise ScenarioError(f"scenario.name = {self.name!r}: give a name of printable characters (it names the run "
                                "in its folder, summaries and sweep tables)")


@dataclass(frozen=True)
class Sumo:
    """``[sumo]``: SUMO's own settings."""

    step_length_s: float = 0.1  # SUMO step [s] (a whole multiple of controller.plant_step_s)
    lateral_resolution_m: float = 0.0  # sublane width [m]; 0: no sublane model (moveToXY places exactly either way)
    extra_args: tuple[str, ...] = ()  # further SUMO options, e.g. ["--max-depart-delay", "300"]; not those the run sets itself, nor any that writes or reads a file


# the work a run may take per simulated second, per vehicle: plant steps per SUMO step, and nominal
# predictor steps per horizon (each plant step runs one prediction)
MAX_PLANT_STEPS_PER_STEP = 1000
MIN_CONTROL_ZONE_M = 20.0  # the shortest control zone [m]: set, or left to a route after a cut
MAX_PREDICTOR_STEPS = 10000
MAX_PREDICTOR_STEPS_PER_S = 2_000_000  # plant steps per second x predictor steps per horizon (the paper's Euler: 1.6e6)


@dataclass(frozen=True)
class Controller:
    """``[controller]``: plant integration, predictor and Newton-Raphson flow (paper s. 3.1, 4.1)."""

    plant_step_s: float = 0.005  # forward-Euler step of the plant (paper dt); at most its stability limit (0.0111 for the paper car)
    predictor: str = "euler"  # integrator of the predictor: "euler" (the paper's) or "rk4" (docs/method.md)
    predictor_step_s: float = 0.001  # nominal step of the predictor (paper Delta t, for Euler)
    horizon_s: float = 0.2  # prediction horizon T (not given by the paper; see docs/method.md)
    alpha: float = 100.0  # speed-up of the update law, eq. (12)
    damping: float = 1e-6  # relative damping of the regularised inverse
    predictor_mass_factor: float = 1.0  # predictor mass / plant mass (paper's robustness test: 2)
    a_min_mps2: float = -6.0  # input bounds of the tracker
    a_max_mps2: float = 3.0  # [m/s^2]
    steer_max_rad: float = math.pi / 4  # steering bound of the tracker and the lateral barrier [rad]

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"predictor": ("euler", "rk4")}

    def validate(self) -> None:  # (each key's own bounds, steer_max_rad > 0 and a_min < 0 < a_max too: RANGES)
        steps = self.horizon_s / self.predictor_step_s
        if steps > MAX_PREDICTOR_STEPS + 1e-9:
            raise ScenarioError(f"controller.horizon_s / controller.predictor_step_s = {steps:.0f} predictor steps per "
                                f"horizon, more than {MAX_PREDICTOR_STEPS}: raise controller.predictor_step_s or "
                                "shorten controller.horizon_s")
        if self.predictor == "euler" and self.horizon_s < self.predictor_step_s:
            raise ScenarioError("controller.horizon_s must be at least controller.predictor_step_s (Euler predictor)")
        if self.predictor not in self.CHOICES["predictor"]:
            raise ScenarioError(f"controller.predictor must be one of {', '.join(map(repr, self.CHOICES['predictor']))}, "
                                f"got {self.predictor!r}")
        if self.damping < 0:
            raise ScenarioError("controller.damping must be >= 0")


@dataclass(frozen=True)
class Vehicle:
    """``[vehicle]``: a parameter preset and optional overrides of its fields."""

    preset: str = "paper"
    overrides: dict = field(default_factory=dict)

    def params(self) -> BicycleParams:
        base = preset(self.preset)
        names = {f.name for f in dataclasses.fields(BicycleParams)}
        for k in self.overrides:
            if k not in names:
                raise ScenarioError(f"vehicle.{k} is not a vehicle parameter; known: {', '.join(sorted(names))}")
        try:
            return dataclasses.replace(base, **{k: float(v) for k, v in self.overrides.items()})
        except (TypeError, ValueError) as exc:
            raise ScenarioError(f"vehicle: {exc}") from None

    def validate(self) -> None:
        try:
            self.params()
        except ValueError as exc:
            raise ScenarioError(str(exc)) from None


@dataclass(frozen=True)
class Zones:
    """``[zones]``: lengths along each approach's path [m]."""

    control_zone_m: float = 400.0  # length of the control zone before the merging zone [m]
    merging_zone_m: float = 30.0  # length (plain road) or diameter (junction) of the merging zone [m]
    # (each > 0: RANGES, OPEN)


@dataclass(frozen=True)
class Approach:
    """``[[approaches]]``: one controlled path into the merging zone."""

    name: str = ""  # name of the approach (its movement's key)
    route: tuple[str, ...] = ()  # SUMO edge ids from insertion to the end of the network
    merge_entry_edge: str = ""  # edge holding the merging-zone entry
    merge_entry_pos_m: float = 0.0  # its lane position on that edge [m]

    def validate(self) -> None:
        if not self.name:
            raise ScenarioError("every [[approaches]] entry needs a name")
        if len(self.route) < 1:
            raise ScenarioError(f"approaches.{self.name}.route must list at least one edge")
        if self.merge_entry_edge not in self.route:
            raise ScenarioError(f"approaches.{self.name}.merge_entry_edge {self.merge_entry_edge!r} is not on its route")


TURNS = ("left", "straight", "right", "u_turn")


@dataclass(frozen=True)
class DemandFlow:
    """``[[demand.flows]]``: the turning movement counts of one approach [veh/h]."""

    approach: str = ""  # the incoming edge of the junction
    left: float = 0.0  # left turns [veh/h]
    straight: float = 0.0  # straight on [veh/h]
    right: float = 0.0  # right turns [veh/h]
    u_turn: float = 0.0  # U-turns, where the network has them [veh/h]

    @property
    def total_veh_h(self) -> float:
        return self.left + self.straight + self.right + self.u_turn

    def validate(self) -> None:
        if not self.approach:
            raise ScenarioError("every [[demand.flows]] entry needs an approach (an incoming edge of the junction)")


@dataclass(frozen=True)
class DemandInterval:
    """``[[demand.intervals]]``: the demand scaled by ``scale`` from ``begin_s`` to ``end_s`` (a
    peak period); outside every interval the scale is 1."""

    begin_s: float = 0.0  # start of the interval [s]
    end_s: float = 0.0  # its end [s]
    scale: float = 1.0  # factor on every flow (and on demand.rate_veh_h) inside it

    def validate(self) -> None:
        if not (0 <= self.begin_s < self.end_s):
            raise ScenarioError(f"demand.intervals: need 0 <= begin_s < end_s, got begin_s = {self.begin_s}, "
                                f"end_s = {self.end_s}")


@dataclass(frozen=True)
class Demand:
    """``[demand]``: arrivals per approach, drawn from the run's seed.

    Headways are shifted exponential (a Poisson stream thinned by a minimum headway):
    ``h = min_headway_s + Exp(mean_headway_s - min_headway_s)``.
    """

    entry_speed_mps: float = 13.4  # speed at which vehicles are inserted and enter the control zone [m/s]
    mean_headway_s: float = 6.0  # 0: no random arrivals (only [[vehicles]])
    rate_veh_h: float = 0.0  # arrivals per approach per hour; > 0 overrides mean_headway_s
    turn_left: float = 0.0  # turning shares at a junction (straight is the rest)
    turn_right: float = 0.0  # share of right turns
    min_headway_s: float = 1.5  # shortest headway between arrivals of an approach [s]
    max_vehicles: int = 0  # per approach; 0 = no limit
    begin_s: float = 0.0  # first arrival time [s]
    end_s: float = 0.0  # last departure time; 0 = scenario.duration_s
    flows: tuple[DemandFlow, ...] = ()  # turning movement counts per approach; replace rate_veh_h and the shares
    intervals: tuple[DemandInterval, ...] = ()  # periods with scaled demand (a peak)
    sumo_routes: str = ""  # SUMO demand files (.rou.xml: flows, trips, vehicles; several separated by commas, as SUMO's route-files) instead of the keys above
    controlled_share: float = 1.0  # share of the vehicles that are controlled; the others are [human] drivers
    scale: float = 1.0  # with sumo_routes: the file's vehicles scaled by this factor, each kept, copied or left out at random by the run's seed (SUMO's --scale)
    depart_offset_s: float = 0.0  # with sumo_routes: each departure later by a random time up to this, drawn from the run's seed (SUMO's --random-depart-offset), so that seeds differ [s]

    def validate(self) -> None:  # (entry_speed_mps > 0: RANGES)
        by_mean = self.rate_veh_h == 0 and not self.flows and not self.sumo_routes  # (else the rate's check below)
        if by_mean and self.mean_headway_s != 0 and not (0 <= self.min_headway_s < self.mean_headway_s):
            raise ScenarioError(f"demand.min_headway_s = {self.min_headway_s} s must be below demand.mean_headway_s = "
                                f"{self.mean_headway_s} s (or mean_headway_s = 0: no random arrivals)")
        if not (0 <= self.turn_left <= 1 and 0 <= self.turn_right <= 1 and self.turn_left + self.turn_right <= 1):
            raise ScenarioError("demand.turn_left and demand.turn_right must be shares in [0, 1] summing to <= 1")
        names = [f.approach for f in self.flows]
        if len(set(names)) != len(names):
            raise ScenarioError(f"demand.flows: each approach once, got {names}")
        ivs = sorted(self.intervals, key=lambda i: i.begin_s)
        for a, b in zip(ivs, ivs[1:]):
            if b.begin_s < a.end_s:
                raise ScenarioError(f"demand.intervals [{a.begin_s}, {a.end_s}] s and [{b.begin_s}, {b.end_s}] s overlap")
        # every approach's rate, at the peak of the intervals, must leave room above the minimum headway
        peak = max([i.scale for i in self.intervals] + [1.0])
        rates = [(f"demand.flows.{f.approach}", f.total_veh_h) for f in self.flows] or [("demand.rate_veh_h",
                                                                                        self.rate_veh_h)]
        for key, rate in rates:
            if rate * peak > 0 and 3600.0 / (rate * peak) <= self.min_headway_s:
                at_peak = f" at the peak scale {peak:g}" if peak != 1.0 else ""
                raise ScenarioError(f"{key} = {rate:g} veh/h{at_peak} needs a mean headway above "
                                    f"demand.min_headway_s = {self.min_headway_s} s")

    def scale_at(self, t: float) -> float:
        """The demand's scale at time ``t`` [s] (1 outside every interval)."""
        for i in self.intervals:
            if i.begin_s <= t < i.end_s:
                return i.scale
        return 1.0

    def route_files(self, base_dir: Path) -> list[Path]:
        """The files of ``sumo_routes`` (comma-separated), resolved against ``base_dir``."""
        return [(Path(base_dir) / f.strip()).resolve() for f in self.sumo_routes.split(",") if f.strip()]

    def breakpoints(self, begin: float, end: float) -> list[float]:
        """``begin``, every interval boundary inside ``(begin, end)``, ``end``."""
        inner = sorted({x for i in self.intervals for x in (i.begin_s, i.end_s) if begin < x < end})
        return [begin, *inner, end]

    @property
    def headway_s(self) -> float:
        """Mean headway per approach [s] (0: no random arrivals)."""
        return 3600.0 / self.rate_veh_h if self.rate_veh_h > 0 else self.mean_headway_s


@dataclass(frozen=True)
class HumanDriver:
    """``[human]``: the vehicles that ``demand.controlled_share`` leaves to SUMO (docs/mixed-traffic.md).
    SUMO's car-following model drives them, in the controlled vehicles' dimensions.

    Their rule at a coordinated junction (docs/mixed-traffic.md): a human driver on its way to its
    stop line with nothing ahead of it goes on without stopping where its crossing, bounded from
    where it is, fits now; otherwise it stops at SUMO's stop line (or short of the first conflict
    area its body would touch there), and when it stands there, or stands in the queue within
    ``queue_reach_m`` behind drivers already reserved, the coordinator reserves its crossing from
    where it stands, first come first served with the controlled vehicles' reservations and after
    the vehicle ahead of it on its lane (a human ahead: 1 s after its start). Its occupancy of every
    conflict area is bounded from both sides by stepping SUMO's Krauss update: at the latest always
    dawdling (``sigma``), up to the slowest speed limit on its path times its speed factor, one step
    late; at the earliest never dawdling, up to the planning's ``v_max_mps``, one step early. Two
    human drivers' occupancies are kept ``conflict_margin_s`` apart. A controlled vehicle that
    reaches the control zone behind a human whose crossing is not reserved yet waits for it: it is
    scheduled on the move once nothing unreserved is ahead of it, or, standing at the
    merging-zone entry by then, starts from rest on a reserved plan. In a baseline run (SUMO's own
    junction control) the same drivers obey that control.
    """

    car_follow_model: str = "Krauss"  # SUMO's car-following model (the reservation's bounds are Krauss's)
    accel_mps2: float = 2.6  # its acceleration (SUMO's default for a passenger car) [m/s^2]
    decel_mps2: float = 4.5  # its comfortable deceleration [m/s^2]
    sigma: float = 0.5  # driver imperfection (random deceleration up to sigma * accel)
    tau_s: float = 1.0  # desired time headway [s]
    min_gap_m: float = 2.5  # bumper to bumper at a standstill [m]
    speed_dev: float = 0.0  # spread of the desired speed around the speed limit (SUMO's speedDev)
    conflict_margin_s: float = 0.2  # between two human drivers' occupancies of a conflict area (+0.1 s: one controlled) [s]
    queue_reach_m: float = 17.0  # a standing driver this far short of its stop is reserved in the queue [m]

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"car_follow_model": ("Krauss",)}

    def validate(self) -> None:
        if self.car_follow_model not in self.CHOICES["car_follow_model"]:
            raise ScenarioError(f"human.car_follow_model must be one of "
                                f"{', '.join(map(repr, self.CHOICES['car_follow_model']))}, got {self.car_follow_model!r}")
        if not (0.0 <= self.sigma < 1.0):
            raise ScenarioError(f"human.sigma must be in [0, 1), got {self.sigma!r}")


@dataclass(frozen=True)
class Junction:
    """``[junction]``: an intersection whose incoming edges are the approaches.

    With ``id`` set, every incoming edge of that junction is an approach and every lane-to-lane
    connection a movement (its route: incoming edge, outgoing edge; a vehicle's lane, where the
    road has several, is the one SUMO inserts it on); the merging zone is the disc of diameter
    ``zones.merging_zone_m`` around the junction centre. ``[[junctions]]`` lists several junctions
    instead (a corridor); ``lateral_clearance_m`` applies to all. Two movements conflict when they leave on
    the same lane or when the areas their car bodies sweep inside the zone overlap, each body
    widened by ``lateral_clearance_m`` on both sides; they are on the same lane when they share the
    incoming lane, and compatible otherwise (planning/conflicts.py).
    """

    id: str = ""  # id of the SUMO junction to control (every incoming edge is an approach)
    lateral_clearance_m: float = 0.5  # [m] band each car may leave its centre line by (barriers.max_lateral_dev_m)

    def validate(self) -> None:
        if self.lateral_clearance_m < 0:
            raise ScenarioError("junction.lateral_clearance_m must be >= 0")


@dataclass(frozen=True)
class JunctionSpec:
    """``[[junctions]]``: one SUMO junction of the network to control, with its own control zone,
    merging zone and coordinator (a corridor lists several; ``[junction] id`` is the one-junction
    shorthand). A vehicle leaving one junction's merging zone is handed to SUMO, and the next
    junction on its route admits it when it enters that junction's control zone; a control zone
    reaching back past the upstream junction's merging zone is cut there (summary.json
    ``control_zones_cut_m``)."""

    id: str = ""  # id of the SUMO junction (required)
    control_zone_m: float = 0.0  # its control zone [m], 20 or more; 0: zones.control_zone_m
    merging_zone_m: float = 0.0  # diameter of its merging zone [m]; 0: zones.merging_zone_m

    def validate(self) -> None:
        if not self.id:
            raise ScenarioError("every [[junctions]] entry needs an id (a junction of the network)")
        if self.control_zone_m < 0 or self.merging_zone_m < 0:
            raise ScenarioError(f"junctions.{self.id}: control_zone_m and merging_zone_m must be >= 0 (0: [zones])")
        if 0 < self.control_zone_m < MIN_CONTROL_ZONE_M:
            raise ScenarioError(f"junctions.{self.id}: control_zone_m = {self.control_zone_m:g} is shorter than the "
                                f"{MIN_CONTROL_ZONE_M:g} m a control zone needs: give {MIN_CONTROL_ZONE_M:g} or more "
                                "(0: zones.control_zone_m)")


@dataclass(frozen=True)
class Barriers:
    """``[barriers]``: the safety filter between tracker and plant (paper s. 3.2 and 4.2).

    The longitudinal barrier keeps the centre distance to the vehicle ahead on the same path at
    least ``d0 = min_gap_m + vehicle length`` (``min_gap_m`` is bumper to bumper: the paper's
    ``d0 = 5 m`` between point vehicles is ``min_gap_m = 0.2`` for 4.8 m cars).
    """

    longitudinal: bool = True  # the longitudinal barrier (QP on the acceleration)
    lateral: bool = True  # the lateral barrier (bisection on the steering)
    min_gap_m: float = 2.0  # bumper-to-bumper gap kept to the vehicle ahead
    max_braking_mps2: float = 3.0  # a_bar of the barrier (k = 1 / (2 a_bar))
    longitudinal_gain: float = 1.0  # kappa(h) = gain * h (paper: 1)
    root_smoothing_mps: float = 0.1  # c in sqrt(2 a_bar (r - d0) + c^2) - c (0: the exact root)
    max_lateral_dev_m: float = 0.5  # y_max (paper: 0.5 m)
    max_lateral_accel_mps2: float = 2.0  # a_tilde (k = 1 / (2 a_tilde))
    lateral_gamma: float = 15.0  # kappa(h) = gamma h^3 (paper: 15)
    bisection_tol_rad: float = 1e-6  # tolerance of the lateral barrier's bisection [rad]
    anti_windup: bool = True  # the tracker integrates from the applied (filtered) input
    qp_solver: str = "closed_form"  # or a qpsolvers backend, e.g. "osqp" (same QP, slower)
    gap_margin_m: float = 0.0  # added to d0 by the barrier (not to the figures): room for measurement error [m]
    lateral_margin_m: float = 0.0  # taken from y_max by the barrier, likewise [m]

    def validate(self) -> None:
        for k in ("max_braking_mps2", "longitudinal_gain", "max_lateral_dev_m", "max_lateral_accel_mps2",
                  "lateral_gamma", "bisection_tol_rad"):
            if getattr(self, k) <= 0:
                raise ScenarioError(f"barriers.{k} must be > 0")
        if self.min_gap_m < 0 or self.root_smoothing_mps < 0:
            raise ScenarioError("barriers.min_gap_m and barriers.root_smoothing_mps must be >= 0")
        if not (0 <= self.gap_margin_m < math.inf):
            raise ScenarioError(f"barriers.gap_margin_m must be >= 0, got {self.gap_margin_m!r}")
        if not (0 <= self.lateral_margin_m < self.max_lateral_dev_m):
            raise ScenarioError("barriers.lateral_margin_m must be >= 0 and below barriers.max_lateral_dev_m")
        if self.qp_solver != "closed_form":
            import qpsolvers

            if self.qp_solver not in qpsolvers.available_solvers:
                raise ScenarioError(
                    f"barriers.qp_solver {self.qp_solver!r} is not available; use 'closed_form' or one of "
                    f"{', '.join(qpsolvers.available_solvers)}"
                )


@dataclass(frozen=True)
class ListedVehicle:
    """``[[vehicles]]``: a vehicle with a given departure (besides the random demand).

    ``controlled = false`` leaves it to SUMO; ``speed_profile`` (pairs ``[t_s, v_mps]``, linear in
    between) then sets its speed every step.
    """

    id: str = ""  # vehicle id
    approach: str = ""  # its movement (junction) or approach name
    depart_s: float = 0.0  # departure time [s]
    depart_speed_mps: float = 13.4  # departure speed [m/s]
    depart_pos_m: float = -1.0  # front bumper on the first route edge; < 0: SUMO's "base"
    controlled: bool = True  # false: SUMO drives it
    entry_heading_offset_rad: float = 0.0  # heading error at admission (paper s. 4.2: 0.35)
    speed_profile: tuple = ()  # pairs [t_s, v_mps] for a SUMO-driven vehicle's speed

    def validate(self) -> None:
        if not self.id or not self.approach:
            raise ScenarioError("every [[vehicles]] entry needs an id and an approach")
        why = sumo_id_problem(self.id)
        if why:
            raise ScenarioError(f"vehicles: id {self.id!r}: {why}; choose another id")
        for pt in self.speed_profile:
            if not (isinstance(pt, (list, tuple)) and len(pt) == 2 and all(isinstance(v, (int, float)) for v in pt)):
                raise ScenarioError(f"vehicles.{self.id}.speed_profile must be a list of [t_s, v_mps] pairs")
            if not (0.0 <= pt[0] <= MAX_DURATION_S and 0.0 <= pt[1] <= 70.0):
                raise ScenarioError(f"vehicles.{self.id}.speed_profile: [{pt[0]:g}, {pt[1]:g}] is outside [0 to "
                                    f"{MAX_DURATION_S:g} s, 0 to 70 m/s]: give times and speeds in those ranges")
        ts = [pt[0] for pt in self.speed_profile]
        if ts != sorted(ts):
            raise ScenarioError(f"vehicles.{self.id}.speed_profile times must increase")
        if self.speed_profile and self.controlled:
            raise ScenarioError(f"vehicles.{self.id}.speed_profile drives only a vehicle SUMO drives: set "
                                "controlled = false, or leave the profile out (a controlled vehicle follows its plan)")


MIN_STALL_S = 30.0  # the shortest gridlock watchdog (outputs.stall_s) [s]


@dataclass(frozen=True)
class Outputs:
    """``[outputs]``: what the run directory holds."""

    trajectory_interval_s: float = 0.1  # log interval of trajectories.parquet (multiple of the SUMO step)
    sumo_tripinfo: bool = True  # SUMO's tripinfo.xml
    sumo_collisions: bool = True  # SUMO's collisions.xml
    sumo_fcd: bool = False  # SUMO's floating-car data of every vehicle (fcd.xml), e.g. for SUMO-driven leaders
    warmup_s: float = 0.0  # figures count the vehicles that entered the control zone from here on [s]
    measure_end_s: float = 0.0  # ... and up to here (0: the end of the run) [s]
    stall_s: float = 120.0  # a junction where no vehicle crossed for this long while vehicles in its control zone waited, or an entry lane from which none crossed while vehicles waited on it, stops the run as gridlocked (0: never; else >= 30 s, as crossing a control zone takes tens of seconds) [s]

    def validate(self) -> None:  # (trajectory_interval_s > 0: RANGES)
        if not (0 <= self.stall_s < math.inf):
            raise ScenarioError(f"outputs.stall_s must be >= 0 (0: no watchdog), got {self.stall_s!r}")
        if 0 < self.stall_s < MIN_STALL_S:
            raise ScenarioError(f"outputs.stall_s = {self.stall_s:g} s would take ordinary traffic for a gridlock (a "
                                f"car needs tens of seconds through a control zone, and waits for those ahead): give "
                                f"at least {MIN_STALL_S:g} s, or 0 for no watchdog")
        if self.warmup_s < 0 or self.measure_end_s < 0:
            raise ScenarioError("outputs.warmup_s and outputs.measure_end_s must be >= 0")
        if self.measure_end_s and self.measure_end_s <= self.warmup_s:
            raise ScenarioError(f"outputs.measure_end_s ({self.measure_end_s:g} s) must be after outputs.warmup_s "
                                f"({self.warmup_s:g} s): the measurement window would be empty or inverted; raise "
                                "outputs.measure_end_s, lower outputs.warmup_s, or set outputs.measure_end_s = 0 "
                                "for the end of the run (--duration)")


@dataclass(frozen=True)
class Disturbances:
    """``[disturbances]``: what the controller measures and commands is not what the vehicle is
    and does (docs/mixed-traffic.md, Robustness). The plant stays exact; the tracker and both barriers see the
    measured state. Noise is Gaussian, drawn afresh at every plant step from the run's seed; all
    zero (the default) is the undisturbed run."""

    position_noise_m: float = 0.0  # standard deviation on each of x, y (own and leader's) [m]
    speed_noise_mps: float = 0.0  # ... on each velocity component (own v_l, v_n; leader's) [m/s]
    heading_noise_rad: float = 0.0  # ... on the own heading psi [rad]
    actuator_lag_s: float = 0.0  # first-order lag on acceleration and steering (0: none) [s]
    observer_time_s: float = 0.0  # time constant of a state observer the controller sees (0: none) [s]
    longitudinal_accel_mps2: float = 0.0  # constant force on the plant along the body: grade, head wind
    lateral_accel_mps2: float = 0.0  # ... across it: cross wind, road camber [m/s^2]

    def validate(self) -> None:
        for k in ("position_noise_m", "speed_noise_mps", "heading_noise_rad", "actuator_lag_s",
                  "observer_time_s"):
            v = getattr(self, k)
            if not (0 <= v < math.inf):
                raise ScenarioError(f"disturbances.{k} must be >= 0, got {v!r}")
        # (the forces within +-5 m/s^2, a 50 % grade: RANGES)

    @property
    def noisy(self) -> bool:
        return self.position_noise_m > 0 or self.speed_noise_mps > 0 or self.heading_noise_rad > 0


_SECTIONS: dict[str, type] = {
    "scenario": General,
    "sumo": Sumo,
    "controller": Controller,
    "vehicle": Vehicle,
    "zones": Zones,
    "planning": PlanBounds,
    "coordinator": CoordinatorSettings,
    "demand": Demand,
    "human": HumanDriver,
    "junction": Junction,
    "barriers": Barriers,
    "disturbances": Disturbances,
    "outputs": Outputs,
}


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. ``base_dir`` resolves the relative paths in it."""

    general: General
    sumo: Sumo
    controller: Controller
    vehicle: Vehicle
    zones: Zones
    planning: PlanBounds
    coordinator: CoordinatorSettings
    demand: Demand
    human: HumanDriver
    junction: Junction
    barriers: Barriers
    disturbances: Disturbances
    outputs: Outputs
    approaches: tuple[Approach, ...]
    vehicles: tuple[ListedVehicle, ...]
    junctions: tuple[JunctionSpec, ...]
    base_dir: Path

    @property
    def network_path(self) -> Path:
        return (self.base_dir / self.general.network).resolve()

    def controlled_junctions(self) -> tuple[JunctionSpec, ...]:
        """The junctions to control, zones resolved: ``[[junctions]]``, or ``[junction] id``
        (none on a plain road of ``[[approaches]]``)."""
        z = self.zones
        specs = self.junctions or ((JunctionSpec(self.junction.id),) if self.junction.id else ())
        return tuple(JunctionSpec(j.id, j.control_zone_m or z.control_zone_m, j.merging_zone_m or z.merging_zone_m)
                     for j in specs)

    def to_dict(self) -> dict[str, Any]:
        """The full configuration as a TOML-ready dict (every default made explicit)."""
        out: dict[str, Any] = {}
        for key, cls in _SECTIONS.items():
            obj = getattr(self, _ATTR[key])
            d = {}
            for f in dataclasses.fields(obj):
                v = getattr(obj, f.name)
                if key == "vehicle" and f.name == "overrides":
                    d.update({k: float(x) for k, x in v.items()})
                    continue
                d[f.name] = _plain(v)
            out[key] = d
        def table(obj):
            return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}

        out["approaches"] = [table(a) for a in self.approaches]
        if self.junctions:
            out["junctions"] = [table(j) for j in self.junctions]
        if self.vehicles:
            out["vehicles"] = [table(v) for v in self.vehicles]
        return out


def _plain(v):
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    if dataclasses.is_dataclass(v):
        return {f.name: _plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
    return v


_ATTR = {"scenario": "general", "planning": "planning", "coordinator": "coordinator"}
for _k in _SECTIONS:
    _ATTR.setdefault(_k, _k)


def _coerce(section: str, key: str, typ, value):
    where = f"{section}.{key}"
    origin = getattr(typ, "__origin__", None)
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ScenarioError(f"{where} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ScenarioError(f"{where} must be finite, got {value!r}")
        return float(value)
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ScenarioError(f"{where} must be an integer, got {value!r}")
        return value
    if typ is bool:
        if not isinstance(value, bool):
            raise ScenarioError(f"{where} must be true or false, got {value!r}")
        return value
    if typ is str:
        if not isinstance(value, str):
            raise ScenarioError(f"{where} must be a string, got {value!r}")
        return value
    if origin is tuple:
        args = getattr(typ, "__args__", ())
        if args and dataclasses.is_dataclass(args[0]):  # an array of tables, e.g. [[demand.flows]]
            if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
                raise ScenarioError(f"{where} must be an array of tables ([[{where}]]), got {value!r}")
            return tuple(_section(where, args[0], v) for v in value)
        if not isinstance(value, list) or (args and args[0] is str and not all(isinstance(v, str) for v in value)):
            raise ScenarioError(f"{where} must be a list{' of strings' if args and args[0] is str else ''}, got {value!r}")
        return tuple(tuple(v) if isinstance(v, list) else v for v in value)
    if typ is tuple:
        if not isinstance(value, list):
            raise ScenarioError(f"{where} must be a list, got {value!r}")
        return tuple(tuple(v) if isinstance(v, list) else v for v in value)
    raise ScenarioError(f"{where}: unsupported type")  # pragma: no cover


@functools.lru_cache(maxsize=16)
def _euler_step_limit(params: tuple, v_max: float) -> tuple[float, float]:
    """:func:`nrtraffic.vehicle.bicycle.euler_step_limit`, once per vehicle and top speed."""
    import numpy as np

    from nrtraffic.vehicle.bicycle import euler_step_limit

    return euler_step_limit(np.array(params), v_max)


def top_speed(sc: "Scenario") -> float:
    """The vehicles' top speed [m/s]: ``planning.v_max_mps``, at least 1 m/s; their type's maxSpeed
    in SUMO (:mod:`nrtraffic.demand`)."""
    return max(sc.planning.v_max_mps, 1.0)


def plant_step_limit(sc: "Scenario") -> tuple[float, float]:
    """The longest stable ``controller.plant_step_s`` [s] for the scenario's vehicle over its speeds
    (up to :func:`top_speed`), and the speed [m/s] that sets it."""
    return _euler_step_limit(tuple(sc.vehicle.params().as_array()), top_speed(sc))


def _missing(path: Path) -> str:
    """Why ``path`` is no file to read: "not found", "is a folder", or "is not a regular file" (a
    device, a pipe or a socket, which would be read for ever or not at all)."""
    if not path.exists():  # (a link to nowhere too)
        return "not found"
    return "is a folder, not a file" if path.is_dir() else "is not a regular file (a device, pipe or socket)"


# the physically meaningful range [lo, hi] of every numeric key (inclusive; in the key's unit), checked
# before a section's own validate(), and given in the JSON Schema as minimum and maximum. Bounds on
# the work per simulated second (steps per step) are checked in Controller.validate and check_work.
_DAY_S = 86400.0
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "scenario": {"seed": (0, MAX_SEED), "duration_s": (0.0, MAX_DURATION_S), "begin_s": (0.0, 1e8)},
    "sumo": {"step_length_s": (0.001, 1.0), "lateral_resolution_m": (0.0, 5.0)},
    "controller": {"plant_step_s": (1e-4, 0.1), "predictor_step_s": (1e-4, 1.0), "horizon_s": (1e-3, 20.0),
                   "alpha": (1e-3, 1e5), "damping": (0.0, 1.0), "predictor_mass_factor": (0.2, 10.0),
                   "a_min_mps2": (-15.0, 0.0), "a_max_mps2": (0.0, 10.0), "steer_max_rad": (0.0, 1.2)},
    "zones": {"control_zone_m": (MIN_CONTROL_ZONE_M, 5000.0), "merging_zone_m": (0.0, 500.0)},
    "planning": {"v_min_mps": (0.0, 70.0), "v_max_mps": (0.0, 70.0), "u_min_mps2": (-15.0, 0.0),
                 "u_max_mps2": (0.0, 10.0), "max_lateral_accel_mps2": (0.0, 15.0)},
    "coordinator": {"rear_end_spacing_m": (0.0, 200.0), "min_merge_headway_s": (0.0, 3600.0),
                    "conflict_margin_s": (0.0, 60.0), "batch_window_s": (0.0, 600.0), "max_passed": (0, 1000),
                    "max_wait_s": (0.0, _DAY_S)},
    "demand": {"entry_speed_mps": (0.0, 70.0), "mean_headway_s": (0.0, _DAY_S), "rate_veh_h": (0.0, 20000.0),
               "turn_left": (0.0, 1.0), "turn_right": (0.0, 1.0), "min_headway_s": (0.0, 3600.0),
               "max_vehicles": (0, 10_000_000), "begin_s": (0.0, 366 * _DAY_S), "end_s": (0.0, 366 * _DAY_S),
               "controlled_share": (0.0, 1.0), "depart_offset_s": (0.0, 3600.0), "scale": (0.0, 100.0)},
    "demand.flows": {k: (0.0, 20000.0) for k in ("left", "straight", "right", "u_turn")},
    "demand.intervals": {"begin_s": (0.0, 366 * _DAY_S), "end_s": (0.0, 366 * _DAY_S), "scale": (0.0, 100.0)},
    "human": {"accel_mps2": (0.1, 10.0), "decel_mps2": (0.1, 15.0), "sigma": (0.0, 0.99), "tau_s": (0.01, 10.0),
              "min_gap_m": (0.0, 20.0), "speed_dev": (0.0, 0.5), "conflict_margin_s": (0.0, 60.0),
              "queue_reach_m": (0.0, 1000.0)},
    "junction": {"lateral_clearance_m": (0.0, 5.0)},
    "junctions": {"control_zone_m": (0.0, 5000.0), "merging_zone_m": (0.0, 500.0)},
    "barriers": {"min_gap_m": (0.0, 50.0), "max_braking_mps2": (0.1, 15.0), "longitudinal_gain": (1e-3, 1e3),
                 "root_smoothing_mps": (0.0, 10.0), "max_lateral_dev_m": (0.01, 5.0),
                 "max_lateral_accel_mps2": (0.1, 15.0), "lateral_gamma": (1e-3, 1e4), "bisection_tol_rad": (1e-12, 0.1),
                 "gap_margin_m": (0.0, 50.0), "lateral_margin_m": (0.0, 5.0)},
    "disturbances": {"position_noise_m": (0.0, 5.0), "speed_noise_mps": (0.0, 10.0), "heading_noise_rad": (0.0, 0.5),
                     "actuator_lag_s": (0.0, 2.0), "observer_time_s": (0.0, 10.0),
                     "longitudinal_accel_mps2": (-5.0, 5.0), "lateral_accel_mps2": (-5.0, 5.0)},
    "outputs": {"trajectory_interval_s": (0.0, 3600.0), "warmup_s": (0.0, 366 * _DAY_S),
                "measure_end_s": (0.0, 366 * _DAY_S), "stall_s": (0.0, 366 * _DAY_S)},
    "approaches": {"merge_entry_pos_m": (0.0, 1e5)},
    "vehicles": {"depart_s": (0.0, 366 * _DAY_S), "depart_speed_mps": (0.0, 70.0), "depart_pos_m": (-1.0, 1e5),
                 "entry_heading_offset_rad": (-math.pi, math.pi)},
}


# the bounds of RANGES that a key may not take itself (JSON Schema's exclusiveMinimum / exclusiveMaximum)
OPEN: dict[str, str] = {
    "controller.a_min_mps2": "max", "controller.a_max_mps2": "min", "controller.steer_max_rad": "min",
    "zones.merging_zone_m": "min", "planning.v_min_mps": "min", "planning.v_max_mps": "min",
    "planning.u_min_mps2": "max", "planning.u_max_mps2": "min", "demand.entry_speed_mps": "min",
    "human.speed_dev": "max", "outputs.trajectory_interval_s": "min",
}


def range_text(name: str, key: str) -> str:
    """``name.key``'s range as an interval: ``[lo, hi]``, with ``(`` or ``)`` at an open bound (:data:`OPEN`)."""
    lo, hi = RANGES[name][key]
    side = OPEN.get(f"{name}.{key}")
    return f"{'(' if side == 'min' else '['}{lo:g}, {hi:g}{')' if side == 'max' else ']'}"


def _check_ranges(name: str, values: dict) -> None:
    """Refuse a numeric key given outside its :data:`RANGES` (NaN and infinities too; an open
    bound of :data:`OPEN` itself too), naming it."""
    for key, (lo, hi) in RANGES.get(name, {}).items():
        v = values.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        side = OPEN.get(f"{name}.{key}")
        if not (lo <= v <= hi) or (side == "min" and v == lo) or (side == "max" and v == hi):
            raise ScenarioError(f"{name}.{key} = {v!r} is outside its range {range_text(name, key)}: give a value "
                                "in it")


def _section(name: str, cls, table) -> Any:
    if not isinstance(table, dict):
        raise ScenarioError(f"[{name}] must be a table")
    hints = get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    if cls is Vehicle:
        extra = {k: v for k, v in table.items() if k != "preset"}
        for k, v in extra.items():
            _coerce(name, k, float, v)
        kwargs["overrides"] = extra
        if "preset" in table:
            kwargs["preset"] = _coerce(name, "preset", str, table["preset"])
    else:
        for k, v in table.items():
            if k not in known:
                raise ScenarioError(f"unknown key {name}.{k}; known keys of [{name}]: {', '.join(sorted(known))}")
            kwargs[k] = _coerce(name, k, hints[k], v)
    _check_ranges(name, kwargs)
    try:
        obj = cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ScenarioError(f"[{name}]: {exc}") from None
    if hasattr(obj, "validate"):
        obj.validate()
    return obj


def parse_override(text: str) -> tuple[str, str, Any]:
    """``'section.key=value'`` -> (section, key, value); the value is read as TOML, else a string."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ScenarioError(f"--set expects section.key=value, got {text!r}")
    if "\n" in text or "\r" in text:  # (TOML read the next line as another setting, taken in silence)
        raise ScenarioError(f"--set {text!r}: a line break in it; give each setting as its own --set")
    lhs, rhs = text.split("=", 1)
    section, key = lhs.strip().split(".", 1)
    try:
        try:
            value = tomllib.loads(f"v = {rhs.strip()}")["v"]
        except RecursionError:
            raise ScenarioError(f"--set {text!r}: the value is nested too deeply") from None
    except tomllib.TOMLDecodeError:
        value = rhs.strip()
    return section, key, value


def _from_sumocfg(data: dict, base_dir: Path, allow_outside: bool) -> None:
    """``scenario.sumocfg``: the network (``net-file``), route files (``route-files``, as
    ``demand.sumo_routes`` where the scenario gives no demand of its own), ``begin`` (as
    ``scenario.begin_s``) and ``end`` (``scenario.duration_s`` = end - begin) of a SUMO configuration
    filled into ``data`` where it does not give them; its paths are relative to its own folder."""
    import os
    import xml.etree.ElementTree as ET

    name = data["scenario"]["sumocfg"]
    if not isinstance(name, str):
        raise ScenarioError("scenario.sumocfg must be a string (the path of a .sumocfg)")
    cfg = (base_dir / name).resolve()
    if not allow_outside and not cfg.is_relative_to(base_dir.resolve()):
        raise ScenarioError(f"scenario.sumocfg = {name!r} lies outside the scenario's folder (allowed only with "
                            "--allow-outside)")
    if not cfg.is_file():
        raise ScenarioError(f"scenario.sumocfg: file {_missing(cfg)}: {cfg}")
    try:
        root = ET.parse(cfg).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ScenarioError(f"scenario.sumocfg {name}: cannot be read as a SUMO configuration: {exc}") from None

    def value(*keys: str) -> str | None:
        for key in keys:
            el = next(root.iter(key), None)
            if el is not None and el.get("value") is not None:
                return el.get("value").strip()
        return None

    def rel(v: str) -> str:
        return Path(os.path.relpath(cfg.parent / v.strip(), base_dir.resolve())).as_posix()

    sc, demand = data["scenario"], data.setdefault("demand", {})
    net = value("net-file", "n")
    if net and "network" not in sc:
        sc["network"] = rel(net)
    routes = value("route-files", "r")
    if routes and "sumo_routes" not in demand and not demand.get("flows") and not demand.get("rate_veh_h"):
        demand["sumo_routes"] = ",".join(rel(r) for r in routes.split(",") if r.strip())
    for key, cfg_key in (("begin_s", "begin"), ("end", "end")):
        v = value(cfg_key, cfg_key[0])
        if v is None:
            continue
        try:
            t = sumo_time(v)
        except ValueError:
            raise ScenarioError(f"scenario.sumocfg {name}: <{cfg_key} value={v!r}> is not a time") from None
        if not math.isfinite(t) or (t < 0 and not (cfg_key == "end" and t == -1)):  # (SUMO's end -1: none)
            raise ScenarioError(f"scenario.sumocfg {name}: <{cfg_key} value={v!r}> is not a time of SUMO's clock")
        if cfg_key == "end" and t >= 0 and t <= float(sc.get("begin_s", 0.0)) and "duration_s" not in sc:
            raise ScenarioError(f"scenario.sumocfg {name}: <end value={v!r}> is not after the begin "
                                f"({float(sc.get('begin_s', 0.0)):g} s); mend it, or give scenario.duration_s")
        if key == "begin_s":
            sc.setdefault("begin_s", t)
        elif "duration_s" not in sc and t >= 0:
            sc["duration_s"] = max(t - float(sc.get("begin_s", 0.0)), 0.0)
            if sc["duration_s"] > MAX_DURATION_S:
                raise ScenarioError(f"scenario.sumocfg {name}: <end value={v!r}> makes a run of {sc['duration_s']:g} s, "
                                    f"longer than the longest run ({MAX_DURATION_S:g} s): give scenario.duration_s")


# what a run takes from a ``scenario.sumocfg`` (:func:`_from_sumocfg`), by SUMO's long and short names
SUMOCFG_TAKEN = frozenset({"net-file", "n", "route-files", "r", "begin", "b", "end", "e"})


def sumocfg_unused(cfg: Path) -> list[str]:
    """The options of the SUMO configuration ``cfg`` that a run does not take from it (all but
    :data:`SUMOCFG_TAKEN`): its additional files, processing and output options. [] where it cannot
    be read (the scenario check says why)."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(cfg).getroot()
    except (OSError, ET.ParseError):
        return []
    return sorted({el.tag for section in root for el in section if isinstance(el.tag, str)
                   and el.get("value") is not None and el.tag not in SUMOCFG_TAKEN})


def from_dict(data: dict, base_dir: Path, overrides: list[str] | tuple[str, ...] = (),
              allow_outside: bool = False) -> Scenario:
    """Validate a parsed scenario table (plus ``section.key=value`` overrides). The network must lie
    in ``base_dir`` or below, unless ``allow_outside``."""
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    for ov in overrides:
        section, key, value = parse_override(ov)
        if section not in _SECTIONS:
            raise ScenarioError(f"--set {ov!r}: unknown section {section!r}")
        data.setdefault(section, {})[key] = value
    if isinstance(data.get("scenario"), dict) and data["scenario"].get("sumocfg"):
        _from_sumocfg(data, Path(base_dir), allow_outside)
    unknown = set(data) - set(_SECTIONS) - {"approaches", "vehicles", "junctions"}
    if unknown:
        raise ScenarioError(
            f"unknown section(s) {', '.join(sorted(unknown))}; known: "
            f"{', '.join(sorted(list(_SECTIONS) + ['approaches', 'vehicles', 'junctions']))}"
        )
    at_junction = (isinstance(data.get("junction"), dict) and data["junction"].get("id")) or data.get("junctions")
    if at_junction and isinstance(data.get("coordinator", {}), dict) and "terminal_speed" not in data.get(
            "coordinator", {}):  # (a junction's default: the paper's free terminal speed collides there)
        data.setdefault("coordinator", {})["terminal_speed"] = "fixed"
    parts = {_ATTR[k]: _section(k, cls, data.get(k, {})) for k, cls in _SECTIONS.items()}
    jl = data.get("junctions", [])
    if not isinstance(jl, list):
        raise ScenarioError("[[junctions]] must be an array of tables")
    junctions = tuple(_section("junctions", JunctionSpec, j) for j in jl)
    jids = [j.id for j in junctions]
    if len(set(jids)) != len(jids):
        raise ScenarioError(f"[[junctions]] ids must be unique, got {jids}")
    if junctions and parts["junction"].id:
        raise ScenarioError("give the junctions to control either as [junction] id or as [[junctions]], not both")
    appr = data.get("approaches", [])
    if not isinstance(appr, list) or (not appr and not parts["junction"].id and not junctions):
        raise ScenarioError("a scenario needs [junction] id, [[junctions]] or at least one [[approaches]] entry")
    if appr and junctions:
        raise ScenarioError("[[approaches]] (a plain road) and [[junctions]] do not go together")
    approaches = tuple(_section("approaches", Approach, a) for a in appr)
    names = [a.name for a in approaches]
    if len(set(names)) != len(names):
        raise ScenarioError(f"approach names must be unique, got {names}")
    listed = data.get("vehicles", [])
    if not isinstance(listed, list):
        raise ScenarioError("[[vehicles]] must be an array of tables")
    vehicles = tuple(_section("vehicles", ListedVehicle, v) for v in listed)
    for v in vehicles:
        if v.approach not in names and not parts["junction"].id and not junctions:
            raise ScenarioError(f"vehicles.{v.id}.approach {v.approach!r} is not an approach ({', '.join(names)})")
    ids = [v.id for v in vehicles]
    if len(set(ids)) != len(ids):
        raise ScenarioError(f"[[vehicles]] ids must be unique, got {ids}")
    sc = Scenario(approaches=approaches, vehicles=vehicles, junctions=junctions, base_dir=Path(base_dir).resolve(),
                  **parts)
    if not allow_outside and not sc.network_path.is_relative_to(sc.base_dir):
        raise ScenarioError(f"scenario.network = {sc.general.network!r} lies outside the scenario's folder "
                            f"{sc.base_dir} (allowed only with --allow-outside)")
    if sc.demand.sumo_routes:
        if not sc.controlled_junctions():
            raise ScenarioError("demand.sumo_routes needs a [junction] id or [[junctions]] (its vehicles' crossings are "
                                "the movements of those junctions that their routes take)")
        files = sc.demand.route_files(sc.base_dir)
        twice = sorted({f.name for f in files if files.count(f) > 1})
        if twice:  # (its vehicles would all be there twice)
            raise ScenarioError(f"demand.sumo_routes names {twice[0]} twice: give each file once")
        for routes in files:
            if not allow_outside and not routes.is_relative_to(sc.base_dir):
                raise ScenarioError(f"demand.sumo_routes = {sc.demand.sumo_routes!r} lies outside the scenario's folder "
                                    f"{sc.base_dir} (allowed only with --allow-outside)")
            if not routes.is_file():
                raise ScenarioError(f"demand.sumo_routes: file {_missing(routes)}: {routes}")
        if sc.demand.flows or sc.demand.rate_veh_h > 0:
            raise ScenarioError("demand.sumo_routes replaces demand.flows and demand.rate_veh_h: give one of them")
    elif sc.demand.depart_offset_s > 0:
        raise ScenarioError("demand.depart_offset_s shifts the departures of demand.sumo_routes, and there is none: "
                            "leave it out (the random arrivals of rate_veh_h and flows differ by seed already)")
    elif sc.demand.scale != 1.0:
        raise ScenarioError("demand.scale scales the vehicles of demand.sumo_routes, and there is none: scale "
                            "demand.rate_veh_h or the flows themselves, or give a [[demand.intervals]] scale")
    if sc.demand.controlled_share < 1.0:
        if not sc.controlled_junctions():
            raise ScenarioError("demand.controlled_share < 1 needs a [junction] (human drivers stop at its "
                                "merging-zone entry)")
        if sc.coordinator.conflict_model != "conflict_points":
            raise ScenarioError('demand.controlled_share < 1 needs coordinator.conflict_model = "conflict_points" '
                                "(human drivers' crossings are reserved per conflict area)")
    if sc.controlled_junctions() and sc.coordinator.terminal_speed == "free":
        raise ScenarioError('coordinator.terminal_speed = "free" at a junction lets a held-back car cross its merging '
                            "zone slower than its reservation, and the cars after it run into it: use \"fixed\" (the "
                            "default at a junction), or leave the key out")
    if sc.network_path.is_dir():
        raise ScenarioError(f"scenario.network = {sc.general.network!r} is a folder, not a network file: name the "
                            ".net.xml file in it")
    if not sc.network_path.is_file():
        raise ScenarioError(f"network file {_missing(sc.network_path)}: {sc.network_path} (scenario.network = "
                            f"{sc.general.network!r})")
    try:  # (the tracker's predictor model: the vehicle with its mass scaled)
        sc.vehicle.params().with_mass_factor(sc.controller.predictor_mass_factor)
    except ValueError as exc:
        raise ScenarioError(f"controller.predictor_mass_factor = {sc.controller.predictor_mass_factor:g} gives the "
                            f"predictor a vehicle out of range ({exc}): choose a factor that keeps its mass in "
                            "range") from None
    if sc.controller.plant_step_s > sc.sumo.step_length_s:
        raise ScenarioError("controller.plant_step_s must not exceed sumo.step_length_s")
    ratio = sc.sumo.step_length_s / sc.controller.plant_step_s
    if abs(ratio - round(ratio)) > 1e-9:
        raise ScenarioError("sumo.step_length_s must be a whole multiple of controller.plant_step_s")
    if ratio > MAX_PLANT_STEPS_PER_STEP + 1e-9:
        raise ScenarioError(f"sumo.step_length_s / controller.plant_step_s = {ratio:.0f} plant steps per SUMO step, "
                            f"more than {MAX_PLANT_STEPS_PER_STEP}: raise controller.plant_step_s")
    v_top = top_speed(sc)
    h_max, v_at = plant_step_limit(sc)
    if sc.controller.plant_step_s > h_max:
        need = (f"controller.plant_step_s = {sc.controller.plant_step_s:g} s is too long for the plant's forward-Euler "
                f"step: this vehicle's lateral and yaw modes at {v_at:.2f} m/s need {h_max:.3g} s or less, or the "
                "plant is integrated unstably")
        shortest = max(RANGES["controller"]["plant_step_s"][0], sc.sumo.step_length_s / MAX_PLANT_STEPS_PER_STEP)
        if h_max < shortest:
            raise ScenarioError(f"{need}; that is below the shortest plant step allowed ({shortest:g} s): the tyres "
                                "(vehicle.Caf, vehicle.Car) are far too stiff for the vehicle's mass and yaw inertia "
                                "(vehicle.m, vehicle.Iz) and axle distances (vehicle.lf, vehicle.lr): check them")
        for n in range(math.ceil(sc.sumo.step_length_s / h_max - 1e-9), MAX_PLANT_STEPS_PER_STEP + 1):
            if abs(sc.sumo.step_length_s / n * 1e6 - round(sc.sumo.step_length_s / n * 1e6)) <= 1e-6:
                raise ScenarioError(f"{need}: set it to {sc.sumo.step_length_s / n:.4g} (sumo.step_length_s / {n}) "
                                    "or less")  # (the first whole divisor of the SUMO step with at most six decimals)
        raise ScenarioError(f"{need}: set it to a whole divisor of sumo.step_length_s of {h_max:.3g} s or less")
    speeds = [("demand.entry_speed_mps", sc.demand.entry_speed_mps)] + [
        (f"vehicles.{v.id}.depart_speed_mps", v.depart_speed_mps) for v in sc.vehicles]
    for where, v in speeds:
        if v > v_top + 1e-9:
            raise ScenarioError(f"{where} = {v:g} m/s is faster than the vehicles' top speed, planning.v_max_mps = "
                                f"{sc.planning.v_max_mps:g} m/s (SUMO refuses to insert them): lower it, or raise "
                                "planning.v_max_mps")
    c = sc.controller
    work = c.horizon_s / c.predictor_step_s / c.plant_step_s
    if work > MAX_PREDICTOR_STEPS_PER_S * (1 + 1e-9):
        raise ScenarioError(f"controller: {work:.3g} predictor steps per simulated second and vehicle "
                            f"(horizon_s / predictor_step_s / plant_step_s), more than {MAX_PREDICTOR_STEPS_PER_S:.0e}: "
                            "raise controller.predictor_step_s or controller.plant_step_s, or shorten horizon_s")
    obs = sc.disturbances.observer_time_s
    if 0 < obs < sc.controller.plant_step_s:
        raise ScenarioError(f"disturbances.observer_time_s ({obs:g} s) must be 0 (no observer) or at least "
                            f"controller.plant_step_s ({sc.controller.plant_step_s:g} s)")
    ratio = sc.outputs.trajectory_interval_s / sc.sumo.step_length_s
    if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
        raise ScenarioError(f"outputs.trajectory_interval_s ({sc.outputs.trajectory_interval_s:g} s) must be a whole "
                            f"multiple of sumo.step_length_s ({sc.sumo.step_length_s:g} s)")
    return sc


def load(path: str | Path, overrides: list[str] | tuple[str, ...] = (), allow_outside: bool = False) -> Scenario:
    """Read and validate a scenario file. Files it names (the network) must lie in its folder or
    below, unless ``allow_outside``.

    Raises
    ------
    ScenarioError : with a message naming the file and the offending key.
    """
    if not isinstance(path, (str, Path)) and not hasattr(path, "__fspath__"):
        raise ScenarioError(f"scenario {path!r}: give the path of a scenario.toml, or of the folder holding it")
    path = Path(path)
    if path.is_dir():
        path = path / "scenario.toml"
    if not path.is_file():
        raise ScenarioError(f"scenario file {_missing(path)}: {path}")
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8-sig"))  # (past a byte-order mark: some editors write one)
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: not a UTF-8 text file (byte {exc.start}): a scenario is TOML text") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot be read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ScenarioError(f"{path}: arrays or inline tables nested too deeply to read") from None
    try:
        return from_dict(data, path.parent, overrides, allow_outside=allow_outside)
    except ScenarioError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    except RecursionError:
        raise ScenarioError(f"{path}: a value nested too deeply (a scenario's values are numbers, strings and "
                            "flat lists)") from None


def dumps(sc: Scenario, network: str | None = None, sumo_routes: str | None = None) -> str:
    """The resolved configuration as TOML text; ``network`` and ``sumo_routes`` replace the paths
    of the network and the route files (copies placed beside the file). ``scenario.sumocfg`` is
    left out: what it gave is in the other keys."""
    import tomli_w

    d = sc.to_dict()
    d["scenario"].pop("sumocfg", None)
    if network is not None:
        d["scenario"]["network"] = network
    if sumo_routes is not None:
        d["demand"]["sumo_routes"] = sumo_routes
    return tomli_w.dumps(d)


def dump(sc: Scenario, path: Path, network: str | None = None, sumo_routes: str | None = None) -> None:
    """Write the resolved configuration (``scenario.resolved.toml``), see :func:`dumps`."""
    path.write_text(dumps(sc, network, sumo_routes))
