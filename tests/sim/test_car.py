"""The car model (issue 24): hand-worked step responses, each built-in car's structure, rollout against the
simulator, step jitter."""

import math
from dataclasses import replace

import numpy as np
import pytest

from racerlab.errors import ConfigError
from racerlab.sim import Simulator, World
from racerlab.sim.car import LOG_TIMING, advance, log_timing, pack, rollout, step_durations, step_lengths
from racerlab.spec import (
    CAR_TABLE,
    MODEL_POINT_AHEAD_M,
    STEP_LENGTHS,
    STEP_S,
    WHEELBASE_M,
    CarParams,
    car_params,
    control_of,
)

DT = STEP_S


def bare(**kw) -> CarParams:
    """A car with one mechanism at a time: no delay, no lags, full steering, no slide, instant traction."""
    base = dict(delay_steps=0.0, steer_tau_s=0.0, yaw_gain=1.0, slide_mps=0.0, yaw_tau_s=0.0, speed_tau_s=0.0,
                accel_mps2=1000.0, brake_mps2=1000.0, ground_factor=1.0, grip_mps2=1000.0, accel_fade_mps=0.0)
    return CarParams(**{**base, **kw})


def step(car, v=0.0, steer=0.0, w=0.0, old=(0.0, 0.0), new=(0.0, 0.0), dt=DT):
    """One `advance` from the origin heading east: (x, y, yaw, v, steer, w, beta)."""
    return advance(0.0, 0.0, 0.0, v, steer, w, old[0], old[1], new[0], new[1], False, pack(car), dt)


def test_hinge_is_a_first_order_lag():
    """A 20° step through τ = 0.167 s: 1 - exp(-dt/τ) of it after one step (ROS 2's 10 % per 1/60 s tick
    gives 1 - 0.9⁴ = 34 %, the exponential 33 %), whatever the sub-steps."""
    cmd = math.radians(20)
    for n in (1, 4, 9):
        s = step(bare(steer_tau_s=0.167, substeps=n), v=1.0, new=(cmd, 1.0))[4]
        assert s == pytest.approx(cmd * (1 - math.exp(-DT / 0.167)), rel=1e-9)
    assert 1 - math.exp(-DT / 0.167) == pytest.approx(0.329, abs=1e-3)


def test_traction_limits_the_acceleration_and_the_cap_the_speed():
    # standing start, command 2 m/s, accel 3.2 m/s² (ROS 1's measured limit): 3.2 / 15 = 0.2133 m/s after a step
    assert step(bare(accel_mps2=3.2), new=(0.0, 2.0))[3] == pytest.approx(3.2 / 15)
    # braking from 2 to 1 at 6 m/s²: 0.4 m/s less
    assert step(bare(brake_mps2=6.0), v=2.0, new=(0.0, 1.0))[3] == pytest.approx(1.6)
    # 4 m/s commanded: the wheels' 100 rad/s x 0.035 m = 3.5 m/s cap, times the 1.03 ground factor
    assert step(bare(ground_factor=1.03), v=3.0, new=(0.0, 4.0))[3] == pytest.approx(3.5 * 1.03)
    # effort control without a speed loop (droa, version 3-4): toward the cap whatever the command
    assert step(bare(regulated=False), v=1.0, new=(0.0, 1.0))[3] == pytest.approx(3.5)


def test_speed_lag_after_the_traction_limit():
    """τ_v = 0.1 s and no traction limit, one sub-step: 1 → 2 m/s gains (1 - e^(-2/3)) of the step."""
    v = step(bare(speed_tau_s=0.1, substeps=1), v=1.0, new=(0.0, 2.0))[3]
    assert v == pytest.approx(1.0 + (1 - math.exp(-DT / 0.1)))


