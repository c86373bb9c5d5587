"""``nrtraffic sweep`` on a local Dask cluster of two workers: tables, a failing run, resuming."""

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from runners.cli import main

SHORT = ["--set", "scenario.duration_s=25", "--set", "demand.end_s=12", "--set", "demand.rate_veh_h=600",
         "--set", "outputs.warmup_s=0"]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """cross4 with a second network file that SUMO cannot load (a connection through an internal lane
    it does not have): nrtraffic's runs on it fail in the worker. (The baseline rebuilds the
    junction with netconvert, which repairs it.)"""
    from conftest import SCENARIOS

    d = tmp_path_factory.mktemp("scenario")
    for f in (SCENARIOS / "cross4").iterdir():
        if f.is_file():
            shutil.copy(f, d / f.name)
    # a network that passes the checks before SUMO starts (its edges and junction are there) but that
    # SUMO cannot load
    net = (d / "net.net.xml").read_text()
    broken = re.sub(r'via=":C_[0-9]+_0"', 'via=":C_999_0"', net, count=1)
    assert broken != net
    (d / "broken.net.xml").write_text(broken)
    out = tmp_path_factory.mktemp("sweep") / "out"
    argv = ["sweep", str(d / "scenario.toml"), "--seeds", "1:2", "--grid", "scenario.network=net.net.xml,broken.net.xml",
            "--baseline", "priority", "--workers", "2", "--out", str(out), "--no-progress", *SHORT]
    code = main(argv)
    return argv, code, out


def test_sweep_writes_tables_and_records_the_failing_runs(study):
    _, code, out = study
    assert code == 1  # some runs failed
    df = pd.read_csv(out / "sweep.csv")
    assert len(df) == 2 * 2 * 2  # grid points x seeds x controls
    is_bad = (df["scenario.network"] == "broken.net.xml") & (df["control"] == "nrtraffic")
    good, bad = df[~is_bad], df[is_bad]
    assert (good["status"] == "ok").all() and (bad["status"] == "failed").all()
    assert bad["error"].str.len().gt(0).all()
    assert set(good["control"]) == {"nrtraffic", "priority"}
    # each finished run is a complete run directory under its final name, and its row is its summary
    for _, r in good.iterrows():
        s = json.loads((Path(r["run_dir"]) / "summary.json").read_text())
        assert s["seed"] == r["seed"] and s["status"] == "ok"
        assert s["vehicles_spawned"] == r["vehicles_spawned"] > 0
    assert not list(out.rglob(".*.tmp-*"))  # nothing half-written under a temporary name
    # the summary: mean, sd and Student-t 95 % half-width, recomputed here from the per-run rows
    summ = pd.read_csv(out / "sweep_summary.csv")
    row = summ[(summ["scenario.network"] == "net.net.xml") & (summ["control"] == "nrtraffic")].iloc[0]
    x = good[(good["control"] == "nrtraffic") & (good["scenario.network"] == "net.net.xml")]["vehicles_spawned"]
    x = x.to_numpy(float)
    assert row["runs"] == 2 and row["failed"] == 0
    assert row["vehicles_spawned_mean"] == pytest.approx(x.mean())
    assert row["vehicles_spawned_sd"] == pytest.approx(x.std(ddof=1))
    assert row["vehicles_spawned_ci95"] == pytest.approx(stats.t.ppf(0.975, 1) * x.std(ddof=1) / np.sqrt(2))
    bad_row = summ[(summ["scenario.network"] == "broken.net.xml") & (summ["control"] == "nrtraffic")].iloc[0]
    assert bad_row["runs"] == 0 and bad_row["failed"] == 2
    for f in ("sweep.md", "sweep.png", "sweep_seeds.png"):
        assert (out / f).stat().st_size > 0


def test_resuming_skips_finished_runs(study):
    argv, _, out = study
    df = pd.read_csv(out / "sweep.csv")
    ok_dirs = [Path(d) for d in df.loc[df["status"] == "ok", "run_dir"]]
    stamps = {d: (d / "summary.json").stat().st_mtime_ns for d in ok_dirs}
    code = main(argv)
    assert code == 1  # the broken runs fail again
    assert {d: (d / "summary.json").stat().st_mtime_ns for d in ok_dirs} == stamps  # not run again
    df2 = pd.read_csv(out / "sweep.csv")
    assert (df2["status"] == "ok").sum() == len(ok_dirs)


