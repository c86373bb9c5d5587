"""Every study committed under ``docs/``, with the command that makes it, run again in one go.

``python -m runners.studies`` (``make studies``) runs each study's command into ``runs/studies/``
(a sweep resumes where it stopped, as ``nrtraffic sweep`` does) and, when it succeeds (a sweep whose
only unfinished runs stopped as gridlocks has), copies its tables and figures over the committed ones: exactly the files its ``docs/`` folder holds, nothing
else. A study that fails leaves its committed files as they are, the others go on, and the command
exits with status 1. Options after ``--`` go to every sweep (``--workers N``, ``--scheduler
ADDRESS`` or ``--cluster slurm ...``; the default is ``--workers 2``).

``--list`` shows each study, where it is committed, its command and what its committed runs cost
(the sum of their own wall times in its ``sweep.csv``: the work to do, not the wall time on N
workers). ``--check`` re-makes studies and compares each sweep's table with the committed one
(:func:`compare_table`) instead of copying. The prose and the tables in the pages that quote a
study are read again by hand: this only re-makes the files.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"


@dataclass(frozen=True)
class Study:
    """One committed study: ``argv``, the ``nrtraffic`` command without ``--out`` and the worker
    options; ``docs``, its folder under ``docs/``; ``copy``, file written -> file committed where
    the names differ (default: every file of the folder, under its own name, that the command
    wrote); ``shown_in``, the page whose code block gives the command (None where the page says it
    in words, e.g. "the same for tee3")."""

    name: str
    argv: tuple[str, ...]
    docs: str
    copy: dict = field(default_factory=dict)
    shown_in: str | None = None

    @property
    def kind(self) -> str:
        return self.argv[0]


def _sweep(scenario: str, *args: str) -> tuple[str, ...]:
    return ("sweep", f"sumo_scenarios/{scenario}", *args)


_STUDY = ("--seeds", "1:20", "--grid", "demand.rate_veh_h=200,400,600", "--baseline",
          "traffic_light,priority,allway_stop", "--duration", "600")
_KNOBS = ("--seeds", "1:5", "--duration", "600", "--set", "demand.rate_veh_h=600")
_CAPACITY = ("--seeds", "1:10", "--grid", "demand.rate_veh_h=200,400,600,800,1000,1200,1600", "--baseline",
             "traffic_light,allway_stop,priority", "--duration", "900", "--set", "outputs.warmup_s=120")
_PENETRATION = ("--seeds", "1:10", "--grid", "demand.controlled_share=0,0.1,0.25,0.5,0.75,0.9,1", "--grid",
                "demand.rate_veh_h=400,600", "--baseline", "traffic_light,priority,allway_stop", "--duration", "600")
_MIXED_MARGIN = ("--seeds", "1:10", "--grid", "demand.controlled_share=0.25,0.5,0.75,0.9", "--grid",
                 "coordinator.conflict_margin_s=0.3,0.5,1.0", "--set", "demand.rate_veh_h=600", "--baseline",
                 "allway_stop", "--duration", "600")
_SMALL = ("--seeds", "1:3", "--baseline", "traffic_light,priority,allway_stop", "--duration", "600")
_REAL = ("--seeds", "1:10", "--grid", "demand.scale=1,1.5", "--set", "demand.depart_offset_s=30", "--baseline",
         "as_is,actuated,traffic_light,priority,allway_stop")
_HOUR = ("--seeds", "1:3", "--duration", "3900")


def _as(prefix: str) -> dict:
    return {"sweep.csv": f"{prefix}.csv", "sweep.md": f"{prefix}.md"}


STUDIES: tuple[Study, ...] = (
    Study("study", _sweep("cross4", *_STUDY), "study", shown_in="studies.md"),
    Study("margin", _sweep("cross4", "--seeds", "1:5", "--grid", "coordinator.conflict_margin_s=0.5,1.0,2.0",
                           "--set", "demand.rate_veh_h=600", "--duration", "600"), "study",
          _as("margin_sweep"), "junction-control.md"),
    Study("knobs_fifo", _sweep("cross4", *_KNOBS, "--set", 'coordinator.policy="fifo"'), "study",
          _as("sequencing_fifo"), "junction-control.md"),
    Study("knobs_window", _sweep("cross4", *_KNOBS, "--grid", "coordinator.batch_window_s=0,1.5,3,6", "--set",
                                 "coordinator.max_passed=3"), "study", _as("sequencing_window"), "junction-control.md"),
    Study("knobs_cap", _sweep("cross4", *_KNOBS, "--grid", "coordinator.max_passed=0,1,8", "--set",
                              "coordinator.batch_window_s=3"), "study", _as("sequencing_cap"), "junction-control.md"),
    Study("study_tee3", _sweep("tee3", *_STUDY), "study_tee3"),
    Study("capacity_cross4", _sweep("cross4", *_CAPACITY), "capacity/cross4", shown_in="capacity/README.md"),
    Study("capacity_tee3", _sweep("tee3", *_CAPACITY), "capacity/tee3"),
    Study("capacity_short", _sweep("cross4_short", "--seeds", "1:10", "--grid", "demand.rate_veh_h=200,400,600",
                                   "--baseline", "traffic_light,allway_stop,priority", "--duration", "600"),
          "capacity/cross4_short", shown_in="capacity/README.md"),
    Study("penetration", _sweep("cross4", *_PENETRATION), "penetration", shown_in="mixed-traffic.md"),
    Study("penetration_tee3", _sweep("tee3", *_PENETRATION), "penetration_tee3"),
    Study("mixed_margin", _sweep("cross4", *_MIXED_MARGIN), "mixed_margin_cross4", shown_in="mixed-traffic.md"),
    Study("mixed_margin_tee3", _sweep("tee3", *_MIXED_MARGIN), "mixed_margin_tee3"),
    Study("robustness", ("robustness",), "robustness", shown_in="mixed-traffic.md"),
    Study("plant_step_cross4", _sweep("cross4", "--seeds", "1:5", "--grid", "controller.plant_step_s=0.005,0.01",
                                      "--grid", "demand.rate_veh_h=400,1000", "--duration", "600"),
          "plant_step_cross4", shown_in="performance.md"),
    Study("cross4_2lane", _sweep("cross4_2lane", *_SMALL), "cross4_2lane", shown_in="real-networks.md"),
    Study("station_mill", _sweep("station_mill", *_SMALL), "station_mill", shown_in="real-networks.md"),
    Study("corridor3", _sweep("corridor3", "--seeds", "1:3", "--baseline",
                              "traffic_light,traffic_light_coordinated,priority,allway_stop", "--duration", "600"),
          "corridor3", shown_in="real-networks.md"),
    Study("bologna_pasubio", _sweep("bologna_pasubio", *_REAL), "real/bologna_pasubio", shown_in="real/README.md"),
    Study("bologna_pasubio_arterial", _sweep("bologna_pasubio_arterial", *_REAL), "real/bologna_pasubio_arterial",
          shown_in="real/README.md"),
    Study("bologna_acosta", _sweep("bologna_acosta", *_REAL), "real/bologna_acosta", shown_in="real/README.md"),
    Study("grid4", _sweep("grid4", "--seeds", "1:10", "--baseline", "as_is,actuated,traffic_light,priority,allway_stop"),
          "real/grid4", shown_in="real/README.md"),
    Study("grid4_high", _sweep("grid4", "--seeds", "1:5", "--baseline", "as_is,actuated,traffic_light", "--set",
                               'demand.sumo_routes="demand_high.rou.xml"'), "real/grid4_high", shown_in="real/README.md"),
    Study("acosta_hour", _sweep("bologna_acosta", *_HOUR, "--set", "demand.depart_offset_s=30", "--baseline",
                                "as_is,actuated"), "real/hour/bologna_acosta", shown_in="real/README.md"),
    Study("pasubio_hour", _sweep("bologna_pasubio", *_HOUR, "--set", "demand.depart_offset_s=30", "--baseline",
                                 "as_is,actuated"), "real/hour/bologna_pasubio"),
    Study("arterial_hour", _sweep("bologna_pasubio_arterial", *_HOUR, "--set", "demand.depart_offset_s=30",
                                  "--baseline", "as_is,actuated"), "real/hour/bologna_pasubio_arterial"),
    Study("grid4_hour", _sweep("grid4", *_HOUR, "--baseline", "as_is,actuated"), "real/hour/grid4"),
    Study("paper", ("paper", "all"), "paper", shown_in="paper.md"),
)


def committed(study: Study, docs: Path | None = None) -> list[Path]:
    """The study's committed files, relative to its folder (the files of the folder that are not
    another study's under a name of its own)."""
    folder = (docs or DOCS) / study.docs
    theirs = {dst for s in STUDIES if s.docs == study.docs and s is not study for dst in s.copy.values()}
    mine = set(study.copy.values())
    out = []
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = f.relative_to(folder)
        if str(rel) in mine or (not study.copy and str(rel) not in theirs):
            out.append(rel)
    return out


