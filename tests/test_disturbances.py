"""Disturbances: actuator lag against its closed-form step response, a constant force, measurement
noise that reaches the controller but not the plant, reproducible by seed, and the robust margin."""

import math

import numpy as np
import pytest

from nrtraffic import scenario
from nrtraffic.control import batch as kb
from nrtraffic.geometry import LanePath, segment_frames
from nrtraffic.scenario import ScenarioError
from nrtraffic.vehicle.params import preset
from runners.single import run_scenario

H = 0.005  # plant step [s]


def _kernel(x0, u0, n_steps, alpha=0.0, lag_s=0.0, force=(0.0, 0.0), noise_sd=None, seed=0, observer_s=0.0):
    """One vehicle on a straight road, barriers off, stepped one plant step per call; returns the
    (n_steps + 1, 6) plant states, the (n_steps, 2) actuators' outputs before each step and the
    (n_steps, 6) errors of the observer's estimate after each step (with ``observer_s`` > 0)."""
    p = preset("paper").as_array()
    path = LanePath.from_points([(-10.0, 0.0), (2000.0, 0.0)])
    X, U = np.array([x0], dtype=float), np.array([u0], dtype=float)
    prof = np.zeros((1, 5, 5))
    prof[0, :, 0] = np.arange(5) * 1e9
    prof[0, :, 2] = x0[2]
    cfg = np.zeros(kb.N_CFG)
    cfg[[kb.CFG_H, kb.CFG_HORIZON, kb.CFG_DT_PRED, kb.CFG_ALPHA, kb.CFG_DAMPING, kb.CFG_STEADY_AFTER,
         kb.CFG_PREDICTOR, kb.CFG_LAG_TAU, kb.CFG_FORCE_LONG, kb.CFG_FORCE_LAT, kb.CFG_OBSERVER_TAU]] = (
        H, 0.2, 0.1, alpha, 1e-6, 3.0, 1.0, lag_s, *force, observer_s)
    out = np.zeros((1, kb.N_OUT))
    out[0, kb.OUT_S] = x0[0] + 10.0
    act = np.zeros((1, 2))
    xe = X.copy()
    acc = kb.new_acc(1)
    rng = np.random.default_rng(seed)
    states, acts, errors = [X[0].copy()], [], []
    for k in range(n_steps):
        noise = np.zeros((1, 1, 0)) if noise_sd is None else rng.standard_normal((1, 1, kb.N_NOISE)) * noise_sd
        acts.append(act[0].copy())
        kb.advance(X, U, k * H, 1, cfg, p, p, np.array([-6.0, -0.78]), np.array([3.0, 0.78]), prof, np.zeros(1),
                   np.zeros(1), np.zeros(1, dtype=np.int64), np.array([0, len(path.s)], dtype=np.int64), path.xy,
                   path.s, segment_frames(path.xy, path.s), np.zeros(1, dtype=np.int64),
                   np.full(1, kb.NO_LEADER, dtype=np.int64), np.zeros((1, 6)), acc, out, noise, act, xe,
                   np.full((1, 2), np.nan))
        states.append(X[0].copy())
        errors.append(xe[0] - X[0])
    return np.array(states), np.array(acts), np.array(errors)


def test_actuator_lag_is_the_first_order_step_response():
    """A step of the command (the tracker frozen: alpha = 0) from a lag at rest: the acceleration
    the plant receives over step k is a (1 - exp(-t_k / tau)), read from the speed it gains; the
    steering's lag follows d (1 - exp(-t_k / tau))."""
    tau, a0 = 0.3, 1.2
    x, act, _ = _kernel([0.0, 0.0, 10.0, 0.0, 0.0, 0.0], [a0, 0.0], 300, lag_s=tau)
    t = H * np.arange(300)
    assert np.allclose(np.diff(x[:, 2]) / H, a0 * (1.0 - np.exp(-t / tau)), rtol=0.0, atol=1e-9)
    assert np.allclose(act[:, 0], a0 * (1.0 - np.exp(-t / tau)), rtol=0.0, atol=1e-12)
    d0 = 0.01
    _, act, _ = _kernel([0.0, 0.0, 10.0, 0.0, 0.0, 0.0], [0.0, d0], 300, lag_s=tau)
    assert np.allclose(act[:, 1], d0 * (1.0 - np.exp(-t / tau)), rtol=0.0, atol=1e-14)
    # no lag: the command acts at once
    x, _, _ = _kernel([0.0, 0.0, 10.0, 0.0, 0.0, 0.0], [a0, 0.0], 50)
    assert np.allclose(np.diff(x[:, 2]) / H, a0, rtol=0.0, atol=1e-9)


def test_a_constant_force_adds_to_the_plants_acceleration():
    x, _, _ = _kernel([0.0, 0.0, 10.0, 0.0, 0.0, 0.0], [1.0, 0.0], 100, force=(-0.49, 0.0))  # 5 % uphill
    assert np.allclose(np.diff(x[:, 2]) / H, 1.0 - 0.49, rtol=0.0, atol=1e-9)
    x, _, _ = _kernel([0.0, 0.0, 10.0, 0.0, 0.0, 0.0], [0.0, 0.0], 1, force=(0.0, 0.3))  # cross wind
    assert (x[1, 3] - x[0, 3]) / H == pytest.approx(0.3, abs=1e-12)


