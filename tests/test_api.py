"""The Python API (``nrtraffic.run``, ``nrtraffic.baseline``, ``nrtraffic.sweep``): the DataFrames
it returns against SUMO's own outputs of the same run."""

import re
import shutil
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd
import pytest

import nrtraffic
from nrtraffic import scenario
from nrtraffic.scenario import ScenarioError

from conftest import SCENARIOS

CROSS4 = SCENARIOS / "cross4"


def _sumo_vehicles(run_dir: Path) -> set[str]:
    """The vehicles SUMO had in the network after any step (its fcd.xml)."""
    return {v.get("id") for ts in ET.parse(run_dir / "fcd.xml").getroot().iter("timestep") for v in ts.iter("vehicle")}


def test_run_returns_the_run_as_dataframes():
    """``nrtraffic.run("sumo_scenarios/cross4", duration_s=120, seed=1)`` without ``out``: a run
    directory under the temporary folder; ``vehicles`` a row per vehicle SUMO inserted (SUMO's
    fcd.xml), the ones SUMO saw arrive (tripinfo.xml) among them; ``movements`` one row per
    movement of the network's junction C; ``trajectories()`` the controlled vehicles."""
    res = nrtraffic.run(str(CROSS4), duration_s=120, seed=1, overrides={"outputs.sumo_fcd": True})
    try:
        assert Path(tempfile.gettempdir()) in res.run_dir.parents
        assert res.summary["status"] == "ok" and res.summary["seed"] == 1 and res.summary["sim_time_s"] == 120
        v = res.vehicles
        assert isinstance(v, pd.DataFrame) and len(v) > 10
        # every vehicle SUMO inserted is in the run, the ones of its last step too
        seen = _sumo_vehicles(res.run_dir)
        assert set(v["vehicle_id"]) == seen and len(v) == len(seen) == res.summary["vehicles_spawned"]
        arrived = {t.get("id") for t in ET.parse(res.run_dir / "tripinfo.xml").getroot().iter("tripinfo")}
        assert arrived and arrived <= seen
        net = ET.parse(CROSS4 / "net.net.xml").getroot()
        turns = {(c.get("from"), c.get("to")) for c in net.iter("connection")
                 if c.get("from") in {"N_in", "S_in", "E_in", "W_in"}}
        assert len(res.movements) == len(turns)
        assert set(res.approaches["approach"]) == {"N_in", "S_in", "E_in", "W_in"}
        traj = res.trajectories()
        assert set(traj["vehicle_id"]) == set(v.loc[v["t_enter_s"].notna(), "vehicle_id"])
        assert res.report.is_file()
        again = nrtraffic.Run(res.run_dir)  # a run directory opened later
        assert again.summary == res.summary and again.vehicles.equals(v)
    finally:
        shutil.rmtree(res.run_dir, ignore_errors=True)


def test_baseline_returns_the_same_kind_of_run(tmp_path):
    res = nrtraffic.baseline(CROSS4, "priority", seed=2, duration_s=60, out=tmp_path / "b", report=False,
                             overrides=["outputs.sumo_fcd=true", "outputs.warmup_s=0"])
    assert res.run_dir == tmp_path / "b" and res.summary["control"] == "sumo_priority"
    assert set(res.vehicles["vehicle_id"]) == _sumo_vehicles(res.run_dir)
    assert not res.report.exists()
    page = res._repr_html_()
    assert "<td>sumo_priority</td>" in page and f"<td>{res.summary['vehicles_spawned']}</td>" in page


def test_settings_as_python_values_are_the_scenario_keys():
    """A mapping of Python values is read as ``--set`` texts would be."""
    from runners.api import settings

    ov = settings({"demand.rate_veh_h": 600, "outputs.sumo_fcd": True, "scenario.name": 'a "b" c',
                   "controller.horizon_s": 0.25})
    sc = scenario.load(CROSS4, ov)
    assert (sc.demand.rate_veh_h, sc.outputs.sumo_fcd, sc.general.name, sc.controller.horizon_s) == (
        600.0, True, 'a "b" c', 0.25)


def test_bad_input_raises_before_anything_is_written(tmp_path):
    with pytest.raises(ScenarioError, match="rate_veh_h"):
        nrtraffic.run(CROSS4, out=tmp_path / "r", overrides={"demand.rate_veh_h": -5})
    assert not (tmp_path / "r").exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    from runners.api import OutputError

    with pytest.raises(OutputError, match="not empty"):
        nrtraffic.run(CROSS4, out=tmp_path / "mine", duration_s=30, overrides={"outputs.warmup_s": 0})
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["notes.txt"]


