import pytest

from nrtraffic.planning.coordinator import Coordinator, CoordinatorSettings, ScheduleInfeasible
from nrtraffic.planning.profiles import PlanBounds


def test_fifo_merge_times_on_one_lane_by_hand():
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=10.0, min_merge_headway_s=4.0), PlanBounds())
    D, v = 400.0, 13.4
    a1 = c.schedule("a", "L", 0.0, v, D)
    a2 = c.schedule("b", "L", 2.0, v, D)
    a3 = c.schedule("c", "L", 20.0, v, D)
    a4 = c.schedule("d", "other", 2.5, v, D)
    # hand-computed: free arrival t0 + D / v0; headway max(4 s, 10 m / v_m)
    assert a1.t_merge == pytest.approx(D / v) and a1.binding == "earliest"
    assert a2.t_merge == pytest.approx(D / v + 4.0) and a2.binding == "rear_end" and a2.predecessor == "a"
    assert a3.t_merge == pytest.approx(20.0 + D / v) and a3.binding == "earliest"
    assert a4.t_merge == pytest.approx(2.5 + D / v) and a4.predecessor is None
    # the car held back slows down and arrives at the speed the closed form gives
    T = a2.t_merge - 2.0
    assert a2.profile.v_m == pytest.approx((3 * D / T - v) / 2)


def test_distance_spacing_binds_at_low_merge_speed():
    c = Coordinator(CoordinatorSettings(rear_end_spacing_m=30.0, min_merge_headway_s=0.0), PlanBounds())
    a1 = c.schedule("a", "L", 0.0, 5.0, 100.0)
    a2 = c.schedule("b", "L", 0.5, 5.0, 100.0)
    assert a2.t_merge == pytest.approx(a1.t_merge + 30.0 / a1.profile.v_m)


def test_unmeetable_schedule_is_reported():
    c = Coordinator(CoordinatorSettings(min_merge_headway_s=500.0), PlanBounds())
    c.schedule("a", "L", 0.0, 13.4, 400.0)
    with pytest.raises(ScheduleInfeasible, match="vehicle b"):
        c.schedule("b", "L", 1.0, 13.4, 400.0)
