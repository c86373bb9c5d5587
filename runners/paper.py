"""``nrtraffic paper``: reproduce the experiments of Shivam et al. (IFAC 2020).

``curved`` (section 4.1): five vehicles on the curved road with a 100 % predictor mass error, and
the variants the paper reports (straight road, no mass error, predictor step 0.002 s), plus a sweep
of the prediction horizon T, which the paper does not state.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from nrtraffic import plots, scenario
from nrtraffic.results import read_trajectories
from runners.single import run_scenario

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "sumo_scenarios"

# the paper's predictor: forward Euler at Delta t = 0.001 s (the scenarios use RK4, docs/method.md)
EULER = ['controller.predictor="euler"', "controller.predictor_step_s=0.001"]
CURVED_VARIANTS = {
    "curved": [],
    "straight": ['scenario.network="straight.net.xml"'],
    "no_mass_error": ["controller.predictor_mass_factor=1.0"],
    "predictor_step_0.002": ['controller.predictor="euler"', "controller.predictor_step_s=0.002"],
}
# runs repeated with the paper's Euler predictor, for the predictor comparison of each table
CURVED_EULER = ("curved", "straight", "no_mass_error")
CBF_EULER = ("without_cbf", "with_cbf")
HORIZONS = (0.05, 0.1, 0.2, 0.3, 0.5)


def _fmt_cm(x):
    return "n/a" if x is None else f"{100 * x:.2f} cm"


# the files each experiment writes at the top of its folder, beside its runs' folders
CURVED_FILES = ("fig2_distance.png", "fig3_tracking_error.png", "fig4_acceleration.png", "paper_table.md",
                "paper_results.json")
CBF_FILES = ("fig5_speeds.png", "fig6_distance.png", "fig7_lateral_deviation.png", "fig8_tracking_error.png",
             "fig9_acceleration.png", "fig10_steering.png", "fig_antiwindup.png", "paper_table.md",
             "paper_results.json")


def _run_all(path: Path, runs: dict, seed, progress: bool, out: Path, files) -> tuple[dict, dict, dict]:
    """Every run of an experiment (``runs``: :func:`_curved_runs`, :func:`_cbf_runs`), each into
    its run directory, whose earlier run (:func:`claim_out` checked that it holds nothing else)
    goes first; their summaries by table: the variants, the Euler predictor's, the horizon sweep.
    The figures and tables of an earlier reproduction in ``out`` (``files``) go before any run: a
    reproduction stopped halfway would leave them beside runs they do not describe."""
    from runners.single import remove_run_files

    for name in files:
        if (out / name).is_file() or (out / name).is_symlink():
            (out / name).unlink()
    done = {"variants": {}, "euler": {}, "horizon": {}}
    for (table, key), (overrides, run_dir) in runs.items():
        if run_dir.is_dir():
            remove_run_files(run_dir)
        done[table][key] = run_scenario(scenario.load(path, overrides), run_dir, seed=seed, progress=progress).summary
    return done["variants"], done["euler"], done["horizon"]


def _layout(out: Path, experiment: str) -> tuple[set[str], list[Path]]:
    """What ``nrtraffic paper EXPERIMENT --out OUT`` writes: the names at the top of ``out`` and the
    run directories."""
    parts = [("curved", _curved_runs, CURVED_FILES), ("cbf", _cbf_runs, CBF_FILES)]
    top, dirs = set(), []
    for name, runs, files in parts:
        if experiment not in (name, "all"):
            continue
        sub = out / name if experiment == "all" else out
        dirs += [d for _, d in runs(sub).values()]
        top |= {name} if experiment == "all" else {d.relative_to(out).parts[0] for d in dirs} | set(files)
    return top, dirs


def claim_out(out: Path, experiment: str) -> None:
    """Make ``out`` ready for the experiment, or refuse it (:class:`~runners.api.OutputError`, exit 2)
    before anything runs: a folder SUMO can use and not in a sweep's, either new, empty or an earlier
    output of the same command (its manifest lists what it wrote), with no file of the user's in its
    run directories. Its manifest then lists, before anything is written, what it will write."""
    from runners.api import OutputError, usable_path, writable_dir
    from runners.single import MANIFEST, in_a_run, in_a_sweep, normal, read_manifest
    from runners.sweep import foreign_files, record_tables

    out = Path(out)
    usable_path(out)
    owner = in_a_sweep(out)
    if owner is not None and (owner != normal(out) or (out / "runs").exists()):
        raise OutputError(f"--out {out} lies in the sweep folder {owner}: choose a folder outside it")
    inside = in_a_run(out)
    if inside is not None:
        raise OutputError(f"--out {out} lies in the run directory {inside}: choose a folder outside it")
    top, dirs = _layout(out, experiment)
    if out.is_dir():
        m = read_manifest(out, sweep=True)
        own = (set(m["created"]) - set(m["preexisting"]) if m is not None else set()) | {MANIFEST}
        foreign = sorted(p.name for p in out.iterdir() if p.name not in own)
        clash = [n for n in foreign if n in top]
        if clash or (foreign and m is None):
            raise OutputError(f"--out {out} holds {', '.join((clash or foreign)[:5])}, which no earlier reproduction "
                              "there wrote (files of your own?): choose an empty folder, or the folder of an earlier "
                              "`nrtraffic paper` to run it again")
        for d in dirs:
            mine = foreign_files(d) if d.is_dir() else []
            if mine:
                raise OutputError(f"{d} holds {', '.join(mine[:3])}, which its run did not write (files of your "
                                  "own?): the run there would be replaced; move them out of the folder")
    writable_dir(out)
    record_tables(out, written=False, planned=sorted(top))


def _curved_runs(out: Path) -> dict:
    """The curved-road experiment's runs: ``(table, key) -> (overrides, run directory)``."""
    runs = {("variants", k): (v, out / k) for k, v in CURVED_VARIANTS.items()}
    runs.update({("euler", k): (CURVED_VARIANTS[k] + EULER, out / "euler" / k) for k in CURVED_EULER})
    runs.update({("horizon", T): ([f"controller.horizon_s={T}"], out / "horizon" / f"T{T}") for T in HORIZONS})
    return runs