def test_yaw_gain_and_slide_scale_the_turn():
    """Held wheels at 20°, 1 m/s: yaw rate v·κ, κ = g·tan δ / (L·√(1 + (g·tan δ / 2)²)); the slide halves g at
    slide_mps."""
    d = math.radians(20)
    for gain, slide, v in ((1.0, 0.0, 1.0), (0.6, 0.0, 1.0), (0.6, 1.5, 1.5), (0.6, 1.5, 3.0)):
        g = gain / (1 + (v / slide) ** 2) if slide else gain
        t = g * math.tan(d)
        kappa = t / (WHEELBASE_M * math.sqrt(1 + 0.25 * t * t))
        yaw = step(bare(yaw_gain=gain, slide_mps=slide), v=v, steer=d, new=(d, v))[2]
        assert yaw == pytest.approx(v * kappa * DT, rel=1e-9)
    # the grip caps v²κ: 3 m/s on full 30° lock with gain 1 would need 3²·1.78/0.164... the cap gives 4.9 / 9
    yaw = step(bare(grip_mps2=4.9), v=3.0, steer=math.radians(30), new=(math.radians(30), 3.0))[2]
    assert yaw == pytest.approx(4.9 / 3.0 * DT)


def test_tyres_saturate_toward_their_lateral_acceleration():
    """Held wheels at 20° (gain 1: κ_w = tan 20° / (0.164 · √(1 + tan² 20° / 4)) = 2.1835 1/m), 1.5 m/s:
    v²κ_w = 4.913 m/s². With tyre_sat_mps2 at that the curvature is κ_w / √2; at half of it κ_w / √5; the lateral
    acceleration stays below the saturation, and CarParams.unsaturated inverts it."""
    d, v = math.radians(20), 1.5
    t = math.tan(d)
    kw = t / (WHEELBASE_M * math.sqrt(1 + 0.25 * t * t))
    assert kw == pytest.approx(2.1835, abs=1e-4) and v * v * kw == pytest.approx(4.913, abs=1e-3)
    for sat, factor in ((v * v * kw, 1 / math.sqrt(2)), (v * v * kw / 2, 1 / math.sqrt(5))):
        car = bare(tyre_sat_mps2=sat)
        yaw = step(car, v=v, steer=d, new=(d, v))[2]
        assert yaw == pytest.approx(v * kw * factor * DT, rel=1e-9)
        assert v * v * kw * factor < sat
        assert float(car.saturated(kw, v)) == pytest.approx(kw * factor, rel=1e-12)
        assert float(car.unsaturated(kw * factor, v)) == pytest.approx(kw, rel=1e-9)
    assert float(bare().saturated(kw, v)) == kw  # 0: off


def test_the_driven_front_wheels_turn_the_car_while_the_speed_changes():
    """Wheels held at 20° (κ_w = 2.1835 1/m), front_drive 0.5, traction 3 m/s², one sub-step of 1/15 s: speeding up
    from 1 to 1.2 m/s (mid-step 1.1) adds 0.5 · 3 · sin 20° / 1.1² = 0.4240 1/m, braking from 2 to 1.8 (mid-step 1.9)
    takes 0.5 · 3 · sin 20° / 1.9² = 0.1421 1/m off, from a standstill (mid-step 0.1 m/s, counted as 1) it adds
    0.5130; a held speed, or front_drive 0, turns as the bicycle alone."""
    d, kw = math.radians(20), 2.1835
    car = bare(front_drive=0.5, accel_mps2=3.0, brake_mps2=3.0, substeps=1)
    for v0, cmd, v_mid, extra in ((1.0, 2.0, 1.1, 0.4240), (2.0, 1.0, 1.9, -0.1421), (0.0, 2.0, 0.1, 0.5130),
                                  (1.5, 1.5, 1.5, 0.0)):
        yaw = step(car, v=v0, steer=d, new=(d, cmd))[2]
        assert yaw == pytest.approx(v_mid * (kw + extra) * DT, rel=2e-4)
        off = step(replace(car, front_drive=0.0), v=v0, steer=d, new=(d, cmd))[2]
        assert off == pytest.approx(v_mid * kw * DT, rel=2e-4)
    assert step(car, v=1.0, steer=-d, new=(-d, 2.0))[2] == pytest.approx(-1.1 * (kw + 0.4240) * DT, rel=2e-4)


