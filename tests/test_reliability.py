"""Faults and bad input: a run killed by SIGTERM or SIGKILL keeps what it finished, a full disk is a
clear failure, and every bad flag or file is refused with exit 2 and a message naming it."""

import json
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import pandas as pd
import pyarrow.parquet as pq
import pytest

from conftest import ROOT, SCENARIOS, copy_scenario
from nrtraffic.results import PARTIAL_TRAJECTORIES, read_trajectories
from runners.cli import main

CROSS4 = SCENARIOS / "cross4" / "scenario.toml"


def _start_long_run(out):
    """cross4 for an hour with trajectories every 0.1 s, in a process of its own (same CPU target);
    the tests stop it at its first checkpoint."""
    cmd = [sys.executable, "-m", "runners.cli", "run", str(CROSS4), "--duration", "3600", "--set",
           "outputs.trajectory_interval_s=0.1", "--out", str(out), "--no-progress"]
    return subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_checkpoint(proc, out, timeout=240.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if proc.poll() is not None:
            pytest.fail(f"the run ended early: {proc.communicate()}")
        if (out / "summary.json").is_file() and (out / PARTIAL_TRAJECTORIES).is_file():
            try:
                s = json.loads((out / "summary.json").read_text())
            except ValueError:  # (never half-written: renamed whole, or overwritten in place)
                pytest.fail("summary.json could not be read")
            if s.get("sim_time_s", 0) > 0:  # a checkpoint, not the summary written at the start
                return s
        time.sleep(0.2)
    proc.kill()
    pytest.fail("no checkpoint within the time limit")


def test_sigterm_stops_a_run_and_keeps_every_output_readable(tmp_path):
    out = tmp_path / "run"
    proc = _start_long_run(out)
    _wait_for_checkpoint(proc, out)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    assert "SIGTERM" in err and str(out) in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and "SIGTERM" in s["error"]
    assert 0 < s["sim_time_s"] < 3600
    v = pd.read_csv(out / "vehicles.csv")
    assert len(v) == s["vehicles_spawned"] > 0
    t = pq.read_table(out / "trajectories.parquet").to_pandas()  # a whole Parquet file, with its footer
    assert len(t) > 0 and t["t"].max() <= s["sim_time_s"] + 1e-9
    assert not (out / PARTIAL_TRAJECTORIES).exists()
    for f in ("tripinfo.xml", "collisions.xml"):  # SUMO closed its outputs
        ET.parse(out / f)


def test_sigterm_or_ctrl_c_at_any_moment_leaves_a_readable_summary(tmp_path):
    """30 moments from 0.1 s to 20 s after the command starts (interpreter start, imports, the
    checks before SUMO, set-up, the run), SIGTERM and SIGINT in turn: every run ends with exit 1
    and a summary.json that says it failed and names the signal. Five at a time, so that more of
    them land in the slower start."""
    import random

    rng = random.Random(20261202)
    moments = sorted(rng.uniform(0.1, 20.0) for _ in range(30))
    cases = [(t, signal.SIGTERM if i % 2 else signal.SIGINT, tmp_path / f"run{i:02d}") for i, t in enumerate(moments)]
    for k in range(0, len(cases), 5):
        batch = []
        t0 = time.monotonic()
        for t, sig, out in cases[k:k + 5]:
            batch.append((t0 + t, sig, out, _start_long_run(out)))
        for when, sig, out, proc in batch:
            time.sleep(max(0.0, when - time.monotonic()))
            assert proc.poll() is None, proc.communicate()
            proc.send_signal(sig)
        for when, sig, out, proc in batch:
            _, err = proc.communicate(timeout=180)
            assert proc.returncode == 1, (when - t0, sig, err)
            s = json.loads((out / "summary.json").read_text())
            name = "SIGTERM" if sig == signal.SIGTERM else "SIGINT"
            assert s["status"] == "failed" and name in s["error"], (when - t0, s, err[-2000:])
            assert 0 <= s["sim_time_s"] < 3600


# the command as a process, with a signal sent to it at a chosen moment: when a module is first
# imported (before any code of it runs), when the interpreter exits after the command returned, or
# late in its shut-down (an object of the script freed with the modules' globals)
_SIGNAL_AT = """
import atexit, importlib.abc, os, runpy, signal, sys, time
sig, at = signal.Signals[sys.argv.pop(1)], sys.argv.pop(1)
class At(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name == at:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), sig)
class Late:
    def __del__(self):
        os.kill(os.getpid(), sig)
        time.sleep(0.3)
if at == "exit":
    atexit.register(os.kill, os.getpid(), sig)
elif at == "teardown":
    late = Late()
elif at == "compiler":  # inside llvmlite's ctypes callback that asks numba for a kernel's object code
    import numba.core.codegen as cg
    from runners import interrupts
    getbuffer, sent = cg.JITCodeLibrary._object_getbuffer_hook, []
    def in_callback(cls, ll_module):
        if interrupts._armed and not sent:  # the first kernel the run compiles or loads
            sent.append(os.kill(os.getpid(), sig))
        return getbuffer(ll_module)
    cg.JITCodeLibrary._object_getbuffer_hook = classmethod(in_callback)
else:
    sys.meta_path.insert(0, At())
runpy.run_module("runners.cli", run_name="__main__", alter_sys=True)
"""


@pytest.mark.parametrize("at", ["nrtraffic", "runners.api", "compiler", "exit", "teardown"])
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_while_the_command_starts_or_exits_is_handled(at, sig, tmp_path):
    """The command's handlers were installed only after it had imported nrtraffic and the API's
    helpers, and taken off before the interpreter exited: a signal then was a KeyboardInterrupt
    traceback (SIGINT) or a kill (SIGTERM, status -15) that left no summary. Now one while nrtraffic
    is imported waits for the run directory and stops the run there (exit 1, "failed" naming the
    signal); one after the command has returned its status, while the process exits, is noted and
    changes nothing: the run is complete. Late in the shut-down, the interpreter had put back the
    default action (status 143 or 130 after an "ok" run): now the signal is ignored there. One while
    numba loaded the run's first kernel, inside llvmlite's callback, was raised there: ctypes
    ignored the interrupt, LLVM got no object code and the process died of a segmentation fault
    (status -11, its summary still "running"); now it is sent again until it lands outside, and
    stops the run as any other."""
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", _SIGNAL_AT, sig, at, "run", str(CROSS4), "--duration", "10",
                           "--set", "outputs.warmup_s=0", "--out", str(out), "--no-progress"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert "Traceback" not in proc.stderr, proc.stderr
    s = json.loads((out / "summary.json").read_text())
    if at in ("exit", "teardown"):
        assert proc.returncode == 0 and s["status"] == "ok" and (out / "report.html").is_file(), proc.stderr
    else:
        assert proc.returncode == 1, proc.stderr
        assert s["status"] == "failed" and sig in s["error"] and sig in proc.stderr


def test_sigkill_leaves_the_last_checkpoint_and_the_trajectories_up_to_it(tmp_path):
    out = tmp_path / "run"
    proc = _start_long_run(out)
    first = _wait_for_checkpoint(proc, out)
    assert first["status"] == "running"
    proc.kill()
    proc.communicate(timeout=60)
    s = json.loads((out / "summary.json").read_text())  # whole: written under a temporary name
    assert s["status"] == "running" and s["sim_time_s"] > 0
    v = pd.read_csv(out / "vehicles.csv")
    assert len(v) > 0
    t = read_trajectories(out)  # the stream, up to its last whole batch
    assert len(t) > 0 and t["t"].max() > 0
    assert not (out / "trajectories.parquet").exists()


def test_a_full_disk_is_a_clear_failure_and_the_figures_are_kept(tmp_path, monkeypatch, capsys):
    from nrtraffic import results

    def full(self):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(results.TrajectoryWriter, "flush", full)
    out = tmp_path / "run"
    code = main(["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out", str(out), "--no-progress"])
    assert code == 1
    assert "No space left on device" in capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and "No space left" in s["error"]
    assert (out / "vehicles.csv").is_file()


@pytest.mark.parametrize("flags, named", [
    (["--duration", "-5"], "--duration"), (["--duration", "nan"], "--duration"), (["--duration", "inf"], "--duration"),
    (["--duration", "1e12"], "--duration"), (["--seed", "-1"], "--seed"), (["--seed", "2.5"], "--seed"),
    (["--seed", str(2**31)], "--seed"),
])
def test_bad_run_flags_exit_2_naming_the_flag(flags, named, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", str(CROSS4), "--out", str(tmp_path / "o"), *flags])
    assert exc.value.code == 2
    assert f"argument {named}" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_schema_write_to_a_folder_or_nowhere_exits_2(tmp_path, capsys):
    """``schema --write`` names a file: a folder, or a file in a folder that does not exist, exits 2
    naming the flag (a Python error had exited 1)."""
    for where in (tmp_path, tmp_path / "no" / "s.json"):
        assert main(["schema", "--write", str(where)]) == 2
        assert f"--write {where}" in capsys.readouterr().err
    assert main(["schema", "--write", str(tmp_path / "s.json")]) == 0
    assert json.loads((tmp_path / "s.json").read_text())["type"] == "object"


@pytest.mark.parametrize("flags", [["--rtol", "-1"], ["--atol", "nan"], ["--atol", "inf"]])
def test_bad_replay_tolerances_exit_2(flags, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(ROOT / "tests" / "golden" / "cross4"), *flags])
    assert exc.value.code == 2
    assert flags[0] in capsys.readouterr().err


@pytest.mark.parametrize("what", ["summary.json", "trajectories.parquet"])
def test_replay_of_a_truncated_file_exits_2_naming_it(what, tmp_path, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(ROOT / "tests" / "golden" / "cross4", run)
    data = (run / what).read_bytes().rstrip()  # (summary.json is padded with blanks: cut into its text)
    (run / what).write_bytes(data[: len(data) // 2])
    assert main(["replay", str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert what in err and "cannot be read" in err


def test_out_that_is_a_file_or_unwritable_exits_2(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    for out in (f, f / "below"):
        assert main(["run", str(CROSS4), "--out", str(out), "--no-progress"]) == 2
        assert "--out" in capsys.readouterr().err


def test_binary_scenario_file_exits_2(tmp_path, capsys):
    bad = tmp_path / "scenario.toml"
    bad.write_bytes(bytes(range(256)))
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "not a UTF-8 text file" in capsys.readouterr().err


def test_scenario_files_cannot_reach_outside_their_folder(tmp_path, capsys):
    d = tmp_path / "scen"
    d.mkdir()
    text = CROSS4.read_text().replace('network = "net.net.xml"', f'network = "../{"../" * 12}etc/hostname"')
    (d / "scenario.toml").write_text(text)
    assert main(["run", str(d), "--out", str(tmp_path / "o")]) == 2
    assert "outside the scenario's folder" in capsys.readouterr().err
    assert not (tmp_path / "o" / "sumo").exists()
    # with --allow-outside a network elsewhere is used
    (d / "scenario.toml").write_text(CROSS4.read_text().replace(
        'network = "net.net.xml"', f'network = "{SCENARIOS / "cross4" / "net.net.xml"}"'))
    assert main(["run", str(d), "--out", str(tmp_path / "o2"), "--duration", "5", "--set", "outputs.warmup_s=0", "--allow-outside",
                 "--no-progress"]) == 0


def _scenario_copy(tmp_path, old=None, new=None, extra=""):
    return copy_scenario("cross4", tmp_path / "scen", old, new or "", extra)


@pytest.mark.parametrize("old, new, extra, message", [
    ('id = "C"', 'id = "Q"', "", "junction 'Q' is not in it"),
    ('id = "C"', 'id = "N"', "", "junction 'N' (dead_end) has no movements"),
    ('network = "net.net.xml"', 'network = "net.nod.xml"', "", "not a SUMO network"),
    ("", "", '\n[[approaches]]\nname = "x"\nroute = ["N_in", "nowhere"]\nmerge_entry_edge = "N_in"\n',
     "'nowhere' is not in it"),
    ('preset = "paper"', 'preset = "paper"\nlength = 1e6', "", "beyond a road vehicle"),
    ('preset = "paper"', 'preset = "paper"\nm = 1e300', "", "vehicle parameter m = 1e+300 is outside its physical range"),
    ("", "", '\n[[vehicles]]\nid = "far"\napproach = "N_in.straight"\ndepart_s = 1.0\ndepart_pos_m = 99999.0\n',
     "vehicles.far.depart_pos_m = 99999 m lies beyond its first edge N_in"),
    ('preset = "paper"', 'preset = "paper"\nCaf = 1.0', "", "vehicle parameter Caf = 1 is outside its physical range"),
    # a watchdog shorter than a crossing: ordinary waiting stopped the run as a gridlock
    ("trajectory_interval_s = 0.5", "trajectory_interval_s = 0.5\nstall_s = 0.1", "",
     "outputs.stall_s = 0.1 s would take ordinary traffic for a gridlock"),
    # vehicle ids SUMO refuses once started (one was written unescaped into the route file), and
    # speed profiles out of range or on a vehicle that never follows one
    ("", "", '\n[[vehicles]]\nid = "a&b"\napproach = "N_in.straight"\ndepart_s = 1.0\n',
     "id 'a&b': SUMO takes no '&' in a vehicle id"),
    ("", "", '\n[[vehicles]]\nid = "a b"\napproach = "N_in.straight"\ndepart_s = 1.0\n',
     "id 'a b': SUMO takes no ' ' in a vehicle id"),
    ("", "", '\n[[vehicles]]\nid = "h\\u0001"\napproach = "N_in.straight"\ndepart_s = 1.0\n',
     "SUMO takes no '\\x01' in a vehicle id"),
    ("", "", '\n[[vehicles]]\nid = "s"\napproach = "N_in.straight"\ncontrolled = false\n'
     'speed_profile = [[0.0, 5.0], [1.0, -3.0]]\n', "vehicles.s.speed_profile: [1, -3] is outside"),
    ("", "", '\n[[vehicles]]\nid = "s"\napproach = "N_in.straight"\nspeed_profile = [[0.0, 5.0]]\n',
     "vehicles.s.speed_profile drives only a vehicle SUMO drives"),
    ('network = "net.net.xml"', 'network = "."', "", "is a folder, not a network file"),
    ("trajectory_interval_s = 0.5", "trajectory_interval_s = 0.25", "", "whole multiple of sumo.step_length_s"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--no-such-option", "1"]', "",
     "no option --no-such-option"),
    # SUMO options that write files (they landed outside --out, relative to the working folder)
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--output-prefix", "../../"]', "",
     "--output-prefix would write files outside the run folder"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--summary-output", "s.xml"]', "",
     "--summary-output would write files outside the run folder"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--error-log", "e.txt"]', "",
     "--error-log would write files outside the run folder"),
    # SUMO's one-letter options and the = form (-l wrote the log anywhere)
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["-l", "x.log"]', "",
     "-l (--log) would write files outside the run folder"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["-C", "x.sumocfg"]', "",
     "-C (--save-configuration) would write files outside the run folder"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--netstate-dump=n.xml"]', "",
     "--netstate-dump=n.xml would write files outside the run folder"),
    # SUMO's other long names of an option (it wrote the file; it was refused as unknown)
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--ndump", "n.xml"]', "",
     "--ndump (--netstate-dump) would write files outside the run folder"),
    # a suffix on SUMO's output names (it wrote outside the run with "_d/../../x"), outputs the run
    # cannot read, and an option given twice (SUMO refused each once started)
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--output-suffix", "_d/../../x"]', "",
     "--output-suffix would write files outside the run folder"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--output.format", "csv"]', "",
     "--output.format: the run reads SUMO's outputs as XML"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--human-readable-time"]', "",
     "--human-readable-time: the run reads SUMO's times as seconds"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--max-depart-delay", "3", "--max-depart-delay", "2"]',
     "", "--max-depart-delay is given twice"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["-q"]', "", "no option -q"),
    # device and state options that write files of their own into the working folder
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--device.ssm.probability", "1"]', "",
     "--device.ssm.probability would write files outside the run folder"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--device.rerouting.output", "rr.xml"]', "",
     "--device.rerouting.output would write files outside the run folder"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--save-state.times", "5"]', "",
     "--save-state.times would write files outside the run folder"),
    # options that read a file the run neither checks nor keeps (SUMO read one from anywhere, or
    # stopped once started with only "Process Error")
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--weight-files", "/etc/hostname"]', "",
     "--weight-files would have SUMO read a file that the run does not check"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--load-state=state.xml"]', "",
     "--load-state=state.xml would have SUMO read a file"),
    # options that stood in for demand keys (a run of a tenth of its cars, "ok"), that SUMO refused
    # once started, or that set up an output the run does not write
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--scale", "10"]', "",
     "--scale: the run sets it itself (demand.scale)"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--max-num-vehicles", "0"]', "",
     "--max-num-vehicles: the run sets it itself"),
    # collisions no longer checked, and a signalised baseline whose signals are off, both "ok"
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--ignore-accidents"]', "",
     "--ignore-accidents: the run sets it itself (collisions are recorded)"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--tls.all-off"]', "",
     "--tls.all-off: the run sets it itself (a signalised control keeps its signals on"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--threads", "0"]', "",
     "SUMO needs at least one thread"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--vehroute-output.exit-times"]', "",
     "sets up a SUMO output that the run does not write"),
    # a setting of an output the run does write (it had been called one the run does not write)
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--tripinfo-output.write-unfinished"]', "",
     "sets up SUMO's tripinfo-output, which the run writes itself with its own settings"),
    # an option the run sets itself (SUMO refused it once started), and one that makes SUMO wait for ever
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--time-to-teleport", "-1"]', "",
     "--time-to-teleport: the run sets it itself"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--seed", "5"]', "", "--seed: the run sets it itself"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--random"]', "", "--random: the run sets it itself"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--remote-port", "9999"]', "",
     "SUMO would wait for a TraCI client of its own"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--device.toc.probability", "1"]', "",
     "SUMO's take-over device needs parameters of the vehicle type"),
    # SUMO started and failed on these, or (the mesoscopic model) ran with no car controlled and said "ok"
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--mesosim"]', "",
     "--mesosim: SUMO's mesoscopic model has no lanes"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--version"]', "", "--version: it prints SUMO's"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--no-internal-links"]', "",
     "--no-internal-links: the controlled vehicles are driven along the junction's internal lanes"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = [""]', "", "sumo.extra_args: an empty item"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["foo.sumocfg"]', "",
     "'foo.sumocfg' is not an option"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--max-depart-delay"]', "",
     "--max-depart-delay needs a value (time)"),
    ("step_length_s = 0.1", 'step_length_s = 0.1\nextra_args = ["--max-depart-delay", "abc"]', "",
     "--max-depart-delay needs a number (time), not 'abc'"),
    # named as the keys that set the arrivals (the message had been about mean_headway_s, which the
    # file does not set and the run does not use)
    ("min_headway_s = 1.5", "min_headway_s = 20.0", "",
     "demand.rate_veh_h = 400 veh/h needs a mean headway above demand.min_headway_s = 20.0 s"),
])
def test_scenarios_that_would_run_wrong_exit_2_naming_the_problem(old, new, extra, message, tmp_path, capsys):
    d = _scenario_copy(tmp_path, old or None, new or None, extra)
    assert main(["run", str(d), "--out", str(tmp_path / "o"), "--duration", "5", "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o" / "summary.json").exists()


@pytest.mark.parametrize("flag", [["--xml-validation", "always"], ["-X", "always"]])
def test_sumo_schema_validation_always_accepts_the_files_the_run_writes(flag, tmp_path, capsys):
    """With SUMO's --xml-validation always, every input must declare its schema: the queue
    detectors the run writes declared none (and their ids held '|'), so SUMO stopped at its start
    (exit 1). Now the run finishes and measures its queues; a recorded run's queues.xml, of
    detectors named the earlier way, still reads."""
    from nrtraffic.results import parse_queues

    out = tmp_path / "o"
    args = ", ".join(f'"{a}"' for a in flag)
    assert main(["run", str(CROSS4), "--out", str(out), "--duration", "30", "--set", "outputs.warmup_s=0",
                 "--set", f"sumo.extra_args=[{args}]", "--no-progress"]) == 0, capsys.readouterr().err
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    assert sorted(pd.read_csv(out / "approaches.csv")["approach"]) == ["E_in", "N_in", "S_in", "W_in"]
    assert sorted(parse_queues(out / "queues.xml")["approach"].unique()) == ["E_in", "N_in", "S_in", "W_in"]
    earlier = parse_queues(ROOT / "tests" / "golden" / "cross4" / "queues.xml")
    assert sorted(earlier["approach"].unique()) == ["E_in", "N_in", "S_in", "W_in"]


def test_out_holding_another_run_is_refused_unless_forced(tmp_path, capsys):
    out = tmp_path / "o"
    base = ["run", str(CROSS4), "--out", str(out), "--no-progress", "--set", "outputs.warmup_s=0"]
    assert main(base + ["--duration", "4"]) == 0
    assert main(base + ["--duration", "4"]) == 0  # a finished run of the same configuration: run again
    assert main(base + ["--duration", "5"]) == 2
    assert "not a finished run of this configuration" in capsys.readouterr().err
    created = set(json.loads((out / "manifest.json").read_text())["created"])
    assert {"summary.json", "vehicles.csv", "report.html", "sumo", "sumo/routes.rou.xml"} <= created
    (out / "sumo" / "extra.rou.xml").write_text("<routes/>")  # not the run's: kept, and so is its folder
    (out / "notes.txt").write_text("mine")
    assert main(base + ["--duration", "5", "--force"]) == 0
    assert (out / "notes.txt").read_text() == "mine" and (out / "sumo" / "extra.rou.xml").is_file()
    assert json.loads((out / "summary.json").read_text())["sim_time_s"] == pytest.approx(5.0)
    other = tmp_path / "other"
    other.mkdir()
    (other / "x").write_text("")
    assert main(["baseline", str(CROSS4), "--junction", "priority", "--out", str(other), "--duration", "4", "--set", "outputs.warmup_s=0"]) == 2


def test_force_never_removes_or_overwrites_the_users_own_files(tmp_path, capsys):
    """A folder of the user's own files (their network in ``sumo/``), where no run has been, has no
    manifest: ``--force`` refuses it with exit 2 and touches nothing. A run into a folder that holds
    nothing but a finished run's files and the user's own keeps theirs through every forced run
    after it, a baseline's too."""
    mine = tmp_path / "mine"
    (mine / "sumo").mkdir(parents=True)
    (mine / "sumo" / "my_network.net.xml").write_text("<net/>")
    (mine / "notes.txt").write_text("mine")
    base = ["run", str(CROSS4), "--out", str(mine), "--set", "outputs.warmup_s=0", "--no-progress", "--force"]
    assert main(base + ["--duration", "4"]) == 2
    assert "manifest.json" in capsys.readouterr().err
    assert sorted(p.relative_to(mine).as_posix() for p in mine.rglob("*")) == ["notes.txt", "sumo",
                                                                             "sumo/my_network.net.xml"]
    (mine / "notes.txt").unlink()  # an empty folder but for the user's network: the run may go in
    (mine / "sumo" / "my_network.net.xml").rename(tmp_path / "n.xml")
    (mine / "sumo").rmdir()
    assert main(base + ["--duration", "4"]) == 0
    (tmp_path / "n.xml").rename(mine / "sumo" / "my_network.net.xml")
    (mine / "notes.txt").write_text("mine")
    assert main(base + ["--duration", "5"]) == 0  # replaces the run's files, and only those
    assert (mine / "sumo" / "my_network.net.xml").read_text() == "<net/>"
    assert (mine / "notes.txt").read_text() == "mine"
    assert json.loads((mine / "summary.json").read_text())["sim_time_s"] == pytest.approx(5.0)
    assert main(["baseline", str(CROSS4), "--junction", "priority", "--out", str(mine), "--duration", "4", "--set", "outputs.warmup_s=0",
                 "--force"]) == 0
    assert (mine / "sumo" / "my_network.net.xml").read_text() == "<net/>"
    capsys.readouterr()
    assert main(base[:-1] + ["--duration", "6"]) == 2  # without --force, as before
    assert "not a finished run of this configuration" in capsys.readouterr().err


def test_paper_and_robustness_refuse_an_out_they_would_write_the_users_files_in(tmp_path, capsys):
    """``nrtraffic paper`` and ``nrtraffic robustness`` keep to a run's rules for ``--out``: a
    folder of the user's files (one named as a file the study writes, or any other), a path SUMO
    misreads or a file exit 2 before anything runs, and nothing of the user's is touched. So does
    a file of the user's in a run folder of an earlier reproduction."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "paper_table.md").write_text("mine")
    (tmp_path / "afile").write_text("mine")
    for study in (["paper", "curved"], ["paper", "all"], ["robustness"]):
        for out, named in ((mine, "paper_table.md"), (tmp_path / "a,b", "','"), (tmp_path / "afile", "not a folder")):
            assert main([*study, "--out", str(out), "--no-progress"]) == 2
            assert named in capsys.readouterr().err
    assert [p.name for p in mine.iterdir()] == ["paper_table.md"] and (mine / "paper_table.md").read_text() == "mine"
    assert (tmp_path / "afile").read_text() == "mine" and not (tmp_path / "a,b").exists()
    # an earlier reproduction's folder (its manifest lists what it wrote) with a file of the user's
    # in one of its runs
    earlier = tmp_path / "earlier"
    (earlier / "straight").mkdir(parents=True)
    (earlier / "manifest.json").write_text(json.dumps({"sweep": 1, "preexisting": [], "created": ["straight"]}))
    (earlier / "straight" / "notes.txt").write_text("mine")
    assert main(["paper", "curved", "--out", str(earlier), "--no-progress"]) == 2
    assert "notes.txt, which its run did not write" in capsys.readouterr().err
    assert (earlier / "straight" / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("edit, message", [
    # netconvert's default corner (4 m) and junction-lane detail (5 points): a 126-degree turn too
    # tight for the car
    ("default_corner", "movement MillLn_EB.right: its path turns on a radius of"),
    # a merging zone smaller than the junction
    ("small_zone", "internal lanes reach 21.3 m from its centre, beyond the merging zone"),
])
def test_a_junction_the_car_cannot_drive_exits_2_naming_the_movement(edit, message, tmp_path, capsys):
    from nrtraffic.sumo.netbuild import build_network

    if edit == "default_corner":
        d = copy_scenario("station_mill", tmp_path / "scen")
        nod = d / "station_mill.nod.xml"
        nod.write_text(nod.read_text().replace(' radius="15"', ""))
        build_network(nod, d / "station_mill.edg.xml", d / "station_mill.net.xml")
    else:
        d = copy_scenario("station_mill", tmp_path / "scen", "merging_zone_m = 46.0", "merging_zone_m = 30.0")
    out = tmp_path / "o"
    assert main(["run", str(d), "--out", str(out), "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())  # nothing was simulated, nothing is left


def test_an_interrupt_inside_compiled_code_is_reported_as_the_interrupt():
    """A SIGTERM that arrives while a numba function runs surfaces as that function's SystemError
    ("returned a result with an exception set"), with the interrupt as its context: the run reports
    the interrupt, not the SystemError."""
    from nrtraffic.engine import _interrupt_in

    class Terminated(KeyboardInterrupt):
        pass

    try:
        try:
            raise Terminated("terminated by SIGTERM")
        except Terminated:
            raise SystemError("CPUDispatcher(<function touching_pairs>) returned a result with an exception set")
    except SystemError as exc:
        got = _interrupt_in(exc)
    assert isinstance(got, Terminated) and "SIGTERM" in str(got)
    assert _interrupt_in(ValueError("no interrupt here")) is None


@pytest.mark.parametrize("sig, other", [("SIGTERM", ("SIGINT", "Ctrl-C", "KeyboardInterrupt")),
                                        ("SIGINT", ("SIGTERM", "Terminated"))])
def test_a_replay_stopped_by_a_signal_names_that_signal(sig, other, tmp_path, monkeypatch, capsys):
    """A signal whose interrupt a library swallowed while the replay ran (numba, say) still stops
    it, at the engine's next look; the message said "KeyboardInterrupt", Ctrl-C's, for a SIGTERM.
    Now it names the signal that came, and nothing else."""
    import os

    from nrtraffic import engine as engine_mod

    tick = engine_mod.Engine._tick
    sent = []

    def swallowing(self, *args, **kwargs):
        if not sent:
            sent.append(sig)
            try:  # (a library that catches the interrupt raised in it and goes on)
                os.kill(os.getpid(), getattr(signal, sig))
                for _ in range(1000):
                    pass
            except KeyboardInterrupt:
                pass
        return tick(self, *args, **kwargs)

    monkeypatch.setattr(engine_mod.Engine, "_tick", swallowing)
    out = tmp_path / "replay"
    assert main(["replay", str(ROOT / "tests" / "golden" / "cross4"), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert sent and f"stopped by {sig}" in err and "Traceback" not in err, err
    assert not any(word in err for word in other), err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and sig in s["error"] and not any(word in s["error"] for word in other)


_ROUTE_CASES = {
    "zero_rate": ('<flow id="x" route="r" begin="0" end="100" vehsPerHour="0"/><route id="r" edges="W_in E_out"/>',
                  "vehsPerHour must be > 0"),
    "zero_rate_trip": ('<flow id="x" from="W_in" to="E_out" begin="0" end="100" vehsPerHour="0"/>',
                       "duarouter could not route its trips: Error: Invalid repetition rate in the definition of flow 'x'"),
    "no_vehicles": ('<route id="r" edges="W_in E_out"/>', "holds no <vehicle>, <trip> or <flow>"),
    "malformed": ('<flow id="x" from="W_in"', "cannot be read as XML"),
    "huge_flow": ('<flow id="x" from="W_in" to="E_out" begin="0" end="100" number="1000000000"/>',
                  "more than the 1000000 vehicles one flow may have"),
    # a flow by period with no end, in an open-ended run (--duration 0 in the test): terabytes of times
    "huge_flow_open": ('<flow id="x" route="r" begin="0" end="1e9" period="3"/><route id="r" edges="W_in E_out"/>',
                       "makes more than the 1000000 vehicles one flow may have in the run"),
    # a rate no lane carries (a million vehicles in an hour had taken minutes to build and run)
    "flow_too_dense": ('<flow id="x" route="r" begin="0" end="3600" number="1000000"/><route id="r" '
                       'edges="W_in E_out"/>', "departs 1000000 veh/h, more than the 20000 veh/h one flow may have"),
    "flow_at_once": ('<flow id="x" route="r" begin="5" end="5" number="3"/><route id="r" edges="W_in E_out"/>',
                     "departs all at one moment"),
    # flows SUMO refuses, taken silently (one rate of two used, or the flow dropped)
    "two_rates": ('<flow id="x" route="r" begin="0" end="100" period="1" vehsPerHour="100"/><route id="r" '
                  'edges="W_in E_out"/>', "gives both period and vehsPerHour; give one rate"),
    "negative_number": ('<flow id="x" route="r" begin="0" end="100" number="-3"/><route id="r" edges="W_in E_out"/>'
                        '<vehicle id="v" route="r" depart="1"/>', "number=-3 is negative"),
    "route_distribution": ('<routeDistribution id="rd"><route id="r1" edges="W_in E_out" probability="1"/>'
                           '</routeDistribution><vehicle id="v" route="rd" depart="1"/>', "is a <routeDistribution>"),
    "fractional_number": ('<flow id="x" route="r" begin="0" end="100" number="2.5"/><route id="r" edges="W_in E_out"/>',
                          "number='2.5' is not a whole number of vehicles"),
    "trip_nan_depart": ('<trip id="a" from="N_in" to="S_out" depart="nan"/>', "depart='nan' is not finite"),
    "flow_negative_begin": ('<flow id="x" route="r" begin="-10" end="30" vehsPerHour="600"/><route id="r" '
                            'edges="W_in E_out"/>', "begin=-10 is negative"),
    "end_before_begin": ('<flow id="x" route="r" begin="50" end="10" period="2"/><route id="r" edges="W_in E_out"/>'
                         '<vehicle id="v" route="r" depart="1"/>', "end=10 is before begin=50"),
    "exp_negative": ('<flow id="x" route="r" begin="0" end="100" period="exp(-1)"/><route id="r" edges="W_in E_out"/>'
                     '<vehicle id="v" route="r" depart="1"/>', "the rate of exp(RATE) must be a number > 0"),
    # trips and flows by from/to go to duarouter, which hung on these rates: checked first
    "exp_nan_trip": ('<flow id="x" from="W_in" to="E_out" begin="0" end="20" period="exp(nan)"/>',
                     "<flow id='x'>: period='exp(nan)': the rate of exp(RATE) must be a number > 0"),
    "exp_tiny_trip": ('<flow id="x" from="W_in" to="E_out" begin="0" end="20" period="exp(1e-300)"/>',
                      "a rate below 1e-09 per second makes no vehicle in any run"),
    "huge_flow_route": ('<flow id="x" route="r" begin="0" end="100" number="1000000000"/><route id="r" edges="W_in E_out"/>',
                        "more than the 20000 veh/h one flow may have"),
    "unknown_edges": ('<trip id="x" depart="1" from="W_in" to="Nowhere_out"/>', "The edge 'Nowhere_out' within the route for trip 'x' is not known"),
    "no_movement": ('<vehicle id="x" depart="1"><route edges="W_in"/></vehicle>',
                    "none of its 1 vehicles crosses a controlled junction"),
    "id_twice": ('<route id="r" edges="W_in E_out"/><vehicle id="a" route="r" depart="1"/>'
                 '<vehicle id="a" route="r" depart="2"/>', "the vehicle id 'a' is given twice"),
}


@pytest.mark.parametrize("case", sorted(_ROUTE_CASES))
def test_a_bad_route_file_is_refused_before_sumo_starts(case, tmp_path, capsys):
    """A route file's errors are found when the demand is built before SUMO starts: exit 2 naming
    the element, and nothing is written (the run exited 1 after SUMO had started, or, for a flow of
    0 veh/h, with a ZeroDivisionError)."""
    body, message = _ROUTE_CASES[case]
    d = copy_scenario("tee3", tmp_path / "tee3")
    (d / "flows.rou.xml").write_text(f"<routes>\n{body}\n</routes>\n")
    out = tmp_path / "o"
    duration = "0" if case == "huge_flow_open" else "20"
    assert main(["run", str(d / "routes.toml"), "--out", str(out), "--duration", duration, "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("old, new, flags, message", [
    ('approach = "E_in"', 'approach = "Q_in"', [], "Q_in is not an approach of the junction"),
    ("straight = 100.0", "straight = 100.0\nu_turn = 10.0", [], "u_turn"),
    ("", "", ["--duration", "0", "--set", "scenario.duration_s=0", "--set", "demand.rate_veh_h=100"],
     "random demand needs"),
    ("", "", ["--duration", "20", "--set", "demand.entry_speed_mps=16", "--set", "planning.v_max_mps=20"],
     "departs at 16 m/s on edge S_in, whose speed limit is 13.89 m/s"),
])
def test_a_bad_demand_is_refused_before_sumo_starts(old, new, flags, message, tmp_path, capsys):
    """Counts for an approach the junction lacks, a U-turn count where it has none, open-ended random
    demand for a run without an end, a departure faster than the departure edge allows: exit 2
    before anything is written (these exited 1 once SUMO had started)."""
    d = copy_scenario("cross4", tmp_path / "cross4")
    counts = d / "counts.toml"
    if old:
        text = counts.read_text()
        assert old in text
        counts.write_text(text.replace(old, new, 1))
    out = tmp_path / "o"
    args = ["run", str(counts), "--out", str(out), "--no-progress"] + (flags or ["--duration", "20"])
    if flags:  # (these: cross4 itself)
        args[1] = str(d / "scenario.toml")
    assert main(args) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_corridor_flows_into_a_junction_that_is_not_controlled_are_refused_naming_the_fix(tmp_path, capsys):
    """corridor3 without J3 in [[junctions]] but with its flows: exit 2 before SUMO starts, naming the
    flows, the junction they lead into and the two fixes."""
    d = copy_scenario("corridor3", tmp_path / "c3", '[[junctions]]\nid = "J3"\n', "")
    out = tmp_path / "o"
    assert main(["run", str(d / "scenario.toml"), "--out", str(out), "--duration", "20", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "E_J3, J2_J3, N3_J3, S3_J3 is not an approach" in err
    assert 'add [[junctions]] id = "J3", or remove their [[demand.flows]]' in err
    assert not out.exists()


def test_sweep_flags_and_demand_are_checked_before_any_worker_starts(tmp_path, capsys):
    """Seeds outside 0..2^31-1 and a demand that cannot be built stop a sweep with exit 2 before any
    run starts, naming the flag or the key (a negative seed failed inside a Dask worker)."""
    assert main(["sweep", str(CROSS4), "--seeds=-1:0", "--out", str(tmp_path / "a"), "--no-progress"]) == 2
    assert "seeds are 0 to 2^31 - 1" in capsys.readouterr().err
    assert main(["sweep", str(CROSS4), "--seeds", "-1:0", "--out", str(tmp_path / "a"), "--no-progress"]) == 2
    assert "seeds are 0 to 2^31 - 1" in capsys.readouterr().err  # (not taken for an option)
    d = copy_scenario("cross4", tmp_path / "cross4")
    counts = d / "counts.toml"
    counts.write_text(counts.read_text().replace('approach = "E_in"', 'approach = "Q_in"', 1))
    assert main(["sweep", str(counts), "--seeds", "1:2", "--out", str(tmp_path / "b"), "--no-progress"]) == 2
    assert "Q_in is not an approach" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.mark.parametrize("value", ["[" * 3000 + "]" * 3000, "{a = " * 3000 + "1" + "}" * 3000])
def test_deeply_nested_toml_is_refused_with_exit_2(value, tmp_path, capsys):
    """Arrays or inline tables nested thousands deep (an uncaught RecursionError): exit 2, in the
    file and in --set."""
    d = _scenario_copy(tmp_path, None, None, f"\n[extra]\nnested = {value}\n")
    assert main(["run", str(d), "--out", str(tmp_path / "o"), "--duration", "5", "--no-progress"]) == 2
    assert "nested too deeply" in capsys.readouterr().err
    assert main(["run", str(CROSS4), "--out", str(tmp_path / "o"), "--duration", "5", "--no-progress",
                 "--set", f"outputs.warmup_s={value}"]) == 2
    assert "nested too deeply" in capsys.readouterr().err


def test_runs_that_did_not_do_their_job_say_so(tmp_path):
    """A run with no vehicle is refused before SUMO starts (it said ok, with a warning); one whose
    tracker barely tracks (alpha 1e-3 instead of 100: the car falls tens of metres behind its plan)
    finishes with a warning in summary.json."""
    assert main(["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", "--set", "demand.rate_veh_h=0", "--set",
                 "demand.mean_headway_s=0", "--out", str(tmp_path / "none"), "--no-progress"]) == 2
    assert not (tmp_path / "none" / "summary.json").exists()
    paper = SCENARIOS / "paper_curved" / "scenario.toml"
    assert main(["run", str(paper), "--duration", "30", "--set", "controller.alpha=0.001", "--out",
                 str(tmp_path / "slack"), "--no-progress"]) == 0
    s = json.loads((tmp_path / "slack" / "summary.json").read_text())
    assert s["max_tracking_error_m"] > 3.2 and any("more than a lane's width" in w for w in s["warnings"])


def test_missing_sumo_is_exit_2_naming_the_package(tmp_path, monkeypatch, capsys):
    """SUMO's binaries or libsumo missing: exit 2 before anything runs, naming what to install (a
    Python traceback for run and baseline)."""
    from nrtraffic.sumo import netbuild

    def absent(name):
        raise netbuild.SumoToolError(f"SUMO binary {name!r} not found: install the 'eclipse-sumo' package "
                                     "(pip install eclipse-sumo)")

    with monkeypatch.context() as m:
        m.setattr(netbuild, "sumo_binary", absent)
        for cmd in (["run", str(CROSS4)], ["baseline", str(CROSS4), "--junction", "priority"]):
            assert main(cmd + ["--out", str(tmp_path / "o"), "--duration", "5"]) == 2
            assert "eclipse-sumo" in capsys.readouterr().err
    with monkeypatch.context() as m:
        m.setitem(sys.modules, "libsumo", None)  # import libsumo raises ImportError
        assert main(["run", str(CROSS4), "--out", str(tmp_path / "o"), "--duration", "5"]) == 2
        assert "pip install libsumo" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_the_default_run_folder_is_a_safe_name_under_runs(tmp_path, monkeypatch):
    """A scenario named ``../../escape`` runs into runs/escape-seed1, not two folders up."""
    from runners.cli import slug

    assert slug("../../escape") == "escape" and slug("cross4 counts/peak") == "cross4_counts_peak"
    assert slug("...") == "run"


def test_a_sweep_too_large_or_with_an_unreachable_scheduler_is_refused_in_one_line(tmp_path, capsys):
    """More than 20000 runs (a typo in --seeds) needs --force; a scheduler nobody listens at is one
    line with exit 2, not a traceback from Dask."""
    assert main(["sweep", str(CROSS4), "--seeds", "0:30000", "--out", str(tmp_path / "a"), "--no-progress"]) == 2
    assert "30001 runs, more than 20000" in capsys.readouterr().err
    # one seed twice would be one run counted as two samples (intervals of "± 0")
    assert main(["sweep", str(CROSS4), "--seeds", "1,2,1", "--out", str(tmp_path / "a"), "--no-progress"]) == 2
    assert "seed 1 is given twice" in capsys.readouterr().err
    assert main(["sweep", str(CROSS4), "--seeds", "1,,2", "--out", str(tmp_path / "a"), "--no-progress"]) == 2
    assert "expected A:B or a comma list of integers" in capsys.readouterr().err
    assert main(["sweep", str(CROSS4), "--seeds", "1:2", "--duration", "5", "--set", "outputs.warmup_s=0", "--scheduler", "tcp://127.0.0.1:1",
                 "--out", str(tmp_path / "b"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "no Dask scheduler answered within" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists()  # (refused: nothing written)
    # not an address at all: refused at once (it waited for a connection, then "cannot reach it")
    assert main(["sweep", str(CROSS4), "--seeds", "1", "--scheduler", "nonsense", "--out", str(tmp_path / "b"),
                 "--no-progress"]) == 2
    assert "expected a Dask scheduler's address" in capsys.readouterr().err
    # a port that is none, a host nobody knows, tls:// without Dask's TLS settings: said at once, by name
    # (they had waited 10 s for "cannot reach it (OSError)", or said "no Dask scheduler answers (TypeError)")
    for address, said in (("tcp://127.0.0.1:99999", "port 99999 is not a port"), ("127.0.0.1:0", "port 0 is not"),
                          ("tcp://nohost.invalid:8786", "no host is known by the name nohost.invalid"),
                          ("tls://127.0.0.1:1", "tls:// needs Dask's TLS settings")):
        assert main(["sweep", str(CROSS4), "--seeds", "1", "--duration", "5", "--set", "outputs.warmup_s=0",
                     "--scheduler", address, "--out", str(tmp_path / "b"), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert said in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "b").exists()


def test_a_scheduler_address_where_something_else_answers_is_refused_in_one_line(tmp_path, capsys):
    """A server that is not Dask's (here one answering HTTP 403) at --scheduler: Dask's client read
    its reply as a frame of exabytes (a numpy MemoryError traceback); now exit 2 in one line."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    port = srv.getsockname()[1]

    def answer():
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            try:
                conn.sendall(b"HTTP/1.1 403 Forbidden\r\nContent-Length: 0\r\n\r\n" * 64)
            except OSError:
                pass
            finally:
                conn.close()

    threading.Thread(target=answer, daemon=True).start()
    try:
        code = main(["sweep", str(CROSS4), "--seeds", "1", "--duration", "5", "--set", "outputs.warmup_s=0",
                     "--scheduler", f"tcp://127.0.0.1:{port}", "--out", str(tmp_path / "c"), "--no-progress"])
    finally:
        srv.close()
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and "--scheduler" in err
    assert "something answers there, but not as a Dask scheduler" in err and "MemoryError" not in err, err
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("fills_after", [1, 2, 3, 4])  # (a 30 s run writes 4 files: 4 is the last summary)
def test_a_disk_that_fills_at_any_write_still_ends_with_a_summary_that_says_failed(fills_after, tmp_path,
                                                                                    monkeypatch, capsys):
    """The disk fills after the run's first ``fills_after`` file writes (the summary written at the
    start, the checkpoints, the final tables): every later write of a new file fails with ENOSPC.
    summary.json, which holds its space from the start, is still overwritten in place at the end:
    readable, ``"status": "failed"``, and why; exit 1."""
    from nrtraffic import results

    calls = {"n": 0}
    atomic, table = results.write_atomic, results.write_table

    def count():
        calls["n"] += 1
        if calls["n"] > fills_after:
            raise OSError(28, "No space left on device")

    def full_atomic(path, data):
        count()
        atomic(path, data)

    def full_table(path, t):
        count()
        table(path, t)

    monkeypatch.setattr(results, "write_atomic", full_atomic)
    monkeypatch.setattr(results, "write_table", full_table)
    import runners.single as single
    monkeypatch.setattr(single, "write_table", full_table)
    out = tmp_path / "run"
    code = main(["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out", str(out), "--no-progress"])
    s = json.loads((out / "summary.json").read_text())
    if fills_after == 4:  # every table was written, and the last summary went in place: a whole run
        assert code == 0 and s["status"] == "ok" and s["sim_time_s"] == pytest.approx(30.0)
        return
    assert code == 1
    assert "No space left on device" in capsys.readouterr().err
    assert s["status"] == "failed" and "No space left" in s["error"]


