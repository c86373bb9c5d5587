import tomllib

import pytest

from nrtraffic import scenario
from nrtraffic.scenario import ScenarioError


def test_paper_scenario_loads(paper_curved_path):
    sc = scenario.load(paper_curved_path)
    assert sc.controller.predictor_mass_factor == 2.0
    assert sc.network_path.is_file()
    assert sc.vehicle.params().m == 2050.0


def _write(tmp_path, paper_curved_path, text_edit):
    src = paper_curved_path.read_text()
    dst = tmp_path / "scenario.toml"
    dst.write_text(text_edit(src))
    (tmp_path / "curved.net.xml").write_text((paper_curved_path.parent / "curved.net.xml").read_text())
    return dst


def test_unknown_key_is_named(tmp_path, paper_curved_path):
    f = _write(tmp_path, paper_curved_path, lambda s: s.replace("alpha = 100.0", "alpah = 100.0"))
    with pytest.raises(ScenarioError, match=r"unknown key controller\.alpah"):
        scenario.load(f)


def test_wrong_type_and_range_are_named(tmp_path, paper_curved_path):
    f = _write(tmp_path, paper_curved_path, lambda s: s.replace("alpha = 100.0", 'alpha = "fast"'))
    with pytest.raises(ScenarioError, match=r"controller\.alpha must be a number"):
        scenario.load(f)
    f = _write(tmp_path, paper_curved_path, lambda s: s.replace("horizon_s = 0.2", "horizon_s = -1.0"))
    with pytest.raises(ScenarioError, match=r"controller\.horizon_s = -1.0 is outside its range"):
        scenario.load(f)


def test_missing_network_and_malformed_file(tmp_path, paper_curved_path):
    f = _write(tmp_path, paper_curved_path, lambda s: s.replace('"curved.net.xml"', '"nothere.net.xml"'))
    with pytest.raises(ScenarioError, match="network file not found"):
        scenario.load(f)
    f = _write(tmp_path, paper_curved_path, lambda s: s + "\n[[[broken")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        scenario.load(f)
    with pytest.raises(ScenarioError, match="scenario file not found"):
        scenario.load(tmp_path / "none.toml")


def test_a_network_that_is_a_device_or_a_pipe_is_named_as_such(tmp_path, paper_curved_path):
    """``scenario.network = "/dev/zero"`` or a named pipe: "is not a regular file", not "not found"
    (it exists), and nothing is read from it (a pipe would block)."""
    import os

    fifo = tmp_path / "pipe.net.xml"
    os.mkfifo(fifo)
    for net in ("/dev/zero", str(fifo)):
        f = _write(tmp_path, paper_curved_path, lambda s: s.replace('"curved.net.xml"', f'"{net}"'))
        with pytest.raises(ScenarioError, match="network file is not a regular file"):
            scenario.load(f, allow_outside=True)


def test_a_file_saved_with_a_byte_order_mark_reads_as_without(tmp_path, paper_curved_path):
    """Some editors save UTF-8 with a byte-order mark; the file reads as the same scenario."""
    f = _write(tmp_path, paper_curved_path, lambda s: s)
    plain = scenario.load(f)
    f.write_bytes(b"\xef\xbb\xbf" + f.read_bytes())
    assert scenario.load(f) == plain


def test_overrides_and_resolved_round_trip(tmp_path, paper_curved_path):
    sc = scenario.load(paper_curved_path, ["controller.horizon_s=0.3", 'scenario.network="straight.net.xml"'])
    assert sc.controller.horizon_s == 0.3 and sc.network_path.name == "straight.net.xml"
    with pytest.raises(ScenarioError, match="unknown section"):
        scenario.load(paper_curved_path, ["nosuch.key=1"])
    out = tmp_path / "resolved.toml"
    scenario.dump(sc, out)
    again = scenario.from_dict(tomllib.loads(out.read_text()), paper_curved_path.parent)
    assert again.to_dict() == sc.to_dict()


def test_unknown_vehicle_parameter(paper_curved_path):
    with pytest.raises(ScenarioError, match="vehicle.wheels is not a vehicle parameter"):
        scenario.load(paper_curved_path, ["vehicle.wheels=3"])


def test_a_plant_step_beyond_eulers_stability_limit_is_refused(tmp_path, paper_curved_path):
    """The paper's car needs a plant step of 0.0111 s or less (tests/test_bicycle.py checks the
    limit against the plant); the message names the key and a step that divides the SUMO step."""
    f = _write(tmp_path, paper_curved_path, lambda s: s.replace("plant_step_s = 0.005", "plant_step_s = 0.02"))
    with pytest.raises(ScenarioError, match=r"controller\.plant_step_s = 0\.02 s .* 0\.0111 s or less.* set it to "
                                            r"0\.01 \(sumo\.step_length_s / 10\)"):
        scenario.load(f)
    f = _write(tmp_path, paper_curved_path, lambda s: s.replace("plant_step_s = 0.005", "plant_step_s = 0.01"))
    assert scenario.load(f).controller.plant_step_s == 0.01


def test_a_vehicle_too_stiff_for_any_allowed_plant_step_is_named(tmp_path, paper_curved_path):
    """Tyres in range but far too stiff for the mass, yaw inertia and axle distances (also in range)
    need a plant step below the shortest allowed: the message names the vehicle's keys at once (no
    step is searched for, as none would do). A SUMO step with no short enough divisor of six
    decimals or fewer gets no number to set."""
    stiff = ["vehicle.Caf=1e7", "vehicle.Car=1e7", "vehicle.m=300", "vehicle.Iz=50", "vehicle.lf=10"]
    with pytest.raises(ScenarioError, match=r"below the shortest plant step allowed \(0\.0001 s\).*vehicle\.Caf"):
        scenario.load(paper_curved_path, stiff)
    with pytest.raises(ScenarioError, match=r"0\.0111 s or less.*a whole divisor of sumo\.step_length_s of 0\.0111 s"):
        scenario.load(paper_curved_path, ["sumo.step_length_s=0.0123457", "controller.plant_step_s=0.0123457"])
