"""Run results: the in-memory figures of a run, streaming trajectory writer, run-directory I/O.

A run directory holds ``summary.json``, ``vehicles.csv``, ``trajectories.parquet``,
``scenario.resolved.toml``, ``sumo/`` (the SUMO inputs of the run) and SUMO's ``tripinfo.xml`` and
``collisions.xml`` (DESIGN.md, contracts).

Counting, the same in every table (summary.json and its ``junctions``, movements.csv,
approaches.csv), over the measurement window ``[w0, w1]`` (``outputs.warmup_s`` to
``outputs.measure_end_s`` or the end of the run) [s]:

- **throughput** (``throughput_veh_h``): crossings whose vehicle left a merging zone during the
  window, per hour of the window; summary.json's is the sum of its junctions' (on a corridor a
  vehicle through three junctions counts three times), and a junction's is the sum of its
  approaches' and of its movements'.
- **delay figures** (``vehicles``, ``vehicles_completed``, ``mean_delay_s``, ...): the crossings
  (trips, in summary.json) that entered the control zone during the window and left the merging
  zone before the end of the run.
- **served share** (``served_share``): at a junction, of the vehicles demanded of it in the window,
  the share it served. Demanded: the crossings that entered its control zone during the window
  early enough to leave its merging zone before the end of the run at their free-flow speed
  (``t_exit_free_s``), and the vehicles due to depart towards it in the window that SUMO could
  not insert by the end of the run; served: those of them that left its merging zone. At most 1 by
  construction; summary.json's is over all junctions (served crossings / demanded crossings).

Resolutions (:data:`RESOLUTIONS`, by the unit suffix of a figure's name): times and durations
0.001 s, lengths and positions 0.001 m, speeds 0.001 m/s, accelerations 0.001 m/s^2, flows
0.1 veh/h, shares and fractions 0.0001, queues 0.001 veh, fuel 0.001 mL, energy 0.001 m^2/s^3,
barrier values 0.000001, any other number 0.000001; counts are whole numbers. No value is written
with more digits than its resolution, so float noise (a delay of -2.5e-14 s) is written as 0.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from nrtraffic.sumo.network import edge_of

VEHICLE_COLUMNS = [
    "vehicle_id", "junction", "leg", "legs", "approach", "driver", "movement", "lane", "depart_delay_s", "t_arrive_s", "t_enter_s", "v_enter_mps", "t_merge_planned_s", "t_merge_actual_s",
    "t_exit_s", "t_exit_free_s", "delay_s", "max_tracking_error_m", "steady_tracking_error_m", "transient_tracking_error_m",
    "max_lateral_dev_m",
    "min_bumper_gap_m", "energy_u2", "fuel_ml", "predecessor", "relation", "binding", "profile", "plan_rear_end_intrusion_m",
    "v_merge_planned_mps",
    "min_center_distance_m", "max_abs_accel_mps2", "cbf_long_active_frac", "cbf_lat_active_frac",
    "cbf_long_fallbacks", "cbf_lat_fallbacks", "min_h_long", "min_h_lat", "plant_steps", "t_held_s", "t_release_s",
    "replans", "sumo_time_loss_s", "stops", "status",
]

TRAJECTORY_COLUMNS = {
    "t": "float64", "vehicle_id": "string", "s_m": "float64", "x": "float64", "y": "float64", "v_l": "float64",
    "v_n": "float64", "psi": "float64", "psi_dot": "float64", "a_cmd": "float64", "delta_cmd": "float64",
    "a_track": "float64", "delta_track": "float64", "ref_x": "float64", "ref_y": "float64", "ref_s_m": "float64", "tracking_error_m": "float64",
    "lateral_dev_m": "float64", "center_distance_m": "float64", "bumper_gap_m": "float64",
    "cbf_long_active": "float64", "cbf_lat_active": "float64", "h_long": "float64", "h_lat": "float64",
}


@dataclass
class RunResult:
    """What a run produced: ``summary`` (the figures of summary.json) and one row per vehicle."""

    summary: dict
    vehicles: pd.DataFrame
    run_dir: Path | None = None
    extra: dict = field(default_factory=dict)


PARTIAL_TRAJECTORIES = "trajectories.partial.arrows"  # the stream a run writes until it closes
LANE_WIDTH_M = 3.2  # SUMO's default lane width: a tracking error beyond it is warned of [m]


class TrajectoryWriter:
    """Streams trajectory rows to disk in bounded batches, so that neither memory nor a crash
    depends on the length of the run.

    While the run goes, every ``flush_rows`` rows become one record batch of an Arrow IPC stream
    (``trajectories.partial.arrows`` beside ``path``, zstd-compressed), flushed to the operating
    system: a run killed outright (SIGKILL, power) leaves a stream that :func:`read_trajectories`
    reads up to its last whole batch. :meth:`close` turns the stream into ``path`` (Parquet, one row
    group per batch, written under a temporary name and renamed) and removes it.
    """

    def __init__(self, path: Path, flush_rows: int = 5_000):
        import pyarrow as pa

        self.path = Path(path)
        self.partial = self.path.with_name(PARTIAL_TRAJECTORIES)
        self.flush_rows = flush_rows
        self._cols: dict[str, list] = {k: [] for k in TRAJECTORY_COLUMNS}
        self._n = 0
        self._sink = None
        self._stream = None
        self._schema = pa.schema(
            [(k, pa.string() if v == "string" else pa.float64()) for k, v in TRAJECTORY_COLUMNS.items()]
        )
        self.rows_written = 0
        self._closed = False

    def append(self, **cols) -> None:
        """Append equal-length columns (arrays or lists); every trajectory column is required."""
        n = None
        for k in TRAJECTORY_COLUMNS:
            v = cols[k]
            if np.ndim(v) == 0:
                v = [v]
            self._cols[k].extend(list(v) if not isinstance(v, np.ndarray) else v.tolist())
            n = len(v)
        self._n += n or 0
        if self._n >= self.flush_rows:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows as one batch of the stream and hand it to the operating system."""
        import pyarrow as pa

        if self._n == 0:
            return
        # (an interrupt inside append may have left the columns of its step unequal: that step is dropped)
        n = min(len(v) for v in self._cols.values())
        batch = pa.RecordBatch.from_pydict({k: v[:n] for k, v in self._cols.items()}, schema=self._schema)
        if self._stream is None:
            self._sink = pa.OSFile(str(self.partial), "wb")
            self._stream = pa.ipc.new_stream(self._sink, self._schema,
                                             options=pa.ipc.IpcWriteOptions(compression="zstd"))
        self._stream.write_batch(batch)
        self._sink.flush()
        self.rows_written += n
        self._cols = {k: [] for k in TRAJECTORY_COLUMNS}
        self._n = 0

    def close(self) -> None:
        """Flush, and write ``path`` from the stream (an empty file when nothing was logged); once
        closed, nothing more (a second close must not write an empty file over the first's)."""
        import pyarrow.parquet as pq

        if self._closed:
            return
        self._closed = True
        self.flush()
        tmp = self.path.with_name(self.path.name + ".tmp")
        if self._stream is None:
            pq.write_table(self._schema.empty_table(), tmp)
        else:
            self._stream.close()
            self._sink.close()
            self._stream = self._sink = None
            with pq.ParquetWriter(tmp, self._schema, compression="zstd") as out:
                for batch in _stream_batches(self.partial):
                    out.write_batch(batch)
        tmp.replace(self.path)
        self.partial.unlink(missing_ok=True)


