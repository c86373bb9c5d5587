"""Reading SUMO networks before a simulation starts (sumolib)."""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path

TURNS = {"l": "left", "L": "left", "s": "straight", "r": "right", "R": "right", "t": "uturn"}


def edge_of(lane_id: str) -> str:
    """The edge of a SUMO lane: its id less the ``_<index>`` SUMO appends (``Saffi_103_158#1_0`` ->
    ``Saffi_103_158#1``; a junction's internal lane ``:J_3_0`` -> its internal edge ``:J_3``)."""
    return lane_id.rsplit("_", 1)[0]


class NetworkError(ValueError):
    """The network does not have what the scenario names."""


@dataclass(frozen=True)
class JunctionMovement:
    """One lane-to-lane connection through a junction: incoming edge and lane -> outgoing edge and
    lane, with SUMO's direction."""

    in_edge: str
    out_edge: str
    turn: str  # left | straight | right | uturn
    in_lane: int = 0  # index of the incoming lane (0: the rightmost)
    out_lane: int = 0  # index of the lane it enters on the outgoing edge
    in_lanes: int = 1  # lanes of the incoming edge
    twin: bool = False  # another road leaves the incoming edge with the same turn (SUMO's "L" beside "l")

    @property
    def route(self) -> str:
        """The turning movement it belongs to: ``<in_edge>.<turn>`` (the demand's unit), or
        ``<in_edge>.<turn>.<out_edge>`` where two roads leave the incoming edge with that turn."""
        return f"{self.in_edge}.{self.turn}" + (f".{self.out_edge}" if self.twin else "")

    @property
    def lane(self) -> str:
        """SUMO's id of the incoming lane."""
        return f"{self.in_edge}_{self.in_lane}"

    @property
    def name(self) -> str:
        """``<in_edge>.<turn>`` on a one-lane approach, ``<in_edge>_<lane>.<turn>`` on a wider one
        (each with ``.<out_edge>`` for a :attr:`twin`)."""
        if self.in_lanes == 1:
            return self.route
        return f"{self.lane}.{self.turn}" + (f".{self.out_edge}" if self.twin else "")


def read_net(net_path: Path):
    """The network as sumolib reads it (junction-internal lanes included), read once per file and
    version of it in a process: a run reads it for each junction, the check before it again, and an
    OpenStreetMap network takes seconds to read."""
    p = Path(net_path).resolve()
    st = p.stat()
    return _read_net(str(p), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=4)
def _read_net(path: str, mtime_ns: int, size: int):
    import sumolib

    return sumolib.net.readNet(path, withInternal=True, withPrograms=True)


def open_xml(path):
    """A SUMO XML file opened for reading (binary), gzip-compressed (``.net.xml.gz``, ``.rou.xml.gz``,
    as SUMO reads and writes them) or plain: for ElementTree's ``parse`` and ``iterparse``."""
    f = open(path, "rb")
    if f.read(2) == b"\x1f\x8b":
        import gzip

        f.close()
        return gzip.open(path, "rb")
    f.seek(0)
    return f


CAR_CLASS = "passenger"  # SUMO's vehicle class of nrtraffic's car: the lanes it may use


def is_road(edge) -> bool:
    """Whether a sumolib edge is a road a car may drive: a normal edge (not a junction's internal
    lane, walking area or pedestrian crossing) with a lane that allows SUMO's passenger class (not a
    footpath, cycle track or tram line)."""
    return edge.getFunction() in ("", "normal") and any(lane.allows(CAR_CLASS) for lane in edge.getLanes())


