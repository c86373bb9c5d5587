import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")
# compiled kernels for a generic x86-64/arm64 CPU: the golden run (make golden) was recorded so, and
# replays on another machine then take the same floating-point paths
os.environ.setdefault("NUMBA_CPU_NAME", "generic")

SCENARIOS = ROOT / "sumo_scenarios"


def copy_scenario(name: str, dest: Path, old: str | None = None, new: str = "", extra: str = "") -> Path:
    """A copy of scenario folder ``name`` (its files) in ``dest``; in its scenario.toml ``old``
    (which must be there) replaced by ``new`` and ``extra`` appended."""
    dest.mkdir(parents=True, exist_ok=True)
    for f in (SCENARIOS / name).iterdir():
        if f.is_file():
            (dest / f.name).write_bytes(f.read_bytes())
    toml = dest / "scenario.toml"
    text = toml.read_text()
    if old is not None:
        assert old in text, old
        text = text.replace(old, new)
    toml.write_text(text + extra)
    return dest


@pytest.fixture(scope="session")
def paper_curved_path():
    return SCENARIOS / "paper_curved" / "scenario.toml"


def conflict_gaps(run_dir: Path) -> tuple[list[tuple[str, str, str, float]], float]:
    """From a run's own records (vehicles.csv, movements.json): for every two crossings of
    conflicting movements, the time between one leaving their shared conflict area and the other
    entering it, by the times they actually entered the merging zone (the zone is crossed at the
    planned constant speed); ``([(junction, vehicle, vehicle, gap [s]), ...], the margin [s])``."""
    import json
    import tomllib

    import pandas as pd

    veh = pd.read_csv(run_dir / "vehicles.csv")
    doc = json.loads((run_dir / "movements.json").read_text())
    areas = {(c["movement"], c["with"]): (c["from_m"], c["to_m"]) for c in doc["conflict_areas"]}
    coord = tomllib.loads((run_dir / "scenario.resolved.toml").read_text())["coordinator"]
    assert coord["conflict_model"] == "conflict_points"
    veh["mv"] = veh["approach"] + "." + veh["movement"]
    rows = veh[veh["t_exit_s"].notna()].to_dict("records")
    out = []
    for i, a in enumerate(rows):
        for b in rows[i + 1:]:
            if (a["mv"], b["mv"]) in areas:
                assert a["junction"] == b["junction"]  # relations are within a junction only
                (fa, ta), (fb, tb) = areas[(a["mv"], b["mv"])], areas[(b["mv"], a["mv"])]
                va, vb = a["v_merge_planned_mps"], b["v_merge_planned_mps"]
                a_in, a_out = a["t_merge_actual_s"] + fa / va, a["t_merge_actual_s"] + ta / va
                b_in, b_out = b["t_merge_actual_s"] + fb / vb, b["t_merge_actual_s"] + tb / vb
                out.append((a["junction"], a["vehicle_id"], b["vehicle_id"], max(b_in - a_out, a_in - b_out)))
    return out, coord["conflict_margin_s"]
