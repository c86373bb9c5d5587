"""A SUMO demand file (``.rou.xml``) read into the run's departures (``demand.sumo_routes``).

Each ``<vehicle>`` (with a ``route`` reference or an inline ``<route>``), ``<trip>`` (``from``/
``to``, ``via``) and ``<flow>`` (``from``/``to`` or a route; ``period``, ``vehsPerHour``,
``probability`` or ``number`` between ``begin`` and ``end``) becomes departures of nrtraffic's own
vehicle type on the file's whole route. Trips and flows given by ``from``/``to`` are first routed by
SUMO's ``duarouter`` (:func:`routed`: the fastest route at free flow, as SUMO routes a trip at
insertion in an empty network). A vehicle's crossings are the junction movements whose incoming and
outgoing edges its route uses, in order along it (one per controlled junction it passes). Flows follow
SUMO's rules: ``period`` and ``vehsPerHour`` and ``number`` give equally spaced departures,
``period="exp(r)"`` exponential headways of rate ``r`` [1/s], ``probability`` one chance per second;
the random ones are drawn from the run's seed. Pure Python: SUMO then inserts the vehicles from the
run's route file like any other demand.
"""

from __future__ import annotations

import math
import subprocess
import tempfile
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

import numpy as np

from nrtraffic.limits import sumo_id_problem, sumo_time
from nrtraffic.sumo.network import CAR_CLASS, give_way_room, open_xml, safe_depart_speed


class DemandFileError(ValueError):
    """The demand file cannot be read or names what the junction does not have."""


def _num(el, key: str, where: str, default=None) -> float:
    v = el.get(key)
    if v is None:
        if default is None:
            raise DemandFileError(f"{where}: needs {key}")
        return default
    try:
        x = sumo_time(v) if key in ("depart", "begin", "end") else float(v)  # (times also as h:m:s)
    except ValueError:
        if key == "depart" and v in ("triggered", "containerTriggered", "now", "split", "begin"):
            raise DemandFileError(f"{where}: depart={v!r}: the run takes departures in seconds only; give the "
                                  "time") from None
        raise DemandFileError(f"{where}: {key}={v!r} is not a number") from None
    if not math.isfinite(x):
        raise DemandFileError(f"{where}: {key}={v!r} is not finite")
    return x


DEPART_LANES = ("random", "free", "allowed", "best", "best_prob", "first")  # SUMO's departLane words
# SUMO's departSpeed words (read as the run's entry speed) and departPos words (read as SUMO's base)
DEPART_SPEEDS = ("random", "max", "desired", "speedLimit", "last", "avg")
DEPART_POSITIONS = ("random", "free", "random_free", "base", "last", "stop", "splitFront")
MAX_FLOW_VEHICLES = 1_000_000  # vehicles of one <flow> given by number
MAX_FLOW_RATE_VEH_H = 20000.0  # one <flow>'s departures per hour (as demand.rate_veh_h: ten times a lane's capacity)
_ROUTED: dict[tuple, Path] = {}  # (file, its version, network) -> the file routed by duarouter, once per process
_TMP: list = []  # the process's folder for routed and merged files, removed when the process ends


def _scratch(name: str) -> Path:
    """A new path for ``name`` in the process's temporary folder (removed at exit)."""
    if not _TMP:
        _TMP.append(tempfile.TemporaryDirectory(prefix="nrtraffic-routes-"))
    return Path(tempfile.mkdtemp(dir=_TMP[0].name)) / name


def _unrouted(root) -> bool:
    """Whether the file has trips or flows given by their ends (``from``/``to``, ``via``,
    ``fromJunction``...) rather than by a route."""
    return any(el.tag in ("trip", "flow") and el.get("route") is None and el.find("route") is None
               and (el.get("from") or el.get("fromJunction") or el.get("fromTaz")) for el in root)


