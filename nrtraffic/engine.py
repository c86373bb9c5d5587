"""The co-simulation's tick: SUMO + coordinator + profiles + NR-flow tracking + barriers + plant.

Each SUMO step (``sumo.step_length_s``), at time ``t`` with SUMO and the embedded models in step,
:meth:`Engine._tick` runs, in this order:

1. **read SUMO**: the vehicles SUMO inserted get their record (``waiting`` -> ``approaching``, or
   SUMO-driven); one batched read of every vehicle (:meth:`SumoSession.snapshot`); the zone
   crossings of the vehicles SUMO drives; human drivers at their stop lines;
2. **each junction decides**: reserved starts from rest that have come; the vehicles whose centre
   of gravity crossed a control-zone entry are scheduled (coordinator -> merge time ->
   energy-optimal profile), batched or held (:class:`~nrtraffic.junction.admission.Admission`);
   controlled vehicles that would enter their merging zone late stop before it and, standing,
   have their start reserved again (:class:`~nrtraffic.junction.late.LateGuard`);
3. **measure**: every controlled vehicle's leader on its path (a late one's: its merging-zone
   entry, where that is nearer); the own collision check; the trajectory log;
4. **advance** the controlled vehicles to ``t + dt`` in the compiled kernel (tracker, barriers,
   plant sub-steps; :class:`~nrtraffic.control.kernel.Kernel`);
5. **write to SUMO**: their poses (``moveToXY``); vehicles past the merging zone released to
   SUMO, or handed to the next junction of their trip;
6. **step** SUMO, and read its collisions.

The states a vehicle passes through are :mod:`nrtraffic.lifecycle`'s; the junctions are built
from the network by :mod:`nrtraffic.junction.build`, the demand by :mod:`nrtraffic.demand`, and the
figures are computed from the records by :mod:`nrtraffic.results`.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from nrtraffic import __version__, measure, metrics
from nrtraffic.control import batch as kb
from nrtraffic.control.kernel import Kernel
from nrtraffic.background import Background
from nrtraffic.demand import Demand
from nrtraffic.junction import Layout, build, humans
from nrtraffic.junction.admission import Admission
from nrtraffic.junction.late import LateGuard
from nrtraffic.lifecycle import State
from nrtraffic.measure import LEADER_LOOKAHEAD_M
from nrtraffic.planning.coordinator import Coordinator
from nrtraffic.results import (RunFacts, RunResult, TrajectoryWriter, approach_table, movements_of, parse_queues,
                               read_tripinfo, round_frame, round_summary, run_summary, vehicle_table)
from nrtraffic.state import RunState
from nrtraffic.watchdog import Gridlock, OpenEnd, watch_junctions
from nrtraffic.sumo.adapter import SumoSession, VehicleType, handover_tau_s, sumo_version, write_sumocfg
from nrtraffic.sumo.network import NetworkError

CHECKPOINT_WALL_S = 10.0  # wall time between checkpoints of the figures (``checkpoint``) [s]
GUI_MARGIN_M = 50.0  # sumo-gui opens on the merging zones with this much road around them [m]
# parts of the tick timed for ``wall_time_breakdown_s``: the compiled kernel (with the Python that
# reads its results), SUMO's step (with its collision list), reading and writing SUMO's vehicles,
# admission (coordinator; its rear-end QPs also as ``qp``), leader search, the own collision check,
# and trajectory logging
WALL_PHASES = ("kernel", "sumo_step", "sumo_io", "admission", "qp", "leaders", "collision_check", "logging")


def _interrupt_in(exc: BaseException) -> BaseException | None:
    """The Ctrl-C or SIGTERM behind ``exc``, if any: one that arrives while a compiled (numba)
    function runs surfaces as that function's SystemError, with the interrupt as its context."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


class SignalStop(KeyboardInterrupt):
    """The signal (SIGTERM, SIGINT) that stopped the run, by its name, where its own interrupt was
    lost in a library that swallowed it (:class:`Engine`'s ``stop_requested``): the run's error
    names that signal, never Ctrl-C's KeyboardInterrupt for a SIGTERM."""


def describe(error: BaseException) -> str:
    """``error`` as a run's summary and the command say it: its type and message, or the signal
    alone for a :class:`SignalStop`."""
    return f"stopped by {error}" if isinstance(error, SignalStop) else f"{type(error).__name__}: {error}"


