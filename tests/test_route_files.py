"""Route files as SUMO reads them, on a corridor of three controlled junctions: whole routes kept,
trips routed (as duarouter routes them: the fastest path at the speed limits), each vehicle's
crossings taken from its route, and a route the network cannot drive refused before SUMO starts."""

import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import pandas as pd
import pytest
import sumolib

from conftest import ROOT, copy_scenario

ROUTES = """<routes>
    <vType id="lorry" vClass="truck" length="12"/>
    <trip id="through" depart="2" from="W_J1" to="J3_E"/>
    <vehicle id="side" type="lorry" depart="4" departPos="50" departLane="0"><route edges="N1_J1 J1_J2 J2_S2"/></vehicle>
    <flow id="west" from="E_J3" to="J2_N2" begin="0" end="40" vehsPerHour="180"/>
    <trip id="via" depart="6" from="S3_J3" to="J1_W" via="J3_J2"/>
</routes>
"""


def _corridor(tmp_path, routes=ROUTES):
    d = copy_scenario("corridor3", tmp_path / "sc", "min_headway_s = 1.5\n",
                      'min_headway_s = 1.5\nsumo_routes = "r.rou.xml"\n')
    toml = d / "scenario.toml"
    text = toml.read_text()
    text = text[:text.index("[[demand.flows]]")] + text[text.index("[[junctions]]"):]  # the file is the demand
    toml.write_text(text)
    (d / "r.rou.xml").write_text(routes)
    return d


def _run(args, **kw):
    return subprocess.run([sys.executable, "-m", "runners.cli", *map(str, args), "--no-progress"], cwd=ROOT,
                          capture_output=True, text=True, **kw)


def test_a_route_file_drives_a_corridor_each_vehicle_on_its_whole_route(tmp_path):
    d = _corridor(tmp_path)
    out = tmp_path / "run"
    r = _run(["run", d / "scenario.toml", "--duration", "150", "--set", "outputs.warmup_s=0", "--out", out])
    assert r.returncode == 0, r.stderr
    net = sumolib.net.readNet(str(d / "net.net.xml"))

    def fastest(a, b, via=()):
        stops = [a, *via, b]
        path = [stops[0]]
        for x, y in zip(stops, stops[1:]):
            path += [e.getID() for e in net.getFastestPath(net.getEdge(x), net.getEdge(y))[0][1:]]
        return path

    # the routes SUMO was given: each vehicle's whole route; trips routed on the fastest path
    rou = ET.parse(out / "sumo" / "routes.rou.xml").getroot()
    routes = {r.get("id"): r.get("edges").split() for r in rou.iter("route")}
    given = {v.get("id"): routes[v.get("route")] for v in rou.iter("vehicle")}
    assert given["through"] == fastest("W_J1", "J3_E") == ["W_J1", "J1_J2", "J2_J3", "J3_E"]
    assert given["side"] == ["N1_J1", "J1_J2", "J2_S2"]
    assert given["via"] == fastest("S3_J3", "J1_W", ["J3_J2"])
    flow = [v for v in given if v.startswith("west.")]
    assert len(flow) == 2 and all(given[v] == fastest("E_J3", "J2_N2") for v in flow)
    # SUMO drove them to the end of those routes (its own tripinfo: where each arrived, how far it went)
    trips = {t.get("id"): t for t in ET.parse(out / "tripinfo.xml").getroot().iter("tripinfo")}
    assert float(trips["side"].get("departPos")) == 50.0 and trips["side"].get("departLane") == "N1_J1_0"
    for vid, edges in given.items():
        assert trips[vid].get("arrivalLane").rsplit("_", 1)[0] == edges[-1]
        assert float(trips[vid].get("routeLength")) > sum(net.getEdge(e).getLength() for e in edges[1:-1])
    # one crossing per controlled junction on the route, in order, each under control
    v = pd.read_csv(out / "vehicles.csv")
    legs = v.groupby("vehicle_id")["junction"].apply(list).to_dict()
    assert legs["through"] == ["J1", "J2", "J3"]
    assert legs["side"] == ["J1", "J2"]
    assert legs["via"] == ["J3", "J2", "J1"]
    assert all(legs[f] == ["J3", "J2"] for f in flow)
    assert v["t_exit_s"].notna().all() and (v["plant_steps"] > 0).all()
    # the run says that the file's vehicles, its truck too, drive as nrtraffic's car
    summary = json.loads((out / "summary.json").read_text())
    assert any("its 5 vehicles drive as nrtraffic's car" in w and "1 of vClass truck" in w for w in summary["warnings"])
    # the run folder holds its route file: it replays from there alone
    assert (out / "sumo" / "r.rou.xml").read_text() == ROUTES
    (d / "r.rou.xml").unlink()
    r = _run(["replay", out, "--out", tmp_path / "again"])
    assert r.returncode == 0 and "matches" in r.stdout + r.stderr, r.stdout + r.stderr


