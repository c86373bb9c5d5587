"""The registry of committed studies (runners/studies.py) against what is committed: every study's
files, the commands the pages show, and the seeds, controls, grid values and durations of the
committed tables themselves."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pandas as pd
import pytest

from runners import studies
from runners.cli import build_parser
from runners.studies import STUDIES, Study, command, committed, copy_outputs
from runners.sweep import parse_seeds

DOCS = Path(__file__).resolve().parent.parent / "docs"
SWEEPS = [s for s in STUDIES if s.kind == "sweep"]


def _option(argv, name) -> list[str]:
    return [argv[k + 1] for k, a in enumerate(argv) if a == name]


def test_every_committed_study_file_belongs_to_exactly_one_study():
    folders = {p.parent for p in DOCS.rglob("sweep.csv")} | {DOCS / "paper"}
    registered = {DOCS / s.docs for s in STUDIES}
    assert folders == registered, "a docs folder of study results without a registered command, or the reverse"
    for folder in registered:
        files = sorted(p.relative_to(folder) for p in folder.rglob("*") if p.is_file())
        owners = [rel for s in STUDIES if DOCS / s.docs == folder for rel in committed(s)]
        assert sorted(owners) == files, folder  # every file once, none twice


def test_every_command_is_one_the_command_line_takes(tmp_path):
    parser = build_parser()
    for s in STUDIES:
        args = parser.parse_args(command(s, tmp_path / s.name, ["--workers", "2"]))
        assert args.command == s.kind


def _page_commands(page: Path) -> list[tuple[str, ...]]:
    """The nrtraffic commands of a page's shell blocks, continuation lines joined, ``S="..."``
    variables expanded, without ``--out``, ``--workers`` and comments."""
    out = []
    for block in re.findall(r"```sh\n(.*?)```", page.read_text(), flags=re.S):
        text = block.replace("\\\n", " ")
        names = {}
        for line in text.splitlines():
            m = re.match(r'^(\w+)="(.*)"$', line.strip())
            if m:
                names[m.group(1)] = m.group(2)
                continue
            for k, v in names.items():
                line = line.replace(f"${k}", v)
            words = shlex.split(line, comments=True)
            if not words or words[0] != "nrtraffic":
                continue
            kept, skip = [], False
            for w in words[1:]:
                if skip:
                    skip = False
                elif w in ("--out", "--workers"):
                    skip = True
                else:
                    kept.append(w)
            out.append(tuple(kept))
    return out


def test_the_pages_show_the_registered_commands():
    shown = [s for s in STUDIES if s.shown_in]
    assert len(shown) >= 20
    for s in shown:
        assert s.argv in _page_commands(DOCS / s.shown_in), f"{s.name}: not the command docs/{s.shown_in} shows"


@pytest.mark.parametrize("study", SWEEPS, ids=[s.name for s in SWEEPS])
def test_each_sweep_command_made_its_committed_table(study: Study):
    """Seeds, controls, grid keys and values, duration and warm-up, read back from the committed
    sweep.csv (written by the sweep itself). No run of a committed table failed, but for runs the
    watchdog stopped as gridlocks, which are a result (the arterial past its capacity, and a lane
    that starves in mixed traffic past capacity)."""
    name = next((dst for src, dst in study.copy.items() if src == "sweep.csv"), "sweep.csv")
    df = pd.read_csv(DOCS / study.docs / name)
    a = study.argv
    assert set(df["seed"]) == set(parse_seeds(_option(a, "--seeds")[0]))
    baselines = _option(a, "--baseline")
    assert set(df["control"]) == {"nrtraffic", *(baselines[0].split(",") if baselines else [])}
    grid = dict(g.split("=", 1) for g in _option(a, "--grid"))
    assert list(df.columns[:list(df.columns).index("seed")]) == list(grid)
    for key, values in grid.items():
        assert sorted(set(df[key])) == sorted(float(v) for v in values.split(",")), key
    stopped = df[df["status"] != "ok"]
    assert (stopped["status"] == "gridlock").all() and all("Gridlock: " in str(e) for e in stopped["error"])
    assert stopped.empty or study.name in ("bologna_pasubio_arterial", "penetration", "mixed_margin")
    ok = df[df["status"] == "ok"]
    if _option(a, "--duration"):
        assert (ok["sim_time_s"] == float(_option(a, "--duration")[0])).all()
    warmup = [v.split("=")[1] for v in _option(a, "--set") if v.startswith("outputs.warmup_s=")]
    if warmup:
        assert (ok["measure_from_s"] == float(warmup[0])).all()


def test_copy_takes_only_the_committed_files_under_their_names(tmp_path):
    docs = tmp_path / "docs"
    (docs / "study").mkdir(parents=True)
    for f in ("sweep.csv", "sweep.md", "margin_sweep.csv", "margin_sweep.md"):
        (docs / "study" / f).write_text("old")
    out = tmp_path / "out"
    out.mkdir()
    for f in ("sweep.csv", "sweep.md", "runs.txt"):
        (out / f).write_text(f"new {f}")
    main, margin = (next(s for s in STUDIES if s.name == n) for n in ("study", "margin"))
    assert sorted(map(str, copy_outputs(main, out, docs))) == ["sweep.csv", "sweep.md"]
    assert (docs / "study" / "margin_sweep.csv").read_text() == "old"
    assert not (docs / "study" / "runs.txt").exists()
    assert sorted(map(str, copy_outputs(margin, out, docs))) == ["margin_sweep.csv", "margin_sweep.md"]
    assert (docs / "study" / "margin_sweep.csv").read_text() == "new sweep.csv"


def test_a_study_that_fails_leaves_its_files_and_the_command_fails(tmp_path, monkeypatch, capsys):
    docs = tmp_path / "docs"
    (docs / "broken").mkdir(parents=True)
    (docs / "broken" / "sweep.csv").write_text("old")
    monkeypatch.setattr(studies, "DOCS", docs)
    monkeypatch.setattr(studies, "STUDIES", (Study("broken", ("sweep", "sumo_scenarios/no_such_scenario",
                                                              "--seeds", "1"), "broken"),))
    assert studies.main(["--runs", str(tmp_path / "runs")]) == 1
    assert (docs / "broken" / "sweep.csv").read_text() == "old"
    assert "broken: failed (exit 2)" in capsys.readouterr().out


def test_a_study_whose_only_failures_are_gridlocks_is_copied(tmp_path, monkeypatch, capsys):
    """Runs the watchdog stopped are a result of a study (its table says gridlock): the study is
    done and its files are copied. cross4 with 200 s between merging-zone entries on a lane
    gridlocks (tests/test_gridlock.py); SUMO's priority rule on the same seed finishes."""
    docs = tmp_path / "docs"
    (docs / "stuck").mkdir(parents=True)
    (docs / "stuck" / "sweep.csv").write_text("old")
    monkeypatch.setattr(studies, "DOCS", docs)
    monkeypatch.setattr(studies, "STUDIES", (Study("stuck", (
        "sweep", "sumo_scenarios/cross4", "--seeds", "3", "--baseline", "priority", "--duration", "150",
        "--set", "coordinator.min_merge_headway_s=200", "--set", "outputs.stall_s=30",
        "--set", "outputs.warmup_s=0"), "stuck"),))
    assert studies.main(["--runs", str(tmp_path / "runs"), "--", "--workers", "1"]) == 0
    df = pd.read_csv(docs / "stuck" / "sweep.csv").set_index("control")
    assert df.loc["nrtraffic", "status"] == "gridlock" and df.loc["priority", "status"] == "ok"
    assert "stuck: 1 runs stopped as gridlocks" in capsys.readouterr().out


