"""Calibration: a fit on a log driven by a known car recovers its constants; stretches skip what is not driving."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from racerlab.calibrate import constant_velocity_errors, errors, fit_car, medians, split, stretches
from racerlab.calibrate.data import HISTORY
from racerlab.calibrate.fit import _searched, median_interval
from racerlab.errors import ConfigError
from racerlab.sim.car import rollout
from racerlab.spec import STEP_S, car_params

TRUE = car_params("droa", delay_steps=1.4, steer_tau_s=0.2, yaw_gain=0.55, slide_mps=2.0, yaw_tau_s=0.0,
                  speed_tau_s=0.05, accel_mps2=4.0, brake_mps2=6.0, ground_factor=1.05)


def synthetic_log(car, episodes=6, steps=160, seed=0) -> pd.DataFrame:
    """Simtrace rows of `car` driving random held actions (each held 3-8 steps, as a policy's runs are) from a
    standstill; jittered step lengths like the real simulator's, stamped as DRoA does: a row's pose belongs to the
    previous row's tstamp (the step from row j to j + 1 lasts tstamp_j - tstamp_{j-1})."""
    rng = np.random.default_rng(seed)
    rows = []
    for ep in range(episodes):
        acts, n = [], 0
        while n < steps:
            k = int(rng.integers(3, 9))
            acts += [[float(rng.choice([-30, -20, -10, 0, 10, 20, 30])), float(rng.choice([0.8, 1.4, 2.0, 2.6]))]] * k
            n += k
        acts = np.array(acts[:steps])
        dts = rng.uniform(0.055, 0.078, steps)
        dts *= STEP_S / dts.mean()
        start = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 0.0, "steering_angle": 0.0, "yaw_rate": 0.0}
        path = rollout(start, acts, history=[[0.0, 0.0]], car=car, dt=dts)
        poses = np.vstack([[0.0, 0.0, 0.0], path[:-1]])
        t = np.cumsum(dts)
        for j in range(steps):
            rows.append({"unique_episode": ep, "steps": j + 1, "x": poses[j, 0], "y": poses[j, 1], "yaw": poses[j, 2],
                         "steering_angle": acts[j, 0], "speed": acts[j, 1], "tstamp": t[j],
                         "episode_status": "prepare" if j == 0 else "in_progress"})
    return pd.DataFrame(rows)


def test_a_fit_recovers_the_car_that_drove_the_log():
    st = stretches(synthetic_log(TRUE), every=2)
    fit_st, held = split(st)
    start = car_params("droa")  # the default car: far from TRUE in delay, lag, gain, slide and traction
    car = fit_car(fit_st, start)
    assert car.delay_steps == pytest.approx(1.4, abs=0.1)
    # the hinge's lag and the yaw rate's are two first-order lags in a row on the way from the command to the turn:
    # the logs tell their sum, not how it divides
    assert car.steer_tau_s + car.yaw_tau_s == pytest.approx(0.2, abs=0.03)
    # the turn at the log's speeds: the yaw gain and the slide together (on held actions the hinge's kick at each
    # command change trades a little against the gain: the fit may use some of it)
    assert car.yaw_gain_at(1.4) == pytest.approx(TRUE.yaw_gain_at(1.4), rel=0.08)
    assert car.accel_mps2 == pytest.approx(4.0, rel=0.15)
    assert car.ground_factor == pytest.approx(1.05, abs=0.01)
    # and it predicts the held-out episodes almost exactly, far better than the constant-velocity guess
    err = medians(errors(held, car))
    assert err[15] < 0.03
    assert err[15] < 0.2 * medians(constant_velocity_errors(held))[15]
    assert medians(errors(held, start))[15] > 5 * err[15]


def test_a_fit_finds_the_front_drive_and_searches_it_only_for_a_car_that_has_it():
    """The console velocity car with its driven front wheels at 0.8 drives the log; from 0.3 the fit finds 0.8 within
    10 %, and predicts the held-out episodes to a centimetre where the car without the front drive is 15 cm off. The
    droa car (no front drive) does not search it."""
    from dataclasses import replace

    from racerlab.calibrate.fit import _searched

    true = replace(car_params("console", "5"), front_drive=0.8)
    fit_st, held = split(stretches(synthetic_log(true), every=2))
    car = fit_car(fit_st, replace(true, front_drive=0.3))
    assert car.front_drive == pytest.approx(0.8, rel=0.1)
    assert medians(errors(held, car))[15] < 0.02 < 0.1 < medians(errors(held, replace(true, front_drive=0.0)))[15]
    assert "front_drive" in _searched(true) and "front_drive" not in _searched(car_params("droa"))


