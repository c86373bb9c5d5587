"""The ``nrtraffic`` command.

Nothing but the standard library's argument parser and :mod:`runners.interrupts` is imported
before :func:`main` has installed the command's handling of SIGTERM and Ctrl-C: nrtraffic itself
(even its limits: importing the package reads every source file of it, to keep the compiled
kernels fresh) and the Python API's helpers are imported when first used.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from runners import interrupts

_SHARED = ("OutputError", "slug", "writable_dir")  # helpers shared with the Python API (runners.api)


def __getattr__(name: str):
    if name in _SHARED:
        from runners import api

        return getattr(api, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _bounded(parse, lo, hi, name: str, what: str):
    """An argparse type: ``parse(text)`` within ``[lo, hi]`` (which refuses nan; ``hi`` = inf
    refuses inf too), else an error saying ``what`` the flag takes."""
    def check(text: str):
        try:
            v = parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {name}") from None
        if not (lo <= v <= hi) or v == float("inf"):
            raise argparse.ArgumentTypeError(f"{text!r}: {what}")
        return v
    return check


def _duration(text: str) -> float:
    """--duration: simulated seconds, 0 (until every vehicle has left) to a week."""
    from nrtraffic.limits import MAX_DURATION_S

    return _bounded(float, 0.0, MAX_DURATION_S, "a number of seconds",
                    f"the simulated time must be between 0 and {MAX_DURATION_S:.0f} s")(text)


def _seed(text: str) -> int:
    """--seed: 0 to the largest seed SUMO takes."""
    from nrtraffic.limits import MAX_SEED

    return _bounded(int, 0, MAX_SEED, "a whole number", f"a seed must be between 0 and {MAX_SEED}")(text)


_tolerance = _bounded(float, 0.0, float("inf"), "a number", "a tolerance must be finite and >= 0")
GUI_DELAY_MS = 100.0  # sumo-gui's delay between steps by default [ms]: 0.1 s steps at about real time
_gui_delay = _bounded(float, 0.0, 10000.0, "a number of milliseconds", "the delay must be between 0 and 10000 ms")


def _add_run(sub) -> None:
    p = sub.add_parser("run", help="run one scenario", description="Run one scenario and write its run directory.")
    p.add_argument("scenario", type=_given_path, help="scenario.toml (or the folder holding it)")
    p.add_argument("--seed", type=_seed, default=None, help="random seed of arrivals and SUMO (default: the scenario's)")
    p.add_argument("--duration", type=_duration, default=None, metavar="S",
                   help="simulated time [s] (default: the scenario's; 0 runs until every vehicle has left)")
    p.add_argument("--out", type=_folder, default=None, metavar="DIR",
                   help="run directory (default: runs/<scenario>-seed<N>)")
    p.add_argument("--force", action="store_true",
                   help="replace the earlier run's files in --out when it is not a finished run of this configuration "
                        "(the folder's other files stay)")
    p.add_argument("--allow-outside", action="store_true",
                   help="let the scenario name files outside its own folder (refused by default)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scenario setting (repeatable), e.g. --set controller.horizon_s=0.3")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--gui", action="store_true",
                   help="watch the run in sumo-gui, opened on the controlled junctions (needs a display: DISPLAY, or "
                        "xvfb-run; vehicles coloured by state: grey approaching, amber waiting for their batch, red "
                        "held, blue under control, green released, white driven by SUMO, purple a human driver "
                        "going to its stop line, pink a human driver whose crossing is reserved)")
    p.add_argument("--gui-delay", type=_gui_delay, default=None, metavar="MS",
                   help=f"with --gui, the wall time each SUMO step takes at least [ms] (default {GUI_DELAY_MS:g}; "
                        "0: as fast as it can)")


def _add_paper(sub) -> None:
    p = sub.add_parser("paper", help="reproduce the paper's experiments",
                       description="Reproduce the experiments of Shivam et al. (IFAC 2020) and compare with its numbers.")
    p.add_argument("experiment", choices=["curved", "cbf", "all"],
                   help="curved: section 4.1, tracking on a curved road; cbf: section 4.2, barrier functions; "
                        "all: both (into DIR/curved and DIR/cbf)")
    p.add_argument("--out", type=_folder, required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=_seed, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_baseline(sub) -> None:
    from nrtraffic.sumo.netbuild import BASELINES

    p = sub.add_parser("baseline", help="the same demand under SUMO's own junction control",
                       description="Run a junction scenario's demand and seed with SUMO driving every vehicle "
                                   "under its own junction control, into a run directory of the same form.")
    p.add_argument("scenario", type=_given_path, help="scenario.toml with a [junction] (or its folder)")
    p.add_argument("--junction", required=True, choices=BASELINES, metavar="CONTROL",
                   help="SUMO's junction control: as_is (the network's own control, unchanged: its signal "
                        "programmes and right of way), actuated (SUMO's gap-based actuated signals on the "
                        "network's own phases), or the junctions rebuilt as " + ", ".join(BASELINES[2:]))
    p.add_argument("--seed", type=_seed, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--duration", type=_duration, default=None, metavar="S", help="simulated time [s]")
    p.add_argument("--out", type=_folder, required=True, metavar="DIR", help="run directory")
    p.add_argument("--force", action="store_true",
                   help="replace the earlier run's files in --out when it is not a finished run of this configuration "
                        "(the folder's other files stay)")
    p.add_argument("--allow-outside", action="store_true",
                   help="let the scenario name files outside its own folder (refused by default)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scenario setting (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_sweep(sub) -> None:
    from nrtraffic.sumo.netbuild import BASELINES

    p = sub.add_parser(
        "sweep", help="many seeds and grid points on Dask, aggregated with confidence intervals",
        description="Run every (grid point, seed) of a scenario, and optionally SUMO's junction control on the same "
                    "seeds, on Dask distributed: a local cluster of worker processes by default, an existing "
                    "scheduler, or batch jobs of a Slurm or PBS cluster (--cluster). Each run directory is written under a temporary name and renamed when finished; "
                    "re-running the same command skips finished runs; a failing run is retried once and then "
                    "recorded as failed while the others go on. Writes DIR/sweep.csv (one row per run), "
                    "DIR/sweep_summary.csv (mean, sd, 95 % CI per grid point and control), DIR/sweep.md and "
                    "the figures DIR/sweep.png and DIR/sweep_seeds.png. Exit status 1 when a run failed.")
    p.add_argument("scenario", type=_given_path, help="scenario.toml (or the folder holding it)")
    p.add_argument("--seeds", required=True, help="seeds, A:B inclusive or a comma list, e.g. 1:20")
    p.add_argument("--grid", action="append", default=[], metavar="SECTION.KEY=V1,V2,...",
                   help="a scenario setting and its values (repeatable; the grid is the product), "
                        "e.g. --grid demand.rate_veh_h=200,400,600")
    p.add_argument("--baseline", default=None, metavar="CONTROL[,CONTROL...]",
                   help=f"also run SUMO's junction control on the same seeds: {', '.join(BASELINES)}")
    p.add_argument("--duration", type=_duration, default=None, metavar="S", help="simulated time per run [s] "
                   "(default: the scenario's)")
    p.add_argument("--allow-outside", action="store_true",
                   help="let the scenario name files outside its own folder (refused by default)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a scenario setting in every run (repeatable)")
    _add_cluster_args(p)


def _add_cluster_args(p) -> None:
    """Where a sweep runs and where it writes: shared by sweep and robustness."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=2, help="worker processes of the local cluster (default 2)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="use an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (workers must see DIR)")
    from runners.clusters import add_arguments

    add_arguments(p, where)  # --cluster slurm|pbs and the batch jobs' cores, memory, walltime, queue, account
    p.add_argument("--out", type=_folder, required=True, metavar="DIR", help="output folder")
    p.add_argument("--force", action="store_true",
                   help="run again, and replace, run directories in --out that were made with another "
                        "configuration (without it such a resume is refused); also allows more than 20000 runs")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_robustness(sub) -> None:
    p = sub.add_parser(
        "robustness", help="the controller under measurement noise and actuator lag",
        description="Run the paper's barrier experiment (paper_cbf, seeds 1-5) and cross4 (400 veh/h per approach, "
                    "seeds 1-3, 600 s) without disturbances, at three levels of measurement noise, at the middle "
                    "level with a damped Newton step, a gap margin or a state observer, and with an actuator lag "
                    "(runners/robustness.py lists them), as one resumable sweep. Writes DIR/sweep.md (traffic, "
                    "and safety and tracking per scenario and level), DIR/sweep.csv, DIR/sweep_summary.csv and "
                    "DIR/robustness.png.")
    _add_cluster_args(p)


