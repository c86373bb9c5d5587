"""The Python API: ``nrtraffic.run``, ``nrtraffic.baseline`` and ``nrtraffic.sweep``.

The same operations as ``nrtraffic run``, ``nrtraffic baseline`` and ``nrtraffic sweep``, with the
same checks (a bad key, value or demand raises :class:`~nrtraffic.scenario.ScenarioError` before
SUMO starts; a folder that holds something else raises :class:`OutputError`), writing the same run
directories, and returning objects that read them: :class:`Run` (``summary``, ``vehicles``,
``movements``, ``approaches``, ``trajectories()``) and :class:`Sweep` (``table``, ``summary``).
A run that stops early raises :class:`~nrtraffic.engine.RunFailed`; what it had finished is in its
run directory (``exc.result.run_dir``).

Without ``out``, a run or sweep is written into a new folder under the system's temporary
directory (``tempfile.mkdtemp``), which is kept: ``Run.run_dir`` / ``Sweep.path`` say where.

Nothing heavy is imported here at module level: ``import nrtraffic`` stays light, and the
command line imports the helpers it shares with the API from here.
"""

from __future__ import annotations

import contextlib
import json
import math
import numbers
import os
import re
import threading
from collections.abc import Iterable, Mapping
from functools import cached_property
from pathlib import Path


class OutputError(ValueError):
    """The output folder cannot be used."""


def usable_path(path: Path) -> None:
    """Refuse (exit 2) an output folder whose path is too long, that is a file, or whose path SUMO
    would misread."""
    path = Path(path)
    long = [p for p in path.absolute().parts if len(os.fsencode(p)) > 255]
    if long or len(os.fsencode(str(path.absolute()))) > 4000:
        raise OutputError(f"--out {str(path)[:60]}...: a name in the path is longer than the file system takes "
                          "(255 bytes a name, about 4000 the whole path); choose a shorter one")
    if path.is_symlink() and not path.exists():  # (mkdir would say "File exists")
        raise OutputError(f"--out {path}: is a link to {os.readlink(path)}, which does not exist (or a loop of links); "
                          "remove the link, or give the folder itself")
    if path.exists() and not path.is_dir():
        raise OutputError(f"--out {path}: exists and is not a folder")
    if "${" in str(path.absolute()) or str(path).startswith("~"):  # (SUMO reads them; nrtraffic takes them as they are)
        raise OutputError(f"--out {path}: SUMO reads ${{NAME}} in a file name as an environment variable and a leading ~ "
                          "as a home folder, so its files would go elsewhere; give the folder's path without them")
    odd = sorted({c for c in str(path.absolute()) if c in SUMO_PATH_CHARS or not c.isprintable()})
    if odd:
        raise OutputError(f"--out {path}: its path holds {' '.join(repr(c) for c in odd)}, which SUMO misreads in a "
                          "file name (a list separator, a host:port, a quote, a line break or another control character); "
                          "choose a folder without them")