def test_the_wheels_point_the_offset_left_of_the_command():
    """steer_offset_deg 1°: commanded straight at 1 m/s the car bends left at κ = tan 1° / (0.164 · √(1 + tan² 1° / 4))
    = 0.10643 1/m, 0.0070955 rad a step; commanded 1° right it goes straight; 0 is the car without it."""
    car = bare(steer_offset_deg=1.0)
    yaw = step(car, v=1.0, new=(0.0, 1.0))[2]
    assert yaw == pytest.approx(0.0070955, rel=1e-4)
    right = math.radians(-1.0)
    assert step(car, v=1.0, steer=right, old=(right, 1.0), new=(right, 1.0))[2] == pytest.approx(0.0, abs=1e-15)
    assert step(bare(steer_offset_deg=0.0), v=1.0, new=(0.0, 1.0))[2] == 0.0
    with pytest.raises(ValueError, match="steer_offset_deg"):
        bare(steer_offset_deg=30.0)


def test_pure_pursuit_and_the_line_command_the_wheels_angle_less_the_offset():
    """A car whose wheels point 1.5° left of the command is asked for 1.5° less than one without, for the same
    pose (pure pursuit) and the same line point (the racing line's steering)."""
    from racerlab.line import racing_line
    from racerlab.sim.pursuit import PurePursuit

    cars = [car_params("console", "4", steer_offset_deg=0.0), car_params("console", "4", steer_offset_deg=1.5)]
    steer = []
    for car in cars:
        w = World("lab_oval", 1, car=car)
        steer.append(PurePursuit.on_centre_line(w.sim.track, car=car)(w.sim)[0])
    assert steer[1] == pytest.approx(steer[0] - 1.5, abs=1e-12)
    lines = [racing_line(World("lab_oval", 1).sim.track, car=car) for car in cars]
    assert lines[1].steering_deg - lines[0].steering_deg == pytest.approx(-1.5 + 0 * lines[0].steering_deg,
                                                                          abs=0.05)


def test_yaw_rate_lag():
    """With yaw_tau_s the yaw rate approaches the wheels' v·κ exponentially, so the first step turns less."""
    d = math.radians(20)
    t = math.tan(d)
    target = t / (WHEELBASE_M * math.sqrt(1 + 0.25 * t * t))
    w = step(bare(yaw_tau_s=0.1, substeps=1), v=1.0, steer=d, new=(d, 1.0))[5]
    assert w == pytest.approx(target * (1 - math.exp(-DT / 0.1)))


def test_delay_acts_late_and_fractions_split_the_step():
    """delay 2: a speed command acts from the second step after its row; delay 1.5: half of step 1 still on the
    old command, then the new one."""
    sim = Simulator("lab_oval", 1, bare(delay_steps=2.0, accel_mps2=3.0))
    sim.step(0.0, 0.0)  # prepare
    speeds = []
    for _ in range(4):
        sim.step(0.0, 2.0)
        speeds.append(float(sim.state.speed[0]))
    # rows 1 and 2 move on the prepare step's zero command (clipped to 0.1 m/s: reached at once), row 3 on row 1's
    assert speeds[0] == pytest.approx(0.1)
    assert speeds[1] == pytest.approx(0.1)
    assert speeds[2] == pytest.approx(0.1 + 3.0 / 15)
    half = step(bare(delay_steps=0.5, accel_mps2=3.0, substeps=4), v=0.0, old=(0.0, 0.0), new=(0.0, 2.0))[3]
    # first half toward 0.1 m/s (0.1 reached: 3 x 1/30 = 0.1 exactly), second half + 3 m/s² x 1/30 s
    assert half == pytest.approx(0.1 + 3.0 / 30)