def _add_replay(sub) -> None:
    from runners.replay import ATOL, RTOL

    p = sub.add_parser(
        "replay", help="re-run a finished run headless and compare with what it recorded",
        description="Re-run a run directory from its scenario.resolved.toml and compare summary.json, vehicles.csv "
                    "and trajectories.parquet with the recorded ones: every number must satisfy "
                    "|replayed - recorded| <= atol + rtol |recorded| (wall-clock figures excepted). Exit status 0 "
                    "when they match, 1 with the differences (which figure, which vehicle, by how much) when not.")
    p.add_argument("run_dir", type=_given_path, help="a run directory written by run, baseline or sweep")
    p.add_argument("--rtol", type=_tolerance, default=RTOL, help=f"relative tolerance (default {RTOL:g})")
    p.add_argument("--atol", type=_tolerance, default=ATOL, help=f"absolute tolerance, in each figure's unit "
                   f"(default {ATOL:g})")
    p.add_argument("--out", type=_folder, default=None, metavar="DIR",
                   help="keep the replay in DIR (default: a temporary folder, removed); never the run itself")
    p.add_argument("--force", action="store_true",
                   help="replace an earlier run's files in --out when it holds one")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_compare(sub) -> None:
    p = sub.add_parser(
        "compare", help="finished runs of one scenario side by side (nrtraffic and SUMO's controls)",
        description="Put finished runs of one scenario side by side, e.g. a run and its baselines: their headline "
                    "figures, and per approach and per movement throughput, delay (mean, 95th percentile), level "
                    "of service, stops and queues (mean, 95th percentile over the detector periods, longest), "
                    "each run's own figures over its measurement window. Writes DIR/compare.html, "
                    "DIR/compare_runs.csv, DIR/compare_movements.csv and DIR/compare_approaches.csv (one row "
                    "per run and movement or approach) and prints the tables. Exit status 2 for a folder that is "
                    "not a finished run, or runs of different scenarios.")
    p.add_argument("run_dirs", type=_given_path, nargs="+", metavar="RUN_DIR",
                   help="run directories written by run or baseline (or a sweep's runs), two or more")
    p.add_argument("--out", type=_folder, default=None, metavar="DIR",
                   help="where to write the report (default: runs/<scenario>-compare): not a run directory, and "
                        "not a folder that already holds compare.html or compare_*.csv (see --force); other "
                        "files in it are left alone")
    p.add_argument("--force", action="store_true",
                   help="replace the comparison's own files (compare.html, compare_*.csv) in a folder that holds "
                        "them; nothing else in it is touched")