def copy_outputs(study: Study, out: Path, docs: Path | None = None) -> list[Path]:
    """Copy what ``out`` (the study's output folder) holds of its committed files over them;
    returns the files copied. A committed file the command did not write is left as it is."""
    docs = docs or DOCS
    copied = []
    for rel, src in _written(study, out, docs):
        if src.is_file():
            shutil.copyfile(src, docs / study.docs / rel)
            copied.append(rel)
    return copied


def _written(study: Study, out: Path, docs: Path | None = None) -> list[tuple[Path, Path]]:
    """Each committed file of the study, with the file of ``out`` its command writes for it."""
    back = {dst: src for src, dst in study.copy.items()}
    return [(rel, out / back.get(str(rel), str(rel))) for rel in committed(study, docs)]


# figures of a run that are not results: how long it took, and where it was written
_NOT_RESULTS = ("wall_time", "real_time_factor", "run_dir")


def _last_decimal(text: str) -> int:
    """The power of ten of a number's last written digit: -3 for "0.041", -5 for "9e-05", 0 for
    "230" (0 for an empty cell)."""
    from decimal import Decimal, InvalidOperation

    try:
        return int(Decimal(text).as_tuple().exponent) if text else 0
    except (InvalidOperation, TypeError, ValueError):
        return 0