def run_curved(out: Path, seed: int | None = None, progress: bool = True) -> dict:
    """Run the curved-road experiment and its variants; write figures and ``paper_table.md``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = SCENARIOS / "paper_curved" / "scenario.toml"
    results, euler, sweep = _run_all(path, _curved_runs(out), seed, progress, out, CURVED_FILES)
    base = scenario.load(path)
    # figures of the main run
    main = out / "curved"
    traj = read_trajectories(main)
    veh = pd.read_csv(main / "vehicles.csv")
    zone_end = base.zones.control_zone_m + base.zones.merging_zone_m
    plots.distance_travelled(traj, veh, out / "fig2_distance.png", zone_end)
    plots.per_vehicle(traj, veh, "tracking_error_m", "tracking error [cm]", "Tracking error |y - r|",
                      out / "fig3_tracking_error.png", scale=100.0)
    plots.per_vehicle(traj, veh, "a_cmd", "longitudinal acceleration [m/s$^2$]", "Longitudinal acceleration a_l",
                      out / "fig4_acceleration.png", hlines=((-0.48, "paper: |a| < 0.48"), (0.48, "")))
    table = _curved_table(results, sweep, base, euler)
    (out / "paper_table.md").write_text(table)
    (out / "paper_results.json").write_text(json.dumps({"variants": results, "horizon_sweep": sweep,
                                                        "euler_predictor": euler}, indent=1))
    print(table)
    return results


def _predictor_section(runs: dict, euler: dict, figures: list[tuple[str, str, callable]], base) -> list[str]:
    """Lines comparing each figure of ``runs`` with the same runs under the paper's Euler predictor."""
    c = base.controller
    lines = [
        "",
        f"## Predictor: {c.predictor.upper()} (Dt = {c.predictor_step_s} s nominal) against the paper's Euler "
        "(Dt = 0.001 s)",
        "",
        "Every figure above is measured with the scenario's predictor; the same runs with the paper's forward-Euler",
        "predictor give (speed: `nrtraffic bench`):",
        "",
        f"| run | figure | {c.predictor} | euler | difference |",
        "|---|---|---|---|---|",
    ]
    for name in euler:
        for label, key, fmt in figures:
            a, b = runs[name].get(key), euler[name].get(key)
            diff = "" if a is None or b is None else fmt(a - b)
            lines.append(f"| {name} | {label} | {'n/a' if a is None else fmt(a)} | {'n/a' if b is None else fmt(b)} "
                         f"| {diff} |")
    return lines