def _add_bench(sub) -> None:
    p = sub.add_parser("bench", help="run the benchmarks and write their table",
                       description="Benchmark the compiled kernels, whole runs against SUMO alone on the same "
                                   "demand, where a run's time goes, and peak memory (ratios measured in one "
                                   "run; takes a few minutes).")
    p.add_argument("--write", type=os.path.expanduser, default=None, metavar="FILE",
                   help="write the table to FILE (markdown; default bench/results.md, with --scale bench/scale.md; "
                        "with --quick only where given)")
    p.add_argument("--quick", action="store_true",
                   help="short runs (120 s instead of 600 s; memory at 60 and 120 s): a smoke test, not the figures")
    p.add_argument("--scale", action="store_true",
                   help="only the scale benchmark: grids of 1, 4, 16 and 36 junctions of two-lane roads, every "
                        "junction controlled: cost per controlled vehicle-step and memory (its figure goes beside "
                        "the table, as .png)")


class _Version(argparse.Action):
    """``--version``: nrtraffic's version and SUMO's, then exit 0 (SUMO is not started)."""

    def __init__(self, option_strings, dest, **kw):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        print(version_text())
        parser.exit(0)


def version_text() -> str:
    """``nrtraffic X.Y.Z`` and ``SUMO X.Y.Z`` (the eclipse-sumo and libsumo packages installed),
    one a line."""
    from importlib.metadata import PackageNotFoundError, version

    from nrtraffic import __version__

    def of(package: str) -> str | None:
        try:
            return version(package)
        except PackageNotFoundError:
            return None

    sumo, lib = of("eclipse-sumo"), of("libsumo")
    if sumo is None:
        line = "SUMO not installed (pip install eclipse-sumo libsumo, or make install)"
    else:
        line = f"SUMO {sumo}" + ("" if lib == sumo else f" (libsumo {lib or 'not installed'})")
    return f"nrtraffic {__version__}\n{line}"


