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

from nrtraffic import scenario
from nrtraffic.control.batch import N_ACC, advance
from nrtraffic.control.nr_flow import nr_update
from nrtraffic.geometry import LanePath
from nrtraffic.vehicle.bicycle import euler_step
from nrtraffic.vehicle.params import preset

ROOT = Path(__file__).resolve().parent.parent


def _best(fn, repeat=5, number=200):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def bench_kernels(horizon=0.2, dt_pred=0.001) -> dict:
    P = preset("paper")
    p, pp = P.as_array(), P.with_mass_factor(2.0).as_array()
    x = np.array([0.0, 0.0, 13.4, 0.01, 0.1, 0.01])
    u = np.array([0.1, 0.01])
    un = np.empty(2)
    w = np.empty(6)
    lo, hi = np.array([-6.0, -0.78]), np.array([3.0, 0.78])
    ref = np.array([2.7, 0.3])
    nr_update(x, u, pp, ref, horizon, dt_pred, 100.0, 1e-6, 0.005, lo, hi, un)
    t_tracker = _best(lambda: nr_update(x, u, pp, ref, horizon, dt_pred, 100.0, 1e-6, 0.005, lo, hi, un))
    xp = x.copy()
    t_plant = _best(lambda: euler_step(xp, u, p, 0.005, w), number=20000)
    return {"tracker_step_us": t_tracker * 1e6, "plant_step_us": t_plant * 1e6}


def bench_batch(n_vehicles: int, horizon=0.2, n_sub=20) -> float:
    """Seconds per vehicle per simulated second of the batched kernel (synthetic straight road)."""
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
    args = dict(h=0.005, plant_p=p, pred_p=pp, horizon=horizon, dt_pred=0.001, alpha=100.0, damping=1e-6,
                u_lo=np.array([-6.0, -0.78]), u_hi=np.array([3.0, 0.78]))
    acc = np.zeros((N, N_ACC))
    outs = (np.zeros(N), np.zeros(N), np.zeros((N, 2)), np.zeros(N))
    pid = np.zeros(N, dtype=np.int64)
    off = np.array([0, len(path.s)], dtype=np.int64)
    hint = np.zeros(N, dtype=np.int64)

    def step(t):
        advance(X, U, t, n_sub, args["h"], p, pp, horizon, 0.001, 100.0, 1e-6, args["u_lo"], args["u_hi"], prof,
                np.zeros(N), s_enter, pid, off, path.xy, path.s, hint, 3.0, acc, *outs)

    step(0.0)
    n_steps = 20
    t0 = time.perf_counter()
    for k in range(n_steps):
        step(0.1 * (k + 1))
    wall = time.perf_counter() - t0
    sim = n_steps * n_sub * 0.005
    return wall / sim / N


def bench_run(scenario_path: Path) -> dict:
    """Co-simulation against SUMO alone on the same demand (the run's own route file)."""
    from nrtraffic.sumo.adapter import SumoSession
    from runners.single import run_scenario

    sc = scenario.load(scenario_path)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        res = run_scenario(sc, out)
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
    r = bench_run(ROOT / "sumo_scenarios" / "paper_curved" / "scenario.toml")
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
        lines.append(f"| batched kernel, {n} vehicles: wall time per vehicle per simulated second | {1e3 * v:.2f} ms "
                     f"(real-time factor per vehicle {1 / v:.0f}) |")
    lines += [
        f"| {r['scenario']}: co-simulation real-time factor | {r['cosim_rtf']:.1f} |",
        f"| {r['scenario']}: SUMO alone, same demand and steps, real-time factor | {r['sumo_rtf']:.0f} |",
        f"| {r['scenario']}: co-simulation / SUMO alone wall time | {r['slowdown']:.1f} x |",
        f"| peak resident memory of the benchmark process | {rss:.0f} MiB |",
    ]
    return "\n".join(lines) + "\n"


def main(args) -> int:
    table = run_all()
    print(table)
    if args.write:
        Path(args.write).write_text(table)
    return 0
