"""A run's or a sweep's figures and ``report.html``: its tables and figures in one self-contained
file (images embedded), to open in any browser or attach to a study."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import pandas as pd

# what a report shows of summary.json, in this order
HEADLINE = ["control", "scenario", "seed", "status", "measure_from_s", "measure_to_s", "vehicles_completed",
            "throughput_veh_h", "demand_veh_h", "served_share", "vehicles_waiting_to_enter", "mean_delay_s", "los",
            "p95_delay_s", "mean_sumo_time_loss_s", "mean_fuel_ml", "collisions", "collisions_geometric",
            "min_bumper_gap_m", "max_lateral_dev_m", "max_tracking_error_m", "cbf_long_fallbacks",
            "vehicles_held", "real_time_factor"]

# how reports name and round the figures of summary.json and the run's tables: key -> (header with
# its unit, decimals | "int" | "pct" (a share, shown in per cent) | "text")
FIELDS = {
    "control": ("control", "text"), "scenario": ("scenario", "text"), "seed": ("seed", "int"),
    "status": ("status", "text"), "measure_from_s": ("measured from [s]", 1), "measure_to_s": ("measured to [s]", 1),
    "vehicles_completed": ("vehicles completed", "int"), "throughput_veh_h": ("throughput [veh/h]", 1),
    "demand_veh_h": ("demand [veh/h]", 1), "served_share": ("served [% of vehicles demanded]", "pct"),
    "vehicles_demanded": ("vehicles demanded", "int"), "vehicles_served": ("vehicles served", "int"),
    "vehicles_waiting_to_enter": ("vehicles waiting to enter", "int"), "mean_delay_s": ("mean delay [s]", 1),
    "los": ("LOS", "text"), "p95_delay_s": ("95th-percentile delay [s]", 1),
    "mean_sumo_time_loss_s": ("mean SUMO timeLoss [s]", 1), "mean_fuel_ml": ("mean fuel [mL/veh]", 1),
    "collisions": ("collisions, SUMO's check", "int"), "collisions_geometric": ("collisions, own check", "int"),
    "min_bumper_gap_m": ("smallest bumper gap [m]", 2), "max_lateral_dev_m": ("largest lateral deviation [m]", 3),
    "max_tracking_error_m": ("largest tracking error [m]", 3),
    "steady_tracking_error_m": ("largest steady tracking error [m]", 3),
    "cbf_long_fallbacks": ("longitudinal barrier fallbacks", "int"), "vehicles_held": ("vehicles held", "int"),
    "real_time_factor": ("real-time factor", 1),
    # movements.csv, approaches.csv
    "approach": ("approach", "text"), "movement": ("movement", "text"), "vehicles": ("vehicles", "int"),
    "los_thresholds": ("LOS thresholds", "text"), "stops_per_vehicle": ("stops per vehicle", 2),
    "fuel_ml_per_vehicle": ("fuel [mL/veh]", 1),
    "mean_queue_veh": ("mean queue [veh]", 2), "max_queue_veh": ("longest queue [veh]", 1),
    "mean_queue_m": ("mean queue [m]", 1), "max_queue_m": ("longest queue [m]", 1),
    "p95_queue_veh": ("95th-percentile queue [veh]", 1),
    # summary.json junctions and corridor
    "junction": ("junction", "text"), "direction": ("direction (entry road)", "text"),
    "travel_time_s": ("travel time [s]", 1), "delay_s": ("delay [s]", 1),
    "control_zone_m": ("control zone [m]", 1), "merging_zone_m": ("merging zone [m]", 1),
    # by driver
    "driver": ("driver", "text"), "share": ("share", "pct"), "runs": ("runs", "int"),
    "vehicles_per_run": ("vehicles per run", 1),
}
_UNITS = (("_veh_h", "veh/h"), ("_mps2", "m/s²"), ("_mps", "m/s"), ("_ml", "mL"), ("_veh", "veh"), ("_s", "s"),
          ("_m", "m"))


def human(key: str) -> str:
    """A column's header as a reader wants it: :data:`FIELDS`' where it names it, else its words
    with the unit its name ends in (``mean_wait_s`` -> ``mean wait [s]``)."""
    if key in FIELDS:
        return FIELDS[key][0]
    for suffix, unit in _UNITS:
        if key.endswith(suffix):
            return f"{key[:-len(suffix)].replace('_', ' ')} [{unit}]"
    if key.endswith("_share"):
        return f"{key[:-6].replace('_', ' ')} share [%]"
    return key.replace("_", " ")


def _kind(key: str):
    if key in FIELDS:
        return FIELDS[key][1]
    if key.endswith("_share"):
        return "pct"
    return 2


def fmt(key: str, value) -> str:
    """A value of column ``key`` as a report shows it: rounded to the column's resolution, shares
    in per cent, "-" for none."""
    if value is None or (isinstance(value, float) and value != value):
        return "-"
    kind = _kind(key)
    if isinstance(value, bool) or kind == "text" or isinstance(value, str):
        return str(value)
    v = float(value)
    if kind == "pct":
        return f"{100.0 * v:.1f} %"
    if kind == "int":
        return f"{v:.0f}"
    out = f"{v:.{kind}f}"
    return out[1:] if out.startswith("-") and float(out) == 0.0 else out  # no "-0.0"


def display(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with human headers and every value formatted (:func:`human`, :func:`fmt`)."""
    return pd.DataFrame({human(c): [fmt(c, v) for v in df[c]] for c in df.columns})