def display_missing(out: Path) -> str | None:
    """Why ``--gui`` cannot open sumo-gui here: on Linux and the BSDs, a graphical program needs
    ``DISPLAY`` (X11) or ``WAYLAND_DISPLAY``; None where one is set, or on macOS and Windows. The
    message names the virtual display to run under, and the run's ``.sumocfg`` to open after a
    headless run."""
    if not sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return None
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    cfg = Path(out) / "sumo" / "run.sumocfg"
    return ("--gui needs a display, and neither DISPLAY nor WAYLAND_DISPLAY is set (no desktop session, e.g. over "
            "ssh or in CI). Run it under a virtual display: xvfb-run -a nrtraffic run ... --gui (apt-get install "
            "xvfb); or run without --gui and then open the run's demand in sumo-gui on a machine with a display: "
            f"sumo-gui -c {cfg} (SUMO driving every vehicle, without the controller)")


def _sumo_missing() -> str | None:
    """What of SUMO is missing (its binaries, libsumo), with the package to install; None when
    nothing is."""
    from nrtraffic.sumo import netbuild

    try:
        for name in ("sumo", "netconvert"):
            netbuild.sumo_binary(name)
    except netbuild.SumoToolError as exc:
        return f"{exc} (or run make install)"
    try:
        import libsumo  # noqa: F401
    except ImportError:
        return "libsumo is not installed: pip install libsumo (or run make install)"
    return None


def _add_schema(sub) -> None:
    p = sub.add_parser("schema", help="the scenario file format as a JSON Schema (or a key reference)",
                       description="Print the JSON Schema of scenario files, generated from the declaration of the "
                                   "format (editors that read JSON Schema check and complete scenario.toml with it; "
                                   "a committed copy is docs/scenario.schema.json).")
    p.add_argument("--markdown", action="store_true", help="the key reference in markdown instead (docs/scenario_keys.md)")
    p.add_argument("--write", type=os.path.expanduser, default=None, metavar="FILE",
                   help="write to FILE instead of printing")


def _given_path(text: str) -> Path:
    """A file or folder to read, with a leading ``~`` read as the home folder (as ``--out`` is)."""
    return Path(os.path.expanduser(text))


def _folder(text: str) -> Path:
    """An ``--out`` folder as given, with a leading ``~`` read as the home folder (as the shell reads
    it unquoted, and as SUMO and the table writers read it: the whole run goes to one place): an
    empty one (``--out ""``, an unset shell variable) would be the working folder, which nobody means."""
    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: name a folder (--out runs/mine)")
    return Path(os.path.expanduser(text))


