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
    p = sub.add_parser("baseline", help="the same demand under SUMO's own junction control",
                       description="Run a junction scenario's demand and seed with SUMO driving every vehicle "
                                   "under its own junction control, into a run directory of the same form.")
    p.add_argument("scenario", type=Path, help="scenario.toml with a [junction] (or its folder)")
    p.add_argument("--junction", required=True, choices=["traffic_light", "priority", "allway_stop",
                                                         "right_before_left"], help="SUMO's junction control")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="simulated time [s]")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="run directory")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scenario setting (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_compare(sub) -> None:
    p = sub.add_parser("compare", help="nrtraffic against SUMO's junction control over demands and seeds",
                       description="Run a junction scenario under nrtraffic and SUMO's traffic_light, priority and "
                                   "allway_stop control for each demand level and seed (in parallel processes; "
                                   "finished runs are skipped), and write the comparison table and figure.")
    p.add_argument("scenario", type=Path, help="scenario.toml with a [junction]")
    p.add_argument("--rates", default="200,400,600", help="demand levels, veh/h per approach (default 200,400,600)")
    p.add_argument("--seeds", default="1:5", help="seeds, A:B inclusive or a comma list (default 1:5)")
    p.add_argument("--duration", type=float, default=1800.0, metavar="S", help="simulated time per run [s]")
    p.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_bench(sub) -> None:
    p = sub.add_parser("bench", help="run the benchmarks and print their table",
                       description="Benchmark the compiled kernels and whole runs (ratios measured in one run).")
    p.add_argument("--write", type=Path, default=None, metavar="FILE", help="also write the table to FILE (markdown)")


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
    _add_compare(sub)
    _add_bench(sub)
    args = parser.parse_args(argv)
    from nrtraffic.engine import RunFailed
    from nrtraffic.scenario import ScenarioError
    from nrtraffic.sumo.network import NetworkError

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
        if args.command == "compare":
            from runners import compare

            return compare.main(args)
        if args.command == "bench":
            from runners import bench

            return bench.main(args)
    except (ScenarioError, NetworkError) as exc:
        print(f"nrtraffic: scenario error: {exc}", file=sys.stderr)
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
