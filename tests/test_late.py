"""A controlled vehicle held up before its merging zone by what its plan did not foresee never
enters the merging zone later than planned (nrtraffic.junction.late)."""

import numpy as np
import pytest

from nrtraffic import scenario
from nrtraffic.planning.crossing import travel_time, travel_times
from runners.single import run_scenario


@pytest.mark.parametrize("v, D, a, v_max", [(0.0, 20.0, 2.5, 13.89), (5.0, 200.0, 2.5, 13.89),
                                             (13.89, 50.0, 2.5, 13.89), (15.0, 30.0, 2.0, 15.0), (3.0, 0.0, 2.0, 13.0)])
def test_the_fastest_entry_is_the_fastest_motion_within_the_bounds(v, D, a, v_max):
    """The late guard's fastest entry (``travel_times`` from the speed now, up to ``v_max``)
    against a fine explicit integration of full acceleration up to the top speed."""
    dt, x, u, t = 1e-4, 0.0, v, 0.0
    while x < D:
        u_next = min(u + a * dt, v_max)
        x += 0.5 * (u + u_next) * dt
        u, t = u_next, t + dt
    assert float(travel_times(np.array([D]), a, v_max, np.array([v]))[0]) == pytest.approx(t, abs=2e-3)


def test_travel_times_is_travel_time_of_each_element():
    rng = np.random.default_rng(3)
    d, v0, cap = rng.uniform(-5, 300, 400), rng.uniform(0, 20, 400), rng.uniform(1, 20, 400)
    assert travel_times(d, 2.5, cap, v0).tolist() == [travel_time(*x) for x in zip(d, [2.5] * 400, cap, v0)]


def test_a_car_held_up_by_a_vehicle_its_plan_did_not_know_stops_and_is_planned_again(tmp_path):
    """cross4 with no random demand. A SUMO-driven car (no plan, no reservation) stops on N_in
    short of the junction for 20 s; a controlled car behind it on the same lane was planned to
    cross long before that. It must not cross late: it stops before the merging zone, its start
    is reserved again, and it enters the merging zone when its last plan says. A controlled car
    from the east, planned to cross in the window the held-up car would have used late, crosses
    undisturbed. No collision."""
    from conftest import copy_scenario

    extra = """
[[vehicles]]
id = "stopper"
approach = "N_in.straight"
depart_s = 0.0
depart_speed_mps = 13.4
controlled = false
speed_profile = [[0.0, 13.4], [33.0, 13.4], [36.0, 0.0], [56.0, 0.0], [60.0, 13.4], [300.0, 13.4]]

[[vehicles]]
id = "behind"
approach = "N_in.straight"
depart_s = 4.0
depart_speed_mps = 13.4

[[vehicles]]
id = "cross"
approach = "E_in.straight"
depart_s = 40.0
depart_speed_mps = 13.4
"""
    d = copy_scenario("cross4", tmp_path / "scen", "rate_veh_h = 400.0", "rate_veh_h = 0.0\nmean_headway_s = 0.0",
                      extra)
    sc = scenario.load(d / "scenario.toml", ["scenario.duration_s=120.0", "outputs.warmup_s=0.0"])
    res = run_scenario(sc, tmp_path / "run")
    v = res.vehicles.set_index("vehicle_id")
    b = v.loc["behind"]
    assert b["replans"] >= 1
    # it entered when its last plan said (the kernel tracks it to centimetres), not 20 s late
    assert abs(b["t_merge_actual_s"] - b["t_merge_planned_s"]) < 0.3, (b["t_merge_actual_s"], b["t_merge_planned_s"])
    assert b["t_merge_actual_s"] > 56.0  # (the car ahead stood till then)
    c = v.loc["cross"]
    assert c["replans"] == 0 and abs(c["t_merge_actual_s"] - c["t_merge_planned_s"]) < 0.3
    assert res.summary["collisions"] == 0 and res.summary["collisions_geometric"] == 0