def writable_dir(path: Path) -> None:
    """Refuse (exit 2) an output folder that is a file, has a path SUMO misreads (:func:`usable_path`)
    or cannot be created or written, before anything runs."""
    path = Path(path)
    usable_path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-test-{threading.get_ident()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OutputError(f"--out {path}: cannot write there: {exc.strerror or exc}") from None


def writable_file(text: str, own: tuple[str, ...] = ()) -> Path:
    """``--write FILE`` checked before the work that it is to hold (:class:`~runners.api.OutputError`,
    exit 2): a file's name, not a folder's (nor one ending in a slash), printable, in a folder that
    exists, and either new or an earlier output of the same command (one that begins with one of
    ``own``): a file of the user's is never written over."""
    path = Path(text)
    if not text.strip() or text.endswith(("/", os.sep)) or path.is_dir():
        raise OutputError(f"--write {text}: is a folder; name a file in it")
    if not text.isprintable():
        raise OutputError(f"--write {text!r}: the name holds a line break or another control character; choose "
                          "another")
    if not path.absolute().parent.is_dir():
        raise OutputError(f"--write {text}: its folder does not exist")
    if os.path.lexists(path):
        try:
            with open(path, "rb") as f:
                head = f.read(200).decode("utf-8", "replace")
        except OSError:
            head = ""
        if path.is_symlink() or not path.is_file() or not head.startswith(own or ("\0",)):
            raise OutputError(f"--write {text}: exists and is not an earlier output of this command (a file of your "
                              "own?); remove it, or choose another name")
    return path


def write_file(path: Path, text: str) -> None:
    """Write ``--write FILE`` (checked by :func:`writable_file`) whole or not at all, or
    OutputError (exit 2)."""
    from nrtraffic.results import write_atomic

    try:
        write_atomic(path, text.encode())
    except OSError as exc:
        raise OutputError(f"--write {path}: cannot write there: {exc.strerror or exc}") from None


SUMO_PATH_CHARS = ",:'\""  # SUMO reads a comma in a file name as a list separator, "host:port" as a socket; quotes fail


def slug(name: str) -> str:
    """A scenario name as a folder name under runs/: letters, digits, ``.``, ``_`` and ``-`` only
    (a name such as ``../../x`` cannot lead out of it), at most 100 characters."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._-")[:100].strip("._-") or "run"


def claim(out: Path, sc, seed, duration, control: str, force: bool) -> list[Path]:
    """Check the scenario against its network and build its demand (exit 2 on an error, before
    anything is written), then make ``out`` ready for the run. Returns the folders made for it
    (for :func:`give_up`)."""
    from runners.single import check, check_demand, claim_run_dir

    check(sc)
    check_demand(sc, seed, duration)
    new = [p for p in (Path(out).absolute(), *Path(out).absolute().parents) if not os.path.lexists(p)]
    writable_dir(out)
    try:
        claim_run_dir(out, sc, seed, duration, control, force)  # (locked for the run: refused() frees it)
    except ValueError as exc:
        for p in new:  # (the folders made for the refused run go again)
            with contextlib.suppress(OSError):
                p.rmdir()
        raise OutputError(str(exc)) from None
    except OSError as exc:
        raise OutputError(f"--out {out}: cannot clear the earlier run: {exc}") from None
    return new


@contextlib.contextmanager
def refused(out: Path, new: list[Path]):
    """Around a run after :func:`claim`: a scenario error (exit 2) before SUMO starts leaves
    nothing of the run (:func:`give_up`); however it ends, the folder's lock goes."""
    from nrtraffic.scenario import ScenarioError
    from nrtraffic.sumo.network import NetworkError
    from runners.single import unlock_run_dir

    try:
        yield
    except (ScenarioError, NetworkError):
        unlock_run_dir(out)
        give_up(out, new)
        raise
    finally:  # (the run has ended, whichever way: the folder is free)
        unlock_run_dir(out)


def give_up(out: Path, new: list[Path]) -> None:
    """A run refused (exit 2) after :func:`claim`, before SUMO started (no ``summary.json``): what
    it wrote into ``out`` goes (its manifest's files, nothing else), and so do the folders made for
    it (``new``) where they are empty."""
    from runners.single import read_manifest, remove_run_files

    out = Path(out)
    if (out / "summary.json").exists():
        return
    if read_manifest(out) is not None:
        with contextlib.suppress(OSError):
            remove_run_files(out)
    for p in new:
        with contextlib.suppress(OSError):
            p.rmdir()


# ------------------------------------------------------------------ results
class Run:
    """A run directory, read when asked (each table once).

    Attributes
    ----------
    run_dir : the run directory (``Path``).
    summary : ``summary.json`` as a dict.
    vehicles, movements, approaches : ``vehicles.csv`` (a row per vehicle and junction crossed),
        ``movements.csv`` and ``approaches.csv`` as DataFrames (empty where the run wrote none).
    report : ``report.html`` (``Path``; absent when the run was made with ``report=False``).

    ``Run(path)`` opens any finished run directory, also one written by the command line.
    """

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        if not (self.run_dir / "summary.json").is_file():
            raise FileNotFoundError(f"{self.run_dir} holds no summary.json: not a run directory")

    @cached_property
    def summary(self) -> dict:
        return json.loads((self.run_dir / "summary.json").read_text())

    def _csv(self, name: str):
        import pandas as pd

        path = self.run_dir / name
        if not path.is_file() or path.stat().st_size == 0:
            return pd.DataFrame()
        return pd.read_csv(path)

    @cached_property
    def vehicles(self):
        return self._csv("vehicles.csv")

    @cached_property
    def movements(self):
        return self._csv("movements.csv")

    @cached_property
    def approaches(self):
        return self._csv("approaches.csv")

    @property
    def report(self) -> Path:
        return self.run_dir / "report.html"

    def trajectories(self):
        """``trajectories.parquet`` as a DataFrame (read now, not kept: it can be large): per
        controlled vehicle and log instant, ``t`` [s], pose, inputs, reference and errors."""
        from nrtraffic.results import read_trajectories

        return read_trajectories(self.run_dir)

    def _repr_html_(self) -> str:  # (a notebook shows a run as its headline figures)
        import html

        keys = ("scenario", "control", "seed", "status", "sim_time_s", "vehicles_spawned", "vehicles_completed",
                "throughput_veh_h", "mean_delay_s", "los", "p95_delay_s", "collisions", "warnings")
        rows = "".join(f"<tr><th style='text-align:left'>{k}</th><td>{html.escape(str(self.summary[k]))}</td></tr>"
                       for k in keys if k in self.summary)
        return f"<p>run directory <code>{html.escape(str(self.run_dir))}</code></p><table>{rows}</table>"

    def __repr__(self) -> str:
        s = self.summary
        return (f"Run({s.get('scenario')!r}, seed {s.get('seed')}, {s.get('control', 'nrtraffic')}, "
                f"status {s.get('status')!r}, run_dir={str(self.run_dir)!r})")


class Sweep:
    """A sweep's output folder: ``table`` (``sweep.csv``, a row per run: grid values, seed,
    control, status, error, the run's figures, ``run_dir``), ``summary`` (``sweep_summary.csv``:
    mean, sd and 95 % confidence half-width per grid point and control), ``path`` and
    ``report`` (``report.html``); :meth:`run` opens one of its runs."""

    def __init__(self, path: str | Path):
        import pandas as pd

        self.path = Path(path)
        self.table = pd.read_csv(self.path / "sweep.csv")
        self.summary = pd.read_csv(self.path / "sweep_summary.csv")

    @property
    def failed(self):
        """The rows of the runs that failed (``error`` says why)."""
        return self.table[self.table["status"] != "ok"]

    @property
    def report(self) -> Path:
        return self.path / "report.html"

    def run(self, row: int) -> Run:
        """The run of row ``row`` of :attr:`table`."""
        return Run(self.table["run_dir"].iloc[row])

    def __repr__(self) -> str:
        return f"Sweep({len(self.table)} runs, {len(self.failed)} failed, path={str(self.path)!r})"


# ------------------------------------------------------------------ operations
def _toml(v) -> str:
    """A Python value as TOML text, for a ``section.key=value`` setting."""
    import numpy as np

    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):  # (a float, or numpy's)
        v = float(v)
        return ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")) if not math.isfinite(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, Mapping):
        key = lambda k: k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)  # noqa: E731
        return "{" + ", ".join(f"{key(str(k))} = {_toml(x)}" for k, x in v.items()) + "}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    from nrtraffic.scenario import ScenarioError

    raise ScenarioError(f"a setting's value must be a number, string, bool, list or table, not {type(v).__name__} "
                        f"({v!r})")


