"""``nrtraffic bench``: speed of the hot kernels and of whole runs, as ratios measured in one run.

Machines are shared and noisy: compare the ratios (co-simulation against SUMO alone on the same
demand, tracker step against plant step), not the absolute times.
"""

from __future__ import annotations

import platform
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

from nrtraffic import scenario
from nrtraffic.control.nr_flow import EULER, PREDICTORS, RK4, new_workspace, nr_update
from nrtraffic.geometry import LanePath
from nrtraffic.vehicle.bicycle import euler_step
from nrtraffic.vehicle.params import preset

ROOT = Path(__file__).resolve().parent.parent
JUNCTION_RK4_STEP_S = 0.05  # the junction scenarios' predictor step (controller.predictor_step_s)


def _best(fn, repeat=5, number=200):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


@njit
def _loop_tracker(n, x, u, pp, ref, horizon, dt_pred, method, lo, hi, un, ws, wsP):
    for _ in range(n):
        nr_update(x, u, pp, ref, horizon, dt_pred, method, 100.0, 1e-6, 0.005, lo, hi, un, ws, wsP, True, True, 1.0,
                  0.0)


@njit
def _loop_plant(n, x, u, p, w):
    for _ in range(n):
        euler_step(x, u, p, 0.005, w)


def bench_kernels(horizon=0.2) -> dict:
    """Per-call cost [us] of the tracker update (predictor + sensitivities + update law) with each
    predictor, and of a plant step, each measured inside a compiled loop (no Python dispatch)."""
    P = preset("paper")
    p, pp = P.as_array(), P.with_mass_factor(2.0).as_array()
    x = np.array([0.0, 0.0, 13.4, 0.01, 0.1, 0.01])
    u = np.array([0.1, 0.01])
    un = np.empty(2)
    w = np.empty(6)
    lo, hi = np.array([-6.0, -0.78]), np.array([3.0, 0.78])
    ref = np.array([2.7, 0.3])
    ws = new_workspace()
    out = {}
    for name, method, dt_pred, n in (("euler", EULER, 0.001, 2000), ("rk4", RK4, JUNCTION_RK4_STEP_S, 20000)):
        _loop_tracker(1, x, u, pp, ref, horizon, dt_pred, method, lo, hi, un, *ws)
        out[f"tracker_{name}_us"] = _best(lambda: _loop_tracker(n, x, u, pp, ref, horizon, dt_pred, method, lo, hi,
                                                                un, *ws), number=1) / n * 1e6
    xp = x.copy()
    _loop_plant(1, xp, u, p, w)
    out["plant_step_us"] = _best(lambda: _loop_plant(200000, xp, u, p, w), number=1) / 200000 * 1e6
    return out


def bench_batch(n_vehicles: int, horizon=0.2, n_sub=20, barriers: bool = True, predictor: str = "rk4",
                dt_pred: float = JUNCTION_RK4_STEP_S) -> float:
    """Wall time [us] of the batched kernel per vehicle per plant step (synthetic straight road,
    vehicles 20 m apart at 13.4 m/s, each following the one ahead: both barriers evaluated every
    plant step)."""
    from nrtraffic.control import batch as kb
    from nrtraffic.geometry import segment_frames

    P = preset("paper")
    p, pp = P.as_array(), P.with_mass_factor(2.0).as_array()
    path = LanePath.from_points([(0.0, 0.0), (5000.0, 0.0)])
    N = n_vehicles
    X = np.zeros((N, 6))
    X[:, 0] = np.arange(N) * 20.0
    X[:, 2] = 13.4
    U = np.zeros((N, 2))
    prof = np.zeros((N, 5, 5))
    prof[:, :, 0] = np.arange(5) * 1e9
    prof[:, :, 2] = 13.4
    s_enter = X[:, 0].copy()
    cfg = np.zeros(kb.N_CFG)
    cfg[[kb.CFG_H, kb.CFG_HORIZON, kb.CFG_DT_PRED, kb.CFG_ALPHA, kb.CFG_DAMPING, kb.CFG_STEADY_AFTER,
         kb.CFG_PREDICTOR]] = (0.005, horizon, dt_pred, 100.0, 1e-6, 3.0, PREDICTORS[predictor])
    cfg[[kb.CFG_CBF_LONG, kb.CFG_CBF_LAT, kb.CFG_D0, kb.CFG_A_BAR, kb.CFG_LONG_GAIN, kb.CFG_Y_MAX, kb.CFG_K_LAT,
         kb.CFG_GAMMA, kb.CFG_BISECT_TOL, kb.CFG_ANTI_WINDUP, kb.CFG_ROOT_C]] = (
        float(barriers), float(barriers), 6.8, 3.0, 1.0, 0.5, 0.25, 15.0, 1e-6, 1.0, 0.1)
    lead_idx = np.arange(1, N + 1, dtype=np.int64)
    lead_idx[-1] = kb.NO_LEADER
    acc = kb.new_acc(N)
    out = np.zeros((N, kb.N_OUT))
    out[:, kb.OUT_S] = s_enter
    pid = np.zeros(N, dtype=np.int64)
    off = np.array([0, len(path.s)], dtype=np.int64)
    frames = segment_frames(path.xy, path.s)
    hint = np.searchsorted(path.s, s_enter).astype(np.int64) - 1
    hint[hint < 0] = 0
    lo, hi = np.array([-6.0, -0.78]), np.array([3.0, 0.78])

    def step(t):
        kb.advance(X, U, t, n_sub, cfg, p, pp, lo, hi, prof, np.zeros(N), s_enter, pid, off, path.xy, path.s, frames,
                   hint, lead_idx, np.zeros((N, 6)), acc, out)

    step(0.0)
    n_steps = 20
    t0 = time.perf_counter()
    for k in range(n_steps):
        step(0.1 * (k + 1))
    wall = time.perf_counter() - t0
    return wall / (n_steps * n_sub * N) * 1e6


