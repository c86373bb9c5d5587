"""``nrtraffic bench``: speed of the hot kernels and of whole runs, as ratios measured in one run.

Machines are shared and noisy: compare the ratios (co-simulation against SUMO alone on the same
demand, tracker step against plant step), not the absolute times.
"""

from __future__ import annotations

import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

from nrtraffic import scenario
from nrtraffic.control.nr_flow import EULER, RK4, new_workspace, nr_update, predictor_steps
from nrtraffic.geometry import LanePath
from nrtraffic.vehicle.bicycle import euler_step
from nrtraffic.vehicle.params import preset

ROOT = Path(__file__).resolve().parent.parent
JUNCTION_RK4_STEP_S = 0.1  # the junction scenarios' nominal predictor step (controller.predictor_step_s)
PAIRS = 3  # whole runs: each with SUMO alone back to back, this many times (the table gives the medians)


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
    p = pp = P.as_array()  # as in the junction scenarios: no predictor model error
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
    out["rk4_steps"] = predictor_steps(x[2], pp, horizon, JUNCTION_RK4_STEP_S, RK4)
    return out


def bench_batch(n_vehicles: int, horizon=0.2, n_sub=20, barriers: bool = True, predictor: str = "rk4",
                dt_pred: float = JUNCTION_RK4_STEP_S) -> float:
    """Wall time [us] of the batched kernel per vehicle per plant step, best of 5: cross4's vehicle
    and controller (with this horizon, predictor and barriers) on a synthetic straight road,
    vehicles 20 m apart at 13.4 m/s, each following the one ahead (both barriers evaluated every
    plant step), through the library's :class:`~nrtraffic.control.kernel.Kernel`."""
    from nrtraffic.control.batch import NO_LEADER, new_acc
    from nrtraffic.control.kernel import Kernel
    from nrtraffic.control.table import N_PROFILE_SEG
    from nrtraffic.junction import Movement

    flag = "true" if barriers else "false"
    sc = scenario.load(ROOT / "sumo_scenarios" / "cross4" / "scenario.toml", [
        f"controller.horizon_s={horizon}", f'controller.predictor="{predictor}"', f"controller.predictor_step_s={dt_pred}",
        f"sumo.step_length_s={n_sub * 0.005}", f"barriers.longitudinal={flag}", f"barriers.lateral={flag}"])
    kern = Kernel(sc, sc.vehicle.params(), seed=1)
    path = LanePath.from_points([(0.0, 0.0), (5000.0, 0.0)])
    road = Movement("road", "road", "through", ("road",), path, ["road_0"], {"road_0": (0.0, 1.0)}, 0.0, 4900.0,
                    4990.0)
    kern.pack_paths({"road": road})
    prof = np.zeros((N_PROFILE_SEG, 5))
    prof[:, 0] = np.arange(N_PROFILE_SEG) * 1e9
    prof[:, 2] = 13.4  # constant speed
    N = n_vehicles
    for i in range(N):
        kern.take(f"v{i}", np.array([20.0 * i, 0.0, 13.4, 0.0, 0.0, 0.0]), prof, 0.0, 20.0 * i, 0.0, road,
                  new_acc(1)[0])
    kern.table.lead_idx[:] = np.arange(1, N + 1)
    kern.table.lead_idx[-1] = NO_LEADER
    dt = sc.sumo.step_length_s
    kern.advance(0.0, dt)
    n_steps = 20
    best = np.inf
    for rep in range(5):  # best of 5: the machines are shared
        t0 = time.perf_counter()
        for k in range(n_steps):
            kern.advance(dt * (rep * n_steps + k + 1), dt)
        best = min(best, time.perf_counter() - t0)
    return best / (n_steps * n_sub * N) * 1e6


