"""``nrtraffic baseline``: the same demand and seed under SUMO's own junction control."""

from __future__ import annotations

from pathlib import Path

from nrtraffic import scenario as scenario_mod
from nrtraffic.results import RunResult
from nrtraffic.sumo.netbuild import with_junction_type
from runners.single import execute, prepare_run_dir


def run_baseline(sc: scenario_mod.Scenario, junction_type: str, out: Path, seed: int | None = None,
                 duration_s: float | None = None, progress: bool = False) -> RunResult:
    """SUMO drives every vehicle of the scenario's demand through its junctions rebuilt as
    ``junction_type``; the run directory has the same files and figures (tracking and barrier
    figures are null). ``traffic_light_coordinated``: traffic lights at every junction, their
    offsets set for green waves along the run's own demand by SUMO's tlsCoordinator
    (:func:`coordinate_signals`)."""
    ids = [j.id for j in sc.controlled_junctions()]
    if not ids:
        raise scenario_mod.ScenarioError("baselines need a scenario with a [junction] or [[junctions]] (rebuilt "
                                         "with SUMO's control)")
    out = prepare_run_dir(sc, out)
    net = with_junction_type(sc.network_path, ids, junction_type,
                             out / "sumo" / f"{sc.network_path.stem}.{junction_type}.net.xml")
    additional = ()
    if junction_type == "traffic_light_coordinated":
        additional = (coordinate_signals(sc, net, out / "sumo", seed, duration_s),)
    # the trajectory file stays empty: nothing is tracked
    return execute(sc, out, seed, duration_s, progress, extra_summary={"junction_type": junction_type},
                   control=False, network=net, label=f"sumo_{junction_type}", additional=additional)


def coordinate_signals(sc: scenario_mod.Scenario, net: Path, sdir: Path, seed: int | None,
                       duration_s: float | None) -> Path:
    """Offsets of the traffic lights of ``net`` for green waves along the run's demand (the
    routes its vehicles take, and how many take each), from SUMO's ``tlsCoordinator.py``: it
    pairs consecutive signals on the routes and shifts each one's cycle by the travel time at the
    speed limit, the busiest pairs first. Writes ``tls_offsets.add.xml`` into ``sdir``."""
    import subprocess
    import sys
    import tempfile

    import sumo

    from nrtraffic.demand import Demand
    from nrtraffic.sumo.netbuild import SumoToolError

    with tempfile.TemporaryDirectory() as tmp:
        eng = Demand.of(sc, seed=seed, duration_s=duration_s)
        demand = eng.departures()
        # the tool reads vehicles with their routes inside them
        lines = ["<routes>"]
        for vid, route, depart, *_ in demand:
            lines.append(f'    <vehicle id="{vid}" depart="{depart:.2f}"><route edges="'
                         f'{" ".join(eng.route_edges(route))}"/></vehicle>')
        lines.append("</routes>")
        routes = Path(tmp) / "embedded.rou.xml"
        routes.write_text("\n".join(lines) + "\n")
        out = sdir / "tls_offsets.add.xml"
        tool = Path(sumo.SUMO_HOME) / "tools" / "tlsCoordinator.py"
        proc = subprocess.run([sys.executable, str(tool), "-n", str(net), "-r", str(routes), "-o", str(out)],
                              capture_output=True, text=True)
        if proc.returncode != 0 or not out.is_file():
            raise SumoToolError(f"SUMO's tlsCoordinator failed on {net}:\n{proc.stderr.strip()}")
    return out
