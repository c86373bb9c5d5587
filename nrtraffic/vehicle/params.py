"""Vehicle parameters: frozen dataclasses with units, and named presets."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np


MAX_LENGTH_M = 25.0  # longest body accepted [m] (a truck and trailer)
MAX_WIDTH_M = 4.0  # widest body accepted [m]
# physical ranges of the other parameters (a car to a loaded truck): mass [kg], yaw inertia [kg m^2],
# axle distances [m], cornering stiffness [N/rad], the low-speed blend [m/s] and its time constant [s]
RANGES = {"m": (300.0, 60000.0), "Iz": (50.0, 1e6), "lf": (0.3, 10.0), "lr": (0.3, 10.0), "Caf": (1e3, 1e7),
          "Car": (1e3, 1e7), "v_blend_low": (0.01, 10.0), "v_blend_high": (0.01, 20.0), "tau_kin": (1e-3, 10.0)}


@dataclass(frozen=True)
class BicycleParams:
    """Parameters of the dynamic bicycle model (paper eq. 1) and its low-speed treatment.

    Attributes
    ----------
    m : float
        Mass [kg].
    Iz : float
        Yaw moment of inertia [kg m^2].
    lf, lr : float
        Distance from the centre of gravity to the front / rear axle [m].
    Caf, Car : float
        Cornering stiffness of the front / rear tyre [N/rad].
    v_blend_low, v_blend_high : float
        Low-speed treatment [m/s]: below ``v_blend_low`` the lateral and yaw dynamics are those of
        the kinematic bicycle model, above ``v_blend_high`` those of the dynamic model, smoothly
        blended (C^1, smoothstep) in between. The dynamic model's lateral and yaw eigenvalues grow
        as 1 / v_l: forward Euler at 0.005 s is stable for it alone only above about 0.65 m/s
        (``bicycle.euler_step_limit_at``), hence the defaults 0.5 / 1.5, with which the blended
        model is stable at steps up to 0.011 s at every speed.
    tau_kin : float
        Time constant [s] with which the kinematic model pulls lateral velocity and yaw rate to
        their kinematic (no-slip) values.
    length, width : float
        Body size [m], for SUMO and the geometric collision check.
    cg_to_front : float
        Distance from the centre of gravity to the front bumper [m] (SUMO positions are front
        bumpers).
    """

    m: float = 2050.0
    Iz: float = 3344.0
    lf: float = 1.105
    lr: float = 1.738
    Caf: float = 57500.0
    Car: float = 92500.0
    v_blend_low: float = 0.5
    v_blend_high: float = 1.5
    tau_kin: float = 0.05
    length: float = 4.8
    width: float = 1.9
    cg_to_front: float = 2.4

    def __post_init__(self) -> None:
        for f in fields(self):
            val = getattr(self, f.name)
            if not np.isfinite(val) or val <= 0.0:
                raise ValueError(f"vehicle parameter {f.name} must be a positive number, got {val!r}")
        for name, (lo, hi) in RANGES.items():
            if not lo <= getattr(self, name) <= hi:
                raise ValueError(f"vehicle parameter {name} = {getattr(self, name):g} is outside its physical range "
                                 f"{lo:g} to {hi:g}")
        if self.length > MAX_LENGTH_M or self.width > MAX_WIDTH_M:
            raise ValueError(f"vehicle parameter length ({self.length:g} m) or width ({self.width:g} m) is beyond a "
                             f"road vehicle's ({MAX_LENGTH_M:g} m x {MAX_WIDTH_M:g} m)")
        if self.v_blend_high <= self.v_blend_low:
            raise ValueError("vehicle parameter v_blend_high must be above v_blend_low")
        if self.cg_to_front >= self.length:
            raise ValueError("vehicle parameter cg_to_front must be shorter than length")

    @property
    def wheelbase(self) -> float:
        """lf + lr [m]."""
        return self.lf + self.lr

    @property
    def cg_to_rear(self) -> float:
        """Distance from the centre of gravity to the rear bumper [m]."""
        return self.length - self.cg_to_front

    def with_mass_factor(self, factor: float) -> "BicycleParams":
        """A copy with the mass scaled (the paper's predictor uses twice the mass)."""
        return replace(self, m=self.m * factor)

    def as_array(self) -> np.ndarray:
        """Packed for the compiled kernels (order: :data:`PARAM_NAMES`)."""
        return np.array([getattr(self, n) for n in PARAM_NAMES], dtype=np.float64)


PARAM_NAMES = ("m", "Iz", "lf", "lr", "Caf", "Car", "v_blend_low", "v_blend_high", "tau_kin")

PRESETS: dict[str, BicycleParams] = {
    # Shivam et al. 2020, section 4 (after Kong et al. 2015); body size of a mid-size car.
    "paper": BicycleParams(),
}


def preset(name: str) -> BicycleParams:
    """Named parameter preset (``'paper'``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown vehicle preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None