@pytest.mark.parametrize("stop", [KeyboardInterrupt("interrupted (SIGINT)"), RuntimeError("a library's own error")])
def test_a_run_stopped_while_its_demand_is_built_says_failed(tmp_path, monkeypatch, stop):
    """Stopped after the run directory says "running" but before the demand exists (the layout
    read, the arrivals not yet drawn): the summary says failed and why, never "running"."""
    from nrtraffic import engine as engine_mod
    from nrtraffic import scenario
    from nrtraffic.engine import RunFailed
    from runners.single import run_scenario

    def broken(*args, **kwargs):
        raise stop

    monkeypatch.setattr(engine_mod, "Demand", broken)
    out = tmp_path / "run"
    with pytest.raises(RunFailed):
        run_scenario(scenario.load(CROSS4), out, duration_s=60)
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and str(stop) in s["error"]


def test_a_trajectory_step_cut_short_by_an_interrupt_is_dropped_and_the_file_stays_whole(tmp_path):
    """An interrupt inside TrajectoryWriter.append leaves that step's columns of unequal length: the
    file written at close holds every whole step before it, and nothing of the cut one."""
    from nrtraffic.results import TRAJECTORY_COLUMNS, TrajectoryWriter

    w = TrajectoryWriter(tmp_path / "trajectories.parquet")
    row = {k: ("a" if k == "vehicle_id" else 1.0) for k in TRAJECTORY_COLUMNS}
    for t in (0.0, 0.5, 1.0):
        w.append(**{**row, "t": t})

    class Interrupted:  # the value of a column that is not reached: the interrupt comes first
        @property
        def ndim(self):
            raise KeyboardInterrupt

    cut = dict(row, t=1.5, psi=Interrupted())
    with pytest.raises(KeyboardInterrupt):
        w.append(**cut)
    w.close()
    w.close()  # (a second close, as a failure's clean-up may do, keeps the file)
    t = pq.read_table(tmp_path / "trajectories.parquet").to_pandas()
    assert t["t"].tolist() == [0.0, 0.5, 1.0] and (t["vehicle_id"] == "a").all()


