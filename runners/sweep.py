"""``nrtraffic sweep``: every (grid point, seed, control) of a study as one run, on Dask distributed.

Layout of the output folder ``DIR``::

    runs/<grid point>/seed<S>/<control>/   one run directory each (control: nrtraffic or a baseline)
    sweep.csv                              one row per run: grid values, seed, control, status, figures
    sweep_summary.csv                      per grid point and control: mean, sd, 95 % CI of each figure
    sweep.md                               the headline figures as a markdown table
    sweep.png, sweep_seeds.png             figures against the grid value, and per-seed distributions
    manifest.json                          what the sweep wrote at the top of DIR (a resume writes only over those)

A run directory is written under a temporary name and renamed when the run has finished, so a run
directory under its final name is always complete; re-running the same command skips those. A
run that fails is retried once; if it fails again it is recorded in ``sweep.csv`` with its error,
what it had finished is kept in ``<control>.failed/``, and the others go on. A run the watchdog
stopped as a gridlock is not retried (it would stop the same way), nor run again by the same
command (:func:`stopped_before`): its row's status is ``gridlock``.

The jobs run on a local cluster of worker processes (one simulation at a time per process:
libsumo holds one simulation per process) or on an existing Dask scheduler given by address.
Workers of an external cluster must see ``DIR`` and the scenario at the same paths (a shared file
system) and have nrtraffic installed.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import logging
import json
import math
import numbers
import os
import re
import shutil
import socket
import sys
import threading
import time
import uuid
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from nrtraffic import _kernel_cache
from nrtraffic.sumo.netbuild import BASELINES as SUMO_BASELINES

NRTRAFFIC = "nrtraffic"
GRIDLOCK = "gridlock"  # the status of a run the watchdog stopped (nrtraffic.watchdog.Gridlock)
BASELINES = SUMO_BASELINES  # SUMO's junction controls a sweep can add as baselines
# the figures of the markdown table and the figures (the CSVs hold every figure of summary.json)
HEADLINE = ("throughput_veh_h", "mean_delay_s", "mean_sumo_time_loss_s", "mean_fuel_ml", "collisions",
            "collisions_geometric")
# summary entries that are not figures of the run
NOT_FIGURES = {"scenario", "seed", "status", "error", "nrtraffic_version", "sumo_version", "control",
               "junction_type", "los"}

MIN_SEEDS_FOR_CI = 5  # the figures draw no confidence interval from fewer seeds
MAX_RUNS = 20000  # a sweep with more runs (a typo in --seeds, say) needs --force
SCHEDULER_TIMEOUT_S = 10.0  # how long to try to reach --scheduler [s]

_ONE_SIMULATION = threading.Lock()  # per worker process, whatever its thread count


class SweepError(ValueError):
    """A sweep's arguments are wrong (bad grid, seed range or baseline)."""


@dataclass(frozen=True)
class Job:
    """One run of a sweep. ``overrides`` are ``section.key=value`` settings (the sweep's ``--set``
    followed by the grid point's)."""

    scenario: str
    overrides: tuple[str, ...]
    point: tuple[tuple[str, str], ...]  # the grid point: (key, value) pairs
    seed: int
    control: str
    duration_s: float | None
    run_dir: str
    fingerprint: str = ""  # digest of the resolved configuration, control, seed and duration
    allow_outside: bool = False  # the scenario may name files outside its folder

    def spec(self) -> dict:
        return {"scenario": self.scenario, "overrides": list(self.overrides), "seed": self.seed,
                "control": self.control, "duration_s": self.duration_s, "run_dir": self.run_dir,
                "fingerprint": self.fingerprint, "allow_outside": self.allow_outside}


FINGERPRINT = "sweep_fingerprint.json"  # in every run directory a sweep writes
# fault injection for the tests: "<seed>:<control>" makes the worker running that job die
FAULT_KILL_WORKER = "NRTRAFFIC_FAULT_KILL_WORKER"