def bench_run(scenario_path: Path, duration_s: float | None = None) -> dict:
    """Co-simulation against SUMO alone on the same demand (the run's own route file and network,
    every vehicle driven by SUMO)."""
    from nrtraffic.sumo.adapter import SumoSession
    from runners.single import run_scenario

    sc = scenario.load(scenario_path)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        res = run_scenario(sc, out, duration_s=duration_s)
        co_wall, sim = res.summary["wall_time_s"], res.summary["sim_time_s"]
        t0 = time.perf_counter()
        with SumoSession(sc.network_path, out / "sumo" / "routes.rou.xml", sc.sumo.step_length_s, sc.general.seed,
                         sc.sumo.lateral_resolution_m) as sumo:
            while sumo.time < sim - 1e-9:
                sumo.step()
        sumo_wall = time.perf_counter() - t0
    return {"scenario": sc.general.name, "sim_time_s": sim, "cosim_wall_s": co_wall, "sumo_wall_s": sumo_wall,
            "cosim_rtf": sim / co_wall, "sumo_rtf": sim / sumo_wall, "slowdown": co_wall / sumo_wall}


def run_all() -> str:
    k = bench_kernels()
    batch = {n: bench_batch(n) for n in (1, 10, 50)}
    no_cbf = bench_batch(10, barriers=False)
    runs = [bench_run(ROOT / "sumo_scenarios" / "paper_curved" / "scenario.toml"),
            bench_run(ROOT / "sumo_scenarios" / "cross4" / "scenario.toml", duration_s=300.0)]
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    lines = [
        "# nrtraffic benchmarks",
        "",
        f"Machine: {platform.machine()}, {platform.python_implementation()} {platform.python_version()}. "
        "Times are best-of-5 and vary with load; the ratios are the figures to compare.",
        "",
        "| what | value |",
        "|---|---|",
        f"| tracker step (predictor T = 0.2 s / Dt = 0.001 s with sensitivities + update), per vehicle | {k['tracker_step_us']:.1f} us |",
        f"| plant Euler step, per vehicle | {k['plant_step_us']:.3f} us |",
        f"| tracker / plant step | {k['tracker_step_us'] / k['plant_step_us']:.0f} x |",
    ]
    for n, v in batch.items():
        lines.append(f"| batched kernel with barriers, {n} vehicles: wall time per vehicle per simulated second | "
                     f"{1e3 * v:.2f} ms (real-time factor per vehicle {1 / v:.0f}) |")
    lines.append(f"| batched kernel, 10 vehicles, barriers off / on | {no_cbf / batch[10]:.2f} |")
    for r in runs:
        lines += [
            f"| {r['scenario']} ({r['sim_time_s']:.0f} s): co-simulation real-time factor | {r['cosim_rtf']:.1f} |",
            f"| {r['scenario']}: SUMO alone, same demand and steps, real-time factor | {r['sumo_rtf']:.0f} |",
            f"| {r['scenario']}: co-simulation / SUMO alone wall time | {r['slowdown']:.1f} x |",
        ]
    lines.append(f"| peak resident memory of the benchmark process | {rss:.0f} MiB |")
    return "\n".join(lines) + "\n"


def main(args) -> int:
    table = run_all()
    print(table)
    if args.write:
        Path(args.write).write_text(table)
    return 0