def junction_movements(net_path: Path, junction_id: str) -> tuple[list[JunctionMovement], tuple[float, float]]:
    """The movements through ``junction_id``, one per lane-to-lane connection of every incoming
    lane a car may use (the first, where a lane connects to two lanes of the same road), U-turns
    included, and its position; sidewalks, cycle lanes, walking areas and crossings are not
    movements, and an approach's lanes count its car lanes only. Two
    roads reached from one incoming road with the same turn (SUMO's "l" and "L") are two turning
    movements (:attr:`JunctionMovement.twin`)."""
    net = read_net(net_path)
    if not net.hasNode(junction_id):
        raise NetworkError(f"junction {junction_id!r} is not in {net_path}")
    node = net.getNode(junction_id)
    out = []
    for edge in node.getIncoming():
        if not is_road(edge):  # (a junction's internal lanes, walking areas and crossings)
            continue
        lanes = [lane for lane in edge.getLanes() if lane.allows(CAR_CLASS)]  # (not its sidewalk or bike lane)
        for lane in lanes:
            seen = set()
            for con in lane.getOutgoing():
                to = con.getTo().getID()
                if to in seen or not is_road(con.getTo()) or not con.getToLane().allows(CAR_CLASS):
                    continue
                turn = TURNS.get(con.getDirection(), con.getDirection())
                seen.add(to)
                out.append(JunctionMovement(edge.getID(), to, turn, lane.getIndex(), con.getToLane().getIndex(),
                                            len(lanes)))
    roads: dict[tuple[str, str], set[str]] = {}
    for m in out:
        roads.setdefault((m.in_edge, m.turn), set()).add(m.out_edge)
    out = [dataclasses.replace(m, twin=True) if len(roads[(m.in_edge, m.turn)]) > 1 else m for m in out]
    if not out:
        raise NetworkError(f"junction {junction_id!r} ({node.getType()}) has no movements: no incoming lane "
                           f"connects through it to another road, so there is nothing to coordinate")
    x, y = node.getCoord()
    return out, (float(x), float(y))


@functools.lru_cache(maxsize=65536)
def give_way_room(net, edges: tuple[str, ...], front_m: float) -> tuple[float, str] | None:
    """The distance [m] from a departing vehicle's front (``front_m`` along the first of ``edges``,
    a tuple: the answer is kept per network, route and position, as a route file repeats them)
    to the first link of its route where it has no priority (a minor, equal, stop or all-way-stop
    link, as SUMO's insertion sees it, or a traffic light's link that is never a major green), and
    that junction's id; None where the route has none. Other traffic lights' links are left out
    (whether one is red depends on the moment)."""
    room = -front_m
    for e, nxt in zip(edges, [*edges[1:], None]):
        if not net.hasEdge(e):
            return None
        edge = net.getEdge(e)
        room += edge.getLength()
        if nxt is None or not net.hasEdge(nxt):
            return None
        links = edge.getConnections(net.getEdge(nxt))
        if {c.getState() for c in links} & set("m=sw") or (links and all(_never_major(net, c) for c in links)):
            return room, edge.getToNode().getID()
    return None


def _never_major(net, con) -> bool:
    """Whether a connection is a traffic light's link that no phase of its programmes makes a major
    green (``G``): a car must always be able to give way there (SUMO's insertion check)."""
    if not con.getTLSID():
        return False
    k = con.getTLLinkIndex()
    phases = [ph for prog in net.getTLS(con.getTLSID()).getPrograms().values() for ph in prog.getPhases()]
    return bool(phases) and all(k >= len(ph.state) or ph.state[k] != "G" for ph in phases)


def safe_depart_speed(room_m: float, decel_mps2: float, step_s: float) -> float:
    """The highest speed [m/s] at which a car can depart ``room_m`` [m] before a link where it must
    give way and still stop before it, braking at ``decel_mps2`` from the next step of ``step_s`` [s]
    on: ``v^2 + 2 v decel step <= 2 decel room``. SUMO's own insertion check counts half a step of
    reaction (``v^2 + v decel step <= 2 decel room``), so a car this fast is always inserted; the
    bound is about 0.2 m/s below SUMO's at a 0.1 s step (tests/test_city_roads.py)."""
    b = decel_mps2 * step_s
    return max(0.0, -b + math.sqrt(b * b + 2.0 * decel_mps2 * max(room_m, 0.0)))


