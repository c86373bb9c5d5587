"""The co-simulation loop: SUMO + coordinator + profiles + NR-flow tracking + plant.

Per SUMO step (``sumo.step_length_s``): vehicles SUMO inserted drive at the entry speed until their
centre of gravity crosses the control-zone entry; then they are admitted (coordinator -> merge time
-> energy-optimal profile -> reference on their lane path), advanced through the plant sub-steps by
the compiled kernel, and their poses pushed to SUMO. After the merging zone they are handed back to
SUMO. The loop composes the pieces; the maths lives in ``vehicle``, ``control``, ``planning`` and
``geometry``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from nrtraffic import __version__, metrics
from nrtraffic.control.batch import (ACC_ENERGY, ACC_FUEL, ACC_MAX_ABS_A, ACC_MAX_ERR, ACC_MAX_ERR_STEADY,
                                     ACC_MAX_ERR_TRANSIENT, ACC_MAX_LAT, N_ACC, advance)
from nrtraffic.demand import shifted_exponential_arrivals
from nrtraffic.geometry import LanePath
from nrtraffic.planning.coordinator import Coordinator, ScheduleInfeasible
from nrtraffic.results import VEHICLE_COLUMNS, RunResult, TrajectoryWriter
from nrtraffic.scenario import Scenario
from nrtraffic.sumo.adapter import SumoSession, VehicleType, sumo_version, write_routes

N_PROFILE_SEG = 5  # packed profile segments (at most 3 arcs + cruise, padded)
STEADY_AFTER_S = 3.0
PATH_SPACING_M = 0.25  # sampling of the smoothed lane paths [m]  # DESIGN.md: steady-state tracking error counts after 3 s under control


class RunFailed(RuntimeError):
    """A run stopped early; ``result`` holds what was finished."""

    def __init__(self, message: str, result: RunResult):
        super().__init__(message)
        self.result = result


@dataclass
class ApproachPath:
    """An approach's lane path and its zone boundaries (arc length of the centre of gravity) [m]."""

    name: str
    route: tuple[str, ...]
    path: LanePath
    lane_offset: dict  # lane id -> (s at lane start, shape length / SUMO length)
    s_control: float
    s_merge: float
    s_exit: float

    def s_of(self, lane: str, pos: float) -> float:
        off, scale = self.lane_offset[lane]
        return off + pos * scale


@dataclass
class VehicleRecord:
    vehicle_id: str
    approach: str
    t_depart: float
    status: str = "waiting"  # waiting -> approaching -> controlled -> released | lost
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
    acc: np.ndarray = field(default_factory=lambda: np.zeros(N_ACC))
    min_gap: float = math.inf
    min_center: float = math.inf
    s_last: float = math.nan