def _stream_batches(path: Path):
    """The whole record batches of an Arrow IPC stream, stopping quietly at a truncated tail."""
    import pyarrow as pa

    with pa.OSFile(str(path), "rb") as f:
        try:
            reader = pa.ipc.open_stream(f)
        except (pa.ArrowInvalid, OSError):
            return
        while True:
            try:
                yield reader.read_next_batch()
            except StopIteration:
                return
            except (pa.ArrowInvalid, OSError):  # cut off mid-batch by a kill
                return


# decimals a figure is written with, by the unit suffix of its name (the first that matches); a
# figure of no listed unit takes that of the key it is under (summary.json's nested tables), and
# at the top DEFAULT_DECIMALS
RESOLUTIONS = (
    ("_veh_h", 1),  # flows [veh/h]: 0.1
    ("share", 4), ("_frac", 4),  # shares and fractions: 0.0001
    ("_mps2", 3), ("_mps", 3),  # accelerations [m/s^2], speeds [m/s]: 0.001
    ("error_m", 5), ("_dev_m", 5),  # tracking errors and lateral deviations [m]: 0.01 mm (the paper's are mm)
    ("_s", 3), ("_m", 3),  # times and durations [s], lengths and positions [m]: 0.001
    ("_veh", 3), ("_ml", 3), ("_u2", 3), ("_per_vehicle", 3), ("_factor", 3),  # queues, fuel, energy, means
)
EXACT_DECIMALS = {"t": 3}  # collision_events' time [s]
DEFAULT_DECIMALS = 6  # anything else (barrier values, counts written as floats)
AGGREGATES = ("_mean", "_sd", "_ci95")  # a sweep's statistics of a figure


def decimals_of(name: str, inherited: int = DEFAULT_DECIMALS) -> int:
    """The decimals a figure named ``name`` is written with (:data:`RESOLUTIONS`; a sweep's
    ``<figure>_mean``, ``_sd`` and ``_ci95`` those of the figure)."""
    for agg in AGGREGATES:
        if name.endswith(agg):
            name = name[:-len(agg)]
            break
    if name in EXACT_DECIMALS:
        return EXACT_DECIMALS[name]
    for suffix, d in RESOLUTIONS:
        if name.endswith(suffix):
            return d
    return inherited


def _round(x: float, d: int) -> float:
    """``x`` to ``d`` decimals, without a negative zero."""
    return round(float(x), d) + 0.0


