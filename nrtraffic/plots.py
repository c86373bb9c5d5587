"""Figures (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

G = 9.81  # [m/s^2]


def _save(fig, path: Path, rect=(0.0, 0.0, 1.0, 1.0)) -> Path:
    fig.tight_layout(rect=rect)
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


def cbf_figures(with_cbf: pd.DataFrame, without_cbf: pd.DataFrame, fcd: pd.DataFrame, d0: float, y_max: float,
                out: Path, no_antiwindup: pd.DataFrame | None = None) -> list[Path]:
    """Paper figures 5-10 of the barrier-function experiment (follower with and without barriers)."""
    out = Path(out)
    paths = []
    lead = fcd[fcd["vehicle_id"] != with_cbf["vehicle_id"].iloc[0]]
    # fig. 5: speeds
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(lead["t"], lead["speed"], label="car 1 (leader, SUMO)", color="tab:blue")
    ax.plot(with_cbf["t"], with_cbf["v_l"], label="car 2 (with barriers)", color="tab:red")
    ax.plot(without_cbf["t"], without_cbf["v_l"], label="car 2 (without)", color="tab:red", ls=":", lw=0.9)
    ax.set(xlabel="time [s]", ylabel="speed [m/s]", title="Speeds")
    ax.legend()
    ax.grid(alpha=0.3)
    paths.append(_save(fig, out / "fig5_speeds.png"))
    # fig. 6: distance between the vehicles
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(with_cbf["t"], with_cbf["center_distance_m"], label="with barriers", color="tab:red")
    ax.plot(without_cbf["t"], without_cbf["center_distance_m"], label="without", color="tab:gray", ls=":")
    ax.axhline(d0, color="k", ls="--", lw=0.8, label=f"d0 = {d0:.1f} m")
    ax.set(xlabel="time [s]", ylabel="centre distance [m]", title="Distance between the vehicles")
    ax.legend()
    ax.grid(alpha=0.3)
    paths.append(_save(fig, out / "fig6_distance.png"))
    # fig. 7: lateral deviation, both runs
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(without_cbf["t"], without_cbf["lateral_dev_m"], label="without barriers", color="tab:gray")
    ax.plot(with_cbf["t"], with_cbf["lateral_dev_m"], label="with barriers", color="tab:red")
    for y in (y_max, -y_max):
        ax.axhline(y, color="k", ls="--", lw=0.8)
    ax.set(xlabel="time [s]", ylabel="lateral deviation [m]", title="Deviation from the lane centre")
    ax.legend()
    ax.grid(alpha=0.3)
    paths.append(_save(fig, out / "fig7_lateral_deviation.png"))
    extra = [("with barriers", with_cbf, "tab:red", "-")]
    if no_antiwindup is not None:
        extra.append(("with barriers, no anti-windup", no_antiwindup, "tab:purple", ":"))
    for name, col, ylabel, title in [
        ("fig8_tracking_error.png", "tracking_error_m", "tracking error [m]", "Tracking error |y - r|"),
        ("fig9_acceleration.png", "a_cmd", "a_l [m/s$^2$]", "Longitudinal acceleration (applied)"),
        ("fig10_steering.png", "delta_cmd", "delta_f [rad]", "Steering angle (applied)"),
    ]:
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        for label, df, color, ls in extra:
            ax.plot(df["t"], df[col], label=label, color=color, ls=ls, lw=1.0)
        ax.set(xlabel="time [s]", ylabel=ylabel, title=title)
        ax.legend()
        ax.grid(alpha=0.3)
        paths.append(_save(fig, out / name))
    return paths


def antiwindup_figure(on: pd.DataFrame, off: pd.DataFrame, path: Path) -> Path:
    """Lateral deviation and steering with and without anti-windup of the tracker."""
    fig, axes = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True)
    for df, label, color in ((on, "anti-windup (default)", "tab:red"), (off, "no anti-windup", "tab:purple")):
        axes[0].plot(df["t"], df["lateral_dev_m"], label=label, color=color, lw=1.0)
        axes[1].plot(df["t"], df["delta_cmd"], label=label, color=color, lw=1.0)
    axes[0].set(ylabel="lateral deviation [m]", title="Tracker anti-windup against the barriers (T = 0.2 s)")
    axes[1].set(xlabel="time [s]", ylabel="delta_f applied [rad]")
    for ax in axes:
        ax.legend()
        ax.grid(alpha=0.3)
    return _save(fig, path)


def conflict_areas(movements: dict, path: Path) -> Path:
    """The junction's movements with their conflict areas (``movements.json``): one panel per
    movement, its path through the merging zone (dashed circle) in colour, the stretches on which its body can
    touch another movement's (its conflict areas) drawn thick, the paths it conflicts with thin."""
    import math

    import numpy as np

    mvs = movements["movements"]
    names = list(mvs)
    areas: dict[str, list] = {}
    for a in movements.get("conflict_areas", []):
        areas.setdefault(a["movement"], []).append(a)
    cols = min(4, len(names))
    rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 3.0 * rows), squeeze=False)
    paths = {n: np.asarray(mvs[n]["zone_path"]) for n in names}
    # several junctions (a corridor): each panel shows its own junction
    junction = {n: mvs[n].get("junction", "") for n in names}
    zones = movements.get("merging_zones") or {"": movements.get("merging_zone")}
    frame = {}
    for j in set(junction.values()):
        allxy = np.vstack([paths[n][:, 1:] for n in names if junction[n] == j])
        frame[j] = (0.5 * (allxy.min(axis=0) + allxy.max(axis=0)),
                    0.5 * (allxy.max(axis=0) - allxy.min(axis=0)).max() + 2.0)
    for ax, n in zip(axes.flat, names):
        centre, half = frame[junction[n]]
        zone = zones.get(junction[n])
        for other in (o for o in names if junction[o] == junction[n]):
            q = paths[other]
            ax.plot(q[:, 1], q[:, 2], color="0.85", lw=0.8, zorder=1)
        for a in areas.get(n, []):
            q = paths[a["with"]]
            ax.plot(q[:, 1], q[:, 2], color="0.45", lw=0.8, zorder=2)
        p_ = paths[n]
        ax.plot(p_[:, 1], p_[:, 2], color="tab:blue", lw=1.5, zorder=3)
        ax.annotate("", xy=p_[-1, 1:], xytext=p_[-4, 1:], arrowprops=dict(arrowstyle="->", color="tab:blue"))
        for a in areas.get(n, []):
            sel = (p_[:, 0] >= a["from_m"]) & (p_[:, 0] <= a["to_m"])
            ax.plot(p_[sel, 1], p_[sel, 2], color="tab:red", lw=5, alpha=0.35, solid_capstyle="butt", zorder=4)
        if zone:
            ax.add_patch(plt.Circle(tuple(zone["centre_xy"]), zone["diameter_m"] / 2.0, fill=False, ls="--",
                                    color="0.6", lw=0.8))
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{junction[n] + ' ' if junction[n] else ''}{n}: {len(areas.get(n, []))} areas", fontsize=8)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.suptitle("conflict areas (red) on each movement's path; grey: the movements it conflicts with", fontsize=9)
    return _save(fig, path, rect=(0.0, 0.0, 1.0, 1.0 - 0.4 / (3.0 * rows)))  # (room for the title)


