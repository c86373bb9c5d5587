"""``nrtraffic robustness``: the controller under measurement noise and actuator lag
(docs/mixed-traffic.md, Robustness).

Runs the paper's barrier experiment (``paper_cbf``, seeds 1-5) and cross4 (400 veh/h per approach,
seeds 1-3, 600 s) at every level of :data:`LEVELS` as one sweep (resumable, on Dask like
``nrtraffic sweep``), and writes ``DIR/sweep.md`` (the traffic table and the safety and tracking
table per scenario and level), ``DIR/sweep.csv``, ``DIR/sweep_summary.csv``,
``DIR/robustness.png`` and ``DIR/report.html``. The noise seed is the run's: every level sees the same arrivals.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pandas as pd

from runners.sweep import (NRTRAFFIC, SweepError, check_out, check_resume, check_where, failed_advice, make_out,
                           parse_seeds, plan, record_tables, remove_stale, run_sweep)

ROOT = Path(__file__).resolve().parent.parent


def _noise(position_m: float, speed_mps: float, heading_rad: float) -> tuple[str, ...]:
    return (f"disturbances.position_noise_m={position_m}", f"disturbances.speed_noise_mps={speed_mps}",
            f"disturbances.heading_noise_rad={heading_rad}")


# (name, overrides): three noise levels (standard deviations of position, each velocity component
# and heading), the middle one with a damped Newton step and with the barrier's gap margin too, an
# actuator lag alone, and the middle level seen through a state observer
LEVELS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("0 none", ()),
    ("1 low", _noise(0.02, 0.02, 0.002)),
    ("2 middle", _noise(0.05, 0.05, 0.005)),
    ("3 high", _noise(0.1, 0.1, 0.01)),
    ("4 middle, damping 0.01", _noise(0.05, 0.05, 0.005) + ("controller.damping=0.01",)),
    ("5 middle, damping 0.01, gap margin 0.2 m", _noise(0.05, 0.05, 0.005)
     + ("controller.damping=0.01", "barriers.gap_margin_m=0.2")),
    ("6 actuator lag 0.1 s", ("disturbances.actuator_lag_s=0.1",)),
    ("7 middle, observer 0.5 s", _noise(0.05, 0.05, 0.005) + ("disturbances.observer_time_s=0.5",)),
)

# (scenario folder, seeds, duration [s] or None for the scenario's, further overrides)
STUDY: tuple[tuple[str, str, float | None, tuple[str, ...]], ...] = (
    ("paper_cbf", "1:5", None, ()),
    ("cross4", "1:3", 600.0, ("demand.rate_veh_h=400",)),
)


def jobs(out: Path) -> list:
    """Every run of the study; each job's grid point is (scenario, level)."""
    out = Path(out)
    todo = []
    for name, seeds, duration, extra in STUDY:
        for level, overrides in LEVELS:
            point = (("scenario.name", name), ("disturbances.level", level))
            for j in plan(ROOT / "sumo_scenarios" / name / "scenario.toml", parse_seeds(seeds), [], [NRTRAFFIC],
                          out, duration, extra + overrides):
                run_dir = out / "runs" / name / f"level{level.split(' ')[0]}" / f"seed{j.seed}" / j.control
                todo.append(dataclasses.replace(j, point=point, run_dir=str(run_dir)))
    return todo


def figure(df: pd.DataFrame, path: Path) -> None:
    """Per scenario, against the level: the largest tracking error and lateral deviation and the
    smallest centre distance over the runs, with the barriers' limits y_max and d0 dashed."""
    from nrtraffic import scenario
    from nrtraffic.plots import plt

    ok = df[df["status"] == "ok"]
    names = list(dict.fromkeys(ok["scenario.name"]))
    panels = (("max_tracking_error_m", "max", "largest tracking error [m]"),
              ("max_lateral_dev_m", "max", "largest lateral deviation [m]"),
              ("min_center_distance_m", "min", "smallest centre distance [m]"))
    fig, axes = plt.subplots(len(names), 3, figsize=(13.0, 3.4 * len(names)), squeeze=False)
    for r, name in enumerate(names):
        sc = scenario.load(ROOT / "sumo_scenarios" / name / "scenario.toml")
        limits = {"max_lateral_dev_m": sc.barriers.max_lateral_dev_m,
                  "min_center_distance_m": sc.barriers.min_gap_m + sc.vehicle.params().length}
        g = ok[ok["scenario.name"] == name].groupby("disturbances.level", sort=True)
        for c, (k, how, label) in enumerate(panels):
            ax = axes[r, c]
            v = getattr(g[k], how)()
            ax.bar(range(len(v)), v.to_numpy(), color="tab:blue", alpha=0.8)
            if k in limits:
                ax.axhline(limits[k], color="tab:red", ls="--", lw=1,
                           label="y_max" if k == "max_lateral_dev_m" else "d0")
                ax.legend(fontsize=7, loc="best")
            ax.set_xticks(range(len(v)), [s.split(" ", 1)[1] for s in v.index], rotation=25, fontsize=7,
                          ha="right")
            ax.set_ylabel(label, fontsize=8)
            ax.set_title(name, fontsize=9)
            ax.grid(alpha=0.3, axis="y")
    fig.suptitle("worst case over the runs of each level (true states)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _figures(df: pd.DataFrame, summ: pd.DataFrame, out: Path) -> list[str]:
    """The study's figure (the sweep's own, drawn against grid points of two scenarios, would mislead)."""
    figure(df, Path(out) / "robustness.png")
    return ["robustness.png"]


_figures.names = ("robustness.png",)  # every name it may write


def main(args) -> int:
    from runners.clusters import from_args

    batch = from_args(args)
    check_where(args.workers, args.scheduler, batch)
    out = Path(args.out)
    check_out(out)  # (as a sweep's: not in another sweep's folder, no file of the user's replaced)
    todo = jobs(out)
    mine = {Path(j.run_dir).relative_to(out / "runs").parts[0] for j in todo}
    other = sorted(p.name for p in (out / "runs").iterdir() if p.name not in mine) if (out / "runs").is_dir() else []
    if other:  # (another sweep's folder: its tables would be replaced by this study's)
        raise SweepError(f"--out {out} holds another sweep's runs (runs/{other[0]}): choose an empty folder, or the "
                         "folder of an earlier robustness study to resume")
    make_out(out)
    check_resume(todo, force=args.force)
    remove_stale(out)
    record_tables(out, written=False)  # (what is there now is not the study's)
    df = run_sweep(todo, args.out, workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress,
                   figures=_figures, batch=batch)
    print((Path(args.out) / "sweep.md").read_text())
    failed = int((df["status"] != "ok").sum())
    if failed:
        print(failed_advice(df))
    return 1 if failed else 0
