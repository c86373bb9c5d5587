"""Every numeric scenario key is refused outside its physical range, and what is accepted runs in
bounded work: extreme values drawn for every key either stop the run before SUMO starts with exit 2
and a message naming the key, or a 10 s run finishes (no hang, no traceback)."""

import math
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from conftest import ROOT, SCENARIOS
from nrtraffic import scenario as S

PAPER = SCENARIOS / "paper_curved" / "scenario.toml"
# sections that are arrays of tables (no --set for them)
_ARRAYS = {"demand.flows", "demand.intervals", "approaches", "vehicles", "junctions"}
KEYS = [(sec, k) for sec, keys in S.RANGES.items() if sec not in _ARRAYS for k in keys]
EXTREMES = (-1e9, -1.0, 0.0, 1e-9, 1e-4, 1.0, 1e4, 1e9, math.inf, -math.inf, math.nan)


def _toml(v: float, integer: bool) -> str:
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return str(int(v)) if integer and float(v).is_integer() else repr(float(v))


@pytest.mark.parametrize("sec, key", KEYS, ids=[f"{s}.{k}" for s, k in KEYS])
def test_values_outside_the_range_are_refused_naming_the_key(sec, key):
    lo, hi = S.RANGES[sec][key]
    integer = isinstance(lo, int) and isinstance(hi, int)
    for v in (lo - (1 if integer else max(abs(lo), 1.0) * 1e-3), hi + (1 if integer else max(abs(hi), 1.0) * 1e-3),
              math.nan):
        if integer and math.isnan(v):
            continue
        with pytest.raises(S.ScenarioError, match=rf"{sec}\.{key}"):
            S.load(PAPER, [f"{sec}.{key}={_toml(v, integer)}"])


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=st.sampled_from(KEYS), value=st.one_of(st.sampled_from(EXTREMES),
                                                  st.sampled_from([b for keys in S.RANGES.values() for r in keys.values()
                                                                   for b in r])))
@example(key=("controller", "predictor_mass_factor"), value=0.1)  # (the predictor's mass out of range: exit 1)
def test_extreme_values_are_refused_or_run_in_bounded_work(key, value, tmp_path_factory):
    sec, k = key
    lo, hi = S.RANGES[sec][k]
    integer = isinstance(lo, int) and isinstance(hi, int)
    out = tmp_path_factory.mktemp("run") / "o"
    cmd = [sys.executable, "-m", "runners.cli", "run", str(PAPER), "--duration", "10", "--set",
           f"{sec}.{k}={_toml(value, integer)}", "--out", str(out), "--no-progress"]
    try:
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{sec}.{k} = {value!r}: a 10 s run did not end within 300 s")
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode in (0, 2), (proc.returncode, proc.stderr[-500:])
    if proc.returncode == 2:
        assert sec in proc.stderr and not (out / "summary.json").exists()


@pytest.mark.parametrize("name", sorted(n for n in S.OPEN if n.rsplit(".", 1)[0] not in _ARRAYS))
def test_an_open_bound_is_refused_and_the_schema_says_it_is_open(name):
    """A key whose range excludes a bound (a zone of 0 m, a speed limit of 0) is refused there,
    naming the key, and the schema gives that bound as exclusive: the schema's minimum 0 had been
    refused as "must be > 0", so the documented range was wider than the check."""
    from nrtraffic.scenario_schema import json_schema

    sec, key = name.rsplit(".", 1)
    lo, hi = S.RANGES[sec][key]
    bound = lo if S.OPEN[name] == "min" else hi
    with pytest.raises(S.ScenarioError, match=rf"{sec}\.{key}"):
        S.load(PAPER, [f"{sec}.{key}={bound!r}"])
    prop = json_schema()["properties"][sec]["properties"][key]
    assert prop["exclusiveMinimum" if S.OPEN[name] == "min" else "exclusiveMaximum"] == bound


@pytest.mark.parametrize("setting", ["disturbances.longitudinal_accel_mps2=-5.0", "disturbances.lateral_accel_mps2=5.0",
                                     "disturbances.longitudinal_accel_mps2=-0.5", "human.speed_dev=0.49"])
def test_values_inside_the_documented_range_are_taken(setting):
    """A downhill grade (a negative longitudinal disturbance) and the bounds of the documented
    ranges are taken: the range had refused every negative grade that the check allows, and
    allowed speed_dev up to 1 where the check stops at 0.5."""
    S.load(PAPER, [setting])


@pytest.mark.parametrize("metres, taken", [(10.0, False), (19.9, False), (20.0, True), (0.0, True)])
def test_a_junction_of_its_own_control_zone_needs_20_m(metres, taken, tmp_path):
    """A control zone shorter than 20 m (the shortest a cut may leave a route, junction.build)
    is refused for one junction of a corridor as for ``zones.control_zone_m``, naming the key;
    0 (take ``[zones]``'s) and 20 m are taken."""
    from conftest import copy_scenario

    folder = copy_scenario("corridor3", tmp_path / "c", 'id = "J2"\n', f'id = "J2"\ncontrol_zone_m = {metres}\n')
    if taken:
        import tomllib

        sc = S.load(folder / "scenario.toml")
        want = metres or tomllib.loads((folder / "scenario.toml").read_text())["zones"]["control_zone_m"]
        assert [j.control_zone_m for j in sc.controlled_junctions() if j.id == "J2"] == [want]
    else:
        with pytest.raises(S.ScenarioError, match=r"junctions\.J2: control_zone_m"):
            S.load(folder / "scenario.toml")


def test_a_control_zone_under_20_m_is_refused_before_sumo_starts(tmp_path):
    """``nrtraffic run`` with ``zones.control_zone_m=10``: exit 2, the key named, nothing run."""
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "runners.cli", "run", str(SCENARIOS / "cross4"), "--duration", "10",
                           "--set", "zones.control_zone_m=10", "--out", str(out)], capture_output=True, text=True,
                          cwd=ROOT)
    assert proc.returncode == 2 and "zones.control_zone_m" in proc.stderr
    assert not (out / "summary.json").exists()