def queues(series: pd.DataFrame, path: Path, t_from: float = 0.0) -> Path:
    """Queue length over time per approach (SUMO's lane-area detectors, ``queues.xml``): the mean
    and the longest jam of each detector period, in vehicles; the warm-up shaded."""
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    for appr, g in series.groupby("approach"):
        mid = 0.5 * (g["begin_s"] + g["end_s"])
        line, = ax.plot(mid, g["max_queue_veh"], lw=1.2, label=f"{appr} (longest)")
        ax.plot(mid, g["mean_queue_veh"], lw=0.8, ls="--", color=line.get_color())
    if t_from > 0:
        ax.axvspan(0, t_from, color="0.9", zorder=0, label="warm-up")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("queue [vehicles]")
    ax.set_ylim(0, max(1.0, float(series["max_queue_veh"].max()) * 1.1))
    if float(series["max_queue_veh"].max()) == 0.0:
        ax.text(0.5, 0.5, "no vehicle queued on any approach", transform=ax.transAxes, ha="center", color="0.4")
    ax.set_title("queue per approach (solid: longest jam in each 10 s; dashed: its time mean)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    return _save(fig, path)


def delay_by_movement(table: pd.DataFrame, path: Path, signalised: bool, junction_of: dict | None = None) -> Path:
    """Mean delay per movement (``movements.csv``) as bars, with the HCM level-of-service bands
    (signalised or unsignalised thresholds) behind them; the 95th percentile as a tick. With
    ``junction_of`` (approach -> junction) and several junctions, a row of bars per junction."""
    from nrtraffic.metrics import LOS_SIGNALISED, LOS_UNSIGNALISED

    bounds = LOS_SIGNALISED if signalised else LOS_UNSIGNALISED
    t = table[table["vehicles"] > 0]
    junction = t["approach"].map(junction_of or {}).fillna("")
    groups = [(j, t[junction == j]) for j in sorted(set(junction))]
    top = max([bounds[-1] * 1.2] + [float(x) * 1.1 for x in t["p95_delay_s"].fillna(0)])
    widest = max(len(g) for _, g in groups)
    fig, axes = plt.subplots(len(groups), 1, figsize=(min(13.0, max(5.0, 0.6 * widest + 1.5)), 0.4 + 3.2 * len(groups)),
                             squeeze=False)
    edges = (0.0, *bounds, top)
    shades = ["#e8f5e9", "#f1f8e9", "#fffde7", "#fff3e0", "#fbe9e7", "#ffebee"]
    for ax, (j, g) in zip(axes[:, 0], groups):
        for k, letter in enumerate("ABCDEF"):
            ax.axhspan(edges[k], edges[k + 1], color=shades[k], zorder=0)
            ax.text(widest - 0.4, 0.5 * (edges[k] + edges[k + 1]), letter, fontsize=8, va="center", color="0.4")
        x = range(len(g))
        ax.bar(x, g["mean_delay_s"], color="tab:blue", zorder=2, label="mean")
        ax.scatter(x, g["p95_delay_s"], color="k", marker="_", s=120, zorder=3, label="95th percentile")
        ax.set_xticks(list(x), [f"{a}\n{m}" for a, m in zip(g["approach"], g["movement"])], fontsize=7)
        ax.set_xlim(-0.6, widest - 0.2)
        ax.set_ylim(0, top)
        ax.set_ylabel(f"{'junction ' + j + ': ' if j else ''}delay [s]", fontsize=8)
    axes[0, 0].set_title(f"delay per movement, HCM level of service ({'signalised' if signalised else 'unsignalised'} "
                         "thresholds)", fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="upper left")
    return _save(fig, path)


MOVEMENT_COLOURS = {"left": "tab:orange", "straight": "tab:blue", "right": "tab:green", "uturn": "tab:purple",
                    "through": "tab:blue"}
_SOURCE_NOTE = {"fcd": "every vehicle, its front bumper (SUMO's fcd.xml)",
                "trajectories": "the controlled vehicles while under control, their centre of gravity\n"
                                "(outputs.sumo_fcd = true draws every vehicle)"}


def _draw_series(ax, df: pd.DataFrame) -> set:
    """One line per segment of a time-space series (:mod:`nrtraffic.timespace`): coloured by
    movement, human drivers dashed, vehicles in no table grey; returns the styles used."""
    from matplotlib.collections import LineCollection

    used = set()
    groups: dict[tuple, list] = {}
    for (_, mv, driver), g in df.groupby(["segment", "movement", "driver"], sort=False, dropna=False):
        colour = "0.6" if driver == "sumo" else MOVEMENT_COLOURS.get(mv, "k")
        style = "--" if driver == "human" else "-"
        groups.setdefault((colour, style), []).append(g[["t", "s_m"]].to_numpy())
        used.add(("sumo" if driver == "sumo" else mv, driver))
    for (colour, style), lines in groups.items():
        ax.add_collection(LineCollection(lines, colors=colour, linestyles=style, linewidths=0.6))
    return used


def _legend(fig, used: set) -> None:
    """The movements' colours and drivers' styles used, below the figure."""
    handles = [plt.Line2D([], [], color=c, label=k) for k, c in MOVEMENT_COLOURS.items()
               if any(mv == k for mv, _ in used) and not (k == "through" and any(mv == "straight" for mv, _ in used))]
    if any(d == "human" for _, d in used):
        handles.append(plt.Line2D([], [], color="k", ls="--", label="human driver"))
    if any(d == "sumo" for _, d in used):
        handles.append(plt.Line2D([], [], color="0.6", label="other (SUMO)"))
    if handles:
        fig.legend(handles=handles, fontsize=7, ncol=len(handles), loc="lower center", frameon=False)


def time_space(series: dict, roads: dict, path: Path, source: str) -> Path:
    """Time-space diagram, one panel per approach road (``series`` and ``roads`` from
    :func:`nrtraffic.timespace.time_space_series` and :func:`~nrtraffic.timespace.roads`), a column
    per junction: each vehicle's distance from the start of the approach edge against time, once
    per road; the control-zone entry dotted, the merging zone shaded."""
    junctions = sorted({r.junction for n, r in roads.items() if n in series})
    columns = [sorted(n for n, r in roads.items() if r.junction == j and n in series) for j in junctions]
    rows = max(len(c) for c in columns)
    fig, axes = plt.subplots(rows, len(columns), figsize=(8.0 if len(columns) == 1 else 4.2 * len(columns),
                                                          1.9 * rows + 0.9), sharex=True, squeeze=False)
    used: set = set()
    t_max = max([float(df["t"].max()) for df in series.values() if len(df)] + [1.0])
    for col, names in enumerate(columns):
        for row in range(rows):
            ax = axes[row, col]
            if row >= len(names):
                ax.axis("off")
                continue
            name = names[row]
            r = roads[name]
            ax.axhspan(r.merge_entry_m, r.merge_exit_m, color="0.88", zorder=0)
            ax.axhline(r.control_zone_start_m, color="0.5", ls=":", lw=0.8, zorder=0)
            used |= _draw_series(ax, series[name])
            ax.set_ylabel(f"{name} [m]", fontsize=8)
            ax.set_ylim(0, r.top_m)
            ax.set_xlim(0, t_max)
            ax.tick_params(labelsize=7)
            if row == 0 and len(columns) > 1:
                ax.set_title(f"junction {r.junction}", fontsize=9)
        axes[min(rows, len(names)) - 1, col].set_xlabel("time [s]", fontsize=8)
        axes[min(rows, len(names)) - 1, col].xaxis.set_tick_params(labelbottom=True)
    fig.suptitle("time-space per approach road: distance from the start of the road, control-zone entry dotted, "
                 "merging zone shaded;\n" + _SOURCE_NOTE[source], fontsize=9)
    _legend(fig, used)
    return _save(fig, path, rect=(0, 0.03, 1, 1))


def arterial(series: dict, arts: dict, path: Path, source: str) -> Path:
    """Arterial (green-wave) diagram of a corridor, one panel per direction (``series`` and
    ``arts`` from :func:`nrtraffic.timespace.arterial_series`): each vehicle's distance along the
    arterial against time; each junction's merging zone shaded and named."""
    names = sorted(arts)
    fig, axes = plt.subplots(len(names), 1, figsize=(10.5, 3.4 * len(names) + 0.6), sharex=True, squeeze=False)
    used: set = set()
    t_max = max([float(df["t"].max()) for df in series.values() if len(df)] + [1.0])
    for ax, name in zip(axes[:, 0], names):
        art = arts[name]
        for junction, a, b in art.zones:
            ax.axhspan(a, b, color="0.85", zorder=0)
            ax.annotate(junction, (t_max, 0.5 * (a + b)), xytext=(3, 0), textcoords="offset points", fontsize=7,
                        va="center", annotation_clip=False)
        used |= _draw_series(ax, series.get(name, pd.DataFrame(columns=["segment", "movement", "driver"])))
        ax.set_ylabel(f"entering by {name}\n[m]", fontsize=8)
        ax.set_ylim(0, art.top_m)
        ax.set_xlim(0, t_max)
        ax.tick_params(labelsize=7)
    _legend(fig, used)
    axes[0, 0].set_title("arterial: distance along the corridor per direction, merging zones shaded;\n"
                         + _SOURCE_NOTE[source], fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    return _save(fig, path, rect=(0, 0.03, 1, 1))