def _curved_table(r: dict, sweep: dict, base, euler: dict) -> str:
    c = r["curved"]
    rows = []

    def row(what, paper, measured, ok, note=""):
        rows.append(f"| {what} | {paper} | {measured} | {'yes' if ok else 'NO'} | {note} |")

    row("transient tracking error (first 3 s)", "< 6 cm", _fmt_cm(c["transient_tracking_error_m"]),
        c["transient_tracking_error_m"] < 0.06)
    row("steady-state tracking error (after 3 s)", "< 2 cm", _fmt_cm(c["steady_tracking_error_m"]),
        c["steady_tracking_error_m"] < 0.02)
    row("longitudinal acceleration", "< 0.48 m/s^2 (< 5 % g)", f"{c['max_abs_accel_mps2']:.3f} m/s^2",
        c["max_abs_accel_mps2"] < 0.48)
    s = r["straight"]
    row("straight road, steady-state error", "1.34 cm", _fmt_cm(s["steady_tracking_error_m"]),
        s["steady_tracking_error_m"] <= 0.0134)
    n = r["no_mass_error"]
    row("no mass error, steady-state error", "1.34 cm", _fmt_cm(n["steady_tracking_error_m"]),
        n["steady_tracking_error_m"] <= 0.0134)
    d = r["predictor_step_0.002"]
    ratio = d["steady_tracking_error_m"] / euler["curved"]["steady_tracking_error_m"]
    row("Euler predictor step 0.002 s, steady-state error", "~ +50 % (about 3 cm)",
        f"{_fmt_cm(d['steady_tracking_error_m'])} ({100 * (ratio - 1):+.1f} % against Euler at 0.001 s)",
        d["steady_tracking_error_m"] <= 0.03, "absolute value below the paper's; the increase is smaller (see docs/paper.md)")
    row("collisions", "0", str(c["collisions"]), c["collisions"] == 0)
    row("vehicles completing", "5", str(c["vehicles_completed"]), c["vehicles_completed"] == 5)
    lines = [
        "# Paper experiment 1: tracking on a curved road (Shivam et al. 2020, section 4.1)",
        "",
        f"Horizon T = {base.controller.horizon_s} s, alpha = {base.controller.alpha}, plant dt = "
        f"{base.controller.plant_step_s} s, predictor {base.controller.predictor.upper()} at Dt = "
        f"{base.controller.predictor_step_s} s (nominal), predictor mass x"
        f"{base.controller.predictor_mass_factor}. Tracking error: distance between the centre of gravity and its"
        " reference, at every plant step.",
        "",
        "| figure | paper | measured | meets | note |",
        "|---|---|---|---|---|",
        *rows,
        "",
        "## Effect of the prediction horizon T (curved road, mass x2)",
        "",
        "| T [s] | transient error | steady-state error | max lateral deviation | max abs accel [m/s^2] | real-time factor |",
        "|---|---|---|---|---|---|",
    ]
    for T, sm in sweep.items():
        lines.append(
            f"| {T} | {_fmt_cm(sm['transient_tracking_error_m'])} | {_fmt_cm(sm['steady_tracking_error_m'])} | "
            f"{_fmt_cm(sm['max_lateral_dev_m'])} | {sm['max_abs_accel_mps2']:.3f} | {sm['real_time_factor']:.1f} |"
        )
    cm = lambda x: f"{100 * x:.3f} cm"  # noqa: E731
    lines += _predictor_section(r, euler, [
        ("transient tracking error", "transient_tracking_error_m", cm),
        ("steady-state tracking error", "steady_tracking_error_m", cm),
        ("max abs acceleration [m/s^2]", "max_abs_accel_mps2", lambda x: f"{x:.3f}"),
        ("max lateral deviation", "max_lateral_dev_m", cm),
        ("collisions", "collisions", lambda x: f"{x:d}"),
        ("vehicles completing", "vehicles_completed", lambda x: f"{x:d}"),
    ], base)
    return "\n".join(lines) + "\n"


