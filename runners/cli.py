"""The ``nrtraffic`` command."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _add_run(sub) -> None:
    p = sub.add_parser("run", help="run one scenario", description="Run one scenario and write its run directory.")
    p.add_argument("scenario", type=Path, help="scenario.toml (or the folder holding it)")
    p.add_argument("--seed", type=int, default=None, help="random seed of arrivals and SUMO (default: the scenario's)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="simulated time [s] (default: the scenario's; 0 runs until every vehicle has left)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="run directory (default: runs/<scenario>-seed<N>)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scenario setting (repeatable), e.g. --set controller.horizon_s=0.3")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_paper(sub) -> None:
    p = sub.add_parser("paper", help="reproduce the paper's experiments",
                       description="Reproduce the experiments of Shivam et al. (IFAC 2020) and compare with its numbers.")
    p.add_argument("experiment", choices=["curved", "cbf", "all"],
                   help="curved: section 4.1, tracking on a curved road; cbf: section 4.2, barrier functions; "
                        "all: both (into DIR/curved and DIR/cbf)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_baseline(sub) -> None:
    from nrtraffic.sumo.netbuild import JUNCTION_TYPES

    p = sub.add_parser("baseline", help="the same demand under SUMO's own junction control",
                       description="Run a junction scenario's demand and seed with SUMO driving every vehicle "
                                   "under its own junction control, into a run directory of the same form.")
    p.add_argument("scenario", type=Path, help="scenario.toml with a [junction] (or its folder)")
    p.add_argument("--junction", required=True, choices=JUNCTION_TYPES, help="SUMO's junction control")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="simulated time [s]")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="run directory")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scenario setting (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_sweep(sub) -> None:
    from nrtraffic.sumo.netbuild import JUNCTION_TYPES

    p = sub.add_parser(
        "sweep", help="many seeds and grid points on Dask, aggregated with confidence intervals",
        description="Run every (grid point, seed) of a scenario, and optionally SUMO's junction control on the same "
                    "seeds, on Dask distributed: a local cluster of worker processes by default, or an existing "
                    "scheduler. Each run directory is written under a temporary name and renamed when finished; "
                    "re-running the same command skips finished runs; a failing run is retried once and then "
                    "recorded as failed while the others go on. Writes DIR/sweep.csv (one row per run), "
                    "DIR/sweep_summary.csv (mean, sd, 95 %% CI per grid point and control), DIR/sweep.md and "
                    "the figures DIR/sweep.png and DIR/sweep_seeds.png. Exit status 1 when a run failed.")
    p.add_argument("scenario", type=Path, help="scenario.toml (or the folder holding it)")
    p.add_argument("--seeds", required=True, help="seeds, A:B inclusive or a comma list, e.g. 1:20")
    p.add_argument("--grid", action="append", default=[], metavar="SECTION.KEY=V1,V2,...",
                   help="a scenario setting and its values (repeatable; the grid is the product), "
                        "e.g. --grid demand.rate_veh_h=200,400,600")
    p.add_argument("--baseline", default=None, metavar="CONTROL[,CONTROL...]",
                   help=f"also run SUMO's junction control on the same seeds: {', '.join(JUNCTION_TYPES)}")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="simulated time per run [s] "
                   "(default: the scenario's)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scenario setting in every run (repeatable)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=2, help="worker processes of the local cluster (default 2)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="use an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (workers must see DIR)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_replay(sub) -> None:
    from runners.replay import ATOL, RTOL

    p = sub.add_parser(
        "replay", help="re-run a finished run headless and compare with what it recorded",
        description="Re-run a run directory from its scenario.resolved.toml and compare summary.json, vehicles.csv "
                    "and trajectories.parquet with the recorded ones: every number must satisfy "
                    "|replayed - recorded| <= atol + rtol |recorded| (wall-clock figures excepted). Exit status 0 "
                    "when they match, 1 with the differences (which figure, which vehicle, by how much) when not.")
    p.add_argument("run_dir", type=Path, help="a run directory written by run, baseline or sweep")
    p.add_argument("--rtol", type=float, default=RTOL, help=f"relative tolerance (default {RTOL:g})")
    p.add_argument("--atol", type=float, default=ATOL, help=f"absolute tolerance, in each figure's unit "
                   f"(default {ATOL:g})")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="keep the replay in DIR (default: a temporary folder, removed)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_bench(sub) -> None:
    p = sub.add_parser("bench", help="run the benchmarks and write their table",
                       description="Benchmark the compiled kernels, whole runs against SUMO alone on the same "
                                   "demand, where a run's time goes, and peak memory (ratios measured in one "
                                   "run; takes a few minutes).")
    p.add_argument("--write", type=Path, default=Path("bench/results.md"), metavar="FILE",
                   help="write the table to FILE (markdown; default bench/results.md)")
    p.add_argument("--quick", action="store_true",
                   help="short runs (120 s instead of 600 s; memory at 60 and 120 s): a smoke test, not the figures")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nrtraffic",
        description="Co-simulation of signal-free intersections: SUMO + energy-optimal planning + "
                    "Newton-Raphson-flow tracking of a dynamic bicycle model.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_run(sub)
    _add_paper(sub)
    _add_baseline(sub)
    _add_sweep(sub)
    _add_replay(sub)
    _add_bench(sub)
    args = parser.parse_args(argv)
    from nrtraffic.engine import RunFailed
    from nrtraffic.scenario import ScenarioError
    from nrtraffic.sumo.network import NetworkError
    from runners.replay import ReplayError
    from runners.sweep import SweepError

    try:
        if args.command == "run":
            return _cmd_run(args)
        if args.command == "paper":
            from runners import paper

            return paper.main(args)
        if args.command == "baseline":
            from nrtraffic import scenario
            from runners.baseline import run_baseline

            sc = scenario.load(args.scenario, args.overrides)
            res = run_baseline(sc, args.junction, args.out, seed=args.seed, duration_s=args.duration,
                               progress=not args.no_progress)
            _print_summary(res.summary, args.out)
            return 0
        if args.command == "sweep":
            from runners import sweep

            return sweep.main(args)
        if args.command == "replay":
            from runners import replay

            return replay.main(args)
        if args.command == "bench":
            from runners import bench

            return bench.main(args)
    except (ScenarioError, NetworkError) as exc:
        print(f"nrtraffic: scenario error: {exc}", file=sys.stderr)
        return 2
    except (SweepError, ReplayError) as exc:
        print(f"nrtraffic: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        print(f"nrtraffic: {exc}", file=sys.stderr)
        if exc.result.run_dir is not None:
            print(f"nrtraffic: what was finished is in {exc.result.run_dir}", file=sys.stderr)
        return 1
    return 0


def _cmd_run(args) -> int:
    from nrtraffic import scenario
    from runners.single import run_scenario

    sc = scenario.load(args.scenario, args.overrides)
    seed = sc.general.seed if args.seed is None else args.seed
    out = args.out or Path("runs") / f"{sc.general.name}-seed{seed}"
    res = run_scenario(sc, out, seed=seed, duration_s=args.duration, progress=not args.no_progress)
    _print_summary(res.summary, out)
    return 0


def _print_summary(s: dict, out: Path) -> None:
    keys = ["control", "vehicles_completed", "throughput_veh_h", "mean_delay_s", "mean_sumo_time_loss_s",
            "collisions", "collisions_geometric", "max_tracking_error_m", "steady_tracking_error_m",
            "max_lateral_dev_m", "min_bumper_gap_m", "vehicles_held", "real_time_factor"]
    print(json.dumps({k: s.get(k) for k in keys}, indent=1))
    print(f"run directory: {out}")


if __name__ == "__main__":
    sys.exit(main())
