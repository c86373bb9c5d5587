"""The engineer's workflow: demand as turning movement counts and peak intervals, the measurement
window, the movement table, SUMO's wait to insert, and a run directory that opens in sumo-gui."""

import json
import math
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd
import pytest

from nrtraffic import metrics, scenario
from nrtraffic.demand import Demand
from nrtraffic.scenario import ScenarioError
from nrtraffic.sumo.demandfile import DemandFileError, read_sumo_demand
from nrtraffic.sumo.netbuild import sumo_binary

from conftest import SCENARIOS

CROSS4 = SCENARIOS / "cross4" / "scenario.toml"
FLOWS = ('demand.flows=[{approach="N_in", straight=500.0, left=60.0, right=40.0}, '
         '{approach="S_in", straight=500.0, left=60.0, right=40.0}, '
         '{approach="E_in", straight=100.0, left=30.0, right=20.0}, '
         '{approach="W_in", straight=100.0, left=30.0, right=20.0}]')


def _engine(overrides, tmp_path, duration=3600.0, seed=5):
    sc = scenario.load(CROSS4, overrides)
    return Demand.of(sc, seed=seed, duration_s=duration)  # reads the network; SUMO is not started


@pytest.mark.parametrize("override, message", [
    ('demand.flows=[{approach="N_in", left=-5.0}]', "demand.flows.left = -5.0 is outside its range"),
    ('demand.flows=[{approach="N_in", lefty=5.0}]', "unknown key demand.flows.lefty"),
    ('demand.flows=[{straight=5.0}]', "needs an approach"),
    ('demand.flows=[{approach="N_in", straight="many"}]', "demand.flows.straight must be a number"),
    ("demand.flows=5", "must be an array of tables"),
    ('demand.flows=[{approach="N_in", straight=100.0}, {approach="N_in", left=5.0}]', "each approach once"),
    ('demand.flows=[{approach="N_in", straight=3000.0}]', "demand.flows.N_in = 3000 veh/h needs a mean headway"),
    ("demand.intervals=[{begin_s=100.0, end_s=50.0}]", "begin_s < end_s"),
    ("demand.intervals=[{begin_s=0.0, end_s=50.0, scale=-1.0}]", "demand.intervals.scale = -1.0 is outside its range"),
    ("demand.intervals=[{begin_s=0.0, end_s=100.0}, {begin_s=50.0, end_s=150.0}]", "overlap"),
    ("demand.intervals=[{begin_s=0.0, end_s=100.0, scale=10.0}]", "at the peak scale 10"),
    ("outputs.warmup_s=-1.0", "outputs.warmup_s = -1.0 is outside its range"),
    ("outputs.measure_end_s=50.0", None),  # valid alone (warm-up 0)
])
def test_demand_and_window_keys_are_validated_by_name(override, message):
    if message is None:
        scenario.load(CROSS4, [override, "outputs.warmup_s=10.0"])
        with pytest.raises(ScenarioError, match="must be after outputs.warmup_s"):
            scenario.load(CROSS4, [override, "outputs.warmup_s=60.0"])
        return
    with pytest.raises(ScenarioError, match=message):
        scenario.load(CROSS4, [override, "demand.rate_veh_h=400.0"])


def test_flows_name_approaches_and_turns_the_junction_has(tmp_path):
    with pytest.raises(ValueError, match="X_in is not an approach of the junction"):
        _engine(['demand.flows=[{approach="X_in", straight=100.0}]'], tmp_path).departures()
    with pytest.raises(ValueError, match="demand.flows.N_in.u_turn: the approach has no such movement"):
        _engine(['demand.flows=[{approach="N_in", u_turn=10.0}]'], tmp_path).departures()


