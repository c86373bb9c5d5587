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

RUN_FIGURES = ("movements.png", "delays.png", "queues.png", "time_space.png", "arterial.png")


def run_figures(run_dir: Path) -> list[Path]:
    """The figures of a run directory that its files allow: conflict areas (``movements.png``),
    delay per movement with the LOS bands (``delays.png``), queues per approach (``queues.png``) and
    the time-space diagram of the controlled vehicles (``time_space.png``)."""
    from nrtraffic import plots
    from nrtraffic.metrics import is_signalised
    from nrtraffic import timespace
    from nrtraffic.results import PARTIAL_TRAJECTORIES, parse_queues

    run_dir = Path(run_dir)
    made = []
    summary = json.loads((run_dir / "summary.json").read_text())
    doc = json.loads((run_dir / "movements.json").read_text()) if (run_dir / "movements.json").is_file() else {}
    if doc.get("conflict_areas"):
        made.append(plots.conflict_areas(doc, run_dir / "movements.png"))
    mv = run_dir / "movements.csv"
    if mv.is_file():
        table = pd.read_csv(mv)
        if (table["vehicles"] > 0).any():
            made.append(plots.delay_by_movement(table, run_dir / "delays.png", is_signalised(summary.get("control"))))
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
    return df.to_html(index=False, na_rep="-", float_format=lambda v: f"{v:.4g}", border=0, classes="t")


_STYLE = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1100px;color:#222}
h1{font-size:1.4em}h2{font-size:1.1em;margin-top:1.6em;border-bottom:1px solid #ccc}
table.t{border-collapse:collapse;font-size:.85em}table.t td,table.t th{padding:2px 8px;text-align:right}
table.t tr:nth-child(even){background:#f4f4f4}img{max-width:100%}figure{margin:1em 0}
.note{color:#555;font-size:.85em}"""


def _page(title: str, body: list[str]) -> str:
    return (f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>\n" + "\n".join(body)
            + "\n</body></html>\n")


def run_report(run_dir: Path) -> Path:
    """``report.html`` of a run directory: its headline figures, the movement and approach tables
    and its figures (made here if missing)."""
    run_dir = Path(run_dir)
    run_figures(run_dir)
    s = json.loads((run_dir / "summary.json").read_text())
    head = pd.DataFrame([(k, s[k]) for k in HEADLINE if k in s], columns=["figure", "value"])
    body = ["<p class='note'>nrtraffic run directory " + html.escape(str(run_dir)) + "; definitions in the README "
            "(delay from the control-zone entry to the merging-zone exit, plus the wait to enter the network; "
            "LOS by the HCM thresholds: signalised for a traffic light, unsignalised otherwise).</p>",
            "<h2>Run</h2>", _table(head)]
    for name, title in (("movements.csv", "Movements"), ("approaches.csv", "Approaches (queues from SUMO's "
                                                                          "lane-area detectors)")):
        if (run_dir / name).is_file():
            body += [f"<h2>{title}</h2>", _table(pd.read_csv(run_dir / name))]
    figs = [run_dir / f for f in RUN_FIGURES if (run_dir / f).is_file()]
    if figs:
        body += ["<h2>Figures</h2>"] + [_img(f) for f in figs]
    out = run_dir / "report.html"
    out.write_text(_page(f"{s.get('scenario', '')}: {s.get('control', '')}, seed {s.get('seed', '')}", body))
    return out


def sweep_report(out_dir: Path, tables: list[tuple[str, pd.DataFrame]], figures: list[str]) -> Path:
    """``report.html`` of a sweep: its tables (each a note and a table, as in sweep.md) and the
    figures of ``out_dir`` named in ``figures``."""
    out_dir = Path(out_dir)
    body = []
    for note, table in tables:
        body += [f"<p class='note'>{html.escape(note)}</p>", _table(table)]
    for f in figures:
        if (out_dir / f).is_file():
            body.append(_img(out_dir / f))
    out = out_dir / "report.html"
    out.write_text(_page(f"nrtraffic sweep: {out_dir.name}", body))
    return out
