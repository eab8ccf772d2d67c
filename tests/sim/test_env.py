"""The Gymnasium adapters: registration, env_checker, the batched vector env and its autoreset."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import racerlab  # noqa: F401 - registers racerlab/DeepRacer-v0
from racerlab.errors import ConfigError
from racerlab.sim.env import DeepRacerEnv, DeepRacerVectorEnv

CONTINUOUS = {"action_space_type": "continuous", "sensor": ["FEATURES"], "neural_network": "MLP",
              "action_space": {"steering_angle": {"low": -20, "high": 10}, "speed": {"low": 0.5, "high": 3.5}}}


def centre_reward(params):
    w = params["track_width"]
    d = params["distance_from_center"]
    return 1.0 if d <= 0.1 * w else 0.5 if d <= 0.25 * w else 1e-3


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("metadata", [None, CONTINUOUS])
def test_single_env_passes_env_checker(aws_track, metadata):
    env = gym.make("racerlab/DeepRacer-v0", track=aws_track("reInvent2019_track"), reward_function=centre_reward,
                   model_metadata=metadata, observation="features")
    check_env(env.unwrapped)
    assert isinstance(env.unwrapped, DeepRacerEnv)


def test_continuous_actions_are_clipped_and_rescaled(aws_track):
    env = DeepRacerEnv(aws_track("reInvent2019_track"), centre_reward, CONTINUOUS)
    env.reset(seed=0)
    env.step(np.array([0.0, 0.0], np.float32))
    _, _, _, _, info = env.step(np.array([-1.0, 2.0], np.float32))
    assert info["params"]["steering_angle"] == -20.0
    assert info["params"]["speed"] == 3.5
    _, _, _, _, info = env.step(np.array([0.5, -0.5], np.float32))
    assert info["params"]["steering_angle"] == pytest.approx(2.5)
    assert info["params"]["speed"] == pytest.approx(1.25)


def test_discrete_actions_follow_metadata(aws_track):
    meta = {"action_space": [{"steering_angle": 15, "speed": 0.7}, {"steering_angle": -5, "speed": 2.2}],
            "sensor": ["FEATURES"], "neural_network": "MLP"}
    env = DeepRacerEnv(aws_track("reInvent2019_track"), centre_reward, meta)
    assert env.action_space == gym.spaces.Discrete(2)
    env.reset(seed=0)
    env.step(0)
    _, _, _, _, info = env.step(1)
    assert (info["params"]["steering_angle"], info["params"]["speed"]) == (-5, 2.2)


def test_make_vec_gives_the_batched_simulator(aws_track):
    venv = gym.make_vec("racerlab/DeepRacer-v0", num_envs=16, vectorization_mode="vector_entry_point",
                        track=aws_track("reInvent2019_track"), reward_function=centre_reward)
    assert isinstance(venv.unwrapped, DeepRacerVectorEnv)
    assert venv.unwrapped.sim.num_cars == 16
    obs, info = venv.reset(seed=3)
    assert obs.shape == (16, venv.unwrapped.single_observation_space.shape[0]) and obs.dtype == np.float32
    assert venv.observation_space.contains(obs)


def test_vector_env_matches_single_envs(aws_track):
    """Car i of the batch behaves exactly like a single env started at the same point."""
    track = aws_track("reInvent2019_track")
    n = 4
    venv = DeepRacerVectorEnv(n, track, centre_reward, start={"advance": 0.25})
    singles = [DeepRacerEnv(track, centre_reward, start={"offset": 0.25 * i}) for i in range(n)]
    obs_v, _ = venv.reset(seed=0)
    obs_s = [e.reset(seed=0)[0] for e in singles]
    assert np.allclose(obs_v, np.stack(obs_s))
    rng = np.random.default_rng(0)
    alive = [True] * n  # a car is compared up to its first episode's end (the batch then restarts it at once)
    for _ in range(40):
        a = rng.integers(0, 10, n)
        ov, rv, tv, trv, iv = venv.step(a)
        for i, e in enumerate(singles):
            if not alive[i]:
                continue
            o, r, t, tr, info = e.step(int(a[i]))
            assert r == rv[i] and t == tv[i] and info["episode_status"] == iv["episode_status"][i]
            if t:
                alive[i] = False
                continue
            assert np.allclose(o, ov[i])
    assert any(alive)  # not every car left the track at once: the observations were compared


def test_same_step_autoreset_keeps_final_observation(aws_track):
    venv = DeepRacerVectorEnv(2, aws_track("reInvent2019_track"), centre_reward)
    venv.reset(seed=0)
    for _ in range(200):
        obs, rew, term, trunc, info = venv.step(np.array([4, 4]))  # straight at 1 m/s: off the track soon
        if term.any():
            break
    assert term.any()
    i = int(np.flatnonzero(term)[0])
    fin = info["final_info"]
    assert info["_final_obs"][i] and fin["_episode_status"][i] and fin["episode_status"][i] == "off_track"
    assert list(fin["_progress"]) == list(term | trunc) and fin["steps"][i] == info["steps"][i] > 0
    assert not np.allclose(info["final_obs"][i], obs[i])  # the new episode's first observation
    assert venv.unwrapped.sim.steps[i] == 0  # reset, waiting for its prepare step


def test_no_reward_function_is_the_fast_path(aws_track):
    env = DeepRacerEnv(aws_track("reInvent2019_track"))
    env.reset(seed=0)
    env.step(0)
    _, r, _, _, info = env.step(0)
    assert r == 0.0 and "params" not in info


def test_unknown_observation_is_a_clear_error(aws_track):
    with pytest.raises(ConfigError, match="observation 'radar' is not available"):
        DeepRacerEnv(aws_track("reInvent2019_track"), observation="radar")


def _run_to_first_end(venv, action):
    venv.reset(seed=0)
    for _ in range(300):
        obs, rew, term, trunc, info = venv.step(np.array([action] * venv.num_envs))
        if term.any():
            return term, info
    raise AssertionError("no episode ended")


def test_vector_info_is_batched_like_gymnasiums_own_vector_envs(aws_track):
    """Gymnasium's SyncVectorEnv over the single env is the reference: same keys, masks and dtypes."""
    track = aws_track("reInvent2019_track")
    ours = DeepRacerVectorEnv(2, track, centre_reward)
    theirs = gym.vector.SyncVectorEnv([lambda: DeepRacerEnv(track, centre_reward) for _ in range(2)],
                                      autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    (t1, ours_info), (t2, ref_info) = _run_to_first_end(ours, 4), _run_to_first_end(theirs, 4)
    def keys(d):  # the single env always keeps params; the vector env only with info_params=True
        return sorted(set(d) - {"params", "_params"})

    assert keys(ours_info) == keys(ref_info)
    assert keys(ours_info["final_info"]) == keys(ref_info["final_info"])
    for info, term in ((ours_info, t1), (ref_info, t2)):
        assert info["_steps"].all() and info["_episode_status"].all()
        fin = info["final_info"]
        assert list(fin["_episode_status"]) == list(term)
        assert set(fin["episode_status"][term]) == {"off_track"}
    for key in ("progress", "steps"):
        assert ours_info["final_info"][key].dtype.kind == ref_info["final_info"][key].dtype.kind


def test_render_modes_are_declared_so_make_vec_env_does_not_warn(aws_track):
    import warnings

    env = gym.make("racerlab/DeepRacer-v0", track=aws_track("reInvent2019_track"), render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3 and frame.std() > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        venv = gym.make_vec("racerlab/DeepRacer-v0", num_envs=2, vectorization_mode="vector_entry_point",
                            track=aws_track("reInvent2019_track"), render_mode="rgb_array")
    venv.reset(seed=0)
    assert len(venv.render()) == 2
    with pytest.raises(ConfigError, match="render_mode"):
        DeepRacerEnv(aws_track("reInvent2019_track"), render_mode="human")


def test_the_envs_say_which_car_they_drive(aws_track):
    track = aws_track("reInvent2019_track")
    env = DeepRacerEnv(track, centre_reward, {**CONTINUOUS, "version": "5"}, car="console")
    _, info = env.reset(seed=0)
    assert info["car"] == env.car.name == "console, velocity control (version >= 5)"
    effort = DeepRacerEnv(track, centre_reward, {**CONTINUOUS, "version": "4"})  # the default simulator: droa
    assert effort.reset(seed=0)[1]["car"] == "droa, effort control (version 3-4)"
    venv = DeepRacerVectorEnv(3, track, centre_reward, {**CONTINUOUS, "version": "5.0"},
                              car={"simulator": "console", "yaw_gain": 0.5})
    _, info = venv.reset(seed=0)
    assert list(info["car"]) == ["console, velocity control (version >= 5)"] * 3 and info["_car"].all()
    assert venv.car.yaw_gain == 0.5