def test_flows_give_each_movement_its_count(tmp_path):
    """Four hours of arrivals: every movement's count is within 4 standard deviations of its flow
    (Poisson-like arrivals: sd ~ sqrt(count)); the approaches not listed get none."""
    e = _engine([FLOWS], tmp_path, duration=4 * 3600.0)
    dep = e.departures()
    counts = pd.Series([mv for _, mv, *_ in dep]).value_counts()
    flows = {"N_in": (60, 500, 40), "S_in": (60, 500, 40), "E_in": (30, 100, 20), "W_in": (30, 100, 20)}
    for appr, (left, straight, right) in flows.items():
        for turn, q in (("left", left), ("straight", straight), ("right", right)):
            expect = 4 * q
            assert abs(counts.get(f"{appr}.{turn}", 0) - expect) < 4 * math.sqrt(expect) + 2, (appr, turn)
    assert e.demand_veh_h(0.0, 3600.0) == pytest.approx(1500.0)
    # the old keys still work: one rate for every approach, turns by the global shares (cross4: 20 %
    # left, 20 % right), each count within 4 sd of its binomial expectation
    old = _engine(["demand.rate_veh_h=400.0"], tmp_path, duration=4 * 3600.0).departures()
    turns = pd.Series([mv.split(".")[1] for _, mv, *_ in old]).value_counts()
    n = len(old)
    assert abs(n - 4 * 4 * 400) < 4 * math.sqrt(4 * 4 * 400)
    for turn, share in (("left", 0.2), ("right", 0.2), ("straight", 0.6)):
        assert abs(turns[turn] - share * n) < 4 * math.sqrt(n * share * (1 - share)), turn


def test_an_interval_scales_the_demand_inside_it(tmp_path):
    """A peak: scale 2 from 1800 to 3600 s over 400 veh/h per approach. Arrivals inside it are
    twice as dense (each approach: 400 expected before, 400 inside), and the window's mean demand
    is the integral of the rate: 4 x 400 x (1800 + 2 x 1800) / 3600 = 2400 veh/h."""
    e = _engine(["demand.rate_veh_h=400.0", "demand.intervals=[{begin_s=1800.0, end_s=3600.0, scale=2.0}]"],
                tmp_path, duration=3600.0)
    t = np.array([d[2] for d in e.departures()])
    before, inside = (t < 1800).sum(), (t >= 1800).sum()
    assert abs(before - 800) < 4 * math.sqrt(800) and abs(inside - 1600) < 4 * math.sqrt(1600)
    assert e.demand_veh_h(0.0, 3600.0) == pytest.approx(2400.0)
    assert e.demand_veh_h(1800.0, 2700.0) == pytest.approx(3200.0)
    assert e.demand_veh_h(900.0, 2700.0) == pytest.approx(2400.0)


def test_movement_table_by_hand():
    """Vehicles that entered the control zone inside [100, 400] s and left the merging zone count;
    throughput over the 300 s window; LOS of the mean by the table named."""
    v = pd.DataFrame({
        "approach": ["N_in"] * 4 + ["E_in"] * 2,
        "movement": ["straight", "straight", "straight", "left", "left", "left"],
        "t_arrive_s": [50.0, 120.0, 200.0, 150.0, 300.0, 390.0],
        "t_exit_s": [80.0, 150.0, 230.0, 185.0, 340.0, np.nan],
        "delay_s": [99.0, 4.0, 8.0, 12.0, 30.0, np.nan],
        "stops": [0.0, 0.0, 1.0, 1.0, 2.0, np.nan],
        "fuel_ml": [20.0, 18.0, 22.0, 25.0, 30.0, np.nan],
    })
    m = metrics.movement_table(v, 100.0, 400.0, signalised=False).set_index(["approach", "movement"])
    ns = m.loc[("N_in", "straight")]
    assert ns["vehicles"] == 2 and ns["throughput_veh_h"] == pytest.approx(24.0)
    assert ns["mean_delay_s"] == pytest.approx(6.0) and ns["los"] == "A"
    assert ns["p95_delay_s"] == pytest.approx(4.0 + 0.95 * 4.0)
    assert ns["stops_per_vehicle"] == pytest.approx(0.5) and ns["fuel_ml_per_vehicle"] == pytest.approx(20.0)
    assert m.loc[("E_in", "left"), "mean_delay_s"] == pytest.approx(30.0)
    assert m.loc[("E_in", "left"), "los"] == "D"  # unsignalised: 25 < 30 <= 35
    assert metrics.movement_table(v, 100.0, 400.0, signalised=True).set_index(
        ["approach", "movement"]).loc[("E_in", "left"), "los"] == "C"  # signalised: 20 < 30 <= 35