def fingerprint(config: dict, control: str, seed: int, duration_s: float | None) -> str:
    """Digest of everything that decides a run's results: the resolved scenario (every key, defaults
    included), what drives the vehicles, the seed and the simulated time."""
    text = json.dumps({"scenario": config, "control": control, "seed": seed, "duration_s": duration_s},
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _fingerprint_record(run_dir: Path) -> dict:
    """What :func:`write_fingerprint` wrote into ``run_dir`` (empty where it wrote nothing readable)."""
    try:
        rec = json.loads((Path(run_dir) / FINGERPRINT).read_text())
    except (OSError, ValueError):
        return {}
    return rec if isinstance(rec, dict) else {}


def recorded_fingerprint(run_dir: Path) -> str | None:
    return _fingerprint_record(run_dir).get("fingerprint")


def write_fingerprint(run_dir: Path, spec: dict, **extra) -> None:
    """Record the job ``spec`` a run directory holds (nothing for a job without a fingerprint)."""
    if spec.get("fingerprint"):
        (Path(run_dir) / FINGERPRINT).write_text(json.dumps({
            "fingerprint": spec["fingerprint"], "scenario": spec["scenario"], "overrides": spec["overrides"],
            "control": spec["control"], "seed": spec["seed"], "duration_s": spec["duration_s"], **extra},
            indent=1) + "\n")


def failed_dir(run_dir) -> Path:
    """Where what a run that did not finish had written is kept: ``<run_dir>.failed``."""
    return Path(run_dir).parent / f"{Path(run_dir).name}.failed"


# ------------------------------------------------------------------ arguments
MAX_SEEDS = 1_000_000  # seeds of one sweep, even with --force


def parse_seeds(text: str) -> list[int]:
    """``A:B`` (inclusive) or a comma list of integers."""
    try:
        if ":" in text:
            a, b = (int(x) for x in text.split(":"))
        else:
            seeds = [int(x) for x in text.split(",")]  # (an empty item, as in 1,,2, is not a seed)
    except ValueError:
        raise SweepError(f"--seeds {text!r}: expected A:B or a comma list of integers") from None
    if ":" in text:
        for x in (a, b):  # (checked before the list is made: 1:3000000000 would fill the memory)
            if not 0 <= x <= 2**31 - 1:
                raise SweepError(f"--seeds {text!r}: seeds are 0 to 2^31 - 1, got {x}")
        if b - a + 1 > MAX_SEEDS:
            raise SweepError(f"--seeds {text!r}: {b - a + 1} seeds; a sweep takes at most {MAX_SEEDS} "
                             "(split the study into several sweeps)")
        seeds = list(range(a, b + 1))
    if not seeds:
        raise SweepError(f"--seeds {text!r} selects no seed")
    bad = [x for x in seeds if not 0 <= x <= 2**31 - 1]
    if bad:
        raise SweepError(f"--seeds {text!r}: seeds are 0 to 2^31 - 1, got {bad[0]}")
    twice = sorted(x for x, n in Counter(seeds).items() if n > 1)
    if twice:  # (the same run twice would count as two samples: intervals narrower than they are)
        raise SweepError(f"--seeds {text!r}: seed {twice[0]} is given twice; give each seed once")
    return seeds


def parse_grid(items: list[str]) -> list[tuple[str, list[str]]]:
    """``section.key=v1,v2,...`` (repeatable) -> [(key, [values])]; the points are their product
    (their values are checked by :func:`study`, :func:`check_grid`)."""
    grid = []
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        vals, outside = _split_values(item, values)
        if any(c in outside for c in "[]{}"):  # (its commas would split a list or a table into pieces)
            raise SweepError(f"--grid {item!r}: a list or table cannot be a grid value on the command line (its "
                             "commas separate the values); sweep over it with the Python API, "
                             "nrtraffic.sweep(..., grid={'" + key + "': [[...], [...]]}), or one sweep per value")
        if not sep or "." not in key or not any(vals):
            raise SweepError(f"--grid {item!r}: expected SECTION.KEY=V1,V2,...")
        if not all(vals):  # ("400,,600" or "400,": a value left out, not a point to drop in silence)
            raise SweepError(f"--grid {item!r}: an empty value between or after its commas; give each value once, "
                             "e.g. SECTION.KEY=400,600")
        if key in dict(grid):
            raise SweepError(f"--grid {key} is given twice")
        grid.append((key, vals))
    return grid


def _split_values(item: str, values: str) -> tuple[list[str], str]:
    """A ``--grid`` item's values, split at the commas outside quotes (``"a,b.rou.xml"`` is one
    TOML string), each stripped, the quotes kept (the value is read as TOML); and the text outside
    quotes (a quoted file name may hold brackets)."""
    vals, cur, outside, quote = [], [], [], ""
    for c in values:
        if quote:
            quote = "" if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c == ",":
            vals.append("".join(cur).strip())
            cur = []
            continue
        else:
            outside.append(c)
        cur.append(c)
    if quote:
        raise SweepError(f"--grid {item!r}: a quote ({quote}) is not closed; close each quoted value, "
                         'e.g. demand.sumo_routes="a.rou.xml","b.rou.xml"')
    return vals + ["".join(cur).strip()], "".join(outside)


def check_grid(grid: list[tuple[str, list[str]]], duration_s: float | None = None) -> None:
    """Refuse a grid over the seed, over the duration when ``--duration`` (``duration_s``) sets it
    for every run, and a value given twice (``400`` and ``400.0``): one configuration twice would
    count its runs as twice the samples."""
    for key, vals in grid:
        if key in ("scenario.seed", "general.seed"):
            raise SweepError(f"--grid {key}: a sweep's seeds are --seeds (each run's seed); give them there")
        if key in ("scenario.duration_s", "general.duration_s") and duration_s is not None and len(vals) > 1:
            raise SweepError(f"--grid {key} and --duration {duration_s:g}: --duration sets every run's duration, so "
                             "its grid points would be one configuration; give the durations in --grid alone")
        same = _same_values(vals)
        if same:
            raise SweepError(f"--grid {key}: {same[0]} and {same[1]} are the same value; give each once")


def _same_values(vals: list[str]) -> tuple[str, str] | None:
    """Two items of ``vals`` that are one value (``400`` and ``400.0``, or the same text)."""
    seen: dict = {}
    for v in vals:
        try:
            k = float(v)
        except ValueError:
            k = v.strip('"\'')
        if k in seen:
            return seen[k], v
        seen[k] = v
    return None


def parse_baselines(text: str | None) -> list[str]:
    """``--baseline A,B``: SUMO's controls to run beside nrtraffic, each once (None: none)."""
    if text is None:
        return []
    out = [b.strip() for b in text.split(",") if b.strip()]
    if not out:
        raise SweepError(f"--baseline {text!r} names no control: give some of {', '.join(BASELINES)}, or leave "
                         "--baseline out")
    if len(out) < len(text.split(",")):  # ("priority,,actuated": a control left out, not dropped in silence)
        raise SweepError(f"--baseline {text!r}: an empty name between or after its commas; give e.g. "
                         f"--baseline {','.join(out)}")
    for b in out:
        if b not in BASELINES:
            raise SweepError(f"--baseline {b!r}: expected some of {', '.join(BASELINES)}")
    twice = sorted(b for b, n in Counter(out).items() if n > 1)
    if twice:
        raise SweepError(f"--baseline: {twice[0]} is given twice; give each control once")
    return out


def point_name(point: tuple[tuple[str, str], ...]) -> str:
    """Folder name of a grid point: ``key=value+key=value`` (``base`` without a grid). The run
    directories under it are given to SUMO, which reads a comma in a file name as a list
    separator, a colon as host:port and fails on quotes: those, and path separators, become
    ``_``."""
    from runners.api import SUMO_PATH_CHARS

    name = "+".join(f"{k}={v}" for k, v in point) or "base"
    return "".join("_" if c in SUMO_PATH_CHARS or c in "/\\" else c for c in name)


def plan(scenario_path: Path, seeds: list[int], grid: list[tuple[str, list[str]]], controls: list[str], out: Path,
         duration_s: float | None = None, overrides: tuple[str, ...] = (), allow_outside: bool = False) -> list[Job]:
    """Every job of the sweep. Each grid point's configuration is loaded, and its demand built, here
    first, so a bad key, value or demand stops the sweep before any run starts, with the scenario
    loader's message."""
    from nrtraffic import scenario
    from nrtraffic.sumo.network import NetworkError
    from runners.single import check, check_demand

    keys = [k for k, _ in grid]
    jobs, seen = [], []
    for values in itertools.product(*[v for _, v in grid]):
        point = tuple(zip(keys, values))
        ov = tuple(overrides) + tuple(f"{k}={v}" for k, v in point)
        try:
            sc = scenario.load(scenario_path, list(ov), allow_outside=allow_outside)
            check(sc)
            for seed in seeds:  # (every seed's: its random arrivals may give no vehicle, or a speed too high)
                try:
                    check_demand(sc, seed, duration_s)
                except scenario.ScenarioError as exc:  # (the seed named where another seed's demand was right)
                    if seed == seeds[0] or f"seed {seed}" in str(exc):
                        raise
                    raise scenario.ScenarioError(f"seed {seed}: {exc}") from None
        except (scenario.ScenarioError, NetworkError) as exc:
            if not point:
                raise
            raise type(exc)(f"at the grid point {', '.join(f'{k}={v}' for k, v in point)}: {exc}") from None
        if any(c != NRTRAFFIC for c in controls) and not sc.controlled_junctions():
            raise SweepError("--baseline needs a scenario with a [junction]")
        config = sc.to_dict()
        named = point_name(point)
        twin = next((p for p in seen if point_name(p) == named), None) if point else None
        if twin is not None:  # (one folder for two grid points: one of them would fail as "another configuration")
            raise SweepError(f"--grid: the points {', '.join(f'{k}={v}' for k, v in twin)} and "
                             f"{', '.join(f'{k}={v}' for k, v in point)} have one folder name ({named}); give values "
                             "that differ in letters or digits")
        seen.append(point)
        for seed in seeds:
            for control in controls:
                d = Path(out) / "runs" / point_name(point) / f"seed{seed}" / control
                jobs.append(Job(str(Path(scenario_path).resolve()), ov, point, seed, control, duration_s, str(d),
                                fingerprint(config, control, seed, duration_s), allow_outside))
    return jobs


# ------------------------------------------------------------------ one run (on a worker)
def finished(job: Job) -> dict | None:
    """The summary of the job's run directory when it holds a complete, successful run of this job."""
    return None if unfinished(job) else json.loads((Path(job.run_dir) / "summary.json").read_text())


def unfinished(job: Job) -> str | None:
    """Why the job's run directory does not hold a complete, successful run of this job (None when
    it does)."""
    path = Path(job.run_dir) / "summary.json"
    if not path.is_file():
        return "not run"
    try:
        s = json.loads(path.read_text())
    except (OSError, ValueError):
        return "its summary.json cannot be read"
    if s.get("status") != "ok":
        return f"status {s.get('status')!r}: {s.get('error') or 'no error recorded'}"
    if s.get("seed") != job.seed:
        return f"its run has seed {s.get('seed')}, not {job.seed}"
    if job.fingerprint and recorded_fingerprint(job.run_dir) != job.fingerprint:
        return "its run was made with another configuration"
    if job.duration_s and not math.isclose(float(s.get("sim_time_s") or 0.0), job.duration_s, abs_tol=0.5):
        return f"its run simulated {s.get('sim_time_s')} s, not {job.duration_s:g} s"
    return None


def stopped_before(job: Job) -> str | None:
    """The error of an earlier run of this very job (same configuration, control, seed and
    duration: its fingerprint) that the watchdog stopped as a gridlock, where its ``.failed``
    directory holds it; else None. The same command run again takes it as it stands: a retry
    stops the same way. (:func:`run_job` records it only for a gridlock, and a later attempt
    replaces the whole directory.)"""
    rec = _fingerprint_record(failed_dir(job.run_dir)) if job.fingerprint else {}
    return str(rec["gridlock"]) if rec.get("gridlock") and rec.get("fingerprint") == job.fingerprint else None


def run_job(spec: dict) -> dict:
    """Run one job into ``spec['run_dir']`` through a temporary directory renamed on success; on
    failure what was finished goes to ``<run_dir>.failed`` and the exception propagates (so Dask
    retries it), but for a run the watchdog stopped as a gridlock, which is a result that a retry
    repeats. Returns the run's summary (of a gridlock, its status and error only)."""
    from nrtraffic import scenario
    from runners.baseline import run_baseline
    from runners.single import run_scenario

    final = Path(spec["run_dir"])
    final.parent.mkdir(parents=True, exist_ok=True)
    if os.environ.get(FAULT_KILL_WORKER) == f"{spec['seed']}:{spec['control']}":
        os._exit(70)  # fault injection (tests): this job's worker process dies
    tmp = final.parent / f".{final.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    failed = failed_dir(final)
    _kernel_cache.quiet()  # (the sweep said it before it started its workers)
    with _ONE_SIMULATION:
        try:
            sc = scenario.load(spec["scenario"], spec["overrides"], allow_outside=spec.get("allow_outside", False))
            if spec["control"] == NRTRAFFIC:
                res = run_scenario(sc, tmp, seed=spec["seed"], duration_s=spec["duration_s"])
            else:
                res = run_baseline(sc, spec["control"], tmp, seed=spec["seed"], duration_s=spec["duration_s"])
        except BaseException as exc:
            wrote = tmp.exists()
            if wrote:
                shutil.rmtree(failed, ignore_errors=True)
                tmp.rename(failed)
            # a gridlock is a result of the run, not a fault: a retry would stop the same way
            if wrote and isinstance(exc, Exception) and _stopped_as_gridlock(failed):
                error = f"{type(exc).__name__}: {exc}".strip()
                write_fingerprint(failed, spec, gridlock=error)  # (the same command keeps it: stopped_before)
                return {"status": GRIDLOCK, "error": error}
            raise
    write_fingerprint(tmp, spec)
    shutil.rmtree(failed, ignore_errors=True)
    if final.exists():  # an earlier, unfinished or different run of this job
        shutil.rmtree(final)
    tmp.rename(final)
    return res.summary


def check_resume(jobs: list[Job], force: bool = False) -> None:
    """Refuse to resume into run directories made with another configuration (a different
    scenario, ``--set``, grid value or duration), unless ``force``: then they are run again. A run
    directory to be run again that holds files its run did not write (:func:`foreign_files`) is
    refused even with ``force``: it is replaced whole."""
    clash = []
    for j in jobs:
        d = Path(j.run_dir)
        if d.is_dir() and finished(j) is None:
            mine = foreign_files(d)
            if mine:
                shown = ", ".join(mine[:3]) + (f" and {len(mine) - 3} more" if len(mine) > 3 else "")
                raise SweepError(f"{d} holds {shown}, which its run did not write (files of your own?): the run "
                                 "there would be replaced whole; move them out of the sweep's folder")
        if (d / "summary.json").is_file() and recorded_fingerprint(d) != j.fingerprint:
            clash.append(d)
    if clash and not force:
        raise SweepError(
            f"{len(clash)} run director{'y' if len(clash) == 1 else 'ies'} in the output folder "
            f"{'was' if len(clash) == 1 else 'were'} made with a different configuration (or by an older version), "
            f"e.g. {clash[0]}: use another --out, or --force to run them again with this one")


def foreign_files(d: Path) -> list[str]:
    """The files and folders in a sweep's run directory ``d`` that its run did not write (its
    manifest's ``created``, and the sweep's fingerprint): all of them where it has no run
    manifest (files of the user's, or a run of a version without manifests)."""
    from runners.single import MANIFEST, _tree, read_manifest

    m = read_manifest(d)
    ours = (set(m["created"]) if m is not None else set()) | {MANIFEST, FINGERPRINT}
    return sorted(p for p in _tree(d) if p not in ours)


def remove_stale(out: Path) -> list[Path]:
    """Delete the temporary run directories of runs that were killed (``.<control>.tmp-<pid>-...``
    under ``out/runs``), and Dask's scratch folders of sweeps that were (``jobs/.dask-scratch-<pid>-...``),
    whose process is gone; returns them."""
    gone = []
    for d in (*Path(out).glob("runs/**/.*.tmp-*"), *Path(out).glob("jobs/.dask-scratch-*")):
        try:
            pid = int(d.name.split(".tmp-" if ".tmp-" in d.name else ".dask-scratch-")[1].split("-")[0])
        except (IndexError, ValueError):
            continue
        try:
            os.kill(pid, 0)
            continue  # still running (another sweep on the same folder)
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        shutil.rmtree(d, ignore_errors=True)
        gone.append(d)
    return gone


# ------------------------------------------------------------------ the sweep
def sweep_figures(df: pd.DataFrame, summ: pd.DataFrame, out: Path) -> list[str]:
    """A sweep's figures (:func:`figure`, :func:`seed_figure`) in ``out``; returns their names."""
    if not (len(summ) and (summ["runs"] > 0).any()):
        return []
    figure(summ, out / "sweep.png")
    seed_figure(df, out / "sweep_seeds.png")
    if has_humans(df):
        driver_figure(df, summ, out / "drivers.png")
        return ["sweep.png", "drivers.png", "sweep_seeds.png"]
    return ["sweep.png", "sweep_seeds.png"]


sweep_figures.names = ("sweep.png", "sweep_seeds.png", "drivers.png")  # every name it may write
# what write_tables writes beside the figures
TABLE_NAMES = ("sweep.csv", "sweep_summary.csv", "sweep.md", "sweep_approaches.csv", "sweep_movements.csv",
               "report.html")


class Progress:
    """How far a sweep is: a tqdm bar on a terminal; elsewhere (a file, a pipe, CI) a line on
    stderr per finished run, or per 2 % of the runs when there are more than 50::

        sweep: 7/40 runs done (1 failed), 3 min 10 s elapsed, about 15 min left; last: base/seed3/nrtraffic ok

    and, while no run finishes, a line every ``quiet_s`` (60 s)::

        sweep: 0/40 runs done, 1 min 00 s elapsed; runs under way

    (the bar is redrawn each second: its elapsed time moves). ``total`` runs of which ``initial``
    were finished before (a resumed sweep: not counted in the time left); ``enabled`` False:
    nothing at all."""

    def __init__(self, total: int, initial: int, enabled: bool = True, stream=None, quiet_s: float = 60.0):
        self.stream = stream or sys.stderr
        self.total, self.n, self.failed, self.gridlocks, self.initial = total, initial, 0, 0, initial
        self.t0 = self.t_said = time.monotonic()
        self.lines = enabled and not self.stream.isatty()
        self.every = max(1, total // 50)
        self.bar = None
        self._lock, self._stop = threading.Lock(), threading.Event()
        if enabled and not self.lines:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, desc="runs", unit="run", file=self.stream)
        if self.lines:
            self._print(f"sweep: {total - initial} run{'s' if total - initial != 1 else ''} to do"
                        + (f" ({initial} of {total} finished before)" if initial else ""))
        if enabled and initial < total:
            threading.Thread(target=self._while_quiet, args=(quiet_s,), daemon=True).start()

    def _while_quiet(self, quiet_s: float) -> None:
        """Until :meth:`close`: the bar redrawn each second, or a line after ``quiet_s`` without one."""
        while not self._stop.wait(1.0 if self.bar is not None else min(quiet_s, 1.0)):
            with self._lock:
                if self._stop.is_set():
                    return
                if self.bar is not None:
                    self.bar.refresh()
                elif time.monotonic() - self.t_said >= quiet_s:
                    self._print(f"sweep: {self.n}/{self.total} runs done, {_duration(time.monotonic() - self.t0)} "
                                "elapsed; runs under way")

    def done(self, job: Job, failed: bool, gridlock: bool = False) -> None:
        """One more run finished (``failed``: recorded as failed; ``gridlock``: stopped as one)."""
        with self._lock:
            self._done(job, failed, gridlock)

    def _done(self, job: Job, failed: bool, gridlock: bool) -> None:
        self.n += 1
        self.failed += bool(failed)
        self.gridlocks += bool(gridlock)
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(failed=self.failed, **({"gridlocks": self.gridlocks} if self.gridlocks else {}),
                                 remaining=self.total - self.n, refresh=False)
        elif self.lines and (self.n % self.every == 0 or self.n == self.total):
            elapsed = time.monotonic() - self.t0
            left = elapsed / (self.n - self.initial) * (self.total - self.n)
            run = Path(job.run_dir)
            failed_now = f"{self.failed} failed" + (f", {self.gridlocks} of them gridlocks" if self.gridlocks else "")
            self._print(f"sweep: {self.n}/{self.total} runs done ({failed_now}), {_duration(elapsed)} elapsed"
                        + (f", about {_duration(left)} left" if self.n < self.total else "")
                        + f"; last: {run.parent.parent.name}/{run.parent.name}/{run.name} "
                        + ("gridlock" if gridlock else "failed" if failed else "ok"))

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            if self.bar is not None:
                self.bar.close()

    def _print(self, text: str) -> None:
        self.t_said = time.monotonic()
        print(text, file=self.stream, flush=True)


def _duration(s: float) -> str:
    """A wall-clock time for a person: ``42 s``, ``3 min 10 s``, ``1 h 05 min``."""
    s = int(round(s))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def _connect(client_class, address: str):
    """A Dask client of the scheduler at ``address``, or TimeoutError after about
    ``SCHEDULER_TIMEOUT_S``: Dask's own timeout does not bound a server that accepts the connection
    and never answers, so the connection is made in a thread that is waited for no longer."""
    got: dict = {}

    def connect():
        try:
            got["client"] = client_class(address, timeout=SCHEDULER_TIMEOUT_S)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            got["error"] = exc

    thread = threading.Thread(target=connect, daemon=True)  # (a daemon: the process never waits for it)
    thread.start()
    thread.join(SCHEDULER_TIMEOUT_S + 5.0)
    if "client" in got:
        return got["client"]
    if "error" in got:
        raise got["error"]
    raise TimeoutError(f"no answer from {address}")


@contextlib.contextmanager
def _quiet_workers():
    """The worker processes started inside write nothing to the terminal: their standard error is
    the null device. A Ctrl-C at the terminal reaches the whole process group; the sweep stops
    (one line, exit 1) and stops its workers, which would otherwise each print the traceback of
    their own interrupt. (A failed run is a row of the sweep, with its error, not a message.)"""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # (no standard error to speak of)
        yield
        return
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def run_sweep(jobs: list[Job], out: Path, workers: int = 2, scheduler: str | None = None,
              progress: bool = True, figures=sweep_figures, batch=None) -> pd.DataFrame:
    """Run the jobs not yet finished on Dask, then write the tables and figures (``figures``, see
    :func:`write_tables`) from every run directory. Returns ``sweep.csv`` as a DataFrame. ``batch``
    (a :class:`runners.clusters.BatchSpec`) runs the workers as batch jobs of Slurm or PBS, with
    their job script and output in ``out/jobs``."""
    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    errors: dict[str, str] = {}
    gridlocks: set[str] = set()  # (run directories of the runs the watchdog stopped)
    todo = []
    for j in jobs:
        if finished(j) is not None:
            continue
        before = stopped_before(j)
        if before is None:
            todo.append(j)
        else:  # (an earlier pass's gridlock of this very job: a retry would stop the same way)
            errors[j.run_dir] = before
            gridlocks.add(j.run_dir)
    if todo and progress and any(j.control == NRTRAFFIC for j in todo):
        _kernel_cache.announce()  # (the workers compile them; they say nothing themselves)
    if todo:
        withdraw_tables(out, (*TABLE_NAMES, *getattr(figures, "names", ())))
        # a worker that dies (e.g. killed by the OS) is one failure of that job, not three; and a
        # worker holds only the job it runs (saturation 1.0: the others wait at the scheduler), so
        # that its death counts against that job alone, not against one queued behind it
        # Dask's own scratch files (its workers' spill space and locks) in the sweep's folder, removed
        # afterwards: by default they go to the system's temporary folder, outside --out
        jobs_dir = out / "jobs"
        made_jobs = not jobs_dir.exists()
        scratch = jobs_dir / f".dask-scratch-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        scratch.mkdir(parents=True)
        with dask.config.set({"distributed.scheduler.allowed-failures": 1,
                              "distributed.scheduler.worker-saturation": 1.0,
                              "temporary-directory": str(scratch)}), _removed(scratch, jobs_dir if made_jobs else None):
            if scheduler:
                try:
                    client, cluster = _connect(Client, scheduler), None
                except (OSError, TimeoutError, ValueError):
                    raise SweepError(f"--scheduler {scheduler}: no Dask scheduler answered within "
                                     f"{SCHEDULER_TIMEOUT_S:g} s: start it (dask scheduler), or check the address and "
                                     "port") from None
                except MemoryError:  # (a reply that is not Dask's, read as the length of a frame of exabytes)
                    raise SweepError(f"--scheduler {scheduler}: something answers there, but not as a Dask scheduler "
                                     "(its reply is not Dask's protocol): check the port (a Dask scheduler listens on "
                                     "8786 unless told otherwise; 8787 is its dashboard)") from None
                except Exception as exc:  # noqa: BLE001 - no Dask scheduler took the connection
                    if scheduler.startswith("tls://") and "ssl" in str(exc).lower():
                        raise SweepError(f"--scheduler {scheduler}: tls:// needs Dask's TLS settings (certificates, "
                                         "distributed.comm.tls in the Dask configuration): set them, or give the "
                                         "scheduler's tcp:// address") from None
                    raise SweepError(f"--scheduler {scheduler}: no Dask scheduler answers there "
                                     f"({type(exc).__name__}): check the address and port, and that it runs") from None
            elif batch is not None:
                from runners.clusters import make_cluster

                cluster = make_cluster(batch, len(todo), out / "jobs")
                client = Client(cluster)
            else:
                with _quiet_workers():
                    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           dashboard_address=":0", memory_limit=0, local_directory=str(scratch),
                                           silence_logs=logging.CRITICAL)  # (a failed run is a row, not a traceback)
                client = Client(cluster)
            report = None
            try:
                futures = {client.submit(run_job, j.spec(), retries=1, pure=False,
                                         key=f"run-{uuid.uuid4().hex}"): j for j in todo}
                report = Progress(len(jobs), len(jobs) - len(todo), progress)
                for fut in as_completed(futures):
                    job = futures[fut]
                    if fut.status != "finished":
                        exc = fut.exception()
                        errors[job.run_dir] = f"{type(exc).__name__}: {exc}".strip()
                    else:
                        try:
                            got = fut.result()
                        except Exception as exc:  # noqa: BLE001 - (its result lost with its worker): a row
                            got = {"status": "failed", "error": f"{type(exc).__name__}: {exc}".strip()}
                            errors[job.run_dir] = got["error"]
                        if got.get("status") == GRIDLOCK:
                            errors[job.run_dir] = got["error"]
                            gridlocks.add(job.run_dir)
                    report.done(job, job.run_dir in errors, gridlock=job.run_dir in gridlocks)
            finally:
                if report is not None:  # (also when the sweep stops halfway: its lines stop)
                    report.close()
                client.close()
                if cluster is not None:
                    cluster.close()
    df = collect(jobs, errors, gridlocks)
    # (listed before they are written: a sweep killed while it writes them can be resumed)
    record_tables(out, written=False, planned=(*TABLE_NAMES, *getattr(figures, "names", ())))
    write_tables(df, out, figures)
    record_tables(out, written=True)
    return df


