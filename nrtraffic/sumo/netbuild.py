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
    equal the coordinates of the plain XML (REFERENCE.md section 5), and 4 decimals.
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


def with_junction_type(net: Path, junction_ids, junction_type: str, output: Path) -> Path:
    """A copy of ``net`` whose junctions ``junction_ids`` (one id or several) have SUMO's
    ``junction_type`` (the baselines: traffic_light, priority, allway_stop, right_before_left; a
    coordinated traffic light is built as traffic_light). Round trip through plain XML."""
    import re
    import tempfile

    if junction_type not in JUNCTION_TYPES:
        raise ValueError(f"unknown junction type {junction_type!r}; use one of {', '.join(JUNCTION_TYPES)}")
    junction_ids = (junction_ids,) if isinstance(junction_ids, str) else tuple(junction_ids)
    node_type = "traffic_light" if junction_type == "traffic_light_coordinated" else junction_type
    with tempfile.TemporaryDirectory() as tmp:
        prefix = Path(tmp) / "plain"
        proc = subprocess.run([sumo_binary("netconvert"), "--sumo-net-file", str(net), "--plain-output-prefix",
                               str(prefix), "--no-warnings", "true"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise SumoToolError(f"netconvert could not read {net}:\n{proc.stderr.strip()}")
        nod = Path(f"{prefix}.nod.xml")
        text = nod.read_text()
        for junction_id in junction_ids:
            pat = re.compile(r'(<node id="' + re.escape(junction_id) + r'"[^>]*?type=")([^"]*)(")')
            if not pat.search(text):
                raise SumoToolError(f"junction {junction_id!r} not found in {net}")
            text = pat.sub(lambda m: m.group(1) + node_type + m.group(3), text)
        nod.write_text(text)
        args = ["--node-files", str(nod), "--edge-files", f"{prefix}.edg.xml", "--connection-files",
                f"{prefix}.con.xml", "--output-file", str(output), "--no-turnarounds", "true",
                "--offset.disable-normalization", "true", "--no-warnings", "true", "--precision", "4"]
        proc = subprocess.run([sumo_binary("netconvert")] + args, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SumoToolError(f"netconvert failed building the {junction_type} variant:\n{proc.stderr.strip()}")
    return output