def test_wait_to_enter_is_sumos_depart_delay_and_counts_in_delay(tmp_path):
    """SUMO's priority junction at 600 veh/h per approach backs the minor roads up to where SUMO
    inserts vehicles. Every vehicle's depart_delay_s equals SUMO's own departDelay in tripinfo.xml
    less the wait for the next SUMO step after its desired departure (at most one step), its delay
    includes it, and the demand not yet inserted at the end is reported."""
    from runners.baseline import run_baseline

    sc = scenario.load(CROSS4, ["demand.rate_veh_h=600.0", "outputs.warmup_s=60.0"])
    res = run_baseline(sc, "priority", tmp_path / "prio", duration_s=600.0)
    veh = res.vehicles.set_index("vehicle_id")
    trips = {t.get("id"): float(t.get("departDelay"))  # SUMO writes it to 0.01 s
             for t in ET.parse(tmp_path / "prio" / "tripinfo.xml").getroot().iter("tripinfo")}
    desired = {v.get("id"): float(v.get("depart"))
               for v in ET.parse(tmp_path / "prio" / "sumo" / "routes.rou.xml").getroot().iter("vehicle")}
    common = [v for v in trips if v in veh.index]
    assert len(common) > 50
    for v in common:
        step_wait = math.ceil(desired[v] / 0.1 - 1e-9) * 0.1 - desired[v]
        assert 0.0 <= step_wait < 0.1 + 1e-9
        assert veh.loc[v, "depart_delay_s"] == pytest.approx(max(0.0, trips[v] - step_wait), abs=0.006)
    assert veh["depart_delay_s"].max() > 5.0  # the minor roads did back up
    fin = veh[veh["delay_s"].notna()]
    assert (fin["delay_s"] >= fin["depart_delay_s"] - 1.0).all()
    s = res.summary
    assert s["vehicles_waiting_to_enter"] > 0 and s["mean_wait_to_enter_s"] > 0
    assert s["measure_from_s"] == 60.0 and s["measure_to_s"] == pytest.approx(600.0)
    assert s["demand_veh_h"] == pytest.approx(2400.0)
    # served: of the crossings that entered the control zone in the window early enough to leave at
    # free flow by the end, and of the vehicles due in the window that SUMO could not insert, those
    # that left
    due = veh[veh["t_arrive_s"].between(60.0, 600.0) & (veh["t_exit_free_s"] <= 600.0)]
    assert s["vehicles_served"] == due["t_exit_s"].notna().sum()
    assert len(due) < s["vehicles_demanded"] <= len(due) + s["vehicles_waiting_to_enter"]
    assert s["served_share"] == pytest.approx(s["vehicles_served"] / s["vehicles_demanded"], abs=1e-4)
    # the minor roads backed up to where SUMO inserts vehicles: about the flow served of the demand
    assert s["served_share"] < 0.9 and abs(s["served_share"] - s["throughput_veh_h"] / 2400.0) < 0.1
    left = veh["t_exit_s"].between(60.0, 600.0).sum()
    assert s["throughput_veh_h"] == pytest.approx(left / (540.0 / 3600.0), abs=0.1)
    # only the vehicles that entered the control zone in the window count
    inside = veh[veh["t_arrive_s"].between(60.0, 600.0) & veh["t_exit_s"].notna()]
    assert s["vehicles_completed"] == len(inside)
    assert s["mean_delay_s"] == pytest.approx(inside["delay_s"].mean(), abs=1e-3)  # (each to 0.001 s)
    assert s["los"] == metrics.level_of_service(s["mean_delay_s"], False)
    # a baseline has no barriers: null, not false and 0
    assert s["barriers_longitudinal"] is None and s["cbf_long_fallbacks"] is None
    movements = pd.read_csv(tmp_path / "prio" / "movements.csv")
    assert len(movements) == 12 and movements["vehicles"].sum() == len(inside)