def settings(overrides) -> list[str]:
    """``overrides`` as ``section.key=value`` texts: a mapping ``{"demand.rate_veh_h": 600}`` or
    ``{"demand": {"rate_veh_h": 600}}`` (values as Python numbers, strings, bools, lists, dicts),
    pairs ``[("demand.rate_veh_h", 600)]``, or texts as ``--set`` takes them."""
    if overrides is None:
        return []
    if isinstance(overrides, str):
        return [overrides]
    from nrtraffic.scenario import ScenarioError

    how = "give {'section.key': value}, {'section': {'key': value}} or ['section.key=value', ...]"
    if isinstance(overrides, Mapping):
        out = []
        for k, v in overrides.items():
            if "." not in str(k) and isinstance(v, Mapping):  # ({'demand': {'rate_veh_h': 300}}: a section's keys)
                out += [f"{k}.{kk}={_toml(vv)}" for kk, vv in v.items()]
            elif "." not in str(k):
                raise ScenarioError(f"overrides: {k!r} is no 'section.key'; {how}")
            else:
                out.append(f"{k}={_toml(v)}")
        return out
    if not isinstance(overrides, Iterable):
        raise ScenarioError(f"overrides={overrides!r}: {how}")
    out = []
    for o in overrides:
        if isinstance(o, tuple) and len(o) == 2 and isinstance(o[0], str):  # (('demand.rate_veh_h', 600), ...)
            out.append(f"{o[0]}={_toml(o[1])}")
        elif isinstance(o, str):
            out.append(o)
        else:
            raise ScenarioError(f"overrides: {o!r} is no 'section.key=value'; {how}")
    return out


