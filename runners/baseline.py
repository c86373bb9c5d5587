"""``nrtraffic baseline``: the same demand and seed under SUMO's own junction control."""

from __future__ import annotations

from pathlib import Path

from nrtraffic import scenario as scenario_mod
from nrtraffic.results import RunResult
from nrtraffic.sumo.netbuild import BASELINES, actuated, is_signalised_network, with_junction_type
from runners.single import execute, prepare_run_dir


def run_baseline(sc: scenario_mod.Scenario, junction_type: str, out: Path, seed: int | None = None,
                 duration_s: float | None = None, progress: bool = False, report: bool = False) -> RunResult:
    """SUMO drives every vehicle of the scenario's demand through its controlled junctions under
    ``junction_type`` (:data:`~nrtraffic.sumo.netbuild.BASELINES`); the run directory has the same
    files and figures (tracking and barrier figures are null).

    - ``as_is``: the network's own control, unchanged (its signal programmes, priorities and right
      of way); level of service by the signalised thresholds where every controlled junction is a
      signal.
    - ``actuated``: SUMO's gap-based actuated signals on the network's own phases
      (:func:`~nrtraffic.sumo.netbuild.actuated`).
    - ``traffic_light``, ``priority``, ``allway_stop``, ``right_before_left``: the junctions rebuilt
      with SUMO's default for that control; ``traffic_light_coordinated``: traffic lights at every
      junction, their offsets set for green waves along the run's own demand by SUMO's
      tlsCoordinator (:func:`coordinate_signals`).

    ``report``: also the figures and ``report.html``, before the final ``summary.json``
    (:func:`~runners.single.execute`)."""
    ids = [j.id for j in sc.controlled_junctions()]
    if not ids:
        raise scenario_mod.ScenarioError("baselines need a scenario with a [junction] or [[junctions]] (rebuilt "
                                         "with SUMO's control)")
    if junction_type not in BASELINES:
        raise scenario_mod.ScenarioError(f"unknown baseline {junction_type!r}: use one of {', '.join(BASELINES)}")
    out = prepare_run_dir(sc, out)
    signalised = None
    if junction_type == "as_is":
        net = out / "sumo" / sc.network_path.name  # (prepare_run_dir's copy, unchanged)
        signalised = is_signalised_network(net, ids)
    elif junction_type == "actuated":
        net = actuated(sc.network_path, ids, out / "sumo" / f"{sc.network_path.stem}.actuated.net.xml")
    else:
        net = with_junction_type(sc.network_path, ids, junction_type,
                                 out / "sumo" / f"{sc.network_path.stem}.{junction_type}.net.xml")
    additional = ()
    if junction_type == "traffic_light_coordinated":
        additional = (coordinate_signals(sc, net, out / "sumo", seed, duration_s),)
    # the trajectory file stays empty: nothing is tracked
    return execute(sc, out, seed, duration_s, progress, extra_summary={"junction_type": junction_type}, report=report,
                   control=False, network=net, label=f"sumo_{junction_type}", additional=additional,
                   signalised=signalised)


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
