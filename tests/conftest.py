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


@pytest.fixture(scope="session")
def paper_curved_path():
    return SCENARIOS / "paper_curved" / "scenario.toml"