def test_only_a_fresh_table_of_gridlocks_and_finished_runs_counts(tmp_path):
    import time

    from runners.studies import _gridlocks_only

    t0 = time.time() - 60
    for status, n in ((["ok", "gridlock", "gridlock"], 2), (["ok", "gridlock", "failed"], 0), (["ok", "ok"], 0)):
        pd.DataFrame({"status": status}).to_csv(tmp_path / "sweep.csv", index=False)
        assert _gridlocks_only(tmp_path, t0) == n
    pd.DataFrame({"status": ["ok", "gridlock"]}).to_csv(tmp_path / "sweep.csv", index=False)
    assert _gridlocks_only(tmp_path, time.time() + 60) == 0  # (a table of an earlier pass)
    assert _gridlocks_only(tmp_path / "none", t0) == 0


def test_an_unknown_study_is_refused():
    assert studies.main(["--only", "no_such_study", "--dry-run"]) == 2


def test_a_remade_table_agrees_to_the_decimals_it_was_committed_with(tmp_path):
    head = "demand.rate_veh_h,seed,control,status,wall_time_s,run_dir,max_tracking_error_m,vehicles_completed\n"
    old = tmp_path / "old.csv"
    old.write_text(head + "400,1,nrtraffic,ok,3.1,a,0.041,230\n400,2,nrtraffic,ok,3.0,b,0.001,231\n")
    same = tmp_path / "same.csv"  # other wall times and folders, finer decimals, another row order
    same.write_text(head + "400,2,nrtraffic,ok,9.9,y,0.0005,231\n400,1,nrtraffic,ok,7.7,x,0.04061,230\n")
    assert studies.compare_table(old, same) == []
    moved = tmp_path / "moved.csv"
    moved.write_text(head + "400,1,nrtraffic,ok,3.1,a,0.12284,230\n400,2,nrtraffic,ok,3.0,b,0.001,232\n")
    diff = studies.compare_table(old, moved)
    assert [d.split(":")[0] for d in diff] == ["max_tracking_error_m", "vehicles_completed"]
    assert "1 of 2 runs, by up to 0.08184" in diff[0]
    exp = tmp_path / "exp.csv"  # a committed exponent keeps its own resolution
    exp.write_text(head + "400,1,nrtraffic,ok,3.1,a,9e-05,230\n400,2,nrtraffic,ok,3.0,b,0.001,231\n")
    assert studies.compare_table(exp, tmp_path / "exp.csv") == []
    near = tmp_path / "near.csv"
    near.write_text(head + "400,1,nrtraffic,ok,3.1,a,0.000094,230\n400,2,nrtraffic,ok,3.0,b,0.001,231\n")
    assert studies.compare_table(exp, near) == []
    near.write_text(head + "400,1,nrtraffic,ok,3.1,a,0.0001,230\n400,2,nrtraffic,ok,3.0,b,0.001,231\n")
    assert studies.compare_table(exp, near)[0].startswith("max_tracking_error_m: 1 of 2 runs")
    fewer = tmp_path / "fewer.csv"
    fewer.write_text(head + "400,1,nrtraffic,ok,3.1,a,0.041,230\n")
    assert studies.compare_table(old, fewer)[0].startswith("runs: 2 committed, 1 re-made")