def test_bad_grid_is_refused_before_any_run(tmp_path, capsys):
    from conftest import SCENARIOS

    code = main(["sweep", str(SCENARIOS / "cross4"), "--seeds", "1:2", "--grid", "demand.no_such_key=1,2",
                 "--out", str(tmp_path / "o")])
    assert code == 2
    assert "no_such_key" in capsys.readouterr().err
    assert not (tmp_path / "o" / "runs").exists()
    # a list value: its commas would cut it into pieces ('["--threads"' had been named as a bad value)
    code = main(["sweep", str(SCENARIOS / "cross4"), "--seeds", "1", "--grid", 'sumo.extra_args=["--threads","2"],[]',
                 "--out", str(tmp_path / "o")])
    assert code == 2 and "a list or table cannot be a grid value on the command line" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    # a quoted value keeps its comma: the grid point is the whole string (its file is not there)
    code = main(["sweep", str(SCENARIOS / "cross4"), "--seeds", "1", "--grid",
                 'demand.sumo_routes="no,such.rou.xml","other.rou.xml"', "--out", str(tmp_path / "o")])
    assert code == 2 and 'at the grid point demand.sumo_routes="no,such.rou.xml":' in capsys.readouterr().err
    # ... and its brackets: a file name, not a list
    code = main(["sweep", str(SCENARIOS / "cross4"), "--seeds", "1", "--grid",
                 'demand.sumo_routes="no[1].rou.xml","other.rou.xml"', "--out", str(tmp_path / "o")])
    assert code == 2 and 'at the grid point demand.sumo_routes="no[1].rou.xml":' in capsys.readouterr().err
    code = main(["sweep", str(SCENARIOS / "cross4"), "--seeds", "1", "--grid", 'demand.sumo_routes="a.rou.xml',
                 "--out", str(tmp_path / "o")])
    assert code == 2 and "a quote (\") is not closed" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_sweep_run_replays(study):
    """A run directory of a sweep (its path holds ``key=value`` folders, which pandas would read
    as Hive partitions of the trajectory file) replays to the same figures."""
    _, _, out = study
    df = pd.read_csv(out / "sweep.csv")
    run = df.loc[(df["status"] == "ok") & (df["control"] == "nrtraffic"), "run_dir"].iloc[0]
    assert "=" in run
    assert main(["replay", run, "--no-progress"]) == 0


def test_resuming_with_another_configuration_is_refused_unless_forced(study, tmp_path, capsys):
    argv, _, out = study
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    argv = [a if a != str(out) else str(copy) for a in argv]
    df = pd.read_csv(copy / "sweep.csv")
    ok_dirs = [copy / Path(d).relative_to(out) for d in df.loc[df["status"] == "ok", "run_dir"]]
    stamps = {d: (d / "summary.json").stat().st_mtime_ns for d in ok_dirs}
    changed = [a.replace("demand.rate_veh_h=600", "demand.rate_veh_h=300") for a in argv]
    assert changed != argv
    assert main(changed) == 2
    assert "different configuration" in capsys.readouterr().err
    assert {d: (d / "summary.json").stat().st_mtime_ns for d in ok_dirs} == stamps  # nothing touched
    # --force runs them again with the new configuration, which then resumes cleanly
    assert main(changed + ["--force"]) == 1  # the broken network still fails
    assert all((d / "summary.json").stat().st_mtime_ns != stamps[d] for d in ok_dirs)
    assert main(changed) == 1


def test_stale_temporary_run_directories_are_removed(tmp_path):
    import os

    from runners.sweep import remove_stale

    dead = 2**22 + 12345  # above the default pid_max: no such process
    stale = tmp_path / "runs" / "base" / "seed1" / f".nrtraffic.tmp-{dead}-abcd1234"
    live = tmp_path / "runs" / "base" / "seed2" / f".nrtraffic.tmp-{os.getpid()}-abcd1234"
    for d in (stale, live):
        d.mkdir(parents=True)
        (d / "summary.json").write_text("{}")
    assert remove_stale(tmp_path) == [stale]
    assert not stale.exists() and live.exists()


