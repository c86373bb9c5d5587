"""``nrtraffic baseline``: the same demand and seed under SUMO's own junction control."""

from __future__ import annotations

from pathlib import Path

from nrtraffic import scenario as scenario_mod
from nrtraffic.results import RunResult
from nrtraffic.sumo.netbuild import with_junction_type
from runners.single import execute, prepare_run_dir


def run_baseline(sc: scenario_mod.Scenario, junction_type: str, out: Path, seed: int | None = None,
                 duration_s: float | None = None, progress: bool = False) -> RunResult:
    """SUMO drives every vehicle of the scenario's demand through its junction rebuilt as
    ``junction_type``; the run directory has the same files and figures (tracking and barrier
    figures are null)."""
    if not sc.junction.id:
        raise scenario_mod.ScenarioError("baselines need a scenario with a [junction] (its id is rebuilt)")
    out = prepare_run_dir(sc, out)
    net = with_junction_type(sc.network_path, sc.junction.id, junction_type,
                             out / "sumo" / f"{sc.network_path.stem}.{junction_type}.net.xml")
    # the trajectory file stays empty: nothing is tracked
    return execute(sc, out, seed, duration_s, progress, extra_summary={"junction_type": junction_type},
                   control=False, network=net, label=f"sumo_{junction_type}")
