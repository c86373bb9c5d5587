"""Runs of one scenario side by side (``nrtraffic compare``): nrtraffic and SUMO's junction
controls, per run, per movement and per approach.

Every figure is the run's own: a run's headline figures from its ``summary.json``, per movement
from its ``movements.csv``, per approach from its ``approaches.csv`` (demand, throughput, queues).
Per approach, the figures that ``approaches.csv`` does not hold are computed from the run's
``vehicles.csv`` the way ``movements.csv`` is, with every movement of the approach together: the
crossings that entered the control zone in the run's measurement window and left the merging zone;
mean and 95th-percentile delay [s], HCM level of service of the mean (signalised thresholds where
the run's junctions are signals), stops per vehicle (SUMO's waitingCount over the trip). The 95th
percentile of the queue is taken over the detector periods inside the window (SUMO's lane-area
detectors, ``queues.xml``, 10 s periods) of the longest queue of each period, the approach's lanes
added up, by linear interpolation between the order statistics (numpy's default).
"""

from __future__ import annotations

import html
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

FINISHED = ("ok", "gridlock")  # a run that wrote all its tables (gridlock: it stopped when traffic did)
RUN_FIGURES = ["control", "seed", "status", "measure_from_s", "measure_to_s", "vehicles_completed", "throughput_veh_h",
               "demand_veh_h", "served_share", "vehicles_waiting_to_enter", "mean_delay_s", "p95_delay_s", "los",
               "mean_sumo_time_loss_s", "mean_fuel_ml", "collisions", "collisions_geometric", "min_bumper_gap_m"]
MOVEMENT_FIGURES = ["vehicles", "throughput_veh_h", "mean_delay_s", "p95_delay_s", "los", "stops_per_vehicle",
                    "fuel_ml_per_vehicle"]
APPROACH_FIGURES = ["demand_veh_h", "throughput_veh_h", "vehicles", "mean_delay_s", "p95_delay_s", "los",
                    "stops_per_vehicle", "mean_queue_veh", "p95_queue_veh", "max_queue_veh"]
# what the console shows side by side (the files hold every figure above)
CONSOLE_MOVEMENT = ["vehicles", "mean_delay_s", "los", "stops_per_vehicle"]
CONSOLE_APPROACH = ["throughput_veh_h", "mean_delay_s", "los", "stops_per_vehicle", "mean_queue_veh", "p95_queue_veh"]


class CompareError(ValueError):
    """Run directories that cannot be compared."""


@dataclass
class Run:
    """One run directory: its label in the comparison, summary and tables."""

    label: str
    run_dir: Path
    summary: dict
    movements: pd.DataFrame
    approaches: pd.DataFrame


def _check(run_dir: Path) -> dict:
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise CompareError(f"{run_dir}: no such folder")
    try:
        s = json.loads((run_dir / "summary.json").read_text())
    except FileNotFoundError:
        raise CompareError(f"{run_dir}: not a run directory (no summary.json)") from None
    except (OSError, ValueError) as exc:
        raise CompareError(f"{run_dir}: summary.json cannot be read ({exc})") from None
    if not isinstance(s, dict):
        raise CompareError(f"{run_dir}: summary.json is not a run's summary (not a JSON object)")
    status = s.get("status")
    if status not in FINISHED:
        why = f": {s['error']}" if s.get("error") else ""
        raise CompareError(f"{run_dir}: not a finished run (summary.json status {status!r}{why}); compare runs "
                           "whose status is ok, or run it again")
    lost = [k for k in ("scenario", *RUN_FIGURES) if k not in s]
    if lost:  # (every finished run writes them all; one without is edited or damaged, and would show "-")
        raise CompareError(f"{run_dir}/summary.json has no {', '.join(lost[:4])}{' and more' if len(lost) > 4 else ''}"
                           ": not a finished run's summary (edited or damaged); run it again")
    for name, needed in (("movements.csv", ("approach", "movement")), ("approaches.csv", ("approach",)),
                         ("vehicles.csv", ("vehicle_id", "approach", "movement"))):
        if not (run_dir / name).is_file():
            raise CompareError(f"{run_dir}: a finished run without {name} (written by an older version?): "
                               "run it again")
        try:
            columns = pd.read_csv(run_dir / name, nrows=0).columns
        except (OSError, ValueError) as exc:
            raise CompareError(f"{run_dir}: its tables cannot be read ({name}: {type(exc).__name__}); run it "
                               "again") from None
        lost = [c for c in needed if c not in columns]
        if lost:
            raise CompareError(f"{run_dir}/{name} has no column {', '.join(lost)}: not a run's table (edited or "
                               "damaged); run it again")
    return s


