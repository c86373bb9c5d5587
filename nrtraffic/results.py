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
    "vehicle_id", "approach", "movement", "t_enter_s", "v_enter_mps", "t_merge_planned_s", "t_merge_actual_s",
    "t_exit_s", "delay_s", "max_tracking_error_m", "steady_tracking_error_m", "transient_tracking_error_m",
    "max_lateral_dev_m",
    "min_bumper_gap_m", "energy_u2", "fuel_ml", "predecessor", "relation", "binding", "profile", "plan_rear_end_intrusion_m",
    "v_merge_planned_mps",
    "min_center_distance_m", "max_abs_accel_mps2", "cbf_long_active_frac", "cbf_lat_active_frac",
    "cbf_long_fallbacks", "cbf_lat_fallbacks", "min_h_long", "min_h_lat", "plant_steps", "t_held_s",
    "sumo_time_loss_s", "status",
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


class TrajectoryWriter:
    """Streams trajectory rows to Parquet in row groups (never the whole run in memory)."""

    def __init__(self, path: Path, flush_rows: int = 50_000):
        import pyarrow as pa

        self.path = Path(path)
        self.flush_rows = flush_rows
        self._cols: dict[str, list] = {k: [] for k in TRAJECTORY_COLUMNS}
        self._n = 0
        self._writer = None
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
        import pyarrow as pa
        import pyarrow.parquet as pq

        if self._n == 0:
            return
        table = pa.Table.from_pydict(self._cols, schema=self._schema)
        if self._writer is None:
            self._writer = pq.ParquetWriter(self.path, self._schema, compression="zstd")
        self._writer.write_table(table)
        self.rows_written += self._n
        self._cols = {k: [] for k in TRAJECTORY_COLUMNS}
        self._n = 0

    def close(self) -> None:
        self.flush()
        if self._writer is None:  # no rows: still write a valid, empty file
            import pyarrow.parquet as pq

            pq.write_table(self._schema.empty_table(), self.path)
        else:
            self._writer.close()
            self._writer = None


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
    vehicles.to_csv(path, index=False, float_format="%.6g")


def read_trajectories(run_dir: Path) -> pd.DataFrame:
    return read_parquet_file(Path(run_dir) / "trajectories.parquet")


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
