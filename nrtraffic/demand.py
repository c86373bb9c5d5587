"""Arrivals drawn from the run's random generator (pure: no SUMO, no I/O)."""

from __future__ import annotations

import numpy as np


def shifted_exponential_arrivals(rng: np.random.Generator, begin_s: float, end_s: float, mean_headway_s: float,
                                 min_headway_s: float, max_vehicles: int = 0) -> np.ndarray:
    """Departure times [s] in ``[begin_s, end_s]``: the first after one headway, then headways
    ``min_headway_s + Exp(mean_headway_s - min_headway_s)`` (mean ``mean_headway_s``).

    ``max_vehicles`` > 0 caps the count; ``end_s`` may be ``inf`` when it does.
    """
    if max_vehicles <= 0 and not np.isfinite(end_s):
        raise ValueError("arrivals need a finite end time or a maximum number of vehicles")
    out = []
    t = begin_s
    scale = mean_headway_s - min_headway_s
    while True:
        t += min_headway_s + rng.exponential(scale)
        if t > end_s or (max_vehicles > 0 and len(out) >= max_vehicles):
            break
        out.append(t)
    return np.array(out)