@pytest.mark.parametrize("command", [["run", str(CROSS4)], ["baseline", str(CROSS4)],
                                     ["sweep", str(CROSS4), "--seeds", "1"]])
def test_an_empty_out_is_refused_not_taken_for_the_working_folder(command, tmp_path, capsys, monkeypatch):
    """``--out ""`` (an unset shell variable) was the working folder: the run wrote into it."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main([*command, "--out", "", "--duration", "5", "--no-progress"])
    assert exc.value.code == 2 and "--out: is empty: name a folder" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_an_out_name_too_long_for_the_file_system_is_refused_before_anything_runs(tmp_path, capsys):
    """A 300-character folder name failed once SUMO started, "File name too long", exit 1."""
    out = tmp_path / ("x" * 300)
    assert main(["run", str(CROSS4), "--out", str(out), "--duration", "5", "--set", "outputs.warmup_s=0",
                 "--no-progress"]) == 2
    assert "longer than the file system takes" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["with,comma", "col:on", "q'uote", "new\nline", "tab\there"])
def test_an_out_path_sumo_would_misread_is_refused(tmp_path, capsys, name):
    """SUMO reads a comma in a file name as a list separator and host:port as a socket; a quote
    failed it too, and a line break (SUMO could not open its outputs): exit 2 before anything is
    written, for a run and for a sweep."""
    out = tmp_path / name
    flags = ["--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]
    assert main(["run", str(CROSS4), "--out", str(out), *flags]) == 2
    assert "which SUMO misreads in a file name" in capsys.readouterr().err
    assert main(["sweep", str(CROSS4), "--seeds", "1", "--out", str(out), *flags]) == 2
    assert "which SUMO misreads in a file name" in capsys.readouterr().err
    assert not out.exists()


def test_a_sweep_does_not_write_into_a_folder_of_the_users_files(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "sweep.csv").write_text("my own table\n")
    assert main(["sweep", str(CROSS4), "--seeds", "1", "--out", str(out), "--duration", "5", "--set",
                 "outputs.warmup_s=0", "--no-progress"]) == 2
    assert "and no earlier sweep (no runs/ folder)" in capsys.readouterr().err
    assert (out / "sweep.csv").read_text() == "my own table\n" and sorted(p.name for p in out.iterdir()) == ["sweep.csv"]


def test_a_sweep_resumes_only_over_tables_it_wrote(tmp_path, capsys):
    """A folder of the user's with a runs/ folder in it (a project where runs were made) and a
    report.html of theirs: refused, and nothing written. A finished sweep's own folder resumes and
    rewrites its tables; a file of the user's put into it later is refused by name and kept."""
    flags = ["--seeds", "1", "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress", "--workers", "1"]
    mine = tmp_path / "project"
    (mine / "runs").mkdir(parents=True)
    (mine / "report.html").write_text("my report")
    assert main(["sweep", str(CROSS4), "--out", str(mine), *flags]) == 2
    assert "report.html, which no sweep there recorded writing" in capsys.readouterr().err
    assert (mine / "report.html").read_text() == "my report" and not any((mine / "runs").iterdir())
    (mine / "report.html").unlink()  # (a project whose runs/ holds the user's own runs, no sweep's)
    assert main(["run", str(CROSS4), "--out", str(mine / "runs" / "cross4"), *flags[2:-2]]) == 0
    capsys.readouterr()
    assert main(["sweep", str(CROSS4), "--out", str(mine), *flags]) == 2
    assert "holds a runs/ folder that no sweep wrote" in capsys.readouterr().err
    assert sorted(p.name for p in (mine / "runs").iterdir()) == ["cross4"]
    out = tmp_path / "study"
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags]) == 0
    created = json.loads((out / "manifest.json").read_text())["created"]
    assert {"sweep.csv", "sweep.md", "report.html", "runs"} <= set(created)
    # tables it did not write (no baseline: no side-by-side tables; no human drivers) are not claimed
    assert not {"sweep_movements.csv", "sweep_approaches.csv", "drivers.png"} & set(created)
    (out / "sweep.md").write_text("stale")
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags]) == 0  # (a resume: its tables again)
    assert (out / "sweep.md").read_text() != "stale"
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags]) == 2
    assert "notes.txt" in capsys.readouterr().err and (out / "notes.txt").read_text() == "mine"
    # nor a file of the user's named like a table it did not write, for a resume that would write it
    (out / "notes.txt").unlink()
    (out / "sweep_movements.csv").write_text("mine")
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags, "--baseline", "priority"]) == 2
    assert "sweep_movements.csv" in capsys.readouterr().err
    assert (out / "sweep_movements.csv").read_text() == "mine"


