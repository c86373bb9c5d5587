"""Run results: the in-memory figures of a run, streaming trajectory writer, run-directory I/O.

A run directory holds ``summary.json``, ``vehicles.csv``, ``trajectories.parquet``,
``scenario.resolved.toml``, ``sumo/`` (the SUMO inputs of the run) and SUMO's ``tripinfo.xml`` and
``collisions.xml`` (DESIGN.md, contracts).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

VEHICLE_COLUMNS = [
    "vehicle_id", "junction", "leg", "legs", "approach", "driver", "movement", "lane", "depart_delay_s", "t_arrive_s", "t_enter_s", "v_enter_mps", "t_merge_planned_s", "t_merge_actual_s",
    "t_exit_s", "delay_s", "max_tracking_error_m", "steady_tracking_error_m", "transient_tracking_error_m",
    "max_lateral_dev_m",
    "min_bumper_gap_m", "energy_u2", "fuel_ml", "predecessor", "relation", "binding", "profile", "plan_rear_end_intrusion_m",
    "v_merge_planned_mps",
    "min_center_distance_m", "max_abs_accel_mps2", "cbf_long_active_frac", "cbf_lat_active_frac",
    "cbf_long_fallbacks", "cbf_lat_fallbacks", "min_h_long", "min_h_lat", "plant_steps", "t_held_s", "t_release_s",
    "sumo_time_loss_s", "stops", "status",
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
        batch = pa.RecordBatch.from_pydict(self._cols, schema=self._schema)
        if self._stream is None:
            self._sink = pa.OSFile(str(self.partial), "wb")
            self._stream = pa.ipc.new_stream(self._sink, self._schema,
                                             options=pa.ipc.IpcWriteOptions(compression="zstd"))
        self._stream.write_batch(batch)
        self._sink.flush()
        self.rows_written += self._n
        self._cols = {k: [] for k in TRAJECTORY_COLUMNS}
        self._n = 0

    def close(self) -> None:
        """Flush, and write ``path`` from the stream (an empty file when nothing was logged)."""
        import pyarrow.parquet as pq

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


def write_summary(path: Path, summary: dict) -> None:
    tmp = Path(path).with_suffix(".json.tmp")
    tmp.write_text(json.dumps(_clean(summary), indent=2, default=_json_default) + "\n")
    tmp.replace(path)


def write_vehicles(path: Path, vehicles: pd.DataFrame) -> None:
    write_table(path, vehicles)


QUEUE_COLUMNS = ["approach", "begin_s", "end_s", "mean_queue_veh", "max_queue_veh", "mean_queue_m", "max_queue_m"]


def parse_queues(path: Path) -> pd.DataFrame:
    """Queues per approach and detector period from SUMO's lane-area detectors (``queues.xml``,
    detector ids ``queue|approach|lane``): ``mean_queue_veh`` is SUMO's time-mean of the longest jam
    (``meanMaxJamLengthInVehicles``), ``max_queue_veh`` the longest (``maxJamLengthInVehicles``),
    each summed over the approach's lanes; the same in metres."""
    import xml.etree.ElementTree as ET

    if not Path(path).is_file():
        return pd.DataFrame(columns=QUEUE_COLUMNS)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError:  # a run that stopped early may leave it unterminated
        return pd.DataFrame(columns=QUEUE_COLUMNS)
    rows = [(iv.get("id").split("|")[1], float(iv.get("begin")), float(iv.get("end")),
             float(iv.get("meanMaxJamLengthInVehicles")), float(iv.get("maxJamLengthInVehicles")),
             float(iv.get("meanMaxJamLengthInMeters")), float(iv.get("maxJamLengthInMeters")))
            for iv in root.iter("interval")]
    df = pd.DataFrame(rows, columns=QUEUE_COLUMNS)
    return df.groupby(["approach", "begin_s", "end_s"], as_index=False).sum()


def write_table(path: Path, table: pd.DataFrame) -> None:
    """A CSV table, written under a temporary name and renamed when whole."""
    tmp = Path(path).with_suffix(".csv.tmp")
    table.to_csv(tmp, index=False, float_format="%.6g")
    tmp.replace(path)


def write_movements(path: Path, result: "RunResult") -> pd.DataFrame:
    """``movements.csv``: the per-movement table of a run (:func:`nrtraffic.metrics.movement_table`)
    over its measurement window."""
    from nrtraffic.metrics import is_signalised, movement_table

    s = result.summary
    known = ()
    doc_path = Path(path).parent / "movements.json"
    if doc_path.is_file():
        known = [(m["approach"], m["turn"]) for m in json.loads(doc_path.read_text())["movements"].values()]
    table = movement_table(result.vehicles, s.get("measure_from_s") or 0.0, s.get("measure_to_s") or 0.0,
                           is_signalised(s.get("control")), known)
    write_table(path, table)
    return table


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