class Engine:
    """One co-simulation run.

    Parameters
    ----------
    scenario : validated scenario.
    seed : random seed (arrivals and SUMO's ``--seed``); default the scenario's.
    duration_s : simulated time [s]; default the scenario's (0: until every vehicle has left).
    workdir : where SUMO's inputs (``sumo/``) and outputs are written.
    trajectories : optional streaming writer for per-step vehicle rows.
    progress : show a progress bar.
    """

    def __init__(self, scenario: Scenario, workdir: Path, seed: int | None = None, duration_s: float | None = None,
                 trajectories: TrajectoryWriter | None = None, progress: bool = False):
        self.sc = scenario
        self.seed = scenario.general.seed if seed is None else int(seed)
        self.duration = scenario.general.duration_s if duration_s is None else float(duration_s)
        self.workdir = Path(workdir)
        self.traj = trajectories
        self.progress = progress
        self.params = scenario.vehicle.params()
        c = scenario.controller
        self.plant_p = self.params.as_array()
        self.pred_p = self.params.with_mass_factor(c.predictor_mass_factor).as_array()
        self.u_lo = np.array([c.a_min_mps2, -c.steer_max_rad])
        self.u_hi = np.array([c.a_max_mps2, c.steer_max_rad])
        self.n_sub = int(round(scenario.sumo.step_length_s / c.plant_step_s))
        self.records: dict[str, VehicleRecord] = {}
        self.collision_pairs: set[tuple[str, str]] = set()
        self.geometric_collisions: set[tuple[str, str]] = set()

    # ------------------------------------------------------------------ set-up
    def _demand(self) -> list[tuple[str, str, float, float]]:
        d = self.sc.demand
        rng = np.random.default_rng(self.seed)
        end = d.end_s if d.end_s > 0 else (self.duration if self.duration > 0 else math.inf)
        if d.max_vehicles == 0 and not math.isfinite(end):
            raise ValueError("demand needs demand.max_vehicles, demand.end_s or scenario.duration_s")
        veh = []
        for a in self.sc.approaches:
            times = shifted_exponential_arrivals(rng, d.begin_s, end, d.mean_headway_s, d.min_headway_s, d.max_vehicles)
            veh += [(f"{a.name}.{k}", a.name, float(t), d.entry_speed_mps) for k, t in enumerate(times)]
        veh.sort(key=lambda v: v[2])
        return veh

    def _paths(self, sumo: SumoSession) -> dict[str, ApproachPath]:
        out = {}
        z = self.sc.zones
        for a in self.sc.approaches:
            lanes = sumo.route_lanes(a.route)
            pts = [pt for _, shape, _ in lanes for pt in shape]
            path = LanePath.from_points(pts, smooth_spacing=PATH_SPACING_M)
            # arc length of each lane's start on the (smoothed) path; lane positions scale linearly
            starts = [path.project(shape[0])[0] for _, shape, _ in lanes] + [path.length]
            offsets = {lane: (starts[k], (starts[k + 1] - starts[k]) / length if length > 0 else 1.0)
                       for k, (lane, _, length) in enumerate(lanes)}
            lane_m = f"{a.merge_entry_edge}_0"
            s_m = offsets[lane_m][0] + a.merge_entry_pos_m * offsets[lane_m][1]
            s_c = s_m - z.control_zone_m
            if s_c < self.params.length:
                raise ValueError(
                    f"approach {a.name}: the control zone starts {s_c:.1f} m into the route; vehicles need "
                    f"room to be inserted before it (lengthen the route or move merge_entry_pos_m)"
                )
            if s_m + z.merging_zone_m > path.length:
                raise ValueError(f"approach {a.name}: the merging zone runs past the end of the route")
            out[a.name] = ApproachPath(a.name, a.route, path, offsets, s_c, s_m, s_m + z.merging_zone_m)
        return out

    # ------------------------------------------------------------------ run
    def run(self) -> RunResult:
        """Run the simulation; returns a :class:`RunResult` or raises :class:`RunFailed` (with the
        partial result) when SUMO or a component fails mid-run."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        sdir = self.workdir / "sumo"
        sdir.mkdir(exist_ok=True)
        p = self.params
        vtype = VehicleType(length_m=p.length, width_m=p.width, max_speed_mps=max(self.sc.planning.v_max_mps, 1.0))
        demand = self._demand()
        for vid, appr, t, _ in demand:
            self.records[vid] = VehicleRecord(vid, appr, t)
        routes = sdir / "routes.rou.xml"
        write_routes(routes, vtype, {a.name: a.route for a in self.sc.approaches}, demand)
        o = self.sc.outputs
        self.sumo = SumoSession(
            self.sc.network_path, routes, self.sc.sumo.step_length_s, self.seed, self.sc.sumo.lateral_resolution_m,
            tripinfo=self.workdir / "tripinfo.xml" if o.sumo_tripinfo else None,
            collisions=self.workdir / "collisions.xml" if o.sumo_collisions else None,
            extra_args=self.sc.sumo.extra_args,
        )
        self.coord = Coordinator(self.sc.coordinator, self.sc.planning)
        wall0 = time.perf_counter()
        error = None
        self.t = 0.0
        try:
            with self.sumo:
                self.paths = self._paths(self.sumo)
                self._loop()
        except (Exception, KeyboardInterrupt) as exc:  # keep what was finished
            error = exc
        wall = time.perf_counter() - wall0
        if self.traj is not None:
            self.traj.close()
        result = self._result(wall, error)
        if error is not None:
            raise RunFailed(f"run stopped at t={self.t:.2f} s: {type(error).__name__}: {error}", result) from error
        return result

    def _loop(self) -> None:
        from tqdm import tqdm

        sc = self.sc
        dt = sc.sumo.step_length_s
        log_every = max(1, int(round(sc.outputs.trajectory_interval_s / dt)))
        self.batch_ids: list[str] = []
        self._alloc(0)
        approaching: list[str] = []
        step = 0
        total = self.duration if self.duration > 0 else None
        fmt = ("{l_bar}{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]" if total
               else "{desc}: {n:.0f} sim s [{elapsed}, {rate_fmt}]")
        bar = tqdm(total=total, desc=self.sc.general.name, unit="sim s", disable=not self.progress, leave=False,
                   bar_format=fmt)
        try:
            while True:
                self.t = self.sumo.time
                if self.duration > 0 and self.t >= self.duration - 1e-9:
                    break
                if self.t > 0 and self.sumo.pending() == 0 and not self.batch_ids:
                    break
                for vid in self.sumo.departed():
                    rec = self.records.get(vid)
                    if rec is not None:
                        rec.status = "approaching"
                        self.sumo.hold_speed(vid, sc.demand.entry_speed_mps)
                        approaching.append(vid)
                for vid in list(approaching):
                    if self._try_admit(vid):
                        approaching.remove(vid)
                self._advance(dt)
                self._gaps()
                if step % log_every == 0:
                    self._log()
                self._push_and_release()
                self.sumo.step()
                for a, b, _ in self.sumo.collisions():
                    self.collision_pairs.add(tuple(sorted((a, b))))
                step += 1
                bar.update(dt)
            self.t = self.sumo.time
        finally:
            bar.close()

    # ------------------------------------------------------------------ batch arrays
    def _alloc(self, n: int) -> None:
        self.X = np.zeros((n, 6))
        self.U = np.zeros((n, 2))
        self.prof = np.zeros((n, N_PROFILE_SEG, 5))
        self.t_enter = np.zeros(n)
        self.s_enter = np.zeros(n)
        self.path_id = np.zeros(n, dtype=np.int64)
        self.hint = np.zeros(n, dtype=np.int64)
        self.acc = np.zeros((n, N_ACC))
        self.out_s = np.zeros(n)
        self.out_lat = np.zeros(n)
        self.out_ref = np.zeros((n, 2))
        self.out_err = np.zeros(n)
        self.gap = np.full(n, np.nan)
        self.center = np.full(n, np.nan)
        names = list(self.paths) if hasattr(self, "paths") else []
        self.path_names = names
        if names:
            xy = [self.paths[k].path.xy for k in names]
            self.path_off = np.concatenate([[0], np.cumsum([len(a) for a in xy])]).astype(np.int64)
            self.path_xy = np.ascontiguousarray(np.concatenate(xy))
            self.path_s = np.ascontiguousarray(np.concatenate([self.paths[k].path.s for k in names]))

    def _append(self, vid, x0, prof, t0, s0, pid, hint) -> None:
        self.batch_ids.append(vid)
        self.X = np.vstack([self.X, x0[None]])
        self.U = np.vstack([self.U, np.zeros((1, 2))])
        self.prof = np.concatenate([self.prof, prof[None]])
        self.t_enter = np.append(self.t_enter, t0)
        self.s_enter = np.append(self.s_enter, s0)
        self.path_id = np.append(self.path_id, pid)
        self.hint = np.append(self.hint, hint)
        self.acc = np.vstack([self.acc, np.zeros((1, N_ACC))])
        for name in ("out_s", "out_lat", "out_err"):
            setattr(self, name, np.append(getattr(self, name), 0.0))
        self.out_s[-1] = s0
        self.out_ref = np.vstack([self.out_ref, np.zeros((1, 2))])
        self.gap = np.append(self.gap, np.nan)
        self.center = np.append(self.center, np.nan)

    def _remove(self, keep: np.ndarray) -> None:
        self.batch_ids = [v for v, k in zip(self.batch_ids, keep) if k]
        for name in ("X", "U", "prof", "t_enter", "s_enter", "path_id", "hint", "acc", "out_s", "out_lat", "out_ref",
                     "out_err", "gap", "center"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name)[keep]))

    # ------------------------------------------------------------------ steps
    def _try_admit(self, vid: str) -> bool:
        rec = self.records[vid]
        ap = self.paths[rec.approach]
        lane, pos = self.sumo.lane_position(vid)
        if lane not in ap.lane_offset:
            return False
        s_cg = ap.s_of(lane, pos) - self.params.cg_to_front
        if s_cg < ap.s_control:
            return False
        xf, yf, psi = self.sumo.front_pose(vid)
        v = self.sumo.speed(vid)
        cg = self.params.cg_to_front
        x0 = np.array([xf - cg * math.cos(psi), yf - cg * math.sin(psi), v, 0.0, psi, 0.0])
        s_proj, _ = ap.path.project(x0[:2])
        D = ap.s_merge - s_proj
        try:
            asg = self.coord.schedule(vid, rec.approach, self.t, v, D)
        except ScheduleInfeasible:
            rec.status = "infeasible"
            raise
        rec.status = "controlled"
        rec.t_enter, rec.v_enter, rec.s_enter = self.t, v, s_proj
        rec.t_merge_planned, rec.v_merge_planned = asg.t_merge, asg.profile.v_m
        rec.predecessor, rec.relation, rec.binding = asg.predecessor, asg.relation, asg.binding
        rec.profile_kind = asg.profile.kind
        rec.s_last = s_proj
        hint = int(np.clip(np.searchsorted(ap.path.s, s_proj) - 1, 0, len(ap.path.s) - 2))
        self._append(vid, x0, asg.profile.packed(N_PROFILE_SEG), self.t, s_proj, self.path_names.index(rec.approach), hint)
        return True

    def _advance(self, dt: float) -> None:
        if not self.batch_ids:
            return
        c = self.sc.controller
        advance(self.X, self.U, self.t, self.n_sub, c.plant_step_s, self.plant_p, self.pred_p, c.horizon_s,
                c.predictor_step_s, c.alpha, c.damping, self.u_lo, self.u_hi, self.prof, self.t_enter, self.s_enter,
                self.path_id, self.path_off, self.path_xy, self.path_s, self.hint, STEADY_AFTER_S, self.acc,
                self.out_s, self.out_lat, self.out_ref, self.out_err)
        if not np.all(np.isfinite(self.X)):
            bad = [v for v, ok in zip(self.batch_ids, np.isfinite(self.X).all(axis=1)) if not ok]
            raise FloatingPointError(f"vehicle state became non-finite at t={self.t:.2f} s: {', '.join(bad)}")
        t1 = self.t + dt
        for i, vid in enumerate(self.batch_ids):
            rec = self.records[vid]
            ap = self.paths[rec.approach]
            s_prev, s_new = rec.s_last, self.out_s[i]
            if math.isnan(rec.t_merge_actual) and s_new >= ap.s_merge > s_prev:
                rec.t_merge_actual = self.t + dt * (ap.s_merge - s_prev) / (s_new - s_prev)
            if math.isnan(rec.t_exit) and s_new >= ap.s_exit > s_prev:
                rec.t_exit = self.t + dt * (ap.s_exit - s_prev) / (s_new - s_prev)
            rec.s_last = s_new
        self.t_next = t1

    def _gaps(self) -> None:
        """Centre distance and bumper gap [m] of each controlled vehicle to the vehicle ahead on its
        path (controlled or SUMO-driven)."""
        if not self.batch_ids:
            return
        p = self.params
        pos = {}  # approach -> list of (s_cg, x, y, vid)
        ctrl = set(self.batch_ids)
        for i, vid in enumerate(self.batch_ids):
            rec = self.records[vid]
            pos.setdefault(rec.approach, []).append((self.out_s[i], self.X[i, 0], self.X[i, 1], vid))
        for vid in self.sumo.vehicle_ids():
            if vid in ctrl:
                continue
            rec = self.records.get(vid)
            if rec is None or rec.approach not in pos:
                continue
            ap = self.paths[rec.approach]
            lane, lp = self.sumo.lane_position(vid)
            if lane not in ap.lane_offset:
                continue
            xf, yf, psi = self.sumo.front_pose(vid)
            pos[rec.approach].append((ap.s_of(lane, lp) - p.cg_to_front, xf - p.cg_to_front * math.cos(psi),
                                      yf - p.cg_to_front * math.sin(psi), vid))
        index = {v: i for i, v in enumerate(self.batch_ids)}
        for lst in pos.values():
            lst.sort()
            for k in range(len(lst) - 1):
                s, x, y, vid = lst[k]
                if vid not in index:
                    continue
                s2, x2, y2, vid2 = lst[k + 1]
                gap = s2 - s - p.length  # same vehicle type: rear of leader minus front of follower
                centre = math.hypot(x2 - x, y2 - y)
                i = index[vid]
                self.gap[i], self.center[i] = gap, centre
                rec = self.records[vid]
                rec.min_gap = min(rec.min_gap, gap)
                rec.min_center = min(rec.min_center, centre)
                if gap < 0.0:
                    self.geometric_collisions.add(tuple(sorted((vid, vid2))))

    def _log(self) -> None:
        if self.traj is None or not self.batch_ids:
            return
        X, U = self.X, self.U
        t1 = getattr(self, "t_next", self.t)
        ref_s = np.array([self.s_enter[i] + 0.0 for i in range(len(self.batch_ids))])
        for i, vid in enumerate(self.batch_ids):
            seg = self.prof[i]
            tau = t1 - self.t_enter[i]
            k = int(np.searchsorted(seg[:, 0], tau, side="right") - 1)
            k = max(k, 0)
            d = tau - seg[k, 0]
            ref_s[i] += seg[k, 1] + seg[k, 2] * d + seg[k, 3] * d * d / 2 + seg[k, 4] * d**3 / 6
        s_c = np.array([self.paths[self.records[v].approach].s_control for v in self.batch_ids])
        self.traj.append(
            t=np.full(len(self.batch_ids), t1), vehicle_id=list(self.batch_ids), s_m=self.out_s - s_c,
            x=X[:, 0], y=X[:, 1], v_l=X[:, 2], v_n=X[:, 3], psi=X[:, 4], psi_dot=X[:, 5], a_cmd=U[:, 0],
            delta_cmd=U[:, 1], ref_x=self.out_ref[:, 0], ref_y=self.out_ref[:, 1], ref_s_m=ref_s - s_c,
            tracking_error_m=self.out_err, lateral_dev_m=self.out_lat, center_distance_m=self.center,
            bumper_gap_m=self.gap,
        )

    def _push_and_release(self) -> None:
        if not self.batch_ids:
            return
        cg = self.params.cg_to_front
        keep = np.ones(len(self.batch_ids), dtype=bool)
        live = set(self.sumo.vehicle_ids())
        for i, vid in enumerate(self.batch_ids):
            rec = self.records[vid]
            if vid not in live:
                rec.status = "lost"
                keep[i] = False
                continue
            x, y, vl, vn, psi = self.X[i, :5]
            self.sumo.push_pose(vid, x + cg * math.cos(psi), y + cg * math.sin(psi), psi, math.hypot(vl, vn))
            if self.out_s[i] >= self.paths[rec.approach].s_exit:
                self.sumo.release(vid)
                rec.status = "released"
                keep[i] = False
        for i, vid in enumerate(self.batch_ids):
            if not keep[i]:
                self.records[vid].acc = self.acc[i].copy()
        if not keep.all():
            self._remove(keep)

    # ------------------------------------------------------------------ results
    def _result(self, wall: float, error: BaseException | None) -> RunResult:
        for i, vid in enumerate(getattr(self, "batch_ids", [])):
            self.records[vid].acc = self.acc[i].copy()
        rows = []
        for rec in self.records.values():
            if rec.status == "waiting":
                continue
            ap = getattr(self, "paths", {}).get(rec.approach)
            delay = math.nan
            if ap is not None and not math.isnan(rec.t_exit):
                delay = float(metrics.free_flow_delay(rec.t_enter, rec.t_exit, ap.s_exit - rec.s_enter, rec.v_enter))
            admitted = not math.isnan(rec.t_enter)
            a = rec.acc
            rows.append({
                "vehicle_id": rec.vehicle_id, "approach": rec.approach, "movement": "through",
                "t_enter_s": rec.t_enter, "v_enter_mps": rec.v_enter, "t_merge_planned_s": rec.t_merge_planned,
                "t_merge_actual_s": rec.t_merge_actual, "t_exit_s": rec.t_exit, "delay_s": delay,
                "max_tracking_error_m": a[ACC_MAX_ERR] if admitted else math.nan,
                "steady_tracking_error_m": a[ACC_MAX_ERR_STEADY] if admitted else math.nan,
                "transient_tracking_error_m": a[ACC_MAX_ERR_TRANSIENT] if admitted else math.nan,
                "max_lateral_dev_m": a[ACC_MAX_LAT] if admitted else math.nan,
                "min_bumper_gap_m": rec.min_gap if math.isfinite(rec.min_gap) else math.nan,
                "energy_u2": a[ACC_ENERGY] if admitted else math.nan,
                "fuel_ml": a[ACC_FUEL] if admitted else math.nan,
                "predecessor": rec.predecessor or "", "relation": rec.relation, "binding": rec.binding,
                "profile": rec.profile_kind, "v_merge_planned_mps": rec.v_merge_planned,
                "min_center_distance_m": rec.min_center if math.isfinite(rec.min_center) else math.nan,
                "max_abs_accel_mps2": a[ACC_MAX_ABS_A] if admitted else math.nan,
                "status": rec.status,
            })
        veh = pd.DataFrame(rows, columns=VEHICLE_COLUMNS)
        adm = veh[veh["t_enter_s"].notna()]
        done = veh[veh["t_exit_s"].notna()]
        sim_t = float(self.t)
        summary = {
            "scenario": self.sc.general.name,
            "seed": self.seed,
            "status": "ok" if error is None else "failed",
            "error": None if error is None else f"{type(error).__name__}: {error}",
            "sim_time_s": sim_t,
            "wall_time_s": wall,
            "real_time_factor": sim_t / wall if wall > 0 else None,
            "vehicles_spawned": int((veh["status"] != "waiting").sum()),
            "vehicles_admitted": int(len(adm)),
            "vehicles_completed": int(len(done)),
            "throughput_veh_h": len(done) / sim_t * 3600.0 if sim_t > 0 else None,
            "mean_delay_s": metrics.mean_or_none(done["delay_s"]),
            "p95_delay_s": metrics.percentile_or_none(done["delay_s"], 95),
            "collisions": len(self.collision_pairs),
            "collisions_geometric": len(self.geometric_collisions),
            "min_center_distance_m": metrics.min_or_none(adm["min_center_distance_m"]),
            "min_bumper_gap_m": metrics.min_or_none(adm["min_bumper_gap_m"]),
            "max_tracking_error_m": metrics.max_or_none(adm["max_tracking_error_m"]),
            "steady_tracking_error_m": metrics.max_or_none(adm["steady_tracking_error_m"]),
            "transient_tracking_error_m": metrics.max_or_none(adm["transient_tracking_error_m"]),
            "max_lateral_dev_m": metrics.max_or_none(adm["max_lateral_dev_m"]),
            "max_abs_accel_mps2": metrics.max_or_none(adm["max_abs_accel_mps2"]),
            "mean_energy_u2": metrics.mean_or_none(done["energy_u2"]),
            "mean_fuel_ml": metrics.mean_or_none(done["fuel_ml"]),
            "nrtraffic_version": __version__,
            "sumo_version": sumo_version(),
        }
        return RunResult(summary, veh, self.workdir)