def test_run_directory_opens_in_sumo(tmp_path):
    """sumo/run.sumocfg opens the run's network and routes: SUMO itself inserts the run's vehicles."""
    from runners.single import run_scenario

    sc = scenario.load(CROSS4, ["demand.rate_veh_h=400.0"])
    out = tmp_path / "run"
    run_scenario(sc, out, duration_s=20.0)
    cfg = out / "sumo" / "run.sumocfg"
    proc = subprocess.run([sumo_binary("sumo"), "-c", str(cfg), "--end", "20", "--no-step-log", "true",
                           "--duration-log.statistics", "true"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    routes = ET.parse(out / "sumo" / "routes.rou.xml").getroot()
    due = sum(float(v.get("depart")) <= 19.0 for v in routes.iter("vehicle"))
    inserted = int(proc.stdout.split("Inserted: ")[1].split()[0])
    assert due > 0 and inserted >= due


def test_queues_come_from_sumos_detectors_and_match_the_halting_vehicles(tmp_path):
    """SUMO's traffic light at 600 veh/h per approach: every approach's queue per detector period
    (queues.xml) against the halting vehicles (below SUMO's 1.39 m/s threshold) SUMO's own fcd.xml
    shows on that lane: the longest jam of a period is the largest count of halting vehicles at any
    instant of it, within one vehicle (SUMO counts a car as halting after 1 s below the threshold).
    approaches.csv gives the largest over the window."""
    from runners.baseline import run_baseline

    sc = scenario.load(CROSS4, ["demand.rate_veh_h=600.0", "outputs.sumo_fcd=true", "outputs.warmup_s=0.0"])
    out = tmp_path / "tl"
    run_baseline(sc, "traffic_light", out, duration_s=200.0)
    e2 = pd.DataFrame([{"lane": iv.get("id").split(":", 1)[1], "begin": float(iv.get("begin")),
                        "end": float(iv.get("end")), "max_veh": float(iv.get("maxJamLengthInVehicles"))}
                       for iv in ET.parse(out / "queues.xml").getroot().iter("interval")])
    fcd = [(float(ts.get("time")), v.get("lane"), float(v.get("speed")))
           for ts in ET.parse(out / "fcd.xml").getroot().iter("timestep") for v in ts.iter("vehicle")]
    fcd = pd.DataFrame(fcd, columns=["t", "lane", "speed"])
    halting = fcd[fcd["speed"] < 1.39].groupby(["t", "lane"]).size().rename("n").reset_index()
    checked = 0
    for r in e2.itertuples():
        h = halting[(halting["lane"] == r.lane) & (halting["t"] >= r.begin) & (halting["t"] < r.end)]
        observed = h["n"].max() if len(h) else 0
        assert abs(r.max_veh - observed) <= 1, (r, observed)
        checked += r.max_veh > 0
    assert checked >= 4  # queues did form
    appr = pd.read_csv(out / "approaches.csv").set_index("approach")
    for lane, g in e2.groupby("lane"):
        assert appr.loc[lane.rsplit("_", 1)[0], "max_queue_veh"] == g["max_veh"].max()
    assert appr["demand_veh_h"].tolist() == pytest.approx([600.0] * 4)


def test_report_gathers_the_tables_and_figures_of_a_run(tmp_path):
    """report.html of a run holds its movement and approach tables (a row per movement and per
    approach) and its figures, embedded."""
    from nrtraffic.report import run_report
    from runners.single import run_scenario

    sc = scenario.load(CROSS4, ["demand.rate_veh_h=400.0", "outputs.warmup_s=0.0"])
    out = tmp_path / "run"
    run_scenario(sc, out, duration_s=90.0)
    page = run_report(out).read_text()
    for f in ("movements.png", "delays.png", "queues.png", "time_space.png"):
        assert (out / f).is_file() and (out / f).stat().st_size > 10_000
    assert page.count("data:image/png;base64,") == 4
    movements = pd.read_csv(out / "movements.csv")
    approaches = pd.read_csv(out / "approaches.csv")
    assert len(movements) == 12 and len(approaches) == 4
    for a, m in zip(movements["approach"], movements["movement"]):
        assert f"<td>{a}</td>\n      <td>{m}</td>" in page
    assert page.count("<td>N_in</td>") == 3 + 1  # three movements and one approach


@pytest.mark.skipif(not __import__("shutil").which("xvfb-run"), reason="needs xvfb-run (a virtual display) for sumo-gui")
def test_gui_run_is_the_same_run(tmp_path):
    """``nrtraffic run --gui`` drives sumo-gui through TraCI (here on a virtual display): the same
    vehicles cross at the same times as the headless libsumo run."""
    import os
    import sys

    from conftest import ROOT

    base = [sys.executable, "-m", "runners.cli", "run", str(CROSS4), "--duration", "60", "--no-progress",
            "--set", "outputs.warmup_s=0.0", "--gui-delay", "0"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for name, extra in (("gui", ["--gui"]), ("headless", [])):
        cmd = (["xvfb-run", "-a"] if extra else []) + base + ["--out", str(tmp_path / name)] + extra
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)
        assert proc.returncode == 0, proc.stderr[-2000:]
    a = pd.read_csv(tmp_path / "gui" / "vehicles.csv")
    b = pd.read_csv(tmp_path / "headless" / "vehicles.csv")
    assert len(a) == len(b) > 5
    assert np.allclose(a["t_exit_s"], b["t_exit_s"], equal_nan=True)
    assert np.allclose(a["delay_s"], b["delay_s"], equal_nan=True)


def test_gui_without_a_display_is_refused_at_once(tmp_path):
    """``--gui`` with neither DISPLAY nor WAYLAND_DISPLAY: exit 2 within 10 s, nothing written, and
    the message names DISPLAY, xvfb-run and the .sumocfg the run would write (sumo/run.sumocfg)."""
    import os
    import sys
    import time

    from conftest import ROOT

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = str(ROOT)
    out = tmp_path / "run"
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "runners.cli", "run", str(CROSS4), "--gui", "--out", str(out)],
                          capture_output=True, text=True, timeout=60, env=env, cwd=ROOT)
    assert time.monotonic() - t0 < 10.0
    assert proc.returncode == 2, proc.stderr
    assert "DISPLAY" in proc.stderr and "xvfb-run" in proc.stderr
    assert str(out / "sumo" / "run.sumocfg") in proc.stderr
    assert not out.exists() and not list(tmp_path.iterdir())