def _labels(summaries: list[dict], dirs: list[Path]) -> list[str]:
    """Each run's control, with its folder's name where two runs have the same control."""
    controls = [str(s.get("control")) for s in summaries]
    out = [c if controls.count(c) == 1 else f"{c} ({d.name})" for c, d in zip(controls, dirs)]
    return [o if out.count(o) == 1 else f"{c} ({d})" for o, c, d in zip(out, controls, dirs)]


def _layout(d: Path) -> tuple | None:
    """The movements of a run (the names in its ``movements.json`` and their routes), or None where
    it has none to read."""
    try:
        doc = json.loads((Path(d) / "movements.json").read_text())
        return tuple(sorted((name, tuple(m.get("route", ()))) for name, m in doc["movements"].items()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def load(run_dirs: list[Path]) -> list[Run]:
    """The runs to compare: finished runs (status ok or gridlock) of one scenario, each once;
    :class:`CompareError` names the run directory and the fix otherwise."""
    dirs = [Path(d) for d in run_dirs]
    if len(dirs) < 2:
        raise CompareError("compare needs at least two run directories")
    seen = {}
    for d in dirs:
        key = d.resolve()
        if key in seen:
            raise CompareError(f"{d}: given twice")
        seen[key] = d
    summaries = [_check(d) for d in dirs]
    names = {str(s.get("scenario")) for s in summaries}
    if len(names) > 1:
        first = summaries[0].get("scenario")
        other = next((d, s.get("scenario")) for d, s in zip(dirs, summaries) if s.get("scenario") != first)
        raise CompareError(f"{other[0]} is a run of scenario {other[1]!r}, {dirs[0]} of {first!r}: compare runs of "
                           "one scenario")
    layouts = [(d, _layout(d)) for d in dirs]
    known = [(d, lay) for d, lay in layouts if lay is not None]
    other = next(((d, lay) for d, lay in known if lay != known[0][1]), None)
    if other is not None:  # (one name, two networks: a copied scenario file)
        raise CompareError(f"{other[0]} and {known[0][0]} are runs of scenario {names.pop()!r} on different junctions "
                           "(their movements.json name other movements): compare runs of one scenario")
    runs = []
    for label, d, s in zip(_labels(summaries, dirs), dirs, summaries):
        try:
            mv = pd.read_csv(d / "movements.csv")
            _check_movements(d, mv)
            runs.append(Run(label, d, s, mv, approach_figures(d, s)))
        except CompareError:
            raise
        except (OSError, ValueError, KeyError) as exc:  # (pandas' EmptyDataError and ParserError are ValueErrors)
            raise CompareError(f"{d}: its tables cannot be read ({type(exc).__name__}: {exc}); run it again") from None
    return runs


# movements.csv's columns of numbers (a run writes them; an edited file may not)
MOVEMENT_NUMBERS = ("vehicles", "throughput_veh_h", "mean_delay_s", "p95_delay_s", "stops_per_vehicle",
                    "fuel_ml_per_vehicle")


def _check_movements(d: Path, mv: pd.DataFrame) -> None:
    """A run's ``movements.csv`` as a run writes it (CompareError naming what is wrong, exit 2): a
    row per movement once, numbers where numbers go, a throughput for each."""
    keys = [k for k in ("junction", "approach", "movement") if k in mv.columns]
    twice = mv.duplicated(keys)
    if twice.any() or mv[keys].isna().any().any():
        raise CompareError(f"{d}: its tables cannot be read (movements.csv: a movement given twice or without its "
                           "name: edited or damaged); run it again")
    for col in MOVEMENT_NUMBERS:
        if col in mv.columns and not pd.api.types.is_numeric_dtype(mv[col]):
            raise CompareError(f"{d}: its tables cannot be read (movements.csv: {col} holds text where a run writes "
                               "numbers: edited or damaged); run it again")
    if "throughput_veh_h" in mv.columns and mv["throughput_veh_h"].isna().any():
        raise CompareError(f"{d}: its tables cannot be read (movements.csv: a movement without its throughput: "
                           "edited or damaged); run it again")


def approach_figures(run_dir: Path, summary: dict) -> pd.DataFrame:
    """Per approach of a run: ``approaches.csv``'s figures (its served flow as ``throughput_veh_h``
    where it names it ``served_veh_h``), with the figures it does not hold computed as the module
    docstring says, and ``p95_queue_veh``."""
    from nrtraffic.metrics import movement_table, run_is_signalised
    from nrtraffic.results import parse_queues

    run_dir = Path(run_dir)
    appr = pd.read_csv(run_dir / "approaches.csv")
    if "throughput_veh_h" not in appr and "served_veh_h" in appr:
        appr = appr.rename(columns={"served_veh_h": "throughput_veh_h"})
    w0, w1 = float(summary.get("measure_from_s") or 0.0), float(summary.get("measure_to_s") or 0.0)
    veh = pd.read_csv(run_dir / "vehicles.csv", dtype={"vehicle_id": str})
    known = [(a, "") for a in appr["approach"]]
    per = movement_table(veh.assign(movement=""), w0, w1, run_is_signalised(summary), known)
    per = per.set_index("approach")
    per = per.drop(columns=["movement", "los_thresholds"])
    for col in ("mean_delay_s", "p95_delay_s", "stops_per_vehicle"):
        per[col] = pd.to_numeric(per[col], errors="coerce").round(3)
    per["los"] = per["los"].where(per["los"] != "n/a")
    for col in per.columns:
        if col not in appr:
            appr[col] = appr["approach"].map(per[col])
    q = parse_queues(run_dir / "queues.xml", t0_s=float(summary.get("begin_s") or 0.0))
    if len(q):
        q = q[(q["begin_s"] >= w0 - 1e-9) & (q["end_s"] <= w1 + 1e-9)]
    p95 = q.groupby("approach")["max_queue_veh"].quantile(0.95) if len(q) else pd.Series(dtype=float)
    if "p95_queue_veh" not in appr:
        appr["p95_queue_veh"] = appr["approach"].map(p95.round(2))
    return appr


def _side_by_side(runs: list[Run], table: str, keys: list[str], figures: list[str]) -> pd.DataFrame:
    """The long table: one row per key and run (in the order given), the run's label and control,
    ``figures`` and then the table's other columns."""
    frames = []
    for order, r in enumerate(runs):
        t = getattr(r, table).copy()
        t.insert(len(keys), "run", r.label)
        t.insert(len(keys) + 1, "control", r.summary.get("control"))
        t["_order"] = order
        first = keys + ["run", "control"] + [f for f in figures if f in t]
        frames.append(t[first + [c for c in t.columns if c not in first]])
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(keys + ["_order"], kind="stable").drop(columns="_order").reset_index(drop=True)


@dataclass
class Comparison:
    """The tables of a comparison (long form: one row per key and run)."""

    runs: list[Run]
    headline: pd.DataFrame  # one row per run
    movements: pd.DataFrame
    approaches: pd.DataFrame
    notes: list[str]

    @property
    def scenario(self) -> str:
        return str(self.runs[0].summary.get("scenario"))


def _demand_differs(runs: list[Run]) -> str:
    """The ``[demand]`` settings in which the runs' ``scenario.resolved.toml`` differ, as
    ``key: value / value``, "; "-separated ("" where they agree, or a run has no such file)."""
    import tomllib

    demands = []
    for r in runs:
        try:
            demands.append(tomllib.loads((r.run_dir / "scenario.resolved.toml").read_text()).get("demand") or {})
        except (OSError, ValueError):
            return ""
    keys = sorted(set().union(*demands))
    out = []
    for k in keys:
        vals = [json.dumps(d.get(k), sort_keys=True) for d in demands]
        if len(set(vals)) > 1:
            out.append(f"{k}: " + " / ".join(dict.fromkeys(vals)))
    return "; ".join(out)


def compare(run_dirs: list[Path]) -> Comparison:
    """The runs' figures side by side (see the module docstring)."""
    runs = load(run_dirs)
    head = pd.DataFrame([{"run": r.label, **{k: r.summary.get(k) for k in RUN_FIGURES}, "run_dir": str(r.run_dir)}
                         for r in runs])
    notes = []
    for k, what in (("seed", "seeds"), ("measure_from_s", "measurement windows"),
                    ("measure_to_s", "measurement windows"), ("sim_time_s", "simulated times")):
        vals = {r.summary.get(k) for r in runs}
        if len(vals) > 1 and not any(what in n for n in notes):
            notes.append(f"The runs differ in their {what}: each figure is over its own run's.")
    differ = _demand_differs(runs)
    if differ:
        notes.append(f"The runs differ in their demand ({differ}): their figures answer different traffic; compare "
                     "runs of one demand.")
    if any(r.summary.get("status") != "ok" for r in runs):
        notes.append("A run whose status is gridlock stopped when a junction made no progress: its figures cover "
                     "the time until then.")
    return Comparison(runs, head, _side_by_side(runs, "movements", ["approach", "movement"], MOVEMENT_FIGURES),
                      _side_by_side(runs, "approaches", ["approach"], APPROACH_FIGURES), notes)


# ------------------------------------------------------------------ presentation
def html_grouped(long: pd.DataFrame, keys: list[str], figures: list[str], label: str = "run") -> str:
    """A long table as HTML, the rows of one key (a run each, named in column ``label``) adjacent
    under the key's cells (spanning them), groups shaded in turn."""
    from nrtraffic.report import display

    t = display(long[keys + [label] + [f for f in figures if f in long]])
    head = "".join(f"<th>{html.escape(c)}</th>" for c in t.columns)
    keyed = long[keys].astype(str).agg("|".join, axis=1).tolist()
    sizes = [len(list(g)) for _, g in itertools.groupby(keyed)]
    rows, i = [], 0
    for n_group, size in enumerate(sizes):
        for j in range(size):
            row = t.iloc[i + j].tolist()
            cells = [f"<td rowspan='{size}'>{html.escape(str(v))}</td>" for v in row[:len(keys)]] if j == 0 else []
            cells += [f"<td>{html.escape(str(v))}</td>" for v in row[len(keys):]]
            rows.append(f"<tr class='{'gh'[n_group % 2]}{' first' if j == 0 else ''}'>{''.join(cells)}</tr>")
        i += size
    return f"<table class='t cmp'><thead><tr>{head}</tr></thead><tbody>\n" + "\n".join(rows) + "\n</tbody></table>"


def headline_wide(c: Comparison) -> pd.DataFrame:
    """The runs' headline figures: a row per figure, a column per run."""
    from nrtraffic.report import fmt, human

    rows = [[human(k)] + [fmt(k, v) for v in c.headline[k]] for k in RUN_FIGURES if k != "control"]
    return pd.DataFrame(rows, columns=["figure"] + list(c.headline["run"]))


NOTE = ("Each run's own figures over its measurement window: per movement from its movements.csv; per approach "
        "demand, throughput and queues from its approaches.csv and, with every movement of the approach together, "
        "delay, level of service and stops computed from its vehicles.csv as movements.csv is. Delay: time lost "
        "against free flow from the control-zone entry to the merging-zone exit, plus the wait to enter the "
        "network; LOS: HCM level of service of the mean delay (signalised thresholds for signals, unsignalised "
        "otherwise); stops: SUMO's waitingCount over the trip (times below 0.1 m/s). Queue: SUMO's lane-area "
        "detectors, the longest queue of each 10 s period, the approach's lanes added up; mean over the periods "
        "in the window (SUMO's time mean of the longest queue), 95th percentile over the periods (linear "
        "interpolation), longest the largest.")


def write(c: Comparison, out: Path) -> list[Path]:
    """``compare.html``, ``compare_runs.csv``, ``compare_movements.csv`` and
    ``compare_approaches.csv`` in ``out``."""
    from nrtraffic.report import _page, _table, corridor_tables
    from nrtraffic.results import to_csv

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "compare_runs.csv", out / "compare_movements.csv", out / "compare_approaches.csv"]
    for p, t in zip(paths, (c.headline, c.movements, c.approaches)):
        to_csv(t, p)
    labels = list(c.headline["run"])
    body = [f"<p class='note'>{html.escape(NOTE)}</p>"]
    body += [f"<p class='warn'>{html.escape(n)}</p>" for n in c.notes]
    body += ["<h2>Runs</h2>", _table(headline_wide(c))]
    body += ["<p class='note'>" + "<br>".join(f"{html.escape(r.label)}: {html.escape(str(r.run_dir))}"
                                              for r in c.runs) + "</p>"]
    corridor = [(r.label, corridor_tables(r.summary)) for r in c.runs]
    if any(t for _, t in corridor):
        body.append("<h2>Corridor</h2>")
        for k in range(max(len(t) for _, t in corridor)):
            parts = [(lab, t[k]) for lab, t in corridor if len(t) > k]
            note, first = parts[0][1]
            key = first.columns[0]
            long = pd.concat([t.assign(run=lab) for lab, (_, t) in parts], ignore_index=True)
            figs = [f for f in first.columns[1:]]
            body += [f"<p class='note'>{html.escape(note)}</p>",
                     html_grouped(long.sort_values(key, kind="stable"), [key], figs)]
    body += ["<h2>Approaches</h2>", html_grouped(c.approaches, ["approach"], APPROACH_FIGURES)]
    body += ["<h2>Movements</h2>", html_grouped(c.movements, ["approach", "movement"], MOVEMENT_FIGURES)]
    page = out / "compare.html"
    title = f"{c.scenario}: " + " vs ".join(labels)
    page.write_text(_page(title, body))
    return [page, *paths]


def console(c: Comparison) -> str:
    """The comparison as console text: the runs' headline figures side by side, then per approach
    and per movement the main figures, the runs on adjacent rows."""
    from nrtraffic.report import display

    labels = list(c.headline["run"])
    parts = [f"{c.scenario}: " + " vs ".join(labels), headline_wide(c).to_string(index=False)]
    for title, long, keys, figs in (("per approach", c.approaches, ["approach"], CONSOLE_APPROACH),
                                    ("per movement", c.movements, ["approach", "movement"], CONSOLE_MOVEMENT)):
        t = display(long[keys + ["run"] + [f for f in figs if f in long]])
        repeat = t[keys].eq(t[keys].shift()).all(axis=1)
        t.loc[repeat, keys] = ""  # (a key once, over its runs' rows)
        parts += ["", title + ":", t.to_string(index=False)]
    parts += [f"note: {n}" for n in c.notes]
    return "\n".join(parts) + "\n"