@pytest.mark.parametrize("simulator,control", sorted(CAR_TABLE))
def test_each_built_in_car(simulator, control):
    """Each simulator's car for each control: no answer before its delay, the speed it settles at, the turn it
    holds at 1 m/s with 20°."""
    version = "5" if control == "velocity" else "4"
    car = car_params(simulator, version)
    assert (car.simulator, car.control) == (simulator, control)
    hold = [[0.0, 1.0]] * 6
    start = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 1.0 * car.ground_factor, "steering_angle": 0.0}
    d = int(car.delay_steps)
    turn = rollout(start, [[20.0, 1.0]] * 60, history=hold, car=car)
    assert np.all(np.abs(turn[:d, 2]) < 1e-9)  # the wheels have not moved yet
    assert abs(turn[d, 2]) > 0 or car.delay_steps == d  # a fractional delay turns within the next step
    speed = rollout(start, [[0.0, 2.0]] * 60, history=hold, car=car)
    settled = np.hypot(*(speed[-1, :2] - speed[-2, :2])) / STEP_S
    expect = car.ground_factor * (min(2.0, car.wheel_cap_mps) if car.regulated else car.wheel_cap_mps)
    expect = min(expect, car.top_speed())  # a fading acceleration runs out at the fade speed
    assert settled == pytest.approx(expect, rel=1e-3)
    # the held turn: heading gained per step once settled at 1 m/s (regulated cars)
    if car.regulated:
        v = car.ground_factor
        g = car.yaw_gain / (1 + (v / car.slide_mps) ** 2) if car.slide_mps else car.yaw_gain
        t = g * math.tan(math.radians(20 + car.steer_offset_deg))  # the wheels point the offset left of 20°
        kappa = t / (WHEELBASE_M * math.sqrt(1 + 0.25 * t * t))
        if car.tyre_sat_mps2:  # the tyres saturate: κ / √(1 + (v²κ / sat)²)
            kappa /= math.sqrt(1 + (v * v * kappa / car.tyre_sat_mps2) ** 2)
        kappa = min(kappa, car.grip_mps2 / v**2)
        per_step = (turn[-1, 2] - turn[-2, 2]) % 360
        assert per_step == pytest.approx(math.degrees(v * kappa * STEP_S), rel=1e-3)


def test_version_picks_the_control():
    assert control_of("5") == control_of(6) == "velocity"
    assert control_of("4") == control_of("3.0") == "effort"
    assert car_params("console", "4").control == "effort"
    with pytest.raises(ConfigError, match="simulator"):
        car_params("gazebo")
    with pytest.raises(ConfigError, match="yaw_gian"):
        car_params("droa", yaw_gian=0.5)


def test_rollout_matches_the_simulator_for_a_zero_delay_car():
    """Zero delay: rollout from a car's simtrace state with its actions lands where the simulator drives it."""
    car = car_params("droa", delay_steps=0.0)
    sim = Simulator("lab_oval", 1, car)
    sim.step(0.0, 0.0)  # prepare: the car stands
    s = sim.state
    start = {"x": float(s.model_x[0]), "y": float(s.model_y[0]), "heading": float(s.heading[0]), "speed": 0.0,
             "steering_angle": 0.0, "yaw_rate": 0.0}
    rng = np.random.default_rng(3)
    actions = np.column_stack([rng.uniform(-15, 15, 25), rng.uniform(0.5, 2.0, 25)])
    got = []
    for a in actions:
        sim.step(a[0], a[1])
        got.append([s.model_x[0], s.model_y[0], s.heading[0]])
    pred = rollout(start, actions, car=car)
    assert np.allclose(pred, np.array(got), atol=1e-9)


def test_rollout_history_feeds_the_delay():
    """With a delay of 2 the first two steps follow the history's last two actions: a history of a held 1 m/s
    straight keeps the car straight at 1 m/s for two steps whatever the new actions ask."""
    car = car_params("droa", delay_steps=2.0, yaw_tau_s=0.0)
    start = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": car.ground_factor, "steering_angle": 0.0}
    out = rollout(start, [[30.0, 3.0]] * 4, history=[[0.0, 1.0]] * 3, car=car)
    assert np.allclose(out[:2, 1], 0.0) and np.allclose(out[:2, 2], 0.0)
    assert out[:2, 0] == pytest.approx([car.ground_factor * STEP_S, 2 * car.ground_factor * STEP_S])
    assert out[2, 2] > 0.0  # the 30° command of row 0 acts in step 3