class RunFailed(RuntimeError):
    """A run stopped early; ``result`` holds what was finished."""

    def __init__(self, message: str, result: RunResult):
        super().__init__(message)
        self.result = result


class _Laps:
    """Wall time between successive calls, added to the named phase [s]."""

    def __init__(self, totals: dict):
        self.totals, self.last = totals, time.perf_counter()

    def __call__(self, phase: str) -> float:
        now = time.perf_counter()
        self.totals[phase] += now - self.last
        self.last = now
        return now


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
    signalised : whether the junctions are signals, for the HCM thresholds of level of service
        (default: by ``label``, :func:`~nrtraffic.metrics.is_signalised`; an ``as_is`` baseline
        says it from its network).
    additional : further SUMO additional files (a baseline's coordinated signal offsets).
    stop_requested : called every ten steps; a name it returns (a signal that came) stops the run as
        Ctrl-C does, where the interrupt itself was lost (raised inside a compiled library).
    checkpoint : called with the figures so far (a :class:`RunResult` whose summary says
        ``"status": "running"``) about every ``CHECKPOINT_WALL_S`` seconds of wall time, so that a
        run killed outright leaves its last checkpoint on disk. Wall-clock timing only decides
        when files are written, never what is simulated.
    """

    def __init__(self, scenario, workdir: Path, seed: int | None = None, duration_s: float | None = None,
                 trajectories: TrajectoryWriter | None = None, progress: bool = False, control: bool = True,
                 network: Path | None = None, label: str = "nrtraffic", checkpoint=None, gui: bool = False,
                 additional: tuple = (), signalised: bool | None = None, gui_delay_ms: float = 100.0,
                 stop_requested=None):
        self.sc = scenario
        self.stop_requested = stop_requested
        self.additional = tuple(additional)
        self.control = control
        self.network_path = Path(network) if network is not None else scenario.network_path
        self.label = label
        self.signalised = metrics.is_signalised(label) if signalised is None else bool(signalised)
        self.checkpoint = checkpoint
        self.gui = gui
        self.gui_delay_ms = gui_delay_ms
        self.seed = scenario.general.seed if seed is None else int(seed)
        self.duration = scenario.general.duration_s if duration_s is None else float(duration_s)
        self.workdir = Path(workdir)
        self.traj = trajectories
        self.progress = progress
        self.params = scenario.vehicle.params()
        self.kernel = Kernel(scenario, self.params, self.seed)
        c = scenario.coordinator  # SUMO's headway for the vehicles it gets back (handover_tau_s)
        self.handover_tau = handover_tau_s(c.rear_end_spacing_m, c.min_merge_headway_s, self.params.length,
                                           VehicleType.min_gap_m, scenario.planning.v_max_mps,
                                           scenario.sumo.step_length_s)
        self.layout: Layout | None = None
        self.demand: Demand | None = None
        self.st: RunState | None = None
        self.admission: Admission | None = None
        self.background: Background | None = None  # (made once the junctions' paths are built)
        self.zone_cuts: dict[str, float] = {}  # movement -> its control zone's length where it was cut [m]
        self.collisions_sumo: set[tuple[str, str]] = set()
        self.collisions_geometric: set[tuple[str, str]] = set()
        self.collision_log: list[dict] = []  # first contact of each pair: time, ids, who saw it
        # wall time per part of the tick [s] (summary.json ``wall_time_breakdown_s``; benchmarks)
        self.wall_breakdown = dict.fromkeys(WALL_PHASES, 0.0)
        self._open_end = OpenEnd()  # (a run without a duration) the watch that it can end

    @property
    def t(self) -> float:
        """Simulated time [s]."""
        return self.st.t if self.st is not None else 0.0

    def build_demand(self) -> Demand:
        """The junctions as the network file gives them, and the run's demand (SUMO not started)."""
        self.layout = Layout(self.sc, self.network_path)
        self.demand = Demand(self.sc, self.layout, self.seed, self.duration)
        return self.demand

    def write_demand(self, path: Path) -> list[tuple]:
        """The run's departures as a SUMO route file (:meth:`Demand.write`); returns them."""
        return self.build_demand().write(path, self.params)

    # ------------------------------------------------------------------ run
    def run(self) -> RunResult:
        """Run the simulation; returns a :class:`RunResult` or raises :class:`RunFailed` (with the
        partial result) when SUMO or a component fails mid-run, and
        :class:`~nrtraffic.sumo.network.NetworkError` when the junction and its zones do not suit
        (found once SUMO has read the network, before anything is simulated)."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        sdir = self.workdir / "sumo"
        sdir.mkdir(exist_ok=True)
        self.wall0 = time.perf_counter()
        error = None
        try:
            routes = sdir / "routes.rou.xml"
            departures = self.write_demand(routes)
            self.layout.drop_unused_uturns(self.demand.used_movements())
            self.st = st = RunState(self.sc, self.params, self.layout, self.control, kernel=self.kernel,
                                    itineraries=self.demand.itineraries)
            self.admission = Admission(st, {vid: (mv, t, speed) for vid, mv, t, speed, *_ in departures},
                                       {v[0] for v in departures if v[5] == "human"},
                                       {v.id: v for v in self.sc.vehicles}, self.demand.paced)
            st.mixed = bool(self.admission.human_ids) and self.control
            self.late = LateGuard(st, self.admission)
            copy = sdir / self.network_path.name  # the run directory's own copy, where there is one
            write_sumocfg(sdir / "run.sumocfg", copy if copy.is_file() else self.network_path, routes,
                          self.sc.sumo.step_length_s, self.sc.general.begin_s)
            o = self.sc.outputs
            detectors = build.queue_detectors(self.sc, self.layout, self.network_path, self.workdir, sdir,
                                              self.additional)
            st.sumo = SumoSession(
                self.network_path, routes, self.sc.sumo.step_length_s, self.seed, self.sc.sumo.lateral_resolution_m,
                tripinfo=self.workdir / "tripinfo.xml" if o.sumo_tripinfo else None,
                collisions=self.workdir / "collisions.xml" if o.sumo_collisions else None,
                fcd=self.workdir / "fcd.xml" if o.sumo_fcd else None,
                extra_args=self.sc.sumo.extra_args + detectors, gui=self.gui, begin_s=self.sc.general.begin_s,
                gui_delay_ms=self.gui_delay_ms)
            with st.sumo:
                self._build_junctions(st)
                self.background = Background(self.demand, st)
                if self.gui:
                    self._show_junctions()
                self._loop()
        except NetworkError:
            if self.traj is not None:
                self.traj.close()
            raise
        except (Exception, KeyboardInterrupt) as exc:  # keep what was finished
            error = _interrupt_in(exc) or exc
        wall = time.perf_counter() - self.wall0
        if self.traj is not None:
            try:
                self.traj.close()
            except Exception as exc:  # noqa: BLE001 - a full disk, say: the figures below are still returned
                error = error or exc
        result = self._result(wall, error)
        if error is not None:
            raise RunFailed(f"run stopped at t={self.t:.2f} s: {describe(error)}", result) from error
        return result

    def _build_junctions(self, st: RunState) -> None:
        """Paths, zones, relations, conflict areas and stop lines of every junction, once SUMO has
        read the network; ``movements.json``; a coordinator per junction. Raises NetworkError when
        a junction or its zones do not suit (nothing is simulated then)."""
        try:
            st.paths, self.zone_cuts = build.build_paths(self.sc, self.layout, st.sumo, self.params, self.control)
            self.kernel.pack_paths(st.paths)
            v_max = self.sc.planning.v_max_mps
            self.relations, st.conflict_areas = build.relations(
                self.layout.junctions, st.paths, self.params, self.sc.junction.lateral_clearance_m,
                lambda m, s: self.kernel.crossing_headings(m, min(m.v_limit, v_max), s),
                bool(self.admission.human_ids) and self.control)
            # where vehicles stop before they cross: human drivers, cars queued behind them, and cars
            # with no merge time yet (Admission.hold)
            if self.control:
                st.stop_line = build.stop_lines(st.paths, st.conflict_areas, self.layout.junctions, self.params)
        except ValueError as exc:  # the junction or its zones do not suit: nothing was run
            raise NetworkError(f"{self.sc.general.name}: {exc}") from None
        build.write_movements(self.workdir / "movements.json", st.paths, self.layout.junctions, self.relations,
                              st.conflict_areas)
        for j in self.layout.junctions.values():
            j.coord = Coordinator(self.sc.coordinator, self.sc.planning, j.relations, areas=j.conflict_areas,
                                  human_margin_s=self.sc.human.conflict_margin_s)

    def _show_junctions(self) -> None:
        """sumo-gui opens on the controlled junctions: their merging zones with ``GUI_MARGIN_M``
        around them (a plain road: the network as sumo-gui opens it); says on stderr what it shows."""
        centres = [(j.xy, j.merging_zone_m / 2.0) for j in self.layout.junctions.values() if j.xy is not None]
        if not centres:
            return
        box = self.st.sumo.show(min(x - r for (x, _), r in centres) - GUI_MARGIN_M,
                                min(y - r for (_, y), r in centres) - GUI_MARGIN_M,
                                max(x + r for (x, _), r in centres) + GUI_MARGIN_M,
                                max(y + r for (_, y), r in centres) + GUI_MARGIN_M)
        print(f"sumo-gui: showing {', '.join(self.layout.junctions)} (x {box[0]:.0f} to {box[2]:.0f} m, "
              f"y {box[1]:.0f} to {box[3]:.0f} m), {self.gui_delay_ms:g} ms delay per step", file=sys.stderr, flush=True)

    def _loop(self) -> None:
        """Tick until the duration is reached (or, with none, until every vehicle has left), with
        progress and checkpoints."""
        from tqdm import tqdm

        st, sc = self.st, self.sc
        dt = sc.sumo.step_length_s
        log_every = max(1, int(round(sc.outputs.trajectory_interval_s / dt)))
        total = self.duration if self.duration > 0 else None
        fmt = ("{l_bar}{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]" if total
               else "{desc}: {n:.0f} sim s [{elapsed}, {rate_fmt}]")
        bar = tqdm(total=total, desc=sc.general.name, unit="sim s", disable=None if self.progress else True,
                   leave=False, bar_format=fmt)
        plain_progress = bool(self.progress and total and not sys.stderr.isatty())
        next_report = 0.1 * total if total else math.inf
        next_checkpoint = time.perf_counter() + CHECKPOINT_WALL_S
        step = 0
        try:
            while True:
                st.t = st.sumo.time
                if self.duration > 0 and st.t >= self.duration - 1e-9:
                    break
                if self.duration <= 0 and st.t > 0 and st.sumo.pending() == 0 and not self.kernel.table.ids:
                    break  # (with a duration the run goes on to it, as SUMO's --end: every control's window alike)
                now = self._tick(dt, step % log_every == 0, step % 10 == 0)
                if step % 10 == 0:
                    watch_junctions(st, self.admission)
                    if self.duration <= 0:
                        self._open_end.watch(st)
                    stop = self.stop_requested() if self.stop_requested is not None else None
                    if stop:  # (a library the signal came into may have swallowed its interrupt)
                        raise SignalStop(stop)
                step += 1
                bar.update(dt)
                if plain_progress and st.t + dt >= next_report:  # not a terminal: a line every 10 %
                    print(f"{sc.general.name}: {st.t + dt:.0f}/{total:.0f} sim s "
                          f"({100 * (st.t + dt) / total:.0f} %), {now - self.wall0:.0f} s wall",
                          file=sys.stderr, flush=True)
                    next_report += 0.1 * total
                if self.checkpoint is not None and now >= next_checkpoint:
                    if self.traj is not None:
                        self.traj.flush()
                    self.checkpoint(self._result(now - self.wall0, None, final=False))
                    next_checkpoint = time.perf_counter() + CHECKPOINT_WALL_S
            st.t = st.sumo.time
            for vid in st.sumo.departed():  # (inserted in the last step: in the run, not waiting to enter)
                self.admission.depart(vid, dt)
        finally:
            bar.close()

    def _tick(self, dt: float, log: bool, forget: bool) -> float:
        """One SUMO step of the run (the module's docstring gives the order); returns the wall
        clock at its end."""
        st, sumo, adm = self.st, self.st.sumo, self.admission
        lap = _Laps(self.wall_breakdown)
        # 1. read SUMO
        for vid in sumo.departed():
            adm.depart(vid, dt)
            self.background.departed(vid)
        st.snap = sumo.snapshot()
        driven = measure.track_sumo_driven(st, dt, adm.next_leg)
        if adm.human_ids:
            humans.step(st, adm.blocked_ahead)
        lap("sumo_io")
        # 2. each junction decides
        adm.step(dt)
        self.late.step()
        lap("admission")
        # 3. measure
        measure.leaders(st, driven)
        self.late.close_gates()
        lap("leaders")
        measure.collisions_geometric(st, self.collisions_geometric, self.collision_log)
        lap("collision_check")
        if log:
            self._log()
        if forget:
            self._forget_far()
        lap("logging")
        # 4. advance the controlled vehicles
        for i, k, t_cross in self.kernel.advance(st.t, dt):
            rec = st.records[self.kernel.table.ids[i]]
            if k == 0 and math.isnan(rec.t_merge_actual):
                rec.t_merge_actual = t_cross
            elif k == 1 and math.isnan(rec.t_exit):
                rec.t_exit = t_cross
                st.junctions[rec.junction].left_zone(rec.lane, st.t)
        lap("kernel")
        # 5. write to SUMO
        self._push_and_release()
        if adm.listed:
            self._script(st.t + dt)
        lap("sumo_io")
        # 6. step SUMO
        sumo.step()
        for a, b, kind in sumo.collisions():
            pair = tuple(sorted((a, b)))
            if pair not in self.collisions_sumo:
                self.collisions_sumo.add(pair)
                self.collision_log.append({"t": sumo.time, "pair": list(pair), "source": f"sumo:{kind}"})
        return lap("sumo_step")

    # ------------------------------------------------------------------ what the tick composes
    def _push_and_release(self) -> None:
        """The controlled vehicles' poses to SUMO; those past their merging zone released to SUMO
        (or handed to the next junction of their trip), those SUMO no longer lists lost."""
        st, ctl = self.st, self.kernel.table
        if not ctl.ids:
            return
        lost = ctl.rows < 0  # left SUMO's network (rare); rows found by measure.leaders this step
        keep = ~lost
        fx, fy, psi, speed = self.kernel.front_poses()
        if keep.all():
            st.sumo.push_poses(ctl.ids, fx, fy, psi, speed)
        else:
            st.sumo.push_poses([v for v, k in zip(ctl.ids, keep) if k], fx[keep], fy[keep], psi[keep], speed[keep])
        done = keep & (ctl.out[:, kb.OUT_S] >= ctl.s_zone[:, 1])
        gone = lost | done
        if not gone.any():
            return
        for i in gone.nonzero()[0].tolist():
            vid = ctl.ids[i]
            st.records[vid].acc = ctl.acc[i].copy()
            if done[i]:
                st.sumo.release(vid, self.handover_tau)
                st.life.move(vid, State.RELEASED)
                st.sumo.colour(vid, "released")
                self.admission.next_leg(vid)  # (a corridor: on to the next junction)
            else:
                st.life.move(vid, State.LOST)
        ctl.keep(~gone)

    def _forget_far(self) -> None:
        """Released vehicles more than ``LEADER_LOOKAHEAD_M`` along their last lane can be nobody's
        leader any more: every controlled vehicle is still before its merging-zone exit, a few metres
        into that lane, and a single lane keeps its order. They leave the batched read (``gone``),
        which then grows with the traffic near the junction, not with the length of the exit roads
        (SUMO's own collision check still covers them)."""
        st, tab = self.st, self.st.snap
        self.background.forget_past(st)
        for vid in st.life.members(State.RELEASED):
            k = tab.row.get(vid)
            if k is None:  # it left the network
                st.life.move(vid, State.GONE)
                continue
            if tab.lane[k] == st.paths[st.records[vid].movement].lanes[-1] and tab.lane_pos[k] > LEADER_LOOKAHEAD_M:
                st.sumo.forget(vid)
                st.life.move(vid, State.GONE)

    def _script(self, t_next: float) -> None:
        """SUMO-driven vehicles with a speed profile: the desired speed for the next step."""
        st = self.st
        for vid in st.life.members(State.SUMO):
            if st.records[vid].speed_profile:
                prof = np.asarray(st.records[vid].speed_profile, dtype=float)
                st.sumo.hold_speed(vid, float(np.interp(t_next, prof[:, 0], prof[:, 1])))

    def _log(self) -> None:
        ctl = self.kernel.table
        if self.traj is None or not ctl.ids:
            return
        s_c = np.array([self.st.paths[self.st.records[v].movement].s_control for v in ctl.ids])
        self.traj.append(**self.kernel.log_columns(self.st.t, s_c))

    # ------------------------------------------------------------------ results
    def _result(self, wall: float, error: BaseException | None, final: bool = True) -> RunResult:
        """The figures so far; ``final`` false for a checkpoint of a run still going (status
        "running", no SUMO timeLoss yet)."""
        st = self.st
        records = dict(st.records) if st is not None else {}
        ctl = self.kernel.table
        for i, vid in enumerate(ctl.ids):
            records[vid].acc = ctl.acc[i].copy()
        trips = (read_tripinfo(self.workdir / "tripinfo.xml") if final and self.sc.outputs.sumo_tripinfo else {})
        crossings = st.crossings if st is not None else []
        veh = vehicle_table(crossings + list(records.values()), st.paths if st is not None else {}, trips,
                            self.control)
        o = self.sc.outputs
        junctions = self.layout.junctions if self.layout is not None else {}
        facts = RunFacts(
            scenario=self.sc.general.name, label=self.label, signalised=self.signalised, seed=self.seed,
            sim_time_s=float(self.t),
            wall_time_s=wall, warmup_s=o.warmup_s, measure_end_s=o.measure_end_s, control=self.control,
            barriers=(self.sc.barriers.longitudinal, self.sc.barriers.lateral),
            collisions_sumo=self.collisions_sumo, collisions_geometric=self.collisions_geometric,
            collision_log=self.collision_log, zone_cuts=self.zone_cuts, junctions=junctions,
            zone_crossing_s=self._zone_crossing_s(),
            waiting_to_enter=self._waiting_to_enter(),
            vehicles_spawned=sum(r.status != "waiting" for r in records.values()),
            drivers={r.vehicle_id: r.driver for r in records.values()},
            wall_breakdown=self.wall_breakdown, versions=(__version__, sumo_version()),
            begin_s=self.sc.general.begin_s, notes=tuple(self.demand.notes) if self.demand is not None else ())
        status = ("ok" if error is None else "gridlock" if isinstance(error, Gridlock) else "failed") \
            if final else "running"
        demand = self.demand.demand_veh_h if self.demand is not None else None  # (None: stopped while it was built)
        summary = run_summary(facts, veh, trips, demand, status, error)
        # every table from the same unrounded records, then each figure to its resolution
        extra = {"movements": round_frame(movements_of(veh, summary, self.workdir / "movements.json"))}
        if final and self.sc.controlled_junctions() and self.demand is not None:
            queues = parse_queues(self.workdir / "queues.xml", t0_s=self.sc.general.begin_s)
            extra["approaches"] = round_frame(approach_table(veh, queues, self.layout.approaches,
                                                             self.demand.demand_veh_h, summary["measure_from_s"],
                                                             summary["measure_to_s"]))
            extra["queues"] = queues
        return RunResult(round_summary(summary), round_frame(veh), self.workdir, extra)

    def _waiting_to_enter(self) -> list[tuple[float, str]]:
        """(desired departure [s], junction of its first crossing) of each vehicle of the demand
        that SUMO has not inserted yet."""
        if self.admission is None or self.st is None:
            return []
        where = self.layout.movement_junction
        return [(t, where.get(self.demand.legs(trip)[0], ""))
                for trip, t, _ in self.admission.scheduled.values()]

    def _zone_crossing_s(self) -> float:
        """The time a car needs to cross the longest control zone of the run at the speed limit
        (the fastest movement's lowest limit), the zone as it was built (cut where it reached back
        past where routes start) [s]; 0 before the paths are known."""
        st, out = self.st, 0.0
        if st is None or self.layout is None:
            return out
        for j in self.layout.junctions.values():
            paths = [st.paths[m] for m in j.movements if m in st.paths]
            v = max((p.v_limit for p in paths), default=math.inf)
            if 0 < v < math.inf:
                out = max(out, max(p.s_merge - p.s_control for p in paths) / v)
        return out
