"""One run of one scenario into a run directory."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
from pathlib import Path

import pandas as pd

from nrtraffic import _kernel_cache
from nrtraffic import scenario as scenario_mod
from nrtraffic.engine import Engine, RunFailed, describe
from nrtraffic.results import (RunResult, TrajectoryWriter, write_atomic, write_movements, write_summary, write_table,
                               write_vehicles)
from nrtraffic.sumo.network import NetworkError, check_scenario, check_sumo_args
from runners import interrupts


def check(sc: scenario_mod.Scenario) -> None:
    """What can be checked before SUMO starts: the network is a SUMO network with the junction and
    the edges the scenario names, and ``sumo.extra_args`` are SUMO options (NetworkError)."""
    edges = tuple(e for a in sc.approaches for e in (*a.route, a.merge_entry_edge))
    files = [sc.network_path] + (sc.demand.route_files(sc.base_dir) if sc.demand.sumo_routes else [])
    for f in files:
        if "," in str(f):
            raise NetworkError(f"{f}: its path holds ',', which SUMO reads in a file name as a list separator; "
                               "move the scenario to a folder without commas")
        if "${" in str(f):
            raise NetworkError(f"{f}: its path holds '${{', which SUMO reads in a file name as an environment "
                               "variable; move the scenario to a folder without it")
    check_scenario(sc.network_path, [j.id for j in sc.controlled_junctions()], edges)
    check_sumo_args(tuple(sc.sumo.extra_args))


def check_demand(sc: scenario_mod.Scenario, seed: int | None, duration_s: float | None) -> int:
    """Build the run's whole demand as the run will (counts, intervals, route files,
    ``[[vehicles]]``, corridor flows) from the network file, SUMO not started; any error in it is a
    :class:`~nrtraffic.scenario.ScenarioError` (exit 2) naming what is wrong, not a failure once
    SUMO runs. Returns the number of departures."""
    import xml.etree.ElementTree as ET

    from nrtraffic.demand import Demand

    try:
        demand = Demand.of(sc, seed, duration_s)
        departures = demand.departures()
        d_run = float(sc.general.duration_s if duration_s is None else duration_s)
        if not any(d_run <= 0 or v[2] < d_run for v in departures):  # (a run of no vehicle: nothing done, "ok")
            d = sc.demand
            where = (f"demand.sumo_routes has no departure from scenario.begin_s = {sc.general.begin_s:g} s on"
                     if d.sumo_routes else
                     (f"from demand.begin_s = {d.begin_s:g} s to "
                     + (f"demand.end_s = {d.end_s:g} s" if d.end_s else f"the run's end at {d_run:g} s")
                     + f", its rates and counts give none{f' with seed {seed}' if seed is not None else ''}"))
            if d.sumo_routes and d.scale != 1.0:
                where += f" once demand.scale = {d.scale:g} has scaled it"
            if departures:
                where = f"its first departure is at {min(v[2] for v in departures):g} s, after the run's {d_run:g} s"
                if d.sumo_routes and d.depart_offset_s:
                    where += f" (demand.depart_offset_s = {d.depart_offset_s:g} s shifts each departure)"
            raise scenario_mod.ScenarioError(f"the demand gives the run no vehicle ({where}): check the demand, "
                                             "and the run's length (--duration, scenario.duration_s)")
        _check_depart_speeds(sc, demand, [*departures, *demand.background])  # (SUMO inserts both)
        check_window(sc, duration_s)  # (last: what is wrong in the scenario itself is said first)
        return len(departures)
    except scenario_mod.ScenarioError:
        raise
    except NetworkError:
        raise
    except ET.ParseError as exc:
        raise scenario_mod.ScenarioError(f"demand: a route file is not valid XML: {exc}") from None
    except (ValueError, KeyError, ZeroDivisionError, OverflowError) as exc:
        raise scenario_mod.ScenarioError(f"demand: {exc}") from None


def check_window(sc: scenario_mod.Scenario, duration_s: float | None) -> None:
    """The measurement window (``outputs.warmup_s`` to ``outputs.measure_end_s``, or to the end of
    the run) measures something: one that starts at or after the end of the run is a
    :class:`~nrtraffic.scenario.ScenarioError` (exit 2) naming the keys and the fix. A run until
    every vehicle has left (duration 0) has no known end, and is not checked."""
    o = sc.outputs
    d = float(sc.general.duration_s if duration_s is None else duration_s)
    if d <= 0:
        return
    given = "--duration" if duration_s is not None else "scenario.duration_s"
    lengthen = "--duration, or scenario.duration_s" if duration_s is not None else "scenario.duration_s, or --duration"
    if o.warmup_s >= d:
        end = (f"outputs.measure_end_s = {o.measure_end_s:g} s, cut there" if o.measure_end_s
               else "outputs.measure_end_s = 0: the end of the run")
        raise scenario_mod.ScenarioError(
            f"the measurement window is {'empty' if o.warmup_s == d else 'inverted'}: it starts at outputs.warmup_s = "
            f"{o.warmup_s:g} s, {'when' if o.warmup_s == d else 'after'} the run ends at {d:g} s ({given}; {end}), "
            f"so it would measure nothing. Lengthen the run ({lengthen}) past {o.warmup_s:g} s, "
            "or lower outputs.warmup_s (e.g. --set outputs.warmup_s=0)")


def _check_depart_speeds(sc: scenario_mod.Scenario, demand, departures) -> None:
    """No departure faster than the speed limit of its first edge, which SUMO refuses once it
    runs ("Departure speed ... too high for the departure edge"), nor faster than its type can stop
    from before a link where it must give way (SUMO discards it: "will not be able to depart"), and
    no ``[[vehicles]]`` placed beyond its end (SUMO moved it to the end without a word)."""
    from nrtraffic.sumo.adapter import VehicleType
    from nrtraffic.sumo.network import give_way_room, read_net, safe_depart_speed

    net = read_net(sc.network_path)
    limit: dict[str, float] = {}
    listed = {v.id for v in sc.vehicles}
    firsts: dict[str, str] = {}  # route -> its first edge (a route is shared by many vehicles)
    def where(vid: str) -> str:  # (the key that sets a departure's speed, named only in a refusal)
        return (f"vehicles.{vid}.depart_speed_mps" if vid in listed else
                "its departSpeed in demand.sumo_routes" if sc.demand.sumo_routes else "demand.entry_speed_mps")

    dt = sc.sumo.step_length_s
    length = sc.vehicle.params().length
    for vid, route, _, speed, pos, kind, *_ in departures:
        first = firsts.get(route) or firsts.setdefault(route, demand.route_edges(route)[0])
        if first not in limit:
            limit[first] = net.getEdge(first).getSpeed() if net.hasEdge(first) else float("inf")
        if vid in listed and net.hasEdge(first) and pos > net.getEdge(first).getLength() + 1e-9:
            raise scenario_mod.ScenarioError(
                f"vehicles.{vid}.depart_pos_m = {pos:g} m lies beyond its first edge {first} "
                f"({net.getEdge(first).getLength():.1f} m long): give a position on it")
        if speed > limit[first] + 1e-9:
            raise scenario_mod.ScenarioError(
                f"vehicle {vid} departs at {speed:g} m/s on edge {first}, whose speed limit is {limit[first]:g} m/s "
                f"(SUMO refuses it): lower {where(vid)}")
        human = kind == "human"
        decel = sc.human.decel_mps2 if human else VehicleType.decel_mps2
        room = give_way_room(net, demand.route_edges(route), pos if pos >= 0 else length)
        if room is not None and speed > safe_depart_speed(room[0], decel, dt) + 1e-9:
            # (SUMO's insertion check, a little stricter (safe_depart_speed): the driver must be able to
            # stop, braking at its decel from the next step on, before a link where it has no priority;
            # else SUMO discards the vehicle)
            need = speed * speed / (2 * (room[0] - speed * dt)) if room[0] > speed * dt else float("inf")
            fix = (f"raise human.decel_mps2 (a driver's comfortable deceleration) to at least {need:.2f} m/s^2, or "
                   f"lower {where(vid)}" if human else f"lower {where(vid)}, or start its route further upstream")
            raise scenario_mod.ScenarioError(
                f"vehicle {vid} departs at {speed:g} m/s and, braking at {decel:g} m/s^2, could not stop in the "
                f"{room[0]:.1f} m before the junction {room[1]} where it must give way (SUMO would discard it: "
                f"\"will not be able to depart\"): {fix}")


def prepare_run_dir(sc: scenario_mod.Scenario, out: Path) -> Path:
    """Check the scenario against its network (:func:`check`), then create ``out`` with the SUMO
    network copied in."""
    check(sc)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    begin_manifest(out, run_file_names(sc))
    (out / "sumo").mkdir(exist_ok=True)
    net = sc.network_path
    copies = [(net, out / "sumo" / net.name)] + [(src, out / name) for src, name in route_copies(sc)]
    for src, dst in copies:
        if src.resolve() != dst.resolve():
            try:
                shutil.copyfile(src, dst)
            except OSError as exc:  # (named as the copy it is, not as the user's file it reads)
                raise OSError(exc.errno, exc.strerror, str(dst)) from None
    return out


def route_copies(sc: scenario_mod.Scenario) -> list[tuple[Path, str]]:
    """The scenario's route files (``demand.sumo_routes``) and the names of their copies in a run
    directory (``sumo/``, beside the network's), so that the run can be replayed from it alone."""
    out, used = [], {sc.network_path.name, "routes.rou.xml", "run.sumocfg", "queues.add.xml", "tls_offsets.add.xml"}
    for f in (sc.demand.route_files(sc.base_dir) if sc.demand.sumo_routes else []):
        name, k = f.name, 1
        while name in used:
            name, k = f"{k}_{f.name}", k + 1
        used.add(name)
        out.append((f, f"sumo/{name}"))
    return out


def run_scenario(sc: scenario_mod.Scenario, out: Path, seed: int | None = None, duration_s: float | None = None,
                 progress: bool = False, gui: bool = False, gui_delay_ms: float = 100.0,
                 report: bool = False) -> RunResult:
    """Run ``sc`` and write the run directory ``out``; raises :class:`RunFailed` after writing what
    was finished when the run stops early. ``gui``: in sumo-gui (:class:`~nrtraffic.sumo.adapter.SumoSession`),
    ``gui_delay_ms`` [ms] between its steps. ``report``: also the figures and ``report.html``
    (:func:`execute`)."""
    return execute(sc, prepare_run_dir(sc, out), seed, duration_s, progress, report=report, gui=gui,
                   gui_delay_ms=gui_delay_ms)


def resolve(sc: scenario_mod.Scenario, seed: int | None, duration_s: float | None) -> scenario_mod.Scenario:
    """The scenario with the seed and duration a run uses made explicit."""
    general = dataclasses.replace(sc.general, seed=int(sc.general.seed if seed is None else seed),
                                  duration_s=float(sc.general.duration_s if duration_s is None else duration_s))
    return dataclasses.replace(sc, general=general)


def resolved_text(sc: scenario_mod.Scenario, seed: int | None, duration_s: float | None) -> str:
    """``scenario.resolved.toml`` of a run of ``sc`` (its network and route files copied into
    ``sumo/``; what a ``scenario.sumocfg`` gave is written out as keys)."""
    return scenario_mod.dumps(resolve(sc, seed, duration_s), network=f"sumo/{sc.network_path.name}",
                              sumo_routes=",".join(name for _, name in route_copies(sc)) or None)


# the run directory's list of what the run created in it (``--force`` removes those, and nothing else)
MANIFEST = "manifest.json"
# what a run of an earlier version (without a manifest) wrote into its directory
RUN_FILES = ("summary.json", "vehicles.csv", "movements.csv", "approaches.csv", "trajectories.parquet",
             "trajectories.parquet.tmp", "trajectories.partial.arrows", "scenario.resolved.toml", "movements.json",
             "movements.png", "delays.png", "queues.png", "time_space.png", "arterial.png", "report.html", "tripinfo.xml",
             "collisions.xml", "fcd.xml", "queues.xml", "movements.json.tmp", "summary.json.tmp", "vehicles.csv.tmp", "movements.csv.tmp",
             "approaches.csv.tmp")


def _tree(out: Path) -> set[str]:
    """Every file and folder under ``out``, relative to it (POSIX paths), but the lock of a run
    writing there (:data:`LOCK`)."""
    return {p.relative_to(out).as_posix() for p in out.rglob("*")} - {LOCK}


# the file that marks a folder as being written (``nrtraffic <pid> <start>``: the process writing it
# and when it started): a second run into it, or a --force on it, is refused while that process runs
LOCK = ".nrtraffic-running"


def lock_run_dir(out: Path) -> None:
    """Mark ``out`` (an existing folder) as being written by this process, or ValueError where
    another process that still runs is writing there, or where a file of that name is not such a
    lock (a file of the user's, a link, a folder: refused, never removed). The lock of a process
    that is gone (a run killed outright; its process id taken by another program since) is taken
    over."""
    path = Path(out) / LOCK
    for _ in range(3):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            holder = _lock_holder(path)
            if holder is None:
                raise ValueError(f"--out {out} holds {LOCK}, which is not a run's lock (a file of your own?): move it, "
                                 "or choose another folder") from None
            if holder != (os.getpid(), _started(os.getpid())) and _running(*holder):
                raise ValueError(f"--out {out} is being written by another run (process {holder[0]}): wait until it "
                                 f"has ended, or choose another folder (if no run writes there, remove {path})") from None
            with contextlib.suppress(OSError):  # (stale: its process is gone)
                path.unlink()
            continue
        except OSError as exc:
            raise ValueError(f"--out {out}: cannot write there: {exc.strerror or exc}") from None
        with os.fdopen(fd, "w") as f:
            f.write(f"nrtraffic {os.getpid()} {_started(os.getpid())}\n")
        return
    raise ValueError(f"--out {out}: another run takes it at the same moment; choose another folder")


def holds_files(out: Path) -> bool:
    """Whether the folder ``out`` holds anything but the lock of a run writing there (:data:`LOCK`)."""
    return any(p.name != LOCK for p in Path(out).iterdir())


def unlock_run_dir(out: Path) -> None:
    """Remove this process's lock of ``out`` (:func:`lock_run_dir`), if it holds one."""
    path = Path(out) / LOCK
    if _lock_holder(path) == (os.getpid(), _started(os.getpid())):
        with contextlib.suppress(OSError):
            path.unlink()


def _lock_holder(path: Path) -> tuple[int, str] | None:
    """The process id and start of the lock ``path``, or None where it is no lock of a run (a link,
    a folder, another content)."""
    if path.is_symlink() or not path.is_file():
        return None
    try:
        word, pid, started = path.read_text()[:200].split()
        return (int(pid), started) if word == "nrtraffic" and pid.isdigit() else None
    except (OSError, ValueError):
        return None


def _started(pid: int) -> str:
    """When process ``pid`` started (its start time in clock ticks since boot, /proc/<pid>/stat), so
    that a process id taken again by another program is not taken for the run's; "-" where unknown."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return "-"


def _running(pid: int, started: str) -> bool:
    """Whether the process ``pid`` that started at ``started`` (:func:`_started`) still runs."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # (another user's: it runs)
        pass
    except (OSError, OverflowError, ValueError):  # (no such process id at all)
        return False
    now = _started(pid)
    return started == "-" or now == "-" or now == started


def read_manifest(out: Path, sweep: bool = False) -> dict | None:
    """``out``'s manifest when it is a run's (a JSON object whose ``preexisting`` and ``created`` are
    lists of paths), or with ``sweep`` a sweep's (the same, marked ``"sweep": 1``: a command that
    replaces a run never takes it for one); else None (a file of that name of the user's own, or a
    damaged one)."""
    try:
        m = json.loads((Path(out) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or set(m) != {"preexisting", "created", *(("sweep",) if sweep else ())}:
        return None
    lists = (m["preexisting"], m["created"])
    if (sweep and m["sweep"] != 1) or not all(isinstance(v, list) and all(isinstance(x, str) for x in v)
                                              for v in lists):
        return None
    return m


def run_file_names(sc: scenario_mod.Scenario) -> list[str]:
    """The files (and the ``sumo`` folder) a run of ``sc`` may write into its directory while it
    simulates, by name: SUMO's outputs only where ``[outputs]`` asks for them. (Its tables are
    listed just before each checkpoint writes them, :func:`plan_manifest`; its figures and report
    come at its end, and the manifest lists them once written.)"""
    o = sc.outputs
    skip = set(REPORT_FILES) | set(TABLE_FILES) | ({"fcd.xml"} if not o.sumo_fcd else set()) | (
        {"tripinfo.xml"} if not o.sumo_tripinfo else set()) | ({"collisions.xml"} if not o.sumo_collisions else set())
    return [*(n for n in RUN_FILES if n not in skip), "sumo", "sumo/routes.rou.xml", "sumo/run.sumocfg",
            "sumo/queues.add.xml", f"sumo/{sc.network_path.name}", *(name for _, name in route_copies(sc))]


# what a run writes at its end, only where its data has them: its figures and report
REPORT_FILES = ("movements.png", "delays.png", "queues.png", "time_space.png", "arterial.png", "report.html")
# what a run writes at each checkpoint, each under its temporary name first
TABLES = ("vehicles.csv", "movements.csv", "approaches.csv")
TABLE_FILES = (*TABLES, *(t + ".tmp" for t in TABLES))


def begin_manifest(out: Path, planned=()) -> None:
    """Start ``out``'s manifest: what is there before the run (none of it is the run's), and as
    created already the names of ``planned`` that are not there: the run's files are listed before
    they are written, so that a run killed outright (or stopped by a full disk) can still be
    replaced with ``--force``."""
    out = Path(out)
    pre = sorted(_tree(out) - {MANIFEST})
    _write_json(out / MANIFEST, {"preexisting": pre, "created": sorted(set(planned) - set(pre) - {MANIFEST})})


def update_manifest(out: Path, final: bool = False) -> None:
    """Record in ``out``'s manifest every file and folder the run has created so far (all that is
    there now and was not before it); called with every checkpoint, keeping the names still to be
    written (:func:`begin_manifest`). ``final`` (the run's last word): only what it did write, so
    that a file of the user's that later takes the name of one it did not write (``fcd.xml``, a
    figure) is never taken for the run's."""
    out = Path(out)
    m = read_manifest(out)
    if m is None:
        return
    pre = set(m.get("preexisting", []))
    written = _tree(out) - pre - {MANIFEST}
    m["created"] = sorted(written if final else written | set(m.get("created", [])))
    _write_json(out / MANIFEST, m)


def plan_manifest(out: Path, names) -> None:
    """Add ``names`` to ``out``'s manifest as created, just before the run writes them: a run killed
    while it writes them can still be replaced with ``--force``, and one killed before never claims
    a file of that name that the user puts there afterwards."""
    out = Path(out)
    m = read_manifest(out)
    if m is None or set(names) <= set(m["created"]):
        return
    m["created"] = sorted((set(m["created"]) | set(names)) - set(m["preexisting"]) - {MANIFEST})
    _write_json(out / MANIFEST, m)


def _write_json(path: Path, obj) -> None:
    write_atomic(path, (json.dumps(obj, indent=1) + "\n").encode())


def claim_run_dir(out: Path, sc: scenario_mod.Scenario, seed: int | None, duration_s: float | None, control: str,
                  force: bool = False) -> None:
    """Make ``out`` ready for a run: a missing or empty folder, or a finished run of the same
    configuration and control (run again), is taken as it is. Any other non-empty folder is refused
    (ValueError) unless ``force``; then what the earlier run created there (its manifest,
    :data:`MANIFEST`) is removed first, so that nothing of it stays beside the new one, and nothing
    else is: a non-empty folder without a manifest (the user's own files, or a run of an earlier
    version) is refused even with ``force``. A folder in a sweep's folder is the sweep's, and refused
    (:func:`in_a_sweep`). An existing ``out`` is locked for the run (:func:`lock_run_dir`), also
    against a run that is writing it now; a refusal leaves it unlocked."""
    out = Path(out)
    owner = in_a_sweep(out)
    if owner is not None:
        raise ValueError(f"--out {out} lies in the sweep folder {owner}: its run folders are the sweep's own (its "
                         "tables and resumes read them); choose a folder outside it")
    inside = in_a_run(out)
    if inside is not None:
        raise ValueError(f"--out {out} lies in the run directory {inside}: its files would be taken for that run's "
                         "(and a --force on it would remove them); choose a folder outside it")
    if not out.is_dir():
        return
    lock_run_dir(out)  # (before anything of an earlier run there goes: held until the run ends, unlock_run_dir)
    try:
        if not holds_files(out):
            return
        same = False
        try:
            s = json.loads((out / "summary.json").read_text())
            same = (s.get("status") == "ok" and s.get("control") == control
                    and (out / "scenario.resolved.toml").read_text() == resolved_text(sc, seed, duration_s))
        except (OSError, ValueError):
            pass
        m = read_manifest(out)
        if not (same or force) and m is not None:
            raise ValueError(f"--out {out} is not empty and is not a finished run of this configuration: "
                             "choose another folder, or --force to replace the run in it")
        if m is None:
            raise ValueError(f"--out {out} is not empty and holds no run's {MANIFEST} (files of your own, or a run of "
                             "an earlier version): a run is written only into an empty folder or over a run that "
                             "recorded its files there (--force removes those alone); choose another folder, or empty "
                             "this one yourself")
        # what the new run writes must not meet a file that no earlier run there created (the user's)
        ours = set(m["created"])
        # (every name a run may write or read: a stray fcd.xml would be read for its figures)
        # (a link counts, also one to nothing: the run would write where it points; so does its sumo/
        # folder replaced by a link, where that folder was there before the run)
        clash = sorted(n for n in {*RUN_FILES, *run_file_names(sc)} if n not in ours
                       and ((out / n).is_symlink() or (n != "sumo" and (out / n).exists())))
        if clash:
            named = ", ".join(f"{n} (a link)" if (out / n).is_symlink() else n for n in clash)
            raise ValueError(f"--out {out} holds {named}, which no earlier run there created (files of your "
                             "own?): a run would write over them, or through a link; choose another folder")
        remove_run_files(out, keep=sc.network_path)
    except BaseException:
        unlock_run_dir(out)
        raise


def in_a_sweep(path: Path) -> Path | None:
    """The sweep folder (one with a sweep's manifest) that ``path`` is, or lies in; or where ``path``
    is or lies in a sweep's run folder (one with its fingerprint, as every version of the sweep
    wrote), that sweep's folder (above its ``runs/``); None."""
    from runners.sweep import FINGERPRINT

    for p in _places(path):
        for q in (p, *p.parents):
            if read_manifest(q, sweep=True) is not None:
                return q
            if (q / FINGERPRINT).is_file():
                return next((r.parent for r in q.parents if r.name == "runs"), q)
    return None


def in_a_run(path: Path) -> Path | None:
    """The run directory (:func:`is_run_dir`) that ``path`` lies in, below it (as given, or through
    its links); None. Whatever is written there would be taken for that run's
    files, and a ``--force`` on it would remove them."""
    for p in _places(path):
        for q in p.parents:
            if is_run_dir(q):
                return q
    return None


def is_run_dir(path: Path) -> bool:
    """Whether ``path`` is a run directory: a ``summary.json`` beside a run's manifest, or beside the
    ``scenario.resolved.toml`` of a run of an earlier version."""
    path = Path(path)
    return (path / "summary.json").is_file() and (read_manifest(path) is not None
                                                  or (path / "scenario.resolved.toml").is_file())


def normal(path: Path) -> Path:
    """``path`` made absolute, its ``..`` taken lexically (not through links: :func:`_places`)."""
    return Path(os.path.normpath(Path(path).absolute()))


def _places(path: Path) -> tuple[Path, ...]:
    """Where ``path`` is: as given (:func:`normal`), and through its links (once where they agree)."""
    return tuple(dict.fromkeys((normal(path), Path(path).resolve())))


def remove_run_files(out: Path, keep: Path | None = None) -> None:
    """Remove from ``out`` what the run recorded in its manifest as created (files, then the folders
    it created once they are empty), and the manifest; nothing else. Without a manifest (a finished
    run of an earlier version): the files such a run wrote at the top of ``out``
    (:data:`RUN_FILES`), never anything in ``sumo/``. ``keep`` (the scenario's own network, where
    ``out`` is its folder) always stays, and so does anything outside ``out`` (a listed path with
    ``..`` or absolute, or reached through a link) or listed as there before the run."""
    out = Path(out)
    m = read_manifest(out)
    created, pre = (m["created"], set(m["preexisting"])) if m is not None else (list(RUN_FILES), set())
    kept = Path(keep).resolve() if keep is not None else None
    inside = out.resolve()
    for rel in sorted(created, key=lambda r: r.count("/"), reverse=True):  # deepest first
        p = out / rel
        if rel in pre or Path(rel).is_absolute() or ".." in Path(rel).parts:
            continue  # (never what was there before, nor anything outside the folder)
        if not p.parent.resolve().is_relative_to(inside):
            continue  # (a folder of the run replaced by a link to elsewhere: what is there is not the run's)
        if kept is not None and p.exists() and p.resolve() == kept:
            continue
        if p.is_symlink() or p.is_file():
            p.unlink()
        elif p.is_dir():
            try:
                p.rmdir()  # (only when empty: what the run did not create in it stays)
            except OSError:
                pass
    for name in (MANIFEST, MANIFEST + ".tmp"):
        (out / name).unlink(missing_ok=True)


def execute(sc: scenario_mod.Scenario, out: Path, seed: int | None, duration_s: float | None, progress: bool,
            extra_summary: dict | None = None, report: bool = False, **engine_options) -> RunResult:
    """Record the configuration actually used (seed, duration) in ``scenario.resolved.toml``, run
    the engine (``engine_options`` go to :class:`Engine`) and write the results into the prepared
    run directory ``out``, also when the run stops early. ``report``: the figures and
    ``report.html`` too, made before the final ``summary.json``: until they are written it says
    ``"status": "running"``, and where they cannot be, ``"failed"`` and why (:class:`RunFailed`).
    The run's status is always the last file written."""
    resolved = resolve(sc, seed, duration_s)
    (out / "scenario.resolved.toml").write_text(resolved_text(sc, seed, duration_s))
    # a summary from the start, that holds the space of the last one (write_summary): a run that
    # fills the disk still ends with one that says so
    write_summary(out / "summary.json", {"scenario": sc.general.name, "control": engine_options.get("label", "nrtraffic"),
                                         "seed": resolved.general.seed, "status": "running", "error": None,
                                         "sim_time_s": 0.0, **(extra_summary or {})})
    writer = TrajectoryWriter(out / "trajectories.parquet")

    def checkpoint(result: RunResult) -> None:
        result.summary.update(extra_summary or {})
        _write(result, out)

    def failed(error: str, sim_time_s: float = 0.0) -> RunFailed:  # nothing the engine could write: say so
        try:
            writer.close()  # (nothing, where the engine closed it)
        except Exception:  # noqa: BLE001 - (a full disk, or a writer stopped mid-step): the summary comes first
            pass
        summary = {"scenario": sc.general.name, "control": engine_options.get("label", "nrtraffic"),
                   "seed": resolved.general.seed, "status": "failed", "sim_time_s": sim_time_s,
                   "error": _named(error), **(extra_summary or {})}
        write_summary(out / "summary.json", summary)
        update_manifest(out, final=True)
        return RunFailed(summary["error"], RunResult(summary, pd.DataFrame(), out))

    if engine_options.get("control", True):
        _kernel_cache.announce()  # the first run after installing compiles the kernels (numba)
    engine = None
    try:
        interrupts.arm()  # a SIGTERM or Ctrl-C that came during the checks stops the run here
        engine = Engine(resolved, out, trajectories=writer, progress=progress, checkpoint=checkpoint,
                        stop_requested=interrupts.received,
                        **engine_options)
        result = engine.run()  # (turns an interrupt while it runs into RunFailed)
    except KeyboardInterrupt as exc:  # before the engine ran, or while it gathered its figures
        t = engine.t if engine is not None else 0.0
        when = f"at t={t:.2f} s, its figures not gathered" if t > 0 else "before the simulation started"
        raise failed(f"stopped {when}: {describe(exc)}", t) from exc
    except NetworkError:  # the junction or its zones do not suit: nothing was simulated, nothing is kept
        update_manifest(out)
        remove_run_files(out, keep=sc.network_path)
        raise
    except RunFailed as exc:
        exc.result.summary.update(extra_summary or {})
        exc.result.summary["error"] = _named(exc.result.summary.get("error") or str(exc))
        try:
            _write(exc.result, out, final=True)
        except OSError as werr:
            raise RunFailed(f"{exc}; and the figures could not be written into {out}: {werr}", exc.result) from exc
        raise
    except Exception as exc:  # the figures of a stopped run could not be gathered (SUMO's outputs cut short)
        t = engine.t if engine is not None else 0.0
        raise failed(f"run stopped at t={t:.2f} s, and its figures could not be gathered: {type(exc).__name__}: {exc}",
                     t) from exc
    result.summary.update(extra_summary or {})
    interrupts.defer()  # the run is done: a signal now lets its figures and report be finished
    status = result.summary.get("status")
    if report:  # (its status waits for the report: a run whose report failed never says ok)
        result.summary["status"] = "running"
    try:
        _write(result, out, final=not report)
    except OSError as exc:
        raise RunFailed(f"the run finished, but its figures could not be written into {out}: {exc}", result) from exc
    if report:
        result.summary["status"] = status
        _report(result, out)
    return result


def _report(result: RunResult, out: Path) -> None:
    """The run's figures and ``report.html`` (:func:`~nrtraffic.report.run_report`, which shows the
    run's final status), the manifest, then ``summary.json`` with that status, the last file
    written. Where the report cannot be made (a full disk, an error in a figure; an interrupt
    outside the command), ``summary.json`` says ``"status": "failed"`` and why, and
    :class:`RunFailed` is raised."""
    from nrtraffic import report

    try:
        # (listed before they are drawn: a run killed while it draws them can still be replaced with --force)
        plan_manifest(out, REPORT_FILES)
        report.run_report(out, summary=result.summary)
    except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - any of them leaves the run without its report
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else f"{type(exc).__name__}: {exc}"
        s = result.summary
        s["status"] = "failed"
        s["error"] = _named(f"the run finished, but its report could not be written: {why}")
        raise RunFailed(s["error"], result) from exc
    finally:  # the manifest, then the summary with the run's status: the last file written
        try:
            update_manifest(out, final=True)
        except OSError:
            pass  # (a full disk: the manifest keeps what it had; the summary holds its space)
        write_summary(out / "summary.json", result.summary)


def _named(error: str) -> str:
    """``error``, with the signal that stopped the run where the error does not name it (a library
    stopped mid-call may raise an error of its own)."""
    sig = interrupts.received()
    return error if sig is None or sig in error else f"stopped by {sig}: {error}"


def _write(result: RunResult, out: Path, final: bool = False) -> None:
    """vehicles.csv, movements.csv, then summary.json (each under a temporary name, renamed when
    whole), and the manifest (``final``: the run writes nothing more, :func:`update_manifest`). Where
    a table cannot be written (a full disk), summary.json still is, saying ``"status": "failed"``
    and why (in the space the earlier summary holds), and the OSError goes on."""
    try:
        tables = [t for t in TABLES if t != "approaches.csv" or "approaches" in result.extra]
        plan_manifest(out, [n for t in tables for n in (t, t + ".tmp")])
        write_vehicles(out / "vehicles.csv", result.vehicles)
        write_movements(out / "movements.csv", result)
        if "approaches" in result.extra:
            write_table(out / "approaches.csv", result.extra["approaches"])
    except OSError as exc:
        s = result.summary
        s["status"] = "failed"
        s["error"] = (f"{s['error']}; " if s.get("error") else "") + f"the run's tables could not be written: {exc}"
        write_summary(out / "summary.json", s)
        raise
    write_summary(out / "summary.json", result.summary)
    try:
        update_manifest(out, final=final)
    except OSError:
        pass  # (a full disk: the manifest keeps what it had)