def _sumo_gui_loads() -> bool:
    """sumo-gui starts as far as its version (its shared libraries, libGL among them, are there)."""
    try:
        return subprocess.run([sumo_binary("sumo-gui"), "--version"], capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired, FileNotFoundError):
        return False


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="X11 display names")
@pytest.mark.skipif(not _sumo_gui_loads(), reason="sumo-gui cannot load its libraries here (libGL, X11)")
def test_gui_with_a_display_that_cannot_be_opened_fails_at_once_saying_why(tmp_path):
    """DISPLAY names no X server: sumo-gui stops at once, and the run fails (exit 1) within 30 s
    (not after TraCI's 60 restarts) with sumo-gui's own words and what to do."""
    import os
    import sys
    import time

    from conftest import ROOT

    env = {k: v for k, v in os.environ.items() if k != "WAYLAND_DISPLAY"}
    env.update(PYTHONPATH=str(ROOT), DISPLAY=":87")
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "runners.cli", "run", str(CROSS4), "--gui", "--duration", "5",
                           "--set", "outputs.warmup_s=0", "--no-progress", "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=120, env=env, cwd=ROOT)
    assert time.monotonic() - t0 < 30.0
    assert proc.returncode == 1
    assert "unable to open display :87" in proc.stderr and "xvfb-run" in proc.stderr
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["status"] == "failed"