@pytest.mark.parametrize("body, message", [
    ('<vehicle id="x" depart="1"><route edges="W_J1 J1_J2 J2_J3 nowhere"/></vehicle>',
     "names edge 'nowhere', which the network does not have"),
    ('<vehicle id="x" depart="1"><route edges="W_J1 J2_J3"/></vehicle>',
     "from edge 'W_J1' to 'J2_J3', which the network does not connect"),
    ('<trip id="x" depart="1" from="W_J1" to="N1_J1"/>', "duarouter could not route its trips"),
    ('<trip id="x" depart="1" from="W_J1" to="J1_J2" departLane="2"/>', "departLane=2, but its first edge 'W_J1' has 1"),
    ('<vehicle id="x" depart="1" departLane="left"><route edges="W_J1 J1_J2"/></vehicle>',
     "departLane='left' is not a lane index"),
    ('<trip id="x" depart="1" from="W_J1" to="J1_J2" departLane="left"/>', "Invalid departLane definition for trip 'x'"),
    ('<vehicle id="x" depart="1" departSpeed="fast"><route edges="W_J1 J1_J2"/></vehicle>',
     "departSpeed='fast' is not a number"),
    ('<vehicle id="x" depart="1" departSpeed="-3"><route edges="W_J1 J1_J2"/></vehicle>', "departSpeed=-3 is negative"),
    ('<vehicle id="x" depart="1" departPos="-5"><route edges="W_J1 J1_J2"/></vehicle>',
     "departPos=-5: give the position from the edge's start"),
    ('<vehicle id="x" depart="-5"><route edges="W_J1 J1_J2"/></vehicle>', "depart=-5 is negative"),
    ('<trip id="x" depart="1" from="W_J1" to="J1_J2" departPos="900"/>', "r.rou.xml: <vehicle id='x'>: departPos=900.00 lies beyond its first edge 'W_J1'"),
    # ids SUMO refuses once started (one with "&amp;" was written back unescaped)
    ('<vehicle id="a&amp;b" depart="1"><route edges="W_J1 J1_J2"/></vehicle>', "SUMO takes no '&' in a vehicle id"),
    ('<vehicle id="a b" depart="1"><route edges="W_J1 J1_J2"/></vehicle>', "SUMO takes no ' ' in a vehicle id"),
    ('<vehicle id="x" depart="triggered"><route edges="W_J1 J1_J2"/></vehicle>',
     "depart='triggered': the run takes departures in seconds only"),
    # a flow of 10^12 vehicles to be routed (duarouter ran for minutes and could not be stopped)
    ('<flow id="f" begin="0" end="1e9" period="0.001" from="W_J1" to="J1_J2"/>', "makes 1e+12 vehicles"),
])
def test_a_route_the_network_cannot_drive_is_refused_before_sumo_starts(tmp_path, body, message):
    d = _corridor(tmp_path, f"<routes>\n    {body}\n</routes>\n")
    out = tmp_path / "run"
    r = _run(["run", d / "scenario.toml", "--duration", "30", "--out", out])
    assert r.returncode == 2, r.stderr
    assert re.search(re.escape(message), r.stderr) and "demand.sumo_routes" in r.stderr, r.stderr
    assert not (out / "summary.json").exists()  # refused before the run


