"""``nrtraffic sweep --cluster slurm|pbs``: the batch job flags, the job script, and a sweep on a real
Slurm cluster (this machine's, from tests/slurm/setup.sh) against the same sweep on local workers."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from runners.cli import main

ROOT = Path(__file__).resolve().parent.parent
CROSS4 = str(ROOT / "sumo_scenarios" / "cross4" / "scenario.toml")
SETUP = "tests/slurm/setup.sh"


# ------------------------------------------------------------------ flags, no scheduler needed
def test_walltime_forms():
    from runners.clusters import BatchSpec, parse_walltime
    from runners.sweep import SweepError

    assert parse_walltime("02:00:00") == 7200
    assert parse_walltime("1-02:03:04") == 86400 + 2 * 3600 + 3 * 60 + 4
    spec = BatchSpec("slurm", 1, 1, 2**30, parse_walltime("1-02:03:04"))
    assert spec.walltime == "26:03:04"  # what both sbatch -t and PBS's walltime read
    for bad in ("1:00", "90", "2h", "01:60:00", "01:00:60", "00:00:00", ""):
        with pytest.raises(SweepError, match="--job-walltime"):
            parse_walltime(bad)


@pytest.mark.parametrize("flags, flag, fix", [
    (["--cluster", "slurm", "--job-walltime", "1:30"], "--job-walltime", "HH:MM:SS"),
    (["--cluster", "slurm", "--job-memory", "4"], "--job-memory", "8GB"),
    (["--cluster", "slurm", "--job-memory", "lots"], "--job-memory", "8GB"),
    (["--cluster", "slurm", "--job-cores", "4", "--job-memory", "512MiB"], "--job-memory", "1024 MiB"),
    (["--cluster", "slurm", "--jobs", "0"], "--jobs", "at least one"),
    (["--cluster", "slurm", "--job-cores", "0"], "--job-cores", "at least one"),
    (["--job-walltime", "02:00:00"], "--job-walltime", "--cluster slurm"),
    (["--queue", "short"], "--queue", "--cluster slurm"),
    # a line break would end the #SBATCH line and run the rest as a command of the job
    (["--cluster", "slurm", "--job-directive", "--comment=x\necho injected"], "--job-directive", "line break"),
])
def test_bad_job_flags_exit_2_before_anything_is_submitted(tmp_path, capsys, flags, flag, fix):
    out = tmp_path / "out"
    code = main(["sweep", CROSS4, "--seeds", "1:2", "--out", str(out), "--no-progress", *flags])
    err = capsys.readouterr().err
    assert code == 2
    assert flag in err and fix in err, err
    assert not out.exists()


def test_slurm_without_sbatch_names_the_fix(tmp_path, capsys, monkeypatch):
    # PATH with SUMO and Python (the virtual environment's bin) but no Slurm
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent))
    assert shutil.which("sbatch") is None
    out = tmp_path / "out"
    code = main(["sweep", CROSS4, "--seeds", "1:2", "--out", str(out), "--no-progress", "--cluster", "slurm"])
    err = capsys.readouterr().err
    assert code == 2
    assert "--cluster slurm: sbatch is not on PATH" in err and "slurm-wlm" in err, err
    assert not out.exists()


def test_the_job_script_asks_for_the_flags_and_runs_this_python(tmp_path):
    """What a job asks of Slurm and PBS and what it runs (no job is submitted)."""
    from runners.clusters import BatchSpec, job_cluster, parse_memory, parse_walltime

    walltime = parse_walltime("1-02:03:04")  # 93784 s
    spec = BatchSpec("slurm", 3, 4, parse_memory("16GiB", 4), walltime, "short", "proj42", ("--qos=low",))
    with job_cluster(spec, tmp_path / "jobs") as cluster:
        script = cluster.job_script()
    header = [line for line in script.splitlines() if line.startswith("#SBATCH")]
    for line in ("#SBATCH --cpus-per-task=4", "#SBATCH --mem=16G", "#SBATCH -t 26:03:04", "#SBATCH -p short",
                 "#SBATCH -A proj42", "#SBATCH --qos=low"):
        assert line in header, script
    assert f"cd {os.getcwd()}" in script
    worker = script.splitlines()[-1]
    assert worker.startswith(f"{sys.executable} -m distributed.cli.dask_worker "), worker
    # one thread per worker process, one process per core, 16 GiB / 4 = 4 GiB each, leaving 300 s early
    assert "--nthreads 1" in worker and "--nworkers 4" in worker and "--memory-limit 4.00GiB" in worker, worker
    assert f"--lifetime {93784 - 300}s" in worker, worker

    pbs = BatchSpec("pbs", 1, 2, parse_memory("8GiB", 2), parse_walltime("00:15:00"), "workq")
    with job_cluster(pbs, tmp_path / "pbs") as cluster:
        script = cluster.job_script()
    assert "#PBS -q workq" in script and "#PBS -l walltime=00:15:00" in script, script
    assert "#PBS -l select=1:ncpus=2:mem=" in script, script
    assert "--lifetime" not in script  # a short walltime: the workers stay to its end


# ------------------------------------------------------------------ a real Slurm cluster
def _slurm_answers() -> str | None:
    """Why a Slurm sweep cannot run here (None: it can)."""
    if not (shutil.which("sbatch") and shutil.which("sinfo")):
        return f"Slurm is not installed here (no sbatch/sinfo): sudo {SETUP} installs and starts a one-node cluster"
    try:
        states = subprocess.run(["sinfo", "-h", "-o", "%t"], capture_output=True, text=True, timeout=10)
    except subprocess.TimeoutExpired:
        return f"sinfo did not answer in 10 s: start Slurm (sudo {SETUP} start)"
    if states.returncode != 0:
        return f"no Slurm controller answers ({states.stderr.strip()}): sudo {SETUP} start"
    if not any(s.strip().rstrip("*~#") in ("idle", "mix", "alloc") for s in states.stdout.split()):
        return f"no Slurm node is up (sinfo: {states.stdout.split()}): sudo {SETUP} start"
    return None


def test_a_sweep_on_slurm_equals_the_same_sweep_on_local_workers(tmp_path, capsys):
    reason = _slurm_answers()
    if reason:
        pytest.skip(reason)
    study = ["--seeds", "1:2", "--duration", "90", "--set", "outputs.warmup_s=0", "--no-progress"]
    local, slurm = tmp_path / "local", tmp_path / "slurm"
    assert main(["sweep", CROSS4, *study, "--workers", "1", "--out", str(local)]) == 0
    capsys.readouterr()
    on_slurm = ["sweep", CROSS4, *study, "--cluster", "slurm", "--jobs", "2", "--job-cores", "1",
                "--job-memory", "1GiB", "--job-walltime", "00:10:00", "--out", str(slurm)]
    assert main(on_slurm) == 0
    assert "submitted 2 slurm job(s)" in capsys.readouterr().err

    # the runs ran in two Slurm jobs, each a Dask worker started by the sweep's own Python
    script = (slurm / "jobs" / "job.sh").read_text()
    assert "#SBATCH --mem=1G" in script and "#SBATCH -t 00:10:00" in script
    assert f"{sys.executable} -m distributed.cli.dask_worker" in script
    logs = sorted((slurm / "jobs").glob("nrtraffic-sweep-*.err"))
    assert len(logs) == 2, logs
    for log in logs:
        assert "Start worker" in log.read_text()

    a, b = pd.read_csv(local / "sweep.csv"), pd.read_csv(slurm / "sweep.csv")
    assert (a["status"] == "ok").all() and (b["status"] == "ok").all()
    assert (a["vehicles_completed"] > 0).all()  # figures to compare, not empty runs
    timing = ["wall_time_s", "real_time_factor", "run_dir"]
    pd.testing.assert_frame_equal(a.drop(columns=timing), b.drop(columns=timing))
    assert (local / "sweep.md").read_text() == (slurm / "sweep.md").read_text()

    # resuming: every run is finished, so no job is submitted
    assert main(on_slurm) == 0
    assert "submitted" not in capsys.readouterr().err
    assert len(list((slurm / "jobs").glob("nrtraffic-sweep-*.err"))) == 2


def test_ctrl_c_keeps_the_commands_own_handling():
    """Importing dask_jobqueue replaces the SIGINT handler with one that exits with status 0; the
    sweep imports it so that its own handler (a message, exit status 1, the jobs cancelled) stays."""
    code = ("import signal, sys\n"
            "def mine(*_): pass\n"
            "signal.signal(signal.SIGINT, mine)\n"
            "if sys.argv[1] == 'plain':\n"
            "    import dask_jobqueue\n"
            "else:\n"
            "    from runners.clusters import _jobqueue\n"
            "    _jobqueue()\n"
            "print(signal.getsignal(signal.SIGINT) is mine)\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    got = {how: subprocess.run([sys.executable, "-c", code, how], capture_output=True, text=True, env=env,
                               check=True).stdout.strip() for how in ("plain", "sweep")}
    assert got == {"plain": "False", "sweep": "True"}


def test_the_sites_job_script_prologue_comes_first(tmp_path):
    """Lines from the site's dask-jobqueue configuration (module loads) stay in the job script,
    before the sweep's own."""
    import dask

    from runners.clusters import BatchSpec, job_cluster

    spec = BatchSpec("slurm", 1, 1, 2**30, 600)
    with dask.config.set({"jobqueue.slurm.job-script-prologue": ["module load sumo/1.28"],
                          "jobqueue.slurm.worker-extra-args": ["--no-dashboard"]}):
        with job_cluster(spec, tmp_path) as cluster:
            lines = cluster.job_script().splitlines()
    assert lines.index("module load sumo/1.28") < lines.index(f"cd {os.getcwd()}")
    assert "--no-dashboard" in lines[-1]


def test_a_job_script_slurm_refuses_is_exit_2_before_any_job_is_submitted(tmp_path, capsys):
    """An unknown partition: Slurm's own check of the script (sbatch --test-only) refuses it, the
    sweep exits 2 naming Slurm's words and the flags (it hung, with a traceback)."""
    reason = _slurm_answers()
    if reason:
        pytest.skip(reason)
    out = tmp_path / "out"
    code = main(["sweep", CROSS4, "--seeds", "1", "--duration", "30", "--set", "outputs.warmup_s=0", "--out", str(out),
                 "--no-progress", "--cluster", "slurm", "--queue", "nosuchpartition"])
    err = capsys.readouterr().err
    assert code == 2 and "invalid partition" in err and "--partition" in err, err
    assert not (out / "runs").exists()
