"""The controlled vehicles and the compiled kernel that drives them (pure: no SUMO, no I/O).

:class:`Kernel` holds the kernel's configuration (from the scenario's ``[controller]``, ``[barriers]``
and ``[disturbances]``), the paths packed as the kernel reads them, the measurement noise stream
and the :class:`~nrtraffic.control.table.ControlledTable`. :meth:`Kernel.advance` moves every
controlled vehicle one SUMO step through the plant sub-steps (the tracker of eqs. 11-16 with the
barriers, on the bicycle model of eq. 1).
"""

from __future__ import annotations

import math

import numpy as np

from nrtraffic.control import batch as kb
from nrtraffic.control.leaders import pack_path_lanes
from nrtraffic.control.nr_flow import PREDICTORS
from nrtraffic.control.table import N_PROFILE_SEG, ControlledTable
from nrtraffic.geometry import segment_frames
from nrtraffic.planning.profiles import packed_position

STEADY_AFTER_S = 3.0  # DESIGN.md: steady-state tracking error counts after 3 s under control


def kernel_config(sc, params) -> np.ndarray:
    """The kernel's configuration vector (``kb.CFG_*``) from a scenario and its vehicle's
    parameters. Sets the rear-end QP backend (``kb.QP_SOLVER``) when it is not the closed form."""
    c, b, dist = sc.controller, sc.barriers, sc.disturbances
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
    cfg[kb.CFG_D0] = b.min_gap_m + params.length + b.gap_margin_m
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
    cfg[kb.CFG_LAG_TAU] = dist.actuator_lag_s
    cfg[kb.CFG_FORCE_LONG] = dist.longitudinal_accel_mps2
    cfg[kb.CFG_FORCE_LAT] = dist.lateral_accel_mps2
    cfg[kb.CFG_OBSERVER_TAU] = dist.observer_time_s
    return cfg