def withdraw_tables(out: Path, names) -> list[str]:
    """Remove the tables and figures (``names``) that an earlier pass wrote into ``out`` (its
    manifest lists them), before runs are run or run again: they describe runs about to be
    replaced, and a pass stopped halfway would leave them looking current beside its new runs. The
    pass writes them anew at its end. Returns the names removed."""
    from runners.single import read_manifest

    m = read_manifest(out, sweep=True)
    ours = set(m["created"]) - set(m["preexisting"]) if m is not None else set()
    gone = []
    for n in names:
        if n in ours and ((out / n).is_file() or (out / n).is_symlink()):
            (out / n).unlink()
            gone.append(n)
    return gone


@contextlib.contextmanager
def _removed(scratch: Path, folder: Path | None):
    """Remove ``scratch`` when the block ends (however it ends), and ``folder`` (made for it) if it
    is then empty."""
    try:
        yield
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
        if folder is not None:
            with contextlib.suppress(OSError):
                folder.rmdir()


def collect(jobs: list[Job], errors: dict[str, str] | None = None, gridlocks=frozenset()) -> pd.DataFrame:
    """One row per job from its run directory: grid values, seed, control, status, error, the
    scalar figures of summary.json, and the run directory (``<run_dir>.failed`` for a run that did
    not finish and left one). ``errors``: why this pass's unfinished runs failed, by run
    directory; ``gridlocks``: the run directories of those the watchdog stopped."""
    errors = errors or {}
    rows = []
    for j in jobs:
        row = {k: _number(v) for k, v in j.point}
        row.update(seed=j.seed, control=j.control)
        s = finished(j)
        if s is None:
            row.update(status=GRIDLOCK if j.run_dir in gridlocks else "failed",
                       error=errors.get(j.run_dir) or unfinished(j))
        else:
            row.update(status="ok", error="")
            row.update({k: v for k, v in s.items()
                        if k not in NOT_FIGURES and (v is None or isinstance(v, (int, float)))})
            if len(s.get("junctions") or {}) > 1:  # a corridor: per junction, and along the arterial
                for part in ("junctions", "corridor"):
                    for name, figs in (s.get(part) or {}).items():
                        row.update({f"{part}:{name}:{k}": v for k, v in figs.items()
                                    if v is None or isinstance(v, (int, float))})
        # (a run that did not finish: where what it had finished is kept, where it left anything)
        failed = failed_dir(j.run_dir)
        row["run_dir"] = str(failed if s is None and failed.is_dir() else Path(j.run_dir))
        rows.append(row)
    return pd.DataFrame(rows)


