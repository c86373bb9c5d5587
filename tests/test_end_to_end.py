"""End-to-end runs of paper_curved in SUMO."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest

from nrtraffic import scenario
from nrtraffic.engine import RunFailed
from runners.single import run_scenario

SUMMARY_KEYS = [
    "scenario", "seed", "sim_time_s", "wall_time_s", "real_time_factor", "vehicles_spawned", "vehicles_completed",
    "throughput_veh_h", "mean_delay_s", "p95_delay_s", "collisions", "min_center_distance_m", "min_bumper_gap_m",
    "max_tracking_error_m", "steady_tracking_error_m", "max_lateral_dev_m", "max_abs_accel_mps2", "mean_energy_u2",
    "mean_fuel_ml", "nrtraffic_version", "sumo_version",
]


@pytest.fixture(scope="module")
def curved_run(tmp_path_factory, paper_curved_path):
    out = tmp_path_factory.mktemp("run") / "curved"
    res = run_scenario(scenario.load(paper_curved_path), out)
    return res, out


def test_all_five_complete_without_collisions(curved_run):
    res, out = curved_run
    s = json.loads((out / "summary.json").read_text())
    for k in SUMMARY_KEYS:
        assert k in s, k
    assert s["status"] == "ok"
    assert s["vehicles_completed"] == 5
    assert s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert s["min_bumper_gap_m"] > 0
    # SUMO's own record: five trips, no collisions
    trips = ET.parse(out / "tripinfo.xml").getroot().findall("tripinfo")
    assert len(trips) == 5
    assert ET.parse(out / "collisions.xml").getroot().findall("collision") == []


def test_tracking_meets_the_paper(curved_run):
    res, _ = curved_run
    s = res.summary
    assert s["transient_tracking_error_m"] < 0.06  # paper: under 6 cm
    assert s["steady_tracking_error_m"] < 0.02  # paper: under 2 cm after ~3 s
    assert s["max_abs_accel_mps2"] < 0.48  # paper: under 0.48 m/s^2


def test_schedule_is_met_and_unhindered_car_has_no_delay(curved_run):
    res, out = curved_run
    veh = pd.read_csv(out / "vehicles.csv")
    assert (veh["t_merge_actual_s"] - veh["t_merge_planned_s"]).abs().max() < 0.05
    first = veh.sort_values("t_enter_s").iloc[0]
    assert first["binding"] == "earliest" and abs(first["delay_s"]) < 0.05
    # later cars were held back by the merge headway and slowed down
    held = veh[veh["binding"] == "rear_end"]
    assert len(held) >= 2 and (held["delay_s"] > 0.5).all()


def test_applied_energy_is_close_to_the_planned_optimum(curved_run):
    res, out = curved_run
    veh = pd.read_csv(out / "vehicles.csv")
    for _, r in veh.iterrows():
        T = r["t_merge_planned_s"] - r["t_enter_s"]
        D = r["v_enter_mps"] * T - (r["v_enter_mps"] - r["v_merge_planned_mps"]) * 2 * T / 3  # p(T) of the arc
        J = 3 * (D - r["v_enter_mps"] * T) ** 2 / (2 * T**3)
        if J > 0.01:
            assert r["energy_u2"] == pytest.approx(J, rel=0.15)


def test_trajectories_stream_to_parquet(curved_run):
    res, out = curved_run
    traj = pd.read_parquet(out / "trajectories.parquet")
    for col in ("t", "vehicle_id", "a_cmd", "delta_cmd", "ref_x", "ref_y", "tracking_error_m", "lateral_dev_m",
                "center_distance_m", "bumper_gap_m"):
        assert col in traj.columns
    assert set(traj["vehicle_id"]) == set(res.vehicles["vehicle_id"])
    # logged error equals the distance between logged position and reference
    err = np.hypot(traj["x"] - traj["ref_x"], traj["y"] - traj["ref_y"])
    assert np.allclose(err, traj["tracking_error_m"], atol=1e-9)
    assert (out / "scenario.resolved.toml").is_file() and (out / "sumo" / "curved.net.xml").is_file()


def test_a_failing_run_keeps_what_was_finished(tmp_path, paper_curved_path, monkeypatch):
    from nrtraffic.sumo import adapter

    real_step = adapter.SumoSession.step

    def failing_step(self):
        if self.time > 20.0:
            raise adapter.SumoError("simulated SUMO failure")
        return real_step(self)

    monkeypatch.setattr(adapter.SumoSession, "step", failing_step)
    out = tmp_path / "failed"
    with pytest.raises(RunFailed, match="simulated SUMO failure"):
        run_scenario(scenario.load(paper_curved_path), out)
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and "simulated SUMO failure" in s["error"]
    assert s["sim_time_s"] == pytest.approx(20.0, abs=0.2)
    veh = pd.read_csv(out / "vehicles.csv")
    assert len(veh) >= 2 and (veh["status"] == "controlled").any()
    traj = pd.read_parquet(out / "trajectories.parquet")
    assert traj["t"].max() == pytest.approx(20.0, abs=0.2)


def test_an_unmeetable_schedule_holds_the_vehicle_instead_of_failing(tmp_path, paper_curved_path):
    sc = scenario.load(paper_curved_path, ["coordinator.min_merge_headway_s=400.0", "scenario.duration_s=60.0"])
    res = run_scenario(sc, tmp_path / "held")
    veh = res.vehicles.set_index("vehicle_id")
    assert veh.loc["main.0", "status"] == "released"
    # no plan within the bounds waits 400 s: held, it drives on to its stop line, and standing there
    # its start from rest is reserved, 400 s after the car ahead entered the merging zone
    assert veh.loc["main.1", "t_held_s"] > 10.0
    assert veh.loc["main.1", "status"] == "starting" and veh.loc["main.1", "profile"] == "from_rest"
    assert veh.loc["main.1", "t_merge_planned_s"] >= veh.loc["main.0", "t_merge_planned_s"] + 400.0
    assert veh.loc["main.1", "t_release_s"] > veh.loc["main.0", "t_merge_planned_s"] + 398.0
    assert res.summary["vehicles_held"] >= 1 and res.summary["collisions"] == 0
    assert res.summary["status"] == "ok"  # (the watchdog's 120 s have not passed)
