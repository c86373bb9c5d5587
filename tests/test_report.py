"""Reports: the series the time-space and arterial diagrams draw, report.html, and
``nrtraffic compare``."""

import json
import tomllib
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


def test_report_draws_time_space_and_arterial_and_shows_the_corridor(corridor_run):
    """corridor3's report: the time-space and arterial figures, a title naming the scenario, headers
    with units, the served share in per cent, and each junction's and direction's figures of
    summary.json (also as console text), rounded to their resolution."""
    from nrtraffic.report import console_sections, run_report

    page = run_report(corridor_run).read_text()
    for f in ("time_space.png", "arterial.png"):
        assert (corridor_run / f).stat().st_size > 20_000
    assert page.split("</title>")[0].endswith("corridor3: nrtraffic, seed 1")
    s = json.loads((corridor_run / "summary.json").read_text())
    assert f"<td>{100 * s['served_share']:.1f} %</td>" in page and "<th>95th-percentile delay [s]</th>" in page
    assert "mean_delay_s" not in page and "served_share" not in page
    text = console_sections(s)
    for j, f in s["junctions"].items():
        row = f"<td>{j}</td>\n      <td>{f['vehicles']}</td>\n      <td>{f['throughput_veh_h']:.1f}</td>"
        assert row in page, row
        assert any(line.split()[:3] == [j, str(f["vehicles"]), f"{f['throughput_veh_h']:.1f}"]
                   for line in text.splitlines()), j
    assert s["corridor"] and all(f"<td>{d}</td>" in page and d in text for d in s["corridor"])


@pytest.fixture(scope="module")
def cross4_pair(tmp_path_factory):
    """cross4 for 120 s (measured from 30 s), with nrtraffic and SUMO's traffic light, by the
    commands a user types."""
    from runners.cli import main

    base = tmp_path_factory.mktemp("cross4")
    common = ["--duration", "120", "--no-progress", "--set", "outputs.warmup_s=30.0"]
    assert main(["run", str(CROSS4), "--out", str(base / "nr"), *common]) == 0
    assert main(["baseline", str(CROSS4), "--junction", "traffic_light", "--out", str(base / "tl"), *common]) == 0
    return base