class Kernel:
    """The vehicles under control and what the kernel needs to drive them.

    Parameters
    ----------
    sc : the scenario (``[controller]``, ``[barriers]``, ``[disturbances]``, ``sumo.step_length_s``).
    params : the controlled vehicle's :class:`~nrtraffic.vehicle.params.VehicleParams`.
    seed : the run's seed; the measurement noise has its own stream of it.
    """

    def __init__(self, sc, params, seed: int):
        c = sc.controller
        self.params = params
        self.plant_p = params.as_array()
        self.pred_p = params.with_mass_factor(c.predictor_mass_factor).as_array()
        self.u_lo = np.array([c.a_min_mps2, -c.steer_max_rad])
        self.u_hi = np.array([c.a_max_mps2, c.steer_max_rad])
        self.step_s = sc.sumo.step_length_s
        self.n_sub = int(round(sc.sumo.step_length_s / c.plant_step_s))
        self.cfg = kernel_config(sc, params)
        # measurement noise: its own stream of the run's seed (arrivals are drawn from another), one
        # draw per controlled vehicle and plant step in the order of the batch
        dist = sc.disturbances
        self.noise_sd = np.zeros(kb.N_NOISE)  # standard deviation of each column of the noise
        self.noise_sd[[kb.NZ_X, kb.NZ_Y, kb.NZ_LX, kb.NZ_LY]] = dist.position_noise_m
        self.noise_sd[[kb.NZ_VL, kb.NZ_VN, kb.NZ_LVX, kb.NZ_LVY]] = dist.speed_noise_mps
        self.noise_sd[kb.NZ_PSI] = dist.heading_noise_rad
        self.noise_rng = np.random.default_rng([seed, 0x6E6F697365]) if dist.noisy else None
        self.table = ControlledTable()

    def pack_paths(self, paths: dict) -> None:
        """The movements' paths (name -> :class:`~nrtraffic.junction.Movement`) packed for the
        kernel and the leader search; ``path_index`` gives each movement's path id."""
        self.path_names = list(paths)
        self.path_index = {k: i for i, k in enumerate(self.path_names)}
        xy = [paths[k].path.xy for k in self.path_names]
        self.path_off = np.concatenate([[0], np.cumsum([len(a) for a in xy])]).astype(np.int64)
        self.path_xy = np.ascontiguousarray(np.concatenate(xy))
        self.path_s = np.ascontiguousarray(np.concatenate([paths[k].path.s for k in self.path_names]))
        self.path_frames = np.ascontiguousarray(np.concatenate(
            [segment_frames(paths[k].path.xy, paths[k].path.s) for k in self.path_names]))
        # the lanes of the paths, for the leader search
        self.lane_index, self.pl_off, self.pl_lane, self.pl_start, self.pl_scale = pack_path_lanes(
            [paths[k] for k in self.path_names])

    def take(self, vid: str, x0, packed_profile, t: float, s0: float, lat0: float, m, acc_carried,
             t_merge: float = math.inf, again: bool = False) -> None:
        """Take vehicle ``vid`` under control at time ``t`` [s]: state ``x0``, packed profile from
        arc length ``s0`` [m] of movement ``m``'s path, lateral offset ``lat0`` [m], planned
        merging-zone entry ``t_merge`` [s]; its energy and fuel so far (``acc_carried``, while SUMO
        drove it in the control zone) carry over. ``again``: it was under control before
        (:mod:`nrtraffic.junction.late`): all its figures carry over."""
        hint = int(np.clip(np.searchsorted(m.path.s, s0) - 1, 0, len(m.path.s) - 2))
        self.table.append(vid, x0, packed_profile, t, s0, lat0, m.path.xy_at(s0), self.path_index[m.name], hint,
                          (m.s_merge, m.s_exit), t_merge)
        if again:
            self.table.acc[-1] = acc_carried
            return
        for k in (kb.ACC_ENERGY, kb.ACC_FUEL):
            self.table.acc[-1, k] = acc_carried[k]

    def advance(self, t: float, dt: float) -> list[tuple[int, int, float]]:
        """Advance every controlled vehicle from ``t`` to ``t + dt`` [s]; returns the zone
        boundaries crossed in the step: ``(row, 0 merging-zone entry | 1 exit, time [s])``, the time
        interpolated within the step. Raises FloatingPointError on a non-finite state."""
        ctl = self.table
        if not ctl.ids:
            return []
        n = len(ctl.ids)
        if self.noise_rng is None:
            noise = np.zeros((n, self.n_sub, 0))
        else:
            noise = self.noise_rng.standard_normal((n, self.n_sub, kb.N_NOISE)) * self.noise_sd
        kb.advance(ctl.X, ctl.U, t, self.n_sub, self.cfg, self.plant_p, self.pred_p, self.u_lo, self.u_hi,
                   ctl.prof, ctl.t_enter, ctl.s_enter, ctl.path_id, self.path_off, self.path_xy, self.path_s,
                   self.path_frames, ctl.hint, ctl.lead_idx, ctl.lead_ext, ctl.acc, ctl.out, noise, ctl.act, ctl.xe,
                   ctl.gate)
        if not math.isfinite(float(ctl.X.sum())):  # a NaN or an infinity anywhere makes the sum one
            bad = [v for v, ok in zip(ctl.ids, np.isfinite(ctl.X).all(axis=1)) if not ok]
            raise FloatingPointError(f"vehicle state became non-finite at t={t:.2f} s: {', '.join(bad)}")
        s_prev, s_new = ctl.s_last, ctl.out[:, kb.OUT_S]
        crossed = []
        for i in np.flatnonzero(s_new >= ctl.s_zone[:, 0]):
            for k in (0, 1):
                if s_new[i] >= ctl.s_zone[i, k] > s_prev[i]:
                    crossed.append((int(i), k, t + dt * (ctl.s_zone[i, k] - s_prev[i]) / (s_new[i] - s_prev[i])))
        ctl.s_last[:] = s_new
        return crossed

    def front_poses(self):
        """Front-bumper position (x, y) [m], heading [rad] and speed [m/s] of every controlled vehicle."""
        X, cg = self.table.X, self.params.cg_to_front
        return (X[:, 0] + cg * np.cos(X[:, 4]), X[:, 1] + cg * np.sin(X[:, 4]), X[:, 4], np.hypot(X[:, 2], X[:, 3]))

    def log_columns(self, t: float, s_control: np.ndarray) -> dict:
        """The trajectory rows of every controlled vehicle at ``t`` (positions measured from each
        one's control-zone entry ``s_control`` [m])."""
        ctl = self.table
        X, U, o = ctl.X, ctl.U, ctl.out
        ref_s = np.array([ctl.s_enter[i] + packed_position(ctl.prof[i], t - ctl.t_enter[i]) for i in range(len(ctl.ids))])
        return dict(
            t=np.full(len(ctl.ids), t), vehicle_id=list(ctl.ids), s_m=o[:, kb.OUT_S] - s_control,
            x=X[:, 0], y=X[:, 1], v_l=X[:, 2], v_n=X[:, 3], psi=X[:, 4], psi_dot=X[:, 5], a_cmd=o[:, kb.OUT_A],
            delta_cmd=o[:, kb.OUT_D], a_track=U[:, 0], delta_track=U[:, 1], ref_x=o[:, kb.OUT_REFX],
            ref_y=o[:, kb.OUT_REFY], ref_s_m=ref_s - s_control, tracking_error_m=o[:, kb.OUT_ERR],
            lateral_dev_m=o[:, kb.OUT_LAT],
            center_distance_m=np.where(ctl.lead_idx != kb.NO_LEADER, self._centre_now(), np.nan),
            bumper_gap_m=ctl.gap, cbf_long_active=o[:, kb.OUT_LONG_FRAC], cbf_lat_active=o[:, kb.OUT_LAT_FRAC],
            h_long=o[:, kb.OUT_H_LONG], h_lat=o[:, kb.OUT_H_LAT],
        )

    def _centre_now(self) -> np.ndarray:
        ctl = self.table
        out = np.full(len(ctl.ids), np.nan)
        for i in range(len(ctl.ids)):
            j = ctl.lead_idx[i]
            if j >= 0:
                out[i] = math.hypot(ctl.X[j, 0] - ctl.X[i, 0], ctl.X[j, 1] - ctl.X[i, 1])
            elif j == kb.EXTERNAL_LEADER:
                out[i] = math.hypot(ctl.lead_ext[i, 0] - ctl.X[i, 0], ctl.lead_ext[i, 1] - ctl.X[i, 1])
        return out

    def crossing_headings(self, m, v: float, s: np.ndarray) -> np.ndarray:
        """Body heading [rad] at positions ``s`` of a controlled car that the kernel drives through
        movement ``m``'s merging zone at constant speed ``v`` [m/s], alone, barriers on, entering
        30 m before the zone on the path."""
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
                np.zeros((1, 1, 0)), np.zeros((1, 2)), X.copy(), np.full((1, 2), np.nan))
        U = np.zeros((1, 2))
        ss, hs = [s0], [X[0, 4]]
        t, dt = 0.0, self.step_s  # sampled every SUMO step (well under a metre)
        while ss[-1] < m.s_exit + 1.0 and t < 600.0:
            kb.advance(X, U, t, self.n_sub, *args)
            t += dt
            ss.append(float(out[0, kb.OUT_S]))
            hs.append(float(X[0, 4]))
        hs = np.unwrap(np.array(hs))
        return np.interp(s, np.array(ss), hs)
