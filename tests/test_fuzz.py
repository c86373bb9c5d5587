"""Property-based fuzzing of scenario files and flags (Hypothesis): random mutations of the shipped
scenarios either load (and run) or are refused with a ScenarioError / exit 2 and a message; nothing
ends in a traceback."""

import math
import shutil
import tomllib

import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import SCENARIOS
from nrtraffic import scenario
from runners.cli import main

SHIPPED = ("cross4", "tee3", "cross4_curved", "paper_curved", "paper_cbf")
TABLES = {name: tomllib.loads((SCENARIOS / name / "scenario.toml").read_text()) for name in SHIPPED}

values = st.one_of(
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 0.0, -0.0, 1e-300, 1e300, 0.001, 0.5, 3.0, 600.0]),
    st.text(max_size=12),
    st.booleans(),
    st.lists(st.one_of(st.integers(-5, 5), st.text(max_size=4)), max_size=3),
    st.just({}),
)


@st.composite
def mutated(draw):
    name = draw(st.sampled_from(SHIPPED))
    table = {k: (dict(v) if isinstance(v, dict) else v) for k, v in TABLES[name].items()}
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["set", "set", "set", "delete", "unknown", "drop_section"]))
        sections = [k for k, v in table.items() if isinstance(v, dict)]
        if not sections:
            break
        sec = draw(st.sampled_from(sorted(sections)))
        keys = sorted(table[sec])
        if kind == "set" and keys:
            table[sec][draw(st.sampled_from(keys))] = draw(values)
        elif kind == "delete" and keys:
            del table[sec][draw(st.sampled_from(keys))]
        elif kind == "unknown":
            table[sec][draw(st.text(alphabet="abcdefgh_", min_size=1, max_size=8))] = draw(values)
        elif kind == "drop_section":
            del table[sec]
    return name, table


def _write(folder, name, table) -> bool:
    for f in (SCENARIOS / name).iterdir():
        if f.is_file() and f.suffix == ".xml":
            shutil.copy(f, folder / f.name)
    try:
        (folder / "scenario.toml").write_text(tomli_w.dumps(table))
    except (TypeError, ValueError):  # not representable as TOML: nothing a file could say
        return False
    return True


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=mutated())
def test_mutated_scenarios_load_or_are_refused_with_a_message(case, tmp_path_factory):
    name, table = case
    d = tmp_path_factory.mktemp("fuzz")
    if not _write(d, name, table):
        return
    try:
        sc = scenario.load(d / "scenario.toml")
    except scenario.ScenarioError as exc:
        assert str(exc).strip()
        return
    # what loads is a usable configuration: finite steps and a network beside it
    assert sc.network_path.is_file()
    assert math.isfinite(sc.controller.plant_step_s) and sc.controller.plant_step_s > 0


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=mutated(), duration=st.sampled_from(["2", "0.5", "-1", "nan", "x"]), seed=st.sampled_from(["1", "-3", "7"]))
def test_mutated_scenarios_and_flags_run_or_exit_2_without_a_traceback(case, duration, seed, tmp_path_factory,
                                                                        capsys):
    name, table = case
    d = tmp_path_factory.mktemp("fuzzrun")
    if not _write(d, name, table):
        return
    argv = ["run", str(d), "--duration", duration, "--seed", seed, "--out", str(d / "out"), "--no-progress",
            "--set", "outputs.warmup_s=0"]  # (a window these short runs reach)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse refusing a flag
        code = exc.code
    err = capsys.readouterr().err
    assert code in (0, 1, 2)
    if code != 0:
        assert "nrtraffic" in err and "Traceback" not in err
