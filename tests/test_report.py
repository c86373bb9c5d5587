"""Reports: the series the time-space and arterial diagrams draw, report.html, and
``nrtraffic compare``."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest
from conftest import SCENARIOS

from nrtraffic import scenario, timespace

CORRIDOR3 = SCENARIOS / "corridor3"
CROSS4 = SCENARIOS / "cross4"


@pytest.fixture(scope="module")
def corridor_run(tmp_path_factory):
    """corridor3 for 150 s with SUMO's floating-car data."""
    from runners.single import run_scenario

    out = tmp_path_factory.mktemp("corridor3") / "run"
    sc = scenario.load(CORRIDOR3, ["outputs.sumo_fcd=true", "outputs.warmup_s=30.0"])
    run_scenario(sc, out, duration_s=150.0)
    return out


def _fcd_edges(run_dir):
    """(vehicle, edge) pairs of every position SUMO wrote in fcd.xml."""
    return {(v.get("id"), v.get("lane").rsplit("_", 1)[0])
            for v in ET.parse(run_dir / "fcd.xml").getroot().iter("vehicle")}


def _assert_monotonic_once_per_road(series):
    for road, df in series.items():
        assert (df.groupby("vehicle_id")["segment"].nunique() <= 1).all(), road  # once per road
        for (vid, _), g in df.groupby(["vehicle_id", "segment"]):
            assert (np.diff(g["t"].to_numpy()) > 0).all(), (road, vid)
            assert (np.diff(g["s_m"].to_numpy()) >= 0).all(), (road, vid)  # never back: no legs joined


def test_time_space_draws_each_vehicle_once_per_road_with_its_position_along_it(corridor_run):
    """corridor3, every vehicle from fcd.xml: in each approach road's panel, each vehicle that SUMO
    had on that road appears once, its position never decreasing in time, within the road's
    panel (up to 10 m past the merging zone: not the ~320 m saw-tooth of legs joined). Against the
    controller's own arc lengths (trajectories.parquet, from the control-zone entry), SUMO's front
    bumper is ahead of the centre of gravity by cg_to_front, give or take one SUMO step at the
    speed limit (the two are logged half a step apart)."""
    run = corridor_run
    series = timespace.time_space_series(run)
    doc = json.loads((run / "movements.json").read_text())
    roads = timespace.roads(doc, {})
    assert set(series) == {m["approach"] for m in doc["movements"].values()} and len(series) == 12
    _assert_monotonic_once_per_road(series)
    on_edge = _fcd_edges(run)
    for road, df in series.items():
        assert set(df["vehicle_id"]) == {v for v, e in on_edge if e == road}, road
        assert df["s_m"].min() >= 0 and df["s_m"].max() <= roads[road].merge_exit_m + 10.0 + 1e-9
    multi = pd.read_csv(run / "vehicles.csv", dtype={"vehicle_id": str})
    multi = multi[multi["legs"] == 3]
    assert multi["vehicle_id"].nunique() >= 5
    for vid, legs in multi.groupby("vehicle_id"):
        for appr in legs["approach"]:
            assert (series[appr]["vehicle_id"] == vid).any()
    # against the controller's positions of the same vehicles at the same instants
    traj = timespace.time_space_series(run, source="trajectories")
    _assert_monotonic_once_per_road(traj)
    res = scenario.load(run / "scenario.resolved.toml")
    lead = res.vehicle.params().cg_to_front  # [m]
    step = res.sumo.step_length_s * res.planning.v_max_mps
    compared = 0
    for road in series:
        j = series[road].merge(traj[road], on=["vehicle_id", "t"], suffixes=("_fcd", "_ctl"))
        d = j["s_m_fcd"] - j["s_m_ctl"]
        assert d.between(lead - 0.5, lead + step + 0.5).all(), (road, d.min(), d.max())
        compared += len(j)
    assert compared > 5000


def test_arterial_diagram_follows_the_through_trips_along_the_corridor(corridor_run):
    """corridor3's two directions: each a chain of three straight movements; every trip straight
    through all three junctions (vehicles.csv) is one line from before the first merging zone to
    past the last, its position never decreasing; the whole drawn from SUMO's positions
    agrees with the lane lengths of the network (the chain is as long as its lanes)."""
    run = corridor_run
    series, arts = timespace.arterial_series(run)
    assert set(arts) == {"W_J1", "E_J3"}
    assert [z[0] for z in arts["W_J1"].zones] == ["J1", "J2", "J3"]
    assert [z[0] for z in arts["E_J3"].zones] == ["J3", "J2", "J1"]
    net = ET.parse(run / "sumo" / "net.net.xml").getroot()
    length = {ln.get("id"): float(ln.get("length")) for ln in net.iter("lane")}
    mv = json.loads((run / "movements.json").read_text())["movements"]
    chain = ["W_J1.straight", "J1_J2.straight", "J2_J3.straight"]
    lanes = [ln for m in chain[:-1] for ln in mv[m]["lanes"][:-1]] + mv[chain[-1]]["lanes"]
    assert arts["W_J1"].top_m == pytest.approx(sum(length[ln] for ln in lanes))
    _assert_monotonic_once_per_road(series)
    veh = pd.read_csv(run / "vehicles.csv", dtype={"vehicle_id": str})
    through = veh.groupby("vehicle_id").filter(lambda g: len(g) == 3 and (g["movement"] == "straight").all()
                                               and g["t_exit_s"].notna().all())
    assert through["vehicle_id"].nunique() >= 3
    for vid, g in through.groupby("vehicle_id"):
        name = g.sort_values("leg")["approach"].iloc[0]
        s = series[name].loc[series[name]["vehicle_id"] == vid, "s_m"]
        assert s.min() < arts[name].zones[0][1] and s.max() > arts[name].zones[-1][2], vid


def test_report_draws_time_space_and_arterial(corridor_run):
    from nrtraffic.report import run_report

    page = run_report(corridor_run).read_text()
    for f in ("time_space.png", "arterial.png"):
        assert (corridor_run / f).stat().st_size > 20_000
    assert "corridor3" in page.split("</title>")[0]