def test_a_worker_that_dies_fails_only_the_run_it_was_running(tmp_path, monkeypatch):
    """The worker running seed 1 dies (fault injection) on every attempt: that run is recorded as
    failed (KilledWorker), every other run of the sweep finishes. With one worker, the next run
    would be queued on it when it dies unless the worker holds only the run it runs."""
    from conftest import SCENARIOS

    from runners.sweep import FAULT_KILL_WORKER

    monkeypatch.setenv(FAULT_KILL_WORKER, "1:nrtraffic")
    out = tmp_path / "out"
    argv = ["sweep", str(SCENARIOS / "cross4"), "--seeds", "1:4", "--workers", "1", "--out", str(out),
            "--no-progress", "--set", "scenario.duration_s=8", "--set", "demand.rate_veh_h=300",
            "--set", "outputs.warmup_s=0"]
    assert main(argv) == 1
    df = pd.read_csv(out / "sweep.csv")
    assert len(df) == 4
    failed = df[df["status"] != "ok"]
    assert failed["seed"].tolist() == [1] and "KilledWorker" in failed["error"].iloc[0]


def test_a_run_stopped_as_a_gridlock_is_a_gridlock_row_and_is_not_retried(tmp_path, capsys):
    """cross4 with 200 s between merging-zone entries on a lane (tests/test_gridlock.py): the
    watchdog stops nrtraffic's run. Its row says ``gridlock`` and names the junction, the run is not
    retried (what it finished is in ``.failed``, from its one attempt), SUMO's run of the same
    seed finishes, and the last line does not advise a retry."""
    from conftest import SCENARIOS

    out = tmp_path / "out"
    argv = ["sweep", str(SCENARIOS / "cross4"), "--seeds", "3", "--baseline", "priority", "--workers", "1",
            "--duration", "150", "--out", str(out), "--set", "coordinator.min_merge_headway_s=200",
            "--set", "outputs.stall_s=30", "--set", "outputs.warmup_s=0"]
    assert main(argv) == 1
    df = pd.read_csv(out / "sweep.csv").set_index("control")
    assert df.loc["priority", "status"] == "ok"
    assert df.loc["nrtraffic", "status"] == "gridlock"
    assert "Gridlock: junction C: no vehicle crossed for 30 s" in df.loc["nrtraffic", "error"]
    failed = Path(df.loc["nrtraffic", "run_dir"])  # (the row points at what the run left)
    assert failed == out / "runs" / "base" / "seed3" / "nrtraffic.failed"
    assert json.loads((failed / "summary.json").read_text())["status"] == "gridlock"
    summ = pd.read_csv(out / "sweep_summary.csv").set_index("control")
    assert summ.loc["nrtraffic", "runs"] == 0 and summ.loc["nrtraffic", "failed"] == 1
    md = (out / "sweep.md").read_text()
    assert "| nrtraffic | 0 (1; 1 gridlock) |" in md and "| priority | 1 (0) |" in md and "the gridlocks are" in md
    said = capsys.readouterr()
    assert "last: base/seed3/nrtraffic gridlock" in said.err
    assert "1 of 2 runs failed: 1 stopped as gridlocks" in said.out and "retry them" not in said.out
    # a second pass (the same command) takes it as it stands: a retry would stop the same way
    stamp = (failed / "summary.json").stat().st_mtime_ns
    assert main(argv) == 1
    again = pd.read_csv(out / "sweep.csv").set_index("control")
    assert again.loc["nrtraffic", "status"] == "gridlock" and again.loc["nrtraffic", "error"] == df.loc["nrtraffic", "error"]
    assert (failed / "summary.json").stat().st_mtime_ns == stamp
    said = capsys.readouterr()
    assert "runs to do" not in said.err  # (nothing was run)
    assert "1 of 2 runs failed: 1 stopped as gridlocks" in said.out
    # another configuration of the same run directory is run
    other = argv[:-4] + ["--set", "outputs.stall_s=40"] + argv[-2:] + ["--force"]
    assert main(other) == 1
    third = pd.read_csv(out / "sweep.csv").set_index("control")
    assert "no vehicle crossed for 40 s" in third.loc["nrtraffic", "error"]
    assert (failed / "summary.json").stat().st_mtime_ns != stamp


