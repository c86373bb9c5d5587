"""``nrtraffic replay``: re-run a finished run from its ``scenario.resolved.toml`` and compare.

A run is deterministic for a given seed and machine (one seeded generator, SUMO's ``--seed``, no
wall-clock input), so a replay on the same machine reproduces it exactly. The comparison still
allows a tolerance, ``|replayed - recorded| <= atol + rtol * |recorded|`` on every number, so that
a replay on another machine (other floating-point kernels) passes when the run agrees to that
precision:

- ``summary.json``: every number except those of the wall clock (``wall_time_s``,
  ``real_time_factor``, ``wall_time_breakdown_s``) and the versions;
- ``vehicles.csv``: the same vehicles; every number of every vehicle, and the text columns equal;
- ``movements.csv`` and ``approaches.csv``: every number; ``sumo/routes.rou.xml``: the departures;
- SUMO's ``tripinfo.xml``, ``collisions.xml`` and ``queues.xml``: the same trips, collisions and
  detector intervals, attribute by attribute;
- ``movements.json``: the junction's geometry as the run built it, every number;
- ``trajectories.parquet``: the same log instants per vehicle; every number at every instant.

NaN equals NaN (a figure that does not apply in both).

The report (``report.html``) and the figures are drawn from these tables and are not compared: their
pixels depend on the machine's fonts and Matplotlib.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from nrtraffic.results import read_parquet_file

RTOL = 1e-6
ATOL = 1e-6
WALL_CLOCK = {"wall_time_s", "real_time_factor", "wall_time_breakdown_s", "nrtraffic_version", "sumo_version"}


class ReplayError(ValueError):
    """The folder is not a complete run directory."""


@dataclass(frozen=True)
class Difference:
    where: str  # "summary", "vehicles.csv" or "trajectories.parquet"
    what: str  # figure / vehicle and column
    recorded: object
    replayed: object

    def __str__(self) -> str:
        try:
            delta = f" (difference {float(self.replayed) - float(self.recorded):+.6g})"
        except (TypeError, ValueError):
            delta = ""
        return f"{self.where}: {self.what}: recorded {self.recorded!r}, replayed {self.replayed!r}{delta}"


def _close(a, b, rtol: float, atol: float) -> bool:
    if a is None or b is None:
        return a is None and b is None
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    a, b = float(a), float(b)
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(b - a) <= atol + rtol * abs(a)


def _unit(name: str) -> float:
    """One unit of the resolution a table's figure ``name`` is written with
    (:data:`nrtraffic.results.RESOLUTIONS`): two runs within the tolerance may round a figure on
    either side of a last digit."""
    from nrtraffic.results import decimals_of

    return 10.0 ** -decimals_of(name) * (1 + 1e-9)


def compare_summaries(rec: dict, new: dict, rtol: float = RTOL, atol: float = ATOL) -> list[Difference]:
    """Differences between two summaries: a figure differs when it differs by more than
    ``atol + rtol |recorded|`` plus one unit of its written resolution (:func:`_unit`)."""
    out = []
    for k in sorted(set(rec) | set(new)):
        if k in WALL_CLOCK:
            continue
        a, b = rec.get(k, "<absent>"), new.get(k, "<absent>")
        if isinstance(a, (dict, list)) or isinstance(b, (dict, list)):
            if a != b:
                out.append(Difference("summary", k, a, b))
        elif not _close(a, b, rtol, atol + (_unit(k) if isinstance(a, float) or isinstance(b, float) else 0.0)):
            out.append(Difference("summary", k, a, b))
    return out


def _compare_frames(where: str, rec: pd.DataFrame, new: pd.DataFrame, keys: list[str], rtol: float,
                    atol: float, limit: int, rounded: bool = False) -> list[Difference]:
    """Differences between two tables by the rows of ``keys``; ``rounded``: a written table, whose
    figures may also differ by one unit of their resolution (:func:`_unit`)."""
    out = []
    lost = [k for k in keys if k not in rec.columns or k not in new.columns]
    if lost or not keys:  # (an edited or damaged table: its rows cannot be matched)
        return [Difference(where, "key columns", ", ".join(k for k in keys if k in rec.columns) or "none",
                           ", ".join(k for k in keys if k in new.columns) or "none")]
    for c in sorted(set(rec.columns) ^ set(new.columns)):
        out.append(Difference(where, f"column {c}", "present" if c in rec else "absent",
                              "present" if c in new else "absent"))
    for name, t in (("recorded", rec), ("replayed", new)):
        twice = t.duplicated(keys)
        if twice.any():  # (rows that share their keys cannot be matched one to one: an edited file)
            row = t[twice].iloc[0]
            out.append(Difference(where, f"{_label(keys, tuple(row[k] for k in keys))}",
                                  f"{name}: {int(twice.sum())} row(s) repeat their {', '.join(keys)}", "once each"))
            return out
    rec_i, new_i = rec.set_index(keys), new.set_index(keys)
    missing = rec_i.index.difference(new_i.index)
    extra = new_i.index.difference(rec_i.index)
    for idx in list(missing)[:limit]:
        out.append(Difference(where, f"{_label(keys, idx)}", "present", "absent"))
    for idx in list(extra)[:limit]:
        out.append(Difference(where, f"{_label(keys, idx)}", "absent", "present"))
    common = rec_i.index.intersection(new_i.index)
    cols = [c for c in rec.columns if c in new.columns and c not in keys]
    a, b = rec_i.loc[common, cols], new_i.loc[common, cols]
    for c in cols:
        x, y = a[c], b[c]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            xv, yv = x.to_numpy(float), y.to_numpy(float)
            tol = atol + (_unit(c) if rounded else 0.0)
            bad = ~(np.isclose(yv, xv, rtol=rtol, atol=tol) | (np.isnan(xv) & np.isnan(yv)))
        else:
            both_null = x.isna().to_numpy() & y.isna().to_numpy()
            bad = ~both_null & (x.astype(str) != y.astype(str)).to_numpy()
        for i in np.flatnonzero(bad)[:limit]:
            out.append(Difference(where, f"{_label(keys, common[i])} {c}", _py(x.iloc[i]), _py(y.iloc[i])))
    return out


def _label(keys, idx) -> str:
    idx = idx if isinstance(idx, tuple) else (idx,)
    return ", ".join(f"{k} {_py(v)}" for k, v in zip(keys, idx))


def _py(v):
    return v.item() if isinstance(v, np.generic) else v


def compare_runs(recorded: Path, replayed: Path, rtol: float = RTOL, atol: float = ATOL,
                 limit: int = 5) -> list[Difference]:
    """Differences between two run directories (at most ``limit`` per column and table)."""
    recorded, replayed = Path(recorded), Path(replayed)
    diffs = compare_summaries(json.loads((recorded / "summary.json").read_text()),
                              json.loads((replayed / "summary.json").read_text()), rtol, atol)
    v_rec = pd.read_csv(recorded / "vehicles.csv", dtype={"vehicle_id": str})
    v_new = pd.read_csv(replayed / "vehicles.csv", dtype={"vehicle_id": str})
    if "vehicle_id" not in v_rec.columns or "vehicle_id" not in v_new.columns:  # (edited or damaged)
        return diffs + [Difference("vehicles.csv", "column vehicle_id", *("present" if "vehicle_id" in t.columns
                                                                          else "absent" for t in (v_rec, v_new)))]
    corridor = "leg" in v_rec.columns and "leg" in v_new.columns and (
        v_rec["vehicle_id"].duplicated().any() or v_new["vehicle_id"].duplicated().any())
    keys = ["vehicle_id", "leg"] if corridor else ["vehicle_id"]  # (on a corridor a row per crossing)
    diffs += _compare_frames("vehicles.csv", v_rec, v_new, keys, rtol, atol, limit, rounded=True)
    t_rec, t_new = recorded / "trajectories.parquet", replayed / "trajectories.parquet"
    if t_rec.is_file() or t_new.is_file():
        if not (t_rec.is_file() and t_new.is_file()):
            diffs.append(Difference("trajectories.parquet", "file", t_rec.is_file(), t_new.is_file()))
        else:
            a, b = read_parquet_file(t_rec), read_parquet_file(t_new)
            a["vehicle_id"], b["vehicle_id"] = a["vehicle_id"].astype(str), b["vehicle_id"].astype(str)
            diffs += _compare_frames("trajectories.parquet", a, b, ["vehicle_id", "t"], rtol, atol, limit)
    for name, keys in (("movements.csv", ["junction", "approach", "movement"]), ("approaches.csv", ["approach"])):
        m_rec, m_new = recorded / name, replayed / name
        if m_rec.is_file() != m_new.is_file():
            diffs.append(Difference(name, "file", m_rec.is_file(), m_new.is_file()))
        elif m_rec.is_file():
            (a, ea), (b, eb) = _read(pd.read_csv, m_rec), _read(pd.read_csv, m_new)
            if ea or eb:  # (an emptied or garbled table: which one, and why)
                diffs.append(Difference(name, "readable", ea or True, eb or True))
                continue
            diffs += _compare_frames(name, a, b, [k for k in keys if k in a.columns or k in b.columns] or keys, rtol,
                                     atol, limit, rounded=True)
    r_rec, r_new = recorded / "sumo" / "routes.rou.xml", replayed / "sumo" / "routes.rou.xml"
    if r_rec.is_file() != r_new.is_file():
        diffs.append(Difference("sumo/routes.rou.xml", "file", r_rec.is_file(), r_new.is_file()))
    elif r_rec.is_file():  # (the demand SUMO was given: rebuilt from the configuration)
        (d_rec, ea), (d_new, eb) = _read(_departures, r_rec), _read(_departures, r_new)
        if ea or eb:
            diffs.append(Difference("sumo/routes.rou.xml", "readable", ea or True, eb or True))
        else:
            diffs += _compare_frames("sumo/routes.rou.xml", d_rec, d_new, ["id"], rtol, atol, limit)
    sumo_outputs = (("tripinfo.xml", "tripinfo", ["id"]),
                    ("collisions.xml", "collision", ["time", "collider", "victim", "type"]),
                    ("queues.xml", "interval", ["begin", "id"]))
    for name, tag, keys in sumo_outputs:
        x_rec, x_new = recorded / name, replayed / name
        if x_rec.is_file() != x_new.is_file():
            diffs.append(Difference(name, "file", x_rec.is_file(), x_new.is_file()))
        elif x_rec.is_file():  # (SUMO's own outputs: its trips, its collisions)
            (a, whole_a), (b, whole_b) = _elements(x_rec, tag), _elements(x_new, tag)
            if whole_a != whole_b:  # (a garbled or emptied file, or one with more after its end)
                diffs.append(Difference(name, "whole XML", whole_a, whole_b))
            elif len(a) != len(b):
                diffs.append(Difference(name, f"<{tag}> elements", len(a), len(b)))
            elif len(a):
                diffs += _compare_frames(name, a, b, [k for k in keys if k in a.columns and k in b.columns], rtol,
                                         atol, limit)
    m_rec, m_new = recorded / "movements.json", replayed / "movements.json"
    if m_rec.is_file() != m_new.is_file():
        diffs.append(Difference("movements.json", "file", m_rec.is_file(), m_new.is_file()))
    elif m_rec.is_file():  # (the junction's geometry as the run built it)
        (a, ea), (b, eb) = (_read(lambda p: json.loads(p.read_text()), p) for p in (m_rec, m_new))
        if ea or eb:
            diffs.append(Difference("movements.json", "readable", ea or True, eb or True))
        else:
            diffs += _compare_json("movements.json", "", a, b, rtol, atol)[:limit]
    return diffs


def _read(read, path: Path):
    """``(read(path), None)``, or ``(None, "not readable: <why>")`` for a file that is emptied or
    garbled, so that a difference says which of the two it was."""
    try:
        return read(path), None
    except (ValueError, ET.ParseError, pd.errors.EmptyDataError) as exc:
        return None, f"not readable: {type(exc).__name__}: {exc}"


def _compare_json(where: str, path: str, a, b, rtol: float, atol: float) -> list[Difference]:
    """Every difference between two JSON values: numbers within the tolerance, the rest equal."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [Difference(where, f"{path or '(top)'} keys", sorted(a), sorted(b))]
        return [d for k in a for d in _compare_json(where, f"{path}.{k}" if path else str(k), a[k], b[k], rtol, atol)]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [Difference(where, f"{path} length", len(a), len(b))]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _compare_json(where, f"{path}[{i}]", x, y, rtol, atol)]
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) and not isinstance(b, bool):
        same = (math.isnan(a) and math.isnan(b)) or abs(b - a) <= atol + rtol * abs(a)
        return [] if same else [Difference(where, path, a, b)]
    return [] if a == b else [Difference(where, path, a, b)]