def compare_table(committed_csv: Path, remade_csv: Path) -> list[str]:
    """The figures of a re-made ``sweep.csv`` that differ from the committed one: one line per
    column, with the runs that differ and the largest difference; empty when they agree. Runs are
    matched by their grid values, seed and control; wall times and run folders are left out. A
    number agrees when it is within half a unit of the last decimal the committed table wrote it
    with (a table written at a finer resolution since then still agrees)."""
    import numpy as np
    import pandas as pd

    old_text = pd.read_csv(committed_csv, dtype=str, keep_default_na=False)
    old, new = pd.read_csv(committed_csv), pd.read_csv(remade_csv)
    keys = list(old.columns[:list(old.columns).index("control") + 1])
    if sorted(map(tuple, old[keys].astype(str).values)) != sorted(map(tuple, new[keys].astype(str).values)):
        return [f"runs: {len(old)} committed, {len(new)} re-made, not the same grid points, seeds and controls"]
    order = old.sort_values(keys).index
    old, old_text = old.loc[order].reset_index(drop=True), old_text.loc[order].reset_index(drop=True)
    new = new.sort_values(keys).reset_index(drop=True)
    out = []
    for c in old.columns:
        if c in keys or c.startswith(_NOT_RESULTS):
            continue
        if c not in new:
            out.append(f"{c}: not in the re-made table")
            continue
        x, y = old[c], new[c]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            tol = 0.5 * 10.0 ** old_text[c].map(_last_decimal).to_numpy(float) + 1e-9
            d = np.abs(x.to_numpy(float) - y.to_numpy(float))
            bad = ~((d <= tol) | (x.isna() & y.isna()).to_numpy())
            if bad.any():
                out.append(f"{c}: {int(bad.sum())} of {len(x)} runs, by up to {np.nanmax(np.where(bad, d, np.nan)):.6g}")
        else:
            bad = ~((x.astype(str) == y.astype(str)) | (x.isna() & y.isna()))
            if bad.any():
                out.append(f"{c}: {int(bad.sum())} of {len(x)} runs")
    return out


def cost_s(study: Study, docs: Path | None = None) -> float | None:
    """The sum of the committed runs' own wall times [s] (its sweep.csv), or None without one."""
    import pandas as pd

    f = (docs or DOCS) / study.docs / _table_name(study)
    if not f.is_file():
        return None
    return float(pd.read_csv(f)["wall_time_s"].sum())


def _table_name(study: Study) -> str:
    """The name its sweep.csv is committed under."""
    return next((dst for src, dst in study.copy.items() if src == "sweep.csv"), "sweep.csv")


def _gridlocks_only(out: Path, since: float, study: Study | None = None) -> int:
    """How many runs of the sweep table ``out/sweep.csv`` stopped as gridlocks, where every other
    run of it finished and the sweep wrote it, and every file of ``study``'s to be copied, after
    ``since`` (a wall-clock time; a sweep stopped while it wrote its figures has not); 0
    otherwise."""
    import pandas as pd

    table = out / "sweep.csv"
    files = [src for _, src in _written(study, out)] if study is not None else []
    try:
        if any(f.stat().st_mtime < since for f in (table, *files)):
            return 0
        status = pd.read_csv(table)["status"]
    except (OSError, ValueError, KeyError):
        return 0
    bad = status[status != "ok"]
    return len(bad) if len(bad) and (bad == "gridlock").all() else 0