def test_a_sweep_stopped_while_it_writes_its_tables_resumes(tmp_path, monkeypatch):
    """A sweep stopped after its runs, half-way through writing its tables (sweep.csv written, the
    rest not): its manifest already names them, so the next sweep on the folder resumes and writes
    them whole (it had refused sweep.csv as a file no sweep recorded writing)."""
    from runners import sweep

    flags = ["--seeds", "1", "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress", "--workers", "1"]
    out = tmp_path / "study"
    write_tables = sweep.write_tables

    def stopped(df, out_dir, figures=sweep.sweep_figures):
        (out_dir / "sweep.csv").write_text("half")
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep, "write_tables", stopped)
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags]) == 1
    monkeypatch.setattr(sweep, "write_tables", write_tables)
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags]) == 0
    assert (out / "sweep.csv").read_text() != "half" and (out / "report.html").is_file()


def test_a_sweep_stopped_while_it_replaces_its_runs_leaves_no_table_of_the_old_ones(tmp_path, monkeypatch):
    """A finished sweep run again with another configuration (--force) and stopped after its first
    new run: its tables, figures and report had stayed, describing the old runs beside the new one,
    with nothing to say so. They are removed before any run is replaced; the resume writes them
    anew, of the new runs alone."""
    from runners import sweep

    flags = ["--seeds", "1:2", "--set", "outputs.warmup_s=0", "--no-progress", "--workers", "1"]
    out = tmp_path / "study"
    assert main(["sweep", str(CROSS4), "--out", str(out), "--duration", "5", *flags]) == 0
    written = {"sweep.csv", "sweep.md", "sweep_summary.csv", "report.html", "sweep.png"}
    assert written <= {p.name for p in out.iterdir()}
    done = sweep.Progress.done

    def stop_after_one(self, job, failed, **kw):
        done(self, job, failed, **kw)
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep.Progress, "done", stop_after_one)
    assert main(["sweep", str(CROSS4), "--out", str(out), "--duration", "6", "--force", *flags]) == 1
    assert not written & {p.name for p in out.iterdir()}
    monkeypatch.setattr(sweep.Progress, "done", done)
    assert main(["sweep", str(CROSS4), "--out", str(out), "--duration", "6", "--force", *flags]) == 0
    df = pd.read_csv(out / "sweep.csv")
    assert len(df) == 2 and (df["sim_time_s"] == 6).all() and (df["status"] == "ok").all()