def feeder_roads(net_path: Path, edge_id: str, stop_at: set[str]) -> tuple[str, ...]:
    """The road that feeds ``edge_id`` from upstream, in order of driving: the edges before it
    across nodes that join it to one other road only (a change of road type, a bend drawn as a
    node), up to a junction (a node with a third road), a node in ``stop_at`` (a controlled
    junction) or the network's edge. Empty when ``edge_id`` starts at a junction."""
    net = read_net(net_path)
    chain: list[str] = []
    edge = net.getEdge(edge_id)
    seen = {edge_id}
    while True:
        node = edge.getFromNode()
        if node.getID() in stop_at:
            break
        normal = [e for e in (*node.getIncoming(), *node.getOutgoing()) if is_road(e)]
        neighbours = {(e.getFromNode() if e.getToNode() is node else e.getToNode()).getID() for e in normal}
        ins = [e for e in node.getIncoming() if is_road(e) and e.getFromNode() is not edge.getToNode()]
        if len(neighbours) != 2 or len(ins) != 1 or ins[0].getID() in seen or edge not in ins[0].getOutgoing():
            break
        edge = ins[0]
        seen.add(edge.getID())
        chain.append(edge.getID())
    return tuple(reversed(chain))


def edge_nodes(net_path: Path) -> dict[str, tuple[str, str]]:
    """Every normal edge of the network: ``edge id -> (from junction, to junction)``."""
    return {e.getID(): (e.getFromNode().getID(), e.getToNode().getID())
            for e in read_net(net_path).getEdges(withInternal=False)}


def check_scenario(net_path: Path, junction_ids=(), edges: tuple[str, ...] = ()) -> None:
    """Check, before SUMO starts, that ``net_path`` is a SUMO network holding the junctions and the
    edges a scenario names, and that each junction has movements (not a dead end); raises
    :class:`NetworkError` naming the file and every missing id, or the unsuitable junction.
    ``junction_ids``: one id or several."""
    junction_ids = (junction_ids,) if isinstance(junction_ids, str) else tuple(junction_ids)
    junction_ids = tuple(j for j in junction_ids if j)
    import xml.etree.ElementTree as ET

    try:
        root_tag, nodes, edge_ids = None, set(), set()
        with open_xml(net_path) as f:
            for _, el in ET.iterparse(f, events=("start",)):
                if root_tag is None:
                    root_tag = el.tag
                    if root_tag != "net":
                        raise NetworkError(f"{net_path} is not a SUMO network (its root element is <{root_tag}>)")
                elif el.tag == "junction":
                    nodes.add(el.get("id"))
                elif el.tag == "edge" and el.get("function") != "internal":
                    edge_ids.add(el.get("id"))
    except (ET.ParseError, EOFError) as exc:  # (EOFError: a gzip file cut short)
        raise NetworkError(f"{net_path} is not a readable SUMO network: {exc or 'it ends early'}") from None
    except OSError as exc:
        raise NetworkError(f"{net_path} cannot be read: {exc}") from None
    problems = []
    for junction_id in junction_ids:
        if junction_id not in nodes:
            problems.append(f"junction {junction_id!r} is not in it")
    missing = [e for e in dict.fromkeys(edges) if e not in edge_ids]
    if missing:
        problems.append(f"edge{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))} "
                        f"{'are' if len(missing) > 1 else 'is'} not in it")
    if problems:
        raise NetworkError(f"{net_path}: " + "; ".join(problems))
    for junction_id in junction_ids:  # there, but is it a junction with movements to coordinate?
        try:
            junction_movements(net_path, junction_id)
        except NetworkError:
            raise
        except Exception:  # noqa: BLE001 - sumolib cannot read it: SUMO will say why when it loads it
            pass


_SUMO_OPTIONS: dict[str, str] = {}


def sumo_options() -> dict[str, str]:
    """SUMO's command-line options and their types (``"begin" -> "TIME"``, ``"mesosim" -> "BOOL"``;
    from ``sumo --save-template``), read once."""
    if not _SUMO_OPTIONS:
        import subprocess
        import xml.etree.ElementTree as ET

        from nrtraffic.sumo.netbuild import sumo_binary

        exe = sumo_binary("sumo")
        xml = subprocess.run([str(exe), "--save-template", "stdout"], capture_output=True, text=True, check=True).stdout
        for section in ET.fromstring(xml[xml.index("<"):]):
            for opt in section:
                _SUMO_OPTIONS[opt.tag] = opt.get("type", "STR")
                for syn in opt.get("synonymes", "").split():  # (--ndump is --netstate-dump)
                    if len(syn) > 1:
                        _SUMO_SYNONYMS[syn] = opt.tag
    return _SUMO_OPTIONS


