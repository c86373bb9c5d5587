"""What a run writes, as an engineer reads it: one throughput that the summary, the junctions, the
movements and the approaches share (they add up); a served share of at most 1; a measurement
window that measures something (refused before SUMO starts when it cannot, warned of when it is
shorter than a crossing); and numbers at their stated resolutions, without float noise."""

import json
import math
import xml.etree.ElementTree as ET

import pandas as pd
import pytest

from conftest import SCENARIOS
from nrtraffic import scenario
from nrtraffic.results import decimals_of
from runners.cli import main
from runners.single import run_scenario

CROSS4 = SCENARIOS / "cross4"
CORRIDOR = SCENARIOS / "corridor3"

# short runs of the shipped scenarios: (name, scenario folder, overrides, duration [s]); cross4 and
# corridor3 long enough for a window of two minutes or more after the warm-up
RUNS = {
    "cross4": (CROSS4, ["outputs.warmup_s=60.0"], 240.0),
    "corridor3": (CORRIDOR, ["outputs.warmup_s=60.0"], 240.0),
    "cross4_mixed": (CROSS4, ["demand.controlled_share=0.5", "outputs.warmup_s=30.0"], 100.0),
    "tee3": (SCENARIOS / "tee3", ["outputs.warmup_s=30.0"], 90.0),
    "station_mill": (SCENARIOS / "station_mill", ["outputs.warmup_s=30.0"], 90.0),
    "cross4_2lane": (SCENARIOS / "cross4_2lane", ["outputs.warmup_s=30.0"], 90.0),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("outputs")
    out = {}
    for name, (folder, overrides, duration) in RUNS.items():
        sc = scenario.load(folder / "scenario.toml", overrides)
        run_scenario(sc, base / name, seed=3, duration_s=duration)
        out[name] = base / name
    return out


def _files(run_dir):
    summary = json.loads((run_dir / "summary.json").read_text())
    return (summary, pd.read_csv(run_dir / "vehicles.csv"), pd.read_csv(run_dir / "movements.csv"),
            pd.read_csv(run_dir / "approaches.csv"))


@pytest.mark.parametrize("name", ["cross4", "corridor3"])
def test_throughput_of_summary_junctions_movements_and_approaches_add_up(runs, name):
    """Every table counts the crossings that left a merging zone in the window, per hour of it:
    the summary is the sum of its junctions, each junction the sum of its movements and of its
    approaches, and all equal the count made by hand from vehicles.csv."""
    s, veh, mov, appr = _files(runs[name])
    w0, w1 = s["measure_from_s"], s["measure_to_s"]
    assert w1 - w0 >= 120.0
    hours = (w1 - w0) / 3600.0
    left = veh[veh["t_exit_s"].between(w0, w1)]
    assert len(left) > 20
    by_hand = len(left) / hours
    junctions = s["junctions"]
    assert len(junctions) == (3 if name == "corridor3" else 1)
    tol = 0.1 * (len(junctions) + len(mov))  # each written to 0.1 veh/h
    assert s["throughput_veh_h"] == pytest.approx(by_hand, abs=0.1)
    assert sum(j["throughput_veh_h"] for j in junctions.values()) == pytest.approx(s["throughput_veh_h"], abs=tol)
    assert mov["throughput_veh_h"].sum() == pytest.approx(s["throughput_veh_h"], abs=tol)
    assert appr["throughput_veh_h"].sum() == pytest.approx(s["throughput_veh_h"], abs=tol)
    for jid, j in junctions.items():
        at = left[left["junction"] == jid]
        assert j["throughput_veh_h"] == pytest.approx(len(at) / hours, abs=0.1)
        ap = set(at["approach"])
        assert appr.loc[appr["approach"].isin(ap), "throughput_veh_h"].sum() == pytest.approx(
            j["throughput_veh_h"], abs=0.1 * len(ap))


@pytest.mark.parametrize("name", ["cross4", "corridor3"])
def test_served_share_is_of_the_vehicles_demanded_at_each_junction(runs, name):
    """At each junction: demanded, the crossings that entered its control zone in the window early
    enough to leave by the end of the run at their free-flow speed; served, those that left. The
    share is at most 1, and the summary's is over all junctions."""
    s, veh, _, _ = _files(runs[name])
    w0, w1, end = s["measure_from_s"], s["measure_to_s"], s["sim_time_s"]
    assert s["vehicles_waiting_to_enter"] == 0
    demanded = served = 0
    for jid, j in s["junctions"].items():
        at = veh[(veh["junction"] == jid) & veh["t_arrive_s"].between(w0, w1) & (veh["t_exit_free_s"] <= end)]
        assert j["vehicles_demanded"] == len(at) > 0
        assert j["vehicles_served"] == at["t_exit_s"].notna().sum()
        assert 0.9 <= j["served_share"] <= 1.0
        demanded, served = demanded + len(at), served + j["vehicles_served"]
    assert s["served_share"] == pytest.approx(served / demanded, abs=1e-4)
    assert s["served_share"] <= 1.0
    # free-flow exit: entry time plus the free-flow crossing, so delay = exit - free-flow exit (+ wait to enter)
    done = veh[veh["t_exit_s"].notna()]
    assert (done["delay_s"] - (done["t_exit_s"] - done["t_exit_free_s"] + done["depart_delay_s"])).abs().max() < 0.003


def _numbers(obj):
    if isinstance(obj, dict):
        for k, v in obj.items():
            for kk, x in _numbers(v):
                yield (kk if kk else str(k)), x
    elif isinstance(obj, list):
        for v in obj:
            yield from _numbers(v)
    elif isinstance(obj, float):
        yield "", obj


@pytest.mark.parametrize("name", list(RUNS))
def test_no_float_noise_and_numbers_at_their_resolution(runs, name):
    """No number in vehicles.csv, movements.csv, approaches.csv or summary.json lies in
    (0, 1e-9) in magnitude, and none has more decimals than its figure's resolution (times,
    positions and speeds 0.001, tracking errors and lateral deviations 0.00001 m, flows 0.1 veh/h,
    shares 0.0001)."""
    run_dir = runs[name]
    expected = {"t_exit_s": 3, "v_enter_mps": 3, "throughput_veh_h": 1, "served_share": 4, "min_bumper_gap_m": 3,
                "max_tracking_error_m": 5, "steady_tracking_error_m": 5, "max_lateral_dev_m": 5}
    assert expected == {k: decimals_of(k) for k in expected}
    checked = 0
    for f in ("vehicles.csv", "movements.csv", "approaches.csv"):
        df = pd.read_csv(run_dir / f)
        for c in df.select_dtypes("number").columns:
            x = df[c].dropna().astype(float)
            if x.empty:
                continue
            assert not ((x.abs() > 0) & (x.abs() < 1e-9)).any(), (f, c)
            d = decimals_of(c)
            assert ((x * 10 ** d).round() / 10 ** d - x).abs().max() <= 1e-9 * max(1.0, x.abs().max()), (f, c)
            checked += len(x)
        # as written: no exponent anywhere in the file
        assert "e-" not in (run_dir / f).read_text().lower()
    s = json.loads((run_dir / "summary.json").read_text())
    for key, x in _numbers({k: v for k, v in s.items() if k != "warnings"}):
        assert not (0 < abs(x) < 1e-9), key
        assert math.isfinite(x)
    assert checked > 100


# ---------------------------------------------------------------------- the measurement window
@pytest.mark.parametrize("args, words", [
    (["--duration", "120", "--set", "outputs.warmup_s=200"], ["inverted", "200 s", "120 s"]),
    (["--duration", "60"], ["empty", "60 s"]),  # cross4's warm-up is 60 s
])
def test_a_window_that_measures_nothing_is_refused_before_sumo_starts(tmp_path, capsys, args, words):
    out = tmp_path / "run"
    assert main(["run", str(CROSS4), *args, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    for w in ["outputs.warmup_s", "outputs.measure_end_s", "--duration", *words]:
        assert w in err, (w, err)
    assert not (out / "summary.json").exists()


def test_a_window_ending_before_it_starts_by_measure_end_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(CROSS4), "--duration", "200", "--set", "outputs.warmup_s=80",
                 "--set", "outputs.measure_end_s=50", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "outputs.measure_end_s" in err and "outputs.warmup_s" in err and "lower outputs.warmup_s" in err
    assert not (out / "summary.json").exists()


def test_a_window_shorter_than_a_crossing_runs_with_a_warning(tmp_path, capsys):
    """cross4's control zone is 400 m on roads limited to 13.89 m/s (its network file): about
    29 s to cross. A 60-80 s window is run, and warned of on the console and in summary.json."""
    lane = next(ln for ln in ET.parse(CROSS4 / "net.net.xml").getroot().iter("lane") if ln.get("id") == "W_in_0")
    crossing_s = 400.0 / float(lane.get("speed"))
    out = tmp_path / "run"
    assert main(["run", str(CROSS4), "--duration", "80", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok"
    short = [w for w in s["warnings"] if "shorter than" in w]
    assert len(short) == 1 and f"{crossing_s:.0f} s a car needs to cross the control zone" in short[0]
    assert f"warning: {short[0]}" in printed
    # a window as long as a crossing and more is not warned of
    out2 = tmp_path / "run2"
    assert main(["run", str(CROSS4), "--duration", "100", "--out", str(out2), "--no-progress"]) == 0
    assert not any("shorter than" in w for w in json.loads((out2 / "summary.json").read_text())["warnings"])


def test_the_crossing_a_short_window_is_warned_of_is_of_the_zone_as_cut(tmp_path):
    """A 5000 m control zone on cross4's roads is cut to what the road in holds (summary.json
    ``control_zones_cut_m``; no longer than the lane in the network file, and at most a few car
    lengths shorter): the warning of a short window gives the time to cross that zone at the speed
    limit, not the 360 s of the zone as set."""
    lane = next(ln for ln in ET.parse(CROSS4 / "net.net.xml").getroot().iter("lane") if ln.get("id") == "W_in_0")
    out = tmp_path / "run"
    assert main(["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--set",
                 "zones.control_zone_m=5000", "--out", str(out), "--no-progress"]) == 0
    s = json.loads((out / "summary.json").read_text())
    cut = max(s["control_zones_cut_m"].values())
    assert float(lane.get("length")) - 20.0 < cut <= float(lane.get("length"))
    crossing_s = cut / float(lane.get("speed"))
    short = [w for w in s["warnings"] if "shorter than" in w]
    assert len(short) == 1 and f"the {crossing_s:.0f} s a car needs to cross the control zone" in short[0]


def test_replay_allows_a_last_digit_of_rounding_and_no_more():
    """Two runs equal within the replay's tolerance may round a written figure on either side of
    its last digit (0.001 s for a delay): that is no difference; two digits are."""
    from runners.replay import compare_summaries

    assert compare_summaries({"mean_delay_s": 1.234}, {"mean_delay_s": 1.235}) == []
    assert len(compare_summaries({"mean_delay_s": 1.234}, {"mean_delay_s": 1.236})) == 1
    assert len(compare_summaries({"throughput_veh_h": 960.0}, {"throughput_veh_h": 960.2})) == 1


def test_tables_are_written_positionally_at_their_resolutions(tmp_path):
    """to_csv rounds each column to its figure's resolution and writes no exponent: a tracking
    error of 0.000094 m is 0.00009, a delay of 2.5e-14 s is 0.0, a missing value an empty cell."""
    from nrtraffic.results import to_csv

    t = pd.DataFrame({"vehicle_id": ["a", "b"], "max_tracking_error_m": [0.000094, 0.0123456],
                      "delay_s": [2.5e-14, float("nan")], "throughput_veh_h": [1234.56, 7.0]})
    to_csv(t, tmp_path / "t.csv")
    lines = (tmp_path / "t.csv").read_text().splitlines()
    assert lines == ["vehicle_id,max_tracking_error_m,delay_s,throughput_veh_h",
                     "a,0.00009,0.0,1234.6", "b,0.01235,,7.0"]
