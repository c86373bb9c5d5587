"""SUMO integration: poses pushed with moveToXY are the poses SUMO reports, with the true speed."""

import math

import numpy as np
import pytest

from nrtraffic.sumo.adapter import SumoSession, VehicleType, heading_from_nav, nav_angle, write_routes

R = 430.0 / (math.pi / 6)


def test_nav_angle_round_trip():
    for psi in np.linspace(-3.1, 3.1, 25):
        assert heading_from_nav(nav_angle(psi)) == pytest.approx(psi, abs=1e-12)
    assert nav_angle(0.0) == 90.0 and nav_angle(math.pi / 2) == 0.0


@pytest.mark.parametrize("sublane_m", [0.0, 0.25])
def test_pushed_pose_and_speed_are_what_sumo_reports(tmp_path, paper_curved_path, sublane_m):
    """With or without SUMO's sublane model (``keepRoute=3`` places exactly either way)."""
    net = paper_curved_path.parent / "curved.net.xml"
    routes = tmp_path / "r.rou.xml"
    write_routes(routes, VehicleType(), {"main": ("lead_in", "road", "exit")}, [("v", "main", 0.0, 13.4)])
    with SumoSession(net, routes, 0.1, 7, lateral_resolution_m=sublane_m, tripinfo=tmp_path / "ti.xml") as sumo:
        sumo.step()
        assert "v" in sumo.departed() and "v" in sumo.vehicle_ids()
        sumo.take_over("v")
        rng = np.random.default_rng(0)
        for k in range(40):
            s = 20.0 + 9.0 * k  # along the arc [m]
            lat = rng.uniform(-0.6, 0.6)
            dpsi = rng.uniform(-0.1, 0.1)
            th = s / R
            cx, cy = R * math.sin(th), R * (1 - math.cos(th))
            nx, ny = -math.sin(th), math.cos(th)
            x, y, psi = cx + lat * nx, cy + lat * ny, th + dpsi
            speed = rng.uniform(2.0, 19.0)
            sumo.push_pose("v", x, y, psi, speed)
            sumo.step()
            xs, ys, psis = sumo.front_pose("v")
            assert xs == pytest.approx(x, abs=1e-3) and ys == pytest.approx(y, abs=1e-3)
            assert psis == pytest.approx(psi, abs=1e-4)
            assert sumo.speed("v") == pytest.approx(speed, abs=1e-6)
            assert sumo.collisions() == []
            # the batched read reports the same as the single getters
            tab = sumo.snapshot()
            k = tab.row["v"]
            assert (tab.x[k], tab.y[k], tab.psi[k]) == pytest.approx((xs, ys, psis), abs=1e-12)
            assert (tab.lane[k], tab.lane_pos[k]) == sumo.lane_position("v")
            assert tab.speed[k] == sumo.speed("v") and tab.accel[k] == sumo.acceleration("v")
        # handed back, SUMO drives it to the end of its route
        sumo.release("v")
        for _ in range(400):
            sumo.step()
            if sumo.pending() == 0:
                break
        assert sumo.pending() == 0


@pytest.mark.parametrize("sublane_m", [0.0, 0.25])
def test_pushed_left_turn_keeps_route_and_exact_pose(tmp_path, sublane_m):
    """A vehicle placed off the lane centre along cross4's left turn N -> E, through both pieces of
    its internal lane: SUMO reports the pose pushed (not the lane centre), keeps it on its route's
    lanes, and, released, drives it out on its own route."""
    from conftest import SCENARIOS

    net = SCENARIOS / "cross4" / "net.net.xml"
    routes = tmp_path / "r.rou.xml"
    write_routes(routes, VehicleType(), {"l": ("N_in", "E_out")}, [("v", "l", 0.0, 10.0)])
    with SumoSession(net, routes, 0.1, 3, lateral_resolution_m=sublane_m, tripinfo=tmp_path / "ti.xml") as sumo:
        lanes = sumo.route_lanes(("N_in", "E_out"))
        pts = np.concatenate([np.asarray(shape) for _, shape, _ in lanes])
        seg = np.hypot(*np.diff(pts, axis=0).T)
        s_pts = np.concatenate([[0.0], np.cumsum(seg)])
        sumo.step()
        sumo.departed()
        sumo.take_over("v")
        n_in = len(lanes[0][1])  # points of the approach lane; the turn starts at its end
        s_turn = s_pts[n_in - 1]
        seen = set()
        for k, s in enumerate(np.arange(s_turn - 40.0, s_turn + 60.0, 0.8)):
            x0, y0 = np.interp(s, s_pts, pts[:, 0]), np.interp(s, s_pts, pts[:, 1])
            x1, y1 = np.interp(s + 0.5, s_pts, pts[:, 0]), np.interp(s + 0.5, s_pts, pts[:, 1])
            psi = math.atan2(y1 - y0, x1 - x0)
            lat = 0.5 * math.sin(0.3 * k)  # off the centre line by up to 0.5 m, either side
            x, y = x0 - lat * math.sin(psi), y0 + lat * math.cos(psi)
            sumo.push_pose("v", x, y, psi, 8.0)
            sumo.step()
            xs, ys, psis = sumo.front_pose("v")
            assert (xs, ys) == pytest.approx((x, y), abs=1e-3) and psis == pytest.approx(psi, abs=1e-4)
            lane, _ = sumo.lane_position("v")
            assert lane in {ln for ln, _, _ in lanes}
            seen.add(lane)
        assert sum(ln.startswith(":") for ln in seen) == 2  # both pieces of the turn were driven
        sumo.release("v")
        for _ in range(600):
            sumo.step()
            if sumo.pending() == 0:
                break
        assert sumo.pending() == 0 and sumo.collisions() == []
    import xml.etree.ElementTree as ET

    trip = ET.parse(tmp_path / "ti.xml").getroot().find("tripinfo")
    assert trip.get("arrivalLane") == "E_out_0"