def _stopped_as_gridlock(failed: Path) -> str | None:
    """The watchdog's error where the run whose unfinished directory is ``failed`` stopped as a
    gridlock and recorded it (its summary.json's status ``gridlock``), else None."""
    try:
        s = json.loads((failed / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return str(s.get("error") or "no error recorded") if s.get("status") == GRIDLOCK else None


def _number(v: str):
    try:
        f = float(v)
    except ValueError:
        return v
    return int(f) if f.is_integer() and "." not in v else f


def grid_keys(df: pd.DataFrame) -> list[str]:
    return [c for c in df.columns if "." in c]


def summarize(df: pd.DataFrame) -> pd.DataFrame:
    """Per grid point and control: runs, failed runs, and mean, standard deviation and 95 %
    confidence half-width (Student t) of every figure over the successful runs."""
    from scipy import stats

    keys = grid_keys(df) + ["control"]
    figures = [c for c in df.columns if c not in set(keys) | {"seed", "status", "error", "run_dir"}]
    out = []
    for point, g in df.groupby(keys, sort=True, dropna=False):
        row = dict(zip(keys, point if isinstance(point, tuple) else (point,)))
        ok = g[g["status"] == "ok"]
        row.update(runs=len(ok), failed=int((g["status"] != "ok").sum()))
        for k in figures:
            x = pd.to_numeric(ok[k], errors="coerce").dropna()
            n = len(x)
            sd = float(x.std(ddof=1)) if n > 1 else math.nan
            row[f"{k}_mean"] = float(x.mean()) if n else math.nan
            row[f"{k}_sd"] = sd
            row[f"{k}_ci95"] = float(stats.t.ppf(0.975, n - 1)) * sd / math.sqrt(n) if n > 1 else math.nan
        out.append(row)
    return pd.DataFrame(out)


def write_tables(df: pd.DataFrame, out: Path, figures=sweep_figures) -> None:
    """sweep.csv, sweep_summary.csv, sweep.md (the study table and the safety table), the figures
    that ``figures(df, summary, out)`` draws and report.html with all of them."""
    from nrtraffic.results import to_csv

    to_csv(df, out / "sweep.csv")
    summ = summarize(df)
    to_csv(summ, out / "sweep_summary.csv")
    tables = [table(summ, df)]
    snote, stab = safety_table(df)
    if len(stab):
        tables.append((snote, stab))
    if has_humans(df):
        tables.append(driver_table(summ, df))
    tables += corridor_tables(summ)
    (out / "sweep.md").write_text("\n".join(markdown(n, t) for n, t in tables))
    names = figures(df, summ, out)
    from nrtraffic.report import sweep_report

    sections = []
    side = side_by_side(df)
    if side is not None:
        from nrtraffic.compare import html_grouped

        keys = grid_keys(df)
        for name, (heading, by, side_table) in zip(("sweep_approaches.csv", "sweep_movements.csv"), side):
            to_csv(side_table, out / name)
            figs = [c for c in side_table.columns if c not in set(keys + by + ["control"])]
            grouped = html_grouped(side_table.astype({k: str for k in keys}), keys + by, figs, label="control")
            sections.append((heading, SIDE_NOTE, grouped))
    sweep_report(out, tables, names, title=sweep_title(df, out), sections=sections)


SIDE_NOTE = ("Per grid point, nrtraffic and its baselines side by side: each figure is the mean over the seeds of "
             "the runs' own figures (movements.csv; per approach as nrtraffic compare computes them); a delay or "
             "stops figure over the runs that had such vehicles (runs: how many had a delay); LOS: HCM level of "
             "service of that mean delay. Also in sweep_movements.csv and sweep_approaches.csv.")
SIDE_MOVEMENT = ["vehicles_per_run", "throughput_veh_h", "mean_delay_s", "p95_delay_s", "los", "stops_per_vehicle"]
SIDE_APPROACH = ["throughput_veh_h", "mean_delay_s", "p95_delay_s", "los", "stops_per_vehicle", "mean_queue_veh",
                 "p95_queue_veh", "max_queue_veh"]


def side_by_side(df: pd.DataFrame):
    """A sweep with baselines (two controls or more, one scenario): per grid point, control and
    approach, and per movement, the mean over the seeds of each run's own figures; ``None``
    otherwise. Returns ``[(heading, keys, table)]`` for approaches and movements."""
    from nrtraffic.compare import approach_figures
    from nrtraffic.metrics import level_of_service, run_is_signalised

    ok = df[df["status"] == "ok"]
    if ok["control"].nunique() < 2:
        return None
    keys = grid_keys(df)
    mv, ap, scenarios, signalised = [], [], set(), {}
    for _, r in ok.iterrows():
        d = Path(r["run_dir"])
        try:
            s = json.loads((d / "summary.json").read_text())
            m = pd.read_csv(d / "movements.csv")
            a = approach_figures(d, s)
        except (OSError, ValueError, KeyError):
            continue
        scenarios.add(s.get("scenario"))
        signalised[r["control"]] = run_is_signalised(s, r["control"])
        for t, rows in ((m, mv), (a, ap)):
            t = t.assign(control=r["control"], seed=r["seed"], **{k: r[k] for k in keys})
            if "vehicles" in t:
                t = t.rename(columns={"vehicles": "vehicles_per_run"})
            rows.append(t)
    if len(scenarios) != 1 or not mv:
        return None
    out = []
    for heading, frames, by, figs in (("Approaches, by control", ap, ["approach"], SIDE_APPROACH),
                                      ("Movements, by control", mv, ["approach", "movement"], SIDE_MOVEMENT)):
        long = pd.concat(frames, ignore_index=True)
        figs = [f for f in figs if f in long and f != "los"]
        rows = []
        for point, g in long.groupby(keys + by + ["control"], sort=True, dropna=False):
            row = dict(zip(keys + by + ["control"], point))
            vals = g[figs].apply(pd.to_numeric, errors="coerce")
            row["runs"] = int(vals["mean_delay_s"].notna().sum())
            row.update({f: round(float(vals[f].mean()), 3) if vals[f].notna().any() else None for f in figs})
            delay = row.get("mean_delay_s")
            row["los"] = None if delay is None else level_of_service(delay, signalised[row["control"]])
            rows.append(row)
        table = pd.DataFrame(rows)
        order = {c: i for i, c in enumerate(dict.fromkeys(df["control"]))}  # nrtraffic first, as run
        table = table.sort_values(keys + by + ["control"], key=lambda c: c.map(order) if c.name == "control" else c,
                                  kind="stable").reset_index(drop=True)
        cols = keys + by + ["control", "runs"] + [f for f in (SIDE_APPROACH if by == ["approach"] else SIDE_MOVEMENT)
                                                 if f in table]
        out.append((heading, by, table[cols]))
    return out


def sweep_title(df: pd.DataFrame, out: Path) -> str:
    """The title of a sweep's report: its scenarios (from its runs' summaries; the output folder's
    name when no run finished), seeds, grid keys and controls."""
    names = []
    for d in df.loc[df["status"] == "ok", "run_dir"]:
        try:
            name = json.loads((Path(d) / "summary.json").read_text()).get("scenario")
        except (OSError, ValueError):
            continue
        if name and name not in names:
            names.append(name)
    seeds = sorted(df["seed"].unique()) if len(df) else []
    keys = grid_keys(df)
    return (f"{', '.join(names) or Path(out).name}: sweep"
            + (f", seeds {seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else f", seed {seeds[0]}" if seeds else "")
            + (f" over {', '.join(keys)}" if keys else "")
            + f" ({', '.join(dict.fromkeys(df['control']))})")


def mean_ci(r, k: str, nd: int = 1) -> str:
    """Figure ``k`` of a row of the sweep summary as "mean ± 95 % half-width" with ``nd``
    decimals ("n/a" without runs)."""
    m, c = r.get(f"{k}_mean", math.nan), r.get(f"{k}_ci95", math.nan)
    return "n/a" if m != m else f"{m:.{nd}f}" + ("" if c != c else f" ± {c:.{nd}f}")


def _signalised(r) -> bool:
    """A summary row's junctions are signals (its runs' ``signalised``, else by its control)."""
    from nrtraffic.metrics import is_signalised

    s = r.get("signalised_mean", math.nan)
    return bool(s >= 0.5) if s == s else is_signalised(r["control"])


def table(summ: pd.DataFrame, df: pd.DataFrame) -> tuple[str, pd.DataFrame]:
    """The study table (the one in sweep.md and report.html): a note saying what it shows, and one
    row of formatted cells per grid point and control."""
    from nrtraffic.metrics import level_of_service

    keys = grid_keys(summ)
    seeds = sorted(df["seed"].unique())
    # the gridlocks of each grid point and control
    stuck = Counter(df.loc[df["status"] == GRIDLOCK, keys + ["control"]].itertuples(index=False, name=None))
    served = "served_share_mean" in summ and summ["served_share_mean"].notna().any()
    waiting = "vehicles_waiting_to_enter_mean" in summ
    window = ""
    if "measure_from_s" in df and df["measure_from_s"].notna().any():
        window = (f" The window is {df['measure_from_s'].min():g} s to the end of the run (warm-up excluded): "
                  "throughput counts the vehicles leaving a merging zone in it, per hour (on a corridor, summed "
                  "over its junctions); delay, the vehicles that entered the control zone in it.")
    note = (f"Mean over seeds {seeds[0]}-{seeds[-1]} ({len(seeds)} seeds) with the 95 % confidence half-width; "
             "collisions are totals over the runs. Delay includes the wait to enter the network (SUMO's "
             "departDelay) where the queue backed up to the insertion point. LOS: HCM level of service of the "
             "mean delay (signalised thresholds for the traffic light, unsignalised ones for the others)"
             + ("; served: of the vehicles demanded of the junctions in the window, the share they served "
                "(served_share)" if served else "")
             + ("; not in: demand due by the end that SUMO could not yet insert, per run" if waiting else "")
             + "." + window
             + (" runs (failed): the runs that finished, and those that did not; of these, the gridlocks are the "
                "runs the watchdog stopped (a lane or junction that stood still while vehicles waited: status "
                "`gridlock` in sweep.csv)." if stuck else ""))
    columns = (keys + ["control", "runs (failed)", "throughput [veh/h]"] + (["served"] if served else [])
               + (["not in"] if waiting else [])
               + ["delay [s]", "LOS", "SUMO timeLoss [s]", "fuel [mL/veh]", "collisions: SUMO / own check"])
    rows = []

    def total(r, k):
        m = r.get(f"{k}_mean", math.nan)
        return "n/a" if m != m else f"{round(m * r['runs']):d}"

    for _, r in summ.iterrows():
        extra = []
        if served:
            sh = r.get("served_share_mean", math.nan)
            extra.append("n/a" if sh != sh else f"{100 * sh:.0f} %")
        if waiting:
            extra.append(mean_ci(r, "vehicles_waiting_to_enter", 0))
        delay = r.get("mean_delay_s_mean", math.nan)
        g = stuck[tuple(r[k] for k in keys + ["control"])]
        cells = [f"{r[k]}" for k in keys] + [
            r["control"], f"{r['runs']} ({r['failed']}" + (f"; {g} gridlock{'s' * (g > 1)}" if g else "") + ")", mean_ci(r, "throughput_veh_h", 0), *extra, mean_ci(r, "mean_delay_s"),
            level_of_service(delay, _signalised(r)),
            mean_ci(r, "mean_sumo_time_loss_s"), mean_ci(r, "mean_fuel_ml"),
            f"{total(r, 'collisions')} / {total(r, 'collisions_geometric')}"]
        rows.append(cells)
    return note, pd.DataFrame(rows, columns=columns)


def safety_table(df: pd.DataFrame) -> tuple[str, pd.DataFrame]:
    """The controlled vehicles' safety and tracking figures per grid point (runs with barrier
    figures only: SUMO's controls have none): worst case over the runs, and fallbacks and
    collisions summed over them."""
    ok = df.iloc[0:0]
    if "min_center_distance_m" in df:
        ok = df[(df["status"] == "ok") & df["min_center_distance_m"].notna()]
    keys = [k for k in grid_keys(df) if k in ok]
    note = ("Controlled vehicles, over all runs of a grid point: the largest tracking error and lateral "
            "deviation, the smallest centre distance and bumper gap to the vehicle ahead on the same path "
            "(true states, whatever was measured), and barrier fallbacks and collisions summed.")
    columns = keys + ["control", "runs", "max tracking error [m]", "max lateral deviation [m]",
                      "min centre distance [m]", "min bumper gap [m]", "fallbacks: long / lat",
                      "collisions: SUMO / own check"]
    rows = []
    for point, g in (ok.groupby(keys + ["control"], sort=True) if len(ok) else ()):
        rows.append([*map(str, point), str(len(g)), f"{g['max_tracking_error_m'].max():.3f}",
                     f"{g['max_lateral_dev_m'].max():.3f}", f"{g['min_center_distance_m'].min():.2f}",
                     f"{g['min_bumper_gap_m'].min():.2f}",
                     f"{int(g['cbf_long_fallbacks'].sum())} / {int(g['cbf_lat_fallbacks'].sum())}",
                     f"{int(g['collisions'].sum())} / {int(g['collisions_geometric'].sum())}"])
    return note, pd.DataFrame(rows, columns=columns)


def corridor_tables(summ: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    """A corridor (summary.json ``junctions`` and ``corridor``): per grid point and control, each
    junction's mean delay and level of service, and along the arterial, per direction, the through
    trips' travel time, stops and delay (means over seeds with the 95 % confidence half-width)."""
    from nrtraffic.metrics import level_of_service

    keys = grid_keys(summ)
    out = []

    for part, note, figs in (
            ("junctions", "Per junction of the corridor: the crossings that entered its control zone in the "
             "measurement window and left its merging zone; mean over seeds ± 95 % half-width. LOS: HCM level "
             "of service of the mean delay.",
             [("throughput [veh/h]", "throughput_veh_h", 0), ("delay [s]", "mean_delay_s", 1)]),
            ("corridor", "Along the arterial: the trips straight through every junction, by the road they enter "
             "by; travel time is SUMO's trip duration (insertion to arrival) plus the wait to be inserted, stops "
             "SUMO's waitingCount, delay the crossings' delays added up; mean over seeds ± 95 % half-width.",
             [("trips", "vehicles", 0), ("travel time [s]", "travel_time_s", 1),
              ("stops per vehicle", "stops_per_vehicle", 2), ("delay [s]", "delay_s", 1)])):
        names = sorted({c.split(":")[1] for c in summ.columns if c.startswith(f"{part}:")})
        if not names:
            continue
        label = "junction" if part == "junctions" else "direction (entry road)"
        columns = keys + ["control", label] + [h for h, _, _ in figs] + (["LOS"] if part == "junctions" else [])
        rows = []
        for _, r in summ.iterrows():
            for name in names:
                row = [f"{r[k]}" for k in keys] + [r["control"], name]
                row += [mean_ci(r, f"{part}:{name}:{k}", nd) for _, k, nd in figs]
                if part == "junctions":
                    m = r.get(f"junctions:{name}:mean_delay_s_mean", math.nan)
                    row.append("n/a" if m != m else level_of_service(m, _signalised(r)))
                rows.append(row)
        out.append((note, pd.DataFrame(rows, columns=columns)))
    return out


def has_humans(df: pd.DataFrame) -> bool:
    """Whether any run of the sweep had human drivers (``demand.controlled_share < 1``)."""
    return "human_share" in df and bool((pd.to_numeric(df["human_share"], errors="coerce") > 0).any())


def driver_table(summ: pd.DataFrame, df: pd.DataFrame) -> tuple[str, pd.DataFrame]:
    """Per grid point and control, the figures split by driver (mixed traffic): the share of human
    drivers, the mean delay of each kind (mean over seeds with the 95 % confidence half-width), the
    smallest bumper gap of each kind over the runs, and the colliding pairs by the kinds of the two
    vehicles, summed over the runs (a pair that SUMO's check and the own check both saw counts
    once)."""
    keys = grid_keys(summ)
    ok = df[df["status"] == "ok"]
    note = ("By driver: automated vehicles (controlled by nrtraffic; in SUMO's controls driven by SUMO as "
            "a deterministic driver) and human drivers ([human], SUMO's Krauss driver). Delay: mean over "
            "seeds ± 95 % half-width; gap: smallest bumper gap to the vehicle ahead on the same path, "
            "control zone and merging zone, over the runs; collisions: colliding pairs summed over the runs, "
            "by the kinds of the two vehicles.")
    columns = keys + ["control", "human share", "delay automated [s]", "delay human [s]", "min gap automated [m]",
                      "min gap human [m]", "collisions: automated / mixed / human"]

    rows = []
    for _, r in summ.iterrows():
        sel = ok["control"] == r["control"]
        for k in keys:
            sel &= ok[k] == r[k]
        g = ok[sel]

        def lo(k):
            x = pd.to_numeric(g[k], errors="coerce").min() if k in g else math.nan
            return "n/a" if x != x else f"{x:.2f}"

        def total(k):
            return f"{int(pd.to_numeric(g[k], errors='coerce').fillna(0).sum())}" if k in g else "n/a"

        share = r.get("human_share_mean", math.nan)
        rows.append([f"{r[k]}" for k in keys] + [
            r["control"], "n/a" if share != share else f"{100 * share:.0f} %", mean_ci(r, "mean_delay_automated_s"),
            mean_ci(r, "mean_delay_human_s"), lo("min_bumper_gap_automated_m"), lo("min_bumper_gap_human_m"),
            f"{total('collisions_automated')} / {total('collisions_mixed')} / {total('collisions_human')}"])
    return note, pd.DataFrame(rows, columns=columns)


def driver_figure(df: pd.DataFrame, summ: pd.DataFrame, path: Path) -> None:
    """Mixed traffic: mean delay of automated vehicles and of human drivers, and colliding pairs
    per run, against the grid value per control (means over seeds; band: 95 % interval)."""
    from nrtraffic.plots import plt

    ok = df[df["status"] == "ok"].copy()
    ok["pairs"] = sum(pd.to_numeric(ok.get(f"collisions_{k}"), errors="coerce").fillna(0)
                      for k in ("automated", "mixed", "human"))
    if _one_point(summ):
        fig, axes = plt.subplots(1, 3, figsize=(12.5, 3.8))
        for ax, k, label in zip(axes[:2], ("mean_delay_automated_s", "mean_delay_human_s"),
                                ("mean delay, automated [s]", "mean delay, human drivers [s]")):
            _bars(ax, summ, k, label)
        pairs = [float(ok.loc[ok["control"] == c, "pairs"].mean()) for c in summ["control"]]
        axes[2].bar(range(len(pairs)), pairs, width=0.6, color="0.5")
        for i, v in enumerate(pairs):
            if v == v:
                axes[2].annotate(f"{v:.2f}", (i, v), xytext=(0, 3), textcoords="offset points", ha="center",
                                 fontsize=7)
        axes[2].set_ylim(0, max([1.0] + [1.2 * v for v in pairs if v == v]))
        axes[2].set_xticks(range(len(pairs)), list(summ["control"]), rotation=15, fontsize=8)
        axes[2].set_ylabel("colliding pairs per run")
        axes[2].grid(alpha=0.3, axis="y")
        point = _point_text(summ)
        fig.suptitle("mixed traffic, by driver: mean over seeds ± 95 % confidence interval"
                     + (f", {point}" if point else ""), fontsize=9)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
        return
    _line_rows(summ, ok, _driver_lines, path,
               "mixed traffic, by driver: mean over seeds, band: 95 % confidence interval")


def _driver_lines(axes, summ: pd.DataFrame, ok: pd.DataFrame) -> None:
    """The three panels of :func:`driver_figure` against the grid value, a line per control."""
    xlabel, x, ticks = _x_axis(summ)
    xlabel = {"demand.controlled_share": "share of controlled vehicles"}.get(xlabel, xlabel)
    for control, g in summ.groupby("control", sort=False):
        xs = x[g.index].to_numpy()
        order = xs.argsort()
        line = None
        for ax, k in zip(axes[:2], ("mean_delay_automated_s", "mean_delay_human_s")):
            m = g[f"{k}_mean"].to_numpy()[order]
            c = g[f"{k}_ci95"].fillna(0.0).to_numpy()[order]
            line, = ax.plot(xs[order], m, marker="o", label=control,
                            **({} if line is None else {"color": line.get_color()}))
            ax.fill_between(xs[order], m - c, m + c, color=line.get_color(), alpha=0.2, linewidth=0)
        per_run = []
        for _, r in g.iloc[order].iterrows():
            sel = ok["control"] == control
            for k in grid_keys(summ):
                sel &= ok[k] == r[k]
            per_run.append(float(ok.loc[sel, "pairs"].mean()) if sel.any() else math.nan)
        axes[2].plot(xs[order], per_run, marker="o", color=line.get_color(), label=control)
    for ax, label in zip(axes, ("mean delay, automated [s]", "mean delay, human drivers [s]",
                                "colliding pairs per run")):
        ax.set(xlabel=xlabel, ylabel=label)
        ax.grid(alpha=0.3)
        if ticks:
            ax.set_xticks(range(len(ticks)), ticks, rotation=20, fontsize=7)


def markdown(note: str, tab: pd.DataFrame) -> str:
    """sweep.md: the note and the table of :func:`table`."""
    lines = [note, "", "| " + " | ".join(tab.columns) + " |", "|" + "---|" * len(tab.columns)]
    lines += ["| " + " | ".join(map(str, row)) + " |" for row in tab.itertuples(index=False)]
    return "\n".join(lines) + "\n"


def _x_axis(summ: pd.DataFrame):
    """The x of the figures: the one numeric grid key, else the grid points in order."""
    keys = grid_keys(summ)
    if len(keys) == 1 and pd.api.types.is_numeric_dtype(summ[keys[0]]):
        return keys[0], summ[keys[0]].astype(float), None
    labels = summ[keys].astype(str).agg(",".join, axis=1) if keys else pd.Series(["base"] * len(summ))
    order = {lab: i for i, lab in enumerate(dict.fromkeys(labels))}
    return "grid point", labels.map(order).astype(float), list(order)


def _one_point(summ: pd.DataFrame) -> bool:
    """The sweep has one grid point (its figures are bars per control, not lines)."""
    keys = grid_keys(summ)
    return not keys or len(summ[keys].drop_duplicates()) == 1


def _bars(ax, summ: pd.DataFrame, k: str, label: str) -> bool:
    """Figure ``k`` of a one-point sweep: a bar per control at its mean over seeds, with the 95 %
    confidence interval where there are ``MIN_SEEDS_FOR_CI`` seeds or more; returns whether some
    interval was left out for want of seeds."""
    from nrtraffic.plots import plt

    controls = list(summ["control"])
    m = summ[f"{k}_mean"].to_numpy(dtype=float)
    c = summ[f"{k}_ci95"].fillna(0.0).to_numpy(dtype=float).copy()
    few = summ["runs"].to_numpy() < MIN_SEEDS_FOR_CI
    c[few] = 0.0
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    x = range(len(controls))
    ax.bar(x, m, yerr=c, capsize=5, color=[colours[i % len(colours)] for i in x], alpha=0.85, width=0.6)
    for i, (mi, ci) in enumerate(zip(m, c)):
        if mi == mi:
            ax.annotate(f"{mi:.1f}" + (f" ± {ci:.1f}" if ci > 0 else ""), (i, mi + ci), xytext=(0, 3),
                        textcoords="offset points", ha="center", fontsize=7)
    ax.set_xticks(list(x), controls, rotation=15, fontsize=8)
    ax.set_ylabel(label)
    ax.grid(alpha=0.3, axis="y")
    ax.margins(y=0.15)
    return bool(few.any())


def _point_text(summ: pd.DataFrame) -> str:
    keys = grid_keys(summ)
    return ", ".join(f"{k} = {summ[k].iloc[0]}" for k in keys)


def figure(summ: pd.DataFrame, path: Path) -> None:
    """Throughput, mean delay and fuel against the grid value, mean with its 95 % band per control;
    a single grid point: a bar per control with its 95 % interval. An interval from fewer than
    ``MIN_SEEDS_FOR_CI`` seeds is not drawn: it says little and its width would set the axis."""
    from nrtraffic.plots import plt

    panels = (("throughput_veh_h", "throughput [veh/h]"), ("mean_delay_s", "mean delay [s]"),
              ("mean_fuel_ml", "fuel [mL/veh]"))
    if _one_point(summ):
        fig, axes = plt.subplots(1, 3, figsize=(12.5, 3.8))
        few_any = False
        for ax, (k, label) in zip(axes, panels):
            few_any |= _bars(ax, summ, k, label)
        point = _point_text(summ)
        fig.suptitle("mean over seeds ± 95 % confidence interval" + (f", {point}" if point else "")
                     + (f" (no interval where fewer than {MIN_SEEDS_FOR_CI} seeds: unreliable)" if few_any else ""),
                     fontsize=9)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
        return
    _line_rows(summ, None, lambda axes, sub, _: _lines(axes, sub, panels), path, "mean over seeds, band: 95 % confidence interval",
                         f" (not drawn where fewer than {MIN_SEEDS_FOR_CI} seeds: unreliable)")


def _line_rows(summ: pd.DataFrame, runs: pd.DataFrame | None, draw, path: Path, title: str,
               few_note: str = "") -> None:
    """A figure of three panels against the grid value: one row, or, for a grid of two numeric
    keys, a row per value of the one with fewer (:func:`_facet_key`). ``draw(axes, summ, runs)``
    draws a row from its part of the summary and of the runs table (``runs``: None, or the
    successful runs); where it returns True (a band left out for want of seeds) the title says
    ``few_note``."""
    from nrtraffic.plots import plt

    facet = _facet_key(summ)
    rows = [(None, summ, runs)] if facet is None else [
        (f"{facet} = {v}", summ[summ[facet] == v].drop(columns=[facet]),
         None if runs is None else runs[runs[facet] == v]) for v in sorted(summ[facet].unique())]
    fig, axes = plt.subplots(len(rows), 3, figsize=(12.5, 3.8 if facet is None else 3.4 * len(rows)),
                             squeeze=False)
    few = False
    for row, (label, sub, part) in zip(axes, rows):
        few |= bool(draw(row, sub, part))
        if label:
            row[1].set_title(label, fontsize=9)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(title + (few_note if few else ""), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _facet_key(summ: pd.DataFrame) -> str | None:
    """Of a grid of two numeric keys, the one with fewer values: the figures draw a row of panels
    per value of it, against the other (None for any other grid)."""
    keys = grid_keys(summ)
    if len(keys) != 2 or not all(pd.api.types.is_numeric_dtype(summ[k]) for k in keys):
        return None
    return min(keys, key=lambda k: (summ[k].nunique(), -keys.index(k)))


def _lines(axes, summ: pd.DataFrame, panels) -> bool:
    """Figure ``panels`` (key, label) on ``axes`` against the grid value, a line per control with
    its 95 % band; returns whether some band was left out for want of seeds."""
    xlabel, x, ticks = _x_axis(summ)
    xlabel = {"demand.rate_veh_h": "demand [veh/h per approach]",
              "demand.controlled_share": "share of controlled vehicles"}.get(xlabel, xlabel)
    few_any = False
    for control, g in summ.groupby("control", sort=False):
        xs = x[g.index]
        order = xs.argsort()
        few = g["runs"].to_numpy()[order] < MIN_SEEDS_FOR_CI
        few_any |= bool(few.any())
        for ax, (k, label) in zip(axes, panels):
            m = g[f"{k}_mean"].to_numpy()[order]
            c = g[f"{k}_ci95"].fillna(0.0).to_numpy()[order]
            c[few] = 0.0
            xo = xs.to_numpy()[order]
            line, = ax.plot(xo, m, marker="o", label=control)
            ax.fill_between(xo, m - c, m + c, color=line.get_color(), alpha=0.2, linewidth=0)
            ax.set(xlabel=xlabel, ylabel=label)
            ax.grid(alpha=0.3)
            if ticks:
                ax.set_xticks(range(len(ticks)), ticks, rotation=20, fontsize=7)
    return few_any


def seed_figure(df: pd.DataFrame, path: Path) -> None:
    """Per-seed values of mean delay and throughput: one box per grid point and control, with
    every seed drawn as a point."""
    from nrtraffic.plots import plt

    ok = df[df["status"] == "ok"].copy()
    keys = grid_keys(df)
    ok["group"] = (ok[keys].astype(str).agg(",".join, axis=1) + "\n" if keys else "") + ok["control"]
    groups = list(dict.fromkeys(ok.sort_values(keys + ["control"])["group"]))
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 0.9 * len(groups) + 2), 6.5), sharex=True)
    for ax, k, label in zip(axes, ("mean_delay_s", "throughput_veh_h"), ("mean delay [s]", "throughput [veh/h]")):
        data = [pd.to_numeric(ok.loc[ok["group"] == g, k], errors="coerce").dropna().to_numpy() for g in groups]
        ax.boxplot(data, widths=0.5, showfliers=False)
        for i, d in enumerate(data):
            ax.plot(i + 1 + 0.08 * (((pd.Series(range(len(d))) % 5) - 2).to_numpy()), d, ".", ms=4, alpha=0.7)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y")
    axes[-1].set_xticks(range(1, len(groups) + 1), groups, rotation=30, fontsize=7, ha="right")
    fig.suptitle("per-seed distribution (box: quartiles; dots: seeds)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# what a sweep keeps beside its tables and manifest in ``--out``: its runs, its batch jobs' scripts
SWEEP_FOLDERS = ("runs", "jobs")


# a Dask scheduler's address: [protocol://]host:port
SCHEDULER_ADDRESS = re.compile(r"^((tcp|tls|ucx|ws|wss)://)?(\[[0-9a-fA-F:]+\]|[\w.-]+):(\d{1,5})$")
WORKERS_PER_CORE = 4  # the most worker processes of a local cluster per core of the machine


def check_out(out: Path) -> None:
    """A sweep's ``--out`` (not created here): not a file, nothing in its path that SUMO misreads,
    and either empty or an earlier sweep's: beside ``runs/`` and ``jobs/`` it may hold only what a
    sweep recorded in its manifest as written (:func:`record_tables`), so that a sweep's tables and
    report never replace a user's files of the same name."""
    from runners.api import OutputError, usable_path
    from runners.single import LOCK, MANIFEST, in_a_run, in_a_sweep, normal, read_manifest

    try:
        usable_path(out)
    except OutputError as exc:
        raise SweepError(str(exc)) from None
    owner = in_a_sweep(normal(out).parent)
    if owner is not None:
        raise SweepError(f"--out {out} lies in the sweep folder {owner}: choose a folder outside it")
    inside = in_a_run(out)
    if inside is not None:
        raise SweepError(f"--out {out} lies in the run directory {inside}: choose a folder outside it")
    if not out.is_dir():
        return
    linked = next((p for f in SWEEP_FOLDERS for p in (out / f, *_walk(out / f)) if p.is_symlink()), None)
    if linked is not None:  # (its runs would be written, and replaced, where it points)
        raise SweepError(f"--out {out}: {linked} is a link (to {os.readlink(linked)}); a sweep writes and replaces its "
                         "runs only inside its own folder: remove the link, or choose another folder")
    m = read_manifest(out, sweep=True)
    own = set(m["created"]) | {MANIFEST} if m is not None else set()
    foreign = sorted(p.name for p in out.iterdir() if p.name not in own and p.name not in SWEEP_FOLDERS
                     and p.name != LOCK)  # (a sweep writing there: refused by its lock, by name)
    if foreign and not (out / "runs").is_dir():
        raise SweepError(f"--out {out} holds {', '.join(foreign[:5])}{' and more' if len(foreign) > 5 else ''} and "
                         "no earlier sweep (no runs/ folder): choose an empty folder, or the folder of the sweep to "
                         "resume")
    runs = out / "runs"
    if (m is None and runs.is_dir() and any(runs.iterdir())
            and next(runs.rglob(FINGERPRINT), None) is None):  # (runs/ of a project: the user's own runs)
        raise SweepError(f"--out {out} holds a runs/ folder that no sweep wrote (none of its runs has a sweep's "
                         f"{FINGERPRINT}): a sweep would put its runs among them; choose an empty folder, or the "
                         "folder of the sweep to resume")
    if foreign:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        raise SweepError(f"--out {out} holds {shown}, which no sweep there recorded writing (files of your own, or "
                         f"the tables of a sweep of an earlier version, which kept no {MANIFEST}): a sweep would "
                         "write its tables over them; move them out of the folder and run again to resume its runs/, "
                         "or choose another folder")


def _walk(folder: Path):
    """Everything under ``folder``, not through links (none where it is not a folder)."""
    return folder.rglob("*") if folder.is_dir() and not folder.is_symlink() else ()


def make_out(out: Path) -> bool:
    """Create a sweep's ``--out`` (checked first, :func:`check_out`), or refuse it when it cannot be
    written (:class:`SweepError`); whether it was made here."""
    from runners.api import OutputError, writable_dir

    created = not out.exists()
    try:
        writable_dir(out)
    except OutputError as exc:
        raise SweepError(str(exc)) from None
    return created


def record_tables(out: Path, written: bool, planned=()) -> None:
    """The sweep's manifest in ``out`` (``manifest.json``: what was there before, what it created,
    :func:`~runners.single.read_manifest`): begun before the runs (``written`` False; a new one
    lists the folder's top level as there before), given the names of the tables and figures just
    before they are written (``planned``), then, once written, listing the top-level names it
    created that are there (no planned name it did not write). :func:`check_out` lets a resume write only over those."""
    from runners.single import LOCK, MANIFEST, _write_json, read_manifest

    before = sorted(p.name for p in out.iterdir() if p.name not in (MANIFEST, LOCK))
    m = read_manifest(out, sweep=True) or {"sweep": 1, "preexisting": before, "created": []}
    m["created"] = sorted(set(m["created"]) | (set(planned) - set(m["preexisting"])))
    if written:  # (only what it did write: a name it planned and did not write is not claimed)
        now = {p.name for p in out.iterdir()} - {MANIFEST, MANIFEST + ".tmp", LOCK}
        m["created"] = sorted(now - set(m["preexisting"]))
    _write_json(out / MANIFEST, m)


def check_where(workers, scheduler: str | None, batch=None) -> int:
    """``--workers`` (a whole number, at least 1 and at most :data:`WORKERS_PER_CORE` per core of
    a local cluster) and ``--scheduler`` (a Dask address) checked (:class:`SweepError`); the
    number of workers."""
    if isinstance(workers, bool) or not isinstance(workers, numbers.Integral):  # (the API: 1.5 failed inside Dask)
        raise SweepError(f"workers={workers!r}: give a whole number of worker processes")
    workers = int(workers)
    if scheduler is None and workers < 1:
        raise SweepError(f"--workers {workers}: need at least one worker process")
    if scheduler is not None and not SCHEDULER_ADDRESS.match(scheduler):
        raise SweepError(f"--scheduler {scheduler!r}: expected a Dask scheduler's address, e.g. tcp://10.0.0.5:8786")
    if scheduler is not None:
        host, port = SCHEDULER_ADDRESS.match(scheduler).group(3, 4)
        if not 1 <= int(port) <= 65535:
            raise SweepError(f"--scheduler {scheduler}: port {port} is not a port (1 to 65535); Dask's scheduler "
                             "listens on 8786 unless told otherwise")
        try:
            socket.getaddrinfo(host.strip("[]"), int(port))
        except (OSError, UnicodeError):
            raise SweepError(f"--scheduler {scheduler}: no host is known by the name {host}; check the address") from None
    cores = os.cpu_count() or 1
    if scheduler is None and batch is None and workers > WORKERS_PER_CORE * cores:
        raise SweepError(f"--workers {workers}: this machine has {cores} cores; a local cluster takes at most "
                         f"{WORKERS_PER_CORE * cores} workers (each runs one simulation at a time)")
    return workers


def study(scenario_path: Path, seeds: list[int], grid: list[tuple[str, list[str]]], controls: list[str], out: Path,
          duration_s: float | None = None, overrides: tuple[str, ...] = (), workers: int = 2,
          scheduler: str | None = None, force: bool = False, progress: bool = True,
          allow_outside: bool = False, batch=None) -> pd.DataFrame:
    """A whole sweep (``nrtraffic sweep``, ``nrtraffic.sweep``): check its size and every grid
    point's configuration, refuse a resume of another configuration (unless ``force``), then
    :func:`run_sweep` (``batch``: on Slurm or PBS, see :mod:`runners.clusters`). Returns
    ``sweep.csv`` as a DataFrame."""
    workers = check_where(workers, scheduler, batch)
    n = len(seeds) * len(controls) * math.prod(len(v) for _, v in grid)
    if n > MAX_RUNS and not force:
        raise SweepError(f"the sweep has {n} runs, more than {MAX_RUNS}: narrow --seeds or --grid, or --force to "
                         "run them all")
    check_grid(grid, duration_s)
    from runners.api import one_source

    try:
        one_source(overrides, None, duration_s)
    except ValueError as exc:
        raise SweepError(str(exc)) from None
    given = {o.split("=", 1)[0].strip() for o in overrides}
    both = sorted(given & {k for k, _ in grid}) or sorted(given & {"scenario.seed", "general.seed"})
    if both:  # (the grid's value, or the run's seed, would override it without a word)
        raise SweepError(f"--set {both[0]}: " + ("--grid sets it at every point; give it in one of them" if both[0] in
                                                  dict(grid) else "a sweep's seeds are --seeds; give them there"))
    check_out(Path(out))
    jobs = plan(scenario_path, seeds, grid, controls, out, duration_s, tuple(overrides), allow_outside=allow_outside)
    created = make_out(Path(out))  # (only now: a sweep refused above leaves nothing)
    from runners.single import MANIFEST, lock_run_dir, unlock_run_dir

    try:  # (one sweep at a time in a folder: a second one's --force would replace the first one's runs)
        lock_run_dir(Path(out))
    except ValueError as exc:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise SweepError(str(exc)) from None
    try:
        check_resume(jobs, force=force)
        remove_stale(out)
        record_tables(Path(out), written=False)  # (what is there now is not the sweep's)
        return run_sweep(jobs, out, workers=workers, scheduler=scheduler, progress=progress, batch=batch)
    except SweepError:  # (a scheduler it cannot use: the folder it made for nothing goes again)
        unlock_run_dir(Path(out))
        if created and Path(out).is_dir() and {p.name for p in Path(out).iterdir()} <= {MANIFEST}:
            shutil.rmtree(out)
        raise
    except KeyboardInterrupt:
        # the runs it stopped leave only their temporary folders, which say "running": gone with
        # their workers (a resume runs them again), so that nothing of them looks like a result
        _close_clusters()
        remove_stale(out)
        raise
    finally:
        unlock_run_dir(Path(out))


def _close_clusters() -> None:
    """Close every Dask cluster of this process that an interrupt left open, one stopped while it
    started included, quietly; Dask's own closing of them at exit (which fails with a traceback on
    one that never finished starting) is then not needed."""
    import atexit

    try:
        from distributed.deploy.spec import SpecCluster, close_clusters
    except Exception:  # noqa: BLE001 - not installed, or stopped half-imported: no cluster was made
        return
    for cluster in list(SpecCluster._instances):
        with contextlib.suppress(Exception):
            cluster.close(timeout=5)
    atexit.unregister(close_clusters)


def main(args) -> int:
    from runners.clusters import from_args

    batch = from_args(args)  # --cluster and its job flags, checked before anything is planned or submitted
    grid = parse_grid(args.grid)
    controls = [NRTRAFFIC] + parse_baselines(args.baseline)
    df = study(args.scenario, parse_seeds(args.seeds), grid, controls, args.out, args.duration, tuple(args.overrides),
               workers=args.workers, scheduler=args.scheduler, force=args.force, progress=not args.no_progress,
               allow_outside=args.allow_outside, batch=batch)
    print((Path(args.out) / "sweep.md").read_text())
    n_failed = int((df["status"] != "ok").sum())
    if n_failed:
        for _, r in df[df["status"] != "ok"].iterrows():
            print(f"{r['status']}: {r['run_dir']}: {r['error']}")
        print(failed_advice(df))
        return 1
    return 0


def failed_advice(df: pd.DataFrame) -> str:
    """The closing line of a sweep with failed runs: a retry where a run may succeed again, the
    scenario to fix where its configuration was refused once SUMO had read the network, and
    neither for runs the watchdog stopped as gridlocks (a retry repeats them)."""
    bad = df[df["status"] != "ok"]
    stuck = int((bad["status"] == GRIDLOCK).sum())
    refused = int(bad["error"].astype(str).str.startswith(("NetworkError", "ScenarioError")).sum())
    why = [f"{refused} were refused for their scenario: fix it first"] if refused else []
    why += [f"{stuck} stopped as gridlocks: the junction could not serve that demand (the errors above name the "
            "junction or lane), and a retry stops the same way"] if stuck else []
    if refused == len(bad):
        return (f"{len(bad)} of {len(df)} runs failed: their scenario was refused (the errors above name the key to "
                "fix); a retry fails the same way")
    if refused + stuck == len(bad):
        return f"{len(bad)} of {len(df)} runs failed: " + "; ".join(why)
    retry = f"{len(bad)} of {len(df)} runs failed; re-run the same command to retry them"
    return retry + (f" ({'; '.join(why)})" if why else "")