RUN_FIGURES = ("movements.png", "delays.png", "queues.png", "time_space.png", "arterial.png")


def run_figures(run_dir: Path, summary: dict | None = None) -> list[Path]:
    """The figures of a run directory that its files allow: conflict areas (``movements.png``),
    delay per movement with the LOS bands (``delays.png``), queues per approach (``queues.png``),
    the time-space diagram per approach road (``time_space.png``) and, on a corridor, the arterial
    diagram (``arterial.png``); both of every vehicle where the run wrote fcd.xml, else of the
    controlled vehicles while under control (:mod:`nrtraffic.timespace`). ``summary``: the run's
    (default: its ``summary.json``)."""
    from nrtraffic import plots
    from nrtraffic.metrics import run_is_signalised
    from nrtraffic import timespace
    from nrtraffic.results import PARTIAL_TRAJECTORIES, parse_queues

    run_dir = Path(run_dir)
    made = []
    if summary is None:
        summary = json.loads((run_dir / "summary.json").read_text())
    doc = json.loads((run_dir / "movements.json").read_text()) if (run_dir / "movements.json").is_file() else {}
    if doc.get("conflict_areas"):
        made.append(plots.conflict_areas(doc, run_dir / "movements.png"))
    mv = run_dir / "movements.csv"
    if mv.is_file():
        table = pd.read_csv(mv)
        if (table["vehicles"] > 0).any():
            junction_of = {m["approach"]: m.get("junction", "") for m in doc.get("movements", {}).values()}
            signalised = run_is_signalised(summary)
            made.append(plots.delay_by_movement(table, run_dir / "delays.png", signalised, junction_of))
    if (run_dir / "queues.xml").is_file():
        series = parse_queues(run_dir / "queues.xml", t0_s=summary.get("begin_s") or 0.0)
        if len(series):
            made.append(plots.queues(series, run_dir / "queues.png", summary.get("measure_from_s") or 0.0))
    source = timespace.source_of(run_dir)
    if doc.get("movements") and (source == "fcd" or (run_dir / "trajectories.parquet").is_file()
                                 or (run_dir / PARTIAL_TRAJECTORIES).is_file()):
        series = timespace.time_space_series(run_dir, source)
        if any(len(df) for df in series.values()):
            roads = timespace.roads(doc, {})
            made.append(plots.time_space(series, roads, run_dir / "time_space.png", source))
        series, arts = timespace.arterial_series(run_dir, source)
        if any(len(df) for df in series.values()):
            made.append(plots.arterial(series, arts, run_dir / "arterial.png", source))
    return made


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(path.name)}"></figure>'