def test_a_route_file_at_seven_in_the_morning_gives_the_figures_of_the_same_file_at_zero(tmp_path):
    """scenario.begin_s = 25200 (SUMO's --begin) with tee3's route file moved to 07:00: the same
    vehicles, crossings and figures as the file at 0 s, times measured from the start."""
    from conftest import SCENARIOS

    runs = {}
    for begin in (0, 25200):
        d = tmp_path / f"at{begin}"
        d.mkdir()
        for f in (SCENARIOS / "tee3").iterdir():
            if f.is_file():
                (d / f.name).write_bytes(f.read_bytes())
        tree = ET.parse(d / "flows.rou.xml")
        for el in tree.getroot():
            for key in ("depart", "begin", "end"):
                if el.get(key) is not None:
                    el.set(key, f"{float(el.get(key)) + begin:.2f}")
        tree.write(d / "flows.rou.xml")
        toml = d / "routes.toml"
        toml.write_text(toml.read_text().replace("duration_s = 600.0", f"duration_s = 600.0\nbegin_s = {begin}.0"))
        out = tmp_path / f"run{begin}"
        r = _run(["run", toml, "--duration", "120", "--set", "outputs.warmup_s=10", "--out", out])
        assert r.returncode == 0, r.stderr
        runs[begin] = out
    a, b = (pd.read_csv(runs[k] / "vehicles.csv").set_index("vehicle_id").sort_index() for k in (0, 25200))
    assert len(a) > 10 and list(a.index) == list(b.index)
    num = a.select_dtypes("number").columns
    pd.testing.assert_frame_equal(a[num], b[num], rtol=1e-6, atol=1e-6)
    sa, sb = (json.loads((runs[k] / "summary.json").read_text()) for k in (0, 25200))
    assert sb["begin_s"] == 25200 and sa["begin_s"] == 0
    cfg = ET.parse(runs[25200] / "sumo" / "run.sumocfg").getroot()  # (sumo-gui -c opens it at 07:00 too)
    assert float(next(cfg.iter("begin")).get("value")) == 25200
    for key in ("vehicles_spawned", "throughput_veh_h", "mean_delay_s", "demand_veh_h", "measure_from_s", "measure_to_s"):
        assert sa[key] == pytest.approx(sb[key], rel=1e-9, abs=1e-9), key
    # SUMO's own clock ran from 07:00: its tripinfo departures are the relative ones plus 25200
    dep = {t.get("id"): float(t.get("depart")) for t in ET.parse(runs[25200] / "tripinfo.xml").getroot().iter("tripinfo")}
    dep0 = {t.get("id"): float(t.get("depart")) for t in ET.parse(runs[0] / "tripinfo.xml").getroot().iter("tripinfo")}
    assert dep and all(abs(dep[v] - dep0[v] - 25200) < 1e-6 for v in dep0)


def test_sumo_clock_options_are_refused_for_scenario_begin_s(tmp_path):
    from conftest import SCENARIOS

    r = _run(["run", SCENARIOS / "tee3" / "routes.toml", "--set", 'sumo.extra_args=["--begin", "25200"]',
              "--out", tmp_path / "run"])
    assert r.returncode == 2 and "scenario.begin_s" in r.stderr, r.stderr