def test_a_job_that_stops_as_a_gridlock_returns_it_instead_of_raising(tmp_path):
    """Dask retries a job whose function raises; a gridlock is returned (the same run as the
    sweep above, in this process), so it is run once."""
    from conftest import SCENARIOS

    from runners.sweep import Job, run_job

    d = tmp_path / "runs" / "base" / "seed3" / "nrtraffic"
    job = Job(scenario=str(SCENARIOS / "cross4" / "scenario.toml"), point=(), seed=3, control="nrtraffic",
              overrides=("coordinator.min_merge_headway_s=200", "outputs.stall_s=30", "outputs.warmup_s=0"),
              duration_s=150.0, run_dir=str(d))
    got = run_job(job.spec())
    assert got["status"] == "gridlock" and "Gridlock: junction C" in got["error"]
    assert not d.exists() and json.loads((d.parent / "nrtraffic.failed" / "summary.json").read_text())["status"] \
        == "gridlock"


def test_only_a_gridlock_of_the_run_itself_makes_it_a_gridlock(tmp_path):
    """A run that fails before it writes anything is a failure (retried), even where an earlier
    attempt of the job had stopped as a gridlock and left its summary in ``.failed``."""
    from runners.sweep import Job, run_job

    d = tmp_path / "runs" / "base" / "seed1" / "nrtraffic"
    old = d.parent / "nrtraffic.failed"
    old.mkdir(parents=True)
    (old / "summary.json").write_text(json.dumps({"status": "gridlock", "error": "junction C: ..."}))
    job = Job(scenario=str(tmp_path / "no_such.toml"), overrides=(), point=(), seed=1, control="nrtraffic",
              duration_s=10.0, run_dir=str(d))
    with pytest.raises(Exception, match="no_such"):
        run_job(job.spec())


def test_a_sweep_into_a_file_says_how_far_it_is_and_the_first_run_says_it_compiles(tmp_path):
    """stderr not a terminal (captured): one line per finished run, counting up to the runs that
    sweep.csv then lists, each naming its run directory. With an empty kernel cache (its own
    NUMBA_CACHE_DIR) the sweep says once, before any run finished, that it compiles the kernels
    (the workers do not repeat it); a run after it, the cache filled, does not say it again."""
    import os
    import subprocess
    import sys

    from conftest import ROOT, SCENARIOS

    from nrtraffic._kernel_cache import NOTICE

    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "runners.cli", "sweep", str(SCENARIOS / "cross4"), "--seeds", "1:2",
                           "--workers", "1", "--out", str(out), *SHORT], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stderr.splitlines()
    assert lines.count(NOTICE) == 1
    done = [ln for ln in lines if re.match(r"sweep: \d+/\d+ runs done", ln)]
    assert lines.index(NOTICE) < lines.index(done[0])
    df = pd.read_csv(out / "sweep.csv")
    assert [re.match(r"sweep: (\d+)/(\d+)", ln).groups() for ln in done] == [
        (str(i), str(len(df))) for i in range(1, len(df) + 1)]
    named = {ln.rsplit("last: ", 1)[1].split()[0] for ln in done}
    assert named == {Path(d).relative_to(out / "runs").as_posix() for d in df["run_dir"]}
    assert all("(0 failed)" in ln for ln in done) and (df["status"] == "ok").all()

    again = subprocess.run([sys.executable, "-m", "runners.cli", "run", str(SCENARIOS / "cross4"), "--seed", "3",
                            "--out", str(tmp_path / "run"), *SHORT], capture_output=True, text=True, env=env,
                           cwd=ROOT, timeout=600)
    assert again.returncode == 0, again.stderr[-2000:]
    assert NOTICE not in again.stderr