def round_summary(o, decimals: int = DEFAULT_DECIMALS):
    """summary.json's figures rounded to their resolutions (:data:`RESOLUTIONS`), recursively;
    strings, whole numbers, booleans and None unchanged."""
    if isinstance(o, dict):
        return {k: round_summary(v, decimals_of(str(k), decimals)) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [round_summary(v, decimals) for v in o]
    if isinstance(o, (bool, np.bool_)):
        return bool(o)
    if isinstance(o, (float, np.floating)):
        return _round(o, decimals) if math.isfinite(o) else o
    return o


def round_frame(df: pd.DataFrame) -> pd.DataFrame:
    """A table's float columns rounded to their resolutions (:data:`RESOLUTIONS`, by column name)."""
    df = df.copy()
    for c in df.columns:
        if pd.api.types.is_float_dtype(df[c]):
            df[c] = df[c].round(decimals_of(str(c))) + 0.0
        elif df[c].dtype == object and len(df[c]) and df[c].map(lambda v: isinstance(v, float)).any():
            d = decimals_of(str(c))
            df[c] = df[c].map(lambda v: _round(v, d) if isinstance(v, float) and math.isfinite(v) else v)
    return df


def _json_default(o):
    if isinstance(o, (np.floating,)):
        return None if not np.isfinite(o) else float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _clean(o):
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


# summary.json is padded with trailing blanks to this size [bytes], so that on a full disk the last
# summary can still be written over the earlier one in place, without new space
SUMMARY_RESERVE_BYTES = 64 * 1024


def write_atomic(path: Path, data: bytes) -> None:
    """``data`` into ``path``, under a temporary name and renamed when whole."""
    tmp = Path(path).with_name(Path(path).name + ".tmp")
    try:
        tmp.write_bytes(data)
        tmp.replace(path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def write_summary(path: Path, summary: dict) -> None:
    """summary.json, whole or not at all: written under a temporary name and renamed, padded with
    blanks to :data:`SUMMARY_RESERVE_BYTES`. Where that fails (a full disk), it is written over the
    earlier summary in place, in the space that one holds, when it fits."""
    text = json.dumps(_clean(round_summary(summary)), indent=2, default=_json_default) + "\n"
    data = text.encode()
    data += b" " * max(SUMMARY_RESERVE_BYTES - len(data) - 1, 0) + (b"\n" if len(data) < SUMMARY_RESERVE_BYTES else b"")
    try:
        write_atomic(path, data)
    except OSError:
        path = Path(path)
        if not path.is_file() or path.stat().st_size < len(text.encode()):
            raise
        size = path.stat().st_size
        with open(path, "r+b") as fh:  # the same size: no new blocks
            fh.write(text.encode() + b" " * (size - len(text.encode())))


def write_vehicles(path: Path, vehicles: pd.DataFrame) -> None:
    write_table(path, vehicles)


QUEUE_DETECTOR = "queue:"  # a queue detector's id: this, then its lane's id (SUMO's schema allows no '|')


def queue_approach(detector_id: str) -> str:
    """The approach (edge) of a queue detector: ``queue:<lane>``, the lane's edge (SUMO names a
    lane ``<edge>_<index>``); runs of earlier versions named it ``queue|<approach>|<lane>``."""
    if "|" in detector_id:
        return detector_id.split("|")[1]
    return edge_of(detector_id.removeprefix(QUEUE_DETECTOR))


QUEUE_COLUMNS = ["approach", "begin_s", "end_s", "mean_queue_veh", "max_queue_veh", "mean_queue_m", "max_queue_m"]


def parse_queues(path: Path, t0_s: float = 0.0) -> pd.DataFrame:
    """Queues per approach and detector period from SUMO's lane-area detectors (``queues.xml``,
    detector ids ``queue:<lane>``, :func:`queue_approach`): ``mean_queue_veh`` is SUMO's time-mean of the longest jam
    (``meanMaxJamLengthInVehicles``), ``max_queue_veh`` the longest (``maxJamLengthInVehicles``),
    each summed over the approach's lanes; the same in metres. Periods are measured from the run's
    start, SUMO's clock ``t0_s`` (``scenario.begin_s``) [s]."""
    import xml.etree.ElementTree as ET

    if not Path(path).is_file():
        return pd.DataFrame(columns=QUEUE_COLUMNS)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError:  # a run that stopped early may leave it unterminated
        return pd.DataFrame(columns=QUEUE_COLUMNS)
    rows = [(queue_approach(iv.get("id")), float(iv.get("begin")) - t0_s, float(iv.get("end")) - t0_s,
             float(iv.get("meanMaxJamLengthInVehicles")), float(iv.get("maxJamLengthInVehicles")),
             float(iv.get("meanMaxJamLengthInMeters")), float(iv.get("maxJamLengthInMeters")))
            for iv in root.iter("interval")]
    df = pd.DataFrame(rows, columns=QUEUE_COLUMNS)
    return df.groupby(["approach", "begin_s", "end_s"], as_index=False).sum()


def to_csv(table: pd.DataFrame, path) -> None:
    """``table`` as CSV, its numbers rounded to their resolutions (:func:`round_frame`) and written
    positionally (0.00009, not 9e-05); empty cells for missing values."""
    def positional(v):
        return np.format_float_positional(v, trim="0") if isinstance(v, float) and math.isfinite(v) else v

    df = round_frame(table)
    for c in df.columns:
        if pd.api.types.is_float_dtype(df[c]) or df[c].dtype == object:
            df[c] = df[c].map(positional).astype(object)
    df.to_csv(path, index=False)


def write_table(path: Path, table: pd.DataFrame) -> None:
    """A CSV table (:func:`to_csv`) written under a temporary name and renamed when whole."""
    tmp = Path(path).with_suffix(".csv.tmp")
    to_csv(table, tmp)
    tmp.replace(path)


def write_movements(path: Path, result: "RunResult") -> pd.DataFrame:
    """``movements.csv``: the per-movement table of a run (:func:`nrtraffic.metrics.movement_table`)
    over its measurement window, as the run computed it (``result.extra["movements"]``), or
    computed here from its vehicles."""
    table = result.extra.get("movements")
    if table is None:
        table = movements_of(result.vehicles, result.summary, Path(path).parent / "movements.json")
    write_table(path, table)
    return table


def movements_of(vehicles: pd.DataFrame, s: dict, doc_path: Path) -> pd.DataFrame:
    """The per-movement table of a run's ``vehicles`` over the window of its summary ``s``, with a
    row for every movement of ``movements.json`` (``doc_path``) where there is one."""
    from nrtraffic.metrics import movement_table, run_is_signalised

    known = ()
    if Path(doc_path).is_file():
        known = [(m["approach"], m["turn"]) for m in json.loads(Path(doc_path).read_text())["movements"].values()]
    return movement_table(vehicles, s.get("measure_from_s") or 0.0, s.get("measure_to_s") or 0.0,
                          run_is_signalised(s), known)


def read_trajectories(run_dir: Path) -> pd.DataFrame:
    """A run's trajectories: ``trajectories.parquet``, or, for a run that was killed before it
    could write it, the rows of ``trajectories.partial.arrows`` up to its last whole batch."""
    run_dir = Path(run_dir)
    path = run_dir / "trajectories.parquet"
    if path.is_file() or not (run_dir / PARTIAL_TRAJECTORIES).is_file():
        return read_parquet_file(path)
    import pyarrow as pa

    batches = list(_stream_batches(run_dir / PARTIAL_TRAJECTORIES))
    schema = pa.schema([(k, pa.string() if v == "string" else pa.float64()) for k, v in TRAJECTORY_COLUMNS.items()])
    return pa.Table.from_batches(batches, schema=schema).to_pandas()


def read_parquet_file(path: Path) -> pd.DataFrame:
    """One Parquet file as a DataFrame. Unlike ``pandas.read_parquet`` it does not read
    ``key=value`` folders of the path as Hive partitions (sweep run directories are named so)."""
    import pyarrow.parquet as pq

    return pq.ParquetFile(path).read().to_pandas()


def read_fcd(path: Path) -> pd.DataFrame:
    """SUMO's floating-car data (``fcd.xml``) as rows ``t, vehicle_id, x, y, speed, acceleration``
    (positions of the front bumper, as SUMO reports them)."""
    import xml.etree.ElementTree as ET

    rows = []
    for _, el in ET.iterparse(path, events=("end",)):
        if el.tag == "timestep":
            t = float(el.get("time"))
            for v in el.findall("vehicle"):
                rows.append((t, v.get("id"), float(v.get("x")), float(v.get("y")), float(v.get("speed")),
                             float(v.get("acceleration", "nan"))))
            el.clear()
    return pd.DataFrame(rows, columns=["t", "vehicle_id", "x", "y", "speed", "acceleration"])


# ---------------------------------------------------------------------- the tables of a run
def read_tripinfo(path: Path) -> dict[str, tuple[float, float, float]]:
    """Per finished trip, SUMO's own timeLoss [s], number of stops (``waitingCount``: times its
    speed fell below 0.1 m/s) and travel time (``duration``) [s] from tripinfo.xml (nothing where
    it is missing, or unterminated by a run that stopped early)."""
    if not path.is_file():
        return {}
    import xml.etree.ElementTree as ET

    try:
        return {t.get("id"): (float(t.get("timeLoss")), float(t.get("waitingCount")), float(t.get("duration")))
                for t in ET.parse(path).getroot().iter("tripinfo")}
    except ET.ParseError:
        return {}


def vehicle_table(records, paths: dict, trips: dict, control: bool) -> pd.DataFrame:
    """``vehicles.csv``: one row per crossing (``records``, in order of departure, a corridor
    trip's crossings in order) of a vehicle that entered the run, with its figures. ``trips``:
    SUMO's tripinfo (:func:`read_tripinfo`); ``control``: a controlled run, where the scenario's
    own SUMO-driven vehicles (scripted leaders) are left out."""
    from nrtraffic.control import batch as kb
    from nrtraffic.metrics import free_flow_delay, free_flow_time

    rows = []
    for rec in sorted(records, key=lambda r: (r.t_depart, r.leg)):
        if rec.status == "waiting" or (control and not rec.controlled and rec.driver != "human"):
            continue  # (a SUMO-driven vehicle of the scenario's own, e.g. a scripted leader)
        ap = paths.get(rec.movement)
        delay = t_free = math.nan
        if math.isnan(rec.t_arrive):  # SUMO-driven: t_enter is when it crossed the entry
            t_from, s_from = rec.t_enter, rec.s_enter
        else:  # controlled: from crossing the entry, before any wait for its batch or a merge time
            t_from, s_from = rec.t_arrive, rec.s_arrive
        if ap is not None and not math.isnan(t_from):
            # when it would have left the merging zone at its free-flow speed [s]
            t_free = float(t_from + free_flow_time(ap.s_exit - s_from, rec.v_free))
        if ap is not None and not math.isnan(rec.t_exit):
            # plus the wait to enter the network at all, so that a control whose queues back up to
            # the insertion point is not credited with the demand it kept out
            delay = float(free_flow_delay(t_from, rec.t_exit, ap.s_exit - s_from, rec.v_free)) + rec.depart_delay
        admitted = not math.isnan(rec.t_enter)
        a = rec.acc.copy() if admitted else np.full(kb.N_ACC, np.nan)
        if not rec.controlled:  # SUMO drove it: no tracking, no barriers
            for k in (kb.ACC_MAX_ERR, kb.ACC_MAX_ERR_STEADY, kb.ACC_MAX_ERR_TRANSIENT, kb.ACC_MAX_LAT,
                      kb.ACC_LONG_ACTIVE, kb.ACC_LAT_ACTIVE, kb.ACC_LONG_FALLBACK, kb.ACC_LAT_FALLBACK):
                a[k] = math.nan
        steps = a[kb.ACC_STEPS]

        def fin(v):
            return v if np.isfinite(v) else math.nan

        rows.append({
            "vehicle_id": rec.vehicle_id, "junction": rec.junction, "leg": rec.leg, "legs": len(rec.legs) or 1,
            "approach": rec.approach, "driver": rec.driver,
            "movement": ap.turn if ap is not None else "", "lane": rec.lane,
            "t_arrive_s": rec.t_enter if math.isnan(rec.t_arrive) else rec.t_arrive,
            "depart_delay_s": rec.depart_delay,
            "t_enter_s": rec.t_enter, "v_enter_mps": rec.v_enter, "t_merge_planned_s": rec.t_merge_planned,
            "t_merge_actual_s": rec.t_merge_actual, "t_exit_s": rec.t_exit, "t_exit_free_s": t_free,
            "delay_s": delay,
            "max_tracking_error_m": a[kb.ACC_MAX_ERR], "steady_tracking_error_m": a[kb.ACC_MAX_ERR_STEADY],
            "transient_tracking_error_m": a[kb.ACC_MAX_ERR_TRANSIENT], "max_lateral_dev_m": a[kb.ACC_MAX_LAT],
            "min_bumper_gap_m": fin(rec.min_gap), "energy_u2": a[kb.ACC_ENERGY], "fuel_ml": a[kb.ACC_FUEL],
            "predecessor": rec.predecessor or "", "relation": rec.relation, "binding": rec.binding,
            "profile": rec.profile_kind, "plan_rear_end_intrusion_m": rec.plan_intrusion,
            "v_merge_planned_mps": rec.v_merge_planned,
            "min_center_distance_m": fin(a[kb.ACC_MIN_CENTER]), "max_abs_accel_mps2": a[kb.ACC_MAX_ABS_A],
            "cbf_long_active_frac": a[kb.ACC_LONG_ACTIVE] / steps if steps else math.nan,
            "cbf_lat_active_frac": a[kb.ACC_LAT_ACTIVE] / steps if steps else math.nan,
            "cbf_long_fallbacks": a[kb.ACC_LONG_FALLBACK], "cbf_lat_fallbacks": a[kb.ACC_LAT_FALLBACK],
            "min_h_long": fin(a[kb.ACC_MIN_H_LONG]), "min_h_lat": fin(a[kb.ACC_MIN_H_LAT]),
            "plant_steps": steps if rec.controlled else 0.0,
            "t_held_s": rec.t_held, "t_release_s": rec.t_release, "replans": rec.replans,
            "sumo_time_loss_s": trips.get(rec.vehicle_id, (math.nan,))[0],
            "stops": trips.get(rec.vehicle_id, (math.nan, math.nan))[1],
            "status": rec.status,
        })
    return pd.DataFrame(rows, columns=VEHICLE_COLUMNS)


def trip_table(veh: pd.DataFrame) -> pd.DataFrame:
    """One row per trip: ``veh`` itself when every vehicle crosses one junction; on a corridor,
    a vehicle's crossings added up (delay, energy, fuel), its first crossing's arrival and
    wait to enter, and its last crossing's exit (NaN, as is the delay, until it has crossed
    every junction of its trip)."""
    if veh.empty or (veh["legs"] <= 1).all():
        return veh
    out = veh.drop_duplicates("vehicle_id", keep="first").set_index("vehicle_id")
    last = veh.drop_duplicates("vehicle_id", keep="last").set_index("vehicle_id")
    complete = (last["leg"] == last["legs"] - 1) & last["t_exit_s"].notna()
    out["t_exit_s"] = last["t_exit_s"].where(complete)
    sums = veh.groupby("vehicle_id", sort=False)[["delay_s", "energy_u2", "fuel_ml"]].sum(min_count=1)
    out["delay_s"] = sums["delay_s"].where(complete)
    out["energy_u2"], out["fuel_ml"] = sums["energy_u2"], sums["fuel_ml"]
    return out.reset_index()[veh.columns]


def corridor_table(veh: pd.DataFrame, trips: dict, n_junctions: int, w0: float, w1: float) -> dict:
    """summary.json ``corridor`` (several junctions): the trips straight through every
    controlled junction, per road they enter by (a direction of the arterial), that entered
    their first control zone in the window ``[w0, w1]`` [s] and left the network: how many, their
    mean travel time (SUMO's tripinfo duration, from insertion to arrival, plus the wait to be
    inserted) [s], stops per vehicle (SUMO's waitingCount) and delay (the crossings' delays added
    up) [s]."""
    from nrtraffic import metrics

    if n_junctions < 2 or veh.empty:
        return {}
    n = n_junctions
    g = veh.groupby("vehicle_id", sort=False)
    through = g["movement"].agg(lambda m: bool((m == "straight").all())) & (g["leg"].count() == n)
    first = veh.drop_duplicates("vehicle_id").set_index("vehicle_id")
    ok = through & first["t_arrive_s"].between(w0, w1) & first.index.isin(list(trips))
    delay = g["delay_s"].sum(min_count=n)
    out = {}
    for appr in sorted(set(first.loc[ok[ok].index, "approach"])):
        ids = [v for v in ok[ok].index if first.at[v, "approach"] == appr]
        tt = [trips[v][2] + first.at[v, "depart_delay_s"] for v in ids]
        out[appr] = {"vehicles": len(ids), "travel_time_s": float(np.mean(tt)),
                     "stops_per_vehicle": float(np.mean([trips[v][1] for v in ids])),
                     "delay_s": metrics.mean_or_none(delay[ids])}
    return out


def junction_table(veh: pd.DataFrame, junctions: dict, signalised: bool, w0: float, w1: float,
                   t_end: float, waiting: list) -> dict:
    """summary.json ``junctions``: per controlled junction over the window ``[w0, w1]`` [s] (the
    run ended at ``t_end`` [s]): its throughput [veh/h] (crossings that left its merging zone in
    the window, :func:`~nrtraffic.metrics.left_in_window`); the crossings that entered its control
    zone in the window and left its merging zone (``vehicles``), their mean and 95th-percentile
    delay [s] and the HCM letter (by the signalised thresholds where ``signalised``); the vehicles
    demanded of it and served, and their ratio ``served_share`` (module docstring; ``waiting``:
    ``(desired departure [s], junction)`` of the vehicles SUMO could not insert); and its zones."""
    from nrtraffic import metrics

    out = {}
    for jid, j in junctions.items():
        at = veh[veh["junction"] == jid]
        g = at[metrics.completed_in_window(at, w0, w1)]
        n_left = int(metrics.left_in_window(at, w0, w1).sum())
        demanded, served = demand_served(at, [t for t, jj in waiting if jj == jid], w0, w1, t_end)
        mean = metrics.mean_or_none(g["delay_s"])
        out[jid] = {"vehicles": int(len(g)), "throughput_veh_h": metrics.flow_veh_h(n_left, w0, w1),
                    "vehicles_demanded": demanded, "vehicles_served": served,
                    "served_share": served / demanded if demanded else None,
                    "mean_delay_s": mean, "p95_delay_s": metrics.percentile_or_none(g["delay_s"], 95),
                    "los": (metrics.level_of_service(mean, signalised)
                            if mean is not None else None),
                    "control_zone_m": j.control_zone_m, "merging_zone_m": j.merging_zone_m}
    return out


def demand_served(at: pd.DataFrame, waiting: list, w0: float, w1: float, t_end: float) -> tuple[int, int]:
    """At one junction (``at``: its rows of vehicles.csv; ``waiting``: desired departure times [s]
    of the vehicles bound for it that SUMO could not insert by ``t_end``), the vehicles demanded
    of it in the window ``[w0, w1]`` [s] and how many of them it served: demanded, the crossings
    that entered its control zone in the window and would have left its merging zone by the end of
    the run ``t_end`` at their free-flow speed, and the vehicles not inserted whose desired
    departure is in the window; served, those crossings that left its merging zone."""
    due = at["t_arrive_s"].between(w0, w1) & (at["t_exit_free_s"] <= t_end)
    served = int((due & at["t_exit_s"].notna()).sum())
    return int(due.sum()) + sum(w0 <= t <= w1 for t in waiting), served


def driver_figures(adm: pd.DataFrame, done: pd.DataFrame, kind: dict[str, str], pairs: set) -> dict:
    """Figures split by driver (``demand.controlled_share``): the share of human drivers among
    the vehicles that entered the control zone in the window (``adm``), mean delay (of ``done``)
    and smallest bumper gap of each kind, and the colliding ``pairs`` (SUMO's check or the own one)
    by the kinds (``kind``: vehicle -> driver) of the two vehicles."""
    from nrtraffic import metrics

    n_pair = {"automated": 0, "mixed": 0, "human": 0}
    for a, b in pairs:
        ka, kb_ = kind.get(a, "automated"), kind.get(b, "automated")
        n_pair[ka if ka == kb_ else "mixed"] += 1
    out = {"human_share": float((adm["driver"] == "human").mean()) if len(adm) else None}
    for d in ("automated", "human"):
        out[f"vehicles_{d}"] = int((adm["driver"] == d).sum())
        out[f"mean_delay_{d}_s"] = metrics.mean_or_none(done.loc[done["driver"] == d, "delay_s"])
        out[f"min_bumper_gap_{d}_m"] = metrics.min_or_none(adm.loc[adm["driver"] == d, "min_bumper_gap_m"])
    out.update({f"collisions_{k}": v for k, v in n_pair.items()})
    return out


def approach_table(vehicles: pd.DataFrame, queues: pd.DataFrame, approaches: list[str], demand_veh_h,
                   t_from: float, t_to: float) -> pd.DataFrame:
    """``approaches.csv``: per approach, its demand (``demand_veh_h(t_from, t_to, approach)``) and
    throughput over the window [veh/h] (vehicles of the approach leaving the merging zone in it,
    :func:`~nrtraffic.metrics.left_in_window`: the rows add up to the junctions' throughput), and
    its queue from SUMO's detectors (``queues``, :func:`parse_queues`) over the detector periods
    inside the window: mean and maximum, in vehicles and metres."""
    from nrtraffic import metrics

    cols = ["approach", "demand_veh_h", "throughput_veh_h", "mean_queue_veh", "max_queue_veh", "mean_queue_m",
            "max_queue_m"]
    q = queues
    if len(q):
        q = q[(q["begin_s"] >= t_from - 1e-9) & (q["end_s"] <= t_to + 1e-9)]
    hours = max(t_to - t_from, 0.0) / 3600.0
    rows = []
    for appr in approaches:
        demand = demand_veh_h(t_from, t_to, appr) if hours > 0 else math.nan
        n_left = int(((vehicles["approach"] == appr) & metrics.left_in_window(vehicles, t_from, t_to)).sum())
        g = q[q["approach"] == appr] if len(q) else q
        flow = metrics.flow_veh_h(n_left, t_from, t_to)
        rows.append({"approach": appr, "demand_veh_h": demand,
                     "throughput_veh_h": math.nan if flow is None else flow,
                     "mean_queue_veh": g["mean_queue_veh"].mean() if len(g) else math.nan,
                     "max_queue_veh": g["max_queue_veh"].max() if len(g) else math.nan,
                     "mean_queue_m": g["mean_queue_m"].mean() if len(g) else math.nan,
                     "max_queue_m": g["max_queue_m"].max() if len(g) else math.nan})
    return pd.DataFrame(rows, columns=cols)


@dataclass
class RunFacts:
    """What the tables of a run are computed from, besides its records: who ran it and how long,
    and what happened at the run's level. Times [s]."""

    scenario: str
    label: str  # what drove the vehicles: "nrtraffic" or the baseline's name
    signalised: bool  # the junctions are signals (HCM's signalised level-of-service thresholds)
    seed: int
    sim_time_s: float
    wall_time_s: float
    warmup_s: float
    measure_end_s: float | None
    control: bool
    barriers: tuple[bool, bool]  # longitudinal, lateral
    collisions_sumo: set
    collisions_geometric: set
    collision_log: list
    zone_cuts: dict
    junctions: dict  # id -> Junction
    zone_crossing_s: float  # the time a car needs to cross the longest control zone at the speed limit [s]
    waiting_to_enter: list  # (desired departure [s], junction) of the vehicles SUMO could not insert yet
    vehicles_spawned: int  # vehicles SUMO inserted
    drivers: dict  # vehicle -> "automated" or "human"
    wall_breakdown: dict
    versions: tuple[str, str]  # nrtraffic's, SUMO's
    begin_s: float = 0.0  # SUMO's clock at the run's start (scenario.begin_s); the times above are from it
    notes: tuple = ()  # what the run did differently from the demand as given (warnings)


def run_summary(f: RunFacts, veh: pd.DataFrame, trips: dict, demand_veh_h, status: str,
                error: BaseException | None) -> dict:
    """summary.json of a run from its vehicle table ``veh`` (:func:`vehicle_table`), SUMO's
    ``trips`` and the facts ``f``. ``demand_veh_h(begin, end)``: the demand of a window [veh/h]
    (None where it cannot be known). The window: ``warmup_s`` to ``measure_end_s`` (the end of the
    run where it is not set); throughput, delay figures and served share count in it as the module
    docstring says. Unrounded: :func:`round_summary` gives the figures as written."""
    from nrtraffic import metrics
    from nrtraffic.planning.coordinator import REAR_END_TOL_M

    sim_t, wall = f.sim_time_s, f.wall_time_s
    w0, w1 = f.warmup_s, (f.measure_end_s or sim_t)
    w1 = min(w1, sim_t)
    # the measurement window: vehicles that entered the control zone inside it
    inside = veh["t_arrive_s"].between(w0, w1)
    adm_all = veh[veh["t_enter_s"].notna() & inside]
    # the trips (a corridor: a vehicle's crossings added up; one junction: its crossing)
    trip = trip_table(veh)
    done = trip[trip["t_exit_s"].notna() & trip["t_arrive_s"].between(w0, w1)]
    # the vehicles' own figures (tracking, barriers, gaps) are the automated vehicles'; human
    # drivers have theirs apart (driver_figures)
    adm = adm_all[adm_all["driver"] == "automated"]
    steps = adm["plant_steps"].sum()
    window = max(w1 - w0, 0.0)
    due_at = [(t, j) for t, j in f.waiting_to_enter if t <= sim_t]  # due to depart, but SUMO could not insert it
    due = [t for t, _ in due_at]
    junctions = junction_table(veh, f.junctions, f.signalised, w0, w1, sim_t, due_at)
    # throughput: the crossings that left a merging zone in the window, the sum of the junctions'
    left = metrics.left_in_window(veh, w0, w1)
    if f.junctions:
        left &= veh["junction"].isin(list(f.junctions))
    exits = int(left.sum())
    throughput = metrics.flow_veh_h(exits, w0, w1)
    demand = demand_veh_h(w0, w1) if window > 0 and demand_veh_h is not None else 0.0
    mean_delay = metrics.mean_or_none(done["delay_s"])
    controlled = f.control
    if f.junctions:
        demanded = sum(j["vehicles_demanded"] for j in junctions.values())
        n_served = sum(j["vehicles_served"] for j in junctions.values())
    else:
        demanded, n_served = demand_served(veh, due, w0, w1, sim_t)
    served = n_served / demanded if demanded else None
    warnings = []
    if window <= 0 and sim_t > 0:  # (a run without a duration that ended before its window opened)
        warnings.append(f"the measurement window is empty: it opens at outputs.warmup_s = {w0:g} s and the run "
                        f"ended at {w1:g} s ({'outputs.measure_end_s' if f.measure_end_s else 'its end'}), so no "
                        "figure of traffic was measured; lower outputs.warmup_s, or give the run a longer demand")
    if 0 < window < f.zone_crossing_s:
        warnings.append(f"the measurement window ({w0:g}-{w1:g} s, {window:g} s) is shorter than the "
                        f"{f.zone_crossing_s:.0f} s a car needs to cross the control zone at the speed limit: few "
                        "vehicles both enter and leave inside it; lengthen --duration (scenario.duration_s) or "
                        "outputs.measure_end_s, or lower outputs.warmup_s")
    if f.collisions_sumo or f.collisions_geometric:
        warnings.append(f"collisions: {len(f.collisions_sumo)} in SUMO's check, {len(f.collisions_geometric)} in the "
                        f"own check (collision_events)")
    if window > 0 and not exits:
        warnings.append("no vehicle left a merging zone in the measurement window")
    if served is not None and served < 0.9:
        warnings.append(f"served {100 * served:.1f} % of the vehicles demanded in the window (below 90 %; "
                        "served_share, per junction in junctions)")
    if due:
        warnings.append(f"{len(due)} vehicles due to depart could not enter the network yet (mean wait "
                        f"{np.mean([sim_t - t for t in due]):.0f} s, not in the delay)")
    if f.vehicles_spawned == 0 and not due:
        warnings.append("the run had no vehicle: check the demand and the duration")
    track = metrics.max_or_none(adm["max_tracking_error_m"])
    if track is not None and track > LANE_WIDTH_M:
        warnings.append(f"a vehicle ran {track:.1f} m from its plan, more than a lane's width ({LANE_WIDTH_M:g} m): "
                        "see max_tracking_error_m in vehicles.csv")
    return {
        "scenario": f.scenario,
        "control": f.label,
        "signalised": f.signalised,
        "seed": f.seed,
        "status": status,
        "error": None if error is None else f"{type(error).__name__}: {error}",
        "warnings": warnings + list(f.notes),
        "begin_s": f.begin_s,
        "sim_time_s": sim_t,
        "wall_time_s": wall,
        "real_time_factor": sim_t / wall if wall > 0 else None,
        "measure_from_s": w0,
        "measure_to_s": w1,
        "vehicles_spawned": f.vehicles_spawned,
        "vehicles_admitted": int(len(adm_all)),
        "vehicles_completed": int(len(done)),
        "throughput_veh_h": throughput,
        "demand_veh_h": demand or None,
        "vehicles_demanded": demanded,
        "vehicles_served": n_served,
        "served_share": served,
        "control_zones_cut_m": dict(f.zone_cuts),
        "junctions": junctions,
        "corridor": corridor_table(veh, trips, len(f.junctions), w0, w1),
        "vehicles_waiting_to_enter": len(due),
        "mean_wait_to_enter_s": float(np.mean([sim_t - t for t in due])) if due else None,
        "mean_depart_delay_s": metrics.mean_or_none(done["depart_delay_s"]),
        "mean_delay_s": mean_delay,
        "los": (metrics.level_of_service(mean_delay, f.signalised)
                if mean_delay is not None else None),
        "mean_sumo_time_loss_s": metrics.mean_or_none(done["sumo_time_loss_s"]),
        "vehicles_held": int((veh.loc[inside, "t_held_s"] > 0).sum()),
        "plans_rear_end_constrained": int((adm["profile"] == "rear_end").sum()),
        "plans_rear_end_unresolved": int((adm["plan_rear_end_intrusion_m"] > REAR_END_TOL_M).sum()),
        "p95_delay_s": metrics.percentile_or_none(done["delay_s"], 95),
        "collisions": len(f.collisions_sumo),
        "collisions_geometric": len(f.collisions_geometric),
        "collision_events": f.collision_log[:100],
        "min_center_distance_m": metrics.min_or_none(adm["min_center_distance_m"]),
        "min_bumper_gap_m": metrics.min_or_none(adm["min_bumper_gap_m"]),
        "max_tracking_error_m": metrics.max_or_none(adm["max_tracking_error_m"]),
        "steady_tracking_error_m": metrics.max_or_none(adm["steady_tracking_error_m"]),
        "transient_tracking_error_m": metrics.max_or_none(adm["transient_tracking_error_m"]),
        "max_lateral_dev_m": metrics.max_or_none(adm["max_lateral_dev_m"]),
        "max_abs_accel_mps2": metrics.max_or_none(adm["max_abs_accel_mps2"]),
        "mean_energy_u2": metrics.mean_or_none(done["energy_u2"]),
        "mean_fuel_ml": metrics.mean_or_none(done["fuel_ml"]),
        # what only a controlled run has: null for a baseline
        "barriers_longitudinal": bool(f.barriers[0]) if controlled else None,
        "barriers_lateral": bool(f.barriers[1]) if controlled else None,
        "cbf_long_active_frac": float((adm["cbf_long_active_frac"] * adm["plant_steps"]).sum() / steps) if steps else None,
        "cbf_lat_active_frac": float((adm["cbf_lat_active_frac"] * adm["plant_steps"]).sum() / steps) if steps else None,
        "cbf_long_fallbacks": int(adm["cbf_long_fallbacks"].sum()) if controlled else None,
        "cbf_lat_fallbacks": int(adm["cbf_lat_fallbacks"].sum()) if controlled else None,
        **driver_figures(adm_all, done, f.drivers, f.collisions_sumo | f.collisions_geometric),
        "wall_time_breakdown_s": {**f.wall_breakdown,
                                  "qp": sum(j.coord.qp_wall_s for j in f.junctions.values() if j.coord is not None)},
        "nrtraffic_version": f.versions[0],
        "sumo_version": f.versions[1],
    }