def test_stretches_leave_out_prepare_pause_and_jumps():
    df = synthetic_log(TRUE, episodes=1, steps=60)
    n_all = len(stretches(df, horizon=15))
    assert n_all == 60 - 15 - (HISTORY + 1)  # every start with a full history after the prepare row
    df.loc[30, "episode_status"] = "pause"
    df.loc[45, ["x", "y"]] = [50.0, 50.0]  # an evaluation reset
    st = stretches(df, horizon=15)
    assert 0 < len(st) < n_all
    rows = np.round(st.start[:, 0], 9)
    assert not np.isin(np.round(df["x"].to_numpy()[25:47], 9), rows).any()  # no stretch touches rows 30 or 45


def test_a_log_without_simtrace_columns_is_one_line():
    with pytest.raises(ConfigError, match="no 'tstamp' column"):
        stretches(pd.DataFrame({"x": [0.0], "y": [0.0], "yaw": [0.0], "steering_angle": [0.0], "speed": [1.0],
                                "steps": [1]}), source="my.csv")


def test_the_step_timing_rule_matters_and_the_right_one_fits_best():
    """The same log read by the naive rule (step j -> j + 1 lasts tstamp_{j+1} - tstamp_j) is one step off in
    time: the true car replays it far worse after one step than read by DRoA's own rule (what is left read right is
    the start's estimated speed and wheel angle)."""
    log = synthetic_log(TRUE, episodes=3)
    err = {rule: medians(errors(stretches(log, every=3, timing=rule), TRUE)) for rule in ("previous", "next", "fixed")}
    assert err["previous"][1] < 0.002
    assert err["next"][1] > 10 * err["previous"][1] and err["fixed"][1] > 10 * err["previous"][1]
    assert err["previous"][15] < 0.5 * min(err["next"][15], err["fixed"][15])


def test_the_folds_of_split_hold_out_every_episode_once():
    st = stretches(synthetic_log(TRUE, episodes=7, steps=40), every=5)
    assert set(st.episode) == set(range(7))
    held = [set(split(st, fold=r)[1].episode) for r in range(3)]
    # the default split holds out episodes 1 and 4 (every third from the 2nd); folds 0 and 2 the others
    assert held == [{0, 3, 6}, {1, 4}, {2, 5}]
    assert set(split(st)[1].episode) == {1, 4}
    for r in range(3):
        fit, out = split(st, fold=r)
        assert len(fit) + len(out) == len(st) and not set(fit.episode) & set(out.episode)
    with pytest.raises(ValueError, match="fold 3"):
        split(st, fold=3)


def _short_log(steps=None) -> pd.DataFrame:
    """Eleven rows: 0.1 m a step, then the last two steps before row 9 of 0.09 and 0.11 m turning 2° and 3°; the
    step from row 8 to row 9 stamped 0.08 s (read by the "previous" rule: tstamp_8 - tstamp_7)."""
    x = [0.1 * j for j in range(8)] + [0.79, 0.90, 1.00]
    yaw = [0.0] * 8 + [2.0, 5.0, 7.0]
    t = np.cumsum([0.0] + [STEP_S] * 7 + [0.08, STEP_S, STEP_S])
    return pd.DataFrame({"episode": 0, "x": x, "y": 0.0, "yaw": yaw, "steering_angle": 0.0, "speed": 1.5, "tstamp": t,
                         "steps": steps or list(range(1, 12)), "episode_status": ["prepare"] + ["in_progress"] * 10})


def test_logs_of_unknown_step_lengths_measure_the_start_over_two_steps():
    """Read by the "fixed" rule (the 2022 effort logs: every step 1/15 s, the real ones unknown) the start's speed and
    yaw rate are the differences over the last two steps: (0.09 + 0.11) m and (2 + 3)° over 2/15 s = 1.5 m/s and
    37.5 °/s; by the "previous" rule (lengths known) over the last step: 0.11 m and 3° over 0.08 s. Where the step
    before the last is not usable (a gap in the step count), the last step alone: 0.11 m x 15 = 1.65 m/s. The
    constant-velocity guess keeps the last step."""
    fixed = stretches(_short_log(), horizon=1, timing="fixed")
    assert len(fixed) == 1
    assert fixed.start[0, 3] == pytest.approx(1.5) and fixed.mean_dt[0] == pytest.approx(2 * STEP_S)
    assert np.degrees(fixed.start[0, 5]) == pytest.approx(37.5)
    assert fixed.prev[0, 0] == pytest.approx(0.79) and fixed.prev_dt[0] == pytest.approx(STEP_S)
    known = stretches(_short_log(), horizon=1, timing="previous")
    assert known.start[0, 3] == pytest.approx(0.11 / 0.08) and known.mean_dt[0] == pytest.approx(0.08)
    assert np.degrees(known.start[0, 5]) == pytest.approx(3.0 / 0.08)
    gap = stretches(_short_log(steps=list(range(1, 9)) + [10, 11, 12]), horizon=1, timing="fixed")
    assert gap.start[0, 3] == pytest.approx(1.65) and gap.mean_dt[0] == pytest.approx(STEP_S)