def bench_run(scenario_path: Path, duration_s: float | None = None, overrides: tuple[str, ...] = (),
              pairs: int = 1, floor: bool = False) -> dict:
    """A co-simulation run, then SUMO alone on the same demand (the run's own route file and
    network, every vehicle driven by SUMO, same steps), back to back in this process, ``pairs``
    times. Returns the median wall times, real-time factors and ratio of the pairs (the ratio's
    lowest and highest too), and the wall-time breakdown of the run whose wall time is the median.
    With ``floor``, each pair also runs SUMO alone reading every vehicle after each step as a run
    does (``read_wall_s``: the median)."""
    from nrtraffic.sumo.adapter import drive_alone
    from runners.single import run_scenario

    sc = scenario.load(scenario_path, list(overrides))
    measured = []
    for _ in range(pairs):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "run"
            s = run_scenario(sc, out, duration_s=duration_s).summary
            sumo_wall = drive_alone(sc.network_path, out / "sumo" / "routes.rou.xml", sc.sumo.step_length_s,
                                    sc.general.seed, s["sim_time_s"], sc.sumo.lateral_resolution_m)
            read_wall = drive_alone(sc.network_path, out / "sumo" / "routes.rou.xml", sc.sumo.step_length_s,
                                    sc.general.seed, s["sim_time_s"], sc.sumo.lateral_resolution_m,
                                    read=True) if floor else math.nan
        measured.append((s, sumo_wall, read_wall))
    sim = measured[0][0]["sim_time_s"]
    co = sorted(m[0]["wall_time_s"] for m in measured)
    alone = sorted(m[1] for m in measured)
    ratios = sorted(m[0]["wall_time_s"] / m[1] for m in measured)
    mid = pairs // 2  # (an odd number of pairs: the median is one of them)
    s = next(m[0] for m in measured if m[0]["wall_time_s"] == co[mid])
    return {"scenario": sc.general.name, "overrides": " ".join(overrides), "sim_time_s": sim, "cosim_wall_s": co[mid],
            "read_wall_s": sorted(m[2] for m in measured)[mid],
            "sumo_wall_s": alone[mid], "cosim_rtf": sim / co[mid], "sumo_rtf": sim / alone[mid],
            "slowdown": ratios[mid], "slowdown_range": (ratios[0], ratios[-1]), "pairs": pairs,
            "breakdown": s.get("wall_time_breakdown_s", {}), "vehicles": s["vehicles_admitted"],
            "collisions": s["collisions"] + s["collisions_geometric"]}


def memory_run(duration_s: float) -> None:
    """Run cross4 (400 veh/h per approach) for ``duration_s`` with trajectories logged every 0.1 s
    and print this process's peak resident memory [MiB] (called in a fresh process)."""
    from runners.single import run_scenario

    sc = scenario.load(ROOT / "sumo_scenarios" / "cross4" / "scenario.toml", ["outputs.trajectory_interval_s=0.1"])
    with tempfile.TemporaryDirectory() as tmp:
        res = run_scenario(sc, Path(tmp) / "run", duration_s=duration_s)
        rows = res.summary["vehicles_admitted"]
        size = (Path(tmp) / "run" / "trajectories.parquet").stat().st_size
    print(json.dumps({"duration_s": duration_s, "peak_rss_mib": peak_rss_mib(), "vehicles": rows,
                      "trajectory_mib": size / 2**20}))


def first_runs() -> None:
    """Two 30 s runs of cross4 in this process, and print their wall times [s] (called in a fresh
    process: the first also imports the run's modules and loads the compiled kernels from numba's
    cache)."""
    from runners.single import run_scenario

    sc = scenario.load(ROOT / "sumo_scenarios" / "cross4" / "scenario.toml", [])
    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(2):
            t0 = time.perf_counter()
            run_scenario(sc, Path(tmp) / f"run{k}", duration_s=30.0)
            walls.append(time.perf_counter() - t0)
    print(json.dumps(walls))


