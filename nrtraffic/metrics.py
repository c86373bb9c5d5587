"""Per-vehicle and per-run figures.

Fuel: Kamal et al.'s polynomial as used by this line of work (REFERENCE.md section 3), in mL/s with
``v`` [m/s] and ``u`` [m/s^2]; the acceleration term counts only for ``u > 0``.
Energy: ``1/2 int u^2 dt`` of the applied longitudinal acceleration [m^2/s^3].
Delay: time lost against free flow at the speed the vehicle was sent in with (its departure speed,
the entry speed of the demand), ``(t_exit - t_enter) - (s_exit - s_enter) / v_free`` [s]; a vehicle
held at the control-zone entry enters slower, and that lost time counts.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def fuel_rate(v, u):
    """Fuel consumption rate [mL/s] at speed ``v`` [m/s] and acceleration ``u`` [m/s^2]."""
    f = 0.1569 + 2.450e-2 * v - 7.415e-4 * v * v + 5.975e-5 * v * v * v
    if u > 0.0:
        f += u * (0.07224 + 9.681e-2 * v + 1.075e-3 * v * v)
    return f


def free_flow_delay(t_enter, t_exit, distance_m, v_enter):
    """Delay [s] against crossing ``distance_m`` at the entry speed."""
    return (np.asarray(t_exit) - np.asarray(t_enter)) - np.asarray(distance_m) / np.asarray(v_enter)


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


# HCM level of service by control delay per vehicle [s] (REFERENCE.md section 6): upper bounds of
# A..E; above the last, F
LOS_SIGNALISED = (10.0, 20.0, 35.0, 55.0, 80.0)
LOS_UNSIGNALISED = (10.0, 15.0, 25.0, 35.0, 50.0)


def level_of_service(delay_s: float, signalised: bool) -> str:
    """HCM level-of-service letter of a mean delay [s]: the signalised thresholds for a traffic
    light, the unsignalised (two-way and all-way stop) ones otherwise."""
    if delay_s is None or not np.isfinite(delay_s):
        return "n/a"
    for letter, bound in zip("ABCDE", LOS_SIGNALISED if signalised else LOS_UNSIGNALISED):
        if delay_s <= bound:
            return letter
    return "F"
