"""Per-vehicle and per-run figures.

Fuel: the vehicle's fuel model (:mod:`nrtraffic.vehicle.fuel`), integrated over the vehicle's time
in the zones [mL].
Energy: ``1/2 int u^2 dt`` of the applied longitudinal acceleration [m^2/s^3].
Delay: time lost against free flow at the speed the vehicle was sent in with (its departure speed,
the entry speed of the demand), ``(t_exit - t_arrive) - (s_exit - s_arrive) / v_free`` [s] from
crossing the control-zone entry to leaving the merging zone (a wait at the entry counts), plus the
time SUMO could not insert it because its lane was backed up (SUMO's departDelay).
Throughput: the vehicles leaving a merging zone in the measurement window, per hour of it
(:func:`left_in_window`), in every table; the delay figures count the vehicles that entered the
control zone in the window and left (:func:`completed_in_window`). What the tables hold, and the
resolutions they are written with: :mod:`nrtraffic.results`.
"""

from __future__ import annotations

import numpy as np


def free_flow_delay(t_enter, t_exit, distance_m, v_enter):
    """Delay [s] against crossing ``distance_m`` at the entry speed."""
    return (np.asarray(t_exit) - np.asarray(t_enter)) - np.asarray(distance_m) / np.asarray(v_enter)


def free_flow_time(distance_m, v_free):
    """Time [s] to cover ``distance_m`` [m] at the free-flow speed ``v_free`` [m/s]."""
    return np.asarray(distance_m) / np.asarray(v_free)


def left_in_window(vehicles, t_from: float, t_to: float):
    """Which rows of ``vehicles.csv`` count in a throughput: the crossings whose vehicle left the
    merging zone during ``[t_from, t_to]`` [s] (boolean Series)."""
    return vehicles["t_exit_s"].between(t_from, t_to)


def completed_in_window(vehicles, t_from: float, t_to: float):
    """Which rows count in the delay figures: the crossings that entered the control zone during
    ``[t_from, t_to]`` [s] and left the merging zone (boolean Series)."""
    return vehicles["t_arrive_s"].between(t_from, t_to) & vehicles["t_exit_s"].notna()


def flow_veh_h(count: int, t_from: float, t_to: float):
    """``count`` vehicles over ``[t_from, t_to]`` [s] as a flow [veh/h]; None for an empty window."""
    hours = max(t_to - t_from, 0.0) / 3600.0
    return count / hours if hours > 0 else None


def percentile_or_none(values, q):
    vals = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    return float(np.percentile(vals, q)) if vals.size else None


def mean_or_none(values):
    vals = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    return float(vals.mean()) if vals.size else None


def max_or_none(values):
    vals = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    return float(vals.max()) if vals.size else None


def min_or_none(values):
    vals = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    return float(vals.min()) if vals.size else None


# HCM level of service by control delay per vehicle [s] (Highway Capacity Manual, 6th ed.): upper bounds of
# A..E; above the last, F
LOS_SIGNALISED = (10.0, 20.0, 35.0, 55.0, 80.0)
LOS_UNSIGNALISED = (10.0, 15.0, 25.0, 35.0, 50.0)


def is_signalised(control: str) -> bool:
    """Whether a run's control (summary.json ``control``) is judged by the signalised HCM
    thresholds: SUMO's traffic lights (a run's ``sumo_traffic_light``, a sweep's ``traffic_light``,
    coordinated or not, and actuated ones); nrtraffic and the unsignalised baselines are not. An
    ``as_is`` run says it in its summary (``signalised``), from its network."""
    return str(control).removeprefix("sumo_") in ("traffic_light", "traffic_light_coordinated", "actuated")


def run_is_signalised(summary: dict, control: str | None = None) -> bool:
    """Whether a run is judged by the signalised thresholds: what its summary.json says
    (``signalised``), else by its control (:func:`is_signalised`; ``control`` where the summary's
    is named otherwise, as a sweep's)."""
    return bool(summary.get("signalised", is_signalised(summary.get("control") if control is None else control)))


def level_of_service(delay_s: float, signalised: bool) -> str:
    """HCM level-of-service letter of a mean delay [s]: the signalised thresholds for a traffic
    light, the unsignalised (two-way and all-way stop) ones otherwise."""
    if delay_s is None or not np.isfinite(delay_s):
        return "n/a"
    for letter, bound in zip("ABCDE", LOS_SIGNALISED if signalised else LOS_UNSIGNALISED):
        if delay_s <= bound:
            return letter
    return "F"


MOVEMENT_COLUMNS = ["approach", "movement", "vehicles", "throughput_veh_h", "mean_delay_s", "p95_delay_s", "los",
                    "los_thresholds", "stops_per_vehicle", "fuel_ml_per_vehicle"]


def movement_table(vehicles, t_from: float, t_to: float, signalised: bool, movements=()):
    """One row per (approach, movement) of a run's ``vehicles.csv`` over the window
    ``[t_from, t_to]`` [s]: its throughput [veh/h] (the vehicles that left the merging zone in the
    window, :func:`left_in_window`: the rows add up to the junctions' and the run's throughput),
    and, of the vehicles that entered the control zone in the window and left the merging zone
    (:func:`completed_in_window`, ``vehicles``), the mean and 95th-percentile delay [s], the HCM
    letter of the mean (``los_thresholds`` says which table), stops per vehicle (SUMO's
    waitingCount over the trip) and fuel [mL]. ``movements``: every ``(approach, movement)`` of the
    junction, so that one no vehicle took has its row too."""
    import pandas as pd

    v = vehicles[completed_in_window(vehicles, t_from, t_to)]
    out = vehicles[left_in_window(vehicles, t_from, t_to)]
    rows = []
    keys = set(map(tuple, vehicles[["approach", "movement"]].drop_duplicates().itertuples(index=False)))
    for appr, mv in sorted(keys | set(movements)):
        g = v[(v["approach"] == appr) & (v["movement"] == mv)]
        n_out = int(((out["approach"] == appr) & (out["movement"] == mv)).sum())
        mean = mean_or_none(g["delay_s"])
        rows.append({"approach": appr, "movement": mv, "vehicles": len(g),
                     "throughput_veh_h": flow_veh_h(n_out, t_from, t_to), "mean_delay_s": mean,
                     "p95_delay_s": percentile_or_none(g["delay_s"], 95),
                     "los": level_of_service(mean, signalised) if mean is not None else "n/a",
                     "los_thresholds": "signalised" if signalised else "unsignalised",
                     "stops_per_vehicle": mean_or_none(g["stops"]),
                     "fuel_ml_per_vehicle": mean_or_none(g["fuel_ml"])})
    return pd.DataFrame(rows, columns=MOVEMENT_COLUMNS)
