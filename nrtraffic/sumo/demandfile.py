"""A SUMO demand file (``.rou.xml``) read into the run's departures (``demand.sumo_routes``).

Each ``<vehicle>`` (with a ``route`` reference or an inline ``<route>``), ``<trip>`` (``from``/
``to``) and ``<flow>`` (``from``/``to`` or a route; ``period``, ``vehsPerHour``, ``probability`` or
``number`` between ``begin`` and ``end``) becomes departures of nrtraffic's own vehicle type; each is
mapped to the junction movement whose incoming and outgoing edges its route uses. Flows follow
SUMO's rules: ``period`` and ``vehsPerHour`` and ``number`` give equally spaced departures,
``period="exp(r)"`` exponential headways of rate ``r`` [1/s], ``probability`` one chance per second;
the random ones are drawn from the run's seed. Pure Python: SUMO then inserts the vehicles from the
run's route file like any other demand.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np


class DemandFileError(ValueError):
    """The demand file cannot be read or names what the junction does not have."""


def _num(el, key: str, where: str, default=None) -> float:
    v = el.get(key)
    if v is None:
        if default is None:
            raise DemandFileError(f"{where}: needs {key}")
        return default
    try:
        x = float(v)
    except ValueError:
        raise DemandFileError(f"{where}: {key}={v!r} is not a number") from None
    if not math.isfinite(x):
        raise DemandFileError(f"{where}: {key}={v!r} is not finite")
    return x


def read_sumo_demand(path: Path, movements: dict[tuple[str, str], str], rng: np.random.Generator, end_s: float,
                     entry_speed_mps: float) -> list[tuple[str, str, float, float, float]]:
    """Departures ``(vehicle_id, movement, depart_s, depart_speed_mps, -1)`` of the file, up to
    ``end_s`` [s] for open-ended flows. ``movements`` maps ``(incoming edge, outgoing edge)`` to a
    movement name; a route through the junction on edges it does not have is an error naming the
    element. ``departSpeed`` is used where it is a number, else ``entry_speed_mps``."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise DemandFileError(f"demand.sumo_routes {path}: cannot be read as XML: {exc}") from None
    routes = {r.get("id"): r.get("edges", "").split() for r in root.findall("route")}

    def movement(edges: list[str], where: str) -> str:
        for a, b in zip(edges, edges[1:]):
            if (a, b) in movements:
                return movements[(a, b)]
        raise DemandFileError(f"{where}: its route {' '.join(edges)!r} uses no movement of the junction "
                              f"(in -> out edges: {', '.join(f'{a} -> {b}' for a, b in movements)})")

    def edges_of(el, where: str) -> list[str]:
        if el.get("from") and el.get("to"):
            return [el.get("from"), el.get("to")]
        ref = el.get("route")
        if ref is not None:
            if ref not in routes:
                raise DemandFileError(f"{where}: route {ref!r} is not defined in the file")
            return routes[ref]
        inner = el.find("route")
        if inner is not None:
            return inner.get("edges", "").split()
        raise DemandFileError(f"{where}: needs from/to, a route attribute or an inner <route>")

    def speed(el, where: str) -> float:
        v = el.get("departSpeed")
        if v is None or not v.replace(".", "", 1).isdigit():
            return entry_speed_mps
        return _num(el, "departSpeed", where)

    if not any(el.tag in ("vehicle", "trip", "flow") for el in root):
        raise DemandFileError(f"demand.sumo_routes {path}: holds no <vehicle>, <trip> or <flow> (a SUMO route file "
                              "is expected)")
    out = []
    for el in root:
        tag = el.tag
        if tag not in ("vehicle", "trip", "flow"):
            continue
        vid = el.get("id")
        where = f"demand.sumo_routes {path.name}: <{tag} id={vid!r}>"
        if not vid:
            raise DemandFileError(f"demand.sumo_routes {path.name}: a <{tag}> without an id")
        mv = movement(edges_of(el, where), where)
        v0 = speed(el, where)
        if tag in ("vehicle", "trip"):
            out.append((vid, mv, _num(el, "depart", where), v0, -1.0))
            continue
        begin = _num(el, "begin", where, 0.0)
        end = min(_num(el, "end", where, math.inf), end_s)
        times: list[float] = []
        if el.get("number") is not None and el.get("period") is None and el.get("vehsPerHour") is None:
            n = int(_num(el, "number", where))
            if not math.isfinite(end):
                raise DemandFileError(f"{where}: number needs a finite end")
            times = [begin + k * (end - begin) / n for k in range(n)] if n > 0 else []
        elif el.get("period", "").startswith("exp("):
            try:
                rate = float(el.get("period")[4:-1])
            except ValueError:
                raise DemandFileError(f"{where}: period={el.get('period')!r} is not exp(RATE)") from None
            t = begin
            while rate > 0:
                t += rng.exponential(1.0 / rate)
                if t >= end:
                    break
                times.append(t)
        elif el.get("period") is not None or el.get("vehsPerHour") is not None:
            if el.get("period") is not None:
                period = _num(el, "period", where)
            else:
                vph = _num(el, "vehsPerHour", where)
                if not vph > 0:
                    raise DemandFileError(f"{where}: vehsPerHour must be > 0 (leave the flow out for none)")
                period = 3600.0 / vph
            if not period > 0:
                raise DemandFileError(f"{where}: the period must be > 0")
            times = list(np.arange(begin, end, period)) if math.isfinite(end) else []
        elif el.get("probability") is not None:
            p = _num(el, "probability", where)
            if not 0 <= p <= 1:
                raise DemandFileError(f"{where}: probability must be in [0, 1]")
            steps = np.arange(begin, end, 1.0) if math.isfinite(end) else np.zeros(0)
            times = list(steps[rng.random(len(steps)) < p])
        else:
            raise DemandFileError(f"{where}: needs period, vehsPerHour, probability or number")
        if el.get("number") is not None and (el.get("period") is not None or el.get("vehsPerHour") is not None):
            times = times[:int(_num(el, "number", where))]
        out += [(f"{vid}.{k}", mv, float(t), v0, -1.0) for k, t in enumerate(times)]
    ids = [o[0] for o in out]
    if len(set(ids)) != len(ids):
        raise DemandFileError(f"demand.sumo_routes {path.name}: vehicle ids repeat")
    return out
