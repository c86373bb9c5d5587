"""``nrtraffic compare``: nrtraffic against SUMO's junction control over demand levels and seeds.

Every (demand, seed, control) is one run directory ``DIR/rate<R>/seed<S>/<control>``, run in its
own process (libsumo allows one simulation per process); finished runs are skipped on a re-run.
``DIR/compare.csv`` has one row per run, ``DIR/compare_summary.csv`` the mean, standard deviation
and 95 % confidence interval per demand and control, ``DIR/compare.md`` the table and
``DIR/compare.png`` the figure.
"""

from __future__ import annotations

import json
import math
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

import pandas as pd

CONTROLS = ("nrtraffic", "traffic_light", "priority", "allway_stop")
FIGURES = ("throughput_veh_h", "mean_delay_s", "mean_sumo_time_loss_s", "mean_fuel_ml", "collisions",
           "collisions_geometric", "vehicles_completed", "vehicles_held", "real_time_factor")


def _one(scenario_path: str, rate: float, seed: int, control: str, duration: float, out: str) -> dict:
    from nrtraffic import scenario
    from runners.baseline import run_baseline
    from runners.single import run_scenario

    sc = scenario.load(scenario_path, [f"demand.rate_veh_h={rate}"])
    if control == "nrtraffic":
        res = run_scenario(sc, Path(out), seed=seed, duration_s=duration)
    else:
        res = run_baseline(sc, control, Path(out), seed=seed, duration_s=duration)
    return res.summary


def _row(rate, seed, control, summary) -> dict:
    row = {"rate_veh_h": rate, "seed": seed, "control": control, "status": summary.get("status")}
    row.update({k: summary.get(k) for k in FIGURES})
    return row


def run_compare(scenario_path: Path, rates: list[float], seeds: list[int], out: Path, duration: float,
                workers: int = 2, controls=CONTROLS, progress: bool = True) -> pd.DataFrame:
    from tqdm import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    jobs, rows = [], []
    for rate in rates:
        for seed in seeds:
            for control in controls:
                d = out / f"rate{rate:g}" / f"seed{seed}" / control
                summ = d / "summary.json"
                if summ.is_file():
                    s = json.loads(summ.read_text())
                    if s.get("status") == "ok" and math.isclose(s.get("sim_time_s", 0.0), duration, abs_tol=0.2):
                        rows.append(_row(rate, seed, control, s))
                        continue
                jobs.append((str(scenario_path), rate, seed, control, duration, str(d)))
    bar = tqdm(total=len(jobs), desc="runs", disable=None if progress else True)
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"), max_tasks_per_child=1) as ex:
        futs = {ex.submit(_one, *j): j for j in jobs}
        for f in as_completed(futs):
            _, rate, seed, control, _, _ = futs[f]
            try:
                rows.append(_row(rate, seed, control, f.result()))
            except Exception as exc:  # recorded, the others go on
                rows.append({"rate_veh_h": rate, "seed": seed, "control": control, "status": f"failed: {exc}"})
            bar.update(1)
    bar.close()
    df = pd.DataFrame(rows).sort_values(["rate_veh_h", "control", "seed"])
    df.to_csv(out / "compare.csv", index=False)
    summ = summarize(df)
    summ.to_csv(out / "compare_summary.csv", index=False)
    (out / "compare.md").write_text(markdown(summ, len(seeds), duration))
    figure(summ, out / "compare.png")
    return df


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    """Mean, standard deviation and 95 % confidence half-width (Student t) per demand and control."""
    from scipy import stats

    ok = df[df["status"] == "ok"]
    out = []
    for (rate, control), g in ok.groupby(["rate_veh_h", "control"]):
        row = {"rate_veh_h": rate, "control": control, "runs": len(g)}
        for k in FIGURES:
            x = pd.to_numeric(g[k], errors="coerce").dropna()
            n = len(x)
            row[f"{k}_mean"] = x.mean() if n else math.nan
            row[f"{k}_sd"] = x.std(ddof=1) if n > 1 else math.nan
            row[f"{k}_ci95"] = stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / math.sqrt(n) if n > 1 else math.nan
        out.append(row)
    return pd.DataFrame(out)


def markdown(summ: pd.DataFrame, n_seeds: int, duration: float) -> str:
    lines = [
        f"Mean over {n_seeds} seeds (± 95 % confidence half-width), {duration:g} s each.",
        "",
        "| demand [veh/h per approach] | control | throughput [veh/h] | delay [s] | SUMO timeLoss [s] | fuel [mL/veh] | collisions |",
        "|---|---|---|---|---|---|---|",
    ]

    def f(r, k, nd=1):
        m, c = r[f"{k}_mean"], r[f"{k}_ci95"]
        if m != m:
            return "n/a"
        return f"{m:.{nd}f}" + ("" if c != c else f" ± {c:.{nd}f}")

    for _, r in summ.iterrows():
        lines.append(f"| {r['rate_veh_h']:g} | {r['control']} | {f(r, 'throughput_veh_h', 0)} | {f(r, 'mean_delay_s')} | "
                     f"{f(r, 'mean_sumo_time_loss_s')} | {f(r, 'mean_fuel_ml')} | "
                     f"{int(r['collisions_mean'] * r['runs'])} (own check {int(r['collisions_geometric_mean'] * r['runs'])}) |")
    return "\n".join(lines) + "\n"


def figure(summ: pd.DataFrame, path: Path) -> None:
    from nrtraffic.plots import plt

    fig, axes = plt.subplots(1, 3, figsize=(12.0, 3.8))
    for control, g in summ.groupby("control"):
        g = g.sort_values("rate_veh_h")
        for ax, k, label in zip(axes, ("throughput_veh_h", "mean_delay_s", "mean_fuel_ml"),
                                ("throughput [veh/h]", "mean delay [s]", "fuel [mL/veh]")):
            ax.errorbar(g["rate_veh_h"], g[f"{k}_mean"], yerr=g[f"{k}_ci95"], marker="o", capsize=3, label=control)
            ax.set(xlabel="demand [veh/h per approach]", ylabel=label)
            ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_seeds(text: str) -> list[int]:
    """``A:B`` (inclusive) or a comma list."""
    if ":" in text:
        a, b = text.split(":")
        return list(range(int(a), int(b) + 1))
    return [int(x) for x in text.split(",")]


def main(args) -> int:
    rates = [float(x) for x in args.rates.split(",")]
    run_compare(args.scenario, rates, parse_seeds(args.seeds), args.out, args.duration, args.workers,
                progress=not args.no_progress)
    print((Path(args.out) / "compare.md").read_text())
    return 0
