"""``nrtraffic replay`` against the recorded run in tests/golden (``make golden`` regenerates it)."""

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from conftest import ROOT
from runners.cli import main
from runners.replay import compare_runs, replay

GOLDEN = ROOT / "tests" / "golden" / "cross4"


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    out = tmp_path_factory.mktemp("replay") / "run"
    diffs, kept = replay(GOLDEN, out)
    return diffs, kept


def test_golden_run_replays_within_tolerance(replayed):
    diffs, kept = replayed
    assert diffs == [], "\n".join(map(str, diffs))
    # the golden run is not trivial: vehicles crossed the junction under control
    v = pd.read_csv(GOLDEN / "vehicles.csv")
    assert (v["t_exit_s"].notna()).sum() >= 5
    assert len(pd.read_parquet(GOLDEN / "trajectories.parquet")) > 100


def test_altered_figures_are_named(replayed, tmp_path):
    _, kept = replayed
    altered = tmp_path / "altered"
    shutil.copytree(kept, altered)
    s = json.loads((altered / "summary.json").read_text())
    s["mean_delay_s"] += 0.25
    (altered / "summary.json").write_text(json.dumps(s))
    v = pd.read_csv(altered / "vehicles.csv", dtype={"vehicle_id": str})
    vid = v.loc[v["t_exit_s"].notna(), "vehicle_id"].iloc[0]
    v.loc[v["vehicle_id"] == vid, "t_exit_s"] += 0.1
    v.to_csv(altered / "vehicles.csv", index=False)
    t = pd.read_parquet(altered / "trajectories.parquet")
    t.loc[t.index[10], "x"] += 1e-3
    t.to_parquet(altered / "trajectories.parquet")
    text = [str(d) for d in compare_runs(altered, kept)]
    assert len(text) == 3
    assert any("summary: mean_delay_s" in d and "-0.25" in d for d in text)
    assert any(f"vehicle_id {vid} t_exit_s" in d for d in text)
    assert any(d.startswith("trajectories.parquet") and " x:" in d for d in text)
    # below the tolerance is a match
    t.loc[t.index[10], "x"] -= 1e-3 - 1e-8
    t.to_parquet(altered / "trajectories.parquet")
    assert len(compare_runs(altered, kept)) == 2