def test_front_point_is_the_model_point():
    out = rollout({"x": 1.0, "y": 2.0, "heading": 90.0, "speed": 1.0, "steering_angle": 0.0}, [[0.0, 1.0]],
                  car=car_params(delay_steps=0.0, ground_factor=1.0, speed_tau_s=0.0))
    assert out[0] == pytest.approx([1.0, 2.0 + STEP_S, 90.0])
    assert MODEL_POINT_AHEAD_M == 0.14


def test_step_jitter_is_seeded_and_measured():
    rng = np.random.default_rng(0)
    d = step_lengths(rng, 200_000, "droa")
    lo, hi = STEP_LENGTHS["droa"][0], STEP_LENGTHS["droa"][-1]
    assert lo <= d.min() and d.max() <= hi
    assert d.mean() == pytest.approx(STEP_S, rel=2e-3)  # the table is scaled to a 1/15 s mean
    a = Simulator("lab_oval", 4, car_params(step_jitter=True), seed=5)
    b = Simulator("lab_oval", 4, car_params(step_jitter=True), seed=5)
    c = Simulator("lab_oval", 4, car_params(step_jitter=False), seed=5)
    for _ in range(12):
        for sim in (a, b, c):
            sim.step(0.0, 1.5)
    assert np.array_equal(a.pose, b.pose)
    assert not np.allclose(a.pose, c.pose)
    assert len(set(np.round(a.state.progress, 9))) > 1  # cars draw their own steps


def test_world_takes_the_simulator_and_the_model_version():
    w = World("lab_oval", 1, {"action_space_type": "continuous", "version": "4",
                              "action_space": {"steering_angle": {"low": -30, "high": 30},
                                               "speed": {"low": 0.5, "high": 2}}}, car="console")
    assert w.sim.car_params.name.startswith("console, effort")
    assert World("lab_oval", 1).sim.car_params.simulator == "droa"
    assert World("lab_oval", 1, car={"simulator": "console", "yaw_gain": 0.5}).sim.car_params.yaw_gain == 0.5


def test_step_durations_follow_each_log_kinds_rule():
    t = [10.0, 10.05, 10.13, 10.20]
    # console v5 / DRoA: a row's pose belongs to the previous row's tstamp: row 1 -> 2 lasts 10.05 - 10.0
    assert step_durations(t, "previous")[1:] == pytest.approx([0.05, 0.08])
    assert math.isnan(step_durations(t, "previous")[0])
    assert step_durations(t, "next") == pytest.approx([0.05, 0.08, 0.07])
    assert step_durations(t, "fixed") == pytest.approx([STEP_S] * 3)  # 2022 effort logs: tstamps say nothing
    assert log_timing(car_params("console", "4")) == "fixed" and log_timing(car_params("console", "5")) == "previous"
    assert set(LOG_TIMING) == set(CAR_TABLE)
    with pytest.raises(ValueError, match="unknown step timing"):
        step_durations(t, "whenever")


