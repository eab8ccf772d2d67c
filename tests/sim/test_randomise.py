"""Domain randomisation (`racerlab.sim.randomise`, training.toml [randomise]): each option does what the
docs say, with numbers worked out by hand, and seeded runs repeat."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.errors import ConfigError
from racerlab.model import parse_training_config
from racerlab.model.config import RandomiseSettings
from racerlab.sim import World
from racerlab.sim import _kernels as K
from racerlab.sim.randomise import perturb_images

CONTINUOUS = {"action_space": {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 0.5, "high": 2.0}},
              "action_space_type": "continuous", "sensor": ["FEATURES"], "neural_network": "MLP",
              "training_algorithm": "clipped_ppo", "version": "5"}
CAMERA = {**CONTINUOUS, "sensor": ["FRONT_FACING_CAMERA"], "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"}


def _world(cars=1, metadata=CONTINUOUS, observation="features", seed=3, **randomise):
    return World("lab_oval", cars, metadata, None, observation, seed=seed, randomise=randomise or None)


def _applied(world):
    """(steering °, speed m/s) the simulator applied in the last step, per car."""
    return world.sim.car[:, K.CCMD_STEER].copy(), world.sim.car[:, K.CCMD_SPEED].copy()


@pytest.mark.parametrize("latency", [1, 2])
def test_latency_delays_the_applied_action_by_exactly_that_many_steps(latency):
    w = _world(latency_steps=latency)
    commands = np.linspace(-0.9, 0.9, 12)  # steering in [-1, 1] -> 30 * a degrees
    w.step(np.array([[commands[0], 0.0]]))  # step 0: AWS's prepare step, the action is ignored
    for t in range(1, len(commands)):
        w.step(np.array([[commands[t], 0.0]]))
        steer, _ = _applied(w)
        expected = commands[max(t - latency, 0)] * 30.0
        assert steer[0] == pytest.approx(expected, abs=1e-9), t


def test_latency_restarts_with_each_episode():
    w = _world(latency_steps=1)
    for a in (0.5, 0.5, 0.5):
        w.step(np.array([[a, 0.0]]))
    w.sim.reset()
    w.step(np.array([[-0.2, 0.0]]))  # prepare step of the new episode
    w.step(np.array([[0.7, 0.0]]))
    # the delayed action is the new episode's first command, never one left from the last episode
    assert _applied(w)[0][0] == pytest.approx(-0.2 * 30.0)


def test_a_varying_latency_is_drawn_per_episode_from_none_to_the_most():
    n = 600
    w = _world(cars=n, latency_steps=2, latency_varies=True)
    commands = [0.1, 0.2, 0.3, 0.4]
    for a in commands:
        w.step(np.tile([a, 0.0], (n, 1)))
    # step t (0: the prepare step) applies the command of step t - delay, 0.1 (t - delay + 1) x 30 degrees: at step 3
    # 12, 9 or 6 degrees, about a third each
    delays = np.rint(4 - _applied(w)[0] / 3.0).astype(int)
    assert set(delays) == {0, 1, 2} and all(abs(np.mean(delays == k) - 1 / 3) < 0.07 for k in range(3))
    steady = delays.copy()
    w.step(np.tile([0.5, 0.0], (n, 1)))  # the same delay for the rest of the episode
    assert np.array_equal(np.rint(5 - _applied(w)[0] / 3.0).astype(int), steady)
    with pytest.raises(ConfigError, match="latency_varies draws each episode's latency from 0 to latency_steps"):
        parse_training_config({"randomise": {"latency_varies": True}}, "m/training.toml")


def test_without_latency_the_action_is_applied_at_once():
    w = _world(top_speed=2.0)  # active (the actuation runs) but the same as the action space: no change
    w.step(np.array([[0.1, 0.0]]))
    w.step(np.array([[0.4, 1.0]]))
    steer, speed = _applied(w)
    assert steer[0] == pytest.approx(12.0)
    assert speed[0] == pytest.approx(2.0)


def test_gains_are_uniform_around_one_and_fixed_for_an_episode():
    n = 4000
    w = _world(cars=n, steering_gain=0.2, throttle_gain=0.1)
    a = np.tile([0.5, 1.0], (n, 1))  # 15° and 2 m/s commanded
    w.step(a)
    w.step(a)
    steer, speed = _applied(w)
    g_steer, g_speed = steer / 15.0, speed / 2.0
    assert g_steer.min() >= 0.8 - 1e-12 and g_steer.max() <= 1.2 + 1e-12
    assert g_speed.min() >= 0.9 - 1e-12 and g_speed.max() <= 1.1 + 1e-12
    # uniform on [1 - g, 1 + g]: mean 1, standard deviation 2g / sqrt(12); 4000 draws: ~2 % error
    assert g_steer.mean() == pytest.approx(1.0, abs=0.006)
    assert g_steer.std() == pytest.approx(0.4 / math.sqrt(12), rel=0.05)
    assert g_speed.std() == pytest.approx(0.2 / math.sqrt(12), rel=0.05)
    assert np.histogram(g_steer, bins=4, range=(0.8, 1.2))[0].min() > 850  # flat, not bell-shaped
    w.step(a)
    assert np.array_equal(_applied(w)[0] / 15.0, g_steer)  # same gain for the rest of the episode
    w.sim.reset()
    w.step(a)
    w.step(a)
    assert not np.allclose(_applied(w)[0] / 15.0, g_steer)  # a new episode draws new gains


def test_speeds_are_relative_to_the_action_space_top():
    # the car: throttle = scale x speed / top speed of the action space; here full throttle is 3 m/s
    w = _world(cars=2, speed_scale=0.5, top_speed=3.0)
    a = np.array([[0.0, 1.0], [0.0, -1.0 / 3.0]])  # 2.0 m/s and 1.0 m/s commanded
    w.step(a)
    w.step(a)
    assert _applied(w)[1] == pytest.approx([2.0 / 2.0 * 3.0 * 0.5, 1.0 / 2.0 * 3.0 * 0.5])


def test_image_noise_has_the_asked_standard_deviation():
    rng = np.random.default_rng(0)
    frames = np.full((8, 120, 160, 1), 100, dtype=np.uint8)
    ones = np.ones(8)
    out = perturb_images(frames, np.zeros(8), ones, ones, np.zeros(8, int), 5.0, rng).astype(np.float64)
    assert out.mean() == pytest.approx(100.0, abs=0.05)
    # rounding to whole grey levels adds a variance of 1/12
    assert out.std() == pytest.approx(math.sqrt(25 + 1 / 12), rel=0.01)
    assert frames.max() == 100  # the input is left alone


def test_exposure_and_gamma_follow_the_tone_formula():
    frames = np.full((1, 4, 4, 1), 128, dtype=np.uint8)
    out = perturb_images(frames, [0.0], [1.5], [0.8], [0], 0.0, None)
    assert out[0, 0, 0, 0] == round(255 * (1.5 * 128 / 255) ** 0.8)  # 203
    bright = perturb_images(np.full((1, 2, 2, 1), 200, np.uint8), [0.0], [1.5], [1.0], [0], 0.0, None)
    assert bright.max() == 255  # clipped, not wrapped


def test_blur_spreads_a_point_as_a_unit_gaussian():
    frames = np.zeros((1, 41, 41, 1), dtype=np.uint8)
    frames[0, 20, 20, 0] = 255
    out = perturb_images(frames, [1.0], [1.0], [1.0], [0], 0.0, None)[0, :, :, 0].astype(float)
    peak = 255 / (2 * math.pi)  # a 2-D Gaussian of sigma 1 px at its centre
    assert out[20, 20] == pytest.approx(peak, abs=1.0)
    assert out[20, 21] == pytest.approx(peak * math.exp(-0.5), abs=1.0)
    assert out.sum() == pytest.approx(255, abs=6)


def test_pitch_shifts_rows_and_repeats_the_edge():
    frames = np.arange(10, dtype=np.uint8).repeat(3).reshape(1, 10, 3, 1)
    out = perturb_images(frames, [0.0], [1.0], [1.0], [3], 0.0, None)[0, :, 0, 0]
    assert out.tolist() == [3, 4, 5, 6, 7, 8, 9, 9, 9, 9]


def test_camera_pose_jitter_renders_the_view_from_the_moved_camera():
    w = _world(cars=3, metadata=CAMERA, observation="camera", pose_yaw_deg=4.0, pose_shift_m=0.05)
    frames = w.observe()
    yaw_off, side = w.observation.pose[:, 0], w.observation.pose[:, 1]
    assert np.abs(yaw_off).max() <= math.radians(4.0) and np.abs(side).max() <= 0.05
    assert np.abs(yaw_off).min() > 0  # drawn, not left at 0
    plain = _world(cars=3, metadata=CAMERA, observation="camera")
    for i in range(3):
        x, y, yaw = w.sim.pose[i]
        plain.sim.set_pose(i, x - side[i] * math.sin(yaw), y + side[i] * math.cos(yaw), yaw + yaw_off[i])
    assert np.array_equal(plain.observe(), frames)


def test_lidar_noise_adds_the_asked_spread_to_ranges():
    noisy = _world(cars=64, observation="lidar:walls", lidar_noise_m=0.05)
    plain = World("lab_oval", 64, CONTINUOUS, None, "lidar:walls", seed=3)
    a, b = noisy.observe(), plain.observe()  # the simulator's own lidar noise is the same draw in both
    inside = (b > 0.3) & (b < 0.7)
    assert inside.sum() > 500
    assert (a - b)[inside].std() == pytest.approx(0.05, rel=0.1)
    assert a.min() >= 0.15 and a.max() <= 1.0


def test_lighting_turns_on_the_camera_look_randomisation():
    w = _world(metadata=CAMERA, observation="camera", lighting=True)
    assert w.observation.inner.camera.randomization is not None


def test_seeded_runs_repeat_and_seeds_differ():
    opts = dict(cars=4, metadata=CAMERA, observation="camera", camera_noise=3.0, blur=1.0, exposure=0.2, gamma=0.2,
                pose_pitch_deg=2.0, latency_steps=1, steering_gain=0.1, throttle_gain=0.1)

    def run(seed):
        w = _world(seed=seed, **opts)
        out = []
        for t in range(4):
            out.append(w.observe())
            w.step(np.tile([0.3 - 0.1 * t, 0.5], (4, 1)))
            out.append(w.sim.car[:, [K.CX, K.CY, K.CCMD_STEER]].copy())
        return out

    first, again, other = run(5), run(5), run(6)
    assert all(np.array_equal(x, y) for x, y in zip(first, again, strict=True))
    assert not all(np.array_equal(x, y) for x, y in zip(first, other, strict=True))


def test_default_settings_leave_the_plain_path():
    w = World("lab_oval", 2, CONTINUOUS, None, "features", seed=1, randomise=RandomiseSettings())
    assert w.actuation is None and type(w.observation).__name__ == "FeaturesObservation"
    assert not RandomiseSettings().active and RandomiseSettings(latency_steps=1).active


def test_randomise_table_is_read_and_checked():
    cfg = parse_training_config({"randomise": {"camera_noise": 4, "latency_steps": 2, "lighting": True}})
    assert cfg.randomise.camera_noise == 4.0 and cfg.randomise.latency_steps == 2 and cfg.randomise.active
    assert "[randomise]" in cfg.to_toml()
    with pytest.raises(ConfigError, match="randomise.latency_steps must be 0, 1 or 2"):
        parse_training_config({"randomise": {"latency_steps": 3}}, "m/training.toml")
    with pytest.raises(ConfigError, match="unknown key randomise.noise"):
        parse_training_config({"randomise": {"noise": 3}})
    with pytest.raises(ConfigError, match="randomise.steering_gain must be in"):
        parse_training_config({"randomise": {"steering_gain": 1.5}})


def test_randomisation_does_not_touch_the_observation_of_other_rows():
    w = _world(cars=4, metadata=CAMERA, observation="camera", camera_noise=20.0)
    full = w.observe()
    again = w.observe(rows=[1])
    assert np.array_equal(again[[0, 2, 3]], w.observation.inner.camera.frames[[0, 2, 3]])
    assert not np.array_equal(again[1], full[1])  # fresh noise for the row rendered


def test_the_reward_sees_the_models_action_and_the_car_the_applied_one():
    seen = []

    def reward(params):
        seen.append((params["steering_angle"], params["speed"]))
        return 1.0

    w = World("lab_oval", 1, CONTINUOUS, reward, "features", seed=0,
              randomise={"latency_steps": 1, "speed_scale": 0.5})
    w.step(np.array([[0.2, 1.0]]))
    w.step(np.array([[0.4, 1.0]]))
    assert seen[-1] == pytest.approx((12.0, 2.0))  # the action chosen at this step, in the action space's m/s
    assert _applied(w)[0][0] == pytest.approx(6.0) and _applied(w)[1][0] == pytest.approx(1.0)