def test_a_grid_of_two_keys_runs(tmp_path):
    """Two grid keys and a string value: every run directory's path is one SUMO can read (a grid
    point was named key=value,key=value, and SUMO read the comma in its route file's path as a list
    separator: every run of a two-key grid failed at SUMO's start), and the runs finish."""
    from runners.api import usable_path
    from runners.sweep import plan

    from conftest import SCENARIOS

    jobs = plan(SCENARIOS / "cross4", [1], [("demand.rate_veh_h", ["300", "400"]),
                                            ("coordinator.policy", ['"fifo"', '"batch"'])], ["nrtraffic"], tmp_path / "p")
    dirs = {j.run_dir for j in jobs}
    assert len(dirs) == 4
    for d in dirs:
        usable_path(d)  # (raises where SUMO would misread it)
    out = tmp_path / "out"
    code = main(["sweep", str(SCENARIOS / "cross4"), "--seeds", "1", "--grid", "demand.rate_veh_h=300,400",
                 "--grid", "demand.controlled_share=0.5,1", "--workers", "1", "--out", str(out), "--no-progress",
                 "--set", "scenario.duration_s=20", "--set", "outputs.warmup_s=0"])
    df = pd.read_csv(out / "sweep.csv")
    assert code == 0 and len(df) == 4 and (df["status"] == "ok").all()


def test_a_run_that_is_not_the_jobs_says_why(tmp_path):
    """A sweep's row of a run directory that does not hold its job's run names the reason (it had
    said "not run" of a run that had run, and ended before its duration)."""
    from runners.sweep import Job, finished, unfinished

    d = tmp_path / "run"
    job = Job(scenario="s", overrides=(), point=(), seed=3, control="nrtraffic", duration_s=600.0, run_dir=str(d))
    assert unfinished(job) == "not run"
    d.mkdir()
    for summary, why in (({"status": "failed", "error": "boom"}, "status 'failed': boom"),
                         ({"status": "ok", "seed": 4, "sim_time_s": 600.0}, "its run has seed 4, not 3"),
                         ({"status": "ok", "seed": 3, "sim_time_s": 580.1}, "its run simulated 580.1 s, not 600 s")):
        (d / "summary.json").write_text(json.dumps(summary))
        assert unfinished(job) == why and finished(job) is None
    (d / "summary.json").write_text("{")
    assert unfinished(job) == "its summary.json cannot be read"
    (d / "summary.json").write_text(json.dumps({"status": "ok", "seed": 3, "sim_time_s": 600.0}))
    assert unfinished(job) is None and finished(job)["seed"] == 3


def test_a_sweep_whose_runs_were_refused_for_their_scenario_does_not_say_retry():
    """Runs refused for their scenario once SUMO had read the network (NetworkError,
    ScenarioError) are not worth a retry, and the sweep's last line says so (it had said
    "re-run the same command to retry them" of every failure)."""
    from runners.sweep import failed_advice

    def table(errors):
        return pd.DataFrame({"status": ["ok"] + ["failed"] * len(errors), "error": [""] + errors})

    assert "a retry fails the same way" in failed_advice(table(["NetworkError: movement x: its path ..."]))
    assert failed_advice(table(["KilledWorker: ..."])) == "1 of 2 runs failed; re-run the same command to retry them"
    mixed = failed_advice(table(["KilledWorker: ...", "ScenarioError: ..."]))
    assert "retry them" in mixed and "1 were refused for their scenario" in mixed


def test_a_sweep_says_it_is_under_way_while_no_run_finishes():
    """Off a terminal a sweep prints a line per finished run; between them, while runs are under
    way, it says so after each quiet spell (``quiet_s``, 60 s by default), and nothing once closed."""
    import io
    import time

    from runners.sweep import Job, Progress

    out = io.StringIO()  # (not a terminal: lines)
    p = Progress(3, 0, stream=out, quiet_s=0.05)
    deadline = time.monotonic() + 30.0
    while "under way" not in out.getvalue() and time.monotonic() < deadline:
        time.sleep(0.05)
    job = Job("cross4", (), (), 1, "nrtraffic", None, "/x/runs/base/seed1/nrtraffic")
    p.done(job, failed=False)
    while out.getvalue().count("under way") < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    p.close()
    lines = out.getvalue().splitlines()
    assert lines[0] == "sweep: 3 runs to do"
    assert re.fullmatch(r"sweep: 0/3 runs done, \d+ s elapsed; runs under way", lines[1]), lines
    assert any(line.startswith("sweep: 1/3 runs done (0 failed)") for line in lines)
    assert re.fullmatch(r"sweep: 1/3 runs done, \d+ s elapsed; runs under way", lines[-1]), lines
    time.sleep(0.3)
    assert out.getvalue().splitlines() == lines  # (closed: silent)