def test_a_sumocfg_gives_the_network_route_files_begin_and_end(tmp_path):
    """scenario.sumocfg: the network, two route files (a route defined in one, used in the other),
    begin and end from a SUMO configuration in a folder of its own."""
    from nrtraffic import scenario
    from nrtraffic.demand import Demand

    d = _corridor(tmp_path)
    cfg = d / "sumo"
    cfg.mkdir()
    (d / "net.net.xml").rename(cfg / "city.net.xml")
    (cfg / "defs.rou.xml").write_text('<routes>\n    <route id="r" edges="N1_J1 J1_J2 J2_S2"/>\n</routes>\n')
    (cfg / "cars.rou.xml").write_text('<routes>\n    <vehicle id="a" depart="25210" route="r"/>\n'
                                      '    <vehicle id="early" depart="25100" route="r"/>\n'
                                      '    <trip id="b" depart="25230" from="W_J1" to="J3_E"/>\n</routes>\n')
    (cfg / "city.sumocfg").write_text("""<configuration>
    <input>
        <net-file value="city.net.xml"/>
        <route-files value="defs.rou.xml,cars.rou.xml"/>
        <additional-files value="detectors.add.xml"/>
    </input>
    <processing>
        <time-to-teleport value="-1"/>
    </processing>
    <time>
        <begin value="25200"/>
        <end value="28800"/>
    </time>
</configuration>
""")
    toml = d / "scenario.toml"
    text = toml.read_text().replace('network = "net.net.xml"', 'sumocfg = "sumo/city.sumocfg"')
    text = text.replace("duration_s = 600.0\n", "").replace('sumo_routes = "r.rou.xml"\n', "")
    toml.write_text(text)
    sc = scenario.load(toml)
    assert sc.network_path == (cfg / "city.net.xml").resolve()
    assert sc.general.begin_s == 25200 and sc.general.duration_s == 3600
    assert [p.name for p in sc.demand.route_files(sc.base_dir)] == ["defs.rou.xml", "cars.rou.xml"]
    dem = Demand.of(sc)
    dep = {v[0]: (v[1], v[2]) for v in dem.departures()}
    assert set(dep) == {"a", "b"}  # "early" departs before the begin: SUMO does not insert it
    assert dep["a"][1] == 10.0 and dep["b"][1] == 30.0
    assert dem.route_edges(dep["a"][0]) == ("N1_J1", "J1_J2", "J2_S2")
    assert dem.itineraries[dep["b"][0]] == ("W_J1.straight", "J1_J2.straight", "J2_J3.straight")
    # what it does not take is said (a summary warning), not dropped in silence
    assert any(n.startswith("scenario.sumocfg:") and "additional-files, time-to-teleport are not used" in n
               for n in dem.notes), dem.notes


@pytest.mark.parametrize("begin, end, message", [
    ("100", "40", "<end value='40'> is not after the begin (100 s)"),
    ("0", "1e9", "<end value='1e9'> makes a run of 1e+09 s, longer than the longest run"),
    ("0", "nan", "<end value='nan'> is not a time of SUMO's clock"),
])
def test_a_sumocfg_whose_end_is_not_after_its_begin_is_refused(tmp_path, begin, end, message):
    from nrtraffic import scenario
    from nrtraffic.scenario import ScenarioError

    d = _corridor(tmp_path)
    (d / "c.sumocfg").write_text(f'<configuration><time><begin value="{begin}"/><end value="{end}"/></time>'
                                 '</configuration>')
    toml = d / "scenario.toml"
    toml.write_text(toml.read_text().replace("duration_s = 600.0\n", 'sumocfg = "c.sumocfg"\n'))
    with pytest.raises(ScenarioError, match=re.escape(message)):
        scenario.load(toml)


def test_a_listed_vehicle_with_a_generated_vehicles_id_is_refused(tmp_path):
    """[[vehicles]] id = "N_in.0" beside random demand, which names its vehicles <approach>.<k>:
    refused before SUMO starts (SUMO refused the second insertion at t = 1 s)."""
    d = copy_scenario("cross4", tmp_path / "sc", extra='\n[[vehicles]]\nid = "N_in.0"\napproach = "N_in.straight"\n'
                                                       'depart_s = 50.0\n')
    r = _run(["run", d / "scenario.toml", "--duration", "60", "--out", tmp_path / "o"])
    assert r.returncode == 2 and "vehicle id 'N_in.0' is given twice" in r.stderr, r.stderr