def test_route_lanes_include_internal_lanes(tmp_path, paper_curved_path):
    net = paper_curved_path.parent / "curved.net.xml"
    routes = tmp_path / "r.rou.xml"
    write_routes(routes, VehicleType(), {"main": ("lead_in", "road", "exit")}, [])
    with SumoSession(net, routes, 0.1, 1) as sumo:
        lanes = [lane for lane, _, _ in sumo.route_lanes(("lead_in", "road", "exit"))]
    assert lanes[0] == "lead_in_0" and lanes[-1] == "exit_0"
    assert "road_0" in lanes and any(lane.startswith(":") for lane in lanes)


def test_one_session_per_process(tmp_path, paper_curved_path):
    from nrtraffic.sumo.adapter import SumoError

    net = paper_curved_path.parent / "curved.net.xml"
    routes = tmp_path / "r.rou.xml"
    write_routes(routes, VehicleType(), {"main": ("lead_in", "road", "exit")}, [])
    with SumoSession(net, routes, 0.1, 1):
        with pytest.raises(SumoError, match="already running"):
            SumoSession(net, routes, 0.1, 1).start()


def test_a_new_simulation_reads_none_of_the_last_ones_vehicles(tmp_path):
    """A sweep's worker runs one simulation after another in one process. libsumo keeps the
    last simulation's subscription results until the next one's first step: the snapshot of a
    new simulation must list only vehicles SUMO itself lists in it (none before its first step),
    or the own collision check finds the last run's queue standing at t = 0."""
    from conftest import ROOT

    net = ROOT / "sumo_scenarios" / "cross4" / "net.net.xml"
    routes = tmp_path / "r.rou.xml"
    write_routes(routes, VehicleType(), {"NS": ("N_in", "S_out"), "WE": ("W_in", "E_out")},
                 [(f"v{k}", "NS" if k % 2 else "WE", 2.0 * k, 13.89) for k in range(10)])
    with SumoSession(net, routes, 0.1, 1) as sumo:
        while sumo.time < 30.0:
            sumo.step()
            sumo.departed()  # (subscribes each)
        assert len(sumo.snapshot().ids) >= 5
    with SumoSession(net, routes, 0.1, 1) as sumo:
        for _ in range(40):
            assert set(sumo.snapshot().ids) <= set(sumo.vehicle_ids())
            sumo.step()
            sumo.departed()
        assert sumo.snapshot().ids


def test_split_internal_lanes_are_followed():
    """A left turn's internal lane comes in two pieces (:C_2_0 then :C_12_0 on cross4): both are on
    the path, and consecutive lanes join end to start."""
    from conftest import SCENARIOS

    net = SCENARIOS / "cross4" / "net.net.xml"
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        routes = Path(tmp) / "r.rou.xml"
        write_routes(routes, VehicleType(), {"l": ("N_in", "E_out")}, [])
        with SumoSession(net, routes, 0.1, 1) as sumo:
            lanes = sumo.route_lanes(("N_in", "E_out"))
    internal = [ln for ln, _, _ in lanes if ln.startswith(":")]
    assert len(internal) == 2
    for (_, a, _), (_, b, _) in zip(lanes, lanes[1:]):
        assert np.hypot(a[-1][0] - b[0][0], a[-1][1] - b[0][1]) < 0.01


def test_a_stop_too_close_to_brake_for_stops_the_vehicle_as_soon_as_it_can(tmp_path):
    """SUMO refuses a stop its driver can no longer brake for (13.9 m/s, 5 m ahead): the vehicle is
    told to stop as soon as it can instead, and does, within the distance SUMO's braking needs
    (13.9^2 / (2 x 4.5 m/s^2) = 21.4 m at SUMO's default deceleration, plus one step)."""
    from conftest import ROOT

    net = ROOT / "sumo_scenarios" / "cross4" / "net.net.xml"
    routes = tmp_path / "r.rou.xml"
    write_routes(routes, VehicleType(), {"NS": ("N_in", "S_out")}, [("v", "NS", 0.0, 13.89)])
    with SumoSession(net, routes, 0.1, 1) as sumo:
        while "v" not in sumo.vehicle_ids() or sumo.lane_position("v")[1] < 300.0:
            sumo.step()
        lane, pos = sumo.lane_position("v")
        sumo.stop_at("v", lane, pos + 5.0)  # (refused by SUMO: no exception reaches the caller)
        start = pos
        for _ in range(100):
            sumo.step()
        lane2, pos2 = sumo.lane_position("v")
        assert sumo.speed("v") == pytest.approx(0.0, abs=1e-6)
        assert lane2 == lane and 5.0 < pos2 - start < 13.89**2 / (2 * 4.5) + 13.89 * 0.1 + 1.0
        sumo.cancel_stop("v")  # nothing to drop: no error either


