"""The vehicles under control, as the table the compiled kernel reads (structure of arrays).

One row per controlled vehicle, in the order of ``ids``; the kernel
(:func:`nrtraffic.control.batch.advance`) reads and writes the arrays in place. Rows are added
when a vehicle is admitted and dropped when it leaves the merging zone; the arrays stay
C-contiguous for the kernel.
"""

from __future__ import annotations

import math

import numpy as np

from nrtraffic.control import batch as kb

N_PROFILE_SEG = 81  # packed profile segments (closed forms: at most 3 arcs + cruise; rear-end QP: 80 + cruise)


class ControlledTable:
    """The controlled vehicles' arrays.

    ``X`` state (x, y [m], v_l, v_n [m/s], psi [rad], psi_dot [rad/s]), ``U`` the tracker's
    inputs, ``prof`` the packed profile, ``t_enter``/``s_enter`` when and where on its path
    [s, m] the profile starts, ``path_id``/``hint`` its path and the path segment it was last
    on, ``acc`` its running figures, ``out`` the kernel's outputs of the last step, ``lead_idx``/
    ``lead_ext``/``gap`` its leader (a row, or an external state) and the bumper gap to it [m],
    ``s_zone`` its merging-zone entry and exit on its path [m], ``t_merge`` its planned
    merging-zone entry [s], ``gate`` the point (x, y) [m] of its closed merging-zone entry when a
    nearer leader is its ``lead_*`` (NaN: none; :mod:`nrtraffic.junction.late`), ``s_last`` its
    arc length at the start of the step [m], ``act`` the actuators' output (with an actuator
    lag), ``xe`` the state observer's estimate (with an observer). ``rows`` is each vehicle's row
    in SUMO's table of the step (-1: SUMO no longer lists it).
    """

    COLUMNS = ("X", "U", "prof", "t_enter", "s_enter", "path_id", "hint", "acc", "out", "lead_idx", "lead_ext",
               "gap", "s_zone", "t_merge", "s_last", "act", "xe", "gate")

    def __init__(self) -> None:
        self.ids: list[str] = []
        self.rows = np.zeros(0, dtype=np.int64)
        n = 0
        self.X = np.zeros((n, 6))
        self.U = np.zeros((n, 2))
        self.prof = np.zeros((n, N_PROFILE_SEG, 5))
        self.t_enter = np.zeros(n)
        self.s_enter = np.zeros(n)
        self.path_id = np.zeros(n, dtype=np.int64)
        self.hint = np.zeros(n, dtype=np.int64)
        self.acc = kb.new_acc(n)
        self.out = np.full((n, kb.N_OUT), np.nan)
        self.lead_idx = np.full(n, kb.NO_LEADER, dtype=np.int64)
        self.lead_ext = np.zeros((n, 6))
        self.gap = np.full(n, np.nan)
        self.s_zone = np.zeros((n, 2))
        self.t_merge = np.zeros(n)
        self.s_last = np.zeros(n)
        self.act = np.zeros((n, 2))
        self.xe = np.zeros((n, 6))
        self.gate = np.full((n, 2), np.nan)

    def __len__(self) -> int:
        return len(self.ids)

    def append(self, vid: str, x0, prof, t0: float, s0: float, lat0: float, ref0, pid: int, hint: int,
               s_zone: tuple[float, float], t_merge: float = math.inf) -> None:
        """A vehicle taken under control at time ``t0`` [s]: state ``x0``, profile ``prof`` from
        arc length ``s0`` [m] of path ``pid``, lateral offset ``lat0`` [m], reference point
        ``ref0`` (x, y) [m], planned merging-zone entry ``t_merge`` [s]; SUMO drove it at constant
        speed, straight ahead, until now."""
        self.ids.append(vid)
        row = {
            "X": x0[None], "U": np.zeros((1, 2)), "prof": prof[None], "t_enter": [t0], "s_enter": [s0],
            "path_id": [pid], "hint": [hint], "acc": kb.new_acc(1), "out": np.full((1, kb.N_OUT), np.nan),
            "lead_idx": [kb.NO_LEADER], "lead_ext": np.zeros((1, 6)), "gap": [np.nan],
            "s_zone": [list(s_zone)], "t_merge": [t_merge], "s_last": [s0],
            "act": np.zeros((1, 2)),  # SUMO drove it at constant speed, straight ahead
            "xe": x0[None],  # the observer starts from the state at admission
            "gate": np.full((1, 2), np.nan),
        }
        for name in self.COLUMNS:
            cur = getattr(self, name)
            setattr(self, name, np.ascontiguousarray(np.concatenate([cur, np.asarray(row[name], dtype=cur.dtype)])))
        o = self.out[-1]
        o[kb.OUT_S], o[kb.OUT_LAT] = s0, lat0
        o[kb.OUT_REFX], o[kb.OUT_REFY] = ref0
        o[kb.OUT_ERR] = math.hypot(x0[0] - ref0[0], x0[1] - ref0[1])
        o[kb.OUT_A], o[kb.OUT_D] = 0.0, 0.0
        o[kb.OUT_AX], o[kb.OUT_AY] = 0.0, 0.0  # SUMO drove it at constant speed before

    def keep(self, keep: np.ndarray) -> None:
        """Drop the rows where ``keep`` is False."""
        self.ids = [v for v, k in zip(self.ids, keep) if k]
        for name in self.COLUMNS:
            setattr(self, name, np.ascontiguousarray(getattr(self, name)[keep]))