@pytest.mark.skipif(not __import__("shutil").which("xvfb-run"), reason="needs xvfb-run (a virtual display) for sumo-gui")
def test_gui_opens_on_the_junction_and_paces_the_steps(tmp_path):
    """Under xvfb-run: exit 0; sumo-gui shows junction C (its centre from the network file) in a
    view a few hundred metres wide, not the 1 km network; with ``--gui-delay 250`` the 60 steps of
    6 s (0.1 s each) take at least 15 s of wall time (about 6 s unpaced, sumo-gui's start included)."""
    import os
    import re
    import sys

    from conftest import ROOT

    out = tmp_path / "gui"
    proc = subprocess.run(["xvfb-run", "-a", sys.executable, "-m", "runners.cli", "run", str(CROSS4), "--duration", "6",
                           "--set", "outputs.warmup_s=0", "--gui", "--gui-delay", "250", "--no-progress", "--out", str(out)],
                          capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)},
                          cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    node = ET.parse(SCENARIOS / "cross4" / "net.net.xml").getroot().find("junction[@id='C']")
    cx, cy = float(node.get("x")), float(node.get("y"))
    m = re.search(r"sumo-gui: showing C \(x (\S+) to (\S+) m, y (\S+) to (\S+) m\), 250 ms delay", proc.stderr)
    assert m, proc.stderr[-2000:]
    x0, x1, y0, y1 = map(float, m.groups())
    assert x0 < cx < x1 and y0 < cy < y1
    assert min(x1 - x0, y1 - y0) <= 200.0 and max(x1 - x0, y1 - y0) <= 600.0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["wall_time_s"] >= 60 * 0.250


# ---------------------------------------------------------------- demand.sumo_routes

TEE3 = SCENARIOS / "tee3"
_MOVES = {("W_in", "E_out"): "W_in.straight", ("W_in", "S_out"): "W_in.right", ("E_in", "W_out"): "E_in.straight",
          ("E_in", "S_out"): "E_in.left", ("S_in", "W_out"): "S_in.left", ("S_in", "E_out"): "S_in.right"}


def _routes(tmp_path, body):
    p = tmp_path / "d.rou.xml"
    p.write_text(f"<routes>\n{body}\n</routes>\n")
    return p


def test_sumo_demand_file_follows_sumos_flow_rules(tmp_path):
    """vehsPerHour and period: equally spaced from begin; number alone: spread over [begin, end);
    probability: one chance per second; exp(rate): exponential headways (counts within 4 sd);
    trips and vehicles with a route reference or an inner route; each mapped by its edges."""
    p = _routes(tmp_path, """
    <route id="r" edges="S_in E_out"/>
    <flow id="a" from="W_in" to="E_out" begin="10" end="3610" vehsPerHour="120"/>
    <flow id="b" route="r" begin="0" end="100" number="4" departSpeed="10.5"/>
    <flow id="c" from="E_in" to="S_out" begin="0" end="36000" probability="0.05"/>
    <flow id="d" from="S_in" to="W_out" begin="0" end="36000" period="exp(0.02)"/>
    <trip id="t" depart="3.5" from="W_in" to="S_out"/>
    <vehicle id="v" depart="7"><route edges="E_in W_out"/></vehicle>""")
    dep = read_sumo_demand(p, _MOVES, np.random.default_rng(1), math.inf, 13.89)
    by = pd.DataFrame([(vid, legs[0], t, v, pos) for vid, legs, t, v, pos, *_ in dep],
                      columns=["id", "movement", "t", "v", "pos"])
    a = by[by["id"].str.startswith("a.")]
    assert len(a) == 120 and np.allclose(np.diff(a["t"]), 30.0) and a["t"].iloc[0] == 10.0
    assert (a["movement"] == "W_in.straight").all()
    b = by[by["id"].str.startswith("b.")]
    assert b["t"].tolist() == [0.0, 25.0, 50.0, 75.0] and (b["v"] == 10.5).all() and (b["movement"] == "S_in.right").all()
    assert abs((by["id"].str.startswith("c.")).sum() - 1800) < 4 * math.sqrt(1800)
    assert abs((by["id"].str.startswith("d.")).sum() - 720) < 4 * math.sqrt(720)
    assert by.set_index("id").loc["t", "movement"] == "W_in.right" and by.set_index("id").loc["v", "t"] == 7.0
    assert (by.loc[~by["id"].isin(["b.0", "b.1", "b.2", "b.3"]), "v"] == 13.89).all()  # no departSpeed given
    # SUMO's h:m:s form of a time (it had been refused as "not a number")
    clock = _routes(tmp_path, """
    <trip id="t1" depart="00:01:03.5" from="W_in" to="S_out"/>
    <flow id="f" from="W_in" to="E_out" begin="1:00:00" end="1:00:10" period="5"/>""")
    times = {vid: t for vid, _, t, *_ in read_sumo_demand(clock, _MOVES, np.random.default_rng(1), math.inf, 13.89)}
    assert times == {"t1": 63.5, "f.0": 3600.0, "f.1": 3605.0}
    # a flow without an end goes on for SUMO's day (SUMO 1.28: "Undefined end for flow 'x', defaulting
    # to 24hour duration"; by hand, period="3600" gives 24 trips departing 0 to 82800 s), also in a
    # run without an end (it had made no vehicle at all)
    day = _routes(tmp_path, '<flow id="f" from="W_in" to="E_out" begin="0" period="3600"/>')
    times = [t for _, _, t, *_ in read_sumo_demand(day, _MOVES, np.random.default_rng(1), math.inf, 13.89)]
    assert times == [3600.0 * k for k in range(24)]
    # the run's end cuts open-ended flows
    short = read_sumo_demand(p, _MOVES, np.random.default_rng(1), 100.0, 13.89)
    assert all(t < 100.0 for vid, _, t, *_ in short if vid.startswith(("a.", "c.", "d.")))