def test_compare_puts_each_runs_own_figures_side_by_side(cross4_pair, capsys):
    """compare's CSVs hold, per run, exactly the values of its movements.csv and approaches.csv;
    the per-approach delay and stops are those of the approach's crossings in the window
    (vehicles.csv, computed here by hand), and the 95th-percentile queue that of the detector
    periods in queues.xml."""
    from runners.cli import main

    base = cross4_pair
    out = base / "cmp"
    capsys.readouterr()
    assert main(["compare", str(base / "nr"), str(base / "tl"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "cross4: nrtraffic vs sumo_traffic_light" in printed and "per movement:" in printed
    runs = pd.read_csv(out / "compare_runs.csv")
    assert runs["run"].tolist() == ["nrtraffic", "sumo_traffic_light"]
    mv = pd.read_csv(out / "compare_movements.csv")
    ap = pd.read_csv(out / "compare_approaches.csv")
    assert len(mv) == 2 * 12 and len(ap) == 2 * 4
    queues_seen = 0
    for run, d in (("nrtraffic", base / "nr"), ("sumo_traffic_light", base / "tl")):
        s = json.loads((d / "summary.json").read_text())
        r = runs[runs["run"] == run].iloc[0]
        for k in ("throughput_veh_h", "mean_delay_s", "vehicles_completed", "collisions"):
            assert r[k] == pytest.approx(s[k], nan_ok=True) if s[k] is not None else pd.isna(r[k])
        own = pd.read_csv(d / "movements.csv")
        got = mv[mv["run"] == run].drop(columns=["run", "control"])
        pd.testing.assert_frame_equal(got[own.columns].reset_index(drop=True), own.reset_index(drop=True))
        own = pd.read_csv(d / "approaches.csv")
        got = ap[ap["run"] == run].reset_index(drop=True)
        for col in own.columns:
            mine = "throughput_veh_h" if col == "served_veh_h" and "served_veh_h" not in got else col
            assert got[mine].tolist() == pytest.approx(own[col].tolist(), nan_ok=True) if col != "approach" \
                else got[col].tolist() == own[col].tolist(), col
        # by hand: the approach's crossings that entered in the window and left
        veh = pd.read_csv(d / "vehicles.csv")
        w = veh[(veh["t_arrive_s"] >= s["measure_from_s"]) & (veh["t_arrive_s"] <= s["measure_to_s"])
                & veh["t_exit_s"].notna()]
        q = pd.DataFrame([(iv.get("id").split(":", 1)[1].rsplit("_", 1)[0], float(iv.get("begin")), float(iv.get("end")),
                           float(iv.get("maxJamLengthInVehicles")))
                          for iv in ET.parse(d / "queues.xml").getroot().iter("interval")],
                         columns=["approach", "begin", "end", "max"])
        q = q[(q["begin"] >= s["measure_from_s"]) & (q["end"] <= s["measure_to_s"])]
        q = q.groupby(["approach", "begin"])["max"].sum()
        for row in got.itertuples():
            g = w[w["approach"] == row.approach]
            assert row.vehicles == len(g)
            assert row.mean_delay_s == pytest.approx(g["delay_s"].mean(), abs=1e-3, nan_ok=True)
            assert row.stops_per_vehicle == pytest.approx(g["stops"].mean(), abs=1e-3, nan_ok=True)
            periods = np.sort(q.loc[row.approach].to_numpy())
            assert len(periods) == 9  # 30-120 s in 10 s periods
            rank = 0.95 * (len(periods) - 1)
            lo = periods[int(np.floor(rank))]
            hi = periods[int(np.ceil(rank))]
            assert row.p95_queue_veh == pytest.approx(lo + (rank - np.floor(rank)) * (hi - lo), abs=0.01)
            assert row.max_queue_veh == periods.max()
            queues_seen += periods.max() > 0
    assert queues_seen >= 1  # the traffic light made a queue somewhere
    page = (out / "compare.html").read_text()
    assert "<title>cross4: nrtraffic vs sumo_traffic_light</title>" in page


def test_compare_notes_runs_of_different_demand(cross4_pair, tmp_path, capsys):
    """Two runs whose resolved configurations differ in their demand are compared with a note that
    names the setting and both values; runs of one demand get no such note."""
    import shutil

    from runners.cli import main

    base = cross4_pair
    assert main(["compare", str(base / "nr"), str(base / "tl"), "--out", str(tmp_path / "same")]) == 0
    assert "differ in their demand" not in capsys.readouterr().out
    other = tmp_path / "tl_800"  # (the traffic light's run, as a run at another rate would record it)
    shutil.copytree(base / "tl", other)
    cfg = other / "scenario.resolved.toml"
    text = cfg.read_text()
    rate = tomllib.loads(text)["demand"]["rate_veh_h"]
    head, sep, demand = text.partition("[demand]")
    assert sep and f"rate_veh_h = {rate!r}" in demand
    cfg.write_text(head + sep + demand.replace(f"rate_veh_h = {rate!r}", "rate_veh_h = 800.0", 1))
    assert main(["compare", str(base / "nr"), str(other), "--out", str(tmp_path / "diff")]) == 0
    said = capsys.readouterr().out
    assert f"The runs differ in their demand (rate_veh_h: {rate!r} / 800.0)" in said, said
    assert "differ in their demand" in (tmp_path / "diff" / "compare.html").read_text()


def test_compare_refuses_unfinished_runs_and_other_scenarios(cross4_pair, corridor_run, tmp_path, capsys):
    """Exit 2, naming the folder, for a run that has not finished, a folder that is no run, runs of
    two scenarios, or one run given twice; nothing is written."""
    import shutil

    from runners.cli import main

    nr = cross4_pair / "nr"
    running = tmp_path / "running"
    shutil.copytree(nr, running)
    s = json.loads((running / "summary.json").read_text())
    (running / "summary.json").write_text(json.dumps({**s, "status": "running"}))
    mine = tmp_path / "mine"  # a folder holding a compare.html of the user's own: kept, also with --force
    mine.mkdir()
    (mine / "compare.html").write_text("my own page")
    capsys.readouterr()
    assert main(["compare", str(nr), str(cross4_pair / "tl"), "--out", str(mine)]) == 2
    assert "holds compare.html, which no comparison wrote" in capsys.readouterr().err
    assert (mine / "compare.html").read_text() == "my own page"
    study = tmp_path / "study"  # a sweep's folder: its resume would refuse files no sweep wrote
    study.mkdir()
    (study / "manifest.json").write_text(json.dumps({"sweep": 1, "preexisting": [], "created": []}))
    assert main(["compare", str(nr), str(cross4_pair / "tl"), "--out", str(study / "cmp")]) == 2
    assert "lies in the sweep folder" in capsys.readouterr().err and not (study / "cmp").exists()
    empty, listed = tmp_path / "empty", tmp_path / "listed"  # an emptied table, a summary that is no object
    shutil.copytree(nr, empty)
    (empty / "movements.csv").write_text("")
    shutil.copytree(nr, listed)
    (listed / "summary.json").write_text("[1, 2]")
    elsewhere = tmp_path / "elsewhere"  # the same scenario name on another junction (a copied file)
    shutil.copytree(nr, elsewhere)
    doc = json.loads((elsewhere / "movements.json").read_text())
    doc["movements"] = {f"{k}_other": v for k, v in doc["movements"].items()}
    (elsewhere / "movements.json").write_text(json.dumps(doc))
    cases = [([nr, running], "not a finished run"), ([nr, tmp_path], "not a run directory"),
             ([nr, empty], "its tables cannot be read"), ([nr, listed], "not a run's summary"),
             ([nr, corridor_run], "compare runs of one scenario"), ([nr, nr], "given twice"),
             ([nr], "at least two"), ([nr, elsewhere], "on different junctions")]
    for dirs, message in cases:
        capsys.readouterr()
        assert main(["compare", *map(str, dirs), "--out", str(tmp_path / "cmp")]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "cmp").exists()
    tl = cross4_pair / "tl"
    for into in (tl, tl / "sumo", tl / "new"):  # (a run's folder, or one in it: its files had gone there)
        assert main(["compare", str(nr), str(tl), "--out", str(into)]) == 2
        assert "write the comparison into another folder" in capsys.readouterr().err
    assert not (tl / "new").exists() and not (tl / "sumo" / "compare.html").exists()


def test_a_one_point_sweep_draws_a_bar_per_control_with_its_interval(tmp_path, monkeypatch):
    """A sweep of one grid point: each panel a bar per control at the mean over the seeds, its
    error bar the 95 % Student-t half-width (computed here from the seeds' values); a control with
    fewer than 5 seeds gets no interval."""
    import matplotlib.pyplot as plt
    from scipy import stats

    from runners import sweep

    rng = np.random.default_rng(3)
    rows = []
    for control, n in (("nrtraffic", 6), ("traffic_light", 6), ("priority", 3)):
        for seed in range(1, n + 1):
            rows.append({"demand.rate_veh_h": 400, "seed": seed, "control": control, "status": "ok", "error": "",
                         "throughput_veh_h": 1500 + 40 * rng.standard_normal(), "mean_delay_s": 5 + rng.random(),
                         "mean_fuel_ml": 20 + rng.random(), "run_dir": "x"})
    df = pd.DataFrame(rows)
    summ = sweep.summarize(df)
    figs = []
    monkeypatch.setattr(plt, "close", lambda fig=None: figs.append(fig))
    sweep.figure(summ, tmp_path / "sweep.png")
    assert (tmp_path / "sweep.png").is_file()
    axes = figs[0].axes
    assert len(axes) == 3
    for ax, k in zip(axes, ("throughput_veh_h", "mean_delay_s", "mean_fuel_ml")):
        from matplotlib.container import BarContainer, ErrorbarContainer

        bars = next(c for c in ax.containers if isinstance(c, BarContainer))
        errs = next(c for c in ax.containers if isinstance(c, ErrorbarContainer))
        labels = [t.get_text() for t in ax.get_xticklabels()]
        assert labels == list(summ["control"]) and len(bars.patches) == 3
        for bar, err, control in zip(bars.patches, errs.lines[2][0].get_segments(), labels):
            x = df.loc[df["control"] == control, k].to_numpy()
            assert bar.get_height() == pytest.approx(x.mean())
            half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)) if len(x) >= 5 else 0.0
            assert (err[1][1] - err[0][1]) / 2 == pytest.approx(half)
    assert "grid" not in figs[0].texts[0].get_text() and "rate_veh_h = 400" in figs[0].texts[0].get_text()


def test_a_sweep_with_baselines_puts_the_controls_side_by_side(cross4_pair, tmp_path):
    """A sweep's per-movement and per-approach tables by control: with the two cross4 runs as two
    seeds of each control, each figure is the mean of the two runs' own (movements.csv,
    compare's approach figures), the level of service that of the mean delay."""
    from nrtraffic.compare import approach_figures
    from nrtraffic.metrics import level_of_service
    from runners import sweep

    nr, tl = cross4_pair / "nr", cross4_pair / "tl"
    df = pd.DataFrame([{"demand.rate_veh_h": 400, "seed": seed, "control": c, "status": "ok", "error": "",
                        "run_dir": str(d), "throughput_veh_h": 1.0, "mean_delay_s": 1.0, "mean_fuel_ml": 1.0}
                       for seed in (1, 2) for c, d in (("nrtraffic", nr), ("traffic_light", tl))])
    (appr_heading, _, appr), (mv_heading, _, mv) = sweep.side_by_side(df)
    assert len(mv) == 2 * 12 and len(appr) == 2 * 4
    assert mv["control"].tolist()[:2] == ["nrtraffic", "traffic_light"]
    for control, d, signalised in (("nrtraffic", nr, False), ("traffic_light", tl, True)):
        own = pd.read_csv(d / "movements.csv")
        got = mv[mv["control"] == control].reset_index(drop=True)
        assert got["vehicles_per_run"].tolist() == own["vehicles"].tolist()
        assert got["mean_delay_s"].tolist() == pytest.approx(own["mean_delay_s"].round(3).tolist(), nan_ok=True)
        assert got["runs"].tolist() == (2 * own["mean_delay_s"].notna()).tolist()
        for delay, los in zip(got["mean_delay_s"], got["los"]):
            assert los == (level_of_service(delay, signalised) if delay == delay else None) or pd.isna(los)
        own = approach_figures(d, json.loads((d / "summary.json").read_text()))
        got = appr[appr["control"] == control].reset_index(drop=True)
        for col in ("throughput_veh_h", "p95_queue_veh", "max_queue_veh"):
            assert got[col].tolist() == pytest.approx(own[col].round(3).tolist(), nan_ok=True), col
    sweep.write_tables(df, tmp_path)
    page = (tmp_path / "report.html").read_text()
    assert "<title>cross4: sweep, seeds 1-2 over demand.rate_veh_h (nrtraffic, traffic_light)</title>" in page
    assert "Movements, by control" in page and (tmp_path / "sweep_movements.csv").is_file()


def test_time_space_of_a_run_that_starts_later_on_sumos_clock(tmp_path):
    """cross4 started at 500 s on SUMO's clock (scenario.begin_s): fcd.xml's times are SUMO's, the
    run's are from its start; the diagram's series from fcd.xml and from the controller's
    trajectories agree on every vehicle's position at the same instants (within cg_to_front and a
    SUMO step at the speed limit), and so they are on the run's clock."""
    from runners.single import run_scenario

    sc = scenario.load(CROSS4, ["outputs.sumo_fcd=true", "outputs.warmup_s=0.0", "scenario.begin_s=500.0"])
    out = tmp_path / "run"
    run_scenario(sc, out, duration_s=80.0)
    fcd = timespace.time_space_series(out)
    ctl = timespace.time_space_series(out, source="trajectories")
    lead = sc.vehicle.params().cg_to_front
    step = sc.sumo.step_length_s * sc.planning.v_max_mps
    compared = 0
    for road in fcd:
        assert fcd[road]["t"].between(0.0, 80.0).all()
        j = fcd[road].merge(ctl[road], on=["vehicle_id", "t"], suffixes=("_fcd", "_ctl"))
        assert (j["s_m_fcd"] - j["s_m_ctl"]).between(lead - 0.5, lead + step + 0.5).all(), road
        compared += len(j)
    assert compared > 500