def test_sweep_returns_its_table(tmp_path):
    """Two seeds and two demand levels on one worker: a row per run, each ``ok``, its figures
    those of the run's own summary.json."""
    import json

    sw = nrtraffic.sweep(CROSS4, range(1, 3), grid={"demand.rate_veh_h": [300, 600]}, workers=1,
                         out=tmp_path / "s", overrides={"scenario.duration_s": 25, "demand.end_s": 12,
                                                        "outputs.warmup_s": 0})
    t = sw.table
    assert len(t) == 4 and (t["status"] == "ok").all() and sw.failed.empty
    assert sorted(zip(t["demand.rate_veh_h"], t["seed"])) == [(300, 1), (300, 2), (600, 1), (600, 2)]
    for i in range(len(t)):
        s = json.loads((Path(t["run_dir"].iloc[i]) / "summary.json").read_text())
        assert s["seed"] == t["seed"].iloc[i] and s["vehicles_spawned"] == t["vehicles_spawned"].iloc[i]
        assert sw.run(i).summary == s
    assert len(sw.summary) == 2 and sw.report.is_file()


@pytest.mark.parametrize("kw, named", [
    ({"seed": 2**31}, "seed=2147483648"), ({"seed": 1.5}, "seed=1.5"), ({"seed": "abc"}, "seed='abc'"),
    ({"duration_s": float("nan")}, "duration_s=nan"), ({"duration_s": -5}, "duration_s=-5"),
    ({"duration_s": float("inf")}, "duration_s=inf"),
    ({"seed": "3"}, "seed='3'"), ({"duration_s": "10"}, "duration_s='10'"), ({"duration_s": True}, "duration_s=True"),
])
def test_api_refuses_a_seed_or_duration_the_command_refuses(tmp_path, kw, named):
    from nrtraffic.scenario import ScenarioError

    with pytest.raises(ScenarioError, match=re.escape(named)):
        nrtraffic.run(CROSS4, out=tmp_path / "o", **kw)
    assert not (tmp_path / "o").exists()


def test_api_sweep_grid_values_are_kept_whole(tmp_path, monkeypatch):
    """A list value, and a string with a comma, are one grid value each (they were split at their
    commas into several points)."""
    from runners import api
    from runners import sweep as sweep_mod

    seen = {}
    monkeypatch.setattr(sweep_mod, "study", lambda scenario, seeds, grid, *a, **k: seen.update(grid=grid))
    monkeypatch.setattr(api, "Sweep", lambda out: out)  # (nothing ran: no tables to read)
    nrtraffic.sweep(CROSS4, [1], grid={"sumo.extra_args": [["--max-depart-delay", "300"], []],
                                       "scenario.description": ["a, b"]}, out=tmp_path / "s")
    assert seen["grid"] == [("sumo.extra_args", ['["--max-depart-delay", "300"]', "[]"]),
                            ("scenario.description", ["a, b"])]


@pytest.mark.parametrize("seeds, grid, message", [
    ([1.5], None, "1.5 is not an integer"),  # (run as seed 1)
    ([True], None, "True is not an integer"),
    ([1], {"demand.rate_veh_h": [300, 300.0]}, "300 and 300.0 are the same value"),  # (one point run twice)
])
def test_api_sweep_refuses_what_the_command_line_refuses(seeds, grid, message, tmp_path):
    """``nrtraffic.sweep`` checks its seeds and grid as ``nrtraffic sweep`` does, before anything
    runs or is written."""
    from runners.sweep import SweepError

    with pytest.raises(SweepError, match=re.escape(message)):
        nrtraffic.sweep(CROSS4, seeds, grid=grid, duration_s=5, workers=1, out=tmp_path / "s")
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("kw, message", [
    ({"seeds": []}, "seeds: none given"), ({"seeds": range(1, 1)}, "seeds: none given"),
    ({"seeds": {1: 2}}, "seeds={1: 2}: give the seeds"),  # (a mapping: its keys had been taken as the seeds)
    ({"seeds": [1], "grid": [("demand.rate_veh_h", [300])]}, "grid=[('demand.rate_veh_h', [300])]: give"),
    ({"seeds": [1], "scheduler": 123}, "scheduler=123: give a Dask scheduler's address as text"),
    ({"seeds": [1], "baselines": [None]}, "baselines=[None]: give SUMO's controls by name"),
])
def test_api_sweep_names_a_wrong_argument(kw, message, tmp_path):
    """Arguments of the wrong kind are named (SweepError), not an AttributeError or TypeError from
    inside, nor a message about --seeds, a flag the caller did not use; nothing is written."""
    from runners.sweep import SweepError

    with pytest.raises(SweepError, match=re.escape(message)):
        nrtraffic.sweep(CROSS4, duration_s=5, workers=1, out=tmp_path / "s", **kw)
    assert not (tmp_path / "s").exists()


def test_api_overrides_take_a_sections_table_and_pairs(tmp_path):
    """``overrides={'demand': {'rate_veh_h': 300}}`` and ``[('demand.rate_veh_h', 300)]`` set the
    key as ``{'demand.rate_veh_h': 300}`` does (they had been refused naming --set); anything else
    is named."""
    from nrtraffic.scenario import ScenarioError
    from runners.api import settings

    assert settings({"demand": {"rate_veh_h": 300}}) == settings([("demand.rate_veh_h", 300)]) \
        == settings({"demand.rate_veh_h": 300}) == ["demand.rate_veh_h=300"]
    for bad in ({"demand": 3}, [3], [("a.b", 1, 2)]):
        with pytest.raises(ScenarioError, match="overrides: .* is no 'section.key"):
            settings(bad)