CBF_VARIANTS = {
    "without_cbf": ["barriers.longitudinal=false", "barriers.lateral=false"],
    "with_cbf": [],
    "with_cbf_no_antiwindup": ["barriers.anti_windup=false"],
}
CBF_HORIZONS = (0.2, 1.0, 4.0)
# anti-windup shown at the short horizon, where the unfiltered tracker state matters
ANTIWINDUP_VARIANTS = {
    "T0.2_with_cbf": ["controller.horizon_s=0.2"],
    "T0.2_with_cbf_no_antiwindup": ["controller.horizon_s=0.2", "barriers.anti_windup=false"],
}
CBF_TIME_OFFSET_S = 5.0  # simulation time = paper time + 5 s


def _paper_time(df: pd.DataFrame) -> pd.DataFrame:
    df = df.copy()
    df["t"] = df["t"] - CBF_TIME_OFFSET_S
    return df


def _cbf_runs(out: Path) -> dict:
    """The barrier experiment's runs: ``(table, key) -> (overrides, run directory)``."""
    runs = {("variants", k): (v, out / k) for k, v in CBF_VARIANTS.items()}
    runs.update({("variants", k): (v, out / "antiwindup" / k) for k, v in ANTIWINDUP_VARIANTS.items()})
    runs.update({("euler", k): (CBF_VARIANTS[k] + EULER, out / "euler" / k) for k in CBF_EULER})
    runs.update({("horizon", T): (CBF_VARIANTS["without_cbf"] + [f"controller.horizon_s={T}"],
                                  out / "horizon_without_cbf" / f"T{T}") for T in CBF_HORIZONS})
    return runs


def run_cbf(out: Path, seed: int | None = None, progress: bool = True) -> dict:
    """Run the barrier-function experiment with and without barriers; figures 5-10 and the table."""
    from nrtraffic.results import read_fcd

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = SCENARIOS / "paper_cbf" / "scenario.toml"
    results, euler, sweep = _run_all(path, _cbf_runs(out), seed, progress, out, CBF_FILES)
    base = scenario.load(path)
    d0 = base.barriers.min_gap_m + base.vehicle.params().length
    tr = {k: _paper_time(read_trajectories(out / k)) for k in CBF_VARIANTS}
    tr.update({k: _paper_time(read_trajectories(out / "antiwindup" / k)) for k in ANTIWINDUP_VARIANTS})
    fcd = _paper_time(read_fcd(out / "with_cbf" / "fcd.xml"))
    plots.cbf_figures(tr["with_cbf"], tr["without_cbf"], fcd, d0, base.barriers.max_lateral_dev_m, out,
                      no_antiwindup=tr["with_cbf_no_antiwindup"])
    plots.antiwindup_figure(tr["T0.2_with_cbf"], tr["T0.2_with_cbf_no_antiwindup"], out / "fig_antiwindup.png")
    table = _cbf_table(results, sweep, base, d0, tr, euler)
    (out / "paper_table.md").write_text(table)
    (out / "paper_results.json").write_text(json.dumps({"variants": results, "horizon_sweep": sweep,
                                                        "euler_predictor": euler}, indent=1))
    print(table)
    return results


