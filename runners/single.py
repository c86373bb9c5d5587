"""One run of one scenario into a run directory."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

from nrtraffic import scenario as scenario_mod
from nrtraffic.engine import Engine, RunFailed
from nrtraffic.results import RunResult, TrajectoryWriter, write_movements, write_summary, write_table, write_vehicles
from nrtraffic.sumo.network import NetworkError, check_scenario, check_sumo_args


def check(sc: scenario_mod.Scenario) -> None:
    """What can be checked before SUMO starts: the network is a SUMO network with the junction and
    the edges the scenario names, and ``sumo.extra_args`` are SUMO options (NetworkError)."""
    edges = tuple(e for a in sc.approaches for e in (*a.route, a.merge_entry_edge))
    check_scenario(sc.network_path, [j.id for j in sc.controlled_junctions()], edges)
    check_sumo_args(tuple(sc.sumo.extra_args))


def prepare_run_dir(sc: scenario_mod.Scenario, out: Path) -> Path:
    """Check the scenario against its network (:func:`check`), then create ``out`` with the SUMO
    network copied in."""
    check(sc)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sumo").mkdir(exist_ok=True)
    net = sc.network_path
    dst = out / "sumo" / net.name
    if net.resolve() != dst.resolve():
        shutil.copyfile(net, dst)
    return out


def run_scenario(sc: scenario_mod.Scenario, out: Path, seed: int | None = None, duration_s: float | None = None,
                 progress: bool = False, gui: bool = False) -> RunResult:
    """Run ``sc`` and write the run directory ``out``; raises :class:`RunFailed` after writing what
    was finished when the run stops early. ``gui``: in sumo-gui (:class:`~nrtraffic.sumo.adapter.SumoSession`)."""
    return execute(sc, prepare_run_dir(sc, out), seed, duration_s, progress, gui=gui)


def resolve(sc: scenario_mod.Scenario, seed: int | None, duration_s: float | None) -> scenario_mod.Scenario:
    """The scenario with the seed and duration a run uses made explicit."""
    general = dataclasses.replace(sc.general, seed=int(sc.general.seed if seed is None else seed),
                                  duration_s=float(sc.general.duration_s if duration_s is None else duration_s))
    return dataclasses.replace(sc, general=general)


def resolved_text(sc: scenario_mod.Scenario, seed: int | None, duration_s: float | None) -> str:
    """``scenario.resolved.toml`` of a run of ``sc`` (its network copied into ``sumo/``)."""
    return scenario_mod.dumps(resolve(sc, seed, duration_s), network=f"sumo/{sc.network_path.name}")


# what a run writes into its directory (``--force`` removes these, and nothing else)
RUN_FILES = ("summary.json", "vehicles.csv", "movements.csv", "approaches.csv", "trajectories.parquet",
             "trajectories.parquet.tmp", "trajectories.partial.arrows", "scenario.resolved.toml", "movements.json",
             "movements.png", "delays.png", "queues.png", "time_space.png", "report.html", "tripinfo.xml",
             "collisions.xml", "fcd.xml", "queues.xml", "summary.json.tmp", "vehicles.csv.tmp", "movements.csv.tmp",
             "approaches.csv.tmp")
# ... and into its sumo/ folder, beside the copy of the network (and a baseline's rebuilt network,
# ``<network stem>.<control>.net.xml``)
RUN_SUMO_FILES = ("routes.rou.xml", "queues.add.xml", "run.sumocfg", "tls_offsets.add.xml")


def claim_run_dir(out: Path, sc: scenario_mod.Scenario, seed: int | None, duration_s: float | None, control: str,
                  force: bool = False) -> None:
    """Make ``out`` ready for a run: a missing or empty folder, or a finished run of the same
    configuration and control (run again), is taken as it is. Any other non-empty folder is refused
    (ValueError) unless ``force``; then the files an earlier run wrote are removed from it first, so
    that nothing of it stays beside the new one. Files of the user's own are never removed, nor
    overwritten: a folder where no run has been that holds a file a run would write (its network
    copy in ``sumo/``, say) is refused even with ``force``."""
    out = Path(out)
    if not out.is_dir() or not any(out.iterdir()):
        return
    same = False
    try:
        s = json.loads((out / "summary.json").read_text())
        same = (s.get("status") == "ok" and s.get("control") == control
                and (out / "scenario.resolved.toml").read_text() == resolved_text(sc, seed, duration_s))
    except (OSError, ValueError):
        pass
    if not (same or force):
        raise ValueError(f"--out {out} is not empty and is not a finished run of this configuration: "
                         "choose another folder, or --force to replace the run in it")
    if not _was_run_dir(out):
        theirs = [n for n in (*RUN_FILES, *(f"sumo/{f}" for f in (*RUN_SUMO_FILES, sc.network_path.name)))
                  if (out / n).exists() and not (out / n).resolve() == sc.network_path.resolve()]
        if theirs:
            raise ValueError(f"--out {out} holds files no run wrote that a run would overwrite ({', '.join(theirs)}): "
                             "--force replaces an earlier run's files only; choose another folder")
    remove_run_files(out, keep=sc.network_path)


def _was_run_dir(out: Path) -> bool:
    """Whether a run has been in ``out``: it left its resolved scenario or its summary there."""
    return (out / "scenario.resolved.toml").is_file() or (out / "summary.json").is_file()


def remove_run_files(out: Path, keep: Path | None = None) -> None:
    """Remove from ``out`` the files a run writes (:data:`RUN_FILES`; in ``sumo/``
    :data:`RUN_SUMO_FILES`, and the network copy that its ``scenario.resolved.toml`` names, with a
    baseline's rebuilt networks beside it), and nothing else: where no run has been, ``sumo/`` is
    left as it is, and ``keep`` (the scenario's own network, where ``out`` is its folder) always
    stays. ``sumo/`` itself goes once it is empty."""
    import glob
    import re

    out = Path(out)
    sdir = out / "sumo"
    names = []
    if sdir.is_dir() and _was_run_dir(out):
        names = [sdir / n for n in RUN_SUMO_FILES]
        try:
            m = re.search(r'^network = "sumo/([^"/]+)"', (out / "scenario.resolved.toml").read_text(), re.M)
        except OSError:
            m = None
        if m:
            net = sdir / m.group(1)
            names += [net, *sdir.glob(f"{glob.escape(net.stem)}.*.net.xml")]  # (runners/baseline.py)
    for p in [out / n for n in RUN_FILES] + names:
        if keep is not None and p.exists() and p.resolve() == Path(keep).resolve():
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        elif p.exists() or p.is_symlink():
            p.unlink()
    try:
        sdir.rmdir()  # (only when empty)
    except OSError:
        pass


def execute(sc: scenario_mod.Scenario, out: Path, seed: int | None, duration_s: float | None, progress: bool,
            extra_summary: dict | None = None, **engine_options) -> RunResult:
    """Record the configuration actually used (seed, duration) in ``scenario.resolved.toml``, run
    the engine (``engine_options`` go to :class:`Engine`) and write the results into the prepared
    run directory ``out``, also when the run stops early."""
    resolved = resolve(sc, seed, duration_s)
    (out / "scenario.resolved.toml").write_text(resolved_text(sc, seed, duration_s))
    writer = TrajectoryWriter(out / "trajectories.parquet")

    def checkpoint(result: RunResult) -> None:
        result.summary.update(extra_summary or {})
        _write(result, out)

    engine = Engine(resolved, out, trajectories=writer, progress=progress, checkpoint=checkpoint, **engine_options)
    try:
        result = engine.run()
    except NetworkError:  # the junction or its zones do not suit: nothing was simulated, nothing is kept
        remove_run_files(out, keep=sc.network_path)
        raise
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
    """vehicles.csv, movements.csv, then summary.json (each under a temporary name, renamed when
    whole)."""
    write_vehicles(out / "vehicles.csv", result.vehicles)
    write_movements(out / "movements.csv", result)
    if "approaches" in result.extra:
        write_table(out / "approaches.csv", result.extra["approaches"])
    write_summary(out / "summary.json", result.summary)