def test_rollout_measures_the_start_by_the_logs_rule():
    """rollout with tstamps gives the start's `mean_speed` the window `racerlab calibrate` measures it over: the last
    step (velocity logs) or the last two (the effort logs' "fixed" rule). A car that keeps accelerating at 3 m/s²
    (fade, lags and delay off) whose mean speed over the window was 1.0 m/s is now at 1.0 + 3 x window / 2: after
    one step it has gone (1.0 + 3 x 0.1) x 1/15 + 1.5 / 225 m on a window of 2/15 s, (1.0 + 3 / 30) / 15 + 1.5 / 225
    on one of 1/15 s."""
    t = [0.0, STEP_S, 2 * STEP_S, 3 * STEP_S]  # two history rows, the start, one row after
    hist, acts = [[0.0, 4.0], [0.0, 4.0]], [[0.0, 4.0]]
    start = {"x": 0.0, "y": 0.0, "heading": 0.0, "mean_speed": 1.0, "steering_angle": 0.0}
    for version, window in (("4", 2 * STEP_S), ("5", STEP_S)):
        car = car_params("console", version, delay_steps=0.0, steer_tau_s=0.0, steer_kick=0.0, yaw_tau_s=0.0,
                         speed_tau_s=0.0, accel_mps2=3.0, brake_mps2=30.0, accel_fade_mps=0.0, ground_factor=1.0,
                         wheel_cap_mps=4.0, regulated=True, substeps=1, tyre_sat_mps2=0.0, steer_offset_deg=0.0)
        x = rollout(start, acts, history=hist, car=car, tstamps=t)[0, 0]  # the front point, from 0
        v_now = 1.0 + 3.0 * window / 2
        assert x == pytest.approx((v_now + 1.5 * STEP_S) * STEP_S, rel=1e-9)


def test_the_wheel_offset_is_fitted_only_for_a_car_that_has_one():
    """A log driven by a car whose wheels point 1.2° left of the command: that car replays it (what is left is the
    start's estimated speed and wheel angle), the same car without the offset drifts right of it, 4 x farther; the
    fit searches the offset from a car that has one (the console effort car) and leaves it off for the others."""
    true = replace(TRUE, steer_offset_deg=1.2)
    st = stretches(synthetic_log(true, episodes=2), every=4)
    err = medians(errors(st, true))[15]
    assert err < 0.02 and medians(errors(st, replace(true, steer_offset_deg=0.0)))[15] > 4 * err
    assert "steer_offset_deg" in _searched(true) and "steer_offset_deg" not in _searched(TRUE)
    assert car_params("console", "4").steer_offset_deg != 0 and car_params("droa").steer_offset_deg == 0


def test_median_interval_resamples_episodes_not_stretches():
    # seven episodes of one stretch each, errors 1..7: the median of 7 draws is <= 1 with probability 0.010 and
    # <= 2 with 0.108 (at least 4 of 7 draws at or below it), so the 5 % quantile is 2; by symmetry the 95 % is 6
    assert median_interval(np.arange(1.0, 8.0), np.arange(7)) == (2.0, 6.0)
    # the same error everywhere: nothing to move
    assert median_interval(np.full(40, 0.08), np.repeat(np.arange(8), 5)) == (0.08, 0.08)
    # one long episode (100 stretches at 10) among four short ones (1 each): the pooled median is 10 whenever a
    # resample draws the long episode at all (1 - 0.8^5 = 67 %), else 1; taken stretch by stretch it would be 10
    err = np.r_[np.full(100, 10.0), np.ones(4)]
    eps = np.r_[np.zeros(100, int), np.arange(1, 5)]
    assert median_interval(err, eps) == (1.0, 10.0)


def test_median_interval_needs_five_episodes():
    lo, hi = median_interval(np.linspace(0.05, 0.2, 40), np.repeat(np.arange(4), 10))
    assert np.isnan(lo) and np.isnan(hi)
