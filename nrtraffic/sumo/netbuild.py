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
