"""The Stable-Baselines3 adapter: SB3's VecEnv contract, its env checker, and PPO learning a lap through it."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.env_checker import check_env  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor  # noqa: E402

from racerlab.errors import ConfigError  # noqa: E402
from racerlab.sim.env import DeepRacerEnv  # noqa: E402
from racerlab.sim.sb3 import DeepRacerSB3VecEnv  # noqa: E402


def centre_and_speed(params):
    if not params["all_wheels_on_track"]:
        return 1e-3
    return 1.0 - (params["distance_from_center"] / (0.5 * params["track_width"])) ** 0.5 + params["speed"]


def test_sb3_env_checker_passes_on_the_single_env():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # SB3's checker warns about anything it would trip over
        check_env(DeepRacerEnv("lab_oval", centre_and_speed, render_mode="rgb_array"), warn=True)


def test_vec_env_contract_matches_dummy_vec_env():
    """Shapes and dtypes as SB3's own DummyVecEnv gives them; same-step autoreset with terminal_observation."""
    n, cap = 3, 6
    ours = DeepRacerSB3VecEnv(n, track="lab_oval", reward_function=centre_and_speed, max_episode_steps=cap)
    ref = DummyVecEnv([lambda: DeepRacerEnv("lab_oval", centre_and_speed, max_episode_steps=cap)] * n)
    assert ours.num_envs == n and ours.observation_space == ref.observation_space
    assert ours.action_space == ref.action_space and ours.render_mode == ref.render_mode
    ours.seed(0)
    obs, ref_obs = ours.reset(), ref.reset()
    assert obs.shape == ref_obs.shape == (n, *ref.observation_space.shape) and obs.dtype == ref_obs.dtype
    assert [i["steps"] for i in ours.reset_infos] == [0] * n
    straight = np.full(n, 5)  # 0°, 1 m/s in the default action list: 6 steps stay on the track
    for step in range(1, cap + 1):
        obs, rew, done, infos = ours.step(straight)
        _, ref_rew, ref_done, ref_infos = ref.step(straight)
        assert rew.dtype == ref_rew.dtype and rew.shape == (n,) and done.dtype == ref_done.dtype
        assert len(infos) == n and all(isinstance(i, dict) for i in infos)
        assert list(done) == [step == cap] * n
    for i, info in enumerate(infos):  # every car hit the step cap: truncated, reset in the same step
        assert info["TimeLimit.truncated"] and ref_infos[i]["TimeLimit.truncated"]
        assert info["steps"] == cap and info["episode_status"] == "in_progress"
        assert info["terminal_observation"].shape == obs[i].shape
        assert not np.allclose(info["terminal_observation"], obs[i])  # obs is the next episode's first
    assert list(ours.venv.unwrapped.sim.steps) == [0] * n
    assert ours.get_attr("render_mode") == [None] * n
    assert ours.env_is_wrapped(VecMonitor) == [False] * n
    with pytest.raises(ConfigError, match="set_attr"):
        ours.set_attr("render_mode", None, indices=[0])


def _greedy_episode(model, seed):
    env = DeepRacerEnv("lab_oval", max_episode_steps=400)
    obs, info = env.reset(seed=seed)
    done = False
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, _, term, trunc, info = env.step(action)
        done = term or trunc
    return info


def test_sb3_ppo_learns_a_lap_through_the_adapter():
    torch.manual_seed(0)
    venv = VecMonitor(DeepRacerSB3VecEnv(8, track="lab_oval", reward_function=centre_and_speed,
                                         max_episode_steps=400, seed=0))
    model = PPO("MlpPolicy", venv, n_steps=128, batch_size=256, n_epochs=5, learning_rate=1e-3, seed=0, device="cpu")
    untrained = _greedy_episode(model, seed=1)
    assert untrained["episode_status"] != "lap_complete"  # the lap below is learned, not luck
    for _ in range(6):
        model.learn(4096, reset_num_timesteps=False)
        info = _greedy_episode(model, seed=1)
        if info["episode_status"] == "lap_complete":
            break
    assert info["episode_status"] == "lap_complete" and info["progress"] == pytest.approx(100.0)
    assert len(model.ep_info_buffer) > 0  # VecMonitor saw whole episodes end through the adapter's dones


def test_sb3_make_vec_env_builds_without_warnings():
    from stable_baselines3.common.env_util import make_vec_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # it used to warn that rgb_array is not a declared render mode
        venv = make_vec_env("racerlab/DeepRacer-v0", n_envs=2, env_kwargs={"track": "lab_oval"})
    assert venv.render_mode == "rgb_array" and venv.reset().shape[0] == 2