def test_api_values_are_checked_before_anything_is_written(tmp_path):
    """A numpy number is a number; a value of no setting's type, an unknown junction and a
    fractional number of workers are refused before any folder is made (a raw TypeError had come
    out of the run, and the folders stayed)."""
    import numpy as np

    from runners import api
    from runners.sweep import SweepError

    assert api.settings({"demand.rate_veh_h": np.float64(300), "demand.max_vehicles": np.int64(5),
                         "barriers.lateral": np.bool_(False)}) == [
        "demand.rate_veh_h=300.0", "demand.max_vehicles=5", "barriers.lateral=false"]
    with pytest.raises(ScenarioError, match="must be a number, string, bool, list or table, not NoneType"):
        nrtraffic.run(CROSS4, duration_s=5, overrides={"demand.rate_veh_h": None}, out=tmp_path / "a")
    with pytest.raises(ScenarioError, match="junction='nope': one of"):
        nrtraffic.baseline(CROSS4, "nope", duration_s=5, out=tmp_path / "b")
    with pytest.raises(ScenarioError, match="duration_s=nan: give seconds"):
        nrtraffic.sweep(CROSS4, [1], duration_s=float("nan"), out=tmp_path / "d")
    with pytest.raises(SweepError, match="workers=1.5: give a whole number"):
        nrtraffic.sweep(CROSS4, [1], duration_s=5, workers=1.5, out=tmp_path / "c")
    with pytest.raises(ScenarioError, match="force='no': give True or False"):  # (it had counted as yes)
        nrtraffic.run(CROSS4, duration_s=5, force="no", out=tmp_path / "h")
    with pytest.raises(ScenarioError, match="scenario.name = '': give a name of printable characters"):
        nrtraffic.run(CROSS4, duration_s=5, overrides={"scenario.name": ""}, out=tmp_path / "i")
    with pytest.raises(SweepError, match="seeds=None: give the seeds"):
        nrtraffic.sweep(CROSS4, None, duration_s=5, out=tmp_path / "e")
    for where in ({"scenario": str(CROSS4).encode()}, {"scenario": CROSS4, "out": b"f"}):
        with pytest.raises(ScenarioError, match="give a path as a str or a pathlib.Path"):
            nrtraffic.run(**where, duration_s=5)
    with pytest.raises(ScenarioError, match="give a path as a str or a pathlib.Path"):
        nrtraffic.sweep(bytes(CROSS4), [1], duration_s=5, out=tmp_path / "g")
    assert not any(tmp_path.iterdir())


def test_api_takes_numpy_integers_as_seeds_and_workers(tmp_path):
    """A seed or a number of workers from numpy (np.int64) is a whole number, as the same value
    in Python's int: the run's seed is that number (it had been refused)."""
    import numpy as np

    r = nrtraffic.run(CROSS4, seed=np.int64(3), duration_s=5, out=tmp_path / "r", overrides={"outputs.warmup_s": 0},
                      report=False)
    assert r.summary["seed"] == 3 and isinstance(r.summary["seed"], int)
    s = nrtraffic.sweep(CROSS4, np.arange(1, 2), duration_s=5, workers=np.int64(1), out=tmp_path / "s",
                        overrides={"outputs.warmup_s": 0})
    assert list(s.table["seed"]) == [1] and (s.table["status"] == "ok").all()


def test_api_names_its_own_arguments_when_a_seed_is_given_twice(tmp_path):
    """``seed=2`` with ``overrides={'scenario': {'seed': 3}}``: refused naming ``seed=`` and
    ``overrides`` (it had named --seed and --set, flags the caller did not use)."""
    from nrtraffic.scenario import ScenarioError

    with pytest.raises(ScenarioError, match=re.escape("seed=2 and overrides scenario.seed=3 both give it")):
        nrtraffic.run(CROSS4, seed=2, overrides={"scenario": {"seed": 3}}, out=tmp_path / "o")
    with pytest.raises(ScenarioError, match=re.escape("duration_s=5 and overrides scenario.duration_s=9")):
        nrtraffic.run(CROSS4, duration_s=5, overrides={"scenario.duration_s": 9}, out=tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_api_sweep_takes_its_baselines_from_a_generator(tmp_path, monkeypatch):
    """``baselines=(b for b in ["priority"])``: the generator is read once, for its check and its
    controls alike (a check that read it first had left no baseline to run)."""
    from runners import sweep as sweep_mod

    seen = {}
    monkeypatch.setattr(sweep_mod, "study", lambda *a, **kw: seen.setdefault("controls", a[3]))
    monkeypatch.setattr("runners.api.Sweep", lambda out: None)
    nrtraffic.sweep(CROSS4, [1], baselines=(b for b in ["priority"]), duration_s=5, out=tmp_path / "s")
    assert seen["controls"] == ["nrtraffic", "priority"]