def merged(paths: list[Path]) -> Path:
    """One route file of ``paths`` (SUMO reads several as one: a route or type defined in one is used
    in another): the first where it is the only one, else their elements in one ``<routes>``."""
    paths = [Path(p) for p in paths]
    if len(paths) == 1:
        return paths[0]
    key = tuple((str(p.resolve()), p.stat().st_mtime_ns, p.stat().st_size) for p in paths)
    if key in _ROUTED and _ROUTED[key].is_file():
        return _ROUTED[key]
    root = ET.Element("routes")
    where: dict[tuple[str, str], str] = {}  # (tag kind, id) -> the file that gives it first
    for p in paths:
        try:
            with open_xml(p) as f:
                elements = list(ET.parse(f).getroot())
        except (OSError, EOFError, ET.ParseError) as exc:
            raise DemandFileError(f"demand.sumo_routes {p}: cannot be read as XML: {exc}") from None
        for el in elements:  # (named here by its files: the merged file is nobody's)
            kind = "vehicle" if el.tag in ("vehicle", "trip", "flow") else el.tag
            key = (kind, el.get("id"))
            if el.get("id") is not None and key in where:
                raise DemandFileError(f"demand.sumo_routes: the {kind} id {el.get('id')!r} is given in {where[key]} and "
                                      f"in {p.name}; give each its own id")
            where.setdefault(key, p.name)
        root.extend(elements)
    out = _scratch("merged.rou.xml")
    ET.ElementTree(root).write(out, encoding="utf-8", xml_declaration=True)
    _ROUTED[key] = out
    return out


def _flow_size(el, end: float | None = None) -> float:
    """How many vehicles a ``<flow>`` makes (``number``, or its rate over ``begin`` to ``end``: its
    own, SUMO's default of a day, or ``end`` [s] where given); 0 where a value is not a number (the
    check of the demand names it)."""
    try:
        if el.get("number") is not None:
            return float(el.get("number"))
        span = (float(el.get("end", FLOW_END_S)) if end is None else end) - float(el.get("begin", "0"))
        period = el.get("period")
        if period is not None:
            if period.startswith("exp(") and period.endswith(")"):  # (SUMO's random arrivals at a rate [1/s])
                return span * float(period[4:-1])
            return span / float(period) if float(period) > 0 else 0.0
        for rate, per_s in (("vehsPerHour", 1 / 3600), ("perHour", 1 / 3600), ("probability", 1.0)):
            if el.get(rate) is not None:
                return span * float(el.get(rate)) * per_s
    except ValueError:
        pass
    return 0.0


FLOW_END_S = 86400.0  # SUMO's end of a <flow> that gives none: a day [s]
MIN_EXP_RATE = 1e-9  # the lowest rate of a flow's exp(RATE) [1/s]: one vehicle in about 30 years (duarouter hangs on 1e-100)


def _exp_rate(el, where: str) -> float:
    """The rate [1/s] of a flow's ``period="exp(RATE)"``, checked: a finite number of at least
    :data:`MIN_EXP_RATE` (duarouter hangs on an infinite, NaN or vanishing rate)."""
    try:
        rate = float(el.get("period").strip()[4:-1])
    except ValueError:
        raise DemandFileError(f"{where}: period={el.get('period')!r} is not exp(RATE)") from None
    if not (rate > 0 and math.isfinite(rate)):
        raise DemandFileError(f"{where}: period={el.get('period')!r}: the rate of exp(RATE) must be a number > 0")
    if rate < MIN_EXP_RATE:
        raise DemandFileError(f"{where}: period={el.get('period')!r}: a rate below {MIN_EXP_RATE:g} per second makes no "
                              "vehicle in any run: leave the flow out")
    return rate