@pytest.mark.parametrize("flow, run_end", [('begin="0" end="100" number="10"', 45.0),
                                           ('begin="10" end="100" number="3"', 1000.0),
                                           ('begin="0" number="4"', 2000.0)])
def test_a_flow_of_a_number_departs_as_sumo_departs_it_in_a_shorter_run(flow, run_end, tmp_path):
    """``number`` vehicles are spaced over the flow's own end, or without one over the run's, and a
    shorter run takes those that depart before it ends: the departure times are SUMO's own (its
    tripinfo, given the same flow and --end). All of a flow's vehicles had been squeezed into the
    run (a million in 60 s took two minutes, and 999962 "could not enter")."""
    net = SCENARIOS / "cross4" / "net.net.xml"
    p = _routes(tmp_path, f'<route id="r" edges="W_in E_out"/><flow id="f" route="r" {flow}/>')
    ours = [t for _, _, t, *_ in read_sumo_demand(p, _MOVES, np.random.default_rng(1), run_end, 13.89)]
    info = tmp_path / "tripinfo.xml"
    subprocess.run([sumo_binary("sumo"), "-n", str(net), "-r", str(p), "--end", f"{run_end:g}", "--tripinfo-output",
                    str(info), "--tripinfo-output.write-unfinished", "--no-step-log"], check=True, capture_output=True)
    sumo = sorted(float(t.get("depart")) for t in ET.parse(info).getroot().iter("tripinfo"))
    assert ours == pytest.approx(sumo) and len(ours) > 0


@pytest.mark.parametrize("body, message", [
    ('<flow id="x" route="nope" begin="0" end="10" period="1"/>', "route 'nope' is not defined"),
    ('<trip id="x" depart="1" from="W_in" to="W_out"/>', "none of its 1 vehicles crosses a controlled junction"),
    ('<flow id="x" from="W_in" to="E_out" begin="0" end="10"/>', "needs period, vehsPerHour, probability"),
    ('<flow id="x" from="W_in" to="E_out" begin="0" end="10" probability="2"/>', "probability must be in"),
    ('<trip id="x" depart="soon" from="W_in" to="E_out"/>', "depart='soon' is not a number"),
    ('<trip depart="1" from="W_in" to="E_out"/>', "without an id"),
    ('<vehicle id="x" depart="1"/>', "needs from/to, a route"),
])
def test_sumo_demand_file_errors_name_the_element(tmp_path, body, message):
    with pytest.raises(DemandFileError, match=message):
        read_sumo_demand(_routes(tmp_path, body), _MOVES, np.random.default_rng(1), 100.0, 13.89)
    bad = tmp_path / "bad.rou.xml"
    bad.write_text("<routes><flow")
    with pytest.raises(DemandFileError, match="cannot be read as XML"):
        read_sumo_demand(bad, _MOVES, np.random.default_rng(1), 100.0, 13.89)