def _platoon_speeds(tmp_path, tau_s, spacing_m, v_mps):
    """SUMO alone (its own binary) drives two cars of nrtraffic's type with desired headway
    ``tau_s`` on a straight 1 km road, inserted ``spacing_m`` apart centre to centre at ``v_mps``:
    the follower's speeds [m/s] over 30 s, from SUMO's FCD output (None where SUMO could not insert
    it at that spacing)."""
    import subprocess
    import xml.etree.ElementTree as ET

    from nrtraffic.sumo.netbuild import build_network, sumo_binary

    tmp_path.mkdir()
    (tmp_path / "n.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/><node id="b" x="1000" y="0"/></nodes>')
    (tmp_path / "e.edg.xml").write_text(f'<edges><edge id="r" from="a" to="b" numLanes="1" speed="{v_mps}"/></edges>')
    net = build_network(tmp_path / "n.nod.xml", tmp_path / "e.edg.xml", tmp_path / "r.net.xml")
    vt = VehicleType(max_speed_mps=v_mps, tau_s=tau_s)
    (tmp_path / "r.rou.xml").write_text(
        f'<routes>{vt.xml()}<route id="r" edges="r"/>'
        f'<vehicle id="lead" type="auto" route="r" depart="0" departPos="{60.0 + spacing_m}" departSpeed="{v_mps}"/>'
        f'<vehicle id="follow" type="auto" route="r" depart="0" departPos="60" departSpeed="{v_mps}"/></routes>')
    fcd = tmp_path / "fcd.xml"
    subprocess.run([sumo_binary("sumo"), "-n", str(net), "-r", str(tmp_path / "r.rou.xml"), "--step-length", "0.1",
                    "--end", "30", "--fcd-output", str(fcd), "--no-step-log", "true", "--no-warnings", "true",
                    "--max-depart-delay", "0"], check=True, capture_output=True)
    speeds = [float(v.get("speed")) for ts in ET.parse(fcd).getroot() for v in ts if v.get("id") == "follow"]
    return speeds or None


@pytest.mark.parametrize("spacing_m, v_mps", [(13.89, 13.89), (12.0, 12.0), (12.0, 6.5)])
def test_sumo_keeps_the_planned_spacing_of_a_released_platoon(tmp_path, spacing_m, v_mps):
    """Released past the merging zone, consecutive cars of a lane are max(delta, h_min v) apart
    (delta = 12 m, h_min = 1 s): 13.89 m at 13.89 m/s, 12 m at 12 m/s (where the two meet, the
    tightest case) and at a turn's 6.5 m/s. With handover_tau_s, SUMO's own Krauss driver keeps
    that spacing at constant speed (SUMO's output); with SUMO's default tau = 1 s it cannot: it
    refuses to insert the follower that close at that speed (Krauss: speed kept only while the gap
    less minGap is at least tau v)."""
    from nrtraffic.sumo.adapter import handover_tau_s

    tau = handover_tau_s(12.0, 1.0, 4.8, 2.5, 13.89, 0.1)
    assert 0.1 <= tau < 1.0
    kept = _platoon_speeds(tmp_path / "short", tau, spacing_m, v_mps)
    assert kept is not None and min(kept) >= v_mps - 1e-6
    # Krauss' condition by hand: gap less minGap >= tau v
    assert spacing_m - 4.8 - 2.5 >= tau * v_mps
    if spacing_m - 4.8 - 2.5 < 1.0 * v_mps:
        default = _platoon_speeds(tmp_path / "default", 1.0, spacing_m, v_mps)
        assert default is None or min(default) < v_mps - 0.5


def test_handover_tau_by_hand():
    """0.9 of min over v of (max(delta, h v) - L - minGap) / v: at v = delta / h = 12 m/s,
    (12 - 7.3) / 12 = 0.3917 s, so 0.3525 s; without h_min (delta = 10 m at every speed), at
    v_max = 13.89 m/s: 0.9 (10 - 7.3) / 13.89 = 0.1749 s; never below one step, never above 1 s."""
    from nrtraffic.sumo.adapter import handover_tau_s

    assert handover_tau_s(12.0, 1.0, 4.8, 2.5, 13.89, 0.1) == pytest.approx(0.9 * 4.7 / 12.0)
    assert handover_tau_s(10.0, 0.0, 4.8, 2.5, 13.89, 0.1) == pytest.approx(0.9 * 2.7 / 13.89)
    assert handover_tau_s(8.0, 0.0, 4.8, 2.5, 13.89, 0.1) == 0.1
    assert handover_tau_s(40.0, 3.0, 4.8, 2.5, 13.89, 0.1) == 1.0