def routed(path: Path, net_path: Path) -> Path:
    """``path``, or where it has trips or flows given by ``from``/``to`` (``via``), the same file with
    each routed by SUMO's ``duarouter`` on the network ``net_path`` (the fastest route at the edges'
    speed limits; departures, flows and attributes as they are). Raises DemandFileError, naming
    duarouter's message, where a trip has no route."""
    from nrtraffic.sumo.netbuild import sumo_binary

    path, net_path = Path(path), Path(net_path)
    try:
        with open_xml(path) as f:
            root = ET.parse(f).getroot()
    except (OSError, EOFError, ET.ParseError) as exc:
        raise DemandFileError(f"demand.sumo_routes {path}: cannot be read as XML: {exc}") from None
    if not _unrouted(root):
        return path
    for el in root:  # (times checked here, as the run checks them: duarouter named a NaN "negative")
        if el.tag in ("vehicle", "trip") and el.get("depart") is not None:
            _num(el, "depart", f"demand.sumo_routes {path.name}: <{el.tag} id={el.get('id')!r}>")
    for el in root.iter("flow"):  # (duarouter writes every vehicle of a flow it routes: bounded first)
        if el.get("period", "").strip().startswith("exp("):
            _exp_rate(el, f"demand.sumo_routes {path.name}: <flow id={el.get('id')!r}>")
        n = _flow_size(el)
        if n > MAX_FLOW_VEHICLES:
            raise DemandFileError(f"demand.sumo_routes {path.name}: <flow id={el.get('id')!r}> makes {n:g} vehicles, "
                                  f"more than the {MAX_FLOW_VEHICLES} vehicles one flow may have: give it an end "
                                  "(or a number) that the study needs")
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size, str(net_path.resolve()), net_path.stat().st_mtime_ns)
    if key in _ROUTED and _ROUTED[key].is_file():
        return _ROUTED[key]
    out = _scratch(f"{path.stem}.routed.rou.xml")
    cmd = [sumo_binary("duarouter"), "--net-file", str(net_path), "--route-files", str(path), "--output-file", str(out),
           "--no-step-log", "true", "--ignore-errors", "false", "--write-license", "false"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise DemandFileError(f"demand.sumo_routes {path.name}: SUMO's duarouter could not be run to route its "
                              f"trips: {exc}") from None
    if proc.returncode < 0:
        raise DemandFileError(f"demand.sumo_routes {path.name}: SUMO's duarouter was stopped by signal "
                              f"{-proc.returncode} while routing its trips (out of memory? a flow with very many "
                              "vehicles)")
    if proc.returncode != 0 or not out.is_file():
        said = [ln.strip() for ln in (proc.stderr or proc.stdout).splitlines()
                if ln.strip() and not ln.startswith("Quitting")]
        raise DemandFileError(f"demand.sumo_routes {path.name}: SUMO's duarouter could not route its trips: "
                              f"{'; '.join(said[-3:]) or f'exit {proc.returncode}'} (mend the element it names)")
    _ROUTED[key] = out
    return out


def read_sumo_demand(path: Path, movements: dict[tuple[str, str], str], rng: np.random.Generator, end_s: float,
                     entry_speed_mps: float, net=None, source: str | None = None,
                     notes: list[str] | None = None, safe_start: tuple[float, float, float] | None = None
                     ) -> list[tuple]:
    """Departures ``(vehicle_id, crossings, depart_s, depart_speed_mps, depart_pos_m, edges,
    depart_lane, vclass, slowed)`` of the file (``vclass``: SUMO's vClass of its ``<vType>``, "passenger"
    where it has none), up to ``end_s`` [s] for open-ended flows: ``crossings`` the
    movements its route takes, in order (``movements`` maps ``(incoming edge, outgoing edge)`` to a
    movement name; none for a route that crosses no controlled junction), ``edges`` its whole
    route. A file none of whose vehicles crosses a controlled junction is an error; with ``net`` (a
    sumolib network) so is a route over an edge the network does not have, or over two edges it
    does not connect, and a ``departLane`` or ``departPos`` its first edge does not have.
    ``departSpeed`` is used where it is a number, else ``entry_speed_mps``, with ``net`` at most the
    first edge's speed limit, and with ``safe_start`` (the front's position at ``base`` [m], the
    car's deceleration [m/s^2], SUMO's step [s]) at most the speed from which it can stop before the
    first link of its route where it gives way (:func:`~nrtraffic.sumo.network.safe_depart_speed`):
    ``slowed`` says whether it was so held below ``entry_speed_mps``; ``departPos`` where it is a
    number, else -1 (SUMO's ``base``);
    ``departLane`` as given (a lane index or SUMO's word), else "best". A trip given by
    ``from``/``to`` that is not routed (:func:`routed`) is the two edges. ``source``: the file's
    name in messages (the user's, where ``path`` is its routed copy). ``notes``: where to say what
    the run leaves out (its ``<stop>`` elements)."""
    path = Path(path)
    label = source or path.name
    try:
        with open_xml(path) as f:
            root = ET.parse(f).getroot()
    except (OSError, EOFError, ET.ParseError) as exc:
        raise DemandFileError(f"demand.sumo_routes {label}: cannot be read as XML: {exc}") from None
    routes = {r.get("id"): r.get("edges", "").split() for r in root.findall("route")}
    vclass = {t.get("id"): t.get("vClass", "passenger") for t in root.iter("vType")}
    distributions = {d.get("id") for d in root.iter("routeDistribution")}
    persons = sum(1 for el in root if el.tag in ("person", "personFlow", "container", "containerFlow"))
    if persons and notes is not None:
        notes.append(f"demand.sumo_routes: its {persons} persons and containers are left out (the run has vehicles "
                     "only)")
    stops = sum(1 for _ in root.iter("stop"))
    if stops and notes is not None:
        notes.append(f"demand.sumo_routes: its {stops} <stop> elements are left out (the run's vehicles drive their "
                     "routes without stopping)")
    checked: set[tuple[str, ...]] = set()

    def crossings(edges: list[str], where: str) -> tuple[str, ...]:
        if net is not None and tuple(edges) not in checked:
            for e in edges:
                if not net.hasEdge(e):
                    raise DemandFileError(f"{where}: its route names edge {e!r}, which the network does not have")
            for a, b in zip(edges, edges[1:]):
                if not any(o.getID() == b for o in net.getEdge(a).getOutgoing()):
                    raise DemandFileError(f"{where}: its route goes from edge {a!r} to {b!r}, which the network does "
                                          "not connect (give the edges between them, or a trip to route)")
            for e in edges:  # (every vehicle drives as nrtraffic's car: a passenger car)
                if not any(lane.allows(CAR_CLASS) for lane in net.getEdge(e).getLanes()):
                    raise DemandFileError(f"{where}: its route uses edge {e!r}, on which a {CAR_CLASS} car may not "
                                          "drive (its lanes are for other vehicle classes, a bus lane, say), and every "
                                          "vehicle of the file drives as nrtraffic's passenger car: leave such "
                                          "vehicles out of the file, or route them around it")
            for a, b in zip(edges, edges[1:]):
                if not any(c.getFromLane().allows(CAR_CLASS) and c.getToLane().allows(CAR_CLASS)
                           for c in net.getEdge(a).getOutgoing()[net.getEdge(b)]):
                    raise DemandFileError(f"{where}: its route turns from edge {a!r} onto {b!r} over lanes a "
                                          f"{CAR_CLASS} car may not use, and every vehicle of the file drives as "
                                          "nrtraffic's passenger car: leave such vehicles out of the file, or route "
                                          "them around it")
            checked.add(tuple(edges))
        return tuple(movements[(a, b)] for a, b in zip(edges, edges[1:]) if (a, b) in movements)

    def edges_of(el, where: str) -> list[str]:
        inner = el.find("route")
        if inner is not None:
            return inner.get("edges", "").split()
        if el.get("from") and el.get("to"):
            return [el.get("from"), el.get("to")]
        ref = el.get("route")
        if ref is not None:
            if ref not in routes:
                if ref in distributions:
                    raise DemandFileError(f"{where}: route {ref!r} is a <routeDistribution>, which the run does not "
                                          "take: give each vehicle its own route (duarouter writes them)")
                raise DemandFileError(f"{where}: route {ref!r} is not defined in the file")
            return routes[ref]
        raise DemandFileError(f"{where}: needs from/to, a route attribute or an inner <route>")

    def speed(el, where: str, edges: list[str], pos: float) -> float:
        v = el.get("departSpeed")
        if v is None or v in DEPART_SPEEDS:
            if net is None:
                return entry_speed_mps
            # the entry speed, at most its first edge's speed limit and (with safe_start) the speed it
            # can stop from before a link where it gives way, as SUMO's "max"
            v0 = min(entry_speed_mps, net.getEdge(edges[0]).getSpeed())
            room = give_way_room(net, tuple(edges), pos if pos >= 0 else safe_start[0]) if safe_start else None
            if room is not None:
                v0 = min(v0, math.floor(1000.0 * safe_depart_speed(room[0], *safe_start[1:])) / 1000.0)
            return v0
        x = _num(el, "departSpeed", where)
        if x < 0:
            raise DemandFileError(f"{where}: departSpeed={v} is negative")
        return x

    def position(el, where: str, first: str) -> float:  # departPos [m] where a number, else -1 (SUMO's base)
        v = el.get("departPos")
        if v is None or v in DEPART_POSITIONS:
            return -1.0
        x = _num(el, "departPos", where)
        if x < 0:
            raise DemandFileError(f"{where}: departPos={v}: give the position from the edge's start (0 or more), "
                                  "or one of " + ", ".join(DEPART_POSITIONS))
        if net is not None and x > net.getEdge(first).getLength():
            raise DemandFileError(f"{where}: departPos={v} lies beyond its first edge {first!r} "
                                  f"({net.getEdge(first).getLength():.1f} m long)")
        return x

    def lane(el, where: str, first: str) -> str:  # departLane as SUMO reads it; "best" where not given
        v = (el.get("departLane") or "best").strip()
        if v.isdigit():
            if net is not None and int(v) >= net.getEdge(first).getLaneNumber():
                raise DemandFileError(f"{where}: departLane={v}, but its first edge {first!r} has "
                                      f"{net.getEdge(first).getLaneNumber()} lane(s), numbered from 0")
        elif v not in DEPART_LANES:
            raise DemandFileError(f"{where}: departLane={v!r} is not a lane index or one of {', '.join(DEPART_LANES)}")
        return v

    if not any(el.tag in ("vehicle", "trip", "flow") for el in root):
        raise DemandFileError(f"demand.sumo_routes {label}: holds no <vehicle>, <trip> or <flow> (a SUMO route file "
                              "is expected)")
    out = []
    for el in root:
        tag = el.tag
        if tag not in ("vehicle", "trip", "flow"):
            continue
        vid = el.get("id")
        where = f"demand.sumo_routes {label}: <{tag} id={vid!r}>"
        if not vid:
            raise DemandFileError(f"demand.sumo_routes {label}: a <{tag}> without an id")
        why = sumo_id_problem(vid)
        if why:
            raise DemandFileError(f"{where}: {why}; rename it in the file")
        edges = edges_of(el, where)
        legs = crossings(edges, where)
        edges = tuple(edges)
        x0 = position(el, where, edges[0])
        v0, ln = speed(el, where, edges, x0), lane(el, where, edges[0])
        slowed = v0 < entry_speed_mps and el.get("departSpeed") in (None, *DEPART_SPEEDS)
        kind = vclass.get(el.get("type"), "passenger")
        if tag in ("vehicle", "trip"):
            t = _num(el, "depart", where)
            if t < 0:
                raise DemandFileError(f"{where}: depart={el.get('depart')} is negative (SUMO's clock starts at 0)")
            out.append((vid, legs, t, v0, x0, edges, ln, kind, slowed))
            continue
        rates = [k for k in ("period", "vehsPerHour", "perHour", "probability") if el.get(k) is not None]
        if len(rates) > 1:  # (SUMO refuses it; the run took one of them)
            raise DemandFileError(f"{where}: gives both {rates[0]} and {rates[1]}; give one rate")
        if el.get("number") is not None and _num(el, "number", where) < 0:
            raise DemandFileError(f"{where}: number={el.get('number')} is negative")
        if el.get("number") is not None and not el.get("number").strip().isdigit():  # (SUMO reads an integer)
            raise DemandFileError(f"{where}: number={el.get('number')!r} is not a whole number of vehicles")
        begin = _num(el, "begin", where, 0.0)
        if begin < 0:  # (SUMO refuses it: "Negative begin time in the definition of flow")
            raise DemandFileError(f"{where}: begin={el.get('begin')} is negative (SUMO's clock starts at 0)")
        if el.get("end") is not None and _num(el, "end", where) < begin:
            raise DemandFileError(f"{where}: end={el.get('end')} is before begin={el.get('begin')}")
        own_end = _num(el, "end", where, FLOW_END_S)  # (SUMO's own end where it gives none: always finite)
        end = min(own_end, end_s)
        # (SUMO spaces a flow's departures over its own end; a flow of a number without one, over the run's)
        span = (own_end if el.get("end") is not None or el.get("number") is None else end) - begin
        size = _flow_size(el, begin + span)
        if size > 0 and (span <= 0 or size / span * 3600.0 > MAX_FLOW_RATE_VEH_H):
            rate = f"{size / span * 3600.0:.0f} veh/h" if span > 0 else "all at one moment"
            raise DemandFileError(f"{where}: departs {rate}, more than the {MAX_FLOW_RATE_VEH_H:g} veh/h one flow may "
                                  "have (ten times a lane's capacity): check its period, vehsPerHour, number, begin "
                                  "and end")
        if el.get("number") is None and _flow_size(el, end) > MAX_FLOW_VEHICLES:
            raise DemandFileError(f"{where}: makes more than the {MAX_FLOW_VEHICLES} vehicles one flow may have "
                                  "in the run: give it an end (or a number) that the study needs")
        times: list[float] = []
        if el.get("number") is not None and el.get("period") is None and el.get("vehsPerHour") is None:
            n = int(_num(el, "number", where))
            if n > MAX_FLOW_VEHICLES:
                raise DemandFileError(f"{where}: number={n} is more than the {MAX_FLOW_VEHICLES} vehicles one flow may "
                                      "have")
            # (spaced over span, above; the run takes those that depart before it ends)
            times = [t for t in (begin + np.arange(n) * (span / n)).tolist() if t < end] if n > 0 else []
        elif el.get("period", "").startswith("exp("):
            rate = _exp_rate(el, where)
            t = begin
            while True:
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
            times = list(np.arange(begin, end, period))
        elif el.get("probability") is not None:
            p = _num(el, "probability", where)
            if not 0 <= p <= 1:
                raise DemandFileError(f"{where}: probability must be in [0, 1]")
            steps = np.arange(begin, end, 1.0)
            times = list(steps[rng.random(len(steps)) < p])
        else:
            raise DemandFileError(f"{where}: needs period, vehsPerHour, probability or number")
        if el.get("number") is not None and (el.get("period") is not None or el.get("vehsPerHour") is not None):
            times = times[:int(_num(el, "number", where))]
        out += [(f"{vid}.{k}", legs, float(t), v0, x0, edges, ln, kind, slowed) for k, t in enumerate(times)]
    twice = sorted(i for i, n in Counter(o[0] for o in out).items() if n > 1)
    if twice:
        more = f" and {len(twice) - 1} more" if len(twice) > 1 else ""
        raise DemandFileError(f"demand.sumo_routes {label}: the vehicle id {twice[0]!r}{more} is given twice; "
                              "give each vehicle its own id")
    if out and not any(o[1] for o in out):
        raise DemandFileError(f"demand.sumo_routes {label}: none of its {len(out)} vehicles crosses a controlled "
                              f"junction: no route uses one of its movements (in -> out edges: "
                              f"{', '.join(f'{a} -> {b}' for a, b in movements)})")
    return out
