"""Baselines as built: ``as_is`` keeps the network's own control, ``actuated`` runs SUMO's
gap-based actuated signals on the network's own phases; both checked against the network files and
SUMO's own record of its signal switches."""

import json
import subprocess
import xml.etree.ElementTree as ET

import pandas as pd
import pytest

from conftest import copy_scenario
from nrtraffic.sumo.netbuild import ACTUATED_MAX_DUR_S, ACTUATED_MIN_DUR_S, sumo_binary, with_junction_type
from runners.cli import main

# the junction's own programme: unequal greens, as a real plan has them (netconvert's default is 42/3/42/3)
OWN_PLAN = {0: 30.0, 2: 18.0}


def _logic(net):
    return ET.parse(net).getroot().find("tlLogic")


@pytest.fixture(scope="module")
def signalised(tmp_path_factory):
    """cross4 whose junction C is a signal with its own plan (30 s and 18 s of green)."""
    d = copy_scenario("cross4", tmp_path_factory.mktemp("sig") / "cross4")
    net = d / "net.net.xml"
    with_junction_type(net, "C", "traffic_light", d / "tl.net.xml")
    tree = ET.parse(d / "tl.net.xml")
    for k, phase in enumerate(tree.getroot().find("tlLogic").iter("phase")):
        if k in OWN_PLAN:
            phase.set("duration", f"{OWN_PLAN[k]:g}")
    tree.write(net, encoding="UTF-8", xml_declaration=True)
    return d


def _baseline(d, control, out, seconds="300"):
    assert main(["baseline", str(d / "scenario.toml"), "--junction", control, "--out", str(out), "--duration",
                 seconds, "--no-progress"]) == 0
    return json.loads((out / "summary.json").read_text())


def test_as_is_keeps_the_networks_own_signal_plan_and_judges_it_as_a_signal(signalised, tmp_path):
    s = _baseline(signalised, "as_is", tmp_path / "as_is")
    assert s["status"] == "ok" and s["control"] == "sumo_as_is" and s["signalised"] is True
    assert s["vehicles_completed"] > 0
    run_net = tmp_path / "as_is" / "sumo" / "net.net.xml"
    assert run_net.read_bytes() == (signalised / "net.net.xml").read_bytes()
    durations = [float(p.get("duration")) for p in _logic(run_net).iter("phase")]
    assert [durations[k] for k in OWN_PLAN] == list(OWN_PLAN.values())
    m = pd.read_csv(tmp_path / "as_is" / "movements.csv")
    assert set(m["los_thresholds"]) == {"signalised"}


def test_as_is_of_an_unsignalised_junction_is_its_priority_rule(tmp_path):
    d = copy_scenario("cross4", tmp_path / "cross4")
    s = _baseline(d, "as_is", tmp_path / "o", "120")
    assert s["status"] == "ok" and s["signalised"] is False
    m = pd.read_csv(tmp_path / "o" / "movements.csv")
    assert set(m["los_thresholds"]) == {"unsignalised"}


def test_actuated_runs_the_networks_phases_with_gap_based_extension(signalised, tmp_path):
    out = tmp_path / "act"
    s = _baseline(signalised, "actuated", out, "600")
    assert s["status"] == "ok" and s["signalised"] is True
    own = _logic(signalised / "net.net.xml")
    act = _logic(out / "sumo" / "net.net.actuated.net.xml")
    assert act.get("type") == "actuated" and own.get("type") == "static"
    own_phases, act_phases = list(own.iter("phase")), list(act.iter("phase"))
    assert [p.get("state") for p in act_phases] == [p.get("state") for p in own_phases]
    for p, q in zip(own_phases, act_phases):
        d = float(p.get("duration"))
        if "G" in p.get("state") and "y" not in p.get("state"):
            assert float(q.get("minDur")) == min(d, ACTUATED_MIN_DUR_S)
            assert float(q.get("maxDur")) == max(d, ACTUATED_MAX_DUR_S)
        else:
            assert q.get("minDur") is None
    # SUMO's own record of the switches, on the run's routes: the greens vary with the traffic,
    # within [minDur, maxDur]; the static plan's are always 30 s and 18 s
    add = tmp_path / "switches.add.xml"
    add.write_text('<additional><timedEvent type="SaveTLSSwitchTimes" source="C" dest="switches.xml"/>'
                   '</additional>')
    subprocess.run([sumo_binary("sumo"), "-n", str(out / "sumo" / "net.net.actuated.net.xml"), "-r",
                    str(out / "sumo" / "routes.rou.xml"), "-a", str(add), "--end", "600", "--no-step-log",
                    "--no-warnings"], cwd=tmp_path, check=True, capture_output=True)
    greens = []
    for el in ET.parse(tmp_path / "switches.xml").getroot():
        if el.get("programID") is not None and float(el.get("duration", "0")) > 4.5:
            greens.append(float(el.get("duration")))
    assert len(greens) > 10
    assert min(greens) >= ACTUATED_MIN_DUR_S - 0.1 and max(greens) <= ACTUATED_MAX_DUR_S + 0.1
    assert len({round(g) for g in greens}) > 3  # extended by the gaps, not a fixed plan


def test_sweep_and_baseline_accept_the_new_controls():
    from runners.sweep import BASELINES, parse_baselines

    assert {"as_is", "actuated"} <= set(BASELINES)
    assert parse_baselines("as_is,actuated") == ["as_is", "actuated"]