class _ReaderMayGo:
    """The command's stdout: when its reader has gone (a pipe closed early, ``| head -1``), what it
    prints goes nowhere and the command ends with its own status; its result is its files, which
    are written (it had ended with exit 1, "cannot write the run's files", over a run that was ok)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._gone()
            return len(text)

    def flush(self):
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._gone()

    def _gone(self):
        devnull = os.open(os.devnull, os.O_WRONLY)  # (what is still buffered goes there too)
        os.dup2(devnull, self._stream.fileno())
        os.close(devnull)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def main(argv: list[str] | None = None) -> int:
    """The ``nrtraffic`` command; returns its exit status. SIGTERM and Ctrl-C are handled from its
    first instruction (:mod:`runners.interrupts`; nothing heavy is imported before it): a run that
    they stop always leaves a summary.json. As the process's command (``argv`` None: the console
    script, ``python -m runners.cli``) a signal after it has its status is ignored (the process is
    exiting with that status, :func:`~runners.interrupts.settle`); called with ``argv`` (from
    Python) the caller's handlers are put back."""
    interrupts.install()
    if argv is None and not isinstance(sys.stdout, _ReaderMayGo):
        sys.stdout = _ReaderMayGo(sys.stdout)
    try:
        try:
            code = _main(argv)
        except KeyboardInterrupt as exc:  # (before the command's own handling: while it starts)
            interrupts.finish()
            print(f"nrtraffic: stopped: {exc or 'interrupted'}", file=sys.stderr)
            return 1
        interrupts.finish()
        stop = interrupts.pending()
        if stop is not None and code == 0:
            print(f"nrtraffic: stopped by {stop} after the run had finished; its outputs are complete",
                  file=sys.stderr)
            code = 1
        return code
    finally:
        if argv is not None:
            interrupts.uninstall()
        else:
            interrupts.settle()