def test_rollout_reads_tstamps_by_the_simulators_rule():
    """A car at a constant 2 m/s straight ahead: each step moves it 2 m/s x that step's length, and the lengths
    come from the tstamps of the history's row, the start row and the rows after (m + 1 + k values)."""
    car = bare(simulator="console", ground_factor=1.0)
    start = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 2.0, "steering_angle": 0.0}
    hist, acts = [[0.0, 2.0]], [[0.0, 2.0]] * 3
    t = [0.0, 0.05, 0.15, 0.20, 0.30]  # rows: history, start, 3 after
    xs = rollout(start, acts, history=hist, car=car, tstamps=t)[:, 0]
    # ROS 1 velocity ("previous"): steps last 0.05 (t1 - t0), 0.10 (t2 - t1), 0.05 (t3 - t2)
    assert xs == pytest.approx(2.0 * np.cumsum([0.05, 0.10, 0.05]))
    xs4 = rollout(start, acts, history=hist, car=replace(car, control="effort"), tstamps=t)[:, 0]
    assert xs4 == pytest.approx(2.0 * STEP_S * np.arange(1, 4))  # the 2022 effort logs: 1/15 s steps
    with pytest.raises(ValueError, match="m \\+ 1 \\+ k = 5"):
        rollout(start, acts, history=hist, car=car, tstamps=t[:4])


def test_the_acceleration_fades_with_speed_and_slows_the_car_above_the_fade():
    """ROS 1 velocity car: 3 m/s² from a standstill, 3 (1 - (v / 2.5)²) at v, and a slowdown above 2.5 m/s even
    when asked for 4 m/s (one sub-step, so the limit is taken at the step's start speed)."""
    car = bare(accel_mps2=3.0, accel_fade_mps=2.5, brake_mps2=6.0, substeps=1)
    assert step(car, v=0.0, new=(0.0, 4.0))[3] == pytest.approx(3.0 / 15)
    assert step(car, v=2.0, new=(0.0, 4.0))[3] == pytest.approx(2.0 + 3.0 * (1 - 0.64) / 15)  # 1.08 m/s²
    assert step(car, v=3.0, new=(0.0, 4.0))[3] == pytest.approx(3.0 - 3.0 * 0.44 / 15)  # -1.32 m/s²
    assert car.accel_limit(2.0) == pytest.approx(1.08) and car.top_speed() == 2.5
    # no fade: the constant traction limit, as before
    assert step(bare(accel_mps2=3.0, substeps=1), v=3.0, new=(0.0, 4.0))[3] == pytest.approx(3.2)
    # a slow command is reached exactly, the fade only limits gaining speed
    assert step(bare(accel_fade_mps=2.5), v=0.9, new=(0.0, 1.0))[3] == pytest.approx(1.0)


def test_a_steering_change_kicks_the_hinge():
    """A 20° step with kick 0.4 and τ 0.2 s: 8° at once, then the lag closes 1 - e^(-dt/τ) of the remaining 12°;
    a held command kicks nothing."""
    d = math.radians(20)
    car = bare(steer_tau_s=0.2, steer_kick=0.4)
    s = step(car, v=1.0, old=(0.0, 1.0), new=(d, 1.0))[4]
    assert s == pytest.approx(d - 0.6 * d * math.exp(-DT / 0.2))
    held = step(car, v=1.0, steer=0.1, old=(d, 1.0), new=(d, 1.0))[4]
    assert held == pytest.approx(d - (d - 0.1) * math.exp(-DT / 0.2))
    # the kick stays within the lock: 0.9 of a -30° -> 30° swing from -25° would reach 29°, not beyond 30°
    big = step(bare(steer_tau_s=0.2, steer_kick=0.9), v=1.0, steer=math.radians(-25),
               old=(math.radians(-30), 1.0), new=(math.radians(30), 1.0))[4]
    assert math.radians(-25 + 54) < big <= math.radians(30)