def _table(df: pd.DataFrame) -> str:
    """An HTML table of already formatted cells (see :func:`display`)."""
    return df.to_html(index=False, na_rep="-", border=0, classes="t")


_STYLE = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
h1{font-size:1.4em}h2{font-size:1.1em;margin-top:1.6em;border-bottom:1px solid #ccc}
table.t{border-collapse:collapse;font-size:.85em}table.t td,table.t th{padding:2px 8px;text-align:right}
table.t tr:nth-child(even){background:#f4f4f4}img{max-width:100%}figure{margin:1em 0}
.note{color:#555;font-size:.85em}.warn{color:#a00;font-size:.9em}
table.cmp tr.g{background:#f1f4f8}table.cmp tr.h{background:#fff}table.cmp tr.first td{border-top:1px solid #ccc}
table.cmp td{white-space:nowrap}"""


# the generator every page of nrtraffic's names in its head (a page of the user's never does)
GENERATOR = "<meta name='generator' content='nrtraffic'>"


def _page(title: str, body: list[str]) -> str:
    return (f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'>{GENERATOR}<title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>\n" + "\n".join(body)
            + "\n</body></html>\n")


def corridor_tables(summary: dict) -> list[tuple[str, pd.DataFrame]]:
    """A corridor's figures of summary.json (``junctions`` when there are several, ``corridor``):
    per junction, and per direction of the arterial; each ``(note, table)``."""
    out = []
    junctions = summary.get("junctions") or {}
    if len(junctions) > 1:
        rows = [{"junction": j, **{k: f.get(k) for k in ("vehicles", "throughput_veh_h", "served_share",
                                                           "mean_delay_s", "p95_delay_s", "los", "control_zone_m",
                                                           "merging_zone_m")}}
                for j, f in junctions.items()]
        out.append(("Per junction: throughput, the crossings that left its merging zone in the measurement "
                    "window, per hour (they add up to the run's); served, the share of the vehicles demanded of "
                    "it in the window that left; vehicles and delay, the crossings that entered its control zone "
                    "in the window and left its merging zone; LOS: HCM level of service of the mean delay.",
                    pd.DataFrame(rows)))
    corridor = summary.get("corridor") or {}
    if corridor:
        rows = [{"direction": d, **{k: f.get(k) for k in ("vehicles", "travel_time_s", "stops_per_vehicle", "delay_s")}}
                for d, f in corridor.items()]
        out.append(("Along the arterial, per direction: the trips straight through every junction that entered "
                    "the first control zone in the window and left the network; travel time is SUMO's trip "
                    "duration (insertion to arrival) plus the wait to be inserted, stops SUMO's waitingCount "
                    "(times below 0.1 m/s), delay the crossings' delays added up.", pd.DataFrame(rows)))
    return out


def driver_table(summary: dict) -> tuple[str, pd.DataFrame] | None:
    """Mixed traffic (summary.json ``human_share`` above 0): the figures split by driver, with the
    colliding pairs by the kinds of the two vehicles in the note; None without human drivers."""
    share = summary.get("human_share")
    if not share:
        return None
    rows = [{"driver": d, "vehicles": summary.get(f"vehicles_{d}"),
             "share": (1.0 - share) if d == "automated" else share,
             "mean_delay_s": summary.get(f"mean_delay_{d}_s"),
             "min_bumper_gap_m": summary.get(f"min_bumper_gap_{d}_m")} for d in ("automated", "human")]
    pairs = " / ".join(str(summary.get(f"collisions_{k}", "-")) for k in ("automated", "mixed", "human"))
    return (f"By driver: automated vehicles and human drivers (SUMO's driver model), among the vehicles that "
            f"entered the control zone in the window; delay of those that left it; smallest bumper gap to the "
            f"vehicle ahead on the same path. Colliding pairs, automated / mixed / human: {pairs}.",
            pd.DataFrame(rows))


def console_sections(summary: dict) -> str:
    """The corridor and driver tables of a run (:func:`corridor_tables`, :func:`driver_table`) as
    plain text for the console; empty for a single junction without human drivers."""
    import textwrap

    parts = corridor_tables(summary)
    drivers = driver_table(summary)
    if drivers is not None:
        parts.append(drivers)
    return "".join(f"\n{textwrap.fill(note, 110)}\n{display(t).to_string(index=False)}\n" for note, t in parts)


def _run_title(s: dict) -> str:
    return f"{s.get('scenario', '')}: {s.get('control', '')}, seed {s.get('seed', '')}"


def run_report(run_dir: Path, summary: dict | None = None) -> Path:
    """``report.html`` of a run directory: its headline figures, its corridor and driver figures
    where it has them, the movement and approach tables and its figures (made here if missing).
    ``summary``: the run's (default: its ``summary.json``; a run writes its final one after the
    report, so that it says ok only once the report is there)."""
    run_dir = Path(run_dir)
    s = json.loads((run_dir / "summary.json").read_text()) if summary is None else summary
    run_figures(run_dir, s)
    head = pd.DataFrame([(human(k), fmt(k, s[k])) for k in HEADLINE if k in s], columns=["figure", "value"])
    body = ["<p class='note'>nrtraffic run directory " + html.escape(str(run_dir)) + "; definitions in the docs "
            "(outputs): delay from the control-zone entry to the merging-zone exit, plus the wait to enter the "
            "network; LOS by the HCM thresholds: signalised for a traffic light, unsignalised otherwise.</p>"]
    if s.get("warnings"):
        body.append("<ul class='warn'>" + "".join(f"<li>{html.escape(w)}</li>" for w in s["warnings"]) + "</ul>")
    body += ["<h2>Run</h2>", _table(head)]
    corridor = corridor_tables(s)
    if corridor:
        body.append("<h2>Corridor</h2>")
        for note, t in corridor:
            body += [f"<p class='note'>{html.escape(note)}</p>", _table(display(t))]
    drivers = driver_table(s)
    if drivers is not None:
        body += ["<h2>By driver</h2>", f"<p class='note'>{html.escape(drivers[0])}</p>", _table(display(drivers[1]))]
    for name, title in (("movements.csv", "Movements"), ("approaches.csv", "Approaches (queues from SUMO's "
                                                                          "lane-area detectors)")):
        if (run_dir / name).is_file():
            body += [f"<h2>{title}</h2>", _table(display(pd.read_csv(run_dir / name)))]
    figs = [run_dir / f for f in RUN_FIGURES if (run_dir / f).is_file()]
    if figs:
        body += ["<h2>Figures</h2>"] + [_img(f) for f in figs]
    if (run_dir / "movements.json").is_file() and not (run_dir / "time_space.png").is_file():
        body.append("<p class='note'>No time-space diagram: the run has no controlled vehicles and no SUMO "
                    "floating-car data; run it with --set outputs.sumo_fcd=true to draw every vehicle.</p>")
    out = run_dir / "report.html"
    out.write_text(_page(_run_title(s), body))
    return out


def sweep_report(out_dir: Path, tables: list[tuple[str, pd.DataFrame]], figures: list[str],
                 title: str | None = None, sections: list[tuple[str, str, str]] = ()) -> Path:
    """``report.html`` of a sweep: its tables (each a note and a table of formatted cells, as in
    sweep.md), the figures of ``out_dir`` named in ``figures``, then ``sections`` (heading, note and
    an HTML table each); ``title`` names the study (by default the output folder)."""
    out_dir = Path(out_dir)
    body = []
    for note, table in tables:
        body += [f"<p class='note'>{html.escape(note)}</p>", _table(table)]
    for f in figures:
        if (out_dir / f).is_file():
            body.append(_img(out_dir / f))
    for heading, note, table_html in sections:
        body += [f"<h2>{html.escape(heading)}</h2>", f"<p class='note'>{html.escape(note)}</p>", table_html]
    out = out_dir / "report.html"
    out.write_text(_page(title or f"nrtraffic sweep: {out_dir.name}", body))
    return out