def bench_first_runs() -> list[float]:
    """Wall times [s] of the first and the second 30 s run of a fresh process (``first_runs``)."""
    code = "from runners.bench import first_runs; first_runs()"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def peak_rss_mib() -> float:
    """Peak resident memory of this process [MiB]: ``VmHWM`` of /proc/self/status where there is one
    (``ru_maxrss`` survives ``exec`` on Linux, so a child would report its parent's peak), else
    ``ru_maxrss``."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_memory(duration_s: float) -> dict:
    """Peak memory of a whole run in a process of its own (``memory_run``)."""
    code = f"from runners.bench import memory_run; memory_run({float(duration_s)!r})"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


SCALE_SIDES = (1, 2, 4, 6)  # grids of 1, 4, 16 and 36 junctions
SCALE_RATE_VEH_H = 200.0  # departures per hour at each road into a grid: the cars at once grow with it
# the first line of each table nrtraffic bench writes (an earlier one may be written over)
BENCH_TITLES = ("# nrtraffic benchmarks", "# nrtraffic scale benchmark")


# the phases of the loop (WALL_PHASES without "qp", which is part of "admission")
LOOP_PHASES = ("kernel", "sumo_step", "sumo_io", "admission", "leaders", "collision_check", "logging")


def scale_run(side: int, duration_s: float) -> None:
    """A grid of ``side`` x ``side`` junctions (:func:`~nrtraffic.sumo.netbuild.grid_network`, grid4's
    settings), every junction controlled, ``SCALE_RATE_VEH_H`` from each road in, run for
    ``duration_s`` (after 30 s of it untimed, which loads the compiled kernels), then SUMO alone on
    the same route file; prints its figures and this process's peak resident memory as JSON (called
    in a fresh process)."""
    import re

    from nrtraffic.sumo.adapter import drive_alone
    from nrtraffic.sumo.netbuild import grid_network, random_trips
    from runners.single import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        grid_network(side, d / "net.net.xml")
        random_trips(d / "net.net.xml", d / "demand.rou.xml", SCALE_RATE_VEH_H, entries=4 * side, end_s=duration_s)
        text = (ROOT / "sumo_scenarios" / "grid4" / "scenario.toml").read_text()
        ids = [f"{chr(ord('A') + i)}{j}" for i in range(side) for j in range(side)]
        text = re.sub(r'\[\[junctions\]\]\nid = "\w+"\n\n', "", text)
        text += "".join(f'\n[[junctions]]\nid = "{j}"\n' for j in ids)
        (d / "scenario.toml").write_text(text)
        sc = scenario.load(d / "scenario.toml", [f"scenario.duration_s={duration_s}", "outputs.warmup_s=0.0"])
        # 30 s first, not timed: this process loads every compiled kernel from numba's cache once
        run_scenario(sc, d / "warm", duration_s=30.0)
        res = run_scenario(sc, d / "run", duration_s=duration_s)
        s, veh = res.summary, res.vehicles
        b = s.get("wall_time_breakdown_s", {})
        steps = s["sim_time_s"] / sc.sumo.step_length_s
        # controlled vehicle-steps: the plant's sub-steps over the sub-steps per SUMO step
        vsteps = float(veh.plant_steps.sum()) * sc.controller.plant_step_s / sc.sumo.step_length_s
        rss = peak_rss_mib()
        sumo_wall = drive_alone(sc.network_path, d / "run" / "sumo" / "routes.rou.xml", sc.sumo.step_length_s,
                                sc.general.seed, s["sim_time_s"], sc.sumo.lateral_resolution_m)
    print(json.dumps({"junctions": side * side, "sim_time_s": s["sim_time_s"], "cosim_wall_s": s["wall_time_s"],
                      "loop_s": sum(b.get(k, 0.0) for k in LOOP_PHASES), "breakdown": b, "vehicle_steps": vsteps,
                      "at_once": vsteps / steps, "sumo_wall_s": sumo_wall, "admitted": s["vehicles_admitted"],
                      "collisions": s["collisions"] + s["collisions_geometric"], "served": s["served_share"],
                      "peak_rss_mib": rss}))


def bench_scale(side: int, duration_s: float) -> dict:
    """:func:`scale_run` in a process of its own (its memory is its own)."""
    code = f"from runners.bench import scale_run; scale_run({int(side)}, {float(duration_s)!r})"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    if out.returncode != 0:
        raise RuntimeError(f"the {side} x {side} grid failed: {out.stderr.strip()[-800:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def scale_figure(rows: list[dict], path: Path) -> None:
    """Wall time per controlled vehicle and SUMO step, by phase, against the controlled vehicles at
    once (one point per grid)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    x = [r["at_once"] for r in rows]
    ax.plot(x, [1e6 * r["loop_s"] / r["vehicle_steps"] for r in rows], "o-", color="k", label="whole loop")
    for k in LOOP_PHASES:  # (the table's columns, so that the phases add up to the whole loop)
        ax.plot(x, [1e6 * r["breakdown"].get(k, 0.0) / r["vehicle_steps"] for r in rows], ".--", label=k)
    for r in rows:
        ax.annotate(f"{r['junctions']}", (r["at_once"], 1e6 * r["loop_s"] / r["vehicle_steps"]),
                    textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.set_xscale("log")
    ax.set_xticks(x, [f"{v:.0f}" for v in x])  # (ticks at the grids: a log axis' minor labels overlap)
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("controlled vehicles at once (mean; label: junctions)")
    ax.set_ylabel("wall time per controlled vehicle-step [us]")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    tmp = path.with_name(path.name + ".tmp")  # (whole or not at all; a link of that name is replaced, not followed)
    fig.savefig(tmp, dpi=120, format="png", metadata={"Title": FIGURE_TITLE})
    plt.close(fig)
    os.replace(tmp, path)


FIGURE_TITLE = "nrtraffic scale benchmark"  # the PNG's Title, by which a later run knows its own figure


def own_figure(figure: Path, table: Path) -> bool:
    """Whether ``figure`` is a file an earlier ``bench --scale`` wrote: a regular file (not a link)
    holding a PNG titled :data:`FIGURE_TITLE`, or (from before that title) a PNG that the
    benchmark's own table beside it shows."""
    if figure.is_symlink() or not figure.is_file():
        return False
    try:
        data = figure.read_bytes()
        shown = table.is_file() and f"]({figure.name})" in table.read_text(errors="replace")
    except OSError:
        return False
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        return False
    return b"tEXtTitle\x00" + FIGURE_TITLE.encode() in data or shown


def scale_section(duration_s: float, figure: Path | None, district_hour: bool = True) -> list[str]:
    """The scale benchmark's table (grids of ``SCALE_SIDES``), and its figure at ``figure``; with
    ``district_hour``, the 16-junction grid also for an hour."""
    bench_scale(2, 120.0)  # (untimed: compiles every kernel once, if need be, into numba's cache)
    rows = [bench_scale(n, duration_s) for n in SCALE_SIDES]
    hour = bench_scale(4, 3600.0) if district_hour else None  # the 16-junction district for an hour
    if figure is not None:
        scale_figure(rows, figure)
    one = rows[0]["loop_s"] / rows[0]["vehicle_steps"]
    lines = [
        f"## Scale: grids of two-lane roads, every junction controlled ({duration_s:.0f} s, "
        f"{SCALE_RATE_VEH_H:.0f} veh/h from each road in)",
        "",
        "| junctions | controlled at once (mean) | admitted | loop per controlled vehicle-step | against 1 junction "
        "| real-time factor | SUMO alone real-time factor | co-simulation / SUMO alone | peak memory | collisions "
        "| served |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        per = r["loop_s"] / r["vehicle_steps"]
        lines.append(f"| {r['junctions']} | {r['at_once']:.1f} | {r['admitted']} | {1e6 * per:.1f} us | "
                     f"{per / one:.2f} x | {r['sim_time_s'] / r['cosim_wall_s']:.1f} | "
                     f"{r['sim_time_s'] / r['sumo_wall_s']:.0f} | {r['cosim_wall_s'] / r['sumo_wall_s']:.1f} x | "
                     f"{r['peak_rss_mib']:.0f} MiB | {r['collisions']} | {100 * r['served']:.1f} % |")
    if hour is not None:
        lines += ["", f"The 16-junction district for an hour: real-time factor "
                  f"{hour['sim_time_s'] / hour['cosim_wall_s']:.1f} ({hour['cosim_wall_s']:.0f} s wall, set-up and "
                  f"results included), {hour['admitted']} vehicles admitted, {hour['at_once']:.1f} controlled at once, "
                  f"peak memory {hour['peak_rss_mib']:.0f} MiB, {hour['collisions']} collisions, served "
                  f"{100 * hour['served']:.1f} %."]
    lines += ["", "Per controlled vehicle-step, by phase [us]:", "",
              "| junctions | " + " | ".join(LOOP_PHASES) + " |", "|---|" + "---|" * len(LOOP_PHASES)]
    for r in rows:
        lines.append(f"| {r['junctions']} | " + " | ".join(
            f"{1e6 * r['breakdown'].get(k, 0.0) / r['vehicle_steps']:.1f}" for k in LOOP_PHASES) + " |")
    lines += ["", "The loop is the simulation's tick (SUMO's step, reading and writing SUMO, admission, leaders, "
              "the own collision check, the kernel, logging), without set-up and results; a controlled "
              "vehicle-step is one controlled vehicle over one SUMO step (0.1 s). SUMO's step and I/O also carry "
              "the vehicles SUMO drives on their way to a control zone. Peak memory is the whole process's, run "
              "and SUMO alone."]
    if figure is not None:
        lines += ["", f"![cost per vehicle-step against vehicles at once]({figure.name})"]
    return lines


def _breakdown_rows(runs: list[dict]) -> list[str]:
    """The wall-time breakdown of ``runs`` side by side: one "time (share)" column per run."""
    names = {"kernel": "compiled kernel (tracker, barriers, plant)", "sumo_step": "SUMO's step",
             "sumo_io": "SUMO I/O (batched read, moveToXY, hand-over)", "admission": "admission and planning",
             "leaders": "leader search", "collision_check": "own collision check", "logging": "trajectory logging"}
    keys = [k for k in names if all(k in r["breakdown"] for r in runs)]

    def cell(v, r):
        return f"{v:.2f} s ({100 * v / r['cosim_wall_s']:.1f} %)"

    rows = [f"| {names[k]} | " + " | ".join(cell(r["breakdown"][k], r) for r in runs) + " |" for k in keys]
    if all("qp" in r["breakdown"] for r in runs):
        rows.append("| of which rear-end QPs (DAQP) | " + " | ".join(cell(r["breakdown"]["qp"], r) for r in runs) + " |")
    rows.append("| set-up, results and the rest | " + " | ".join(
        cell(r["cosim_wall_s"] - sum(r["breakdown"][k] for k in keys), r) for r in runs) + " |")
    rows.append("| whole run | " + " | ".join(f"{r['cosim_wall_s']:.2f} s" for r in runs) + " |")
    return rows


def run_all(quick: bool = False) -> str:
    """Every benchmark, back to back in this process; returns the markdown table."""
    k = bench_kernels()
    batch = {n: bench_batch(n) for n in (1, 20, 50)}
    batch_euler = bench_batch(20, predictor="euler", dt_pred=0.001)
    no_cbf = bench_batch(20, barriers=False)
    dur = 120.0 if quick else 600.0
    cross = ROOT / "sumo_scenarios" / "cross4" / "scenario.toml"
    # the first run of a process also imports the run's modules and loads every compiled kernel from
    # numba's cache (a sweep's workers pay this once): measured in a process of its own, after a short
    # run here, which fills the cache where an edit emptied it (the fresh process then loads, not
    # compiles) and lets the runs below time the simulation alone
    bench_run(cross, 30.0)
    first, again = bench_first_runs()
    n_pairs = 1 if quick else PAIRS
    runs = [bench_run(cross, dur, pairs=n_pairs, floor=True),
            bench_run(cross, dur, ("demand.rate_veh_h=600",), pairs=n_pairs),
            bench_run(cross, dur, ("controller.plant_step_s=0.01",), pairs=n_pairs),
            bench_run(cross, dur, ('controller.predictor="euler"', "controller.predictor_step_s=0.001"), pairs=n_pairs),
            bench_run(ROOT / "sumo_scenarios" / "cross4_2lane" / "scenario.toml", dur, pairs=n_pairs),
            bench_run(ROOT / "sumo_scenarios" / "corridor3" / "scenario.toml", dur, pairs=n_pairs),
            bench_run(ROOT / "sumo_scenarios" / "paper_curved" / "scenario.toml", pairs=n_pairs),
            bench_run(ROOT / "sumo_scenarios" / "paper_cbf" / "scenario.toml", pairs=n_pairs)]
    mem = [bench_memory(d) for d in ((60.0, 120.0) if quick else (600.0, 3600.0))]
    rss = peak_rss_mib()
    h_limit = scenario.plant_step_limit(scenario.load(cross, []))[0]
    lines = [
        BENCH_TITLES[0],
        "",
        f"`nrtraffic bench` on {platform.machine()}, {platform.python_implementation()} {platform.python_version()}, "
        f"one process, one core. Every figure of a table was measured back to back in one run; the machines are "
        "shared and noisy, so compare ratios (co-simulation against SUMO alone on the same demand, one kernel "
        "against another), not absolute times.",
        "",
        "## Kernels",
        "",
        "| what | value |",
        "|---|---|",
        f"| tracker update, RK4 predictor (T = 0.2 s, Dt = {JUNCTION_RK4_STEP_S} s nominal: {k['rk4_steps']} steps at "
        f"13.4 m/s) with sensitivities, per vehicle | {k['tracker_rk4_us']:.2f} us |",
        f"| tracker update, the paper's Euler predictor (Dt = 0.001 s: 200 steps), per vehicle | "
        f"{k['tracker_euler_us']:.2f} us |",
        f"| plant Euler step, per vehicle | {k['plant_step_us']:.3f} us |",
    ]
    for n, v in batch.items():
        lines.append(f"| batched kernel (RK4, both barriers), {n} vehicles: per vehicle per plant step | {v:.2f} us |")
    lines += [
        f"| batched kernel, 20 vehicles, barriers off | {no_cbf:.2f} us |",
        f"| batched kernel, 20 vehicles, the paper's Euler predictor | {batch_euler:.2f} us |",
        "",
        "## Whole runs against SUMO alone",
        "",
        "| run | simulated | co-simulation real-time factor | SUMO alone real-time factor | co-simulation / "
        "SUMO alone (lowest-highest) | vehicles controlled in the measurement window | collisions |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        label = r["scenario"] + (f" `{r['overrides']}`" if r["overrides"] else "")
        lines.append(f"| {label} | {r['sim_time_s']:.0f} s | {r['cosim_rtf']:.1f} | {r['sumo_rtf']:.0f} | "
                     f"{r['slowdown']:.1f} x ({r['slowdown_range'][0]:.1f}-{r['slowdown_range'][1]:.1f}) | "
                     f"{r['vehicles']} | {r['collisions']} |")
    lines += [
        "",
        f"Each run and SUMO alone ran back to back, {n_pairs} times; the table gives the medians, and the lowest and "
        "highest ratio of a pair. "
        "The real-time factor is simulated time over the run's wall time, set-up and results included. The "
        "first run of a process also imports the run's modules and loads the compiled kernels from numba's cache, "
        f"once (a sweep's workers do it once each): in a fresh process, a 30 s run of cross4 took {first:.2f} s "
        f"as the process's first run and {again:.2f} s the next time. The runs above follow a first run.",
        "",
        f"## Where a run's time goes (cross4, 400 veh/h per approach, {dur:.0f} s)",
        "",
        "The run of median wall time of each row above. The plant step (`controller.plant_step_s`) is the "
        "paper's 0.005 s by default; 0.01 s is within forward Euler's stability limit for this car "
        f"({h_limit:.4f} s), and halves the kernel's plant steps.",
        "",
        "| part | cross4 (plant step 0.005 s) | cross4 `controller.plant_step_s=0.01` |",
        "|---|---|---|",
        *_breakdown_rows([runs[0], runs[2]]),
        "",
        f"SUMO alone on the same demand took {runs[0]['sumo_wall_s']:.2f} s; reading every vehicle after each step "
        f"as a run reads them (subscriptions, then one batched read), with nothing controlled, "
        f"{runs[0]['read_wall_s']:.2f} s ({runs[0]['read_wall_s'] / runs[0]['sumo_wall_s']:.1f} x SUMO alone; "
        "medians of the same pairs). That is the coupling's cost before any control: a run reads fewer vehicles "
        "(it leaves out those released far down their exit road) but also moves its controlled ones.",
        "",
        "## Memory (cross4, 400 veh/h per approach, trajectories every 0.1 s, each run in a process of its own)",
        "",
        "| simulated | peak resident memory | vehicles | trajectories.parquet |",
        "|---|---|---|---|",
        *[f"| {m['duration_s']:.0f} s | {m['peak_rss_mib']:.0f} MiB | {m['vehicles']} | {m['trajectory_mib']:.1f} MiB |"
          for m in mem],
        "",
        f"Peak resident memory of the benchmark process itself: {rss:.0f} MiB.",
    ]
    return "\n".join(lines) + "\n"


def main(args) -> int:
    """``nrtraffic bench``: the table is written to ``--write`` (checked first), or by default to
    the committed ``bench/results.md`` (``bench/scale.md``), except for a ``--quick`` smoke test,
    which only prints its table where no ``--write`` is given."""
    from runners.api import writable_file, write_file

    default = None if args.quick else ("bench/scale.md" if args.scale else "bench/results.md")
    write = writable_file(args.write, own=BENCH_TITLES) if args.write else (Path(default) if default else None)
    if args.scale:
        figure = write.with_suffix(".png") if write is not None else None
        if figure is not None and os.path.lexists(figure) and not own_figure(figure, write):
            from runners.api import OutputError

            raise OutputError(f"--write {write}: the scale benchmark's figure goes beside it as {figure}, which "
                              "exists and is no earlier benchmark's figure (a file of your own, or a link?); remove "
                              "it, or choose another name")
        table = "\n".join([BENCH_TITLES[1], "", *scale_section(
            120.0 if args.quick else 600.0, figure, district_hour=not args.quick)]) + "\n"
    else:
        table = run_all(quick=args.quick)
    print(table)
    if write is not None:
        write_file(write, table)
    return 0