_SUMO_SYNONYMS: dict[str, str] = {}


def sumo_option_name(name: str) -> str:
    """The name of SUMO's option ``name`` stands for (``"ndump"`` -> ``"netstate-dump"``); itself
    where it is no other's synonym."""
    sumo_options()
    return _SUMO_SYNONYMS.get(name, name)


# SUMO options that leave the run nothing to control or nothing to run
NOT_FOR_A_RUN = {
    "mesosim": "SUMO's mesoscopic model has no lanes or positions to place a controlled car on",
    "help": "it prints SUMO's help instead of running", "version": "it prints SUMO's version instead of running",
    "print-options": "it prints SUMO's options instead of running",
    "no-internal-links": "the controlled vehicles are driven along the junction's internal lanes",
    "output.format": "the run reads SUMO's outputs as XML", "human-readable-time": "the run reads SUMO's times "
    "as seconds",
}


SUMO_BOOLS = ("true", "false", "on", "off", "yes", "no", "1", "0")  # the values SUMO reads as a BOOL option's


def _value_error(name: str, kind: str, value: str | None) -> str | None:
    """Why ``value`` does not suit option ``name`` of SUMO type ``kind`` (None: it does)."""
    if kind == "BOOL":
        return None if value is None or value.lower() in SUMO_BOOLS else f"--{name} takes true or false, not {value!r}"
    if value is None:
        return f"--{name} needs a value ({kind.lower()})"
    if kind in ("INT", "FLOAT", "TIME"):
        try:
            number = float(value) if kind != "INT" else int(value)
        except ValueError:
            return f"--{name} needs a number ({kind.lower()}), not {value!r}"
        if name == "threads" and number < 1:  # (SUMO refused it once started)
            return f"--{name} {value}: SUMO needs at least one thread; give 1 or more"
    return None


_SUMO_WRITING: set[str] = set()


def sumo_writing_options() -> set[str]:
    """Names of SUMO's options that write a file (of type FILE in its output and report sections, or
    named ``*output*``; ``*.file``, ``save-state.*`` and the ssm device's; ``output-prefix``, and
    saving its configuration), from ``sumo --save-template --save-commented``."""
    _read_template()
    return _SUMO_WRITING


def sumo_reading_options() -> set[str]:
    """Names of SUMO's options that read a file other than the run's own (network, routes,
    detectors, configuration: :data:`RUN_SETS`): every other option of type FILE that does not write
    (``--weight-files``, ``--load-state``, ``--gui-settings-file``, ...)."""
    _read_template()
    return _SUMO_READING


_SUMO_READING: set[str] = set()


def _read_template() -> None:
    """Sort SUMO's file options into :data:`_SUMO_WRITING` and :data:`_SUMO_READING`, once."""
    if _SUMO_WRITING:
        return
    import re
    import subprocess

    from nrtraffic.sumo.netbuild import sumo_binary

    exe = sumo_binary("sumo")
    text = subprocess.run([str(exe), "--save-template", "stdout", "--save-commented"], capture_output=True,
                          text=True, check=True).stdout
    section, files = None, set()
    for line in text.splitlines():
        m = re.match(r"\s{4}<([\w.-]+)>\s*$", line)
        if m:
            section = m.group(1)
            continue
        m = re.match(r'\s{8}<([\w.-]+) value=.*type="([^"]+)"', line)
        if m and m.group(2).startswith("FILE"):
            files.add(m.group(1))
        if m and m.group(2).startswith("FILE") and not m.group(1).endswith("input-file") and (
                section in ("output", "report") or "output" in m.group(1)):
            _SUMO_WRITING.add(m.group(1))
        elif m and (m.group(1).startswith(("save-state.", "device.ssm.")) or m.group(1).endswith(".file")):
            _SUMO_WRITING.add(m.group(1))  # (state files; the ssm device writes ssm_<vehicle>.xml unasked)
    _SUMO_WRITING.update({"output-prefix", "output-suffix", "save-configuration", "save-template", "save-schema"})
    _SUMO_READING.update(files - _SUMO_WRITING - set(RUN_SETS))