def _seed_duration(sc, seed, duration_s) -> tuple[int, float | None]:
    """``seed`` and ``duration_s`` checked as the command checks ``--seed`` and ``--duration``
    (ScenarioError naming them): a whole number 0 to 2^31 - 1, and a finite 0 to a week [s]; numbers,
    not text (the command line reads its text as numbers; a string here is a slip)."""
    from nrtraffic.limits import MAX_DURATION_S, MAX_SEED
    from nrtraffic.scenario import ScenarioError

    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, numbers.Real):  # (not "3": a number, as --seed is read)
            raise ScenarioError(f"seed={seed!r}: give a whole number 0 to {MAX_SEED}")
        try:
            value = float(seed)
        except ValueError:
            raise ScenarioError(f"seed={seed!r}: give a whole number 0 to {MAX_SEED}") from None
        if not (math.isfinite(value) and value == int(value) and 0 <= value <= MAX_SEED):
            raise ScenarioError(f"seed={seed!r}: give a whole number 0 to {MAX_SEED}")
        seed = int(value)
    if duration_s is not None:
        if isinstance(duration_s, bool) or not isinstance(duration_s, numbers.Real):
            raise ScenarioError(f"duration_s={duration_s!r}: give seconds as a number, 0 to {MAX_DURATION_S:g}")
        try:
            d = float(duration_s)
        except (TypeError, ValueError):
            raise ScenarioError(f"duration_s={duration_s!r}: give seconds, 0 to {MAX_DURATION_S:g}") from None
        if not (math.isfinite(d) and 0 <= d <= MAX_DURATION_S):
            raise ScenarioError(f"duration_s={duration_s!r}: give seconds, 0 to {MAX_DURATION_S:g} (0: until every "
                                "vehicle has left)")
        duration_s = d
    return (sc.general.seed if seed is None else seed), duration_s


def _path(value, name: str) -> Path:
    """A path argument of the Python API (a ``str`` or a ``pathlib.Path``), or a ScenarioError naming it."""
    from nrtraffic.scenario import ScenarioError

    if not isinstance(value, (str, os.PathLike)) or isinstance(os.fspath(value), bytes):
        raise ScenarioError(f"{name}={value!r}: give a path as a str or a pathlib.Path")
    return Path(os.path.expanduser(value))  # (a leading ~ as the home folder, as the table writers read it)


def one_source(overrides, seed, duration_s, api: bool = False) -> None:
    """Refuse (ScenarioError, exit 2) a seed or duration given both as a flag and as a ``--set``
    of its scenario key (the flag wins, and the setting would be dropped without a word), and one
    key set twice to different values (the last would win without a word). ``api``:
    named as the Python API's arguments (``seed=``, ``overrides``), not as flags."""
    from nrtraffic.scenario import ScenarioError

    setting = "overrides" if api else "--set"  # (named as the caller gave them)
    given = {}
    for o in overrides:
        key, _, text = str(o).partition("=")
        key = key.strip()
        if key in given and given[key] != text.strip():  # (the last had won without a word)
            raise ScenarioError(f"{setting} {key} is given twice ({given[key]} and {text.strip()}): give it once")
        given[key] = text.strip()
    for value, flag, arg, names in ((seed, "--seed ", "seed=", ("scenario.seed", "general.seed")),
                                    (duration_s, "--duration ", "duration_s=", ("scenario.duration_s",
                                                                                "general.duration_s"))):
        for name in names:
            if value is None or name not in given:
                continue
            try:
                same = float(given[name]) == float(value)
            except ValueError:
                same = False
            if not same:
                raise ScenarioError(f"{arg if api else flag}{value} and {setting} {name}={given[name]} both give it: "
                                    "give one of them")


