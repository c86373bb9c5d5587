"""Figures (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

G = 9.81  # [m/s^2]


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _car_label(vehicles: pd.DataFrame) -> dict[str, str]:
    order = vehicles.sort_values("t_enter_s")["vehicle_id"].tolist()
    return {v: f"car {k + 1}" for k, v in enumerate(order)}


def distance_travelled(traj: pd.DataFrame, vehicles: pd.DataFrame, path: Path, zone_end_m: float) -> Path:
    """Paper fig. 2: distance travelled from the control-zone entry vs time, held at the end of the
    merging zone after the vehicle leaves it; reference dashed."""
    labels = _car_label(vehicles)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    t_end = traj["t"].max()
    for vid, g in traj.groupby("vehicle_id", sort=False):
        line, = ax.plot(g["t"], g["s_m"].clip(upper=zone_end_m), label=labels.get(vid, vid))
        ax.plot(g["t"], g["ref_s_m"].clip(upper=zone_end_m), ls="--", lw=0.8, color=line.get_color())
        ax.plot([g["t"].iloc[-1], t_end], [min(g["s_m"].iloc[-1], zone_end_m)] * 2, color=line.get_color())
    ax.set_xlabel("time [s]")
    ax.set_ylabel("distance travelled [m]")
    ax.set_title("Distance travelled (solid) and target (dashed)")
    ax.legend()
    ax.grid(alpha=0.3)
    return _save(fig, path)


def per_vehicle(traj: pd.DataFrame, vehicles: pd.DataFrame, column: str, ylabel: str, title: str, path: Path,
                scale: float = 1.0, hlines: tuple = ()) -> Path:
    """One line per vehicle of ``traj[column] * scale`` against time."""
    labels = _car_label(vehicles)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for vid, g in traj.groupby("vehicle_id", sort=False):
        ax.plot(g["t"], g[column] * scale, label=labels.get(vid, vid), lw=1.0)
    for y, text in hlines:
        ax.axhline(y, color="k", ls=":", lw=0.8)
        ax.annotate(text, (ax.get_xlim()[0], y), fontsize=8, va="bottom")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    return _save(fig, path)
