"""The scenario format's JSON Schema and key reference: generated from the declaration, committed
copies in sync, and it agrees with the loader on the shipped scenarios and on mutations of them."""

import copy
import json
import tomllib

import jsonschema
import pytest

from conftest import ROOT, SCENARIOS
from nrtraffic import scenario
from nrtraffic.scenario_schema import json_schema, markdown_reference, schema_text

SHIPPED = sorted(p.parent.name for p in SCENARIOS.glob("*/scenario.toml"))


def test_committed_schema_and_reference_are_the_generated_ones():
    assert (ROOT / "docs" / "scenario.schema.json").read_text() == schema_text(), "run: nrtraffic schema --write docs/scenario.schema.json"
    assert (ROOT / "docs" / "scenario_keys.md").read_text() == markdown_reference(), \
        "run: nrtraffic schema --markdown --write docs/scenario_keys.md"


def test_every_key_the_loader_knows_is_in_the_schema_and_no_other():
    schema = json_schema()
    for name, cls in scenario._SECTIONS.items():
        if cls is scenario.Vehicle:
            continue
        props = set(schema["properties"][name]["properties"])
        assert props == {f.name for f in __import__("dataclasses").fields(cls)}, name


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenarios_validate_against_the_schema(name):
    jsonschema.validate(tomllib.loads((SCENARIOS / name / "scenario.toml").read_text()), json_schema())


@pytest.mark.parametrize("section, key, value", [
    ("controller", "no_such_key", 1.0), ("controller", "predictor", "rk5"), ("coordinator", "terminal_speed", "slow"),
    ("demand", "rate_veh_h", "fast"), ("outputs", "sumo_fcd", 3), ("vehicle", "colour", 1.0),
])
def test_what_the_schema_refuses_the_loader_refuses_too(section, key, value, tmp_path):
    data = tomllib.loads((SCENARIOS / "cross4" / "scenario.toml").read_text())
    bad = copy.deepcopy(data)
    bad.setdefault(section, {})[key] = value
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, json_schema())
    with pytest.raises(scenario.ScenarioError, match=key):
        scenario.from_dict(bad, SCENARIOS / "cross4")


def test_schema_command_prints_json(capsys):
    from runners.cli import main

    assert main(["schema"]) == 0
    assert json.loads(capsys.readouterr().out)["title"].startswith("nrtraffic scenario")
