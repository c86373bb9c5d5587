"""Fuel model of the vehicle: Kamal et al.'s polynomial as used by this line of work (Malikopoulos
et al. 2018), in mL/s with ``v`` [m/s] and ``u`` [m/s^2]; the acceleration term counts only for
``u > 0``. The compiled kernel integrates it every plant step; the engine, for vehicles SUMO
drives, every SUMO step."""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def fuel_rate(v, u):
    """Fuel consumption rate [mL/s] at speed ``v`` [m/s] and acceleration ``u`` [m/s^2]."""
    f = 0.1569 + 2.450e-2 * v - 7.415e-4 * v * v + 5.975e-5 * v * v * v
    if u > 0.0:
        f += u * (0.07224 + 9.681e-2 * v + 1.075e-3 * v * v)
    return f