def test_a_depart_offset_makes_seeds_of_a_route_file_differ_and_keeps_each_seed_the_same():
    """demand.depart_offset_s = 30 (SUMO's --random-depart-offset) on tee3's route file: every
    departure is the file's plus an offset in [0, 30] s; seeds 1 and 2 differ, seed 1 twice is the
    same; without it every seed gives the file's own times. (A run and its baselines build the
    demand the same way, so they share each seed's offsets.)"""
    from conftest import SCENARIOS

    from nrtraffic import scenario
    from nrtraffic.demand import Demand

    toml = SCENARIOS / "tee3" / "routes.toml"
    plain = scenario.load(toml)
    shifted = scenario.load(toml, ["demand.depart_offset_s=30.0"])
    times = lambda sc, seed: {v: t for v, _, t, *_ in Demand.of(sc, seed, 300.0).departures()}  # noqa: E731
    base, a, b = times(plain, 1), times(shifted, 1), times(shifted, 2)
    assert times(plain, 2) == base and times(shifted, 1) == a
    common = set(base) & set(a) & set(b)
    assert len(common) > 20
    assert all(0.0 <= a[v] - base[v] <= 30.0 and 0.0 <= b[v] - base[v] <= 30.0 for v in common)
    assert sum(abs(a[v] - b[v]) > 1e-6 for v in common) > 0.9 * len(common)
    with pytest.raises(scenario.ScenarioError, match="depart_offset_s shifts the departures of demand.sumo_routes"):
        scenario.load(SCENARIOS / "tee3" / "scenario.toml", ["demand.depart_offset_s=30.0"])


def test_one_route_file_named_twice_is_refused_naming_it():
    from conftest import SCENARIOS

    from nrtraffic import scenario

    with pytest.raises(scenario.ScenarioError, match="demand.sumo_routes names flows.rou.xml twice"):
        scenario.load(SCENARIOS / "tee3" / "routes.toml", ['demand.sumo_routes="flows.rou.xml, ./flows.rou.xml"'])


def test_a_route_over_a_bus_lane_is_refused_before_sumo_starts_naming_vehicle_and_edge(tmp_path):
    """bologna_pasubio's edge 27 is bus-only: a vehicle of the route file routed onto it (the source
    file did, with a class that ignores permissions) cannot drive as nrtraffic's passenger car.
    Before, SUMO stopped the run at its insertion with exit 1; now exit 2 before SUMO starts,
    naming the vehicle, the edge and the fix."""
    from conftest import SCENARIOS

    d = tmp_path / "sc"
    d.mkdir()
    for f in (SCENARIOS / "bologna_pasubio").iterdir():
        (d / f.name).write_bytes(f.read_bytes())
    (d / "demand.rou.xml").write_text('<routes>\n  <vehicle id="car" depart="0"><route edges="23 27"/></vehicle>\n'
                                      '</routes>\n')
    r = _run(["run", d, "--duration", "30", "--set", "outputs.warmup_s=0", "--out", tmp_path / "out"])
    assert r.returncode == 2, r.stderr
    assert "<vehicle id='car'>: its route uses edge '27', on which a passenger car may not drive" in r.stderr
    assert "leave such vehicles out of the file" in r.stderr and not (tmp_path / "out" / "summary.json").exists()


def test_demand_scale_keeps_copies_or_leaves_out_a_route_files_vehicles_as_sumos_scale():
    """demand.scale on tee3's route file: 2 gives every vehicle twice (its copy ``<id>#1``, same
    departure and route); 1.5 every vehicle once and about half of them twice; 0.5 about half of
    them; each drawn from the seed (one seed the same twice, two seeds different)."""
    from conftest import SCENARIOS

    from nrtraffic import scenario
    from nrtraffic.demand import Demand

    toml = SCENARIOS / "tee3" / "routes.toml"
    deps = lambda scale, seed: {v: (r, t) for v, r, t, *_ in Demand.of(  # noqa: E731
        scenario.load(toml, [f"demand.scale={scale}"]), seed, 600.0).departures()}
    base = deps(1.0, 1)
    n = len(base)
    assert n > 50
    two = deps(2.0, 1)
    assert len(two) == 2 * n and all(two[f"{v}#1"] == base[v] and two[v] == base[v] for v in base)
    up, up2 = deps(1.5, 1), deps(1.5, 2)
    assert set(base) <= set(up) and abs(len(up) - 1.5 * n) < 4 * (0.25 * n) ** 0.5  # binomial: 4 sd
    assert deps(1.5, 1) == up and set(up) != set(up2)
    half = deps(0.5, 1)
    assert set(half) < set(base) and abs(len(half) - 0.5 * n) < 4 * (0.25 * n) ** 0.5
    with pytest.raises(scenario.ScenarioError, match="demand.scale scales the vehicles of demand.sumo_routes"):
        scenario.load(SCENARIOS / "tee3" / "scenario.toml", ["demand.scale=1.5"])