def build_parser() -> argparse.ArgumentParser:
    """The command line's parser (every command and option; parsing checks them, runs nothing)."""
    parser = argparse.ArgumentParser(
        prog="nrtraffic",
        description="Co-simulation of signal-free intersections: SUMO + energy-optimal planning + "
                    "Newton-Raphson-flow tracking of a dynamic bicycle model.",
    )
    parser.add_argument("--version", action=_Version, help="print the versions of nrtraffic and SUMO and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_run(sub)
    _add_paper(sub)
    _add_baseline(sub)
    _add_sweep(sub)
    _add_robustness(sub)
    _add_replay(sub)
    _add_compare(sub)
    _add_bench(sub)
    _add_schema(sub)
    return parser


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    given, argv = list(sys.argv[1:] if argv is None else argv), []
    while given:  # (--seeds -1:0 would be taken for an option: it is checked as a range instead)
        a = given.pop(0)
        argv.append(f"--seeds={given.pop(0)}" if a == "--seeds" and given and given[0].startswith("-") else a)
    args = parser.parse_args(argv)
    if args.command not in ("run", "baseline"):
        interrupts.arm()  # (a run arms once its run directory says "running")
    if args.command != "schema":
        missing = _sumo_missing()
        if missing:
            print(f"nrtraffic: {missing}", file=sys.stderr)
            return 2
    from nrtraffic.engine import RunFailed
    from nrtraffic.scenario import ScenarioError
    from nrtraffic.sumo.network import NetworkError
    from nrtraffic.sumo.netbuild import SumoToolError
    from runners.api import OutputError
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
            from runners.api import claim as _claim
            from runners.api import one_source, refused
            from runners.baseline import run_baseline

            one_source(args.overrides, args.seed, args.duration)
            sc = scenario.load(args.scenario, args.overrides, allow_outside=args.allow_outside)
            new = _claim(args.out, sc, args.seed, args.duration, f"sumo_{args.junction}", args.force)
            with refused(args.out, new):
                res = run_baseline(sc, args.junction, args.out, seed=args.seed, duration_s=args.duration,
                                   progress=not args.no_progress, report=True)
            _print_summary(res.summary, args.out)
            return 0
        if args.command == "sweep":
            from runners import sweep

            return sweep.main(args)
        if args.command == "robustness":
            from runners import robustness

            return robustness.main(args)
        if args.command == "replay":
            from runners import replay

            return replay.main(args)
        if args.command == "compare":
            from runners import compare

            return compare.main(args)
        if args.command == "bench":
            from runners import bench

            return bench.main(args)
        if args.command == "schema":
            from nrtraffic.scenario_schema import markdown_reference, schema_text

            text = markdown_reference() if args.markdown else schema_text()
            if args.write is None:
                print(text, end="")
            else:
                from runners.api import writable_file, write_file

                # (an earlier output of the command begins as this one does: schema or key reference)
                write_file(writable_file(args.write, own=(text[:30],)), text)
            return 0
    except (ScenarioError, NetworkError) as exc:
        print(f"nrtraffic: scenario error: {exc}", file=sys.stderr)
        return 2
    except (SweepError, ReplayError, OutputError) as exc:
        print(f"nrtraffic: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        print(f"nrtraffic: {exc}", file=sys.stderr)
        if exc.result.run_dir is not None:
            print(f"nrtraffic: what was finished is in {exc.result.run_dir}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # outside a run (a run turns it into RunFailed)
        print(f"nrtraffic: stopped: {exc or 'interrupted'}", file=sys.stderr)
        return 1
    except SumoToolError as exc:  # netconvert or another SUMO tool (a baseline's network)
        stop = interrupts.pending()
        print(f"nrtraffic: {f'stopped by {stop}: ' if stop else ''}{exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # a full disk, a folder that went away: what could not be written, in one line
        where = f" {exc.filename}" if exc.filename else " the run's files"
        print(f"nrtraffic: cannot write{where}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    return 0


def _cmd_run(args) -> int:
    from nrtraffic import scenario
    from runners.api import OutputError, slug
    from runners.api import claim as _claim
    from runners.api import one_source, refused
    from runners.single import run_scenario

    one_source(args.overrides, args.seed, args.duration)
    sc = scenario.load(args.scenario, args.overrides, allow_outside=args.allow_outside)
    seed = sc.general.seed if args.seed is None else args.seed
    out = args.out or Path("runs") / f"{slug(sc.general.name)}-seed{seed}"
    if args.gui_delay is not None and not args.gui:  # (a flag that would do nothing)
        raise OutputError("--gui-delay sets the delay of --gui, which is not given: add --gui, or leave it out")
    args.gui_delay = GUI_DELAY_MS if args.gui_delay is None else args.gui_delay
    if args.gui:
        no_display = display_missing(out)
        if no_display:
            raise OutputError(no_display)  # (exit 2, before SUMO starts)
    new = _claim(out, sc, seed, args.duration, "nrtraffic", args.force)
    with refused(out, new):
        res = run_scenario(sc, out, seed=seed, duration_s=args.duration, progress=not args.no_progress,
                           gui=args.gui, gui_delay_ms=args.gui_delay, report=True)
    _print_summary(res.summary, out)
    return 0


def _print_summary(s: dict, out: Path) -> None:
    """The run's headline figures and its movement table, rounded, on stdout."""
    keys = ["control", "measure_from_s", "measure_to_s", "vehicles_completed", "throughput_veh_h", "demand_veh_h",
            "served_share", "vehicles_waiting_to_enter", "mean_delay_s", "los", "p95_delay_s",
            "mean_sumo_time_loss_s", "collisions", "collisions_geometric", "max_tracking_error_m",
            "steady_tracking_error_m", "max_lateral_dev_m", "min_bumper_gap_m", "vehicles_held", "real_time_factor"]

    def short(v):  # four significant digits: 4.44e-15, not 4.440892098500626e-15
        return f"{v:.4g}" if isinstance(v, float) else ("-" if v is None else str(v))

    width = max(len(k) for k in keys)
    for k in keys:
        if k in s:
            print(f"{k:<{width}}  {short(s[k])}")
    table = out / "movements.csv"
    if table.is_file():
        import pandas as pd

        m = pd.read_csv(table)
        if len(m):
            thresholds = m["los_thresholds"].iloc[0]
            m = m.drop(columns=["los_thresholds"])
            # one format per column, "-" where there is no value
            formats = {"throughput_veh_h": "{:.0f}", "mean_delay_s": "{:.1f}", "p95_delay_s": "{:.1f}",
                       "stops_per_vehicle": "{:.2f}", "fuel_ml_per_vehicle": "{:.1f}"}
            for col, fmt in formats.items():
                if col in m:
                    m[col] = [fmt.format(v) if pd.notna(v) else "-" for v in m[col]]
            print(f"\nper movement (movements.csv; LOS by the {thresholds} HCM thresholds):")
            print(m.to_string(index=False, na_rep="-"))
    from nrtraffic.report import console_sections

    print(console_sections(s), end="")  # (a corridor's junctions and travel times, the split by driver)
    for w in s.get("warnings") or ():
        print(f"warning: {w}")
    print(f"run directory: {out}")


if __name__ == "__main__":
    sys.exit(main())