def test_randomised_dynamics_draw_within_the_spread(monkeypatch):
    """`randomise` draws each car's constants normal around the fitted ones with the fit's spread, cut at two
    spreads; a constant that is off stays off; no randomise, no draw."""
    from racerlab.sim import car as car_mod

    monkeypatch.setitem(car_mod.CAR_SPREAD, ("droa", "velocity"), {"yaw_gain": 0.05, "slide_mps": 0.3})
    car = replace(car_params("droa"), randomise=1.0)
    rows = car_mod.randomised(car, np.random.default_rng(0), 4000)
    gains = rows[:, car_mod.P_YAW_GAIN]
    assert gains.mean() == pytest.approx(car.yaw_gain, abs=0.005)
    assert gains.std() == pytest.approx(0.05 * 0.96, rel=0.05)  # a unit normal clipped at ±2 has sd 0.96
    assert np.abs(gains - car.yaw_gain).max() <= 0.1 + 1e-12
    assert np.all(rows[:, car_mod.P_SLIDE] == 0.0)  # the droa car has no slide: it stays without
    assert np.array_equal(rows[:, car_mod.P_DELAY], np.full(4000, car.delay_steps))  # no spread: fixed
    sim = Simulator("lab_oval", 3, car, seed=1)
    first = sim._car_arr[:, car_mod.P_YAW_GAIN].copy()
    assert len(set(first)) == 3  # each car its own draw
    sim.reset(np.array([True, False, False]))
    assert sim._car_arr[0, car_mod.P_YAW_GAIN] != first[0] and np.array_equal(sim._car_arr[1:, car_mod.P_YAW_GAIN],
                                                                              first[1:])
    plain = Simulator("lab_oval", 3, car_params("droa"), seed=1)
    assert np.all(plain._car_arr[:, car_mod.P_YAW_GAIN] == car.yaw_gain)


def test_randomised_saturation_stays_on_and_above_its_floor(monkeypatch):
    """The console velocity car's saturation (2.84 m/s²) drawn with a spread of 1.2 at randomise 2.5 would reach
    2.84 - 2 x 2.5 x 1.2 = -3.16: the draws stop at 1 m/s² (0 would switch the saturation off, the car turning
    hardest); a car without saturation stays without."""
    from racerlab.sim import car as car_mod

    monkeypatch.setitem(car_mod.CAR_SPREAD, ("console", "velocity"), {"tyre_sat_mps2": 1.2})
    car = replace(car_params("console"), randomise=2.5, tyre_sat_mps2=2.84)
    sat = car_mod.randomised(car, np.random.default_rng(0), 4000)[:, car_mod.P_SAT]
    assert sat.min() == 1.0 and sat.max() <= 2.84 + 2 * 2.5 * 1.2 + 1e-12 and (sat > 2.84).any()
    off = car_mod.randomised(replace(car, tyre_sat_mps2=0.0), np.random.default_rng(0), 100)[:, car_mod.P_SAT]
    assert np.all(off == 0.0)


def test_randomised_front_drive_stays_off_and_above_zero(monkeypatch):
    """front_drive 0.716 drawn with a spread of 0.5 at randomise 1 would reach 0.716 - 2 x 0.5 < 0: the draws stop at
    0; a car without the front drive (0) stays without, and its step is the one without it."""
    from racerlab.sim import car as car_mod

    monkeypatch.setitem(car_mod.CAR_SPREAD, ("console", "velocity"), {"front_drive": 0.5})
    car = replace(car_params("console"), randomise=1.0, front_drive=0.716)
    drive = car_mod.randomised(car, np.random.default_rng(0), 4000)[:, car_mod.P_DRIVE]
    assert drive.min() == 0.0 and drive.max() <= 0.716 + 2 * 0.5 + 1e-12 and (drive > 0.716).any()
    off = car_mod.randomised(replace(car, front_drive=0.0), np.random.default_rng(0), 100)[:, car_mod.P_DRIVE]
    assert np.all(off == 0.0)


def test_randomised_dynamics_train_only(tmp_path):
    """[car] randomise draws the training episodes' cars; evaluations drive the fitted car; a negative factor is one
    line naming the key."""
    from racerlab.model import load_training_config

    p = tmp_path / "training.toml"
    p.write_text('[car]\nsimulator = "console"\nrandomise = 1.5\n')
    cfg = load_training_config(p)
    assert cfg.car.params("5").randomise == 1.5 and cfg.car.params("5", training=False).randomise == 0.0
    p.write_text("[car]\nrandomise = -1\n")
    with pytest.raises(ConfigError, match="car.randomise"):
        load_training_config(p)