def test_a_reproduction_stopped_while_it_replaces_its_runs_leaves_no_table_of_the_old_ones(tmp_path, monkeypatch,
                                                                                            capsys):
    """``nrtraffic paper`` run again into its own earlier folder and stopped at its first run: the
    earlier table, results and figures (here stand-ins of them, listed by its manifest) had stayed
    beside runs they no longer describe. They go before the first run."""
    from runners import paper

    out = tmp_path / "cbf"
    paper.claim_out(out, "cbf")  # (its manifest lists what the reproduction writes)
    for name in paper.CBF_FILES:
        (out / name).write_text("earlier")

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(paper, "run_scenario", stopped)
    assert main(["paper", "cbf", "--out", str(out), "--no-progress"]) == 1
    assert not any((out / name).exists() for name in paper.CBF_FILES)


@pytest.mark.parametrize("flags, message", [
    (["--grid", "demand.rate_veh_h=400,400.0"], "400 and 400.0 are the same value"),
    (["--baseline", "traffic_light,traffic_light"], "traffic_light is given twice"),
    (["--baseline", ""], "names no control"),
    (["--grid", "scenario.seed=1,2"], "a sweep's seeds are --seeds"),
    (["--workers", "100000"], "a local cluster takes at most"),
    # --duration sets every run's: a grid over the duration would be one configuration
    (["--grid", "scenario.duration_s=5,10"], "would be one configuration"),
    # a value or a control left out by a stray comma
    (["--grid", "demand.rate_veh_h=400,,600"], "an empty value between or after its commas"),
    (["--grid", "demand.rate_veh_h=400,"], "an empty value between or after its commas"),
    (["--baseline", "priority,"], "an empty name between or after its commas"),
    # a --set that the grid or --seeds would override without a word
    (["--grid", "demand.rate_veh_h=100,200", "--set", "demand.rate_veh_h=300"], "--grid sets it at every point"),
    (["--set", "scenario.seed=5"], "a sweep's seeds are --seeds"),
    (["--set", "scenario.duration_s=10"], "--duration 5.0 and --set scenario.duration_s=10 both give it"),
    # two values whose folder names are one: the second had failed as "another configuration"
    (["--grid", 'scenario.description="a/b","a_b"', "--set", "outputs.warmup_s=0"], "have one folder name"),
    # a bad value at one grid point: the message says which point
    (["--grid", "demand.rate_veh_h=400,-5", "--set", "outputs.warmup_s=0"],
     "at the grid point demand.rate_veh_h=-5: "),
    (["--grid", "demand.rate_veh_h=10,400", "--set", "outputs.warmup_s=0"],  # (no vehicle in 5 s at the first)
     "at the grid point demand.rate_veh_h=10: "),
])
def test_sweep_flags_that_would_count_a_run_twice_or_do_nothing_are_refused(flags, message, tmp_path, capsys):
    """The same configuration twice (two runs of one seed counted as two samples), a --baseline
    of no control, a grid over the seed (every row had the same seed) or over the duration that
    --duration sets, a value left out by a stray comma, and a local cluster of 100000 workers (it
    hung): exit 2 before anything runs."""
    out = tmp_path / "study"
    assert main(["sweep", str(CROSS4), "--seeds", "1", "--duration", "5", "--no-progress", "--out", str(out),
                 *flags]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_a_sweep_never_replaces_a_run_folder_holding_the_users_files(tmp_path, capsys):
    """A file of the user's in a sweep's run folder (beside a finished run, or in a folder of the
    run's name made before the sweep): a resume that would run it again, with ``--force`` or not,
    is refused by name (exit 2) and the files stay. A replay, even with ``--force``, never takes a
    sweep's folder for a run's (it removed the sweep's tables)."""
    flags = ["--seeds", "1", "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress", "--workers", "1"]
    out = tmp_path / "study"
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags]) == 0
    run = next((out / "runs").glob("*/seed1/nrtraffic"))
    (run / "notes.txt").write_text("mine")
    capsys.readouterr()
    for force in ([], ["--force"]):
        assert main(["sweep", str(CROSS4), "--out", str(out), *flags, "--set", "controller.alpha=50", *force]) == 2
        assert "notes.txt, which its run did not write" in capsys.readouterr().err
        assert (run / "notes.txt").read_text() == "mine"
    early = tmp_path / "early"
    made = early / "runs" / run.relative_to(out).parts[1] / "seed1" / "nrtraffic"
    made.mkdir(parents=True)
    (made / "vehicles.csv").write_text("mine\n")
    assert main(["sweep", str(CROSS4), "--out", str(early), *flags]) == 2
    assert (made / "vehicles.csv").read_text() == "mine\n"
    tables = sorted(p.name for p in out.iterdir())
    assert main(["replay", str(run), "--out", str(out), "--force", "--no-progress"]) == 2
    assert sorted(p.name for p in out.iterdir()) == tables
    # nor a run folder in it, for a replay, a run or another sweep (it replaced the sweep's run)
    (run / "notes.txt").unlink()
    recorded = (run / "summary.json").read_text()
    capsys.readouterr()
    assert main(["replay", str(run), "--out", str(run.parent / "other"), "--force", "--no-progress"]) == 2
    assert main(["run", str(CROSS4), "--out", str(run), "--force", "--duration", "5", "--set", "outputs.warmup_s=0",
                 "--no-progress"]) == 2
    assert "lies in the sweep folder" in capsys.readouterr().err
    assert main(["sweep", str(CROSS4), "--out", str(out / "runs" / "inner"), *flags]) == 2
    assert "lies in the sweep folder" in capsys.readouterr().err
    for study, where in ((["paper", "cbf"], out), (["paper", "cbf"], out / "runs" / "inner"),
                         (["robustness"], out / "runs" / "inner")):  # (nor the other studies)
        assert main([*study, "--out", str(where), "--no-progress"]) == 2
        assert "lies in the sweep folder" in capsys.readouterr().err
    assert (run / "summary.json").read_text() == recorded and not (out / "runs" / "inner").exists()
    assert main(["run", str(CROSS4), "--out", str(out / "runs" / "new" / "deeper"), "--duration", "5", "--set",
                 "outputs.warmup_s=0", "--no-progress"]) == 2  # (its folders, made to be checked, go again)
    assert not (out / "runs" / "new").exists() and not (run.parent / "other").exists()
    # a sweep of a version that kept no manifest of its own: its run folders are known by their
    # fingerprint (a run --force had replaced one)
    (out / "manifest.json").unlink()
    assert main(["run", str(CROSS4), "--out", str(run), "--force", "--duration", "5", "--set", "outputs.warmup_s=0",
                 "--no-progress"]) == 2
    assert f"lies in the sweep folder {out}" in capsys.readouterr().err
    assert (run / "summary.json").read_text() == recorded


@pytest.mark.parametrize("flags", [["--set", "demand.begin_s=100", "--set", "demand.end_s=10"],
                                   ["--set", "scenario.begin_s=100000"]])
def test_a_demand_that_gives_the_run_no_vehicle_is_refused(tmp_path, capsys, flags):
    """An empty demand (arrivals that end before they begin; a route file all of whose departures
    come before the run's start) is exit 2 before SUMO starts: the run would do nothing and say ok."""
    scenario = CROSS4 if "demand.begin_s=100" in flags else ROOT / "sumo_scenarios" / "tee3" / "routes.toml"
    out = tmp_path / "o"
    assert main(["run", str(scenario), "--out", str(out), "--duration", "60", "--set", "outputs.warmup_s=0",
                 "--no-progress", *flags]) == 2
    assert "the demand gives the run no vehicle" in capsys.readouterr().err
    assert not (out / "summary.json").exists()