_SUMO_SHORT: dict[str, str] = {}


def sumo_short_options() -> dict[str, str]:
    """SUMO's one-letter options and the long names they stand for (``"l" -> "log"``), from
    ``sumo --help``, read once."""
    if not _SUMO_SHORT:
        import re
        import subprocess

        from nrtraffic.sumo.netbuild import sumo_binary

        text = subprocess.run([sumo_binary("sumo"), "--help"], capture_output=True, text=True).stdout
        for m in re.finditer(r"^\s+-([A-Za-z]), --([\w.-]+)", text, re.MULTILINE):
            _SUMO_SHORT[m.group(1)] = m.group(2)
    return _SUMO_SHORT


# SUMO options each run sets itself (SumoSession): giving one again fails when SUMO starts
RUN_SETS = {
    "net-file": "scenario.network", "route-files": "the run's demand", "additional-files": "its detectors",
    "configuration-file": "scenario.sumocfg is read by nrtraffic", "step-length": "sumo.step_length_s",
    "seed": "--seed or scenario.seed", "random": "--seed or scenario.seed: a run is reproducible from its seed",
    "lateral-resolution": "sumo.lateral_resolution_m",
    "time-to-teleport": "-1: no vehicle is teleported", "collision.action": "collisions are recorded",
    "collision.check-junctions": "collisions are recorded", "collision.mingap-factor": "collisions are recorded",
    "ignore-accidents": "collisions are recorded", "collision.stoptime": "collisions are recorded",
    "tls.all-off": "a signalised control keeps its signals on; compare with --junction priority or allway_stop",
    "no-step-log": "its own progress", "no-warnings": "its own messages", "duration-log.disable": "its own messages",
    "scale": "demand.scale", "random-depart-offset": "demand.depart_offset_s",
    "max-num-vehicles": "every vehicle of the demand runs",
}


# SUMO outputs each run writes itself, with its own settings (SumoSession: tripinfo.xml, collisions.xml, fcd.xml)
RUN_WRITES = ("tripinfo-output", "collision-output", "fcd-output")


def _shown(item: str, name: str) -> str:
    """An item of ``sumo.extra_args`` as the user gave it, with the option it stands for where that
    is another name (``-l (--log)``, ``--ndump (--netstate-dump)``)."""
    given = item[2:].split("=")[0] if item.startswith("--") else None
    return item if given == name else f"{item} (--{name})"


