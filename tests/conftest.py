import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

SCENARIOS = ROOT / "sumo_scenarios"


@pytest.fixture(scope="session")
def paper_curved_path():
    return SCENARIOS / "paper_curved" / "scenario.toml"