def _elements(path: Path, tag: str) -> tuple[pd.DataFrame, bool]:
    """The attributes of every ``<tag>`` of a SUMO output file, a row each (numbers as numbers), up
    to its last whole element, and whether the file is whole XML."""
    rows, whole = [], True
    try:
        for _, el in ET.iterparse(path):
            if el.tag == tag:
                rows.append(dict(el.attrib))
    except ET.ParseError:
        whole = False
    df = pd.DataFrame(rows)
    for c in df.columns:
        num = pd.to_numeric(df[c], errors="coerce")
        if num.notna().all():
            df[c] = num
    return df, whole


def _departures(path: Path) -> pd.DataFrame:
    """Each vehicle of a run's route file: id, departure [s], departure lane, position and speed,
    and its route's edges."""
    root = ET.parse(path).getroot()
    named = {r.get("id"): r.get("edges", "") for r in root.findall("route")}
    rows = []
    for v in root.iter("vehicle"):
        inner = v.find("route")
        rows.append({"id": v.get("id"), "depart": float(v.get("depart", "nan")), "route": v.get("route") or "",
                     "edges": inner.get("edges", "") if inner is not None else named.get(v.get("route"), ""),
                     **{k: v.get(k, "") for k in ("departLane", "departPos", "departSpeed", "type")}})
    return pd.DataFrame(rows, columns=["id", "depart", "route", "edges", "departLane", "departPos", "departSpeed",
                                       "type"])