def check_sumo_args(args: tuple[str, ...]) -> None:
    """Every option in ``args`` (``sumo.extra_args``: ``--name``, ``--name=value`` or SUMO's
    one-letter ``-x``) must be one of SUMO's, and none may write a file: it would land outside the
    run folder (relative to where nrtraffic was started), beside nothing that names the run; the
    run writes SUMO's outputs it uses itself (``outputs.sumo_fcd`` for fcd.xml). A value such as
    ``-5`` is not an option."""
    import re
    from collections import Counter

    if not args:
        return
    given = [(a, sumo_option_name(a[2:].split("=")[0])) for a in args if a.startswith("--")]
    short = [a for a in args if re.match(r"-[A-Za-z]", a)]
    letters = sumo_short_options()
    unknown = [a for a in short if a[1] not in letters]
    given += [(a, letters[a[1]]) for a in short if a[1] in letters]
    known = sumo_options()
    unknown += [a for a, n in given if n not in known]
    if unknown:
        raise NetworkError(f"sumo.extra_args: SUMO has no option {', '.join(unknown)}")
    # each option with its value: "--name=value", or "--name value" (a BOOL's value is optional)
    k, problems = 0, []
    while k < len(args):
        a = args[k]
        is_option = a.startswith("--") or bool(re.match(r"-[A-Za-z]", a))
        if not is_option:
            problems.append(f"{a!r} is not an option (each item is --name, --name=value, or the value after "
                            f"--name)" if a.strip() else "an empty item")
            k += 1
            continue
        name = sumo_option_name(a[2:].split("=")[0]) if a.startswith("--") else letters[a[1]]
        kind = known[name]
        if "=" in a or (a.startswith("-") and not a.startswith("--") and len(a) > 2):
            value = a.split("=", 1)[1] if "=" in a else a[2:]
            k += 1
        elif k + 1 < len(args) and not (args[k + 1].startswith("--") or re.match(r"-[A-Za-z]", args[k + 1])) \
                and (kind != "BOOL" or args[k + 1].lower() in SUMO_BOOLS):
            value = args[k + 1]
            k += 2
        else:
            value = None
            k += 1
        why = _value_error(name, kind, value)
        if why:
            problems.append(why)
    if problems:
        raise NetworkError(f"sumo.extra_args: {'; '.join(problems)}")
    twice = sorted(n for n, c in Counter(n for _, n in given).items() if c > 1)
    if twice:
        raise NetworkError(f"sumo.extra_args: --{twice[0]} is given twice; give it once")
    unfit = [(a, n) for a, n in given if n in NOT_FOR_A_RUN]
    if unfit:
        a, n = unfit[0]
        raise NetworkError(f"sumo.extra_args: {a}: {NOT_FOR_A_RUN[n]}; leave it out")
    clock = [_shown(a, n) for a, n in given if n in ("begin", "end")]
    if clock:
        raise NetworkError(f"sumo.extra_args: {', '.join(clock)} sets SUMO's clock, which the run keeps itself: "
                           "use scenario.begin_s for the start and scenario.duration_s (or --duration) for the length")
    for a, n in given:
        if n in RUN_SETS:
            raise NetworkError(f"sumo.extra_args: {_shown(a, n)}: the run sets it "
                               f"itself ({RUN_SETS[n]}); leave it out")
        if n.startswith("device.toc."):
            raise NetworkError(f"sumo.extra_args: {a}: SUMO's take-over device needs parameters of the vehicle type "
                               "that nrtraffic's vehicles do not carry (SUMO stops at its start); leave it out")
        if n in ("remote-port", "num-clients"):
            raise NetworkError(f"sumo.extra_args: {a}: SUMO would wait for a TraCI client of its own and the run "
                               "would never start; leave it out")
    of_output = [(a, n) for a, n in given if n not in sumo_writing_options()
                 and any(n.startswith(w + ".") for w in sumo_writing_options())]
    if of_output:
        output = of_output[0][1].split(".")[0]  # (the output it is a setting of)
        what = (f"sets up SUMO's {output}, which the run writes itself with its own settings (its figures read "
                "them)" if output in RUN_WRITES else "sets up a SUMO output that the run does not write")
        raise NetworkError(f"sumo.extra_args: {', '.join(_shown(a, n) for a, n in of_output)} {what}; leave it out")
    writing = [_shown(a, n) for a, n in given if n in sumo_writing_options()]
    if writing:
        raise NetworkError(f"sumo.extra_args: {', '.join(writing)} would write files outside the run folder; "
                           "leave it out (outputs.sumo_fcd = true writes fcd.xml into the run)")
    reading = [_shown(a, n) for a, n in given if n in sumo_reading_options()]
    if reading:
        raise NetworkError(f"sumo.extra_args: {', '.join(reading)} would have SUMO read a file that the run does not "
                           "check or copy into its folder (a replay of the run could not find it); leave it out: "
                           "the run's inputs are the scenario's network and demand")


def edge_lanes(net_path: Path, edges) -> list[tuple[str, str, float]]:
    """``(edge, lane id, lane length [m])`` of every lane of ``edges``, from the network file."""
    net = read_net(net_path)
    return [(e, lane.getID(), lane.getLength()) for e in edges for lane in net.getEdge(e).getLanes()]