def _cbf_table(r: dict, sweep: dict, base, d0: float, tr: dict, euler: dict) -> str:
    wo, w = r["without_cbf"], r["with_cbf"]
    rows = []

    def row(what, paper, measured, ok):
        rows.append(f"| {what} | {paper} | {measured} | {'yes' if ok else 'NO'} |")

    row("without barriers: peak lateral deviation", "about 1.6 m", f"{wo['max_lateral_dev_m']:.2f} m",
        abs(wo["max_lateral_dev_m"] - 1.6) <= 0.25)
    row("without barriers: runs into the leader after its slowdown", "yes",
        f"SUMO collisions {wo['collisions']}, min bumper gap {wo['min_bumper_gap_m']:.2f} m",
        wo["collisions"] > 0 and wo["min_bumper_gap_m"] < 0)
    row("with barriers: peak lateral deviation", "about 0.27 m, never above 0.5 m",
        f"{w['max_lateral_dev_m']:.3f} m", w["max_lateral_dev_m"] <= base.barriers.max_lateral_dev_m)
    row("with barriers: centre distance to the leader", f">= {d0:.1f} m", f"min {w['min_center_distance_m']:.3f} m",
        w["min_center_distance_m"] >= d0 - 0.05)
    row("with barriers: collisions", "0", str(w["collisions"] + w["collisions_geometric"]),
        w["collisions"] + w["collisions_geometric"] == 0)
    t = tr["with_cbf"]
    late = t[t["t"] > 95.0]
    spread = late["tracking_error_m"].max() - late["tracking_error_m"].min() if len(late) else float("nan")
    row("with barriers: tracking error constant after the leader speeds up", "constant",
        f"{late['tracking_error_m'].mean():.2f} m, spread {spread:.3f} m over the last {late['t'].max() - 95:.0f} s",
        spread < 0.1)
    lines = [
        "# Paper experiment 2: barrier functions (Shivam et al. 2020, section 4.2)",
        "",
        f"Horizon T = {base.controller.horizon_s} s, alpha = {base.controller.alpha}; longitudinal barrier with "
        f"d0 = {d0:.1f} m between centres (bumper gap {base.barriers.min_gap_m} m, cars "
        f"{base.vehicle.params().length} m long), a_bar = {base.barriers.max_braking_mps2} m/s^2; lateral barrier "
        f"y_max = {base.barriers.max_lateral_dev_m} m, a_tilde = {base.barriers.max_lateral_accel_mps2} m/s^2, "
        f"gamma = {base.barriers.lateral_gamma}. Times are the paper's (simulation time - 5 s).",
        "",
        "| figure | paper | measured | meets |",
        "|---|---|---|---|",
        *rows,
        "",
        "## Barrier activity",
        "",
        "| run | longitudinal active | lateral active | longitudinal fallbacks | lateral fallbacks | peak lateral | min centre distance | final tracking error |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, sm in r.items():
        fin = tr[name]["tracking_error_m"].iloc[-1]
        la = sm["cbf_long_active_frac"] if sm["barriers_longitudinal"] else None
        lt = sm["cbf_lat_active_frac"] if sm["barriers_lateral"] else None
        lines.append(
            f"| {name} | {'off' if la is None else f'{100 * la:.1f} %'} | {'off' if lt is None else f'{100 * lt:.1f} %'} | "
            f"{sm['cbf_long_fallbacks']} | {sm['cbf_lat_fallbacks']} | {sm['max_lateral_dev_m']:.3f} m | "
            f"{sm['min_center_distance_m']:.3f} m | {fin:.2f} m |"
        )
    lines += [
        "",
        "The T0.2 runs use the horizon of paper_curved (0.2 s); without anti-windup the tracker integrates its",
        "own, unfiltered input, which winds up against the longitudinal barrier and, through the coupling of",
        "the Newton step, drives the steering to its bound and the car off the lane centre",
        "(fig_antiwindup.png; the plotted steering is the last plant step of each SUMO step).",
        "",
        "## Effect of the prediction horizon T without barriers",
        "",
        "| T [s] | peak lateral deviation | collisions |",
        "|---|---|---|",
    ]
    for T, sm in list(sweep.items()) + [(base.controller.horizon_s, wo)]:
        lines.append(f"| {T} | {sm['max_lateral_dev_m']:.3f} m | {sm['collisions']} |")
    m4 = lambda x: f"{x:.4f} m"  # noqa: E731
    m3 = lambda x: f"{x:.3f} m"  # noqa: E731  (distances and gaps are written to 1 mm)
    lines += _predictor_section(r, euler, [
        ("peak lateral deviation", "max_lateral_dev_m", m4),
        ("min centre distance", "min_center_distance_m", m3),
        ("min bumper gap", "min_bumper_gap_m", m3),
        ("collisions (SUMO)", "collisions", lambda x: f"{x:d}"),
        ("max tracking error", "max_tracking_error_m", m4),
    ], base)
    return "\n".join(lines) + "\n"


def main(args) -> int:
    progress = not args.no_progress
    claim_out(Path(args.out), args.experiment)
    if args.experiment in ("curved", "all"):
        run_curved(Path(args.out) / "curved" if args.experiment == "all" else args.out, seed=args.seed,
                   progress=progress)
    if args.experiment in ("cbf", "all"):
        run_cbf(Path(args.out) / "cbf" if args.experiment == "all" else args.out, seed=args.seed, progress=progress)
    return 0
