"""``nrtraffic baseline``: the same demand and seed under SUMO's own junction control."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nrtraffic import scenario as scenario_mod
from nrtraffic.engine import Engine, RunFailed
from nrtraffic.results import RunResult, TrajectoryWriter
from nrtraffic.sumo.netbuild import with_junction_type
from runners.single import _write, prepare_run_dir


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
    seed = sc.general.seed if seed is None else seed
    general = dataclasses.replace(sc.general, seed=int(seed),
                                  duration_s=float(sc.general.duration_s if duration_s is None else duration_s))
    resolved = dataclasses.replace(sc, general=general)
    scenario_mod.dump(resolved, out / "scenario.resolved.toml", network=f"sumo/{sc.network_path.name}")
    writer = TrajectoryWriter(out / "trajectories.parquet")  # stays empty: nothing is tracked
    engine = Engine(resolved, out, trajectories=writer, progress=progress, control=False, network=net,
                    label=f"sumo_{junction_type}")
    try:
        result = engine.run()
    except RunFailed as exc:
        _write(exc.result, out)
        raise
    result.summary["junction_type"] = junction_type
    _write(result, out)
    return result