def test_force_never_removes_anything_outside_the_run_folder(tmp_path, capsys):
    """--force on an earlier run whose sumo/ was replaced by a link to the user's folder, and whose
    manifest lists '../' and absolute paths: the user's files stay. A folder whose manifest.json is
    not a run's (a web app's, say) is refused even with --force."""
    base = ["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]
    user = tmp_path / "user"
    user.mkdir()
    for name in ("net.net.xml", "routes.rou.xml", "victim.txt"):
        (user / name).write_text("mine")
    r = tmp_path / "r"
    assert main(base + ["--out", str(r)]) == 0
    import shutil

    shutil.rmtree(r / "sumo")
    (r / "sumo").symlink_to(user, target_is_directory=True)
    m = json.loads((r / "manifest.json").read_text())
    m["created"] += ["../user/victim.txt", str(user / "victim.txt")]
    (r / "manifest.json").write_text(json.dumps(m))
    assert main(base + ["--out", str(r), "--seed", "2", "--force"]) == 0
    assert sorted(p.name for p in user.iterdir()) == ["net.net.xml", "routes.rou.xml", "victim.txt"]
    app = tmp_path / "app"
    app.mkdir()
    (app / "manifest.json").write_text('{"name": "my web app"}')
    (app / "index.html").write_text("mine")
    capsys.readouterr()
    assert main(base + ["--out", str(app), "--force"]) == 2
    assert "holds no run's manifest.json" in capsys.readouterr().err
    assert (app / "manifest.json").read_text() == '{"name": "my web app"}'


def test_a_disk_that_fills_while_the_report_is_written_says_failed(tmp_path, monkeypatch, capsys):
    """The run's tables are written, then the disk is full for its figures: exit 1 with one line,
    and summary.json says failed and why (it said ok)."""
    from nrtraffic import report

    def full(run_dir, **kw):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(report, "run_report", full)
    out = tmp_path / "run"
    code = main(["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out", str(out), "--no-progress"])
    assert code == 1 and "No space left on device" in capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and "its report could not be written" in s["error"]


@pytest.mark.parametrize("command", [["run"], ["baseline", "--junction", "priority"]])
def test_a_run_says_ok_only_once_its_report_is_written(command, tmp_path, monkeypatch, capsys):
    """summary.json said ok before the figures and report.html were made: a report that failed
    (here an error in a figure, not the disk) left a run that said ok, and a traceback. Now the
    summary says "running" while the report is made and "ok" only after it and the manifest; a
    failed report is exit 1 in one line, and the summary says failed and why."""
    from nrtraffic import report

    real = report.run_report
    seen = []

    def watched(run_dir, **kw):
        seen.append(json.loads((run_dir / "summary.json").read_text())["status"])
        return real(run_dir, **kw)

    def broken(run_dir, **kw):
        seen.append(json.loads((run_dir / "summary.json").read_text())["status"])
        raise ValueError("a figure that cannot be drawn")

    base = [command[0], str(CROSS4), *command[1:], "--duration", "30", "--set", "outputs.warmup_s=0", "--no-progress"]
    monkeypatch.setattr(report, "run_report", watched)
    ok = tmp_path / "ok"
    assert main(base + ["--out", str(ok)]) == 0
    assert seen == ["running"] and json.loads((ok / "summary.json").read_text())["status"] == "ok"
    assert "report.html" in json.loads((ok / "manifest.json").read_text())["created"]
    assert all((ok / f).is_file() for f in ("report.html", "vehicles.csv", "movements.csv", "approaches.csv"))
    assert "<td>ok</td>" in (ok / "report.html").read_text()  # (the report shows the run's final status)
    seen.clear()
    monkeypatch.setattr(report, "run_report", broken)
    out = tmp_path / "failed"
    capsys.readouterr()
    assert main(base + ["--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert seen == ["running"] and "Traceback" not in err and "a figure that cannot be drawn" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed"
    assert s["error"] == "the run finished, but its report could not be written: ValueError: a figure that cannot be drawn"


def test_force_does_not_write_over_files_no_earlier_run_created(tmp_path, capsys):
    """A folder that looks like a finished run (its summary.json and scenario.resolved.toml copied
    in) but holds the user's vehicles.csv and no manifest; and one whose manifest lists the user's
    files as there before: refused, with or without --force, and the user's files stay."""
    import shutil

    base = ["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]
    first = tmp_path / "first"
    assert main(base + ["--out", str(first)]) == 0
    for case, manifest in (("none", None), ("listed", {"created": ["summary.json", "scenario.resolved.toml"],
                                                       "preexisting": ["vehicles.csv"]})):
        o = tmp_path / case
        o.mkdir()
        for f in ("summary.json", "scenario.resolved.toml"):
            shutil.copy(first / f, o / f)
        (o / "vehicles.csv").write_text("mine\n")
        if manifest is not None:
            (o / "manifest.json").write_text(json.dumps(manifest))
        for force in ([], ["--force"]):
            capsys.readouterr()
            assert main(base + ["--out", str(o), *force]) == 2, (case, force)
            assert (o / "vehicles.csv").read_text() == "mine\n"


@pytest.mark.parametrize("factor", [0.97, 1.03])
def test_a_driver_who_cannot_stop_before_giving_way_is_refused_as_sumo_discards_it(factor, tmp_path, capsys):
    """Human drivers braking too gently to stop, from their departure speed, before the junction
    where they give way: the run is refused (exit 2, naming human.decel_mps2 and the least that
    serves) exactly where SUMO itself, given the same route file, discards them ("will not be able
    to depart"); it had run on with those cars gone and SUMO's raw error on the console. The least
    deceleration the check names is the reference: 3 % below it SUMO discards, 3 % above it not."""
    import re

    from nrtraffic import scenario
    from nrtraffic.demand import Demand
    from nrtraffic.sumo.netbuild import sumo_binary

    ov = ["outputs.warmup_s=0", "demand.controlled_share=0"]
    capsys.readouterr()
    assert main(["run", str(CROSS4), "--duration", "40", *sum((["--set", o] for o in ov), []),
                 "--set", "human.decel_mps2=0.1", "--out", str(tmp_path / "r"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    least = float(re.search(r"raise human.decel_mps2 .* to at least ([0-9.]+) m/s", err).group(1))
    assert not (tmp_path / "r").exists()
    b = round(least * factor, 4)
    sc = scenario.load(CROSS4, [*ov, f"human.decel_mps2={b}"])
    routes = tmp_path / "r.rou.xml"
    Demand.of(sc, None, 40.0).write(routes, sc.vehicle.params())
    sumo = subprocess.run([sumo_binary("sumo"), "-n", str(sc.network_path), "-r", str(routes), "--end", "40",
                           "--step-length", "0.1", "--no-step-log"], capture_output=True, text=True)
    discarded = "will not be able to depart" in sumo.stdout + sumo.stderr
    assert discarded == (factor < 1), sumo.stderr[-500:]
    assert main(["run", str(CROSS4), "--duration", "40", *sum((["--set", o] for o in ov), []), "--set",
                 f"human.decel_mps2={b}", "--out", str(tmp_path / "b"), "--no-progress"]) == (2 if factor < 1 else 0)


def test_a_sweep_checks_the_demand_of_every_seed(tmp_path, capsys):
    """A seed whose random arrivals give the run no vehicle is refused (exit 2, naming the seed)
    before any run starts, as the first seed is: it had run with status "ok" and nothing done.
    (cross4 over 3 s: seeds 2, 3 and 4 give one departure each, seed 5 none.)"""
    out = tmp_path / "s"
    assert main(["sweep", str(CROSS4), "--seeds", "2:5", "--duration", "3", "--set", "outputs.warmup_s=0", "--out",
                 str(out), "--no-progress", "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "gives the run no vehicle" in err and "with seed 5" in err and not out.exists()


def test_a_sweep_writes_nothing_through_a_link_in_its_folder(tmp_path, capsys):
    """A sweep folder whose ``runs/``, or one of whose run folders, is a link elsewhere is refused
    (exit 2, naming the link) before anything is written: its runs had gone where the link points,
    and a linked run folder failed with a traceback (rmtree on a link), leaving temporary folders."""
    flags = ["--seeds", "1", "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress", "--workers", "1"]
    out = tmp_path / "study"
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags]) == 0
    run = next((out / "runs").glob("*/seed1/nrtraffic"))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "mine.txt").write_text("mine")
    link_run = run.parent / "sumo_priority"
    link_run.symlink_to(elsewhere, target_is_directory=True)
    capsys.readouterr()
    assert main(["sweep", str(CROSS4), "--out", str(out), *flags, "--baseline", "priority"]) == 2
    assert f"{link_run} is a link" in capsys.readouterr().err
    link_run.unlink()
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / "runs").symlink_to(elsewhere, target_is_directory=True)
    assert main(["sweep", str(CROSS4), "--out", str(linked), *flags]) == 2
    assert "runs is a link" in capsys.readouterr().err
    assert sorted(p.name for p in elsewhere.iterdir()) == ["mine.txt"]
    assert sorted(p.name for p in linked.iterdir()) == ["runs"]


def test_nothing_is_written_into_another_runs_folder(tmp_path, capsys):
    """``--out`` inside a finished run's folder (its files would be taken for that run's, and a
    ``--force`` there would remove them) is refused with exit 2 by run, baseline, replay and sweep,
    as compare refuses it; nothing is made there."""
    run = tmp_path / "run"
    shutil.copytree(ROOT / "tests" / "golden" / "cross4", run)
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    short = ["--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]
    for argv in (["run", str(CROSS4), "--out", str(run / "inner"), *short],
                 ["baseline", str(CROSS4), "--junction", "priority", "--out", str(run / "sumo" / "b"), *short],
                 ["replay", str(run), "--out", str(tmp_path / "x" / ".." / "run" / "r"), "--no-progress"],
                 ["sweep", str(CROSS4), "--seeds", "1", "--out", str(run / "s"), *short]):
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert "lies in the run directory" in err or "would overwrite the run it verifies" in err, (argv, err)
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before
    # a path that only passes through the run's folder (run/../new) leads outside it: taken
    assert main(["run", str(CROSS4), "--out", f"{run}/../new", *short]) == 0
    assert (tmp_path / "new" / "summary.json").is_file()


def test_force_keeps_a_users_file_named_like_one_the_run_did_not_write(tmp_path, capsys):
    """A finished run without fcd.xml or arterial.png lists only what it wrote: a file of the user's
    put into its folder later under one of those names is not taken for the run's. ``--force``
    refuses to write over it (exit 2) and keeps it; without it, the run is replaced."""
    base = ["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]
    out = tmp_path / "o"
    assert main(base + ["--out", str(out)]) == 0
    created = set(json.loads((out / "manifest.json").read_text())["created"])
    assert {"summary.json", "vehicles.csv", "sumo"} <= created
    assert not any((out / n).exists() is False for n in created)  # every name listed was written
    assert "fcd.xml" not in created and "arterial.png" not in created
    (out / "fcd.xml").write_text("mine")
    capsys.readouterr()
    assert main(base + ["--out", str(out), "--force"]) == 2
    assert capsys.readouterr().err.count("fcd.xml") == 1  # (named once)
    assert (out / "fcd.xml").read_text() == "mine"
    (out / "fcd.xml").rename(tmp_path / "fcd.xml")
    (out / "arterial.png").write_text("mine too")
    assert main(base + ["--out", str(out), "--force"]) == 2
    assert (out / "arterial.png").read_text() == "mine too"


def test_force_refuses_a_link_to_nothing_under_a_name_the_run_writes(tmp_path, capsys):
    """A link to a file that does not exist, put into a finished run's folder under a name the run
    writes (fcd.xml, which this run did not write): ``--force`` had taken the name for free and
    written the file where the link points, outside the run folder. Refused (exit 2), naming it;
    nothing is created at the link's target."""
    base = ["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]
    out = tmp_path / "o"
    assert main(base + ["--out", str(out)]) == 0
    target = tmp_path / "elsewhere" / "x.xml"
    target.parent.mkdir()
    (out / "fcd.xml").symlink_to(target)
    capsys.readouterr()
    assert main(base + ["--set", "outputs.sumo_fcd=true", "--out", str(out), "--force"]) == 2
    assert "fcd.xml" in capsys.readouterr().err
    assert not target.exists() and (out / "fcd.xml").is_symlink()


def test_a_run_killed_outright_can_be_replaced_with_force(tmp_path):
    """A run killed with SIGKILL as soon as its summary says "running" (no checkpoint, no clean-up):
    its manifest already lists the files it writes while it simulates, so ``--force`` replaces it;
    a file of the user's beside it stays. Its tables are listed only as a checkpoint writes them: a
    ``vehicles.csv`` of the user's put there afterwards is never taken for the run's (``--force``
    had replaced it)."""
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "runners.cli", "run", str(CROSS4), "--out", str(out), "--no-progress",
           "--duration", "300"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (out / "summary.json").is_file() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert json.loads((out / "summary.json").read_text())["status"] == "running"
    # its manifest names only what such a run writes while it simulates: no fcd.xml (not asked
    # for), no figure or report (they come at the end, and are listed once written)
    planned = set(json.loads((out / "manifest.json").read_text())["created"])
    assert {"summary.json", "tripinfo.xml"} <= planned
    assert not planned & {"fcd.xml", "arterial.png", "delays.png", "report.html"}
    # (killed before its first checkpoint, 10 s of wall time in: its tables not yet named)
    assert not (out / "vehicles.csv").exists()
    assert not planned & {"vehicles.csv", "approaches.csv", "movements.csv"}
    (out / "vehicles.csv").write_text("mine")
    assert main(["run", str(CROSS4), "--out", str(out), "--no-progress", "--duration", "4", "--force"]) == 2
    assert (out / "vehicles.csv").read_text() == "mine"
    (out / "vehicles.csv").unlink()
    (out / "notes.txt").write_text("mine")
    assert main(["run", str(CROSS4), "--out", str(out), "--no-progress", "--duration", "4", "--force",
                 "--set", "outputs.warmup_s=0"]) == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"


def test_an_approach_that_starts_inside_the_merging_zone_is_refused_naming_the_size_that_fits(tmp_path, capsys):
    """cross4_short's arms are 50 m from the centre: a 120 m merging zone swallows their start. The
    message names the approach, where it starts, and the largest merging zone that fits (it said
    only that the path "does not enter the merging zone from outside")."""
    out = tmp_path / "o"
    assert main(["run", str(SCENARIOS / "cross4_short"), "--set", "zones.merging_zone_m=120", "--set",
                 "outputs.warmup_s=0", "--duration", "5", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "its approach E_in starts 50.0 m from junction C's centre, inside the merging zone" in err
    assert "set zones.merging_zone_m to at most 98 m" in err and not (out / "summary.json").exists()


def test_a_run_without_a_duration_ends_when_every_vehicle_stands_still(tmp_path, capsys):
    """``--duration 0`` runs until every vehicle has left. A SUMO-driven vehicle that stops for good
    outside every control zone (speed profile to 0 m/s) held it for ever (past a simulated week):
    now the watchdog ends it after ``outputs.stall_s`` of standstill, as a gridlock naming the
    vehicle, and an automated car that did cross is in its table."""
    extra = ('\n[[vehicles]]\nid = "parked"\napproach = "N_in.straight"\ndepart_s = 1.0\ncontrolled = false\n'
             'speed_profile = [[0.0, 13.0], [5.0, 0.0]]\n'
             '\n[[vehicles]]\nid = "a1"\napproach = "E_in.straight"\ndepart_s = 2.0\n')
    d = _scenario_copy(tmp_path, "rate_veh_h = 400.0", "rate_veh_h = 0.0\nend_s = 1.0", extra)
    out = tmp_path / "o"
    assert main(["run", str(d), "--out", str(out), "--duration", "0", "--no-progress", "--set", "outputs.stall_s=60",
                 "--set", "outputs.warmup_s=0"]) == 1
    assert "every vehicle in the network has stood still for 60 s (outputs.stall_s = 60): parked" in capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "gridlock" and s["sim_time_s"] < 200
    veh = pd.read_csv(out / "vehicles.csv").set_index("vehicle_id")
    assert veh.loc["a1", "status"] == "released"  # (crossed, and left to SUMO after its merging zone)


@pytest.mark.parametrize("table, line", [("vehicles.csv", "garbage,,"), ("movements.csv", "a,b"),
                                         ("approaches.csv", "a,b")])
def test_a_damaged_table_is_a_difference_for_replay_and_an_error_for_compare(table, line, tmp_path, capsys):
    """A run table without its key columns (edited or damaged) is a difference of the replay's
    comparison, and ``compare`` refuses the run (exit 2) naming the file; both had ended in a
    traceback (KeyError, ValueError)."""
    import shutil

    from runners.replay import compare_runs

    golden = ROOT / "tests" / "golden" / "cross4"
    run = tmp_path / "run"
    shutil.copytree(golden, run)
    (run / table).write_text(line + "\n")
    diffs = compare_runs(golden, run)
    assert any(d.where == table for d in diffs)
    assert main(["compare", str(golden), str(run), "--out", str(tmp_path / "cmp")]) == 2
    assert f"{table} has no column" in capsys.readouterr().err and not (tmp_path / "cmp").exists()


def test_checks_after_the_network_is_read_leave_no_folder(tmp_path, capsys):
    """A scenario refused once its junction is built (a merging zone its paths do not reach, a
    turn too tight), and a baseline of a scenario without a junction, exit 2 and leave no folder
    (the run's folder, with the folders made for it, had stayed)."""
    deep = tmp_path / "a" / "b"
    for flags in (["--set", "zones.merging_zone_m=1"], ["--set", "controller.steer_max_rad=0.05"]):
        assert main(["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", *flags, "--out", str(deep),
                     "--no-progress"]) == 2
        assert "scenario error" in capsys.readouterr().err
        assert not (tmp_path / "a").exists()
    assert main(["baseline", str(SCENARIOS / "paper_cbf"), "--junction", "priority", "--out", str(deep),
                 "--no-progress"]) == 2
    assert "baselines need a scenario with a [junction]" in capsys.readouterr().err and not (tmp_path / "a").exists()


def test_bench_write_is_checked_before_the_benchmark_runs(tmp_path, capsys):
    """``bench --write`` to a folder, a name ending in a slash or a missing folder exits 2 at once
    (it had run the whole benchmark first, then failed with exit 1); so does ``schema --write``
    with a trailing slash (it wrote a file of that name)."""
    for where in (str(tmp_path), str(tmp_path / "x.md") + "/", str(tmp_path / "no" / "x.md")):
        for cmd in (["bench", "--quick"], ["schema"]):
            assert main([*cmd, "--write", where]) == 2
            assert f"--write {where}" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_write_never_replaces_a_users_file(tmp_path, capsys):
    """``bench --write`` and ``schema --write`` over a file that is not an earlier output of the
    same command (a file of the user's), or through a link, or to a name with a line break: exit 2
    before any work, the file untouched (bench had overwritten it). An earlier output is replaced."""
    mine = tmp_path / "notes.md"
    mine.write_text("my notes\n")
    link = tmp_path / "link.md"
    link.symlink_to(mine)
    for where in (mine, link):
        for cmd in (["bench", "--quick"], ["schema"], ["schema", "--markdown"]):
            assert main([*cmd, "--write", str(where)]) == 2
            assert "is not an earlier output of this command" in capsys.readouterr().err
    assert main(["bench", "--quick", "--write", f"{tmp_path}/a\nb.md"]) == 2
    assert "line break" in capsys.readouterr().err
    assert mine.read_text() == "my notes\n" and sorted(p.name for p in tmp_path.iterdir()) == ["link.md", "notes.md"]
    for flags in ([], ["--markdown"]):  # (its own earlier output is written again)
        out = tmp_path / f"schema{len(flags)}"
        assert main(["schema", *flags, "--write", str(out)]) == 0
        assert main(["schema", *flags, "--write", str(out)]) == 0


def test_robustness_checks_its_workers_and_refuses_another_sweeps_folder(tmp_path, capsys):
    """``robustness`` takes ``--workers`` as ``sweep`` does (0 had started a study that never
    ran, 100 a hundred worker processes on two cores), and refuses a folder holding another
    sweep's runs (it had written its own beside them, and would replace their tables)."""
    for workers, message in (("0", "need at least one worker"), ("100000", "a local cluster takes at most")):
        assert main(["robustness", "--out", str(tmp_path / "r"), "--workers", workers, "--no-progress"]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    other = tmp_path / "other"
    (other / "runs" / "base" / "seed1").mkdir(parents=True)
    (other / "manifest.json").write_text(json.dumps({"sweep": 1, "preexisting": [], "created": ["sweep.csv"]}))
    assert main(["robustness", "--out", str(other), "--no-progress"]) == 2
    assert "holds another sweep's runs (runs/base)" in capsys.readouterr().err


def test_a_vehicle_inserted_standing_sets_off_and_crosses(tmp_path):
    """A route file's vehicle with ``departSpeed="0"`` sets off as SUMO's driver would and
    crosses (it had been held at 0 m/s for the whole run, and the run said "ok"); its delay is
    counted against a free flow at the entry speed (it had been -inf)."""
    d = copy_scenario("cross4", tmp_path / "c4")
    (d / "d.rou.xml").write_text('<routes><route id="ws" edges="W_in E_out"/>'
                                 '<vehicle id="v" route="ws" depart="1" departSpeed="0"/></routes>\n')
    out = tmp_path / "o"
    assert main(["run", str(d), "--duration", "60", "--set", 'demand.sumo_routes="d.rou.xml"', "--set",
                 "demand.rate_veh_h=0", "--set", "outputs.warmup_s=0", "--out", str(out), "--no-progress"]) == 0
    v = pd.read_csv(out / "vehicles.csv").set_index("vehicle_id").loc["v"]
    assert v["t_exit_s"] < 60 and 0 <= v["delay_s"] < 10


def test_an_open_ended_run_that_ends_before_its_window_says_so(tmp_path):
    """``--duration 0`` with a warm-up past the run's end: the run says that its measurement
    window is empty (it said nothing, "ok" with no figure measured)."""
    out = tmp_path / "o"
    assert main(["run", str(CROSS4), "--duration", "0", "--set", "outputs.warmup_s=200", "--set", "demand.end_s=30",
                 "--out", str(out), "--no-progress"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["measure_to_s"] < 200 and any("the measurement window is empty" in w for w in s["warnings"])


def test_a_minimal_junction_scenario_is_safe_by_default(tmp_path, capsys):
    """A scenario of a .sumocfg and a junction id, every other key at its default, on cross4's
    network and route file: no collision (with the paper's free terminal speed, the default of a
    plain road, it had 23 in SUMO's check and 40 in the own one). At a junction the terminal speed
    defaults to "fixed", and "free" is refused (exit 2) naming the key."""
    import shutil

    d = tmp_path / "cf"
    d.mkdir()
    for f in ("net.net.xml", "demand.rou.xml"):
        shutil.copy(SCENARIOS / "cross4" / f, d / f)
    (d / "c.sumocfg").write_text('<configuration><input><net-file value="net.net.xml"/>'
                                 '<route-files value="demand.rou.xml"/></input></configuration>\n')
    (d / "scenario.toml").write_text('[scenario]\nname = "cf"\nsumocfg = "c.sumocfg"\n[junction]\nid = "C"\n'
                                     '[outputs]\nwarmup_s = 0.0\n')
    assert main(["run", str(d), "--duration", "0", "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    demanded = len(ET.parse(d / "demand.rou.xml").getroot().findall("vehicle"))  # (a run to the end: every one)
    assert s["vehicles_completed"] == demanded == 258 and s["collisions"] == 0 and s["collisions_geometric"] == 0
    assert 'terminal_speed = "fixed"' in (tmp_path / "o" / "scenario.resolved.toml").read_text()
    assert main(["run", str(d), "--duration", "5", "--set", 'coordinator.terminal_speed="free"', "--out",
                 str(tmp_path / "f"), "--no-progress"]) == 2
    assert 'coordinator.terminal_speed = "free" at a junction' in capsys.readouterr().err


def test_links_do_not_get_past_the_run_and_sweep_guards(tmp_path, capsys):
    """A replay whose run files are links into ``--out`` would overwrite the recording and compare
    it with itself ("matches"); a run into a sweep's runs/ reached through a link wrote there; a
    scale benchmark's figure replaced a .png of the user's beside --write. Each exits 2 now and
    touches nothing."""
    import shutil

    recorded = tmp_path / "O"
    shutil.copytree(ROOT / "tests" / "golden" / "cross4", recorded)
    linked = tmp_path / "R"
    linked.mkdir()
    for f in recorded.iterdir():  # (its network and configuration copied, its results linked)
        if f.name in ("sumo", "scenario.resolved.toml"):
            (shutil.copytree if f.is_dir() else shutil.copy)(f, linked / f.name)
        else:
            (linked / f.name).symlink_to(f)
    before = (recorded / "summary.json").read_bytes()
    assert main(["replay", str(linked), "--out", str(recorded), "--force", "--no-progress"]) == 2
    assert "would overwrite the run it verifies" in capsys.readouterr().err
    assert (recorded / "summary.json").read_bytes() == before
    sweep = tmp_path / "sw"
    (sweep / "runs" / "base").mkdir(parents=True)
    (sweep / "manifest.json").write_text(json.dumps({"sweep": 1, "preexisting": [], "created": ["sweep.csv"]}))
    (tmp_path / "lnk").symlink_to(sweep / "runs")
    assert main(["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", "--out",
                 str(tmp_path / "lnk" / "new"), "--no-progress"]) == 2
    assert "lies in the sweep folder" in capsys.readouterr().err and not (sweep / "runs" / "new").exists()
    (tmp_path / "x.png").write_text("mine")
    assert main(["bench", "--quick", "--scale", "--write", str(tmp_path / "x.md")]) == 2
    assert "x.png, which exists" in capsys.readouterr().err and (tmp_path / "x.png").read_text() == "mine"


def test_scale_bench_replaces_only_its_own_figure(tmp_path, capsys):
    """``bench --scale --write T.md`` draws its figure as T.png. Beside its own earlier table it had
    taken any T.png for its own: a file of the user's was written over, and a link was written
    through (also one to nothing). Now those exit 2 before anything is measured, and nothing is
    touched; the figure it draws is titled in the PNG, by which a later run knows it, and one from
    before the title is known by the table that shows it."""
    from runners.bench import BENCH_TITLES, own_figure, scale_figure

    table = tmp_path / "T.md"
    table.write_text(f"{BENCH_TITLES[1]}\n\n![cost](T.png)\n")
    fig = tmp_path / "T.png"
    fig.write_text("mine")
    target = tmp_path / "elsewhere.png"
    for case in ("text", "link to nothing", "link to a figure"):
        if case != "text":
            fig.unlink()
            fig.symlink_to(target)
        if case == "link to a figure":
            scale_figure([{"at_once": 20.0, "loop_s": 1.0, "vehicle_steps": 1e4, "breakdown": {}, "junctions": 1}],
                         target)
        before = target.read_bytes() if target.exists() else None
        capsys.readouterr()
        assert main(["bench", "--quick", "--scale", "--write", str(table)]) == 2, case
        assert "T.png, which exists" in capsys.readouterr().err
        assert (target.read_bytes() if target.exists() else None) == before, case
    assert fig.is_symlink() and table.read_text().startswith(BENCH_TITLES[1])
    fig.unlink()
    rows = [{"at_once": 20.0, "loop_s": 1.0, "vehicle_steps": 1e4, "breakdown": {"kernel": 0.4}, "junctions": 1}]
    scale_figure(rows, fig)
    from PIL import Image

    with Image.open(fig) as png:  # (the title as a PNG reader sees it)
        assert png.text.get("Title") == "nrtraffic scale benchmark"
    assert own_figure(fig, tmp_path / "other.md")  # (titled: its own wherever its table is)
    untitled = tmp_path / "U.png"
    import matplotlib.pyplot as plt

    plt.figure().savefig(untitled, format="png")
    assert not own_figure(untitled, table)  # (a PNG of someone else's, not shown by the table)
    table.write_text(f"{BENCH_TITLES[1]}\n\n![cost](U.png)\n")
    assert own_figure(untitled, table)


def test_gui_delay_without_gui_is_refused(tmp_path, capsys):
    """``--gui-delay`` without ``--gui`` would do nothing: exit 2 naming both (it ran, exit 0)."""
    assert main(["run", str(CROSS4), "--duration", "5", "--gui-delay", "50", "--out", str(tmp_path / "o"),
                 "--no-progress"]) == 2
    assert "--gui-delay sets the delay of --gui" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_a_flag_and_a_set_of_the_same_setting_are_refused(tmp_path, capsys):
    """``--seed`` with another ``--set scenario.seed``, ``--duration`` with another ``--set
    scenario.duration_s``: the flag won and the setting was dropped without a word; now exit 2, for
    a run, a baseline and the Python API (the same value in both is taken)."""
    import nrtraffic
    from nrtraffic.scenario import ScenarioError

    for cmd in (["run", str(CROSS4)], ["baseline", str(CROSS4), "--junction", "priority"]):
        for flags, named in ((["--seed", "3", "--set", "scenario.seed=4"], "--seed 3 and --set scenario.seed=4"),
                             (["--duration", "5", "--set", "scenario.duration_s=10"],
                              "--duration 5.0 and --set scenario.duration_s=10")):
            assert main([*cmd, *flags, "--out", str(tmp_path / "o"), "--no-progress"]) == 2
            assert named in capsys.readouterr().err and not (tmp_path / "o").exists()
    with pytest.raises(ScenarioError, match="seed=3 and overrides scenario.seed=4 both give it"):  # (its own names)
        nrtraffic.run(CROSS4, seed=3, overrides={"scenario.seed": 4}, out=tmp_path / "a")
    with pytest.raises(ScenarioError, match="allow_outside='no': give True or False"):
        nrtraffic.run(CROSS4, duration_s=5, allow_outside="no", out=tmp_path / "b")
    with pytest.raises(ScenarioError, match="report='no': give True or False"):
        nrtraffic.run(CROSS4, duration_s=5, report="no", out=tmp_path / "c")
    from runners.sweep import SweepError

    with pytest.raises(SweepError, match="give the seeds"):  # (bytes had been read as seed 49)
        nrtraffic.sweep(CROSS4, b"1", duration_s=5, out=tmp_path / "d")
    assert not any(tmp_path.iterdir())


def test_compare_replaces_a_link_in_its_out_instead_of_writing_through_it(tmp_path):
    """A link named as one of compare's files in ``--out`` (``--force``) had the comparison written
    to the file it points at, outside ``--out``; the link itself is replaced now."""
    import shutil

    golden = ROOT / "tests" / "golden" / "cross4"
    other = tmp_path / "other"
    shutil.copytree(golden, other)
    (tmp_path / "precious.csv").write_text("mine\n")
    out = tmp_path / "cmp"
    out.mkdir()
    (out / "compare_runs.csv").symlink_to(tmp_path / "precious.csv")
    assert main(["compare", str(golden), str(other), "--out", str(out), "--force"]) == 0
    assert (tmp_path / "precious.csv").read_text() == "mine\n"
    assert not (out / "compare_runs.csv").is_symlink() and (out / "compare_runs.csv").stat().st_size > 5


def test_compare_force_replaces_its_own_files_and_never_the_users(tmp_path, capsys):
    """``compare --force`` replaces an earlier comparison's four files; a file of the user's with one
    of their names (a compare.html of their own) is refused by name, with or without --force, and
    stays. It had been overwritten."""
    golden = ROOT / "tests" / "golden" / "cross4"
    other = tmp_path / "other"
    shutil.copytree(golden, other)
    out = tmp_path / "cmp"
    assert main(["compare", str(golden), str(other), "--out", str(out)]) == 0
    assert main(["compare", str(golden), str(other), "--out", str(out), "--force"]) == 0  # its own: replaced
    for name, text in (("compare.html", "<html>MINE</html>\n"), ("compare_movements.csv", "a,b\n1,2\n")):
        mine = tmp_path / f"mine_{name}"
        mine.mkdir()
        (mine / name).write_text(text)
        capsys.readouterr()
        for force in ([], ["--force"]):
            assert main(["compare", str(golden), str(other), "--out", str(mine), *force]) == 2
            assert f"holds {name}, which no comparison wrote" in capsys.readouterr().err
        assert (mine / name).read_text() == text and sorted(p.name for p in mine.iterdir()) == [name]


@pytest.mark.parametrize("edit, named", [("extra", "a movement given twice or without its name"),
                                         ("twice", "a movement given twice or without its name"),
                                         ("text", "throughput_veh_h holds text"),
                                         ("blank", "a movement without its throughput")])
def test_compare_refuses_a_movements_table_damaged_inside(edit, named, tmp_path, capsys):
    """A movements.csv with its header intact but a row shifted by extra fields, a row repeated, text
    or nothing where the throughput goes: compare had shown it as figures, exit 0."""
    import shutil

    golden = ROOT / "tests" / "golden" / "cross4"
    run = tmp_path / "run"
    shutil.copytree(golden, run)
    lines = (run / "movements.csv").read_text().splitlines()
    first = lines[1].split(",")
    col = lines[0].split(",").index("throughput_veh_h")
    if edit == "extra":
        lines[1] += ",extra,cols"
    elif edit == "twice":
        lines.insert(1, lines[1])
    else:
        first[col] = "abc" if edit == "text" else ""
        lines[1] = ",".join(first)
    (run / "movements.csv").write_text("\n".join(lines) + "\n")
    assert main(["compare", str(golden), str(run), "--out", str(tmp_path / "cmp")]) == 2
    assert named in capsys.readouterr().err and not (tmp_path / "cmp").exists()


def test_compare_refuses_a_summary_without_its_figures(tmp_path, capsys):
    """A summary.json that says "ok" but lacks the figures every finished run writes (edited, or cut
    short by hand): compare refuses it naming what is missing; it had shown "-" for them, exit 0."""
    golden = ROOT / "tests" / "golden" / "cross4"
    run = tmp_path / "run"
    shutil.copytree(golden, run)
    s = json.loads((run / "summary.json").read_text())
    del s["mean_delay_s"], s["throughput_veh_h"]
    (run / "summary.json").write_text(json.dumps(s))
    assert main(["compare", str(golden), str(run), "--out", str(tmp_path / "cmp")]) == 2
    err = capsys.readouterr().err
    assert "summary.json has no throughput_veh_h, mean_delay_s" in err and not (tmp_path / "cmp").exists()


def test_a_run_folder_whose_path_holds_xml_characters_runs(tmp_path):
    """An ``&`` or ``<`` in ``--out`` (a folder name such as ``a&b``): the run goes through, its queue
    detectors write queues.xml, and a replay from that folder matches. The path had been written
    unescaped into the SUMO files, and SUMO stopped at once ("unterminated entity reference"): exit 1."""
    out = tmp_path / "a&b<c>"
    assert main(["run", str(CROSS4), "--duration", "70", "--set", "outputs.warmup_s=0", "--out", str(out),
                 "--no-progress"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "ok" and s["vehicles_completed"] > 0
    assert len(ET.parse(out / "queues.xml").getroot().findall("interval")) > 0
    for j in ("allway_stop",):
        assert main(["baseline", str(CROSS4), "--junction", j, "--duration", "70", "--set", "outputs.warmup_s=0",
                     "--out", str(tmp_path / f"x&{j}"), "--no-progress"]) == 0
    assert main(["replay", str(out), "--no-progress"]) == 0


def test_a_sweep_writes_nothing_outside_its_folder(tmp_path):
    """A sweep on local workers keeps Dask's scratch files (spill space, locks) in its own folder and
    removes them: the system's temporary folder is untouched and none is left in ``--out``. They had
    gone to ``$TMPDIR/dask-scratch-space``, outside the sweep's folder."""
    import os

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    out = tmp_path / "s"
    r = subprocess.run([sys.executable, "-m", "runners.cli", "sweep", str(CROSS4), "--seeds", "1", "--duration", "5",
                        "--set", "outputs.warmup_s=0", "--workers", "1", "--out", str(out), "--no-progress"],
                       cwd=ROOT, env={**os.environ, "TMPDIR": str(tmp)}, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-800:]
    assert list(tmp.iterdir()) == [] and not (out / "jobs").exists()
    assert not any("dask" in p.name for p in out.rglob("*"))


def test_a_quoted_tilde_in_out_is_the_home_folder_for_the_whole_run(tmp_path, monkeypatch, capsys):
    """``--out "~/r1"`` (quoted, so the shell leaves the ~): the whole run goes to the home folder's
    r1, and a file of the user's there is refused as elsewhere. The checks had read it as a folder
    named ~ while SUMO and the table writers read the home folder: a user's tripinfo.xml there was
    overwritten, and the run failed with its files in two places."""
    home = tmp_path / "home"
    (home / "r1").mkdir(parents=True)
    (home / "r1" / "tripinfo.xml").write_text("mine\n")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path)
    short = ["--duration", "30", "--set", "outputs.warmup_s=0", "--no-progress"]
    assert main(["run", str(CROSS4), "--out", "~/r1", *short, "--force"]) == 2
    assert (home / "r1" / "tripinfo.xml").read_text() == "mine\n"
    assert main(["run", str(CROSS4), "--out", "~/r2", *short]) == 0
    assert (home / "r2" / "summary.json").is_file() and not (tmp_path / "~").exists()
    assert main(["compare", str(ROOT / "tests" / "golden" / "cross4"), str(home / "r2"), "--out", "~/c"]) == 0
    assert sorted(p.name for p in (home / "c").iterdir()) == ["compare.html", "compare_approaches.csv",
                                                             "compare_movements.csv", "compare_runs.csv"]
    assert not (tmp_path / "~").exists()


_KILLED_WHILE_DRAWING = """
import os, sys
from nrtraffic import report
def drawing(out, summary=None):
    (out / "delays.png").write_bytes(b"half a figure")
    os._exit(137)  # (killed outright, as by SIGKILL, while it draws)
report.run_report = drawing
from runners.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_run_killed_while_it_draws_its_figures_can_be_replaced_with_force(tmp_path, capsys):
    """A run killed outright while it draws its figures (a half-written delays.png, no final
    manifest): ``--force`` replaces it. Its figures had not been in its manifest, and the folder was
    refused as holding files of the user's."""
    out = tmp_path / "r"
    args = ["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out", str(out), "--no-progress"]
    r = subprocess.run([sys.executable, "-c", _KILLED_WHILE_DRAWING, *args], cwd=ROOT, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 137 and (out / "delays.png").read_bytes() == b"half a figure", r.stderr[-500:]
    assert main([*args, "--force"]) == 0
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"


def test_a_folder_a_run_is_writing_is_refused_to_a_second_run(tmp_path, capsys):
    """While a run writes its folder, a second run into it (with --force too) or a replay into it
    is refused (exit 2, naming the process), and the first run ends "ok" with its own files: the
    second had removed them (--force) and both had said "ok". A lock left by a run killed outright
    (its process gone) is taken over."""
    out = tmp_path / "r"
    long = _start_long_run(out)
    try:
        deadline = time.monotonic() + 120
        while not (out / "summary.json").is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        capsys.readouterr()
        for argv in (["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out", str(out),
                      "--force", "--no-progress"],
                     ["baseline", str(CROSS4), "--junction", "priority", "--duration", "30", "--set",
                      "outputs.warmup_s=0", "--out", str(out), "--force", "--no-progress"],
                     ["replay", str(ROOT / "tests" / "golden" / "cross4"), "--out", str(out), "--force",
                      "--no-progress"]):
            assert main(argv) == 2, argv
            assert f"is being written by another run (process {long.pid})" in capsys.readouterr().err
        assert long.poll() is None and (out / "summary.json").is_file()
    finally:
        long.send_signal(signal.SIGINT)
        long.communicate(timeout=180)
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"  # (stopped by the test)
    stale = tmp_path / "stale"
    stale.mkdir()
    (stale / ".nrtraffic-running").write_text("nrtraffic 999999999 5\n")  # (no such process)
    assert main(["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out", str(stale),
                 "--no-progress"]) == 0
    assert not (stale / ".nrtraffic-running").exists() and not (out / ".nrtraffic-running").exists()


def test_an_out_that_is_a_broken_link_or_a_loop_is_named_as_such(tmp_path, capsys):
    """``--out`` a link to nowhere, or a loop of links: exit 2 saying so (it had said "cannot write
    there: File exists")."""
    (tmp_path / "dangling").symlink_to(tmp_path / "gone")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    for name in ("dangling", "loop"):
        assert main(["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out",
                     str(tmp_path / name), "--no-progress"]) == 2
        assert "which does not exist (or a loop of links)" in capsys.readouterr().err
    assert not (tmp_path / "gone").exists()


def test_a_lock_file_that_is_no_runs_lock_is_never_removed_and_a_stale_one_is_taken_over(tmp_path, capsys):
    """A file of the user's named like the lock (any other content, a link, a folder) is refused by
    name and kept (it had been removed as a stale lock); a lock of a process id that does not exist
    (a huge one had ended in an OverflowError traceback), or of a process id now another program's
    (same id, another start), is taken over."""
    import os

    short = ["--duration", "30", "--set", "outputs.warmup_s=0", "--no-progress"]
    notes = tmp_path / "notes.txt"
    notes.write_text("mine\n")
    cases = {"text": lambda p: p.write_text("my own notes\n"), "number": lambda p: p.write_text("1\n"),
             "link": lambda p: p.symlink_to(notes), "folder": lambda p: p.mkdir()}
    for name, make in cases.items():
        out = tmp_path / name
        out.mkdir()
        make(out / ".nrtraffic-running")
        assert main(["run", str(CROSS4), "--out", str(out), *short]) == 2, name
        assert "which is not a run's lock" in capsys.readouterr().err
        assert os.path.lexists(out / ".nrtraffic-running") and notes.read_text() == "mine\n"
    for name, text in (("huge", "nrtraffic 99999999999 5"), ("reused", f"nrtraffic 1 not-its-start")):
        out = tmp_path / name
        out.mkdir()
        (out / ".nrtraffic-running").write_text(text + "\n")
        assert main(["run", str(CROSS4), "--out", str(out), *short]) == 0, (name, capsys.readouterr().err)
        assert not (out / ".nrtraffic-running").exists()


def test_a_sweep_folder_a_sweep_is_writing_is_refused_to_a_second_sweep(tmp_path, capsys):
    """A second sweep into the folder of a sweep that still runs (--force too) is refused naming its
    process (it had replaced the first one's run folders, which then failed)."""
    out = tmp_path / "s"
    cmd = [sys.executable, "-m", "runners.cli", "sweep", str(CROSS4), "--seeds", "1:3", "--duration", "600",
           "--workers", "1", "--out", str(out), "--no-progress"]
    first = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (out / ".nrtraffic-running").is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        capsys.readouterr()
        assert main(["sweep", str(CROSS4), "--seeds", "1:3", "--duration", "600", "--workers", "1", "--out", str(out),
                     "--force", "--set", "demand.rate_veh_h=300", "--no-progress"]) == 2
        assert f"is being written by another run (process {first.pid})" in capsys.readouterr().err
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=180)
    assert not (out / ".nrtraffic-running").exists()


@pytest.mark.parametrize("given", ["~nosuchuser/x", "${HOME}/x", "o_${HOME}/x"])
def test_an_out_that_sumo_would_read_elsewhere_is_refused(given, tmp_path, monkeypatch, capsys):
    """``--out`` holding ``${NAME}``, or a leading ``~`` that is no home folder here: SUMO reads them
    (an environment variable, a home folder) and had written its outputs there, outside --out,
    over a file of the user's; refused with exit 2 before anything is written."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert main(["run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0", "--out", given,
                 "--no-progress"]) == 2
    assert "SUMO reads ${NAME} in a file name as an environment variable" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_one_vehicle_id_in_two_route_files_names_both_files(tmp_path, capsys):
    """The same vehicle id in two files of ``demand.sumo_routes``: both files are named (the message
    had named the merged file, which is nobody's)."""
    d = tmp_path / "sc"
    d.mkdir()
    shutil.copy(SCENARIOS / "cross4" / "net.net.xml", d / "net.net.xml")
    for name in ("da", "db"):
        (d / f"{name}.rou.xml").write_text('<routes><trip id="dup" depart="1" from="W_in" to="E_out"/></routes>\n')
    (d / "scenario.toml").write_text('[scenario]\nname = "s"\nnetwork = "net.net.xml"\n[junction]\nid = "C"\n'
                                     '[demand]\nsumo_routes = "da.rou.xml,db.rou.xml"\n')
    assert main(["run", str(d / "scenario.toml"), "--duration", "30", "--set", "outputs.warmup_s=0", "--out",
                 str(tmp_path / "o"), "--no-progress"]) == 2
    assert "the vehicle id 'dup' is given in da.rou.xml and in db.rou.xml" in capsys.readouterr().err


def test_a_run_whose_output_reader_has_gone_ends_with_its_own_status(tmp_path):
    """``nrtraffic run ... | (exec 0<&-)``: the reader of stdout closes before the run prints its
    figures. The run's files are its result: exit 0 with a summary that says ok (it had exited 1,
    "cannot write the run's files: Broken pipe", over a run that was ok)."""
    out = tmp_path / "r"
    cmd = [sys.executable, "-m", "runners.cli", "run", str(CROSS4), "--duration", "30", "--set", "outputs.warmup_s=0",
           "--out", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # (the reader goes at once)
    err = proc.stderr.read()
    assert proc.wait(timeout=300) == 0, err
    assert "Broken pipe" not in err and json.loads((out / "summary.json").read_text())["status"] == "ok"


def test_one_setting_given_twice_with_two_values_is_refused(tmp_path, capsys):
    """``--set demand.rate_veh_h=100 --set demand.rate_veh_h=900``: refused naming both values (the
    last had won without a word, where a flag and a --set of one key are refused); the same value
    twice is taken."""
    short = ["--duration", "30", "--set", "outputs.warmup_s=0", "--no-progress"]
    for cmd in (["run", str(CROSS4)], ["sweep", str(CROSS4), "--seeds", "1"]):
        assert main([*cmd, *short, "--set", "demand.rate_veh_h=100", "--set", "demand.rate_veh_h=900",
                     "--out", str(tmp_path / "o")]) == 2
        assert "--set demand.rate_veh_h is given twice (100 and 900)" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    assert main(["run", str(CROSS4), *short, "--set", "demand.rate_veh_h=100", "--set", "demand.rate_veh_h=100",
                 "--out", str(tmp_path / "o")]) == 0


def test_force_refuses_a_sumo_folder_of_the_users_that_became_a_link(tmp_path, capsys):
    """A run's folder whose ``sumo/`` was there before the run (the user's file in it when the run
    was made again there), then replaced by a link to a folder elsewhere: ``--force`` had written
    the run's network, route file and configuration through it, over the user's files of the same
    names. Refused (exit 2), naming it; nothing at the link's target changes."""
    base = ["run", str(CROSS4), "--duration", "5", "--set", "outputs.warmup_s=0", "--no-progress"]
    out = tmp_path / "o"
    assert main(base + ["--out", str(out)]) == 0
    (out / "sumo" / "notes.txt").write_text("mine")
    assert main(base + ["--set", "zones.control_zone_m=300", "--out", str(out), "--force"]) == 0
    assert "sumo" in json.loads((out / "manifest.json").read_text())["preexisting"]
    elsewhere = tmp_path / "elsewhere"
    shutil.move(out / "sumo", elsewhere)
    (out / "sumo").symlink_to(elsewhere)
    before = {p.name: p.read_bytes() for p in elsewhere.iterdir()}
    capsys.readouterr()
    assert main(base + ["--set", "zones.control_zone_m=250", "--out", str(out), "--force"]) == 2
    assert "sumo" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in elsewhere.iterdir()} == before and (out / "sumo").is_symlink()