def _flag(value, name: str) -> bool:
    """A yes/no argument of the Python API: a bool (``force="no"`` had counted as yes)."""
    import numpy as np

    from nrtraffic.scenario import ScenarioError

    if not isinstance(value, (bool, np.bool_)):
        raise ScenarioError(f"{name}={value!r}: give True or False")
    return bool(value)


def _out(out, prefix: str) -> Path:
    if out is not None:
        return _path(out, "out")
    import tempfile

    return Path(tempfile.mkdtemp(prefix=f"nrtraffic-{prefix}-"))


def run(scenario: str | Path, *, seed: int | None = None, duration_s: float | None = None,
        out: str | Path | None = None, overrides=None, force: bool = False, progress: bool = False,
        report: bool = True, allow_outside: bool = False) -> Run:
    """Run one scenario under nrtraffic's control (``nrtraffic run``).

    Parameters
    ----------
    scenario : a scenario.toml, or the folder holding it.
    seed : random seed of the arrivals and of SUMO (default: the scenario's).
    duration_s : simulated time [s] (default: the scenario's; 0: until every vehicle has left).
    out : run directory (default: a new folder under the system's temporary directory, kept).
    overrides : settings over the scenario's, as ``{"section.key": value}`` or ``["section.key=value"]``.
    force : replace an earlier run of another configuration in ``out`` (its files only).
    progress : a progress bar (on a terminal) or a line per 10 % of the run (elsewhere) on stderr.
    report : also draw the figures and write ``report.html``, as the command does.
    allow_outside : let the scenario name files outside its own folder.

    Returns
    -------
    Run : the run directory, with ``summary``, ``vehicles``, ``movements``, ``approaches`` and
        ``trajectories()``.
    """
    from nrtraffic import scenario as scenario_mod
    from runners.single import run_scenario

    one_source(settings(overrides), seed, duration_s, api=True)
    sc = scenario_mod.load(_path(scenario, "scenario"), settings(overrides),
                           allow_outside=_flag(allow_outside, "allow_outside"))
    progress, report = _flag(progress, "progress"), _flag(report, "report")
    seed, duration_s = _seed_duration(sc, seed, duration_s)
    out = _out(out, f"{slug(sc.general.name)}-seed{seed}")
    new = claim(out, sc, seed, duration_s, "nrtraffic", _flag(force, "force"))
    with refused(out, new):
        run_scenario(sc, out, seed=seed, duration_s=duration_s, progress=progress, report=report)
    return Run(out)


def baseline(scenario: str | Path, junction: str, *, seed: int | None = None, duration_s: float | None = None,
             out: str | Path | None = None, overrides=None, force: bool = False, progress: bool = False,
             report: bool = True, allow_outside: bool = False) -> Run:
    """The same demand and seed under SUMO's own junction control (``nrtraffic baseline``):
    ``junction`` is one of ``as_is``, ``actuated``, ``traffic_light``, ``traffic_light_coordinated``,
    ``priority``, ``allway_stop``, ``right_before_left``. The other parameters and the result are
    those of :func:`run`."""
    from nrtraffic import scenario as scenario_mod
    from nrtraffic.sumo.netbuild import BASELINES
    from runners.baseline import run_baseline

    one_source(settings(overrides), seed, duration_s, api=True)
    sc = scenario_mod.load(_path(scenario, "scenario"), settings(overrides),
                           allow_outside=_flag(allow_outside, "allow_outside"))
    progress, report = _flag(progress, "progress"), _flag(report, "report")
    seed, duration_s = _seed_duration(sc, seed, duration_s)
    if junction not in BASELINES:  # (checked before the run folder is made)
        raise scenario_mod.ScenarioError(f"junction={junction!r}: one of {', '.join(BASELINES)}")
    out = _out(out, f"{slug(sc.general.name)}-seed{seed}-{junction}")
    new = claim(out, sc, seed, duration_s, f"sumo_{junction}", _flag(force, "force"))
    with refused(out, new):
        run_baseline(sc, junction, out, seed=seed, duration_s=duration_s, progress=progress, report=report)
    return Run(out)