def test_sumo_routes_key_is_checked_when_the_scenario_loads(tmp_path):
    with pytest.raises(ScenarioError, match="demand.sumo_routes: file not found"):
        scenario.load(TEE3 / "routes.toml", ['demand.sumo_routes="missing.rou.xml"'])
    with pytest.raises(ScenarioError, match="replaces demand.flows and demand.rate_veh_h"):
        scenario.load(TEE3 / "routes.toml", ["demand.rate_veh_h=100.0"])
    with pytest.raises(ScenarioError, match="lies outside the scenario's folder"):
        scenario.load(TEE3 / "routes.toml", ['demand.sumo_routes="../cross4/net.net.xml"'])


def test_a_sumo_demand_file_drives_a_controlled_run(tmp_path):
    """tee3 from flows.rou.xml: the file's vehicles enter, are mapped to their movements by their
    edges and are driven by the controller (they have plant steps and tracking figures)."""
    from runners.single import run_scenario

    sc = scenario.load(TEE3 / "routes.toml", ["outputs.warmup_s=0.0"])
    res = run_scenario(sc, tmp_path / "run", duration_s=90.0)
    v = res.vehicles.set_index("vehicle_id")
    assert v.loc["early_S", "approach"] == "S_in" and v.loc["early_S", "movement"] == "right"
    assert v.loc["early_E", "movement"] == "straight"
    done = v[v["t_exit_s"].notna()]
    assert len(done) > 10 and (done["plant_steps"] > 0).all() and done["max_tracking_error_m"].notna().all()
    assert {i.split(".")[0] for i in done.index} >= {"W_E", "E_W"}
    assert res.summary["collisions"] == 0 and res.summary["demand_veh_h"] > 0


@pytest.mark.parametrize("name", ["cross4", "tee3", "cross4_curved"])
def test_scenario_folder_opens_with_its_demand(name, tmp_path):
    """The scenario folder's .sumocfg opens its network with demand.rou.xml, which is the
    scenario's demand for its seed (kept in sync: `make nets` writes it), and SUMO inserts it."""
    folder = SCENARIOS / name
    fresh = tmp_path / "demand.rou.xml"
    sc = scenario.load(folder / "scenario.toml")
    Demand.of(sc).write(fresh, sc.vehicle.params())
    assert fresh.read_text() == (folder / "demand.rou.xml").read_text()
    proc = subprocess.run([sumo_binary("sumo"), "-c", str(folder / f"{name}.sumocfg"), "--end", "60",
                           "--no-step-log", "true", "--duration-log.statistics", "true"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.split("Inserted: ")[1].split()[0]) > 10


def test_a_control_zone_longer_than_the_road_is_cut_and_reported(tmp_path, capsys):
    """cross4's approach roads are about 500 m long before the merging zone: a 1000 m control zone
    is cut where the routes start (one car length in), every movement's cut is in summary.json,
    and the run admits its vehicles as usual."""
    from conftest import SCENARIOS

    from runners.single import run_scenario

    sc = scenario.load(SCENARIOS / "cross4" / "scenario.toml", ["zones.control_zone_m=1000"])
    s = run_scenario(sc, tmp_path / "r", duration_s=120.0).summary  # admissions count after the 60 s warm-up
    cuts = s["control_zones_cut_m"]
    assert len(cuts) == 12 and all(450.0 < v < 1000.0 for v in cuts.values())
    assert "cut there" in capsys.readouterr().err
    assert s["vehicles_admitted"] > 0 and s["collisions"] == 0
    movements = json.loads((tmp_path / "r" / "movements.json").read_text())["movements"]
    for name, length in cuts.items():
        m = movements[name]
        assert m["merge_entry_m"] - m["control_zone_start_m"] == pytest.approx(length, abs=1e-3)
        assert m["control_zone_start_m"] == pytest.approx(sc.vehicle.params().length)
    plain = run_scenario(scenario.load(SCENARIOS / "cross4" / "scenario.toml"), tmp_path / "p", duration_s=5.0)
    assert plain.summary["control_zones_cut_m"] == {}
