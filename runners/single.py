"""One run of one scenario into a run directory."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

from nrtraffic import scenario as scenario_mod
from nrtraffic.engine import Engine, RunFailed
from nrtraffic.results import RunResult, TrajectoryWriter, write_summary, write_vehicles


def prepare_run_dir(sc: scenario_mod.Scenario, out: Path) -> Path:
    """Create ``out`` with the SUMO network copied in and ``scenario.resolved.toml`` written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sumo").mkdir(exist_ok=True)
    net = sc.network_path
    dst = out / "sumo" / net.name
    if net.resolve() != dst.resolve():
        shutil.copyfile(net, dst)
    return out


def run_scenario(sc: scenario_mod.Scenario, out: Path, seed: int | None = None, duration_s: float | None = None,
                 progress: bool = False) -> RunResult:
    """Run ``sc`` and write the run directory ``out``; raises :class:`RunFailed` after writing what
    was finished when the run stops early."""
    return execute(sc, prepare_run_dir(sc, out), seed, duration_s, progress)


def execute(sc: scenario_mod.Scenario, out: Path, seed: int | None, duration_s: float | None, progress: bool,
            extra_summary: dict | None = None, **engine_options) -> RunResult:
    """Record the configuration actually used (seed, duration) in ``scenario.resolved.toml``, run
    the engine (``engine_options`` go to :class:`Engine`) and write the results into the prepared
    run directory ``out``, also when the run stops early."""
    seed = sc.general.seed if seed is None else seed
    general = dataclasses.replace(sc.general, seed=int(seed),
                                  duration_s=float(sc.general.duration_s if duration_s is None else duration_s))
    resolved = dataclasses.replace(sc, general=general)
    scenario_mod.dump(resolved, out / "scenario.resolved.toml", network=f"sumo/{sc.network_path.name}")
    writer = TrajectoryWriter(out / "trajectories.parquet")

    def checkpoint(result: RunResult) -> None:
        result.summary.update(extra_summary or {})
        _write(result, out)

    engine = Engine(resolved, out, trajectories=writer, progress=progress, checkpoint=checkpoint, **engine_options)
    try:
        result = engine.run()
    except RunFailed as exc:
        exc.result.summary.update(extra_summary or {})
        try:
            _write(exc.result, out)
        except OSError as werr:
            raise RunFailed(f"{exc}; and the figures could not be written into {out}: {werr}", exc.result) from exc
        raise
    result.summary.update(extra_summary or {})
    try:
        _write(result, out)
    except OSError as exc:
        raise RunFailed(f"the run finished, but its figures could not be written into {out}: {exc}", result) from exc
    return result


def _write(result: RunResult, out: Path) -> None:
    """vehicles.csv, then summary.json (each under a temporary name, renamed when whole)."""
    write_vehicles(out / "vehicles.csv", result.vehicles)
    write_summary(out / "summary.json", result.summary)