def command(study: Study, out: Path, where: list[str]) -> list[str]:
    """The full ``nrtraffic`` arguments of a study: its own, ``--out``, and (sweeps and the
    robustness study) where to run."""
    return [*study.argv, "--out", str(out), *(where if study.kind in ("sweep", "robustness") else [])]


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    where = []
    if "--" in argv:
        k = argv.index("--")
        argv, where = argv[:k], argv[k + 1:]
    p = argparse.ArgumentParser(
        prog="python -m runners.studies",
        description="Run every study committed under docs/ again and copy its tables and figures over the committed "
                    "ones (only on success). Options after -- go to every sweep (default: --workers 2).")
    p.add_argument("--only", default=None, metavar="NAME[,NAME...]", help="these studies only (--list names them)")
    p.add_argument("--runs", type=Path, default=ROOT / "runs" / "studies", metavar="DIR",
                   help="where the studies' output folders go (default runs/studies; a sweep resumes there)")
    p.add_argument("--list", action="store_true", help="list the studies, their commands and cost, and exit")
    p.add_argument("--dry-run", action="store_true", help="print the commands without running them")
    p.add_argument("--no-copy", action="store_true", help="run, but leave the committed files as they are")
    p.add_argument("--check", action="store_true",
                   help="run, and compare each sweep's table with the committed one instead of copying (every "
                        "figure but wall times, to the decimals it was committed with); exit 1 where one differs")
    args = p.parse_args(argv)
    chosen = list(STUDIES)
    if args.only:
        names = args.only.split(",")
        unknown = [n for n in names if n not in {s.name for s in STUDIES}]
        if unknown:
            print(f"studies: unknown study {', '.join(unknown)} (--list names them)", file=sys.stderr)
            return 2
        chosen = [s for s in STUDIES if s.name in names]
    where = where or ["--workers", "2"]
    if args.list:
        total = 0.0
        for s in chosen:
            c = cost_s(s)
            total += c or 0.0
            cost = f"{c / 3600:.2f} run-h" if c is not None else "-"
            print(f"{s.name:26s} docs/{s.docs:34s} {cost:>10s}  nrtraffic {shlex.join(s.argv)}")
        print(f"{'total':26s} {'':39s} {total / 3600:.2f} run-h  (the committed runs' own wall times added up)")
        return 0
    failed = []
    t_all = time.perf_counter()
    for k, s in enumerate(chosen, 1):
        out = args.runs / s.name
        cmd = [sys.executable, "-m", "runners.cli", *command(s, out, where)]
        print(f"[{k}/{len(chosen)}] {s.name}: nrtraffic {shlex.join(cmd[3:])}", flush=True)
        if args.dry_run:
            continue
        t0 = time.perf_counter()
        t_wall = time.time()
        code = subprocess.run(cmd, cwd=ROOT).returncode
        took = time.perf_counter() - t0
        stopped = _gridlocks_only(out, t_wall, s) if code == 1 and s.kind == "sweep" else 0
        if stopped:  # (the runs the watchdog stopped are a result of the study: its table says so)
            print(f"[{k}/{len(chosen)}] {s.name}: {stopped} runs stopped as gridlocks, every other run finished",
                  flush=True)
        elif code != 0:
            failed.append(s.name)
            print(f"[{k}/{len(chosen)}] {s.name}: failed (exit {code}) after {took:.0f} s; docs/{s.docs} left as it "
                  "was", flush=True)
            continue
        if args.check:
            table = _table_name(s)
            if not (DOCS / s.docs / table).is_file():
                print(f"[{k}/{len(chosen)}] {s.name}: done in {took:.0f} s; no sweep table to compare", flush=True)
                continue
            diff = compare_table(DOCS / s.docs / table, out / "sweep.csv")
            if diff:
                failed.append(s.name)
            said = (f"the same figures as docs/{s.docs}/{table}" if not diff else
                    f"differs from docs/{s.docs}/{table}:" + "".join(f"\n    {d}" for d in diff))
            print(f"[{k}/{len(chosen)}] {s.name}: done in {took:.0f} s; {said}", flush=True)
            continue
        copied = [] if args.no_copy else copy_outputs(s, out)
        print(f"[{k}/{len(chosen)}] {s.name}: done in {took:.0f} s"
              + ("" if args.no_copy else f", {len(copied)} files copied to docs/{s.docs}"), flush=True)
    if not args.dry_run:
        print(f"studies: {len(chosen) - len(failed)} of {len(chosen)} done in {time.perf_counter() - t_all:.0f} s"
              + (f"; failed or different: {', '.join(failed)} (a failed one resumes when run again)"
                 if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