def test_noise_reaches_the_controller_not_the_plant():
    """With the tracker frozen the plant runs exactly as without noise (the plant is exact); with
    the tracker on, what it commands changes."""
    sd = np.array([0.05, 0.05, 0.1, 0.1, 0.005, 0.05, 0.05, 0.1, 0.1])
    x0 = [0.0, 0.1, 10.0, 0.0, 0.0, 0.0]
    frozen_clean, _, _ = _kernel(x0, [0.3, 0.0], 100)
    frozen_noisy, _, _ = _kernel(x0, [0.3, 0.0], 100, noise_sd=sd)
    assert np.array_equal(frozen_clean, frozen_noisy)
    clean, _, _ = _kernel(x0, [0.3, 0.0], 100, alpha=100.0)
    noisy, _, _ = _kernel(x0, [0.3, 0.0], 100, alpha=100.0, noise_sd=sd)
    assert not np.allclose(clean, noisy, rtol=0.0, atol=1e-6)
    assert np.array_equal(noisy, _kernel(x0, [0.3, 0.0], 100, alpha=100.0, noise_sd=sd)[0])


@pytest.mark.parametrize("key, value", [("position_noise_m", -0.1), ("actuator_lag_s", float("inf")),
                                        ("longitudinal_accel_mps2", 9.81)])
def test_bad_disturbances_are_refused_by_name(tmp_path, key, value):
    from conftest import SCENARIOS

    with pytest.raises(ScenarioError, match=f"disturbances.{key}"):
        scenario.load(SCENARIOS / "paper_cbf" / "scenario.toml", [f"disturbances.{key}={value}"])


def test_noisy_runs_repeat_by_seed_and_the_margins_are_kept(tmp_path):
    """The paper's barrier experiment under noise: the same seed gives the same run, another seed
    another; with the barriers' margins (no noise) the centre distance stays above d0 + margin and
    the lateral deviation below y_max - margin."""
    from conftest import SCENARIOS

    path = SCENARIOS / "paper_cbf" / "scenario.toml"
    noise = ["disturbances.position_noise_m=0.05", "disturbances.speed_noise_mps=0.1",
             "disturbances.heading_noise_rad=0.005"]
    runs = [run_scenario(scenario.load(path, noise), tmp_path / "a", duration_s=60.0, seed=3),
            run_scenario(scenario.load(path, noise), tmp_path / "b", duration_s=60.0, seed=3),
            run_scenario(scenario.load(path, noise), tmp_path / "c", duration_s=60.0, seed=4)]
    key = ["max_tracking_error_m", "min_center_distance_m", "max_lateral_dev_m"]
    a, b, c = ([r.summary[k] for k in key] for r in runs)
    assert a == b and a != c
    margin = 0.3
    sc = scenario.load(path, ["barriers.gap_margin_m=0.3", "barriers.lateral_margin_m=0.05"])
    d0 = sc.barriers.min_gap_m + sc.vehicle.params().length
    clean = run_scenario(sc, tmp_path / "m").summary
    assert clean["min_center_distance_m"] >= d0 + margin - 0.05
    assert clean["max_lateral_dev_m"] <= sc.barriers.max_lateral_dev_m - 0.05 + 1e-9
    assert math.isfinite(clean["min_center_distance_m"])


def test_the_robustness_study_plans_every_level_of_both_scenarios(tmp_path):
    """``nrtraffic robustness``: every level's settings load (a bad key would stop it before any
    run), every (scenario, level, seed) is one run directory, and no two levels share a
    configuration."""
    from runners.robustness import LEVELS, STUDY, jobs

    todo = jobs(tmp_path)
    assert len(todo) == len(LEVELS) * (5 + 3)
    assert len({j.run_dir for j in todo}) == len(todo)
    for name, _, _, _ in STUDY:
        mine = [j for j in todo if dict(j.point)["scenario.name"] == name and j.seed == 1]
        assert len({j.fingerprint for j in mine}) == len(LEVELS)


def test_observer_filters_noise_as_its_closed_form():
    """Noise on x alone: the estimate's error obeys e <- (1 - K) e + K n with K = h / tau (the model
    steps of estimate and plant cancel on a straight cruise), whose stationary standard deviation
    is sigma sqrt(K / (2 - K)). Without noise the estimate stays on the state exactly."""
    sigma, tau = 0.1, 0.05
    sd = np.zeros(kb.N_NOISE)
    sd[kb.NZ_X] = sigma
    cruise = [0.0, 0.0, 10.0, 0.0, 0.0, 0.0]
    e = _kernel(cruise, [0.0, 0.0], 20000, noise_sd=sd, observer_s=tau)[2][1000:, 0]
    k = H / tau
    assert e.std() == pytest.approx(sigma * math.sqrt(k / (2.0 - k)), rel=0.05)
    assert abs(e.mean()) < 3.0 * sigma * math.sqrt(k / (2.0 - k)) / math.sqrt(len(e) * k)
    assert np.all(_kernel(cruise, [0.0, 0.0], 500, noise_sd=np.zeros(kb.N_NOISE), observer_s=tau)[2] == 0.0)


def test_an_observer_without_noise_changes_nothing(tmp_path):
    from conftest import SCENARIOS

    path = SCENARIOS / "cross4" / "scenario.toml"
    a = run_scenario(scenario.load(path), tmp_path / "a", duration_s=60.0).summary
    b = run_scenario(scenario.load(path, ["disturbances.observer_time_s=0.05"]), tmp_path / "b",
                     duration_s=60.0).summary
    for k in ("max_tracking_error_m", "max_lateral_dev_m", "min_center_distance_m", "mean_fuel_ml", "mean_delay_s"):
        assert a[k] == b[k]