def sweep(scenario: str | Path, seeds: Iterable[int] | str, *, grid: Mapping[str, Iterable] | None = None,
          baselines: Iterable[str] | str = (), duration_s: float | None = None, out: str | Path | None = None,
          overrides=None, workers: int = 2, scheduler: str | None = None, force: bool = False,
          progress: bool = False, allow_outside: bool = False) -> Sweep:
    """Every (grid point, seed) of a scenario, and SUMO's junction controls on the same seeds, on
    Dask (``nrtraffic sweep``); resumable: finished runs in ``out`` are not run again.

    Parameters
    ----------
    seeds : the seeds, e.g. ``range(1, 21)``, or ``"1:20"`` as ``--seeds`` takes them.
    grid : ``{"section.key": [values]}``; the grid is the product of the lists.
    baselines : SUMO's junction controls to run as well (names as :func:`baseline` takes them).
    workers, scheduler : a local cluster of ``workers`` processes, or an existing Dask scheduler's
        address. In a script (not a notebook), call it under ``if __name__ == "__main__":`` (the
        worker processes import the script).
    progress : a bar (on a terminal) or a line per finished run (elsewhere) on stderr.
    The others are those of :func:`run`; ``force`` also allows more than 20000 runs.

    Returns
    -------
    Sweep : ``table`` (sweep.csv), ``summary`` (sweep_summary.csv), ``path``; a run that failed
        is a row with ``status`` "failed" (or "gridlock", stopped by the watchdog) and its ``error``
        (:attr:`Sweep.failed`), not an exception.
    """
    from runners import sweep as sweep_mod

    _, duration_s = _seed_duration(None, 0, duration_s)  # (checked as run's; a seed of 0 stands in)
    if not isinstance(seeds, (str, Iterable)) or isinstance(seeds, (bytes, bytearray, Mapping)):
        raise sweep_mod.SweepError(f"seeds={seeds!r}: give the seeds, e.g. range(1, 21) or \"1:20\"")
    if not isinstance(seeds, str):
        seeds = list(seeds)
        if not seeds:
            raise sweep_mod.SweepError("seeds: none given; give at least one, e.g. range(1, 21)")
        odd = [s for s in seeds if isinstance(s, bool) or not isinstance(s, numbers.Integral)]
        if odd:  # (1.5 had been run as seed 1, True as seed 1)
            raise sweep_mod.SweepError(f"seeds: {odd[0]!r} is not an integer; give the seeds as integers, e.g. "
                                       "range(1, 21)")
        seeds = ",".join(str(int(s)) for s in seeds)
    seeds = sweep_mod.parse_seeds(seeds)
    if grid is not None and not isinstance(grid, Mapping):
        raise sweep_mod.SweepError(f"grid={grid!r}: give {{'section.key': [value, ...]}}")
    if scheduler is not None and not isinstance(scheduler, str):
        raise sweep_mod.SweepError(f"scheduler={scheduler!r}: give a Dask scheduler's address as text, e.g. "
                                   "'tcp://10.0.0.5:8786'")
    if not isinstance(baselines, str):
        listed = list(baselines) if isinstance(baselines, Iterable) else None  # (a generator is read once)
        if listed is None or not all(isinstance(b, str) for b in listed):
            raise sweep_mod.SweepError(f"baselines={baselines!r}: give SUMO's controls by name, e.g. ['actuated', "
                                       "'allway_stop'] or 'actuated,allway_stop'")
        baselines = listed
    points = []  # (not through the text of --grid: a list value, or a string with a comma, is one value)
    for k, values in (grid or {}).items():
        values = [values] if isinstance(values, str) or not isinstance(values, Iterable) else list(values)
        if "." not in str(k) or not values:
            raise sweep_mod.SweepError(f"grid {k!r}: expected {{'section.key': [value, ...]}}")
        points.append((str(k), [v if isinstance(v, str) else _toml(v) for v in values]))
    names = baselines if isinstance(baselines, str) else ",".join(baselines)
    controls = [sweep_mod.NRTRAFFIC] + sweep_mod.parse_baselines(names if names else None)
    out = _out(out, "sweep")
    sweep_mod.study(_path(scenario, "scenario"), seeds, points, controls, out, duration_s=duration_s,
                    overrides=tuple(settings(overrides)), workers=workers, scheduler=scheduler,
                    force=_flag(force, "force"), progress=_flag(progress, "progress"),
                    allow_outside=_flag(allow_outside, "allow_outside"))
    return Sweep(out)