def test_stops_in_a_route_file_are_left_out_with_a_warning(tmp_path):
    """<stop> elements, and persons, were dropped from the run's routes without a word. (A corridor with a
    direction that no vehicle drove failed its report: its arterial series added text to numbers.)"""
    d = _corridor(tmp_path, '<routes>\n    <vehicle id="x" depart="1"><route edges="W_J1 J1_J2"/>'
                            '<stop lane="J1_J2_0" endPos="50" duration="5"/></vehicle>\n'
                            '    <person id="p" depart="1"><walk edges="W_J1 J1_J2"/></person>\n</routes>\n')
    out = tmp_path / "run"
    r = _run(["run", d / "scenario.toml", "--duration", "30", "--set", "outputs.warmup_s=0", "--out", out])
    assert r.returncode == 0, r.stderr
    warnings = json.loads((out / "summary.json").read_text())["warnings"]
    assert any("its 1 <stop> elements are left out" in w for w in warnings), warnings
    assert any("its 1 persons and containers are left out" in w for w in warnings), warnings  # (said nothing)


def test_a_scale_copy_with_a_files_id_is_named_and_compressed_files_run(tmp_path):
    """A route file's vehicle ``a#1`` beside the copy ``demand.scale = 2`` makes of ``a`` (named
    ``a#1`` too): the clash is named as such (the message had blamed [[vehicles]], which the scenario
    does not have). A gzipped network and route file (as SUMO reads them) give the run of the plain
    ones."""
    import gzip
    import shutil

    from conftest import SCENARIOS

    d = tmp_path / "s"
    d.mkdir()
    shutil.copy(SCENARIOS / "cross4" / "net.net.xml", d / "net.net.xml")
    (d / "r.rou.xml").write_text('<routes><route id="r" edges="W_in E_out"/><vehicle id="a" route="r" depart="1"/>'
                                 '<vehicle id="a#1" route="r" depart="5"/></routes>\n')
    toml = ('[scenario]\nname = "s"\nnetwork = "{net}"\nduration_s = 60.0\n[junction]\nid = "C"\n[demand]\n'
            'sumo_routes = "r.rou.xml"\n{scale}[outputs]\nwarmup_s = 0\n')
    (d / "a.toml").write_text(toml.format(net="net.net.xml", scale="scale = 2.0\n"))
    r = _run(["run", d / "a.toml", "--out", tmp_path / "o"])
    assert r.returncode == 2 and "by the copy that demand.scale = 2 makes" in r.stderr and "[[vehicles]]" not in r.stderr
    with open(d / "net.net.xml", "rb") as f, gzip.open(d / "net.net.xml.gz", "wb") as g:
        g.write(f.read())
    with open(d / "r.rou.xml", "rb") as f, gzip.open(d / "r.rou.xml.gz", "wb") as g:
        g.write(f.read().replace(b'id="a#1"', b'id="b"'))
    (d / "r.rou.xml").write_text((d / "r.rou.xml").read_text().replace('id="a#1"', 'id="b"'))
    (d / "b.toml").write_text(toml.format(net="net.net.xml.gz", scale="").replace("r.rou.xml", "r.rou.xml.gz"))
    (d / "c.toml").write_text(toml.format(net="net.net.xml", scale=""))
    runs = []
    for name in ("b", "c"):  # (compressed, plain: the same run)
        r = _run(["run", d / f"{name}.toml", "--out", tmp_path / name])
        assert r.returncode == 0, r.stderr
        runs.append((tmp_path / name / "vehicles.csv").read_text())
    assert runs[0] == runs[1] and runs[0].count("\n") == 3  # (a header and the two vehicles)