def test_replay_command_fails_on_an_altered_run_and_says_where(tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(GOLDEN, run)
    v = pd.read_csv(run / "vehicles.csv", dtype={"vehicle_id": str})
    vid = v["vehicle_id"].iloc[0]
    v.loc[0, "energy_u2"] = v.loc[0, "energy_u2"] * 1.01 + 0.01
    v.to_csv(run / "vehicles.csv", index=False)
    assert main(["replay", str(run), "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert f"vehicles.csv: vehicle_id {vid} energy_u2" in out
    assert "difference" in out


def test_replay_refuses_a_folder_that_is_not_a_run(tmp_path, capsys):
    assert main(["replay", str(tmp_path)]) == 2
    assert "scenario.resolved.toml is missing" in capsys.readouterr().err


def test_a_run_recorded_with_the_host_cpu_target_replays_on_the_generic_one(tmp_path):
    """What a CI runner on other hardware sees: a run recorded with numba's host CPU target (its
    vector width and fused multiply-add) replays under ``NUMBA_CPU_NAME=generic`` (this test
    process, tests/conftest.py) within the default tolerance."""
    import os
    import subprocess
    import sys

    run = tmp_path / "host"
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    cmd = [sys.executable, "-m", "runners.cli", "run", str(ROOT / "sumo_scenarios" / "cross4" / "scenario.toml"),
           "--seed", "3", "--duration", "45", "--set", "demand.end_s=15", "--set", "demand.rate_veh_h=600",
           "--set", "outputs.warmup_s=0",
           "--out", str(run), "--no-progress"]
    subprocess.run(cmd, env=env, cwd=ROOT, check=True, capture_output=True)
    assert os.environ.get("NUMBA_CPU_NAME") == "generic"
    diffs, _ = replay(run, tmp_path / "generic")
    assert diffs == [], "\n".join(map(str, diffs))
    v = pd.read_csv(run / "vehicles.csv")
    assert (v["t_enter_s"].notna()).sum() >= 5  # vehicles were controlled


def test_replay_never_writes_into_the_run_it_verifies_nor_over_another_run(tmp_path, capsys):
    """``replay RUN --out RUN`` (or a folder inside it, or one that holds it) would overwrite the
    recording and compare it with itself: exit 2, nothing touched, and an edited recording still
    "differs" in a replay elsewhere. An --out that holds another run is refused unless --force."""
    run = tmp_path / "run"
    shutil.copytree(GOLDEN, run)
    v = pd.read_csv(run / "vehicles.csv", dtype={"vehicle_id": str})
    v.loc[0, "energy_u2"] = v.loc[0, "energy_u2"] * 1.01 + 0.01
    v.to_csv(run / "vehicles.csv", index=False)
    edited = (run / "vehicles.csv").read_bytes()
    for out in (run, run / "inner", tmp_path, Path(f"{run}/../{run.name}")):
        assert main(["replay", str(run), "--out", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "would overwrite the run it verifies" in err and "link" not in err  # (none is a link)
    assert (run / "vehicles.csv").read_bytes() == edited and not (run / "inner").exists()
    other = tmp_path / "other"
    shutil.copytree(GOLDEN, other)
    before = (other / "summary.json").read_bytes()
    assert main(["replay", str(run), "--out", str(other), "--no-progress"]) == 2
    assert "not empty" in capsys.readouterr().err and (other / "summary.json").read_bytes() == before
    kept = tmp_path / "kept"
    assert main(["replay", str(run), "--out", str(kept), "--no-progress"]) == 1  # the edit differs
    assert "difference(s) beyond" in capsys.readouterr().out
    assert (kept / "summary.json").is_file()


@pytest.mark.parametrize("name", ["movements.csv", "movements.json", "sumo/routes.rou.xml"])
def test_an_emptied_file_is_named_on_the_side_it_was_emptied(name, tmp_path):
    """A table emptied in the recording (or in the replay) is "not readable" on that side and
    readable on the other: the difference had put the reader's error on the replayed side."""
    for side in ("recorded", "replayed"):
        edited = tmp_path / side
        shutil.copytree(GOLDEN, edited)
        (edited / name).write_text("")
        rec, new = (edited, GOLDEN) if side == "recorded" else (GOLDEN, edited)
        d = next(d for d in compare_runs(rec, new) if d.where == name)
        bad, good = (d.recorded, d.replayed) if side == "recorded" else (d.replayed, d.recorded)
        assert d.what == "readable" and good is True and str(bad).startswith("not readable"), str(d)


def test_a_stopped_run_is_not_replayed(tmp_path, capsys):
    """A run whose summary says failed (stopped by a signal, say) is refused with exit 2 before
    anything runs: it cannot come out the same (its replay ran to the end and listed 155
    differences)."""
    import json
    import shutil

    from conftest import ROOT
    from runners.cli import main

    run = tmp_path / "run"
    shutil.copytree(ROOT / "tests" / "golden" / "cross4", run)
    s = json.loads((run / "summary.json").read_text())
    (run / "summary.json").write_text(json.dumps({**s, "status": "failed", "error": "terminated by SIGTERM"}))
    assert main(["replay", str(run), "--no-progress"]) == 2
    assert "is not a finished run (summary.json status 'failed')" in capsys.readouterr().err


def test_a_recorded_table_whose_rows_repeat_their_keys_differs_rather_than_failing():
    """An edited trajectories table in which one (vehicle_id, t) appears twice cannot be matched row
    by row: the comparison says so as a difference (it raised a broadcasting ValueError)."""
    from runners.replay import _compare_frames

    new = pd.DataFrame({"vehicle_id": ["a", "a", "b"], "t": [0.0, 0.5, 0.0], "x": [1.0, 2.0, 3.0]})
    rec = new.copy()
    rec.loc[1, "t"] = 0.0  # (row 1 now repeats row 0's keys)
    diffs = _compare_frames("trajectories", rec, new, ["vehicle_id", "t"], 1e-9, 1e-9, 40)
    assert len(diffs) == 1 and "repeat their vehicle_id, t" in str(diffs[0].recorded)
    assert _compare_frames("trajectories", new, new.copy(), ["vehicle_id", "t"], 1e-9, 1e-9, 40) == []


@pytest.mark.parametrize("edit, where", [
    ("movements", "movements.csv"),
    ("routes", "sumo/routes.rou.xml"),
    ("collision", "collisions.xml"),
    ("trip", "tripinfo.xml"),
    ("garbled", "collisions.xml"),
    ("empty_table", "movements.csv"),
    ("empty_routes", "sumo/routes.rou.xml"),
    ("queues", "queues.xml"),
    ("geometry", "movements.json"),
])
def test_an_edited_movement_table_or_route_file_differs(tmp_path, capsys, edit, where):
    """The recorded movements.csv, the route file SUMO was given and SUMO's own outputs are
    compared too: an edited count, a vehicle left out of sumo/routes.rou.xml, a made-up collision
    in collisions.xml or an edited trip duration in tripinfo.xml "differs" (all said "matches")."""
    import re

    run = tmp_path / "run"
    shutil.copytree(GOLDEN, run)
    if edit == "movements":
        m = pd.read_csv(run / "movements.csv")
        m.loc[0, "vehicles"] = int(m.loc[0, "vehicles"]) + 90
        m.to_csv(run / "movements.csv", index=False)
    elif edit == "routes":
        text = (run / "sumo" / "routes.rou.xml").read_text()
        first = re.search(r"\s*<vehicle [^>]*?(/>|>.*?</vehicle>)", text, re.S)
        (run / "sumo" / "routes.rou.xml").write_text(text[:first.start()] + text[first.end():])
    elif edit == "collision":
        text = (run / "collisions.xml").read_text()
        end = text.rindex("</collisions>")
        (run / "collisions.xml").write_text(text[:end] + '    <collision time="30.00" type="collision" lane="N_in_0" '
                                            'pos="100.00" collider="a" victim="b" colliderType="t" victimType="t" '
                                            'colliderSpeed="5.00" victimSpeed="0.00"/>\n' + text[end:])
    elif edit == "garbled":  # (it said "matches": the file was read as cut short)
        (run / "collisions.xml").write_text("garbage<<")
    elif edit == "empty_table":  # (a traceback from pandas)
        (run / "movements.csv").write_text("")
    elif edit == "empty_routes":  # (a traceback from the XML parser)
        (run / "sumo" / "routes.rou.xml").write_text("")
    elif edit == "queues":  # (SUMO's detectors: it said "matches")
        text = (run / "queues.xml").read_text()
        (run / "queues.xml").write_text(text.replace('maxJamLengthInVehicles="0"', 'maxJamLengthInVehicles="9"', 1))
    elif edit == "geometry":  # (the zones as the run built them: it said "matches")
        text = (run / "movements.json").read_text()
        (run / "movements.json").write_text(re.sub(r'"control_zone_start_m": [0-9.]+', '"control_zone_start_m": 905.0',
                                                   text, count=1))
    else:  # (the golden run's cars are all still on their way at its end: a made-up finished trip)
        text = (run / "tripinfo.xml").read_text()
        end = text.rindex("</tripinfos>")
        (run / "tripinfo.xml").write_text(text[:end] + '    <tripinfo id="made_up" depart="1.00" arrival="40.00" '
                                          'duration="39.00" timeLoss="3.00"/>\n' + text[end:])
    assert main(["replay", str(run), "--out", str(tmp_path / "again"), "--no-progress"]) == 1
    assert where in capsys.readouterr().out