def _read_recorded(run_dir: Path) -> dict:
    """The recorded summary, after checking that the run's files can be read at all (a truncated
    or foreign file is a ReplayError naming it, not a difference)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        summary = json.loads((run_dir / "summary.json").read_text())
        if not isinstance(summary, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        raise ReplayError(f"{run_dir / 'summary.json'} cannot be read: {exc}") from None
    try:
        pd.read_csv(run_dir / "vehicles.csv", nrows=1)
    except (OSError, ValueError) as exc:
        raise ReplayError(f"{run_dir / 'vehicles.csv'} cannot be read: {exc}") from None
    traj = run_dir / "trajectories.parquet"
    if traj.is_file():
        try:
            pq.ParquetFile(traj).metadata
        except (OSError, pa.ArrowException) as exc:
            raise ReplayError(f"{traj} cannot be read: {exc}") from None
    return summary


def replay(run_dir: Path, out: Path | None = None, rtol: float = RTOL, atol: float = ATOL,
           progress: bool = False, force: bool = False) -> tuple[list[Difference], Path | None]:
    """Re-run ``run_dir`` from its recorded configuration (into ``out``, or a temporary folder that
    is removed afterwards) and compare. Returns the differences and the replay's folder (None when
    it was temporary). ``out`` may be neither the recorded run, nor inside it, nor hold it (the
    replay would overwrite what it verifies: ReplayError); one that is not empty is refused unless
    ``force``, which replaces an earlier run in it as ``run --force`` does
    (:func:`~runners.single.claim_run_dir`)."""
    from nrtraffic import scenario
    from nrtraffic.engine import RunFailed
    from runners.baseline import run_baseline
    from runners.single import run_scenario, unlock_run_dir

    run_dir = Path(run_dir)
    for f in ("scenario.resolved.toml", "summary.json", "vehicles.csv"):
        if not (run_dir / f).is_file():
            raise ReplayError(f"{run_dir} is not a complete run directory: {f} is missing")
    recorded = _read_recorded(run_dir)
    if recorded.get("status") not in ("ok", "gridlock"):
        raise ReplayError(f"{run_dir} is not a finished run (summary.json status {recorded.get('status')!r}): a run "
                          "that was stopped or failed cannot be replayed to the same figures; run it again")
    sc = scenario.load(run_dir / "scenario.resolved.toml")
    from runners.single import check, check_demand

    check(sc)  # (its network and demand as the run will build them: a damaged copy is said before anything runs)
    check_demand(sc, None, None)
    tmp = None
    if out is not None:
        from runners.single import claim_run_dir

        a, b = Path(out).resolve(), run_dir.resolve()
        same = a == b or a.is_relative_to(b) or b.is_relative_to(a)
        linked = None if same else next((f for f in run_dir.rglob("*") if f.is_symlink()
                                         and f.resolve().is_relative_to(a)), None)
        if same or linked is not None:
            raise ReplayError(f"--out {out} would overwrite the run it verifies ({run_dir}"
                              f"{f', whose {linked.name} is a link into it' if linked is not None else ''}): give "
                              "another folder")
        from runners.single import holds_files, lock_run_dir, read_manifest

        if Path(out).is_dir() and holds_files(out) and not force:
            replace = ", or --force to replace the run in it" if read_manifest(Path(out)) is not None else (
                " (it holds no run's manifest.json: files of your own?)")
            raise ReplayError(f"--out {out} is not empty: choose another folder{replace}")
        control = f"sumo_{recorded['junction_type']}" if recorded.get("junction_type") else "nrtraffic"
        try:
            claim_run_dir(Path(out), sc, None, None, control, force)  # (an existing folder locked for the run)
            Path(out).mkdir(parents=True, exist_ok=True)
            lock_run_dir(Path(out))  # (one made here; where claim_run_dir locked it, the same lock)
        except ValueError as exc:
            unlock_run_dir(Path(out))
            raise ReplayError(str(exc)) from None
        except OSError as exc:  # (a folder it cannot make or clear: read-only, say)
            unlock_run_dir(Path(out))
            raise ReplayError(f"--out {out}: cannot write there: {exc.strerror or exc}") from None
    if out is None:
        tmp = Path(tempfile.mkdtemp(prefix="nrtraffic-replay-"))
        out = tmp / "run"
    try:
        try:
            if recorded.get("junction_type"):
                run_baseline(sc, recorded["junction_type"], out, progress=progress)
            else:
                run_scenario(sc, out, progress=progress)
        except RunFailed as exc:
            if recorded.get("status") == "ok":
                if tmp is not None:  # (its temporary folder goes with it: nothing is kept to point at)
                    exc.result.run_dir = None
                    exc.args = (f"{exc} (a replay without --out keeps nothing; give --out to keep what it finished)",)
                raise
            # the recorded run failed too: compare what both finished
        return compare_runs(run_dir, out, rtol, atol), (None if tmp else Path(out))
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            unlock_run_dir(Path(out))


def main(args) -> int:
    diffs, kept = replay(args.run_dir, args.out, args.rtol, args.atol, progress=not args.no_progress,
                         force=args.force)
    if not diffs:
        print(f"replay of {args.run_dir}: matches (rtol {args.rtol:g}, atol {args.atol:g})")
        return 0
    print(f"replay of {args.run_dir}: differs, {len(diffs)} difference(s) beyond rtol {args.rtol:g}, atol {args.atol:g}:")
    for d in diffs[:40]:
        print(f"  {d}")
    if len(diffs) > 40:
        print(f"  ... and {len(diffs) - 40} more")
    if kept is not None:
        print(f"the replay is in {kept}")
    return 1
