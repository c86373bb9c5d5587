"""Build SUMO networks from plain node/edge XML with SUMO's own ``netconvert``.

The binaries come from the ``eclipse-sumo`` wheel; its ``sumo.SUMO_HOME`` is used rather than the
environment variable, because importing libsumo points ``SUMO_HOME`` at a data-only folder.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path


class SumoToolError(RuntimeError):
    """A SUMO command-line tool is missing or failed."""


def sumo_binary(name: str) -> str:
    """Absolute path of a SUMO binary (``sumo``, ``netconvert``, ...) from the installed wheel.

    Falls back to ``$SUMO_HOME/bin`` and then ``PATH``.
    """
    candidates = []
    try:
        import sumo  # the eclipse-sumo wheel

        candidates.append(Path(sumo.SUMO_HOME) / "bin" / name)
    except ImportError:
        pass
    if os.environ.get("SUMO_HOME"):
        candidates.append(Path(os.environ["SUMO_HOME"]) / "bin" / name)
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return str(c)
    found = shutil.which(name)
    if found:
        return found
    raise SumoToolError(
        f"SUMO binary {name!r} not found: install the 'eclipse-sumo' package (pip install eclipse-sumo)"
    )


def build_network(nodes: Path, edges: Path, output: Path, extra_args: list[str] | None = None) -> Path:
    """Run netconvert on plain XML and write ``output`` (.net.xml).

    Uses ``--no-turnarounds`` and ``--offset.disable-normalization`` so that network coordinates
    equal the coordinates of the plain XML (netconvert's documentation), and 4 decimals.
    """
    cmd = [
        sumo_binary("netconvert"),
        "--node-files", str(nodes),
        "--edge-files", str(edges),
        "--output-file", str(output),
        "--no-turnarounds", "true",
        "--offset.disable-normalization", "true",
        "--no-warnings", "true",
        # netconvert writes coordinates with 2 decimals by default: 1 cm of noise on a curved lane's
        # vertices is a curvature noise that a tracker turns into steering chatter
        "--precision", "4",
    ] + list(extra_args or [])
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SumoToolError(f"netconvert failed for {edges}:\n{proc.stderr.strip()}")
    return output


# SUMO's junction controls the baselines rebuild a network with; "traffic_light_coordinated" is
# "traffic_light" at every junction with offsets for green waves (runners/baseline.py)
JUNCTION_TYPES = ("traffic_light", "traffic_light_coordinated", "priority", "allway_stop", "right_before_left")
# every baseline: the network's own control unchanged ("as_is"), its signals made actuated
# ("actuated"), or its junctions rebuilt with one of SUMO's controls
BASELINES = ("as_is", "actuated") + JUNCTION_TYPES
# actuated phases where a programme gives none: netconvert's own defaults for actuated signals
# (--tls.min-dur, --tls.max-dur) [s]
ACTUATED_MIN_DUR_S = 5
ACTUATED_MAX_DUR_S = 50


def _netconvert(args: list[str], what: str) -> None:
    proc = subprocess.run([sumo_binary("netconvert")] + args, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SumoToolError(f"netconvert failed {what}:\n{proc.stderr.strip()}")


def _plain(net: Path, prefix: Path) -> None:
    """``net`` as plain XML files ``prefix.nod.xml``, ``.edg.xml``, ``.con.xml``, ``.tll.xml``."""
    proc = subprocess.run([sumo_binary("netconvert"), "--sumo-net-file", str(net), "--plain-output-prefix",
                           str(prefix), "--no-warnings", "true"], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SumoToolError(f"netconvert could not read {net}:\n{proc.stderr.strip()}")


def junction_kinds(net: Path, junction_ids) -> dict[str, str]:
    """SUMO's type of each of ``junction_ids`` in ``net`` (``priority``, ``traffic_light``, ...)."""
    import xml.etree.ElementTree as ET

    from nrtraffic.sumo.network import open_xml

    wanted = set(junction_ids)
    kinds = {}
    with open_xml(net) as f:
        for _, el in ET.iterparse(f, events=("start",)):
            if el.tag == "junction" and el.get("id") in wanted:
                kinds[el.get("id")] = el.get("type", "")
    return kinds


def is_signalised_network(net: Path, junction_ids) -> bool:
    """Whether every one of ``junction_ids`` is a signal in ``net`` (the HCM thresholds of an
    ``as_is`` baseline)."""
    kinds = junction_kinds(net, junction_ids)
    return bool(kinds) and all(k.startswith("traffic_light") for k in kinds.values())


def with_junction_type(net: Path, junction_ids, junction_type: str, output: Path,
                       extra_args: tuple[str, ...] = ()) -> Path:
    """A copy of ``net`` whose junctions ``junction_ids`` (one id or several) have SUMO's
    ``junction_type`` (the baselines: traffic_light, priority, allway_stop, right_before_left; a
    coordinated traffic light is built as traffic_light). Round trip through plain XML; the signal
    programmes of the other junctions are kept as the network has them, those of ``junction_ids``
    are SUMO's default for their new type. ``extra_args`` go to netconvert."""
    import re
    import tempfile
    import xml.etree.ElementTree as ET

    if junction_type not in JUNCTION_TYPES:
        raise ValueError(f"unknown junction type {junction_type!r}; use one of {', '.join(JUNCTION_TYPES)}")
    junction_ids = (junction_ids,) if isinstance(junction_ids, str) else tuple(junction_ids)
    node_type = "traffic_light" if junction_type == "traffic_light_coordinated" else junction_type
    with tempfile.TemporaryDirectory() as tmp:
        prefix = Path(tmp) / "plain"
        _plain(net, prefix)
        nod = Path(f"{prefix}.nod.xml")
        text = nod.read_text()
        rebuilt_tls = set()
        for junction_id in junction_ids:
            pat = re.compile(r'<node id="' + re.escape(junction_id) + r'"[^>]*?/?>')
            m = pat.search(text)
            if not m:
                raise SumoToolError(f"junction {junction_id!r} not found in {net}")
            tl = re.search(r'\btl="([^"]*)"', m.group(0))
            rebuilt_tls.add(tl.group(1) if tl else junction_id)
            node = re.sub(r'\s(tl|tlType|tlLayout|controlledInner)="[^"]*"', "", m.group(0))
            node = re.sub(r'(\stype=")[^"]*(")', lambda t: t.group(1) + node_type + t.group(2), node) \
                if ' type="' in node else node.replace(f'id="{junction_id}"', f'id="{junction_id}" type="{node_type}"', 1)
            text = text[:m.start()] + node + text[m.end():]
        nod.write_text(text)
        args = ["--node-files", str(nod), "--edge-files", f"{prefix}.edg.xml", "--connection-files",
                f"{prefix}.con.xml", "--output-file", str(output), "--no-turnarounds", "true",
                "--offset.disable-normalization", "true", "--no-warnings", "true", "--precision", "4",
                *extra_args]
        tll = Path(f"{prefix}.tll.xml")
        if tll.is_file():  # the other junctions' programmes, as the network has them
            tree = ET.parse(tll)
            root = tree.getroot()
            for el in list(root):
                if el.get("id" if el.tag == "tlLogic" else "tl") in rebuilt_tls:
                    root.remove(el)
            if len(root):
                tree.write(tll)
                args += ["--tllogic-files", str(tll)]
        _netconvert(args, f"building the {junction_type} variant of {net}")
    return output


def actuated(net: Path, junction_ids, output: Path) -> Path:
    """A copy of ``net`` whose junctions ``junction_ids`` have SUMO's actuated (gap-based) signals
    on their own phases: a signal programme of the network is kept, phase by phase, with
    ``type="actuated"``, and each of its green phases that has no ``minDur``/``maxDur`` gets
    ``minDur = min(duration, 5 s)`` and ``maxDur = max(duration, 50 s)`` (netconvert's defaults);
    a junction without signals gets netconvert's default actuated programme. SUMO places the
    detectors itself when it loads the network."""
    import xml.etree.ElementTree as ET

    junction_ids = (junction_ids,) if isinstance(junction_ids, str) else tuple(junction_ids)
    kinds = junction_kinds(net, junction_ids)
    plain = [j for j in junction_ids if not kinds.get(j, "").startswith("traffic_light")]
    src = Path(net)
    if plain:
        src = with_junction_type(net, plain, "traffic_light", output, ("--tls.default-type", "actuated"))
    from nrtraffic.sumo.network import open_xml

    with open_xml(src) as f:
        tree = ET.parse(f)
    root = tree.getroot()
    to_node = {e.get("id"): e.get("to") for e in root.iter("edge")}
    tls = {c.get("tl") for c in root.iter("connection") if c.get("tl") and to_node.get(c.get("from")) in junction_ids}
    for logic in root.iter("tlLogic"):
        if logic.get("id") not in tls:
            continue
        logic.set("type", "actuated")
        for phase in logic.iter("phase"):
            state, dur = phase.get("state", ""), float(phase.get("duration", "0"))
            if any(c in state for c in "Gg") and "y" not in state and phase.get("minDur") is None:
                phase.set("minDur", f"{min(dur, ACTUATED_MIN_DUR_S):g}")
                phase.set("maxDur", f"{max(dur, ACTUATED_MAX_DUR_S):g}")
    tree.write(output, encoding="UTF-8", xml_declaration=True)
    return output


def grid_network(n: int, output: Path, block_m: float = 250.0, lanes: int = 2, speed_mps: float = 13.89,
                 seed: int = 42) -> Path:
    """SUMO's ``netgenerate`` grid of ``n`` x ``n`` junctions (ids ``A0`` ... like netgenerate's),
    ``block_m`` [m] apart, roads of ``lanes`` lanes each way at ``speed_mps`` [m/s], and a road of
    ``block_m`` in from each side at every row and column (``4 n`` entries); no U-turns."""
    args = [sumo_binary("netgenerate"), "--grid", "--grid.number", str(n), "--grid.length", f"{block_m:g}",
            "--grid.attach-length", f"{block_m:g}", "--default.lanenumber", str(lanes), "--default.speed",
            f"{speed_mps:g}", "--no-turnarounds", "true", "--seed", str(seed), "-o", str(output)]
    out = subprocess.run(args, capture_output=True, text=True)
    if out.returncode != 0:
        raise SumoToolError(f"netgenerate failed: {out.stderr.strip()[-500:]}")
    return output


def random_trips(net: Path, output: Path, veh_h_per_entry: float, entries: int, end_s: float,
                 seed: int = 42, min_distance_m: float = 300.0) -> Path:
    """A route file of trips from the network's fringe (its roads in) to a random fringe exit at
    least ``min_distance_m`` [m] away, ``veh_h_per_entry`` departures per hour at each of
    ``entries`` entries on average, from 0 to ``end_s`` [s], each on the lane that suits its route
    best at the road's speed: SUMO's ``randomTrips.py``, routed on the shortest path by
    ``duarouter``. The tools' comments (which hold this machine's paths) are left out."""
    import re
    import sys
    import tempfile

    import sumo

    tools = Path(sumo.__file__).parent / "tools"
    period = 3600.0 / (veh_h_per_entry * entries)  # one departure every `period` seconds over all entries
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PATH=f"{Path(sumo_binary('duarouter')).parent}{os.pathsep}{os.environ.get('PATH', '')}")
        out = subprocess.run([sys.executable, str(tools / "randomTrips.py"), "-n", str(net), "--fringe-factor", "max",
                              "--period", f"{period:.6f}", "--begin", "0", "--end", f"{end_s:g}", "--seed", str(seed),
                              "--trip-attributes", 'departLane="best" departSpeed="max"', "--prefix", "g",
                              "--min-distance", f"{min_distance_m:g}", "-o", str(Path(tmp) / "trips.xml"),
                              "--route-file", str(output), "--validate"], capture_output=True, text=True, env=env)
    if out.returncode != 0:
        raise SumoToolError(f"randomTrips.py failed: {out.stderr.strip()[-500:]}")
    output.write_text(re.sub(r"<!--.*?-->\s*", "", output.read_text(), flags=re.S))
    return output
